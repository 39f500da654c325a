"""Random-policy throughput of the single-agent env on the default station.

Prints env-steps/s for ``jax.vmap`` over 1, 16, 256 and 1024 environments, each run a
``jax.lax.scan`` over whole days under ``jax.jit``. Compile time is measured separately
(first call) and excluded from the throughput, which is the best of ``--repeats`` timed
calls. Run: ``make bench`` or ``python benchmarks/throughput.py [--envs 1 16] [--steps 2880]``.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import jax


def make_runner(env, params, num_envs: int, num_steps: int):
    """A jitted function running ``num_envs`` envs for ``num_steps`` random steps (with auto-reset)."""
    space = env.action_space(params)

    def run(key):
        keys = jax.random.split(key, num_envs)
        _, states = jax.vmap(env.reset, in_axes=(0, None))(keys, params)

        def body(carry, k):
            states = carry
            ka, ks = jax.random.split(k)
            actions = jax.vmap(space.sample)(jax.random.split(ka, num_envs))
            _, states, reward, _, _, _ = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(ks, num_envs), states, actions, params)
            return states, reward.sum()

        _, rewards = jax.lax.scan(body, states, jax.random.split(key, num_steps))
        return rewards.sum()

    return jax.jit(run)


def measure(fn, repeats: int):
    key = jax.random.PRNGKey(0)
    start = time.perf_counter()
    jax.block_until_ready(fn(key))
    compile_s = time.perf_counter() - start
    best = float("inf")
    for r in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(jax.random.PRNGKey(r + 1)))
        best = min(best, time.perf_counter() - start)
    return compile_s, best


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", type=int, nargs="+", default=[1, 16, 256, 1024])
    parser.add_argument("--steps", type=int, default=2880, help="scan length per call (default 10 days)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scenario", default="shopping")
    args = parser.parse_args(argv)

    from chargax_marl.single import make

    env, params = make(args.scenario)
    dev = jax.devices()[0]
    print(f"chargax_marl throughput | scenario={args.scenario} ports={params.station.num_ports} "
          f"batteries={params.station.num_batteries} | jax {jax.__version__} on {dev.platform} ({dev.device_kind}) | "
          f"{platform.processor() or platform.machine()} x{os.cpu_count()} cores")
    print(f"{'envs':>6} {'steps/env':>10} {'compile s':>10} {'run s':>9} {'env-steps/s':>14}")
    rows = []
    for n in args.envs:
        steps = max(args.steps // max(n // 16, 1), 288) if n > 16 else args.steps
        compile_s, run_s = measure(make_runner(env, params, n, steps), args.repeats)
        sps = n * steps / run_s
        rows.append({"envs": n, "steps": steps, "compile_s": compile_s, "run_s": run_s, "env_steps_per_s": sps})
        print(f"{n:>6} {steps:>10} {compile_s:>10.2f} {run_s:>9.3f} {sps:>14,.0f}")
    return rows


if __name__ == "__main__":
    main()
