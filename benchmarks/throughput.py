"""Random-policy throughput of the single-agent env on the default station.

Prints env-steps/s for ``jax.vmap`` over 1, 16, 256 and 1024 environments, each run a
``jax.lax.scan`` over whole days under ``jax.jit``. Compile time is measured separately
(first call) and excluded from the throughput, which is the best of ``--repeats`` timed
calls. The last column is the wall time of 100k env-steps at that rate (the unit of the
paper's Table 4). Run: ``make bench`` or
``python benchmarks/throughput.py [--envs 1 16] [--steps 2880] [--csv out.csv]``.

The helpers here (:func:`make_runner`, :func:`measure`, :func:`machine_info`,
:func:`load_info`) are shared by ``peers.py``, ``scaling.py`` and ``profile_step.py``.
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import subprocess
import time

import jax


def machine_info() -> dict:
    """CPU model, core count, jax version and backend (for result files and READMEs)."""
    model = platform.processor() or platform.machine()
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        for line in out.splitlines():
            if line.startswith("Model name:"):
                model = line.split(":", 1)[1].strip()
    except (OSError, subprocess.SubprocessError):
        pass
    dev = jax.devices()[0]
    return {"cpu": model, "cores": os.cpu_count(), "jax": jax.__version__, "backend": dev.platform,
            "device": dev.device_kind, "python": platform.python_version()}


def load_info() -> str:
    """The 1/5/15-minute load averages, as ``uptime`` prints them (other jobs skew timings)."""
    try:
        one, five, fifteen = os.getloadavg()
        return f"load {one:.2f} {five:.2f} {fifteen:.2f}"
    except OSError:
        return "load n/a"


def make_runner(env, params, num_envs: int, num_steps: int):
    """A jitted function running ``num_envs`` envs for ``num_steps`` random steps (with auto-reset).

    The observations are folded into the result, as a policy would read them; without that
    XLA drops the observation code and the timing flatters the env.
    """
    space = env.action_space(params)

    def run(key):
        keys = jax.random.split(key, num_envs)
        _, states = jax.vmap(env.reset, in_axes=(0, None))(keys, params)

        def body(carry, k):
            states = carry
            ka, ks = jax.random.split(k)
            actions = jax.vmap(space.sample)(jax.random.split(ka, num_envs))
            obs, states, reward, _, _, _ = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(ks, num_envs), states, actions, params)
            # use the observation (as a policy would), so XLA cannot drop its computation
            return states, reward.sum() + obs[..., 0].sum()

        _, rewards = jax.lax.scan(body, states, jax.random.split(key, num_steps))
        return rewards.sum()

    return jax.jit(run)


def measure(fn, repeats: int):
    """``(compile_s, best_run_s)``: the first call (compile + run) and the best of ``repeats`` later calls."""
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
    parser.add_argument("--csv", default=None, help="also write the rows to this CSV file")
    args = parser.parse_args(argv)

    from chargax_marl.single import make

    env, params = make(args.scenario)
    info = machine_info()
    print(f"chargax_marl throughput | scenario={args.scenario} ports={params.station.num_ports} "
          f"batteries={params.station.num_batteries} | jax {info['jax']} on {info['backend']} ({info['device']}) | "
          f"{info['cpu']} x{info['cores']} cores | {load_info()}")
    print(f"{'envs':>6} {'steps/env':>10} {'compile s':>10} {'run s':>9} {'env-steps/s':>14} {'s/100k steps':>13}")
    rows = []
    for n in args.envs:
        steps = max(args.steps // max(n // 16, 1), 288) if n > 16 else args.steps
        compile_s, run_s = measure(make_runner(env, params, n, steps), args.repeats)
        sps = n * steps / run_s
        rows.append({"envs": n, "steps": steps, "compile_s": compile_s, "run_s": run_s, "env_steps_per_s": sps,
                     "s_per_100k": 1e5 / sps})
        print(f"{n:>6} {steps:>10} {compile_s:>10.2f} {run_s:>9.3f} {sps:>14,.0f} {1e5 / sps:>13.3f}")
    print(load_info())
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return rows


if __name__ == "__main__":
    main()
