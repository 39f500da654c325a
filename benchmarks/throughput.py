"""Random-policy throughput of the single-agent env on the default station.

Prints env-steps/s for ``jax.vmap`` over 1, 16, 256 and 1024 environments, each run a
``jax.lax.scan`` over whole days under ``jax.jit``. Compile time is measured separately
(first call) and excluded from the throughput, which is the best of ``--repeats`` timed
calls. The last column is the wall time of 100k env-steps at that rate (the unit of the
paper's Table 4). Run: ``make bench`` or
``python benchmarks/throughput.py [--envs 1 16] [--steps 2880] [--csv out.csv]``.

The helpers here (`make_runner`, `measure`, `machine_info`,
`load_info`) are shared by ``peers.py``, ``scaling.py`` and ``profile_step.py``.
"""

from __future__ import annotations

import argparse
import csv
import os
import re
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

import jax


# The views import gymnax (single) and jaxmarl (MARL), whose modules build jnp arrays at import
# time and so start JAX's backend: after that, ``--devices`` (XLA_FLAGS) has no effect. These
# wrappers import chargax_marl only when called, after ``main`` has set the host device count.
def machine_info() -> dict:
    from chargax_marl.machine import machine_info as info

    return info()


def load_info() -> str:
    from chargax_marl.machine import load_info as info

    return info()


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
                jax.random.split(ks, num_envs), states, actions, params
            )
            # use the observation (as a policy would), so XLA cannot drop its computation
            return states, reward.sum() + obs[..., 0].sum()

        _, rewards = jax.lax.scan(body, states, jax.random.split(key, num_steps))
        return rewards.sum()

    return jax.jit(run)


def state_bytes(env, params) -> int:
    """Bytes of one env's state pytree (what a vmapped rollout carries per env)."""
    _, state = env.reset(jax.random.PRNGKey(0), params)
    return int(sum(x.nbytes for x in jax.tree.leaves(state)))


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


def _extract(rev: str, *paths: str) -> Path:
    """Extract ``paths`` of git revision ``rev`` into a new temporary folder; returns it."""
    blob = subprocess.run(
        ["git", "-C", str(Path(__file__).resolve().parents[1]), "archive", rev, *paths],
        check=True,
        capture_output=True,
    ).stdout
    tmp = Path(tempfile.mkdtemp(prefix="chargax_ab_"))
    with tarfile.open(fileobj=BytesIO(blob)) as tar:
        tar.extractall(tmp)
    return tmp


def _base_package(rev: str) -> str:
    """Extract ``chargax_marl`` at git revision ``rev`` as the package ``chargax_ab_base``
    (imports renamed) in a temporary folder on ``sys.path``; returns its name."""
    tmp = _extract(rev, "chargax_marl")
    (tmp / "chargax_marl").rename(tmp / "chargax_ab_base")
    for py in (tmp / "chargax_ab_base").rglob("*.py"):
        py.write_text(re.sub(r"\bchargax_marl\b", "chargax_ab_base", py.read_text()))
    sys.path.insert(0, str(tmp))
    return "chargax_ab_base"


def _base_checkout(rev: str) -> str:
    """Extract the trainers and the package at git revision ``rev`` into a temporary folder (the
    ``--base DIR`` of ``train_speed.py`` and ``optimal_speed.py``); returns its path."""
    return str(_extract(rev, "chargax_marl", "baselines"))


