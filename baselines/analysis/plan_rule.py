"""``python -m baselines.analysis.plan_rule``: the car plan teacher played as a rule.

The teacher is `chargax_marl.teachers.car_plan`: each parked car's remaining demand
valued by its cheapest plan under the day's prices.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import numpy as np

from baselines.analysis.references import RESULTS_DIR, SCENARIOS
from baselines.config import build_env_params, resolve
from baselines.eval import stats
from baselines.eval.rules import evaluate_rules
from chargax_marl.evaluation import run_days
from chargax_marl.teachers.car_plan import plan_action


def main(argv=None) -> dict:
    """``python -m baselines.analysis.plan_rule [--scenario default]``: the plan rule (`plan_action`)
    on the 100 held-out days of a scenario of `baselines.analysis.references`, with and without the
    programme's battery, at several plan power fractions, against always-max and the battery
    rule (paired over days, the same cars), and the fraction of the LP bound's headroom from
    ``<references>/<scenario>.json``.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        ``{"scenario", "always_max_eur", "headroom_eur", "rows"}``: always-max's mean daily
        profit and the bound's mean headroom over it (EUR/day), and one row per battery
        (``"idle"``, ``"dp"``) and power fraction (``None``: always-max ports, with the
        programme's battery only) with ``vs_always_max``, ``vs_battery_rule`` (paired
        differences in EUR/day), ``headroom_fraction`` and ``energy_delivered_kwh``.
    """
    p = argparse.ArgumentParser(description=main.__doc__)
    p.add_argument("--scenario", default="default", choices=sorted(SCENARIOS))
    p.add_argument("--fractions", default="0.2,0.5,1.0")
    p.add_argument(
        "--references", default=str(RESULTS_DIR), help="the directory `make optimal` wrote"
    )
    a = p.parse_args(argv)
    config = resolve({**SCENARIOS[a.scenario], "ENV_KWARGS": {"num_levels": 1}})
    _, params, _, days = build_env_params(config)
    rules = evaluate_rules(params, days, policies=("always_max", "battery_rule"))
    am, rule = rules["always_max"]["daily_profit"], rules["battery_rule"]["daily_profit"]
    bound = json.loads((Path(a.references) / f"{a.scenario}.json").read_text())["policies"][
        "lp_bound"
    ]
    headroom = float(np.mean(bound["daily_profit"]) - np.mean(am))
    key = jax.random.PRNGKey(0)
    out = {
        "scenario": a.scenario,
        "always_max_eur": float(am.mean()),
        "headroom_eur": headroom,
        "rows": [],
    }
    print(
        f"{a.scenario}: always-max {am.mean():.2f} EUR/day, battery rule {rule.mean() - am.mean():+.2f}, "
        f"bound headroom {headroom:.2f}; {len(days)} held-out days, key 0"
    )
    for battery in ("idle", "dp"):
        for frac in [None] * (battery == "dp") + [float(x) for x in a.fractions.split(",")]:
            act = plan_action(params, battery, frac)
            totals = jax.jit(lambda d, k: run_days(lambda s, kk: act(s, kk, params), params, d, k))(
                np.asarray(days), key
            )
            profit = np.asarray(totals.profit_eur, np.float64)
            row = {
                "battery": battery,
                "power_fraction": frac,
                "vs_always_max": stats.paired_difference(profit, am),
                "vs_battery_rule": stats.paired_difference(profit, rule),
                "headroom_fraction": float((profit.mean() - am.mean()) / headroom),
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
