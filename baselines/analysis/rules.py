"""Rule-based policies on the held-out days: daily profit and paired differences.

``python -m baselines.analysis.rules`` evaluates always-max, always-max + battery price rule,
price-threshold, EDF, LLF and (on a station with a battery) the two rules of the trainers'
teachers (`TEACHER_RULES`) on the 100 held-out days of a scenario
(``split_days(365, 100, seed=0)``) with the evaluation key 0, so every policy meets the same
cars, and prints each one's mean daily profit and its paired difference (mean ± standard
error over days) to always-max and to the battery rule. ``--out`` writes the JSON.
"""

from __future__ import annotations

import argparse

from baselines.config import build_env_params, resolve
from baselines.eval.rules import (
    BATTERY_RULES,
    POLICIES,
    add_paired_differences,
    evaluate_rules,
    format_rules,
)
from baselines.runs import write_json
from chargax_marl.core import checks
from chargax_marl.teachers.rules import has_battery


def main(argv=None) -> dict:
    """The command line: every rule of `baselines.eval.rules.POLICIES` (and, on a station with
    a battery, `baselines.eval.rules.BATTERY_RULES`) on the held-out days of ``--scenario``
    at ``--traffic``, the table printed and, with ``--out``, written as JSON (the metrics and
    paired differences, without the per-day profits).

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        ``{policy: entry}`` of `baselines.eval.rules.evaluate_rules`, each entry with
        ``vs_always_max`` and ``vs_battery_rule``.
    """
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--scenario", default="shopping")
    p.add_argument("--traffic", default="medium")
    p.add_argument(
        "--out", default=None, type=checks.output_option("file"), help="write the results JSON here"
    )
    args = p.parse_args(argv)
    _, full, _, days = build_env_params(
        resolve({"SCENARIO": args.scenario, "TRAFFIC": args.traffic})
    )
    names = POLICIES + BATTERY_RULES * has_battery(full)
    results = add_paired_differences(evaluate_rules(full, days, names))
    print(
        f"{args.scenario} / {args.traffic}: {len(days)} held-out days (split_days(seed=0)), key 0, same cars for all"
    )
    print(format_rules(results))
    if args.out:
        write_json(
            {
                "scenario": args.scenario,
                "traffic": args.traffic,
                "days": [int(d) for d in days],
                "results": {
                    k: {kk: vv for kk, vv in v.items() if kk not in ("daily_profit", "days")}
                    for k, v in results.items()
                },
            },
            args.out,
        )
    return results


if __name__ == "__main__":
    main()
