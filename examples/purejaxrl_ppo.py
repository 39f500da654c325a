"""A PureJaxRL-style single-file PPO on the single-agent station, through gymnax's own LogWrapper.

``python examples/purejaxrl_ppo.py --timesteps 2e5`` trains a categorical policy over the
flat ``Discrete`` view `chargax_marl.single.FlatDiscrete` (one shared level for every
port and one for the battery: 441 actions with the defaults) with the structure of
PureJaxRL's ``ppo.py``: ``make_train(config)`` returns a function ``train(key)`` that is
jitted whole, ``jax.vmap`` over envs, ``jax.lax.scan`` over rollout steps, epochs and
minibatches, and episode returns from ``gymnax.wrappers.purerl.LogWrapper``. The only
chargax_marl-specific lines are the two that build the env. Prints the mean return of the
episodes finished in the first and last updates.

A user of PureJaxRL's own ``ppo.py`` changes one line::

    env, env_params = FlatDiscrete(Chargax()), None      # instead of gymnax.make(...)

and keeps ``env.action_space(env_params).n``, ``env.observation_space(env_params).shape``
and ``LogWrapper(env)`` as they are.
"""

from __future__ import annotations

import argparse
from typing import NamedTuple

import distrax
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax.training.train_state import TrainState
from gymnax.wrappers.purerl import LogWrapper

from chargax_marl.single import Chargax, FlatDiscrete


class ActorCritic(nn.Module):
    num_actions: int
    hidden: int = 64

    @nn.compact
    def __call__(self, x):
        a = nn.tanh(nn.Dense(self.hidden)(x))
        a = nn.tanh(nn.Dense(self.hidden)(a))
        logits = nn.Dense(self.num_actions, kernel_init=nn.initializers.orthogonal(0.01))(a)
        c = nn.tanh(nn.Dense(self.hidden)(x))
        c = nn.tanh(nn.Dense(self.hidden)(c))
        return distrax.Categorical(logits=logits), jnp.squeeze(nn.Dense(1)(c), -1)


class Transition(NamedTuple):
    done: jnp.ndarray
    action: jnp.ndarray
    value: jnp.ndarray
    reward: jnp.ndarray
    log_prob: jnp.ndarray
    obs: jnp.ndarray
    info: dict


