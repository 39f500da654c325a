"""``python -m baselines.analysis.ablation``: learning methods side by side on a task, each
paired with a base run and with every shipped no-learning rule on the same days and cars.

Each method is a score file of ``python -m baselines.score`` (every seed of a run on the
task's held-out days and car draws: ``daily_profit`` ``(seeds, days, draws)``). A day's
profit is the mean over seeds and draws; differences are paired per day and their standard
errors are over days, as the scoreboard's (`chargax_marl.benchmark.scoring.compare`).

    python -m baselines.analysis.ablation --task Chargax-shopping-grid10-high-v1 \\
        --base "plan teacher=results/scores/ippo_Chargax-shopping-grid10-high-v1.json" \\
        --method "priority classes=outputs/scores/classes.json" \\
        --rules edf --out results/ablation/grid10
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from chargax_marl.benchmark.references import RULES, load_references
from chargax_marl.benchmark.scoring import compare
from chargax_marl.benchmark.tasks import get_task
from chargax_marl.core import checks


def _mean_se(x: np.ndarray) -> dict:
    return {"mean": float(x.mean()), "stderr": float(x.std(ddof=1) / np.sqrt(x.size))}


def read_score(path: str | Path, task_id: str) -> dict:
    """A score file of ``baselines.score`` for ``task_id``.

    Args:
        path: the score file (JSON).
        task_id: the benchmark task id the file must score.

    Returns:
        The file's JSON object (its ``daily_profit`` ``(seeds, days, draws)`` in EUR/day).

    Raises:
        ValueError: the file scores another task.
    """
    data = json.loads(Path(path).read_text())
    if data.get("task") != task_id:
        raise ValueError(f"{path}: field 'task' is {data.get('task')!r}, expected {task_id!r}")
    return data


def ablation(task_id: str, base: tuple[str, str], methods: list[tuple[str, str]]) -> dict:
    """Every method (and the base) on one task: its score, its paired difference with the
    base, with each rule of the task's references and with the strongest rule.

    Args:
        task_id: a benchmark task id.
        base: ``(name, score file)`` of the run the methods are measured against.
        methods: ``(name, score file)`` of each method.

    Returns:
        ``{"task", "days", "draws", "headroom_eur", "rules", "strongest_rule", "rows":
        [{name, file, seeds, score, score_stderr, vs_base, vs_rules, vs_strongest_rule}]}``;
        score and the differences with the rules as `chargax_marl.benchmark.scoring.compare`
        gives them; differences in EUR/day as ``{"mean", "stderr"}``, paired over days (the
        difference with the base over every held-out day).

    Raises:
        ValueError: a score file of another task, or of other days or draws
            (`chargax_marl.benchmark.scoring.compare`).
    """
    task = get_task(task_id)
    refs = load_references(task)
    rules = [name for name in RULES if name in refs["policies"]]
    strongest = max(rules, key=lambda name: np.nanmean(refs["policies"][name]["daily_profit"]))
    rows, base_day = [], None
    for name, path in [base, *methods]:
        profit = np.asarray(read_score(path, task_id)["daily_profit"], np.float64)
        scored = compare(task, profit)
        day = profit.mean(axis=(0, 2))  # (days,): over seeds and draws
        base_day = day if base_day is None else base_day
        rows.append(
            {
                "name": name,
                "file": str(path),
                "seeds": int(profit.shape[0]),
                "score": scored["score"],
                "score_stderr": scored["score_stderr"],
                "vs_base": None if day is base_day else _mean_se(day - base_day),
                "vs_rules": {rule: scored["vs"][rule] for rule in rules},
                "vs_strongest_rule": scored["vs"][strongest],
            }
        )
    return {
        "task": task_id,
        "days": [int(d) for d in task.eval_days()],
        "draws": int(task.draws),
        "headroom_eur": scored["headroom_eur"],
        "rules": rules,
        "strongest_rule": strongest,
        "rows": rows,
    }


def _pm(entry: dict | None) -> str:
    return "–" if entry is None else f"{entry['mean']:+.1f} ± {entry['stderr']:.1f}"


def to_markdown(result: dict, rules: tuple[str, ...] = ()) -> str:
    """The table of `ablation`'s result, with a column for the difference with each of
    ``rules`` (names of the task's references) besides the strongest rule's.

    Args:
        result: an `ablation` result.
        rules: rule names to give a column each; the strongest rule is left out of them (it
            has its own column).

    Returns:
        A Markdown section: a ``###`` heading of the task, a line on the days, draws and
        strongest rule, and a table with one row per method (seeds, score ± standard error,
        and the paired differences in EUR/day), ending in a newline.
    """
    strongest = result["strongest_rule"]
    rules = tuple(r for r in rules if r != strongest)
    lines = [
        f"### {result['task']}",
        "",
        f"{len(result['days'])} held-out days x {result['draws']} car draws; EUR/day, paired "
        f"per day (mean over seeds and draws), standard errors over days. Strongest rule: "
        f"`{strongest}`.",
        "",
        "| method | seeds | score | vs base | "
        + "".join(f"vs `{r}` | " for r in rules)
        + f"vs `{strongest}` |",
        "|---|---|---|---|" + "---|" * (len(rules) + 1),
    ]
    for row in result["rows"]:
        lines.append(
            f"| {row['name']} | {row['seeds']} | {row['score']:.2f} ± {row['score_stderr']:.2f} "
            f"| {_pm(row['vs_base'])} | "
            + "".join(f"{_pm(row['vs_rules'][r])} | " for r in rules)
            + f"{_pm(row['vs_strongest_rule'])} |"
        )
    return "\n".join(lines) + "\n"


def _pair(text: str) -> tuple[str, str]:
    name, sep, path = text.partition("=")
    if not sep or not name or not path:
        raise argparse.ArgumentTypeError(f"expected NAME=SCORE_FILE, got {text!r}")
    return name, path


def main(argv=None) -> dict:
    """The command line: `ablation` of ``--base`` and every ``--method`` on ``--task``, its
    table printed, and with ``--out OUT`` written to ``OUT.json`` and ``OUT.md``.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        The `ablation` result.

    Raises:
        SystemExit: a malformed argument, or ``--rules`` naming a rule that is not among the
            task's references (``argparse`` exits with status 2).
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", required=True, help="a benchmark task id")
    parser.add_argument("--base", required=True, type=_pair, help="NAME=SCORE_FILE")
    parser.add_argument("--method", action="append", default=[], type=_pair, help="NAME=FILE")
    parser.add_argument("--rules", default="", help="comma-separated rules to show besides")
    parser.add_argument(
        "--out", type=checks.output_option("prefix"), help="write OUT.json and OUT.md"
    )
    args = parser.parse_args(argv)
    result = ablation(args.task, args.base, args.method)
    rules = tuple(r for r in args.rules.split(",") if r)
    unknown = sorted(set(rules) - set(result["rules"]))
    if unknown:
        parser.error(f"--rules: {unknown} are not rules of the task's references {result['rules']}")
    text = to_markdown(result, rules)
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out + ".json").write_text(json.dumps(result, indent=1) + "\n")
        Path(args.out + ".md").write_text(text)
    return result


if __name__ == "__main__":
    main()
