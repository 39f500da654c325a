"""What the training progress bar costs: a chunk of updates with the per-update host callback
that advances the bar (`baselines.algos.runner.run_in_chunks`) against the same updates
without it, compiled once each, then timed interleaved (round-robin, best of ``repeats``).

    python benchmarks/progress_overhead.py                     # make train's config, 4 updates
    python benchmarks/progress_overhead.py --config ppo --updates 8 --repeats 5

Prints seconds per update for both and their ratio (with the callback / without).
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time
from pathlib import Path

import jax
from tqdm.auto import tqdm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # baselines/ is not installed: run from a checkout
from baselines import config as config_lib  # noqa: E402
from baselines.algos import registry, runner  # noqa: E402


def measure(config_name: str, updates: int, repeats: int, seeds: int) -> dict:
    """Seconds per update of ``updates`` updates of ``seeds`` vmapped seeds, with and without
    the progress callback.

    Args:
        config_name: a bundled config (``ippo``, ``ppo``, ``mappo``) or a TOML path.
        updates: updates per timed chunk.
        repeats: interleaved rounds; the best round of each is kept.
        seeds: vmapped seeds (``SEEDS`` of the config files).

    Returns:
        ``{"plain_s", "progress_s", "ratio", "steps_per_update"}``, seconds per update.
    """
    config, run = config_lib.load(config_name)
    algo = run["ALGO"]
    per_update = config["NUM_ENVS"] * config["NUM_STEPS"]
    config["TOTAL_TIMESTEPS"] = updates * per_update
    train = registry.make_train(algo, config)
    keys = jax.random.split(jax.random.PRNGKey(0), seeds)
    bar = tqdm(total=updates * per_update * (repeats + 1), disable=True)
    progress = runner._Progress(bar, per_update)
    fns = {
        "plain": jax.jit(jax.vmap(lambda rs: train.run_updates(rs, updates))),
        "progress": jax.jit(functools.partial(runner._chunk, train, updates, progress.update)),
    }
    rs = jax.jit(jax.vmap(train.init))(keys)
    for fn in fns.values():  # compile and warm up
        jax.block_until_ready(fn(rs))
    best = {name: float("inf") for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            jax.block_until_ready(fn(rs))
            best[name] = min(best[name], (time.perf_counter() - t) / updates)
    return {
        "plain_s": best["plain"],
        "progress_s": best["progress"],
        "ratio": best["progress"] / best["plain"],
        "steps_per_update": per_update,
    }


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", default="ippo")
    p.add_argument("--updates", type=int, default=4)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seeds", type=int, default=4)
    a = p.parse_args(argv)
    row = measure(a.config, a.updates, a.repeats, a.seeds)
    load = os.getloadavg()[0]
    print(
        f"{a.config}: {a.seeds} seeds x {row['steps_per_update']} env-steps per update; "
        f"s per update without the progress callback {row['plain_s']:.3f}, with it "
        f"{row['progress_s']:.3f}, ratio {row['ratio']:.3f} (load average {load:.1f})"
    )
    return row


if __name__ == "__main__":
    main()
