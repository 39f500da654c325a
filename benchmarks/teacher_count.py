"""The car-plan teacher's rank count: `chargax_marl.teachers.car_plan.prefix_count` (a blocked
product with triangular ones) against ``jnp.cumsum``, on the default device.

Times the plan potential (`car_values`) and the plan advice (`plan_advice`), jitted and
vmapped over ``--envs`` states of the default station (always-max for 120 steps from reset),
once with each count, best of 3 rounds of ``--reps`` calls, and checks that both give the same
numbers. One JSON line per batch size.

Run: ``python benchmarks/teacher_count.py [--envs 24 1024 16384] [--out FILE]``.
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from chargax_marl.core import make_params, simulator
from chargax_marl.policies import POLICIES
from chargax_marl.teachers import car_plan


def states(params, n: int, steps: int = 120):
    """``n`` states of always-max played ``steps`` steps from reset (ports in use)."""
    rule = POLICIES["always_max"]

    def one(key):
        def body(s, k):
            k1, k2 = jax.random.split(k)
            return simulator.step(k2, s, rule(s, k1, params), params)[0], None

        s = simulator.reset(key, params)
        return jax.lax.scan(body, s, jax.random.split(key, steps))[0]

    return jax.jit(jax.vmap(one))(jax.random.split(jax.random.PRNGKey(0), n))


def cumsum_count(mask):
    """The count as ``jnp.cumsum`` (float32)."""
    return jnp.cumsum(jnp.asarray(mask, jnp.float32), axis=-1)


def best_seconds(fn, arg, reps: int):
    """The output of ``fn(arg)`` and the best of 3 rounds' mean seconds per call."""
    out = jax.block_until_ready(fn(arg))
    best = float("inf")
    for _ in range(3):
        t = time.perf_counter()
        for _ in range(reps):
            out = fn(arg)
        jax.block_until_ready(out)
        best = min(best, (time.perf_counter() - t) / reps)
    return out, best


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, nargs="+", default=[24, 1024, 16384])
    parser.add_argument("--reps", type=int, default=20)
    parser.add_argument("--out", default=None, help="also append the JSON lines to this file")
    args = parser.parse_args(argv)
    params = make_params()
    blocked = car_plan.prefix_count
    device = str(jax.devices()[0].device_kind)
    rows = []
    for n in args.envs:
        batch = states(params, n)
        timed = {}
        for label, count in (("blocked", blocked), ("cumsum", cumsum_count)):
            car_plan.prefix_count = count  # the functions below look it up when traced
            try:
                values = car_plan.car_values(params)
                advice = car_plan.plan_advice(params)
                potential = jax.jit(
                    jax.vmap(
                        lambda s, values=values: values(
                            s, s.timestep, s.time_remaining_min, s.energy_remaining_kwh
                        )
                    )
                )
                timed[label] = (
                    *best_seconds(potential, batch, args.reps),
                    *best_seconds(jax.jit(jax.vmap(advice)), batch, args.reps),
                )
            finally:
                car_plan.prefix_count = blocked
        (v_b, tv_b, a_b, ta_b), (v_c, tv_c, a_c, ta_c) = timed["blocked"], timed["cumsum"]
        row = {
            "device": device,
            "jax": jax.__version__,
            "envs": n,
            "potential_ms_blocked": tv_b * 1e3,
            "potential_ms_cumsum": tv_c * 1e3,
            "advice_ms_blocked": ta_b * 1e3,
            "advice_ms_cumsum": ta_c * 1e3,
            "identical": bool(
                np.array_equal(np.asarray(v_b), np.asarray(v_c))
                and np.array_equal(np.asarray(a_b), np.asarray(a_c))
            ),
        }
        print(json.dumps(row), flush=True)
        rows.append(row)
    if args.out:
        with open(args.out, "a") as f:
            f.writelines(json.dumps(r) + "\n" for r in rows)
    return rows


if __name__ == "__main__":
    main()
