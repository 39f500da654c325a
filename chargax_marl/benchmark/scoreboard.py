"""The scoreboard: every task × policy, rendered as Markdown from files.

    python -m chargax_marl.benchmark.scoreboard --scores results/scores
    python -m chargax_marl.benchmark.scoreboard --scores results/scores --time results/scores/score_time.json
    python -m chargax_marl.benchmark.scoreboard --scores results/scores \
        --time results/scores/score_time.json --readme README.md   # the README's table
    python -m chargax_marl.benchmark.scoreboard --scores results/scores \
        --gaps results/scores/learner_gaps.md   # the best learned agents against the MPC

Rows: the shipped references of every task (`chargax_marl.benchmark.references`) and one
row per name found in the score files of ``--scores`` (written by ``python -m
baselines.score``: a trained agent on a task). A cell is the score (the fraction of the
hindsight headroom captured) ± its standard error over days, and the EUR/day over
always-max. The "days × draws" row says how many held-out days a column rests on (a day
whose LP bound solve failed has no headroom and is left out); a reference with days of its
own left out (an MPC day with a failed solve) says on how many its cell rests. ``--time``
measures how long `chargax_marl.benchmark.score` takes for a jitted policy (always-max,
compile included) on each task and writes it to the given file; with an existing file, the
table shows it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from chargax_marl import policies
from chargax_marl.benchmark.references import BOUND, RULES, load_references
from chargax_marl.benchmark.scoring import compare, score
from chargax_marl.benchmark.tasks import TASKS, get_task
from chargax_marl.core import checks
from chargax_marl.single.env import Chargax
from chargax_marl.trace import params_fingerprint

DEFAULT_TASK = "Chargax-shopping-v3"
"""The task `time_score` times a host Gymnasium policy on (the current version's default)."""

REFERENCE_LABELS = {
    "random": "random",
    "always_max": "always-max",
    "battery_rule": "always-max + battery rule",
    "edf": "EDF",
    "battery_programme": "battery programme",
    "plan_programme": "plan programme",
    "grid_programme": "grid programme",
    "coupled_plan": "coupled plan",
    "mpc": "MPC (4 h look-ahead)",
    "mpc_levels1": "MPC, learned agents' action space",
    BOUND: "LP bound",
}
"""Row labels of the references, in the table's order (the bound's says which bound, from
`BOUND_LABELS`)."""

BOUND_LABELS = {
    "occupancy": "LP bound (occupancy)",
    "pooled": "LP bound (port-pooled)",
}
"""The bound's row label by the tasks' `Task.bound`."""

CURRENT_VERSION = max(task.version for task in TASKS.values())
"""The benchmark version the README's scoreboard shows; the older versions' tables are in
``docs/benchmark.md``."""

MPCS = ("mpc", "mpc_levels1")
"""The MPC references: in the task's full action space and in the learned agents'."""


def _cell(result: dict, task_days: int) -> str:
    """``score ± s.e. (EUR/day over always-max)``; where the policy itself has days without
    a profit (an MPC reference's failed solves), the number of the task's scored days
    (``task_days``) the cell rests on."""
    over = result["over_always_max_eur"]["mean"]
    days = result.get("days_scored", task_days)
    rests = "" if days == task_days else f"; {days} of {task_days} days"
    return f"{result['score']:.2f} ± {result['score_stderr']:.2f} ({over:+.1f}{rests})"


def _scored_days(task_id: str, references_dir=None) -> int:
    """The held-out days a task's scores rest on: those with an LP bound (a day whose bound
    solve failed has no headroom and is left out of every score)."""
    refs = load_references(task_id, references_dir)
    return compare(task_id, refs["policies"][BOUND]["daily_profit"], references_dir)["days_scored"]


SCORE_FIELDS = ("daily_profit",)
"""The fields a score file needs beside ``name``, ``task`` and ``score``: its cells are
computed from the profits on the current references (``seeds`` is optional: a policy without
seeds is shown by its name alone)."""


def _label(data: dict) -> str:
    """A score file's row label: its name and, where it has them, its seeds."""
    return f"{data['name']} ({data['seeds']} seeds)" if "seeds" in data else str(data["name"])


def read_scores(directory: str | Path) -> list[dict]:
    """The score files of ``directory`` (``*.json`` with ``name``, ``task`` and ``score``),
    each checked against the current code's task parameters.

    Args:
        directory: the folder of score files (``python -m baselines.score`` writes them);
            other JSON files in it are skipped.

    Returns:
        The files' contents, in the order of their sorted paths.

    Raises:
        KeyError: a score file of a task not in the registry (`get_task`).
        ValueError: a score file computed on other parameters than its task's on this code,
            or one without a field of `SCORE_FIELDS`.
    """
    out = []
    for path in sorted(Path(directory).glob("*.json")):
        data = json.loads(path.read_text())
        if not {"name", "task", "score"} <= set(data):
            continue
        missing = [field for field in SCORE_FIELDS if field not in data]
        if missing:
            raise ValueError(
                f"{path}: a score file needs the fields {list(SCORE_FIELDS)}; it lacks {missing}"
                " (write it with `python -m baselines.score` or `json.dump` of "
                "`chargax_marl.benchmark.score`'s result)"
            )
        current = params_fingerprint(get_task(data["task"]).make_params())
        if data.get("params_fingerprint") != current:
            raise ValueError(
                f"{path}: scored on parameters with fingerprint {data.get('params_fingerprint')}, "
                f"but {data['task']} has {current} on this code: re-score the run"
            )
        out.append(data)
    return out


def _reference_label(name: str, task_id: str) -> str:
    """A reference's row label; the bound's names the task's bound."""
    return BOUND_LABELS[TASKS[task_id].bound] if name == BOUND else REFERENCE_LABELS[name]


def render(
    scores_dir: str | Path | None = None,
    timings: str | Path | None = None,
    references_dir: str | Path | None = None,
    version: int = CURRENT_VERSION,
) -> str:
    """The scoreboard of one benchmark version as a Markdown table.

    Args:
        scores_dir: a directory of score files (none: the references alone).
        timings: a file written by ``--time`` (none: no timing row).
        references_dir: where the references live (default: the shipped ones).
        version: the tasks' version (`Task.version`): the current one by default.

    Returns:
        The table, one row per policy and one column per task of that version, with the
        days, draws and seeds each row rests on.

    Raises:
        ValueError: no registered task has that version.
    """
    tasks = [t for t, task in TASKS.items() if task.version == version]
    if not tasks:
        versions = sorted({task.version for task in TASKS.values()})
        raise ValueError(f"field 'version' must be one of {versions}, got {version!r}")
    rows: dict[str, dict[str, str]] = {}
    for name in REFERENCE_LABELS:
        for task_id in tasks:
            rows.setdefault(_reference_label(name, task_id), {})
    scored = {t: _scored_days(t, references_dir) for t in tasks}
    for task_id in tasks:
        refs = load_references(task_id, references_dir)
        for name in REFERENCE_LABELS:
            if name in refs["policies"]:
                rows[_reference_label(name, task_id)][task_id] = _cell(
                    compare(task_id, refs["policies"][name]["daily_profit"], references_dir),
                    scored[task_id],
                )
    for data in read_scores(scores_dir) if scores_dir else []:
        if data["task"] not in scored:
            continue  # a task of another version
        label = _label(data)
        result = compare(data["task"], data["daily_profit"], references_dir)
        rows.setdefault(label, {})[data["task"]] = _cell(result, scored[data["task"]])
    short = [t.removeprefix("Chargax-") for t in tasks]
    lines = [
        "| policy | " + " | ".join(f"`{s}`" for s in short) + " |",
        "|---|" + "---|" * len(tasks),
    ]
    for label, cells in rows.items():
        if not cells:  # a reference no stored file holds yet (added since they were built)
            continue
        lines.append(f"| {label} | " + " | ".join(cells.get(t, "–") for t in tasks) + " |")

    def days(t):  # the days a column's scores rest on, of the task's held-out days
        n = TASKS[t].num_eval_days
        return f"{scored[t]} of {n}" if scored[t] < n else f"{n}"

    lines.append(
        "| days × draws | " + " | ".join(f"{days(t)} × {TASKS[t].draws}" for t in tasks) + " |"
    )
    if timings:
        measured = json.loads(Path(timings).read_text())
        for key, label in (
            ("score_s", "`score` time, jitted policy, s"),
            ("gymnasium_s", "`score` time, Gymnasium host policy, s"),
        ):
            seconds = measured.get(key, {})
            cells = (f"{seconds[t]:.0f}" if t in seconds else "–" for t in tasks)
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _pm(entry: dict) -> str:
    return f"{entry['mean']:+.1f} ± {entry['stderr']:.1f}"


def learner_gaps(scores_dir: str | Path, references_dir: str | Path | None = None) -> str:
    """Per task, the best learned agent of the score files against the MPC and the rules.

    The best agent is the score file of the task with the highest score. Its paired
    differences (EUR/day, per day over seeds and draws, standard errors over days) are with
    the MPC in the task's full action space (``mpc``), with the MPC in the learned agents'
    action space (``mpc_levels1``) and with the strongest shipped no-learning rule (the rule
    of `chargax_marl.benchmark.references.RULES` with the highest mean profit), all as
    `chargax_marl.benchmark.scoring.compare` gives them on the current references.

    Args:
        scores_dir: a directory of score files.
        references_dir: where the references live (default: the shipped ones).

    Returns:
        A Markdown table, one row per task with a score file (``–`` where the task has no
        such reference).
    """
    best: dict[str, dict] = {}
    for data in read_scores(scores_dir):
        if data["task"] not in best or data["score"] > best[data["task"]]["score"]:
            best[data["task"]] = data
    lines = [
        "| task | best learned agent | score | vs MPC, full action space | vs MPC, learned "
        "agents' action space | strongest rule | vs strongest rule |",
        "|---|---|---|---|---|---|---|",
    ]
    for task_id in TASKS:
        if task_id not in best:
            continue
        data = best[task_id]
        refs = load_references(task_id, references_dir)["policies"]
        result = compare(task_id, data["daily_profit"], references_dir)
        rules = [name for name in RULES if name in refs]
        strongest = max(rules, key=lambda name: np.nanmean(refs[name]["daily_profit"]))
        cells = [_pm(result["vs"][name]) if name in refs else "–" for name in MPCS]
        lines.append(
            f"| `{task_id.removeprefix('Chargax-')}` | {_label(data)} "
            f"| {result['score']:.2f} ± {result['score_stderr']:.2f} | {cells[0]} | {cells[1]} "
            f"| {REFERENCE_LABELS.get(strongest, strongest)} | {_pm(result['vs'][strongest])} |"
        )
    return "\n".join(lines)


def time_score(path: str | Path) -> dict:
    """Time `chargax_marl.benchmark.score` of always-max on every task (jit compile
    included, the references already shipped), and of always-max as a host Gymnasium policy
    on the default task; write ``{"score_s": {task: seconds}, "gymnasium_s": {task: s}}``.

    Args:
        path: the JSON file to write (its folder is created if missing).

    Returns:
        What is written: ``{"score_s": {task id: seconds}, "gymnasium_s": {DEFAULT_TASK:
        seconds}, "policy": "always_max"}``, seconds rounded to 0.1 s.
    """
    out = {"score_s": {}, "gymnasium_s": {}, "policy": "always_max"}
    for task_id in TASKS:
        t0 = time.perf_counter()
        score(policies.always_max, task_id)
        out["score_s"][task_id] = round(time.perf_counter() - t0, 1)
    task = get_task(DEFAULT_TASK)
    env = Chargax(params=task.make_params())
    levels = policies.always_max(None, None, task.make_params())
    action = np.asarray(env.levels_to_action(levels, task.make_params()), np.int64)
    t0 = time.perf_counter()
    score(lambda obs: action, task, kind="gymnasium")
    out["gymnasium_s"][task.id] = round(time.perf_counter() - t0, 1)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    return out


START, END = "<!-- scoreboard:start -->", "<!-- scoreboard:end -->"
"""The markers around the current version's scoreboard in a Markdown file."""


def markers(version: int = CURRENT_VERSION) -> tuple[str, str]:
    """The markers around a version's scoreboard: `START` and `END` for the current version,
    ``<!-- scoreboard-v<N>:start -->`` and ``...:end -->`` for an older one.

    Args:
        version: the tasks' version.

    Returns:
        ``(start, end)``.
    """
    if version == CURRENT_VERSION:
        return START, END
    return f"<!-- scoreboard-v{version}:start -->", f"<!-- scoreboard-v{version}:end -->"


def embedded(text: str, version: int = CURRENT_VERSION) -> str:
    """The table between a version's markers (`markers`) in ``text``.

    Args:
        text: the contents of a Markdown file.
        version: whose block (the current version's by default: `START` ... `END`).

    Returns:
        The text between the first start marker and the next end marker, stripped.

    Raises:
        ValueError: the markers are missing, or no end marker follows the first start.
    """
    start, end = markers(version)
    if start not in text or end not in text.split(start, 1)[1]:
        raise ValueError(f"no {start} ... {end} block in the file (an end after the start)")
    return text.split(start, 1)[1].split(end, 1)[0].strip()


def embed(text: str, table: str, version: int = CURRENT_VERSION) -> str:
    """``text`` with the block between a version's markers (`markers`) replaced by ``table``.

    Args:
        text: the contents of a Markdown file with such a block.
        table: the Markdown to put between the markers.
        version: whose block (the current version's by default: `START` ... `END`).

    Returns:
        ``text`` with the first block's contents replaced by ``table`` (on its own lines).

    Raises:
        ValueError: the markers are missing, or out of order (`embedded`).
    """
    embedded(text, version)
    start, end = markers(version)
    head, rest = text.split(start, 1)
    return f"{head}{start}\n{table}\n{end}{rest.split(end, 1)[1]}"


def main(argv=None) -> str:
    """The command line: print the scoreboard of ``--version``'s tasks, and write it where the
    options say.

    ``--gaps`` writes `learner_gaps` of ``--scores`` to a file; ``--time`` names a timing
    file, measured first (`time_score`) when it does not exist; ``--readme`` writes the table
    into that file's block of the version (`markers`).

    Args:
        argv: the arguments (None: ``sys.argv[1:]``); ``--help`` lists them.

    Returns:
        The Markdown table (`render`).
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scores", default=None, help="a directory of score files")
    parser.add_argument(
        "--time",
        default=None,
        type=checks.output_option("file"),
        help="a timing file (measured if missing)",
    )
    parser.add_argument("--readme", default=None, help="write the table into this file's block")
    parser.add_argument(
        "--version",
        type=int,
        default=CURRENT_VERSION,
        help=f"the tasks' version (default {CURRENT_VERSION}, the current one)",
    )
    parser.add_argument(
        "--gaps",
        default=None,
        type=checks.output_option("file"),
        help="write the best learned agents' gaps to the MPC here",
    )
    args = parser.parse_args(argv)
    if args.gaps:
        if not args.scores:
            parser.error("--gaps needs --scores")
        gaps = learner_gaps(args.scores)
        Path(args.gaps).write_text(gaps + "\n")
        print(gaps)
    if args.time and not Path(args.time).exists():
        time_score(args.time)
    table = render(args.scores, args.time, version=args.version)
    print(table)
    if args.readme:
        path = Path(args.readme)
        path.write_text(embed(path.read_text(), table, args.version))
    return table


if __name__ == "__main__":
    main()
