"""``python -m baselines.analysis.plan_rule``: the car plan teacher played as a rule.

The teacher is `chargax_marl.teachers.car_plan`: each parked car's remaining demand
valued by its cheapest plan under the day's prices.
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

from baselines.analysis.references import RESULTS_DIR, SCENARIOS
from baselines.config import build_env_params, resolve
from baselines.eval import references, stats
from baselines.eval.rules import evaluate_rules
from chargax_marl.evaluation import run_days
from chargax_marl.teachers.car_plan import plan_action
from chargax_marl.trace import params_fingerprint


def bound_headroom(bound_profit, always_max_profit) -> tuple[np.ndarray, float]:
    """The days whose LP bound was solved, and the bound's mean headroom over always-max on
    them (a failed solve is stored as ``None``; a plain mean would make every fraction NaN).

    Args:
        bound_profit: ``(days,)`` the bound's daily profit (EUR), ``None`` where it failed.
        always_max_profit: ``(days,)`` always-max's daily profit (EUR) on the same days.

    Returns:
        ``(solved, headroom_eur)``: a ``(days,)`` bool mask and the mean of bound minus
        always-max over the masked days (EUR/day).

    Raises:
        ValueError: the shapes differ, or no day was solved.
    """
    bound = np.asarray(bound_profit, dtype=np.float64)
    am = np.asarray(always_max_profit, dtype=np.float64)
    if bound.shape != am.shape:
        raise ValueError(f"bound_profit: shape {bound.shape} differs from always-max's {am.shape}")
    solved = np.isfinite(bound)
    if not solved.any():
        raise ValueError("bound_profit: no day has a solved bound (every entry is None or NaN)")
    return solved, float(np.mean(bound[solved] - am[solved]))


def main(argv=None) -> dict:
    """``python -m baselines.analysis.plan_rule [--scenario default]``: the plan rule (`plan_action`)
    on the 100 held-out days of a scenario of `baselines.analysis.references`, with and without the
    programme's battery, at several plan power fractions, against always-max and the battery
    rule (paired over days, the same cars), and the fraction of the LP bound's headroom from
    the stored references of the same parameters (the scenario's, one level per port: the
    ``*_full_power`` files of ``make optimal``).

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        ``{"scenario", "always_max_eur", "headroom_eur", "rows"}``: always-max's mean daily
        profit and the bound's mean headroom over it (EUR/day), and one row per battery
        (``"idle"``, ``"dp"``) and power fraction (``None``: always-max ports, with the
        programme's battery only) with ``vs_always_max``, ``vs_battery_rule`` (paired
        differences in EUR/day), ``headroom_fraction`` and ``energy_delivered_kwh``.

    Raises:
        ValueError: ``--references`` holds no file of these parameters and days.
    """
    p = argparse.ArgumentParser(description=main.__doc__)
    p.add_argument("--scenario", default="default", choices=sorted(SCENARIOS))
    p.add_argument("--fractions", default="0.2,0.5,1.0")
    p.add_argument(
        "--references", default=str(RESULTS_DIR), help="the directory `make optimal` wrote"
    )
    a = p.parse_args(argv)
    scenario = SCENARIOS[a.scenario]
    env_kwargs = {**scenario.get("ENV_KWARGS", {}), "num_levels": 1}
    _, params, _, days = build_env_params(resolve({**scenario, "ENV_KWARGS": env_kwargs}))
    stored = references.cached(params, days, a.references)
    if stored is None:
        raise ValueError(
            f"--references {a.references}: no file holds the LP bound of scenario "
            f"{a.scenario!r} with num_levels=1 on these days (fingerprint "
            f"{params_fingerprint(params)}); run `make optimal` first"
        )
    bound = stored["policies"]["lp_bound"]
    rules = evaluate_rules(params, days, policies=("always_max", "battery_rule"))
    am, rule = rules["always_max"]["daily_profit"], rules["battery_rule"]["daily_profit"]
    solved, headroom = bound_headroom(bound["daily_profit"], am)
    key = jax.random.PRNGKey(0)
    out = {
        "scenario": a.scenario,
        "always_max_eur": float(am.mean()),
        "headroom_eur": headroom,
        "rows": [],
    }
    print(
        f"{a.scenario}: always-max {am.mean():.2f} EUR/day, battery rule {rule.mean() - am.mean():+.2f}, "
        f"bound headroom {headroom:.2f} over the {int(solved.sum())} days it was solved; "
        f"{len(days)} held-out days, key 0"
    )
    for battery in ("idle", "dp"):
        for frac in [None] * (battery == "dp") + [float(x) for x in a.fractions.split(",")]:
            act = plan_action(params, battery, frac)
            # run_days compiles the play itself and then checks the policy's outputs
            totals = run_days(lambda s, kk, act=act: act(s, kk, params), params, days, key)
            profit = np.asarray(totals.profit_eur, np.float64)
            row = {
                "battery": battery,
                "power_fraction": frac,
                "vs_always_max": stats.paired_difference(profit, am),
                "vs_battery_rule": stats.paired_difference(profit, rule),
                "headroom_fraction": float((profit[solved].mean() - am[solved].mean()) / headroom),
                "energy_delivered_kwh": float(np.mean(totals.energy_delivered_kwh)),
            }
            out["rows"].append(row)
            ports = "always-max" if frac is None else f"plan {frac:.1f}"
            print(
                f"  ports {ports:<10}, battery {battery:<4}: vs always-max {row['vs_always_max']['mean']:+6.2f} "
                f"± {row['vs_always_max']['stderr']:.2f}, vs battery rule {row['vs_battery_rule']['mean']:+6.2f} "
                f"± {row['vs_battery_rule']['stderr']:.2f}, headroom {row['headroom_fraction']:.3f}, "
                f"delivered {row['energy_delivered_kwh']:.1f} kWh"
            )
    return out


if __name__ == "__main__":
    main()