def _views(package: str, scenario: str, agent_id: str):
    import importlib

    single = importlib.import_module(f"{package}.single")
    marl = importlib.import_module(f"{package}.marl")
    env, params = single.make(scenario)
    multi = marl.ChargaxMARL(params=params, agent_id=agent_id)
    views = {"single": (env, params), "marl": (multi, params)}
    if hasattr(multi, "step_arrays"):  # the array path (a base revision may lack it)
        views["marl_array"] = (multi, params)
    return views


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--envs", type=int, nargs="+", default=[1, 16, 256, 1024, 4096])
    parser.add_argument(
        "--total", type=int, default=2**19, help="env-steps per timed call (default 2^19)"
    )
    parser.add_argument(
        "--min-steps", type=int, default=96, help="shortest scan per call (default 96)"
    )
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--scenario", default="shopping")
    parser.add_argument(
        "--agent-id",
        default="onehot",
        choices=["onehot", "scalar"],
        help="agent-index feature of the multi-agent view (default: its default, one-hot)",
    )
    parser.add_argument(
        "--devices",
        type=int,
        default=os.cpu_count() or 1,
        help="host devices to split the env batch over (default: one per core)",
    )
    parser.add_argument(
        "--base",
        default=None,
        help="also time this git revision, interleaved in the same run (A/B): its env here, and "
        "with --train / --optimal its trainers and MPC (those scripts' --base)",
    )
    parser.add_argument(
        "--train",
        action="store_true",
        help="also time PPO / IPPO / MAPPO training (benchmarks/train_speed.py)",
    )
    parser.add_argument(
        "--train-set",
        nargs="*",
        default=["HIDDEN=64"],
        metavar="KEY=VALUE",
        help="config overrides of the training timings (default: make train's 2 x 64 networks)",
    )
    parser.add_argument(
        "--optimal",
        action="store_true",
        help="also time the MPC per step and the LP bound per day (benchmarks/optimal_speed.py)",
    )
    parser.add_argument("--csv", default=None, help="also write the rows to this CSV file")
    args = parser.parse_args(argv)

    from envbench import set_host_devices

    flags_before = os.environ.get("XLA_FLAGS")
    set_host_devices(args.devices)  # before JAX starts its backend
    if len(jax.devices()) != args.devices:
        # the count came too late to take effect here; leave the caller's environment as it
        # was, or every process it starts afterwards would get that many host devices
        if flags_before is None:
            os.environ.pop("XLA_FLAGS", None)
        else:
            os.environ["XLA_FLAGS"] = flags_before
        raise RuntimeError(
            f"--devices {args.devices}: JAX sees {len(jax.devices())} device(s) because its backend started "
            "before the host device count was set (something imported chargax_marl's views, gymnax or jaxmarl first); run "
            "this script as its own process, or pass --devices equal to the devices JAX already has"
        )
    from envbench import compiled_rollout, steps_for, time_interleaved

    packages = {"": "chargax_marl"}
    if args.base:
        packages["base "] = _base_package(args.base)
    views = {label: _views(pkg, args.scenario, args.agent_id) for label, pkg in packages.items()}
    env, params = views[""]["single"]
    info = machine_info()
    print(
        f"chargax_marl throughput | scenario={args.scenario} ports={params.station.num_ports} "
        f"batteries={params.station.num_batteries} | MARL agent_id={args.agent_id} | jax {info['jax']} on "
        f"{info['backend']} ({info['device']}) x{len(jax.devices())} devices | {info['cpu']} x{info['cores']} cores | "
        f"{load_info()}"
    )
    print(
        "random actions, auto-reset, every observation element consumed, compile excluded, best of "
        f"{args.repeats} interleaved calls of ~{args.total:,} env-steps"
    )
    names = [f"{label}{view}" for label, vs in views.items() for view in vs]
    array = "marl_array" in views[""]
    print(
        f"{'envs':>6} {'dev':>4} "
        + " ".join(f"{n + ' steps/s':>20}" for n in names)
        + f" {'marl/single':>12}"
        + (f" {'array/single':>12}" if array else "")
        + (f" {'single new/base':>16} {'marl new/base':>14}" if args.base else "")
        + f" {'single s/100k':>14} {'compile s':>10}"
    )
    rows = []
    for n in args.envs:
        steps = steps_for(n, args.total, args.min_steps)
        fns, used = {}, 1
        for label, vs in views.items():
            for view, (e, p) in vs.items():
                fns[f"{label}{view}"], used = compiled_rollout(view, e, p, n, steps)
        compile_s, best = time_interleaved(fns, args.repeats)
        sps = {k: n * steps / v for k, v in best.items()}
        row = {
            "envs": n,
            "devices": used,
            "steps": steps,
            "single_temp_bytes_per_env": fns["single"].temp_bytes_per_env,
            **{f"{k.replace(' ', '_')}_steps_per_s": v for k, v in sps.items()},
            "marl_over_single": sps["marl"] / sps["single"],
            "compile_s_max": max(compile_s.values()),
        }
        line = (
            f"{n:>6} {used:>4} "
            + " ".join(f"{sps[k]:>20,.0f}" for k in names)
            + f" {row['marl_over_single']:>12.2f}"
        )
        if array:
            row["marl_array_over_single"] = sps["marl_array"] / sps["single"]
            line += f" {row['marl_array_over_single']:>12.2f}"
        if args.base:
            row["single_new_over_base"] = sps["single"] / sps["base single"]
            row["marl_new_over_base"] = sps["marl"] / sps["base marl"]
            line += f" {row['single_new_over_base']:>16.2f} {row['marl_new_over_base']:>14.2f}"
        row["single_s_per_100k"] = 1e5 / sps["single"]
        print(
            line + f" {row['single_s_per_100k']:>14.3f} {row['compile_s_max']:>10.2f}",
            flush=True,
        )
        rows.append(row)
    print(load_info())
    last = rows[-1]
    temp = last["single_temp_bytes_per_env"]
    print(
        f"memory per env: state {state_bytes(env, params):,} bytes (the pytree a rollout carries "
        "per env)"
        + (
            ""
            if temp is None
            else f"; the single view's {last['envs']}-env rollout program holds {temp:,.0f} "
            f"bytes of temporaries per env (envs per device: {last['envs'] // last['devices']}; "
            "XLA's memory analysis)"
        )
    )
    # The training and MPC timings run in their own processes: this one exposes --devices host
    # devices, and the trainers would shard their 16 envs over them; `make train` runs on
    # JAX's default single CPU device.
    from envbench import without_host_devices

    here = os.path.dirname(os.path.abspath(__file__))
    env = {**os.environ, "XLA_FLAGS": without_host_devices(os.environ.get("XLA_FLAGS", ""))}
    base = (
        ["--base", _base_checkout(args.base)] if args.base and (args.train or args.optimal) else []
    )
    if args.train:
        subprocess.run(
            [sys.executable, os.path.join(here, "train_speed.py"), "--set", *args.train_set, *base],
            check=True,
            env=env,
        )
    if args.optimal:
        subprocess.run(
            [sys.executable, os.path.join(here, "optimal_speed.py"), "--days", "1", *base],
            check=True,
            env=env,
        )
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return rows


if __name__ == "__main__":
    main()
