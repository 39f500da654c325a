"""The contract PureJaxRL's ``ppo.py`` relies on, checked on the single-agent view.

Through gymnax's own ``LogWrapper`` (``gymnax.wrappers.purerl``), PureJaxRL's PPO steps
``NUM_ENVS`` envs under ``jax.vmap`` (params broadcast), keeps the whole ``info`` in each
transition, scans ``NUM_STEPS`` steps per update and updates in a scan, then:

- reshapes every leaf of the trajectory, ``info`` included, to ``(NUM_STEPS * NUM_ENVS, ...)``
  for the minibatches;
- logs ``info["returned_episode_returns"][info["returned_episode"]]``, which needs the two to
  have the same shape, one value per env and step;
- plots ``metrics["returned_episode_returns"].mean(-1).reshape(-1)``, the metrics being the
  infos stacked ``(NUM_UPDATES, NUM_STEPS, NUM_ENVS)``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from gymnax.wrappers.purerl import LogWrapper

from chargax_marl.single import Chargax, FlatDiscrete
from tests.helpers import mixed_station

NUM_ENVS, NUM_STEPS, NUM_UPDATES = 3, 16, 2  # 32 hourly steps: one day ends in update 2
DAY_STEPS = 24


def test_purejaxrl_ppo_shape_operations():
    env = LogWrapper(FlatDiscrete(Chargax(station=mixed_station(), step_minutes=60.0)))
    n_actions = env.action_space(None).n

    def train(key):
        obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, NUM_ENVS), None)

        def update(carry, update_key):
            def env_step(carry, step_key):
                obs, state = carry
                k_act, k_env = jax.random.split(step_key)
                action = jax.random.randint(k_act, (NUM_ENVS,), 0, n_actions)
                obs2, state, reward, terminated, truncated, info = jax.vmap(
                    env.step, in_axes=(0, 0, 0, None)
                )(jax.random.split(k_env, NUM_ENVS), state, action, None)
                done = jnp.logical_or(terminated, truncated)
                return (obs2, state), (done, reward, obs, info)

            carry, traj = jax.lax.scan(env_step, carry, jax.random.split(update_key, NUM_STEPS))
            batch = jax.tree.map(lambda x: x.reshape((NUM_STEPS * NUM_ENVS,) + x.shape[2:]), traj)
            return carry, (traj, batch)

        _, (traj, batch) = jax.lax.scan(update, (obs, state), jax.random.split(key, NUM_UPDATES))
        return traj, batch

    traj, batch = jax.device_get(jax.jit(train)(jax.random.PRNGKey(0)))
    done, reward, obs, info = traj
    assert done.shape == reward.shape == (NUM_UPDATES, NUM_STEPS, NUM_ENVS)
    assert obs.shape == (NUM_UPDATES, NUM_STEPS, NUM_ENVS) + env.observation_space(None).shape
    for k, v in info.items():  # every info leaf is per env and step, with any trailing shape
        assert v.shape[:3] == (NUM_UPDATES, NUM_STEPS, NUM_ENVS), k
        assert batch[3][k].shape == (NUM_UPDATES, NUM_STEPS * NUM_ENVS) + v.shape[3:], k
    assert info["returned_episode"].shape == info["returned_episode_returns"].shape

    # the logged returns: one per finished day and env, each the day's summed reward
    returns = info["returned_episode_returns"][info["returned_episode"]]
    assert returns.shape == (NUM_ENVS,)
    flat_reward = reward.reshape(NUM_UPDATES * NUM_STEPS, NUM_ENVS)
    np.testing.assert_allclose(returns, flat_reward[:DAY_STEPS].sum(0), rtol=1e-4, atol=1e-3)
    ended = np.zeros((NUM_UPDATES * NUM_STEPS, NUM_ENVS), bool)
    ended[DAY_STEPS - 1] = True
    np.testing.assert_array_equal(info["returned_episode"].reshape(ended.shape), ended)
    np.testing.assert_array_equal(done.reshape(ended.shape), ended)

    curve = info["returned_episode_returns"].mean(-1).reshape(-1)
    assert curve.shape == (NUM_UPDATES * NUM_STEPS,) and np.all(np.isfinite(curve))
