"""Score a trained run of ``baselines.train`` on a benchmark task, every seed.

    python -m baselines.score outputs/train_ippo --task Chargax-shopping-v1
    python -m baselines.score results/ippo_shopping_medium --task Chargax-shopping-v1 \\
        --name IPPO --out results/scores/ippo_Chargax-shopping-v1.json \\
        --picture docs/benchmark_day_ippo_shopping.png
    python -m baselines.score --rescore results/scores/*.json   # after references move
    python -m baselines.score outputs/train_ippo --task-file my_task.toml --references refs/

The run's greedy policies are played on the task's held-out days and car draws
(`chargax_marl.benchmark`) in the run's own action space (``num_levels``), and scored
against the task's references: the shipped ones of a registered task, those in the task
file's folder (or ``--references``) of a task read from a file. A run is scored on any task
whose observation and action spaces are its own (`check_run_fits`). The score file is what
the scoreboard reads (``python -m chargax_marl.benchmark.scoreboard``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

from baselines.config import build_env_params
from baselines.runs import load_run
from chargax_marl.benchmark import protocol
from chargax_marl.benchmark.picture import day_picture
from chargax_marl.benchmark.references import SECONDARY, load_references, package_version
from chargax_marl.benchmark.scoring import compare
from chargax_marl.benchmark.tasks import get_task
from chargax_marl.core import checks
from chargax_marl.evaluation import METRICS, check_policy_outputs, play_days, stateless
from chargax_marl.marl import ChargaxMARL
from chargax_marl.single import Chargax
from chargax_marl.trace import params_fingerprint


class CheckpointMismatchError(ValueError):
    """A checkpoint whose observation or action spaces are not the task's, or a score file
    of other parameters than its task's."""


def _describe(space) -> str:
    """A space in words: a `MultiDiscrete` with its choices, a box by its shape."""
    nvec = getattr(space, "nvec", None)
    if nvec is not None:
        return f"MultiDiscrete({[int(n) for n in nvec]})"
    return f"Box(shape={tuple(int(n) for n in space.shape)})"


def spaces(params) -> dict[str, object]:
    """The observation and action spaces a policy trained on ``params`` reads and writes, in
    both views (`chargax_marl.single.Chargax` and, for a discrete action mode,
    `chargax_marl.marl.ChargaxMARL`).

    Args:
        params: concrete env parameters.

    Returns:
        ``{what: value}``: the action mode, the levels per direction, the ports and
        batteries (the agents), the single-agent observation shape and action space, and
        the multi-agent observation size and number of actions per agent. Limits, prices,
        cars and economics are not part of them.
    """
    single = Chargax(params)
    st = params.station
    out = {
        "action mode": str(params.action_mode),
        "levels per direction": int(params.num_levels),
        "ports": int(st.num_ports),
        "batteries": int(st.num_batteries),
        "single-agent observation shape": tuple(
            int(n) for n in single.observation_space(params).shape
        ),
        "single-agent action space": _describe(single.action_space(params)),
    }
    if params.action_mode != "continuous":  # the multi-agent view has discrete actions only
        marl = ChargaxMARL(params)
        out["multi-agent observation size"] = int(marl.obs_size)
        out["multi-agent actions per agent"] = int(marl.num_actions)
    return out


def check_run_fits(run_params, task) -> None:
    """Refuse a run whose observation or action spaces differ from the task's (`spaces`, in
    the run's own number of levels). A task of other limits (a grid connection of another
    size), prices, cars or economics on a station of the same ports is scored: that is what
    a task of one's own is for.

    Args:
        run_params: the run's held-out env parameters.
        task: the benchmark task.

    Raises:
        CheckpointMismatchError: another action mode, another number of ports or batteries,
            or observations or actions of other shapes; the message lists each difference.
    """
    mine = task.policy_params(int(run_params.num_levels))
    run, scored = spaces(run_params), spaces(mine)
    differ = [
        f"{what}: {run[what]!r} (the task's {scored.get(what)!r})"
        for what in run
        if run[what] != scored.get(what)
    ]
    if differ:
        raise CheckpointMismatchError(
            f"the run acts on other observation or action spaces than task {task.id!r} "
            f"(another station, action mode or action space): {'; '.join(differ)}; a "
            "checkpoint is scored only on a task of its own spaces"
        )


