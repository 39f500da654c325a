"""``python -m baselines.analysis.coupled_plan``: the coupled plan rule against the plan programme
and EDF, paired on a task's held-out days and car draws.

The rule is ``coupled_plan`` (`chargax_marl.teachers.rules.coupled_plan_rule`): the parked
cars planned together under the node limits and the peak charge. It is played on the first
``--days`` held-out days and ``--draws`` car draws of each task, with the task's keys, so its
profit on a day and draw is paired with the shipped references' on the same cars
(`chargax_marl.benchmark.references`); the differences are averaged over the draws of a day,
and the standard errors are over days.

    python -m baselines.analysis.coupled_plan --days 20 --draws 2 --out results/coupled_plan.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from chargax_marl.benchmark import protocol
from chargax_marl.benchmark.references import load_references
from chargax_marl.benchmark.tasks import get_task
from chargax_marl.core import checks
from chargax_marl.policies import get_policy

TASKS = ("Chargax-shopping-grid10-high-v1", "Chargax-shopping-peak-v1", "Chargax-shopping-v1")
"""The tasks compared by default."""

OPPONENTS = ("plan_programme", "edf", "always_max")
"""The stored references the rule is paired with."""


def _mean_se(x: np.ndarray) -> dict:
    return {"mean": float(x.mean()), "stderr": float(x.std(ddof=1) / np.sqrt(x.size))}


def compare_task(task_id: str, days: int, draws: int, rule: str = "coupled_plan") -> dict:
    """The rule on a task's first ``days`` held-out days and ``draws`` draws, paired with the
    stored references.

    Args:
        task_id: a benchmark task id.
        days: held-out days (the first ones of ``Task.eval_days()``).
        draws: car draws per day (the first ones of the task's).
        rule: a `chargax_marl.policies.get_policy` name.

    Returns:
        ``{"eur_per_day", "vs": {reference: {"mean", "stderr"}}, "score_on_subset", ...}``
        (EUR/day; ``score_on_subset`` the normalised score on those days and draws only,
        for the rule and each reference).

    Raises:
        ValueError: ``days`` or ``draws`` beyond the task's.
    """
    task = get_task(task_id)
    if not 1 <= days <= task.num_eval_days or not 1 <= draws <= task.draws:
        raise ValueError(
            f"task {task.id!r}: days must lie in [1, {task.num_eval_days}] and draws in "
            f"[1, {task.draws}], got days={days!r}, draws={draws!r}"
        )
    params = task.make_params()
    t0 = time.perf_counter()
    totals = protocol.play(
        get_policy(rule, params), params, task.eval_days()[:days], task.day_keys()[:days, :draws]
    )
    wall_s = time.perf_counter() - t0
    mine = np.asarray(totals.profit_eur, np.float64)
    refs = load_references(task)
    out = {
        "task": task.id,
        "days": days,
        "draws": draws,
        "eur_per_day": float(mine.mean()),
        "missing_kwh": float(np.asarray(totals.missing_kwh, np.float64).mean()),
        "peak_grid_kw": float(np.asarray(totals.peak_grid_kw, np.float64).mean()),
        "vs": {},
        "reference_eur_per_day": {},
        "wall_s": round(wall_s, 1),
    }
    for name in OPPONENTS:
        other = refs["policies"][name]["daily_profit"][:days, :draws]
        out["vs"][name] = _mean_se((mine - other).mean(axis=1))
        out["reference_eur_per_day"][name] = float(other.mean())
    # the normalised score on the subset: (p - always-max) / (bound - always-max), day means
    zero = refs["policies"]["always_max"]["daily_profit"][:days, :draws].mean(axis=1)
    bound = refs["policies"]["lp_bound"]["daily_profit"][:days, :draws].mean(axis=1)
    keep = np.isfinite(bound)
    headroom = float((bound - zero)[keep].mean())
    scores = {
        name: float(((profit.mean(axis=1) - zero)[keep]).mean() / headroom)
        for name, profit in (
            (rule, mine),
            *((n, refs["policies"][n]["daily_profit"][:days, :draws]) for n in OPPONENTS[:2]),
        )
    }
    out["score_on_subset"] = scores
    return out


def main(argv=None) -> list[dict]:
    """The command line: `compare_task` on every ``--task`` (default `TASKS`), one line
    printed per task and, with ``--out``, the list written as JSON.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        One `compare_task` result per task (``--draws`` capped at each task's draws).
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", action="append", help="a task id (repeatable)")
    parser.add_argument("--days", type=int, default=20, help="held-out days, the first ones")
    parser.add_argument(
        "--draws",
        type=int,
        default=2,
        help="car draws per day, the first ones (at most the task's)",
    )
    parser.add_argument(
        "--out",
        default=None,
        type=checks.output_option("file"),
        help="write the results here (JSON)",
    )
    args = parser.parse_args(argv)
    results = []
    for task_id in args.task or TASKS:
        r = compare_task(task_id, args.days, min(args.draws, get_task(task_id).draws))
        vs = "  ".join(f"vs {n} {v['mean']:+.2f} ± {v['stderr']:.2f}" for n, v in r["vs"].items())
        print(f"{r['task']}: {r['eur_per_day']:.2f} EUR/day  {vs}  ({r['wall_s']} s)", flush=True)
        results.append(r)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
    return results


if __name__ == "__main__":
    main()
