"""JaxMARL-style wrappers of `ChargaxMARL`: episode logging, MAPPO's world state and the
observations before an auto-reset.

Each keeps JaxMARL's call signatures (``reset(key)``, ``step(key, state, actions)``) and
forward every other attribute to the wrapped env, so they stack like JaxMARL's: the
MAPPO order is ``LogWrapper(WorldStateWrapper(env))``. Each also has the array step of
`chargax_marl.marl.ChargaxMARL.step_arrays` (``step_arrays(key, state, indices)``:
actions ``(num_agents,)`` in, observations ``(num_agents, obs_size)`` and rewards
``(num_agents,)`` out), the same transition without the per-agent dicts, which the trainers
use.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from chargax_marl.core.types import EnvState, EpisodeTotals
from chargax_marl.marl.env import ChargaxMARL


class _Wrapper:
    def __init__(self, env):
        self._env = env

    def __getattr__(self, name: str) -> Any:
        if name == "_env":  # not set yet (e.g. while unpickling): avoid infinite recursion
            raise AttributeError(name)
        return getattr(self._env, name)

    def step(self, key: jax.Array, state, actions: dict, reset_state=None):
        """The wrapped env's ``step`` with what this wrapper adds (its class docstring), jitted;
        ``actions`` is checked and its host integers clipped first (`host_actions`).

        Args:
            key: the step's key.
            state: this wrapper's state.
            actions: ``{agent: index}``, one entry per agent.
            reset_state: the fresh day's state at the end of a day (``None``: a random one).

        Returns:
            ``(obs, state, rewards, dones, infos)``, JaxMARL's step.

        Raises:
            ValueError: a bad action dict.
        """
        return self._step(key, state, self.host_actions(actions), reset_state)

    def host_actions(self, actions: dict) -> dict:
        """The action dict checked on the host, before it enters ``jit``: the wrapped env's
        ``validate_actions`` (host integers clipped into int32, so a large one clips instead of
        wrapping at the jit boundary; traced values pass through).

        Raises:
            ValueError: a bad action dict (`chargax_marl.marl.ChargaxMARL.validate_actions`).
        """
        return dict(zip(self._env.agents, self._env.validate_actions(actions)))

    def stack_agent_values(self, x: dict) -> jnp.ndarray:
        """A per-agent dict as an array ``(num_agents, ...)`` in agent order."""
        return jnp.stack([x[a] for a in self._env.agents])


def _core_state(state) -> EnvState:
    """Unwrap wrapper states (``.env_state``) down to the core `EnvState`."""
    while not isinstance(state, EnvState):
        state = state.env_state
    return state


@struct.dataclass
class LogEnvState:
    """JaxMARL's ``LogEnvState`` fields (each ``(num_agents,)``) plus the last finished
    episode's totals.

    Attributes:
        env_state: the wrapped env's state.
        episode_returns: each agent's return so far in the running episode.
        episode_lengths: the steps so far in the running episode (int32).
        returned_episode_returns: each agent's return in the last finished episode.
        returned_episode_lengths: the length of the last finished episode (int32).
        returned_totals: the last finished episode's `chargax_marl.core.EpisodeTotals`.
    """

    env_state: Any
    episode_returns: jnp.ndarray
    episode_lengths: jnp.ndarray
    returned_episode_returns: jnp.ndarray
    returned_episode_lengths: jnp.ndarray
    returned_totals: EpisodeTotals


class LogWrapper(_Wrapper):
    """Track per-agent episode returns and lengths across auto-resets, as JaxMARL's ``LogWrapper``.

    ``info`` gains ``returned_episode_returns``, ``returned_episode_lengths`` (the last
    finished episode's values), ``returned_episode`` (True on the step that ended an
    episode) and ``returned_episode_<total>`` for every field of
    `chargax_marl.core.EpisodeTotals` (profit, energies, cars served, ...), each of
    shape ``(num_agents,)``.

    Args:
        env: the multi-agent env to wrap (a `chargax_marl.marl.ChargaxMARL` or a wrapper of
            one); every other attribute is forwarded to it.
        replace_info: drop the env's own infos, keeping only the logged entries.
    """

    def __init__(self, env, replace_info: bool = False):
        super().__init__(env)
        self.replace_info = replace_info

    @functools.partial(jax.jit, static_argnums=(0,))
    def reset(self, key: jax.Array):
        obs, env_state = self._env.reset(key)
        n = self._env.num_agents
        zeros = jnp.zeros((n,), jnp.float32)
        state = LogEnvState(
            env_state,
            zeros,
            jnp.zeros((n,), jnp.int32),
            zeros,
            jnp.zeros((n,), jnp.int32),
            EpisodeTotals.zeros(),
        )
        return obs, state

    @functools.partial(jax.jit, static_argnums=(0,))
    def _step(self, key: jax.Array, state: LogEnvState, actions: dict, reset_state=None):
        if reset_state is None:
            obs, env_state, reward, done, info = self._env.step(key, state.env_state, actions)
        else:
            obs, env_state, reward, done, info = self._env.step(
                key, state.env_state, actions, reset_state
            )
        state, info = self._log(
            state, env_state, self.stack_agent_values(reward), done["__all__"], info
        )
        return obs, state, reward, done, info

    @functools.partial(jax.jit, static_argnums=(0,))
    def step_arrays(self, key: jax.Array, state: LogEnvState, indices: jax.Array, reset_state=None):
        """The wrapped env's ``step_arrays`` with the episode logging (the same state and
        infos as `step`; the logged infos are ``(num_agents,)``).
        Arguments and returns as `chargax_marl.marl.ChargaxMARL.step_arrays`, with this
        wrapper's state.
        """
        obs, env_state, reward, done, info = self._env.step_arrays(
            key, state.env_state, indices, reset_state
        )
        state, info = self._log(state, env_state, reward, done, info)
        return obs, state, reward, done, info

    def _log(self, state: LogEnvState, env_state, reward: jax.Array, ep_done: jax.Array, info):
        """The logged state after a step with per-agent rewards ``reward (num_agents,)``, and
        the infos with the logged entries."""
        n = self._env.num_agents
        new_return = state.episode_returns + reward.astype(jnp.float32)
        new_length = state.episode_lengths + 1
        # The env auto-resets on done, so the finished episode's totals come from the info
        # (per agent in the dict view, scalars in the array view).
        finished = EpisodeTotals(
            **{
                k: jnp.reshape(info[f"episode_{k}"], (-1,))[0]
                for k in EpisodeTotals.__dataclass_fields__
            }
        )
        totals = jax.tree.map(
            lambda new, old: jnp.where(ep_done, new, old), finished, state.returned_totals
        )
        state = LogEnvState(
            env_state=env_state,
            episode_returns=jnp.where(ep_done, 0.0, new_return),
            episode_lengths=jnp.where(ep_done, 0, new_length),
            returned_episode_returns=jnp.where(ep_done, new_return, state.returned_episode_returns),
            returned_episode_lengths=jnp.where(ep_done, new_length, state.returned_episode_lengths),
            returned_totals=totals,
        )
        info = {} if self.replace_info else dict(info)
        info["returned_episode_returns"] = state.returned_episode_returns
        info["returned_episode_lengths"] = state.returned_episode_lengths
        info["returned_episode"] = jnp.full((n,), ep_done)
        for k in EpisodeTotals.__dataclass_fields__:
            info[f"returned_episode_{k}"] = jnp.broadcast_to(getattr(totals, k), (n,))
        return state, info


class WorldStateWrapper(_Wrapper):
    """Add MAPPO's centralised input: ``obs["world_state"]`` of shape ``(num_agents, state_size)``.

    Every row is the env's `get_global_state` (the single-agent observation) of the
    returned state, so after an auto-reset it describes the new day.

    Args:
        env: the multi-agent env to wrap (a `chargax_marl.marl.ChargaxMARL` or a wrapper of
            one); every other attribute is forwarded to it.
    """

    @functools.partial(jax.jit, static_argnums=(0,))
    def reset(self, key: jax.Array):
        obs, env_state = self._env.reset(key)
        obs = dict(obs)
        obs["world_state"] = self.world_state(env_state)
        return obs, env_state

    @functools.partial(jax.jit, static_argnums=(0,))
    def _step(self, key: jax.Array, state, actions: dict, reset_state=None):
        if reset_state is None:
            obs, env_state, reward, done, info = self._env.step(key, state, actions)
        else:
            obs, env_state, reward, done, info = self._env.step(key, state, actions, reset_state)
        obs = dict(obs)
        obs["world_state"] = self.world_state(env_state)
        return obs, env_state, reward, done, info

    def step_arrays(self, key: jax.Array, state, indices: jax.Array, reset_state=None):
        """The wrapped env's ``step_arrays``, unchanged: the observations are a matrix with no
        room for an entry of its own, so an array-path trainer reads the world state of the
        returned state with `global_state` (the same row `step` adds).

        Args:
            key: the step's key.
            state: the wrapped env's state (this wrapper keeps no state of its own).
            indices: ``(num_agents,)`` action indices in agent order.
            reset_state: the fresh day's state at the end of a day (None: a random one).

        Returns:
            The wrapped env's ``(obs, state, rewards, done, info)``
            (`chargax_marl.marl.ChargaxMARL.step_arrays`).
        """
        return self._env.step_arrays(key, state, indices, reset_state)

    def global_state(self, state) -> jnp.ndarray:
        """The world state ``(state_size,)`` of a (wrapped) state: one row of
        `world_state`.

        Args:
            state: a core `EnvState` or a wrapper's state holding one (``.env_state``).

        Returns:
            ``(state_size,)`` float32, the env's ``get_global_state``.
        """
        return self._env.get_global_state(_core_state(state))

    def world_state(self, state) -> jnp.ndarray:
        """``obs["world_state"]``: `global_state` for every agent,
        ``(num_agents, state_size)``.

        Args:
            state: a core `EnvState` or a wrapper's state holding one (``.env_state``).

        Returns:
            ``(num_agents, state_size)``, the same row for every agent.
        """
        ws = self.global_state(state)
        return jnp.broadcast_to(ws, (self._env.num_agents, ws.shape[0]))

    def world_state_size(self) -> int:
        return self._env.state_size


class FinalObservationWrapper(_Wrapper):
    """Report the observations of each step's stepped state, before an auto-reset replaces them.

    ``info["final_observation"]`` ``(num_agents, obs_size)``: row ``i`` is agent ``i``'s
    observation of the state the step reached, which differs from the returned observation
    only on the last step of a day (where the returned one is the fresh day's). A loop that
    bootstraps the value of a truncated day needs it. The entry is opt-in because it breaks
    the infos' contract that every leaf is ``(num_agents,)`` (`ChargaxMARL`'s infos):
    JaxMARL's baselines reshape every info leaf and fail on it, so stack this wrapper only
    under code of your own.

    It wraps a `ChargaxMARL` itself (other wrappers go on top of it and pass the entry
    through; an observation wrapper that appends columns, such as
    `chargax_marl.wrappers.RelativePriceObservation`, appends them to the entry too, so that
    it keeps the observation's size). Its `step` and `step_arrays` are the env's, with the
    entry added.

    Args:
        env: the `ChargaxMARL` to wrap.

    Raises:
        TypeError: ``env`` is not a `ChargaxMARL` (a wrapper of one included).
    """

    adds_final_observation = True
    """Marks an env whose infos hold ``final_observation`` (wrappers above it read this)."""

    def __init__(self, env):
        if not isinstance(env, ChargaxMARL):
            raise TypeError(
                f"FinalObservationWrapper: field 'env' must be a ChargaxMARL itself (put other "
                f"wrappers on top of this one), got {type(env).__name__}"
            )
        super().__init__(env)

    @functools.partial(jax.jit, static_argnums=(0,))
    def _step(self, key: jax.Array, state: EnvState, actions: dict, reset_state=None):
        indices = self._env.stack_actions(actions)
        return self._env._dict_step(
            key, state, indices, reset_state, auto_reset=True, final_observation=True
        )

    @functools.partial(jax.jit, static_argnums=(0,))
    def step_arrays(self, key: jax.Array, state: EnvState, indices: jax.Array, reset_state=None):
        """The env's ``step_arrays`` with ``info["final_observation"]``.
        Arguments and returns as `chargax_marl.marl.ChargaxMARL.step_arrays`.
        """
        env = self._env
        next_state, rewards, done, info = env._transition(
            key, state, indices, reset_state, True, final_observation=True
        )
        return env.get_obs_matrix(next_state), next_state, rewards, done, info
