"""How long `bound_days`, the LP hindsight bound of a task's days, takes end to end: the traces,
the reference's replay, the LP's build and HiGHS, per day.

Each round calls ``bound_days`` on ``--days`` days of a station three times with other keys;
the first call compiles, the other two are timed. With ``--base DIR`` a checkout of another
commit (e.g. ``git worktree add /tmp/base main``) runs the same rounds in its own process,
alternately with this one. Prints s per day of the two timed calls, HiGHS's mean s per day and
the sum of the last call's bounds (EUR), which two commits that solve the same LPs share to
the solver's tolerance.

Run: ``python benchmarks/bound_speed.py [--days 16] [--rounds 2] [--station grid25]
[--base /tmp/base]``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# One checkout's round, run by ``python -c`` in that checkout (its folder first on sys.path).
_ROUND = """
import time
import jax, numpy as np
from chargax_marl.benchmark.tasks import get_task
from chargax_marl.core import make_params
from chargax_marl.optimal import bound as bound_lib
params = get_task({task!r}).make_params() if {task!r} else make_params()
days = np.arange({days}) * 20
seconds = []
for rep in range(3):
    t0 = time.perf_counter()
    b = bound_lib.bound_days(params, days, key=jax.random.PRNGKey(rep))
    seconds.append(time.perf_counter() - t0)
highs = np.mean([x.solve_s for x in b])
total = sum(x.profit_eur for x in b)
print(f"{{seconds[1] / {days}:.3f}} {{seconds[2] / {days}:.3f}} s/day, HiGHS {{highs:.3f}}, sum {{total:.6f}}")
"""

TASKS = {"grid25": "Chargax-shopping-grid25-high-v1", "default": ""}


def one_round(root: Path, station: str, days: int) -> str:
    """``bound_days`` of the checkout at ``root`` in a process of its own; its printed line."""
    code = _ROUND.format(task=TASKS[station], days=days)
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True
    )
    return out.stdout.strip().splitlines()[-1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--days", type=int, default=16, help="days per call")
    parser.add_argument("--rounds", type=int, default=2, help="rounds per checkout")
    parser.add_argument("--station", default="grid25", choices=list(TASKS))
    parser.add_argument("--base", default=None, help="another checkout to compare with")
    args = parser.parse_args()
    if args.days < 1 or args.rounds < 1:
        parser.error(f"--days and --rounds must be >= 1, got {args.days} and {args.rounds}")
    roots = [("this", ROOT)] + ([("base", Path(args.base).resolve())] if args.base else [])
    print(
        f"bound_days on {args.days} days of the {args.station} station, s per day of calls 2 and 3"
    )
    for r in range(args.rounds):
        for name, root in roots:
            print(f"round {r + 1} {name}: {one_round(root, args.station, args.days)}", flush=True)
    print(f"load averages {os.getloadavg()}")


if __name__ == "__main__":
    main()
