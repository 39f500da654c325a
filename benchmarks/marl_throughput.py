"""Throughput of the multi-agent view against the single-agent view (DESIGN.md section 9).

``python benchmarks/marl_throughput.py`` measures, for the default station and a random
policy on the CPU:

1. env-steps/s of ``ChargaxMARL.step`` and ``Chargax.step`` (both with auto-reset), vmapped
   over 1, 16, 256 and 1024 envs inside one jitted ``lax.scan`` (compilation excluded, best
   of ``repeats`` interleaved runs);
2. steps/s of the PettingZoo wrapper (numpy in and out, one env) against a bare jitted
   single-agent step called from Python on one env.

Both views draw the random action the same way (one ``randint`` per step) and carry their
observations through the scan (as a training rollout does), so the difference is the cost of
the view itself: action dict in, per-agent observations, rewards and dones out. (Infos that
the loop does not use are dropped by XLA in both.)
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

from chargax_marl.marl import ChargaxMARL, parallel_env
from chargax_marl.single import Chargax


def _time_best(fns, *args, repeats: int) -> list[float]:
    """Best wall time of each function over ``repeats`` interleaved rounds (robust to a busy machine)."""
    for fn in fns:
        jax.block_until_ready(fn(*args))  # compile and warm up
    best = [np.inf] * len(fns)
    for _ in range(repeats):
        for i, fn in enumerate(fns):
            start = time.perf_counter()
            jax.block_until_ready(fn(*args))
            best[i] = min(best[i], time.perf_counter() - start)
    return best


def _single_runner(env: Chargax, num_envs: int, num_steps: int):
    params = env.default_params
    nvec = env.action_space(params).nvec

    @jax.jit
    def run(key):
        keys = jax.random.split(key, num_envs + 1)
        obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys[1:], params)

        def body(carry, _):
            obs, state, key = carry
            key, k_act, k_step = jax.random.split(key, 3)
            actions = jax.random.randint(k_act, (num_envs, nvec.shape[0]), 0, nvec)
            obs, state, reward, _, _, _ = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(k_step, num_envs), state, actions, params
            )
            return (obs, state, key), reward.sum()

        (obs, _, _), rewards = jax.lax.scan(body, (obs, state, keys[0]), None, length=num_steps)
        return rewards.sum(), obs

    return run


def _marl_runner(env: ChargaxMARL, num_envs: int, num_steps: int):
    n, agents = env.num_actions, env.agents

    @jax.jit
    def run(key):
        keys = jax.random.split(key, num_envs + 1)
        obs, state = jax.vmap(env.reset)(keys[1:])

        def body(carry, _):
            obs, state, key = carry
            key, k_act, k_step = jax.random.split(key, 3)
            # agent-major, as JaxMARL's IPPO unbatchifies its (num_agents * num_envs,) actions
            idx = jax.random.randint(k_act, (len(agents), num_envs), 0, n)
            actions = {a: idx[i] for i, a in enumerate(agents)}
            obs, state, rewards, _, _ = jax.vmap(env.step)(
                jax.random.split(k_step, num_envs), state, actions
            )
            return (obs, state, key), rewards[agents[0]].sum()

        (obs, _, _), rewards = jax.lax.scan(body, (obs, state, keys[0]), None, length=num_steps)
        return rewards.sum(), obs

    return run


def marl_throughput(
    num_envs=(1, 16, 256, 1024),
    num_steps: int = 288,
    repeats: int = 5,
    pettingzoo_steps: int = 288,
    seed: int = 0,
    **make_params_kwargs,
) -> dict:
    """Measure and print env-steps/s of both views; return the numbers as a dict.

    ``make_params_kwargs`` select the scenario (default: the paper's 16-port station).
    """
    single = Chargax(**make_params_kwargs)
    marl = ChargaxMARL(params=single.default_params)
    key = jax.random.PRNGKey(seed)
    rows = []
    print(
        f"default station: {marl.num_agents} agents, {num_steps} steps per run, best of {repeats}, "
        f"compile excluded, backend {jax.default_backend()}"
    )
    print(f"{'envs':>6} {'single steps/s':>16} {'MARL steps/s':>14} {'MARL/single':>12}")
    for b in num_envs:
        t_single, t_marl = _time_best(
            [_single_runner(single, b, num_steps), _marl_runner(marl, b, num_steps)],
            key,
            repeats=repeats,
        )
        s_single, s_marl = b * num_steps / t_single, b * num_steps / t_marl
        rows.append(
            {
                "num_envs": b,
                "single_steps_per_s": s_single,
                "marl_steps_per_s": s_marl,
                "ratio": s_marl / s_single,
            }
        )
        print(f"{b:>6} {s_single:>16,.0f} {s_marl:>14,.0f} {s_marl / s_single:>12.2f}")

    # Bare jitted single-agent step on one env, called from Python.
    params = single.default_params
    step = jax.jit(single.step)
    _, state = single.reset(key, params)
    action = single.action_space(params).sample(key)
    keys = jax.random.split(key, pettingzoo_steps)
    jax.block_until_ready(step(keys[0], state, action, params))
    bare = np.inf
    for _ in range(repeats):
        s = state
        start = time.perf_counter()
        for k in keys:
            _, s, r, _, _, _ = step(k, s, action, params)
        jax.block_until_ready(s)
        bare = min(bare, time.perf_counter() - start)
    bare_sps = pettingzoo_steps / bare

    pz = parallel_env(params=params)
    rng = np.random.default_rng(seed)
    acts = rng.integers(0, marl.num_actions, size=(pettingzoo_steps, marl.num_agents))
    pz.reset(seed=seed)
    pz.step({a: int(acts[0, i]) for i, a in enumerate(pz.possible_agents)})  # compile
    best = np.inf
    for _ in range(repeats):
        pz.reset(seed=seed)
        done_steps = 0
        start = time.perf_counter()
        for t in range(pettingzoo_steps):
            if not pz.agents:
                pz.reset()
            pz.step({a: int(acts[t, i]) for i, a in enumerate(pz.possible_agents)})
            done_steps += 1
        best = min(best, time.perf_counter() - start)
    pz_sps = pettingzoo_steps / best
    print(
        f"one env from Python: bare jitted single step {bare_sps:,.0f} steps/s, "
        f"PettingZoo wrapper {pz_sps:,.0f} steps/s (bare/PettingZoo = {bare_sps / pz_sps:.2f}x)"
    )
    return {"vmapped": rows, "bare_single_steps_per_s": bare_sps, "pettingzoo_steps_per_s": pz_sps}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--num-envs", type=int, nargs="+", default=[1, 16, 256, 1024])
    parser.add_argument("--num-steps", type=int, default=288)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    marl_throughput(tuple(args.num_envs), num_steps=args.num_steps, repeats=args.repeats)


if __name__ == "__main__":
    main()
