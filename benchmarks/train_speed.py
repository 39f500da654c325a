"""Training speed of the baselines: PPO, IPPO and MAPPO env-steps per second.

Each algorithm's ``make_train`` is built with the paper defaults (`baselines.config.SCHEMA`)
except ``NUM_ENVS`` and ``TOTAL_TIMESTEPS``; its ``jax.jit(train)`` is compiled once (compile
seconds are reported apart), then the compiled programs are timed *interleaved* (round-robin
over the algorithms, ``repeats`` rounds, best of them) so that a load change on a shared
machine hits every algorithm alike. The 1-minute load average is printed beside the figures.

    python benchmarks/train_speed.py                         # ppo ippo mappo, 16 envs, 100k steps
    python benchmarks/train_speed.py --envs 16 1024 --repeats 3
    python benchmarks/train_speed.py --algos ppo ippo --set ippo.HIDDEN=64   # an option for IPPO only
    python benchmarks/train_speed.py --config ippo --algos ippo --base /tmp/base   # A/B

``--base DIR`` also times the trainers of another checkout (``git worktree add /tmp/base REV``),
interleaved in the same rounds as rows ``base:<algo>``: its ``baselines/algos/ppo.py`` and
``ippo.py`` (MAPPO is its IPPO with the centralised critic) run on this checkout's library and
other modules, so the A/B isolates a change of the trainers themselves.

Importable: `measure_training` returns the rows, `format_rows` the table.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import time
from pathlib import Path

import jax

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # baselines/ is not installed: run from a checkout
from baselines.algos import registry  # noqa: E402
from baselines.config import SCHEMA, settings  # noqa: E402

STEPS_100K = 100_000


def _steps_for(num_envs: int, timesteps: int, num_steps: int) -> int:
    """``timesteps`` rounded up to whole updates (``NUM_ENVS * NUM_STEPS`` env-steps each)."""
    per_update = num_envs * num_steps
    return max(1, -(-int(timesteps) // per_update)) * per_update


BASE_MAKERS: dict = {}
"""``base:<algo>`` -> the base checkout's ``make_train`` (filled by `load_base`)."""


