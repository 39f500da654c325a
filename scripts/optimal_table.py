"""Print the Markdown table of `make optimal`'s results for the docs.

    python scripts/optimal_table.py [results/optimal] [--compare OLD_DIR]

Reads ``<dir>/<scenario>.json`` (written by ``python -m baselines.analysis.references``) for
the four ten-level scenarios and prints one row per policy: EUR/day, the paired difference to
always-max (mean ± standard error over the held-out days) and the fraction of the headroom
captured; then the battery's worth (the bound minus the bound without the battery). With
``--compare`` it also prints, per scenario and policy, how far the mean profit moved from the
files in ``OLD_DIR`` (a checkout of the previous results).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

SCENARIOS = ("default", "grid25_high", "grid10_high", "peak")
TITLES = {
    "default": "default (`shopping`)",
    "grid25_high": "`shopping-grid25-high`",
    "grid10_high": "`shopping-grid10-high`",
    "peak": "`shopping-peak`",
}
NAMES = {
    "always_max": "always-max",
    "battery_rule": "always-max + battery rule",
    "battery_rule_naive": "always-max + battery rule blind to wear",
    "edf": "EDF",
    "llf": "LLF",
    "price_threshold": "price-threshold",
    "battery_programme": "battery programme",
    "plan_programme": "plan programme",
    "grid_programme": "grid programme",
    "mpc": "MPC, 4 h, every step",
    "lp_bound": "LP bound (always-max occupancy)",
    "lp_bound_no_battery": "LP bound without the battery",
}


def _load(directory: Path) -> dict:
    return {
        s: json.loads((directory / f"{s}.json").read_text())
        for s in SCENARIOS
        if (directory / f"{s}.json").exists()
    }


def _signed(x: float) -> str:
    return f"{'−' if x < 0 else '+'}{abs(x):.2f}"


def _cell(entry: dict) -> str:
    d = entry["vs_always_max"]
    fraction = entry["headroom"]["fraction"]
    return (
        f"{entry['mean_eur']:.1f}, {_signed(d['mean'])} ± {d['stderr']:.2f}, "
        f"{_signed(fraction) if fraction < 0 else f'{fraction:.2f}'}"
    )


def table(results: dict) -> str:
    """The Markdown table of ``results`` (scenario name -> stored result)."""
    names = [s for s in SCENARIOS if s in results]
    head = "| policy | " + " | ".join(TITLES[s] for s in names) + " |"
    lines = [head, "|---" * (len(names) + 1) + "|"]
    for key, label in NAMES.items():
        if not any(key in results[s]["policies"] for s in names):
            continue
        cells = [
            _cell(results[s]["policies"][key]) if key in results[s]["policies"] else "—"
            for s in names
        ]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    worth = [results[s].get("battery_worth") for s in names]
    if any(worth):
        cells = [f"{w['mean']:+.2f} ± {w['stderr']:.2f}" if w else "—" for w in worth]
        lines.append("| battery's worth (bound − bound without it) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def moved(new: dict, old: dict) -> str:
    """Per scenario and policy, the new mean profit minus the old (EUR/day)."""
    lines = []
    for s in SCENARIOS:
        if s not in new or s not in old:
            continue
        parts = []
        for key, label in NAMES.items():
            if key in new[s]["policies"] and key in old[s]["policies"]:
                delta = new[s]["policies"][key]["mean_eur"] - old[s]["policies"][key]["mean_eur"]
                parts.append(f"{label} {delta:+.2f}")
        lines.append(f"- {TITLES[s]}: " + "; ".join(parts))
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("directory", nargs="?", default="results/optimal")
    p.add_argument("--compare", default=None, help="a directory of the previous results")
    args = p.parse_args(argv)
    new = _load(Path(args.directory))
    print(table(new))
    if args.compare:
        print()
        print(moved(new, _load(Path(args.compare))))


if __name__ == "__main__":
    main()
