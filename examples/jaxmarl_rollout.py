"""Vectorised rollout of the multi-agent env with JaxMARL's API: ``vmap`` over envs, ``lax.scan`` over a day.

``python examples/jaxmarl_rollout.py --num-envs 64`` steps 64 stations for one day with random
valid actions (each agent samples uniformly among the actions ``get_avail_actions`` allows),
then prints the mean daily profit over the envs and the env-steps per second (compilation
excluded), as a training loop such as JaxMARL's IPPO would drive it.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from chargax_marl.marl import ChargaxMARL, LogWrapper


def make_rollout(env: ChargaxMARL, num_envs: int):
    """A jitted function ``key -> (per-env day profit, final LogWrapper infos)``."""
    log_env = LogWrapper(env)
    num_steps = env.params.num_steps

    def sample_actions(key, avail):
        # Uniform over the valid actions: a categorical with -inf logits on the masked ones.
        keys = jax.random.split(key, env.num_agents)
        return {
            a: jax.random.categorical(keys[i], jnp.where(avail[a], 0.0, -jnp.inf))
            for i, a in enumerate(env.agents)
        }

    def one_env(key):
        key, k_reset = jax.random.split(key)
        obs, state = log_env.reset(k_reset)

        def body(carry, _):
            obs, state, key = carry
            key, k_act, k_step = jax.random.split(key, 3)
            actions = sample_actions(k_act, env.get_avail_actions(state.env_state))
            obs, state, rewards, dones, infos = log_env.step(k_step, state, actions)
            return (obs, state, key), (
                rewards[env.agents[0]],
                infos["returned_episode_profit_eur"][0],
            )

        _, (rewards, returned_profit) = jax.lax.scan(
            body, (obs, state, key), None, length=num_steps
        )
        return rewards.sum(), returned_profit[-1]

    return jax.jit(lambda key: jax.vmap(one_env)(jax.random.split(key, num_envs)))


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--step-minutes",
        type=float,
        default=5.0,
        help="minutes per step (5 = the paper's 288 steps)",
    )
    args = parser.parse_args(argv)

    env = ChargaxMARL(step_minutes=args.step_minutes)
    rollout = make_rollout(env, args.num_envs)
    key = jax.random.PRNGKey(args.seed)
    jax.block_until_ready(rollout(jax.random.PRNGKey(args.seed + 1)))  # compile
    start = time.perf_counter()
    profit, logged = jax.block_until_ready(rollout(key))
    elapsed = time.perf_counter() - start
    steps_per_s = args.num_envs * env.params.num_steps / elapsed
    profit = np.asarray(profit)
    print(f"{args.num_envs} envs x {env.params.num_steps} steps, {env.num_agents} agents each")
    print(f"mean day profit: {profit.mean():.2f} EUR (std {profit.std():.2f})")
    print(f"env-steps/s:     {steps_per_s:,.0f} (compile excluded)")
    return {"profit": profit, "logged_profit": np.asarray(logged), "steps_per_s": steps_per_s}


if __name__ == "__main__":
    main()
