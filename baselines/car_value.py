"""The car plan teacher in the trainers' config (``PORT_SHAPING="plan"``, ``PLAN_OBS``), and
``python -m baselines.car_value``, the plan played as a rule.

The teacher itself is library code, :mod:`chargax_marl.teachers.car_plan`: each parked car's
remaining demand valued by its cheapest plan under the day's prices (a potential per car),
and the plan advice, charge now or wait (an observation column, ``PLAN_OBS``). This module
maps the trainers' ``PORT_SHAPING`` setting onto it.
"""

from __future__ import annotations

import argparse
import json

import jax
import numpy as np

from baselines import common
from baselines.heuristics import evaluate_rules
from baselines.optimal import RESULTS_DIR, SCENARIOS
from chargax_marl.evaluation import run_days
from chargax_marl.teachers import car_plan

# Re-exported for the trainers until they import the library (chargax_marl.teachers.car_plan).
from chargax_marl.teachers.car_plan import (  # noqa: F401
    PLAN_POWER_FRACTION,
    batched,
    car_values,
    plan_action,
    plan_advice,
    plan_energy,
    plan_value,
    price_order,
    steps_of,
)

PORT_SHAPING_MODES = ("off", "plan")


def port_shaping_mode(config: dict) -> str:
    """``PORT_SHAPING`` as one of :data:`PORT_SHAPING_MODES`."""
    mode = config.get("PORT_SHAPING", "off")
    mode = "off" if mode in (None, False) else mode
    if mode not in PORT_SHAPING_MODES:
        raise ValueError(f"PORT_SHAPING must be one of {PORT_SHAPING_MODES}, got {config.get('PORT_SHAPING')!r}")
    return mode


def car_potential(config: dict, env_params):
    """``None`` when ``PORT_SHAPING`` is off, else the per-car potential of
    :func:`chargax_marl.teachers.car_plan.car_potential`: ``potential(env_state) -> shift``."""
    if port_shaping_mode(config) == "off":
        return None
    return car_plan.car_potential(env_params)


def main(argv=None) -> dict:
    """``python -m baselines.car_value [--scenario default]``: the plan rule (:func:`plan_action`)
    on the 100 held-out days of a scenario of :mod:`baselines.optimal`, with and without the
    programme's battery, at several plan power fractions, against always-max and the battery
    rule (paired over days, the same cars), and the fraction of the LP bound's headroom from
    ``baselines/results/optimal/<scenario>.json``."""
    p = argparse.ArgumentParser(description=main.__doc__)
    p.add_argument("--scenario", default="default", choices=sorted(SCENARIOS))
    p.add_argument("--fractions", default="0.2,0.5,1.0")
    a = p.parse_args(argv)
    config = common.parse_config({}, {**SCENARIOS[a.scenario], "ENV_KWARGS": {"num_levels": 1}})
    _, params, _, days = common.build_env_params(config)
    rules = evaluate_rules(params, days, policies=("always_max", "battery_rule"))
    am, rule = rules["always_max"]["daily_profit"], rules["battery_rule"]["daily_profit"]
    bound = json.loads((RESULTS_DIR / f"{a.scenario}.json").read_text())["policies"]["lp_bound"]
    headroom = float(np.mean(bound["daily_profit"]) - np.mean(am))
    key = jax.random.PRNGKey(0)
    out = {"scenario": a.scenario, "always_max_eur": float(am.mean()), "headroom_eur": headroom, "rows": []}
    print(f"{a.scenario}: always-max {am.mean():.2f} EUR/day, battery rule {rule.mean() - am.mean():+.2f}, "
          f"bound headroom {headroom:.2f}; {len(days)} held-out days, key 0")
    for battery in ("idle", "dp"):
        for frac in [None] * (battery == "dp") + [float(x) for x in a.fractions.split(",")]:
            act = plan_action(params, battery, frac)
            totals = jax.jit(lambda d, k: run_days(lambda s, kk: act(s, kk, params), params, d, k))(np.asarray(days), key)
            profit = np.asarray(totals.profit_eur, np.float64)
            row = {"battery": battery, "power_fraction": frac, "vs_always_max": common.paired_difference(profit, am),
                   "vs_battery_rule": common.paired_difference(profit, rule),
                   "headroom_fraction": float((profit.mean() - am.mean()) / headroom),
                   "energy_delivered_kwh": float(np.mean(totals.energy_delivered_kwh))}
            out["rows"].append(row)
            ports = "always-max" if frac is None else f"plan {frac:.1f}"
            print(f"  ports {ports:<10}, battery {battery:<4}: vs always-max {row['vs_always_max']['mean']:+6.2f} "
                  f"± {row['vs_always_max']['stderr']:.2f}, vs battery rule {row['vs_battery_rule']['mean']:+6.2f} "
                  f"± {row['vs_battery_rule']['stderr']:.2f}, headroom {row['headroom_fraction']:.3f}, "
                  f"delivered {row['energy_delivered_kwh']:.1f} kWh")
    return out


if __name__ == "__main__":
    main()
