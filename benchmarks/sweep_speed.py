"""A sweep in one program against the same trainings one after another.

    python benchmarks/sweep_speed.py                  # IPPO, 16 settings x 4 seeds, 3.6e4 steps
    python benchmarks/sweep_speed.py --config mappo --set TOTAL_TIMESTEPS=7.2e4 --out f.json

The grid is four learning rates x two entropy coefficients x two discounts of the bundled
config (16 settings), each over ``SEEDS`` seeds, scored on the validation days after each of
``CHUNKS`` chunks. Arm ``sweep`` trains them with one `baselines.sweep` call (one compiled
program); arm ``one_by_one`` runs one `baselines.sweep` call per setting, each with its own
training program and evaluation, as separate ``python -m baselines.train`` runs would (without
their process start-up or held-out scoring). Both arms run in this process, one after the
other, ``--settings-per-batch`` applying to the first. Prints each arm's wall seconds, their
ratio, the checked equality of every setting's final parameters between the arms, and the
sweep's ranked table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # baselines/ is not installed: run from a checkout
from baselines import sweep  # noqa: E402
from chargax_marl.machine import load_info, machine_info  # noqa: E402

GRID = ("LR=3e-4,1e-3,2e-3,3e-3", "ENT_COEF=0.003,0.01", "GAMMA=0.9,0.95")


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", default="ippo")
    p.add_argument(
        "--set",
        nargs="*",
        default=["TOTAL_TIMESTEPS=3.6e4", "CHUNKS=2", "SEEDS=4", "OPTIMAL=off"],
        metavar="KEY=value",
    )
    p.add_argument("--settings-per-batch", type=int, default=1)
    p.add_argument("--out", default=None, help="write the figures to this JSON file")
    a = p.parse_args(argv)
    info = machine_info()
    print(f"machine: {json.dumps(info)}\nload before: {load_info()}", flush=True)
    t = time.time()
    together = sweep.sweep(a.config, [*a.set, *GRID], a.settings_per_batch, write=False, quiet=True)
    sweep_s = time.time() - t
    print(f"sweep: {len(together['results'])} settings in {sweep_s:.1f} s", flush=True)
    t, alone = time.time(), []
    for entry in together["results"]:
        fixed = [sweep._override(k, v) for k, v in entry["setting"].items()]
        alone.append(sweep.sweep(a.config, [*a.set, *fixed], write=False, quiet=True))
    one_by_one_s = time.time() - t
    same = all(
        all(
            np.array_equal(np.asarray(x), np.asarray(y))
            for x, y in zip(jax.tree.leaves(p_), jax.tree.leaves(r["params"][0]))
        )
        for p_, r in zip(together["params"], alone)
    )
    ratio = one_by_one_s / sweep_s
    print(
        f"one by one: {one_by_one_s:.1f} s; one by one / sweep = {ratio:.2f}; every setting's "
        f"parameters bit for bit equal: {same}\nload after: {load_info()}\n"
    )
    print(sweep.ranked_table(together))
    out = {
        "machine": info,
        "config": a.config,
        "set": a.set,
        "grid": list(GRID),
        "settings_per_batch": a.settings_per_batch,
        "sweep_seconds": sweep_s,
        "one_by_one_seconds": one_by_one_s,
        "ratio": ratio,
        "bit_equal": same,
        "group_seconds": [g["wall_seconds"] for g in together["groups"]],
        "table": sweep.ranked_table(together),
    }
    if a.out:
        Path(a.out).write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()
