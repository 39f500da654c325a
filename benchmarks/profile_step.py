"""Where the time of one env-step goes: each piece of the transition timed alone under jit.

Every piece runs ``jax.vmap`` over ``--envs`` copies of a realistic mid-day state (random
policy for ``--warmup`` steps, so ports are occupied) inside a ``jax.lax.scan`` of
``--steps`` iterations. A piece's outputs are folded back into the carried state with a
weight of 1e-30, so XLA can neither drop the piece nor hoist it out of the loop; the cost of
that scaffolding (the ``scaffold`` row) is subtracted from every other row. Numbers are
microseconds per env-step, best of ``--repeats``.

Rows: ``env.step`` (gymnax step with auto-reset, what a rollout calls), ``env.step_env``
(no auto-reset), ``simulator.step`` (the core transition), its stages, and pieces of
``traffic.arrive`` (the Poisson draw, the ``(5, L)`` uniform draw, the fleet ``searchsorted``),
``physics.rescale_to_limits``, ``observation.flat_obs``, ``env.reset`` and the per-env key
split a rollout does.

Run: ``python benchmarks/profile_step.py [--envs 1 256] [--ports 16]``; ``--chargax-root`` profiles
another checkout (e.g. a scratch copy with a proposed change) for a before/after comparison.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def pieces(env, params):
    import jax
    import jax.numpy as jnp

    from chargax_marl.core import observation, physics, rng, simulator, traffic
    from chargax_marl.core import reward as reward_lib

    st = params.station
    levels_of = env.action_to_levels

    def full_core(key, s, a):
        return simulator.step(key, s, levels_of(a, params), params)

    def apply_actions(key, s, a):
        return physics.apply_actions(levels_of(a, params), s, params)

    def rescale(key, s, a):
        cur = physics.clip_to_car(
            physics.target_current(levels_of(a, params), s, params), s, params
        )
        return physics.rescale_to_limits(cur * 10.0, st)

    def clip_only(key, s, a):
        return physics.clip_to_car(
            physics.target_current(levels_of(a, params), s, params), s, params
        )

    def charge(key, s, a):
        return physics.charge(s.current_a, s, params)

    def flows(key, s, a):
        return physics.energy_flows(s.current_a * 0.01, st)

    def depart(key, s, a):
        return traffic.depart(s, params)

    def arrive(key, s, a):
        return traffic.arrive(key, s, params)

    def poisson(key, s, a):
        u = rng.uniform(rng.key_seed(key), rng.ARRIVALS, (1,))[0]
        return rng.poisson(u, traffic.arrival_rate(s.timestep, s.is_workday, params))

    def uniform5(key, s, a):
        return rng.uniform(rng.key_seed(key), rng.ARRIVALS, (5 * st.num_ports,))

    def old_poisson(key, s, a):
        return jax.random.poisson(key, traffic.arrival_rate(s.timestep, s.is_workday, params))

    def old_uniform5(key, s, a):
        return jax.random.uniform(key, (5, st.num_ports))

    def searchsorted(key, s, a):
        cdf = jnp.cumsum(params.fleet_share)
        return jnp.searchsorted(cdf / cdf[-1], s.soc, side="right")

    def rewards(key, s, a):
        fl = physics.energy_flows(s.current_a * 0.01, st)
        p_buy, p_sell = reward_lib.grid_prices(s.day, s.timestep, params)
        return reward_lib.profit_eur(fl, p_buy, p_sell, params)

    def obs(key, s, a):
        return observation.flat_obs(s, params)

    def reset(key, s, a):
        return env.reset(key, params)

    def step_env(key, s, a):
        return env.step_env(key, s, a, params)

    def step(key, s, a):
        return env.step(key, s, a, params)

    def scaffold(key, s, a):
        return s.soc

    return {
        "scaffold": scaffold,
        "env.step (auto-reset)": step,
        "env.step_env": step_env,
        "simulator.step": full_core,
        "  apply_actions": apply_actions,
        "    clip_to_car+target": clip_only,
        "    +rescale_to_limits": rescale,
        "  charge": charge,
        "  energy_flows": flows,
        "  depart": depart,
        "  arrive": arrive,
        "    poisson draw (inverse CDF)": poisson,
        "    uniform (5,P) draw (hash)": uniform5,
        "    [0.2: jax.random.poisson]": old_poisson,
        "    [0.2: threefry (5,P) uniform]": old_uniform5,
        "    searchsorted": searchsorted,
        "  grid prices+profit": rewards,
        "observation.flat_obs": obs,
        "env.reset": reset,
    }


def profile(
    num_envs: int,
    num_steps: int,
    repeats: int,
    ports: int | None,
    warmup: int = 150,
    only: list[str] | None = None,
) -> dict:
    import jax
    import jax.numpy as jnp

    from chargax_marl.core.params import make_params
    from chargax_marl.single import Chargax

    kwargs = {}
    if ports:
        num_dc = round(ports * 10 / 16)
        kwargs = {
            "station": "multiple_types",
            "station_kwargs": {"num_dc": num_dc, "num_ac": ports - num_dc},
        }
    params = make_params(**kwargs)
    env = Chargax(params=params)
    space = env.action_space(params)

    @jax.jit
    def start_states(key):
        keys = jax.random.split(key, num_envs)
        _, s = jax.vmap(env.reset, in_axes=(0, None))(keys, params)

        def body(s, k):
            a = jax.random.randint(k, (num_envs,) + space.shape, 0, space.nvec)
            _, s, _, _, _, _ = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(k, num_envs), s, a, params
            )
            return s, None

        s, _ = jax.lax.scan(body, s, jax.random.split(key, warmup))
        return s

    states = start_states(jax.random.PRNGKey(0))
    actions = jax.random.randint(jax.random.PRNGKey(1), (num_envs,) + space.shape, 0, space.nvec)

    def runner(fn):
        @jax.jit
        def run(key, s0, a):
            def body(s, k):
                out = jax.vmap(fn)(jax.random.split(k, num_envs), s, a)
                leaves = [x for x in jax.tree.leaves(out) if jnp.issubdtype(x.dtype, jnp.number)]
                tot = sum(
                    jnp.sum(x.astype(jnp.float32).reshape(num_envs, -1), axis=1) for x in leaves
                )
                return s.replace(soc=s.soc + 1e-30 * tot[:, None]), None

            s, _ = jax.lax.scan(body, s0, jax.random.split(key, num_steps))
            return s.soc.sum()

        return run

    results = {}
    for name, fn in pieces(env, params).items():
        if only and name != "scaffold" and not any(o in name for o in only):
            continue
        run = runner(fn)
        jax.block_until_ready(run(jax.random.PRNGKey(2), states, actions))
        best = float("inf")
        for r in range(repeats):
            start = time.perf_counter()
            jax.block_until_ready(run(jax.random.PRNGKey(3 + r), states, actions))
            best = min(best, time.perf_counter() - start)
        results[name] = best / (num_steps * num_envs) * 1e6
    base = results.pop("scaffold")
    return {"scaffold_us": base, **{k: max(v - base, 0.0) for k, v in results.items()}}


def autoreset_ab(env_counts, repeats: int, total_steps: int = 2**14) -> list[dict]:
    """Interleaved A/B in one process: gymnax's own ``Environment.step`` against ``Chargax.step`` (select the state, then observe once)
    in the random-policy rollout of ``throughput.py``; returns env-steps/s of both."""
    import jax
    from gymnax.environments.environment import Environment
    from throughput import load_info, make_runner

    from chargax_marl.single import Chargax

    class GymnaxStep(Chargax):
        """The env with gymnax's own auto-resetting step (observation built twice), as before."""

        step = Environment.step

    proposed = Chargax()  # Chargax.step selects the state first and observes once (applied)
    params = proposed.default_params
    base = GymnaxStep(params=params)
    rows = []
    for n in env_counts:
        steps = max(total_steps // n, 64)
        fns = {
            "gymnax step": make_runner(base, params, n, steps),
            "proposed": make_runner(proposed, params, n, steps),
        }
        for f in fns.values():
            jax.block_until_ready(f(jax.random.PRNGKey(0)))
        best = {k: float("inf") for k in fns}
        for r in range(repeats):
            for k, f in fns.items():
                start = time.perf_counter()
                jax.block_until_ready(f(jax.random.PRNGKey(r + 1)))
                best[k] = min(best[k], time.perf_counter() - start)
        row = {
            "envs": n,
            "before": n * steps / best["gymnax step"],
            "after": n * steps / best["proposed"],
        }
        row["ratio"] = row["after"] / row["before"]
        rows.append(row)
        print(
            f"auto-reset A/B envs={n:>5}: gymnax step {row['before']:>10,.0f} env-steps/s | select-then-observe "
            f"{row['after']:>10,.0f} env-steps/s | after/before {row['ratio']:.2f}x | {load_info()}",
            flush=True,
        )
    return rows


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--envs", type=int, nargs="+", default=[1, 256])
    parser.add_argument(
        "--steps", type=int, default=None, help="scan length (default 2048/envs, at least 16)"
    )
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument(
        "--ports",
        type=int,
        default=None,
        help="multiple_types station size (default: the default station)",
    )
    parser.add_argument(
        "--only",
        nargs="+",
        default=None,
        help="profile only the pieces whose name contains one of these",
    )
    parser.add_argument(
        "--warmup", type=int, default=150, help="random steps before profiling (occupied ports)"
    )
    parser.add_argument(
        "--chargax-root", default=None, help="import chargax_marl from this checkout instead"
    )
    parser.add_argument(
        "--autoreset-ab",
        action="store_true",
        help="only the interleaved A/B of gymnax's auto-reset step against the proposed one",
    )
    args = parser.parse_args(argv)
    if args.chargax_root:
        sys.path.insert(0, str(Path(args.chargax_root).resolve()))
    sys.path.insert(0, str(HERE))
    from throughput import load_info

    import chargax_marl

    print(
        f"profile_step | chargax_marl from {Path(chargax_marl.__file__).parent} | ports={args.ports or 'default'} | "
        f"{load_info()}"
    )
    if args.autoreset_ab:
        return {"autoreset_ab": autoreset_ab(args.envs, args.repeats)}
    table = {}
    for n in args.envs:
        steps = args.steps or max(2048 // n, 16)
        table[n] = profile(n, steps, args.repeats, args.ports, args.warmup, args.only)
    names = list(table[args.envs[0]])
    print(
        f"{'piece (us per env-step, scaffold subtracted)':<46}"
        + "".join(f"{f'{n} envs':>12}" for n in args.envs)
    )
    for name in names:
        print(f"{name:<46}" + "".join(f"{table[n][name]:>12.2f}" for n in args.envs))
    print(load_info())
    return table


if __name__ == "__main__":
    main()