def score_run(run_dir: str | Path, task_id, references_dir=None) -> dict:
    """Every seed of a run on a task.

    Args:
        run_dir: a ``baselines.train`` output directory (``results.json``, ``params.msgpack``).
        task_id: a benchmark task id, a task file's path
            (`chargax_marl.benchmark.tasks.load_task`) or a `Task`.
        references_dir: where the references live (default: the shipped ones; for a task
            read from a task file, the file's folder).

    Returns:
        `chargax_marl.benchmark.scoring.compare`'s result over the seeds, plus
        ``daily_profit`` ``(seeds, days, draws)``, ``metrics`` (means), ``per_seed_metrics``,
        the run's ``algo``, ``seeds``, ``config`` and ``wall_s``; for a task read from a
        file, ``task_file``, the file's path (`rescore` reads the task from it).

    Raises:
        CheckpointMismatchError: the run acts on other observation or action spaces than
            the task's (`check_run_fits`).
        ValueError: the policy returned non-finite or non-integer levels
            (`chargax_marl.evaluation.check_policy_outputs`).
    """
    task = get_task(task_id)
    load_references(task, references_dir)
    results, train, seed_params = load_run(run_dir)
    _, run_params, _, _ = build_env_params(train.config)
    check_run_fits(run_params, task)
    params = task.policy_params(int(run_params.num_levels))
    make_act = train.make_act(params)
    days, keys, n, r = protocol.flatten_schedule(task.eval_days(), task.day_keys())
    t0 = time.perf_counter()
    totals, counts = jax.jit(
        jax.vmap(lambda p, d, k: play_days(make_act(p), params, d, k), in_axes=(0, None, None))
    )(seed_params, days, keys)
    counts = jax.device_get(counts)  # (seeds, days x draws) each
    check_policy_outputs(counts, np.tile(days, counts.nonfinite_steps.shape[0]), "the run's policy")
    totals = protocol.unflatten_totals(jax.device_get(totals), n, r)
    wall_s = time.perf_counter() - t0
    daily = np.asarray(totals.profit_eur, np.float64)
    per_seed = {
        name: [
            float(x) for x in np.asarray(getattr(totals, METRICS[name]), np.float64).mean((1, 2))
        ]
        for name in ("daily_profit_eur", *SECONDARY)
    }
    source = {} if task.source is None else {"task_file": str(task.source)}
    return {
        **compare(task, daily, references_dir),
        **source,
        "daily_profit": daily,
        "metrics": {k: float(np.mean(v)) for k, v in per_seed.items()},
        "per_seed_metrics": per_seed,
        "algo": results["algo"],
        "seeds": int(daily.shape[0]),
        "num_levels": int(params.num_levels),
        "config": results["config"],
        "run_dir": str(run_dir),
        "params_fingerprint": params_fingerprint(task.make_params()),
        "package_version": package_version(),
        "wall_s": wall_s,
    }


def picture(
    run_dir, task_id, path, name: str | None = None, day_index: int = 0, references_dir=None
):
    """Draw seed 0 of a run on a held-out day of a task beside always-max
    (`chargax_marl.benchmark.picture.day_picture`); returns the figure.

    Args:
        run_dir: a ``baselines.train`` output directory.
        task_id: a benchmark task id, a task file's path or a `Task`.
        path: the PNG to write.
        name: the policy's label (default: the run's algorithm, upper-cased).
        day_index: the position in the task's held-out days (draw 0 is drawn).
        references_dir: where the references live (default: the shipped ones; for a task
            read from a task file, the file's folder).

    Returns:
        The matplotlib figure.

    Raises:
        CheckpointMismatchError: the run acts on other observation or action spaces than
            the task's (`check_run_fits`).
    """
    task = get_task(task_id)
    results, train, seed_params = load_run(run_dir)
    _, run_params, _, _ = build_env_params(train.config)
    check_run_fits(run_params, task)
    params = task.policy_params(int(run_params.num_levels))
    act = stateless(train.make_act(params)(jax.tree.map(lambda x: x[0], seed_params)), "picture")
    fig, _ = day_picture(
        lambda s, k, p: act(s, k),
        task,
        day_index=day_index,
        num_levels=int(run_params.num_levels),
        label=f"{name or results['algo'].upper()} (seed 0)",
        path=path,
        references_dir=references_dir,
    )
    return fig


SCORE_FIELDS = ("name", "task", "daily_profit", "params_fingerprint")
"""Fields of a score file that `rescore` reads."""


def _missing_fields(data: dict) -> list[str]:
    """The `SCORE_FIELDS` that ``data`` lacks (none: it is a score file)."""
    return [k for k in SCORE_FIELDS if k not in data]


