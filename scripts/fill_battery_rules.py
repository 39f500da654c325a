"""The rules the 10 % grid task's learned agent is read against: every port charging in one
priority class (EDF through `chargax_marl.wrappers.priority_class_levels`) and the battery
charging or discharging by a battery rule, filled after the cars. Scored like any policy on
the task's held-out days and draws, and paired per day with the scoreboard's IPPO score file.

    python scripts/fill_battery_rules.py --out results/ablation/fill_battery_rules.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from chargax_marl.benchmark import score
from chargax_marl.benchmark.tasks import get_task
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.policies import get_policy
from chargax_marl.wrappers import priority_class_levels

TASK = "Chargax-shopping-grid10-high-v1"
LEARNED = "results/scores/ippo_Chargax-shopping-grid10-high-v1.json"


def fill_rule(battery_rule: str, params):
    """Ports in the one charging class; the battery's class from ``battery_rule``'s level."""
    base = get_policy(battery_rule, params)
    is_battery = params.station.leaf_kind == KIND_BATTERY

    def policy(state, key, p):
        level = base(state, key, p)
        battery = jnp.where(level > 0, 2, jnp.where(level < 0, 0, 1))  # charge, discharge, idle
        return priority_class_levels(jnp.where(is_battery, battery, 2), state, p, 1)

    return policy


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=None, help="write the result JSON here")
    args = parser.parse_args(argv)
    task = get_task(TASK)
    learned = np.asarray(json.loads(Path(LEARNED).read_text())["daily_profit"]).mean(axis=(0, 2))
    out = {"task": TASK, "learned": LEARNED, "rules": {}}
    for battery_rule in ("battery_rule", "battery_programme"):
        result = score(fill_rule(battery_rule, task.make_params()), TASK)
        rule_day = np.asarray(result["daily_profit"], np.float64).mean(axis=-1)
        diff = learned - rule_day
        out["rules"][f"edf_fill+{battery_rule}"] = {
            "score": result["score"],
            "score_stderr": result["score_stderr"],
            "vs_edf": result["vs"]["edf"],
            "learned_minus_rule": {
                "mean": float(diff.mean()),
                "stderr": float(diff.std(ddof=1) / np.sqrt(diff.size)),
            },
        }
    print(json.dumps(out, indent=1))
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()
