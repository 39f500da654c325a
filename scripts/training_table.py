"""Print the Markdown table of trained runs for the docs.

    python scripts/training_table.py RUN_DIR [RUN_DIR ...] [--compare OLD_ROOT [--old-suffix S]]

Reads each ``RUN_DIR/results.json`` (written by ``python -m baselines.train``) and prints one
row per run: the algorithm, the scenario, the car draws per held-out day, steps × seeds, the
wall time, then each paired difference to a reference (the mean over seeds of each seed's
paired difference on the held-out days, ± its standard error over seeds, and how many seeds
are above the reference by two of their own standard errors over days) and the fraction of
the hindsight headroom captured. Then, per run, where the profit comes from: each policy's
daily profit, battery wear, battery terminal value and energy delivered (means over the
held-out days). With ``--compare`` it also prints, per run, how far the paired differences
moved from ``OLD_ROOT/<run name><S>/results.json`` (a checkout of the previous results, or
the runs kept under another name: ``--compare results --old-suffix _free_battery``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

REFERENCES = {
    "always_max": "always-max",
    "battery_rule": "battery rule",
    "battery_programme": "battery programme",
    "plan_programme": "plan programme",
}


def _signed(x: float) -> str:
    return f"{'−' if x < 0 else '+'}{abs(x):.2f}"


def _above(per_seed: list[dict], name: str) -> int:
    """Seeds whose paired difference to ``name`` is above 0 by two standard errors."""
    return sum(
        1
        for p in per_seed
        if p.get(f"vs_{name}") and p[f"vs_{name}"]["mean"] > 2 * p[f"vs_{name}"]["stderr"]
    )


def row(results: dict) -> list[str]:
    """The table cells of one run's ``results.json``."""
    over, per_seed = results["over_seeds"], results["per_seed"]
    scenario = results["scenario"]
    cells = [
        results["algo"].upper(),
        f"`{scenario['name']}`",
        str(scenario.get("car_draws_per_day", 1)),
        f"{results['timesteps']:.2g} × {results['seeds']}",
        f"{results['wall_seconds'] / 60:.1f} min",
    ]
    for name in REFERENCES:
        d = over.get(f"vs_{name}")
        cells.append(
            "—"
            if d is None
            else f"{_signed(d['mean'])} ± {d['stderr']:.2f} ({_above(per_seed, name)}/"
            f"{len(per_seed)})"
        )
    h = over.get("headroom_fraction")
    cells.append("—" if h is None else f"{h['mean']:.3f} ± {h['stderr']:.3f}")
    return cells


def table(runs: dict[str, dict]) -> str:
    """The Markdown table of ``runs`` (run name -> its ``results.json``)."""
    head = ["run", "algorithm", "scenario", "draws", "steps × seeds", "wall"]
    head += [f"vs {label}" for label in REFERENCES.values()] + ["headroom"]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for name, results in runs.items():
        lines.append(f"| `{name}` | " + " | ".join(row(results)) + " |")
    return "\n".join(lines)


METRICS = {
    "daily_profit_eur": "profit EUR/day",
    "battery_wear_eur": "battery wear EUR/day",
    "battery_terminal_value_eur": "battery terminal value EUR/day",
    "energy_delivered_kwh": "energy delivered kWh/day",
}
POLICIES = ("always_max", "battery_rule", "battery_programme", "plan_programme")


def metrics(name: str, results: dict) -> str:
    """The Markdown table of one run's metrics, for its learner and the rules it is scored
    against (the means over the held-out days; the learner's also over its seeds)."""
    table_ = results["evaluation"]["table"]
    policies = [p for p in POLICIES if p in table_] + [results["algo"]]
    head = [f"`{name}`"] + [
        ("learned " + p.upper()) if p == results["algo"] else p for p in policies
    ]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for key, label in METRICS.items():
        cells = [
            f"{table_[p]['metrics'][key]['mean']:.2f}" if key in table_[p]["metrics"] else "—"
            for p in policies
        ]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def moved(new: dict[str, dict], old: dict[str, dict]) -> str:
    """Per run, the new mean paired differences minus the old (EUR/day)."""
    lines = []
    for name, results in new.items():
        if name not in old:
            continue
        profit = [
            r["evaluation"]["table"][r["algo"]]["metrics"]["daily_profit_eur"]["mean"]
            for r in (old[name], results)
        ]
        parts = [f"profit {profit[0]:.2f} → {profit[1]:.2f} ({_signed(profit[1] - profit[0])})"]
        for ref, label in REFERENCES.items():
            a = results["over_seeds"].get(f"vs_{ref}")
            b = old[name]["over_seeds"].get(f"vs_{ref}")
            if a and b:
                parts.append(
                    f"vs {label} {_signed(b['mean'])} → {_signed(a['mean'])} "
                    f"({_signed(a['mean'] - b['mean'])})"
                )
        a, b = (r["over_seeds"].get("headroom_fraction") for r in (results, old[name]))
        if a and b:
            parts.append(f"headroom {b['mean']:.3f} → {a['mean']:.3f}")
        lines.append(f"- `{name}`: " + "; ".join(parts))
    return "\n".join(lines)


def _load(dirs: list[Path]) -> dict[str, dict]:
    return {d.name: json.loads((d / "results.json").read_text()) for d in dirs}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path, help="run directories holding results.json")
    p.add_argument("--compare", type=Path, default=None, help="a root of the previous runs")
    p.add_argument("--old-suffix", default="", help="the previous runs' names end with this")
    args = p.parse_args(argv)
    new = _load(args.runs)
    print(table(new))
    for name, results in new.items():
        print()
        print(metrics(name, results))
    if args.compare:
        old = {
            name: json.loads((args.compare / (name + args.old_suffix) / "results.json").read_text())
            for name in new
            if (args.compare / (name + args.old_suffix) / "results.json").exists()
        }
        print()
        print(moved(new, old))


if __name__ == "__main__":
    main()