def load_base(root) -> list[str]:
    """Register the trainers of the checkout at ``root`` as ``base:ppo``, ``base:ippo`` and
    ``base:mappo`` (its ``ppo.py`` and ``ippo.py`` under private module names, importing this
    checkout's other modules); returns those names."""
    modules = {}
    for name in ("ppo", "ippo"):
        path = Path(root) / "baselines" / "algos" / f"{name}.py"
        spec = importlib.util.spec_from_file_location(f"_base_{name}", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        modules[name] = module
    BASE_MAKERS["base:ppo"] = modules["ppo"].make_train
    BASE_MAKERS["base:ippo"] = modules["ippo"].make_train
    BASE_MAKERS["base:mappo"] = lambda config, env_params=None: modules["ippo"].make_train(
        config, env_params, centralised_critic=True
    )
    return list(BASE_MAKERS)


def build(algo: str, num_envs: int, timesteps: int, overrides: dict | None = None):
    """``(jitted train, config)`` of ``baselines.<algo>`` (or of a ``base:<algo>`` of
    `load_base`) with the paper defaults plus the overrides."""
    config = dict(overrides or {})
    num_steps = int(config.get("NUM_STEPS", SCHEMA["NUM_STEPS"].default))
    config["NUM_ENVS"] = int(num_envs)
    config["TOTAL_TIMESTEPS"] = _steps_for(num_envs, timesteps, num_steps)
    if algo in BASE_MAKERS:
        train = BASE_MAKERS[algo](config)
    else:
        train = registry.make_train(algo, config)
    return jax.jit(train), train.config


def measure_training(
    algos=("ppo", "ippo", "mappo"),
    num_envs: int = 16,
    timesteps: int = STEPS_100K,
    repeats: int = 3,
    overrides: dict | None = None,
    verbose: bool = True,
) -> list[dict]:
    """Compile each algorithm once, then time ``repeats`` interleaved rounds; one row per algorithm.

    Row keys: ``algo``, ``envs``, ``steps`` (env-steps per run, whole updates), ``compile_s``,
    ``run_s`` (best round), ``runs_s`` (every round), ``s_per_100k``, ``steps_per_s``,
    ``ratio_vs_ppo`` (env-steps/s over PPO's, when PPO is measured), ``load`` (1-min load
    average before the first and after the last round). ``overrides`` are config keys for
    every algorithm; a key ``"<algo>.<KEY>"`` applies to that algorithm only.
    """

    key = jax.random.PRNGKey(0)
    compiled, rows = {}, {}
    for algo in algos:
        mine = {k: v for k, v in (overrides or {}).items() if "." not in k}
        plain = algo.removeprefix("base:")
        mine.update(
            {
                k.split(".", 1)[1]: v
                for k, v in (overrides or {}).items()
                if k.startswith(plain + ".")
            }
        )
        train, config = build(algo, num_envs, timesteps, mine)
        t0 = time.perf_counter()
        fn = train.lower(key).compile()
        compile_s = time.perf_counter() - t0
        compiled[algo] = fn
        rows[algo] = {
            "algo": algo,
            "envs": int(num_envs),
            "steps": int(config["TOTAL_TIMESTEPS"]),
            "compile_s": compile_s,
            "runs_s": [],
            "overrides": mine,
        }
        if verbose:
            print(f"  compiled {algo:<6} {num_envs:>5} envs in {compile_s:6.1f} s", flush=True)
    for algo in algos:  # one untimed warm-up run each (allocations, thread pools)
        jax.block_until_ready(compiled[algo](key))
    load_before = os.getloadavg()[0]
    for r in range(repeats):
        for algo in algos:
            t0 = time.perf_counter()
            jax.block_until_ready(compiled[algo](jax.random.PRNGKey(r + 1)))
            rows[algo]["runs_s"].append(time.perf_counter() - t0)
    load_after = os.getloadavg()[0]
    out = []
    for algo in algos:
        row = rows[algo]
        row["run_s"] = min(row["runs_s"])
        row["s_per_100k"] = row["run_s"] / row["steps"] * STEPS_100K
        row["steps_per_s"] = row["steps"] / row["run_s"]
        row["load"] = (load_before, load_after)
        out.append(row)
    return add_ratios(out)


def add_ratios(rows: list[dict]) -> list[dict]:
    """``rows`` with ``ratio_vs_ppo`` (env-steps/s over PPO's; a ``base:`` row over the base's
    PPO) and, for a row whose ``base:`` twin was timed, ``speedup_vs_base`` (the twin's
    seconds over this row's)."""
    by_algo = {r["algo"]: r for r in rows}
    for row in rows:
        ppo = "base:ppo" if row["algo"].startswith("base:") else "ppo"
        if ppo in by_algo:
            row["ratio_vs_ppo"] = row["steps_per_s"] / by_algo[ppo]["steps_per_s"]
        if "base:" + row["algo"] in by_algo:
            row["speedup_vs_base"] = by_algo["base:" + row["algo"]]["run_s"] / row["run_s"]
    return rows


def mlp_macs(sizes) -> int:
    """Multiply-adds of one forward pass of a dense MLP with these layer widths."""
    return sum(a * b for a, b in zip(sizes[:-1], sizes[1:]))


def network_macs(algo: str, overrides: dict | None = None) -> dict:
    """Analytic multiply-adds of the networks per env-step: ``rollout`` (actor + critic forward
    for every actor row of a step) and ``update`` (``UPDATE_EPOCHS`` x forward + backward,
    counted as 3 forward passes, of every row); ``rows`` the network rows per env-step."""
    overrides = dict(overrides or {})
    envs = int(overrides.get("NUM_MINIBATCHES", SCHEMA["NUM_MINIBATCHES"].default))  # divisible
    train, config = build(algo, envs, 10**9, overrides)
    pol, h, layers = train.policy, int(config["HIDDEN"]), int(config["NUM_LAYERS"])
    epochs = int(config["UPDATE_EPOCHS"])
    if algo == "ppo":
        actor = mlp_macs([pol.obs_dim] + [h] * layers + [pol.num_leaves * pol.k])
        critic = mlp_macs([pol.obs_dim] + [h] * layers + [1])
        rows, rollout = 1, actor + critic
        update = epochs * 3 * rollout
    else:
        n = train.env.num_agents
        actor = mlp_macs([pol.obs_dim] + [h] * layers + [pol.k])
        critic = mlp_macs([pol.critic_dim] + [h] * layers + [1])
        shared = (
            algo == "mappo"
        )  # one critic row per env (baselines.algos.ippo.DEDUP_CENTRAL_CRITIC)
        rows = n
        rollout = n * actor + (1 if shared else n) * critic
        # MAPPO's update evaluates the critic on the whole rollout once per minibatch
        mb = int(config["NUM_MINIBATCHES"])
        update = epochs * 3 * (n * actor + ((mb if mb < n else n) if shared else n) * critic)
    return {
        "algo": algo,
        "rows": rows,
        "rollout_macs": rollout,
        "update_macs": update,
        "total_macs": rollout + update,
    }


def profile_phases(
    algo: str, num_envs: int = 16, updates: int = 2, repeats: int = 2, overrides: dict | None = None
) -> dict:
    """Seconds per update split into rollout (+ GAE) and one update epoch, from timing the
    program with ``UPDATE_EPOCHS`` 1 and 4: ``epoch = (t4 - t1) / 3``, ``rollout = t1 - epoch``."""

    num_steps = int((overrides or {}).get("NUM_STEPS", SCHEMA["NUM_STEPS"].default))
    steps = updates * num_envs * num_steps
    t = {}
    for ep in (1, 4):
        train, _ = build(algo, num_envs, steps, {**(overrides or {}), "UPDATE_EPOCHS": ep})
        fn = train.lower(jax.random.PRNGKey(0)).compile()
        jax.block_until_ready(fn(jax.random.PRNGKey(0)))
        best = float("inf")
        for r in range(repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(fn(jax.random.PRNGKey(r + 1)))
            best = min(best, time.perf_counter() - t0)
        t[ep] = best / updates
    epoch = (t[4] - t[1]) / 3
    return {
        "algo": algo,
        "envs": num_envs,
        "update_s": t[4],
        "rollout_s": t[1] - epoch,
        "epoch_s": epoch,
        "load": os.getloadavg()[0],
    }


def format_rows(rows: list[dict]) -> str:
    lines = [
        f"{'algo':<10} {'envs':>5} {'steps':>9} {'compile s':>9} {'s/100k':>8} {'steps/s':>10} "
        f"{'vs PPO':>7} {'vs base':>7}  load 1-min (before, after)  overrides"
    ]
    for r in rows:
        ratio = f"{r['ratio_vs_ppo']:.2f}" if "ratio_vs_ppo" in r else "-"
        speedup = f"{r['speedup_vs_base']:.2f}" if "speedup_vs_base" in r else "-"
        lines.append(
            f"{r['algo']:<10} {r['envs']:>5} {r['steps']:>9,} {r['compile_s']:>9.1f} {r['s_per_100k']:>8.2f} "
            f"{r['steps_per_s']:>10,.0f} {ratio:>7} {speedup:>7}  {r['load'][0]:.2f}, {r['load'][1]:.2f}  {r.get('overrides') or ''}"
        )
    return "\n".join(lines)


def _parse_set(items) -> dict:
    out = {}
    for item in items or []:
        k, _, v = item.partition("=")
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--algos", nargs="+", default=["ppo", "ippo", "mappo"])
    p.add_argument("--envs", nargs="+", type=int, default=[16])
    p.add_argument(
        "--timesteps",
        type=int,
        default=STEPS_100K,
        help="env-steps per run (rounded up to whole updates)",
    )
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument(
        "--set",
        nargs="*",
        metavar="KEY=VALUE",
        help="config overrides (JSON values), e.g. HIDDEN=64",
    )
    p.add_argument(
        "--config",
        default=None,
        help="start from a bundled config's settings (e.g. ippo: make train's) instead of the "
        "paper defaults; --set and --envs apply on top",
    )
    p.add_argument("--json", type=Path, help="also write the rows here")
    p.add_argument(
        "--base",
        default=None,
        help="also time this checkout's trainers (base:<algo>), interleaved in the same rounds",
    )
    p.add_argument(
        "--phases",
        action="store_true",
        help="instead: split an update into rollout and epochs, with the networks' multiply-adds",
    )
    args = p.parse_args(argv)
    overrides = _parse_set(args.set)
    if args.config:
        base = {k: v for k, v in settings(args.config).items() if k != "TOTAL_TIMESTEPS"}
        overrides = {**base, **overrides}

    print(
        f"jax {jax.__version__} on {jax.devices()[0].platform} x{len(jax.devices())}, {os.cpu_count()} CPUs, "
        f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}",
        flush=True,
    )
    if args.phases:
        for algo in args.algos:
            m = network_macs(algo, overrides)
            for n in args.envs:
                ph = profile_phases(algo, n, overrides=overrides)
                print(
                    f"{algo:<6} {n:>5} envs: update {ph['update_s']:.3f} s = rollout {ph['rollout_s']:.3f} "
                    f"+ 4 x epoch {ph['epoch_s']:.3f}; network MACs per env-step: rollout "
                    f"{m['rollout_macs'] / 1e6:.2f} M, update {m['update_macs'] / 1e6:.2f} M; load {ph['load']:.1f}",
                    flush=True,
                )
        return []
    algos = list(args.algos)
    if args.base:
        load_base(args.base)
        algos += [f"base:{a}" for a in args.algos]
    rows = []
    for n in args.envs:
        rows += measure_training(algos, n, args.timesteps, args.repeats, overrides)
    print(format_rows(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return rows


if __name__ == "__main__":
    main()
