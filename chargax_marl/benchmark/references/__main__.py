"""``python -m chargax_marl.benchmark.references``: compute the references of tasks and
write them as the JSON files `chargax_marl.benchmark.references` ships and loads.

The command lives apart from the library module so that running it does not import the
module a second time.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time

from chargax_marl.benchmark.references import (
    BOUND,
    MPC_REFERENCES,
    RULES,
    ZERO,
    add_mpc,
    compute_references,
    default_references_dir,
    reference_path,
    refill_bound,
    save_references,
)
from chargax_marl.benchmark.tasks import TASKS, get_task, load_task
from chargax_marl.core import checks


def main(argv=None) -> None:
    """The command line: compute the references of tasks and write them as JSON files.

    The tasks are those of ``--task`` (registered ids) and ``--task-file`` (task files,
    `chargax_marl.benchmark.tasks.load_task`), or every registered task when neither is
    given. Per task, one of: ``--refill-bound`` (`refill_bound`), ``--mpc`` (`add_mpc`),
    ``--keep-bound`` (replay the rules, keep the stored bound and MPC references), or a full
    build (`compute_references`, ``--no-bound`` leaving the bound out, ``--rules`` playing
    only some rules); each writes the task's file in ``--out`` (default: the shipped
    references' folder, and a task file's own folder for its task) and prints its path and
    wall time.

    Args:
        argv: the arguments (None: ``sys.argv[1:]``); ``--help`` lists them.

    Raises:
        ValueError: a task file `load_task` refuses.
        SystemExit: ``--keep-bound`` on a task whose parameters' fingerprint or always-max's
            per-day profits differ from the stored file's (the bound must be rebuilt too); or,
            before any work, ``--processes`` below 1, ``--time-limit`` not a positive finite
            number, an ``--out`` or ``--bound-dir`` that cannot be a writable directory.
    """
    parser = argparse.ArgumentParser(
        prog="python -m chargax_marl.benchmark.references", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--task", action="append", help="a task id (repeatable; default: all)")
    parser.add_argument(
        "--task-file",
        action="append",
        metavar="PATH",
        help="a task file (.toml or .json) of a task that is not registered (repeatable)",
    )
    parser.add_argument(
        "--out",
        default=None,
        type=checks.output_option("dir"),
        help="directory of the files (default: the shipped references' folder; for --task-file, "
        "the task file's folder)",
    )
    parser.add_argument("--no-bound", action="store_true", help="the rules only")
    parser.add_argument(
        "--rules",
        nargs="+",
        choices=list(RULES),
        default=None,
        help=f"the rules to play (default: all; {ZERO} is played in any case, it scores 0)",
    )
    parser.add_argument(
        "--keep-bound",
        action="store_true",
        help="replay the rules, keep the stored LP bound (it depends on always-max's occupancy "
        "and the parameters, which must be unchanged)",
    )
    parser.add_argument(
        "--reuse", default=None, help="make optimal's results directory (results/optimal)"
    )
    parser.add_argument(
        "--mpc",
        action="store_true",
        help="add the MPC references to the stored files (an LP per step; nothing else moves)",
    )
    parser.add_argument(
        "--mpc-only",
        choices=list(MPC_REFERENCES),
        default=None,
        help="with --mpc: only this one, the other left as stored",
    )
    parser.add_argument(
        "--processes",
        type=int,
        default=os.cpu_count() or 1,
        help="with --mpc, or for a port-pooled bound: processes that share the days (default: "
        "one per core)",
    )
    parser.add_argument(
        "--refill-bound",
        action="store_true",
        help="solve the stored LP bound's failed days again (each such draw whole, as a full "
        "rebuild does); every other number stays as stored",
    )
    parser.add_argument(
        "--bound-dir",
        default=None,
        type=checks.output_option("dir"),
        help="for a port-pooled bound: keep its solved days in this directory, chunk by chunk, "
        "and reuse them when the command is run again (a stopped build resumes)",
    )
    parser.add_argument(
        "--time-limit",
        type=float,
        default=60.0,
        help="the LP bound's time limit per day and solver attempt, in seconds (default: 60)",
    )
    args = parser.parse_args(argv)
    if args.processes < 1:
        parser.error(f"--processes must be an integer >= 1, got {args.processes}")
    if not (args.time_limit > 0 and math.isfinite(args.time_limit)):
        parser.error(
            f"--time-limit must be a positive finite number of seconds, got {args.time_limit}"
        )
    tasks = [get_task(t) for t in args.task or ()] + [load_task(p) for p in args.task_file or ()]
    rules = RULES if args.rules is None else (ZERO, *(r for r in args.rules if r != ZERO))
    for task in tasks or list(TASKS.values()):
        out = args.out or default_references_dir(task)
        t0 = time.perf_counter()
        if args.refill_bound:
            path = refill_bound(task, out, time_limit_s=args.time_limit)
            print(f"{path}: {time.perf_counter() - t0:.0f} s")
            continue
        if args.mpc:
            only = None if args.mpc_only is None else [args.mpc_only]
            path = add_mpc(task, out, names=only, processes=args.processes)
            print(f"{path}: {time.perf_counter() - t0:.0f} s")
            continue
        if args.keep_bound:
            stored = json.loads(reference_path(task, out).read_text())
            refs = compute_references(task, rules=rules, bound=False)
            if refs["params_fingerprint"] != stored["params_fingerprint"] or (
                refs["policies"][ZERO]["daily_profit"] != stored["policies"][ZERO]["daily_profit"]
            ):
                raise SystemExit(
                    f"{task.id}: the parameters or always-max's days moved; rebuild the bound too"
                )
            for name in (BOUND, *MPC_REFERENCES):
                if name in stored["policies"]:
                    refs["policies"][name] = stored["policies"][name]
                    refs["wall_s"][name] = stored["wall_s"][name]
        else:
            pooled = task.bound == "pooled"
            refs = compute_references(
                task,
                rules=rules,
                bound=not args.no_bound,
                reuse_dir=args.reuse,
                processes=args.processes if pooled else 1,
                bound_dir=args.bound_dir if pooled else None,
                time_limit_s=args.time_limit,
            )
        path = save_references(refs, out)
        print(f"{path}: {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    try:
        main()
    except (ValueError, KeyError) as e:  # the message names what to fix; a traceback buries it
        raise SystemExit(f"python -m chargax_marl.benchmark.references: {e}") from None