def write_score(result: dict, name: str, path: str | Path) -> Path:
    """Write a score file for the scoreboard: ``name`` is its row label.

    Args:
        result: `score_run`'s (or `rescore`'s) result.
        name: the row label.
        path: the JSON file to write (its folder is created if missing).

    Returns:
        ``path``. The file holds ``result`` with ``daily_profit`` as nested lists, ``name``,
        and of the config only ``TOTAL_TIMESTEPS``, ``SCENARIO`` and ``TRAFFIC``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    out = {k: v for k, v in result.items() if k not in ("daily_profit", "config")}
    out["name"] = name
    out["daily_profit"] = np.asarray(result["daily_profit"]).tolist()
    out["config"] = {k: result["config"][k] for k in ("TOTAL_TIMESTEPS", "SCENARIO", "TRAFFIC")}
    path.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    return path


def rescore(path: str | Path, references_dir=None) -> dict:
    """A score file's comparison made again against the current references, from the daily
    profits it stores (nothing is played again): for references recomputed after the run was
    scored.

    Args:
        path: a score file written by `write_score`.
        references_dir: where the references live (default: the shipped ones; for a task
            read from a task file, the file's folder).

    Returns:
        The file's content with `chargax_marl.benchmark.scoring.compare`'s fields made again;
        its profits, metrics and settings as stored. A file of a task read from a task file
        reads the task from that file again (its ``task_file``).

    Raises:
        ValueError: the file is not a score file (it lacks a field `write_score` writes).
        CheckpointMismatchError: the file was scored on other parameters than its task's on
            this code (the run must be scored again).
    """
    stored = json.loads(Path(path).read_text())
    missing = _missing_fields(stored)
    if missing:
        raise ValueError(f"{path}: not a score file, it has no field {missing}")
    task = get_task(stored.get("task_file") or stored["task"])
    current = params_fingerprint(task.make_params())
    if stored.get("params_fingerprint") != current:
        raise CheckpointMismatchError(
            f"{path}: scored on parameters with fingerprint {stored.get('params_fingerprint')}, "
            f"but {task.id} has {current} on this code: score the run again"
        )
    daily = np.asarray(stored["daily_profit"], np.float64)
    return {**stored, **compare(task, daily, references_dir), "daily_profit": daily}


def main(argv=None) -> dict | list:
    """The command line: score a run on a task (optionally drawing a picture and writing the
    score file), or with ``--rescore`` compare score files again and write them back.

    Args:
        argv: the arguments (None: ``sys.argv[1:]``); ``--help`` lists them.

    Returns:
        `score_run`'s result, or with ``--rescore`` the list of `rescore`'s results (files
        that are not score files are skipped).
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", nargs="?")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--task", default=None, help="a benchmark task id")
    which.add_argument(
        "--task-file",
        default=None,
        metavar="PATH",
        help="a task file (.toml or .json) of a task of one's own, instead of --task",
    )
    parser.add_argument(
        "--references",
        default=None,
        metavar="DIR",
        help="the folder of the task's references (default: the shipped ones; for "
        "--task-file, the task file's folder)",
    )
    parser.add_argument("--name", default=None, help="the row label (default: the algorithm)")
    parser.add_argument(
        "--out", default=None, type=checks.output_option("file"), help="write the score file here"
    )
    parser.add_argument(
        "--picture",
        default=None,
        type=checks.output_option("file"),
        help="draw seed 0's first held-out day beside always-max here",
    )
    parser.add_argument(
        "--rescore",
        nargs="+",
        default=None,
        metavar="SCORE_FILE",
        help="compare these score files again against the current references and write them "
        "back (instead of scoring a run)",
    )
    args = parser.parse_args(argv)
    if args.rescore:
        if args.run_dir or args.task or args.task_file:
            parser.error(
                "--rescore takes score files only (no run directory, --task or --task-file)"
            )
        out = []
        missing = [path for path in args.rescore if not Path(path).is_file()]
        if missing:
            parser.error(f"--rescore: no such score files {missing}")
        for path in args.rescore:
            if _missing_fields(json.loads(Path(path).read_text())):
                print(f"{path}: not a score file, left as it is")  # score_time.json, say
                continue
            result = rescore(path, args.references)
            write_score(result, result["name"], path)
            print(f"{path}: score {result['score']:.3f} ± {result['score_stderr']:.3f}")
            out.append(result)
        return out
    task = args.task or args.task_file
    if not (args.run_dir and task):
        parser.error(
            "a run directory and --task or --task-file are required (or --rescore SCORE_FILE ...)"
        )
    if not (Path(args.run_dir) / "results.json").is_file():
        parser.error(
            f"run directory {args.run_dir!r}: no results.json in it (a folder written by "
            "`python -m baselines.train`)"
        )
    if args.task_file and not Path(args.task_file).is_file():
        parser.error(f"--task-file {args.task_file!r}: no such file (a .toml or .json task file)")
    if args.references and not Path(args.references).is_dir():
        parser.error(f"--references {args.references!r}: not a directory of reference files")
    try:
        task = get_task(Path(task) if args.task_file else task)
    except (KeyError, ValueError) as e:
        parser.error(f"--task{'-file' if args.task_file else ''} {task!r}: {e.args[0]}")
    if args.picture:
        picture(args.run_dir, task, args.picture, args.name, references_dir=args.references)
    result = score_run(args.run_dir, task, args.references)
    print(
        f"{task.id}: score {result['score']:.3f} ± {result['score_stderr']:.3f} over "
        f"{result['seeds']} seeds, {result['over_always_max_eur']['mean']:+.2f} ± "
        f"{result['over_always_max_eur']['stderr']:.2f} EUR/day over always-max "
        f"({result['wall_s']:.1f} s)"
    )
    if args.out:
        write_score(result, args.name or result["algo"].upper(), args.out)
    return result


if __name__ == "__main__":
    main()