def make_train(config: dict):
    env, env_params = FlatDiscrete(Chargax(step_minutes=config["STEP_MINUTES"])), None  # the env
    env = LogWrapper(env)
    num_updates = int(config["TOTAL_TIMESTEPS"] // config["NUM_STEPS"] // config["NUM_ENVS"])
    minibatch = config["NUM_ENVS"] * config["NUM_STEPS"] // config["NUM_MINIBATCHES"]
    reward_scale = config["REWARD_SCALE"]

    def train(key):
        network = ActorCritic(env.action_space(env_params).n)
        key, k_init, k_reset = jax.random.split(key, 3)
        obs_shape = env.observation_space(env_params).shape
        params = network.init(k_init, jnp.zeros(obs_shape))
        tx = optax.chain(optax.clip_by_global_norm(0.5), optax.adam(config["LR"], eps=1e-5))
        state = TrainState.create(apply_fn=network.apply, params=params, tx=tx)
        obs, env_state = jax.vmap(env.reset, in_axes=(0, None))(
            jax.random.split(k_reset, config["NUM_ENVS"]), env_params
        )

        def update(runner, _):
            def env_step(runner, _):
                state, env_state, obs, key = runner
                key, k_act, k_step = jax.random.split(key, 3)
                pi, value = network.apply(state.params, obs)
                action = pi.sample(seed=k_act)
                log_prob = pi.log_prob(action)
                obs2, env_state, reward, terminated, truncated, info = jax.vmap(
                    env.step, in_axes=(0, 0, 0, None)
                )(jax.random.split(k_step, config["NUM_ENVS"]), env_state, action, env_params)
                done = jnp.logical_or(terminated, truncated)
                info = {k: info[k] for k in ("returned_episode", "returned_episode_returns")}
                t = Transition(done, action, value, reward * reward_scale, log_prob, obs, info)
                return (state, env_state, obs2, key), t

            runner, traj = jax.lax.scan(env_step, runner, None, config["NUM_STEPS"])
            state, env_state, obs, key = runner
            _, last_value = network.apply(state.params, obs)

            def gae(carry, t):
                adv, next_value = carry
                delta = t.reward + config["GAMMA"] * next_value * (1 - t.done) - t.value
                adv = delta + config["GAMMA"] * config["GAE_LAMBDA"] * (1 - t.done) * adv
                return (adv, t.value), adv

            _, advantages = jax.lax.scan(
                gae, (jnp.zeros_like(last_value), last_value), traj, reverse=True
            )
            targets = advantages + traj.value

            def epoch(carry, _):
                state, key = carry
                key, k_perm = jax.random.split(key)
                batch = (traj, advantages, targets)
                batch = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), batch)
                perm = jax.random.permutation(k_perm, minibatch * config["NUM_MINIBATCHES"])
                batch = jax.tree.map(
                    lambda x: x[perm].reshape((config["NUM_MINIBATCHES"], -1) + x.shape[1:]), batch
                )

                def minibatch_step(state, mb):
                    t, adv, tgt = mb

                    def loss_fn(p):
                        pi, value = network.apply(p, t.obs)
                        ratio = jnp.exp(pi.log_prob(t.action) - t.log_prob)
                        a = (adv - adv.mean()) / (adv.std() + 1e-8)
                        clip = config["CLIP_EPS"]
                        actor = -jnp.minimum(
                            ratio * a, jnp.clip(ratio, 1 - clip, 1 + clip) * a
                        ).mean()
                        v_clipped = t.value + jnp.clip(value - t.value, -clip, clip)
                        critic = (
                            0.5 * jnp.maximum((value - tgt) ** 2, (v_clipped - tgt) ** 2).mean()
                        )
                        return (
                            actor
                            + config["VF_COEF"] * critic
                            - config["ENT_COEF"] * pi.entropy().mean()
                        )

                    grads = jax.grad(loss_fn)(state.params)
                    return state.apply_gradients(grads=grads), None

                state, _ = jax.lax.scan(minibatch_step, state, batch)
                return (state, key), None

            (state, key), _ = jax.lax.scan(epoch, (state, key), None, config["UPDATE_EPOCHS"])
            done = traj.info["returned_episode"]
            mean_return = jnp.sum(traj.info["returned_episode_returns"] * done) / jnp.maximum(
                done.sum(), 1
            )
            return (state, env_state, obs, key), (mean_return, done.sum())

        runner = (state, env_state, obs, key)
        runner, (returns, episodes) = jax.lax.scan(update, runner, None, num_updates)
        return {"runner_state": runner, "returns": returns, "episodes": episodes}

    return train


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--timesteps", type=float, default=2e5)
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--num-steps", type=int, default=128)
    parser.add_argument(
        "--step-minutes",
        type=float,
        default=5.0,
        help="minutes per step (5 = the paper's 288 steps)",
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    config = {
        "LR": 3e-4,
        "NUM_ENVS": args.num_envs,
        "NUM_STEPS": args.num_steps,
        "TOTAL_TIMESTEPS": args.timesteps,
        "UPDATE_EPOCHS": 4,
        "NUM_MINIBATCHES": 4,
        "GAMMA": 0.99,
        "GAE_LAMBDA": 0.95,
        "CLIP_EPS": 0.2,
        "ENT_COEF": 0.01,
        "VF_COEF": 0.5,
        "STEP_MINUTES": args.step_minutes,
        "REWARD_SCALE": 0.1,
    }
    out = jax.jit(make_train(config))(jax.random.PRNGKey(args.seed))
    returns, episodes = np.asarray(out["returns"]), np.asarray(out["episodes"])
    finished = returns[episodes > 0]
    first = float(finished[0]) if finished.size else float("nan")
    last = float(finished[-1]) if finished.size else float("nan")
    print(
        f"{len(returns)} updates, {int(episodes.sum())} episodes finished; mean episode return "
        f"(EUR, one day) first {first:.2f}, last {last:.2f}"
    )
    return {"returns": returns, "episodes": episodes, "first": first, "last": last}


if __name__ == "__main__":
    main()
