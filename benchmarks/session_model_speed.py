"""The simulator's step under the session models v2 and v3 against the paper's, interleaved.

    python benchmarks/session_model_speed.py                       # 64 envs, 7 repeats
    python benchmarks/session_model_speed.py --envs 256 --out f.json

Each arm is one jitted program that plays ``--envs`` days of 288 steps of always-max on the
default station from an empty state (the params an argument, as in training), compiled
before timing. Arms: ``paper`` (``session_model="paper"``), ``v2`` (the default),
``v2_first_free`` (v2 with the paper's first free port) and ``v3`` (``session_model="v3"``:
fixed departures and the port kind each car wants). The repeats alternate the arms and
the medians are printed with their ratios to ``paper``. Time it alone: other jobs on the
cores move the figures.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from chargax_marl import policies
from chargax_marl.core import make_params, simulator


def _program():
    def day(key, params):
        state = simulator.empty_state(jnp.int32(3), params, key)

        def body(s, k):
            s, _ = simulator.step(k, s, policies.always_max(s, k, params), params)
            return s, None

        state, _ = jax.lax.scan(body, state, jax.random.split(key, params.num_steps))
        return state.totals.profit_eur

    return jax.jit(jax.vmap(day, in_axes=(0, None)))


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--out", default=None, help="write the figures to this JSON file")
    args = parser.parse_args(argv)
    arms = {
        "paper": make_params(session_model="paper"),
        "v2": make_params(),
        "v2_first_free": make_params(port_choice="first_free"),
        "v3": make_params(session_model="v3"),
    }
    play = _program()
    keys = jax.random.split(jax.random.PRNGKey(0), args.envs)
    for params in arms.values():
        play(keys, params).block_until_ready()
    times = {name: [] for name in arms}
    for _ in range(args.repeats):
        for name, params in arms.items():
            t0 = time.perf_counter()
            play(keys, params).block_until_ready()
            times[name].append(time.perf_counter() - t0)
    median = {name: float(np.median(t)) for name, t in times.items()}
    out = {
        "envs": args.envs,
        "steps": 288,
        "repeats": args.repeats,
        "median_s": median,
        "ratio_to_paper": {name: median[name] / median["paper"] for name in arms},
        "machine": f"{platform.processor() or platform.machine()}, jax {jax.__version__}",
    }
    for name in arms:
        print(
            f"{name:14s} {1000 * median[name]:8.1f} ms  x{out['ratio_to_paper'][name]:.2f} "
            f"of paper ({args.envs} envs x 288 steps, median of {args.repeats})"
        )
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()
