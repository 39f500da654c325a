"""Train PPO, IPPO or MAPPO from a config file, score on held-out days, write a run directory.

    python -m baselines.train --config ippo_v3 --overwrite     # `make train`
    python -m baselines.train                                  # --config ippo
    python -m baselines.train --config ppo TOTAL_TIMESTEPS=2e6 SEEDS=2 OUT=outputs/ppo_2e6
    python -m baselines.train --config my_settings.toml SCENARIO=shopping-grid25-high
    python -m baselines.train --replot outputs/train_ippo --references results/optimal
    python -m baselines.train --resume outputs/train_ippo     # continue a killed run
    python -m baselines.train --config ppo --overwrite         # replace outputs/train_ppo

``--config`` names a file of ``baselines/configs/`` (or a path); ``KEY=value`` arguments
override its keys (`baselines.config` lists them all; an unknown key is an error). The
run keys say what to train and where to write: ``ALGO``, ``SEEDS``, ``SEED``, ``CHUNKS``,
``OUT`` (default under the git-ignored ``outputs/``), ``OPTIMAL`` and ``REFERENCES_DIR``.

Several seeds train in one compiled program (``jax.vmap``); the env batch is sharded over
every device JAX sees: the local ones, or those of every process with ``--coordinator
HOST:PORT --num-processes N --process-id i`` (``jax.distributed``; only process 0 writes).
Training runs in ``CHUNKS`` jitted pieces under a progress bar; after each piece the greedy
policies are evaluated on the validation days (training days), and the finished run's on the
held-out days (`baselines.pipeline`).

Outputs in ``OUT``: ``curve.png``, ``results.json`` (config, curves, the evaluation table
with every reference, paired differences, wall time) and ``params.msgpack`` (the final
parameters of every seed; leading axis = seed), each written atomically, and
``checkpoint.msgpack``, the whole training state after the last finished chunk. A run that was
killed continues from it with ``--resume OUT`` (the settings come from the checkpoint) and
ends with the parameters and results an uninterrupted run has (the timings aside).

``OUT`` holds one run (`baselines.runs.claim_run_dir`): a directory that already holds a
run's files is refused unless ``--resume OUT`` continues that run or ``--overwrite`` deletes
its files first, and one that another live process is writing (its ``OUT/.lock`` names the
PID) is refused; the lock of a process that was killed is taken over.
"""

from __future__ import annotations

import argparse
import json
import sys

import jax

if __name__ == "__main__":  # before the imports below: importing gymnax already runs JAX,
    from baselines.algos import distributed  # after which jax.distributed.initialize() is refused

    distributed.initialize_from_argv()
from baselines import pipeline  # noqa: E402
from baselines.algos import distributed  # noqa: E402
from baselines.config import DEFAULT_CONFIG, ConfigError, load  # noqa: E402
from baselines.runs import RunDirError  # noqa: E402


def parser() -> argparse.ArgumentParser:
    """The command line: ``--config``, ``KEY=value`` overrides, ``--replot``, ``--resume``,
    ``--overwrite`` and the multi-process flags.

    Returns:
        The argument parser (its description the module docstring).
    """
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "--config",
        default=DEFAULT_CONFIG,
        help=f"a config of baselines/configs/ or a path to a TOML file (default {DEFAULT_CONFIG})",
    )
    p.add_argument("overrides", nargs="*", metavar="KEY=value", help="config keys to override")
    p.add_argument(
        "--replot",
        nargs="+",
        default=None,
        metavar="RUN_DIR",
        help="train nothing: add the MPC stored in --references for each run's params and days "
        "to its results.json and redraw its curve.png",
    )
    p.add_argument(
        "--references",
        default="results/optimal",
        help="with --replot: the directory `make optimal` wrote (default results/optimal)",
    )
    p.add_argument(
        "--resume",
        default=None,
        metavar="RUN_DIR",
        help="continue the run whose directory this is from its checkpoint (after the last "
        "finished chunk), with the settings it was started with; no --config or KEY=value",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="OUT may hold an earlier run: delete its files (results.json, params.msgpack, "
        "curve.png, checkpoint.msgpack) and train afresh; without it such an OUT is refused",
    )
    distributed.add_arguments(p)
    return p


def main(argv=None) -> dict:
    """Run the command line ``argv`` (default ``sys.argv[1:]``).

    Args:
        argv: the arguments (None: ``sys.argv[1:]``); ``--help`` lists them.

    Returns:
        The run's results (what ``results.json`` holds), or ``{}`` for ``--replot``.

    Raises:
        baselines.config.ConfigError: an unknown config, key or value, or overrides with
            ``--resume``.
        ValueError: ``--resume`` of a directory without a readable checkpoint, or with
            ``--overwrite``.
        baselines.runs.RunDirError: ``OUT`` holds another run (without ``--resume`` or
            ``--overwrite``), or another live process is writing it.
    """
    a = parser().parse_intermixed_args(argv)
    if a.replot:
        for run_dir in a.replot:
            r = pipeline.add_stored_mpc(run_dir, a.references)
            mpc = r["evaluation"]["table"]["mpc"]["metrics"]["daily_profit_eur"]["mean"]
            print(
                f"{run_dir}: MPC {mpc:.2f} EUR/day added; {r['algo']} vs MPC {r['vs_mpc']['mean']:+.2f} ± "
                f"{r['vs_mpc']['stderr']:.2f}"
            )
        return {}
    # `python -m baselines.train` has initialised before its imports; a caller of main() must have
    # called distributed.initialize() before importing baselines.train
    distributed.initialize_from_argv(argv)
    if a.resume:
        if a.overrides:
            raise ConfigError(
                f"--resume {a.resume}: the run continues with its own settings; drop {a.overrides}"
            )
        s = pipeline.resume_settings(a.resume)
        out = pipeline.run(
            s["algo"],
            s["config"],
            seeds=s["seeds"],
            seed=s["seed"],
            out=a.resume,
            chunks=s["chunks"],
            optimal=s["optimal"],
            references_dir=s["references_dir"],
            resume=True,
            overwrite=a.overwrite,
        )
        return out.results
    config, run = load(a.config, a.overrides)
    if jax.process_index() == 0:
        print(
            f"processes: {jax.process_count()}  devices: {jax.devices()}  run: {json.dumps(run)}  "
            f"config: {json.dumps(config, default=str)}"
        )
    out = pipeline.run(
        run["ALGO"],
        config,
        seeds=run["SEEDS"],
        seed=run["SEED"],
        out=run["OUT"],
        chunks=run["CHUNKS"],
        optimal=run["OPTIMAL"],
        references_dir=run["REFERENCES_DIR"] or None,
        overwrite=a.overwrite,
    )
    return out.results


if __name__ == "__main__":
    try:
        main()
    except (ValueError, RunDirError) as e:  # the message says what to do; a traceback buries it
        sys.exit(f"baselines.train: {e}")
