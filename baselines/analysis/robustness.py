"""``python -m baselines.analysis.robustness``: learned agents played on settings they never
trained on, against always-max and the strongest rule of each setting.

A setting is a task file (`chargax_marl.benchmark.tasks.load_task`: other prices, users,
traffic or grid limits on a task's station) with its references beside it
(``python -m chargax_marl.benchmark.references --task-file FILE``); a learner's play on it is
a score file (``python -m baselines.score RUN --task-file FILE --out DIR/NAME.json``). For
every setting the table gives, per score file, the paired differences (EUR/day, per day over
seeds and draws, standard errors over days) with always-max and with the setting's strongest
shipped rule (the rule of `chargax_marl.benchmark.references.RULES` with the highest mean
profit there), as `chargax_marl.benchmark.scoring.compare` computes them, and a verdict:
``above`` (more than two standard errors over the rule), ``within`` (within two) or
``below``.

    python -m baselines.analysis.robustness --settings results/robustness \\
        --scores results/robustness/scores --out results/robustness/robustness.md
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from chargax_marl.benchmark.references import RULES, ZERO, load_references
from chargax_marl.benchmark.scoreboard import REFERENCE_LABELS
from chargax_marl.benchmark.scoring import compare
from chargax_marl.benchmark.tasks import load_task


def verdict(diff: dict) -> str:
    """``above``, ``within`` or ``below`` for a paired difference with a rule.

    Args:
        diff: ``{"mean", "stderr"}`` EUR/day, the learner less the rule.

    Returns:
        ``above`` when the mean is more than two standard errors above 0, ``below`` when it is
        more than two below, ``within`` otherwise.
    """
    if diff["mean"] > 2 * diff["stderr"]:
        return "above"
    if diff["mean"] < -2 * diff["stderr"]:
        return "below"
    return "within"


def settings(directory: str | Path) -> dict[str, tuple[Path, object]]:
    """The task files of ``directory`` by task id.

    Args:
        directory: a folder of task files (``*.toml``) with their references.

    Returns:
        ``{task id: (task file, Task)}`` in sorted file order.

    Raises:
        FileNotFoundError: a folder without task files.
    """
    files = sorted(Path(directory).glob("*.toml"))
    if not files:
        raise FileNotFoundError(f"--settings {directory}: no task files (*.toml) in it")
    out = {}
    for path in files:
        task = load_task(path)
        out[task.id] = (path, task)
    return out


def rows(settings_dir: str | Path, scores_dir: str | Path) -> list[dict]:
    """One row per score file of ``scores_dir`` whose task is a setting of ``settings_dir``.

    Args:
        settings_dir: the folder of the settings' task files and references.
        scores_dir: a folder of score files (``*.json``).

    Returns:
        Rows with ``setting``, ``description``, ``name``, ``score``, ``score_stderr``,
        ``vs_always_max`` and ``vs_strongest`` (``{"mean", "stderr"}`` EUR/day),
        ``strongest`` (the rule's name) and ``verdict`` (`verdict`), in the settings' order.

    Raises:
        ValueError: a score file of a task that is none of the settings.
    """
    known = settings(settings_dir)
    out = []
    for path in sorted(Path(scores_dir).glob("*.json")):
        data = json.loads(path.read_text())
        if not {"name", "task", "daily_profit"} <= set(data):
            continue
        if data["task"] not in known:
            raise ValueError(
                f"{path}: task {data['task']!r} is none of the settings of {settings_dir} "
                f"({sorted(known)})"
            )
        file, task = known[data["task"]]
        refs = load_references(task, file.parent)["policies"]
        result = compare(task, data["daily_profit"], file.parent)
        rules = [name for name in RULES if name in refs and name != ZERO]
        strongest = max(rules, key=lambda name: float(np.nanmean(refs[name]["daily_profit"])))
        out.append(
            {
                "setting": task.name,
                "description": task.description,
                "name": data["name"],
                "seeds": data.get("seeds"),
                "score": result["score"],
                "score_stderr": result["score_stderr"],
                "vs_always_max": result["vs"][ZERO],
                "strongest": strongest,
                "vs_strongest": result["vs"][strongest],
                "verdict": verdict(result["vs"][strongest]),
                "days": result["days_scored"],
                "draws": result["draws"],
            }
        )
    order = list(t.name for _, t in known.values())
    return sorted(out, key=lambda r: (order.index(r["setting"]), r["name"]))


def _pm(entry: dict) -> str:
    return f"{entry['mean']:+.1f} ± {entry['stderr']:.1f}"


def table(table_rows: list[dict]) -> str:
    """The rows as a Markdown table.

    Args:
        table_rows: `rows`' output.

    Returns:
        The table, one line per row.
    """
    lines = [
        "| setting | learned agent | score | vs always-max | strongest rule | vs strongest rule "
        "| verdict | days × draws |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in table_rows:
        name = f"{r['name']} ({r['seeds']} seeds)" if r["seeds"] else r["name"]
        lines.append(
            f"| {r['description']} | {name} | {r['score']:.2f} ± {r['score_stderr']:.2f} "
            f"| {_pm(r['vs_always_max'])} | {REFERENCE_LABELS.get(r['strongest'], r['strongest'])} "
            f"| {_pm(r['vs_strongest'])} | {r['verdict']} | {r['days']} × {r['draws']} |"
        )
    return "\n".join(lines)


def main(argv=None) -> str:
    """The command line.

    Args:
        argv: the arguments (None: ``sys.argv``).

    Returns:
        The table.
    """
    p = argparse.ArgumentParser(prog="python -m baselines.analysis.robustness", description=__doc__)
    p.add_argument("--settings", required=True, help="folder of the settings' task files")
    p.add_argument("--scores", required=True, help="folder of the learners' score files")
    p.add_argument("--out", default="", help="write the table here (Markdown) and beside it JSON")
    a = p.parse_args(argv)
    out = Path(a.out) if a.out else None
    if out is not None and (out.is_dir() or not out.parent.is_dir()):
        p.error(f"--out {a.out}: needs a file path in an existing folder")
    if not Path(a.scores).is_dir():
        p.error(f"--scores {a.scores}: not a directory of score files")
    try:
        found = rows(a.settings, a.scores)
    except (FileNotFoundError, ValueError) as e:
        p.error(str(e))
    text = table(found)
    print(text)
    if out is not None:
        out.write_text(text + "\n")
        out.with_suffix(".json").write_text(json.dumps(found, indent=1) + "\n")
    return text


if __name__ == "__main__":
    main()
