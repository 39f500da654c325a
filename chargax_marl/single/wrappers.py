"""Wrappers of the single-agent env: episode logging (JAX) and a Gymnasium adapter (numpy)."""

from __future__ import annotations

from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from chargax_marl.core.types import EnvParams, EnvState, EpisodeTotals
from chargax_marl.single.env import Chargax


@struct.dataclass
class LogState:
    env_state: EnvState
    episode_return: jnp.ndarray
    episode_length: jnp.ndarray
    returned_episode_return: jnp.ndarray
    returned_episode_length: jnp.ndarray
    returned_totals: EpisodeTotals


class LogWrapper:
    """Track episode returns, lengths and the episode totals across auto-resets.

    ``info`` gains ``returned_episode_returns``, ``returned_episode_lengths``,
    ``returned_episode`` (True on the step that ended an episode) and
    ``returned_episode_<total>`` for every field of :class:`EpisodeTotals` (profit,
    energies, cars served and rejected, ...), each holding the last finished episode's value.
    """

    def __init__(self, env: Chargax):
        self._env = env

    def __getattr__(self, name: str):
        return getattr(self._env, name)

    def reset(self, key: jax.Array, params: EnvParams | None = None):
        obs, env_state = self._env.reset(key, params)
        zero = jnp.zeros((), jnp.float32)
        state = LogState(env_state, zero, jnp.zeros((), jnp.int32), zero, jnp.zeros((), jnp.int32),
                         EpisodeTotals.zeros())
        return obs, state

    def step(self, key: jax.Array, state: LogState, action, params: EnvParams | None = None):
        obs, env_state, reward, terminated, truncated, info = self._env.step(key, state.env_state, action, params)
        done = jnp.logical_or(terminated, truncated)
        ep_return = state.episode_return + reward
        ep_length = state.episode_length + 1
        finished = EpisodeTotals(**{k: info[f"episode_{k}"] for k in EpisodeTotals.__dataclass_fields__})
        totals = jax.tree.map(lambda new, old: jnp.where(done, new, old), finished, state.returned_totals)
        new_state = LogState(
            env_state=env_state,
            episode_return=ep_return * (1 - done),
            episode_length=ep_length * (1 - done),
            returned_episode_return=jnp.where(done, ep_return, state.returned_episode_return),
            returned_episode_length=jnp.where(done, ep_length, state.returned_episode_length),
            returned_totals=totals,
        )
        info = dict(info)
        info["returned_episode_returns"] = new_state.returned_episode_return
        info["returned_episode_lengths"] = new_state.returned_episode_length
        info["returned_episode"] = done
        info.update({f"returned_episode_{k}": getattr(totals, k) for k in EpisodeTotals.__dataclass_fields__})
        return obs, new_state, reward, terminated, truncated, info


class GymnasiumEnv(gymnasium.Env):
    """Gymnasium adapter: numpy in and out, the jitted JAX step underneath.

    Observation: ``Box(-inf, inf, (n,), float32)``. Action: ``MultiDiscrete`` with one entry
    per port and battery (discrete modes) or ``Box(-1, 1)`` (continuous). The episode is one
    day; it ends with ``truncated=True`` and does not auto-reset. ``reset(seed=...)`` seeds a
    JAX key, so the same seed gives the same day.
    """

    metadata = {"render_modes": []}

    def __init__(self, env: Chargax | None = None, params: EnvParams | None = None, **overrides: Any):
        if env is None:
            env = Chargax(params=params, **overrides)
        self.env = env
        self.params = params if params is not None else env.default_params
        space = env.action_space(self.params)
        if self.params.action_mode == "continuous":
            self.action_space = gymnasium.spaces.Box(-1.0, 1.0, space.shape, np.float32)
        else:
            self.action_space = gymnasium.spaces.MultiDiscrete(np.asarray(space.nvec, dtype=np.int64))
        n = env.observation_space(self.params).shape[0]
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (n,), np.float32)
        self._reset = jax.jit(env.reset_env)
        self._step = jax.jit(env.step_env)
        self._key = jax.random.PRNGKey(0)
        self._state = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._key = jax.random.PRNGKey(seed)
        self._key, key = jax.random.split(self._key)
        if options and "day" in options:
            obs, self._state = self.env.reset_to_day(int(options["day"]), self.params)
        else:
            obs, self._state = self._reset(key, self.params)
        return np.asarray(obs, dtype=np.float32), {}

    def step(self, action):
        if self._state is None:
            raise RuntimeError("GymnasiumEnv.step called before reset()")
        action = np.asarray(action)
        if not self.action_space.contains(action.astype(self.action_space.dtype)):
            raise ValueError(f"action {action.tolist()} is outside the action space {self.action_space}")
        self._key, key = jax.random.split(self._key)
        obs, state, reward, _, info = self._step(key, self._state, jnp.asarray(action), self.params)
        self._state = state
        truncated = bool(self.env.is_truncated(state, self.params))
        info = {k: float(v) for k, v in jax.device_get(info).items()}
        return np.asarray(obs, dtype=np.float32), float(reward), False, truncated, info
