"""Score a trained run of ``baselines.train`` on a benchmark task, every seed.

    python -m baselines.score outputs/train_ippo --task Chargax-shopping-v1
    python -m baselines.score results/ippo_shopping_medium --task Chargax-shopping-v1 \\
        --name IPPO --out results/scores/ippo_Chargax-shopping-v1.json \\
        --picture docs/benchmark_day_ippo_shopping.png
    python -m baselines.score --rescore results/scores/*.json   # after references move

The run's greedy policies are played on the task's held-out days and car draws
(`chargax_marl.benchmark`) in the run's own action space (``num_levels``), and scored
against the task's shipped references. The score file is what the scoreboard reads
(``python -m chargax_marl.benchmark.scoreboard``).
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
from chargax_marl.evaluation import METRICS, check_policy_outputs, play_days, stateless
from chargax_marl.trace import params_fingerprint, station_fingerprint


class CheckpointMismatchError(ValueError):
    """A checkpoint trained on another station or scenario than the task's."""


def check_run_fits(run_params, task) -> None:
    """Refuse a run whose env differs from the task's in more than its action space.

    Args:
        run_params: the run's held-out env parameters.
        task: the benchmark task.

    Raises:
        CheckpointMismatchError: another action mode, another station, or (for a task that is
            not a shift task) any other parameter: scenario, prices, economics.
    """
    mine = task.policy_params(int(run_params.num_levels))
    if run_params.action_mode != mine.action_mode:
        raise CheckpointMismatchError(
            f"the run acts in action mode {run_params.action_mode!r}; task {task.id!r} is scored "
            f"in {mine.action_mode!r}"
        )
    if station_fingerprint(run_params) != station_fingerprint(mine):
        raise CheckpointMismatchError(
            f"the run was trained on another station than task {task.id!r}'s (station "
            f"fingerprint {station_fingerprint(run_params)}, the task's "
            f"{station_fingerprint(mine)})"
        )
    if not task.is_shift and params_fingerprint(run_params) != params_fingerprint(mine):
        raise CheckpointMismatchError(
            f"the run was trained on other parameters than task {task.id!r} (scenario, prices "
            f"or economics: params fingerprint {params_fingerprint(run_params)}, the task's "
            f"{params_fingerprint(mine)} at num_levels={int(run_params.num_levels)}); score it "
            "on the task of its scenario"
        )


def score_run(run_dir: str | Path, task_id: str, references_dir=None) -> dict:
    """Every seed of a run on a task.

    Args:
        run_dir: a ``baselines.train`` output directory (``results.json``, ``params.msgpack``).
        task_id: a benchmark task id.
        references_dir: where the references live (default: the shipped ones).

    Returns:
        `chargax_marl.benchmark.scoring.compare`'s result over the seeds, plus
        ``daily_profit`` ``(seeds, days, draws)``, ``metrics`` (means), ``per_seed_metrics``,
        the run's ``algo``, ``seeds``, ``config`` and ``wall_s``.

    Raises:
        CheckpointMismatchError: the run was trained on another station or scenario.
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
    return {
        **compare(task, daily, references_dir),
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


def picture(run_dir, task_id: str, path, name: str | None = None, day_index: int = 0):
    """Draw seed 0 of a run on a held-out day of a task beside always-max
    (`chargax_marl.benchmark.picture.day_picture`); returns the figure.

    Args:
        run_dir: a ``baselines.train`` output directory.
        task_id: a benchmark task id.
        path: the PNG to write.
        name: the policy's label (default: the run's algorithm, upper-cased).
        day_index: the position in the task's held-out days (draw 0 is drawn).

    Returns:
        The matplotlib figure.

    Raises:
        CheckpointMismatchError: the run was trained on another station or scenario
            (`check_run_fits`).
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
        references_dir: where the references live (default: the shipped ones).

    Returns:
        The file's content with `chargax_marl.benchmark.scoring.compare`'s fields made again;
        its profits, metrics and settings as stored.

    Raises:
        ValueError: the file is not a score file (it lacks a field `write_score` writes).
        CheckpointMismatchError: the file was scored on other parameters than its task's on
            this code (the run must be scored again).
    """
    stored = json.loads(Path(path).read_text())
    missing = _missing_fields(stored)
    if missing:
        raise ValueError(f"{path}: not a score file, it has no field {missing}")
    task = get_task(stored["task"])
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
    parser.add_argument("--task", default=None, help="a benchmark task id")
    parser.add_argument("--name", default=None, help="the row label (default: the algorithm)")
    parser.add_argument("--out", default=None, help="write the score file here")
    parser.add_argument(
        "--picture", default=None, help="draw seed 0's first held-out day beside always-max here"
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
        if args.run_dir or args.task:
            parser.error("--rescore takes score files only (no run directory or --task)")
        out = []
        for path in args.rescore:
            if _missing_fields(json.loads(Path(path).read_text())):
                print(f"{path}: not a score file, left as it is")  # score_time.json, say
                continue
            result = rescore(path)
            write_score(result, result["name"], path)
            print(f"{path}: score {result['score']:.3f} ± {result['score_stderr']:.3f}")
            out.append(result)
        return out
    if not (args.run_dir and args.task):
        parser.error("a run directory and --task are required (or --rescore SCORE_FILE ...)")
    if args.picture:
        picture(args.run_dir, args.task, args.picture, args.name)
    result = score_run(args.run_dir, args.task)
    print(
        f"{args.task}: score {result['score']:.3f} ± {result['score_stderr']:.3f} over "
        f"{result['seeds']} seeds, {result['over_always_max_eur']['mean']:+.2f} ± "
        f"{result['over_always_max_eur']['stderr']:.2f} EUR/day over always-max "
        f"({result['wall_s']:.1f} s)"
    )
    if args.out:
        write_score(result, args.name or result["algo"].upper(), args.out)
    return result


if __name__ == "__main__":
    main()
