"""Imperfect communication between the agents: delayed observations and lost actions.

Two effects that a real station's controllers live with, as pure functions over the
multi-agent view's stacked arrays (observations ``(num_agents, obs_size)``, action indices
``(num_agents,)``), used by the JaxMARL wrappers `DelayedObservationWrapper` and
`ActionLossWrapper` and by the PettingZoo adapter's ``observation_delay_steps`` and
``action_loss_prob`` options (`chargax_marl.marl.pettingzoo_env.ChargaxParallelEnv`).

- **Delayed observations** (SustainGym's ``periods_delay`` sense): each agent sees its own
  port as it is now (its leaf features, kind and index) but the shared context (prices, time,
  ...) and the load of its ancestor nodes, which the other agents' currents make up, as they
  were ``delay_steps`` steps earlier. Early in a day, before ``delay_steps`` steps have passed,
  the delayed columns show the day's first observation.
- **Lost actions** (EV2Gym's ``FailedActionCommunication`` sense): each agent's action is lost
  with probability ``loss_prob``, independently of the others and of the step before, and the
  port applies its previous action (``lost_action="previous"``; idle at the start of a day) or
  idles (``lost_action="idle"``).

With ``delay_steps=0`` and ``loss_prob=0`` both are the unwrapped env bit for bit: the env
draws its cars from the same keys, and the loss draws come from a stream of their own.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from chargax_marl.core import actions as core_actions
from chargax_marl.core.observation import PORT_FEATURES
from chargax_marl.evaluation import MemoryAct
from chargax_marl.marl.env import NUM_KINDS, ChargaxMARL, actions_to_levels
from chargax_marl.marl.wrappers import _Wrapper

LOST_ACTIONS = ("previous", "idle")
"""What a port applies when its action is lost."""

LOSS_STREAM = 0x105E
"""The constant folded into a step's key for the loss draws (the env's draws are unchanged)."""


def check_delay_steps(delay_steps: Any) -> int:
    """``delay_steps`` as an int, or a ``ValueError`` naming the field and what is allowed.

    Args:
        delay_steps: the delay in steps, a Python or numpy integer ``>= 0``.

    Returns:
        ``delay_steps`` as a Python int.

    Raises:
        ValueError: ``delay_steps`` is not an integer (a bool counts as none) or is negative.
    """
    if isinstance(delay_steps, bool) or not isinstance(delay_steps, (int, np.integer)):
        raise ValueError(f"field 'delay_steps' must be an integer >= 0, got {delay_steps!r}")
    if delay_steps < 0:
        raise ValueError(f"field 'delay_steps' must be an integer >= 0, got {delay_steps!r}")
    return int(delay_steps)


def check_loss(loss_prob: Any, lost_action: Any) -> tuple[float, str]:
    """``(loss_prob, lost_action)`` checked, or a ``ValueError`` naming the field.

    Args:
        loss_prob: the probability that an action is lost, a number in ``[0, 1]``.
        lost_action: what a port applies instead, one of `LOST_ACTIONS`.

    Returns:
        ``(loss_prob, lost_action)`` as a float and a str.

    Raises:
        ValueError: ``loss_prob`` is not a number (a bool counts as none) or lies outside
            ``[0, 1]`` (NaN included), or ``lost_action`` is not one of `LOST_ACTIONS`.
    """
    if isinstance(loss_prob, bool) or not isinstance(loss_prob, (int, float, np.number)):
        raise ValueError(f"field 'loss_prob' must be a number in [0, 1], got {loss_prob!r}")
    if not 0.0 <= float(loss_prob) <= 1.0:
        raise ValueError(f"field 'loss_prob' must be a number in [0, 1], got {loss_prob!r}")
    if lost_action not in LOST_ACTIONS:
        raise ValueError(f"field 'lost_action' must be one of {LOST_ACTIONS}, got {lost_action!r}")
    return float(loss_prob), str(lost_action)


def delayed_columns(env: ChargaxMARL) -> np.ndarray:
    """``(obs_size,)`` bool: the observation columns that a delay shows late, the ancestor
    loads and the shared context (`chargax_marl.marl.ChargaxMARL`'s layout: leaf
    features, kind one-hot, ancestor loads, context, agent index).

    Args:
        env: the multi-agent view (unwrapped), whose observation layout is read.

    Returns:
        ``(obs_size,)`` bool mask, True for the ancestor-load and context columns.
    """
    own = len(PORT_FEATURES) + NUM_KINDS
    id_width = np.asarray(env._layout.agent_id).shape[1]
    mask = np.zeros(env.obs_size, bool)
    mask[own : env.obs_size - id_width] = True
    return mask


def start_history(obs: jax.Array, delay_steps: int) -> jax.Array:
    """The history a day starts with: ``delay_steps`` copies of its first observation,
    ``(delay_steps, num_agents, obs_size)``.

    Args:
        obs: ``(num_agents, obs_size)`` the day's first observations.
        delay_steps: the delay in steps (``>= 0``).

    Returns:
        ``(delay_steps, num_agents, obs_size)``, ``obs`` repeated.
    """
    return jnp.broadcast_to(obs, (delay_steps, *obs.shape))


def delay(obs: jax.Array, history: jax.Array, columns: np.ndarray, done: jax.Array):
    """What the agents see after a step, and the history to keep.

    Args:
        obs: ``(num_agents, obs_size)`` the observations the step returned (a fresh day's
            when ``done``).
        history: ``(delay_steps, num_agents, obs_size)`` the observations of the last
            ``delay_steps`` steps, oldest first.
        columns: `delayed_columns`.
        done: whether the step ended the day (the env auto-reset).

    Returns:
        ``(seen, history)``: the observations with the delayed columns taken from the oldest
        entry of the history, and the history with ``obs`` appended (restarted at a new day).
    """
    if history.shape[0] == 0:
        return obs, history
    seen = jnp.where(done, obs, jnp.where(columns, history[0], obs))
    rolled = jnp.concatenate([history[1:], obs[None]], axis=0)
    return seen, jnp.where(done, start_history(obs, history.shape[0]), rolled)


def lose_actions(
    key: jax.Array,
    indices: jax.Array,
    previous: jax.Array,
    idle_index: int,
    loss_prob: float,
    lost_action: str,
):
    """The action indices the ports apply when each is lost with probability ``loss_prob``.

    Args:
        key: the step's key (the loss draws use ``fold_in(key, LOSS_STREAM)``).
        indices: ``(num_agents,)`` the indices the agents sent.
        previous: ``(num_agents,)`` the indices the ports applied last step.
        idle_index: the idle action's index.
        loss_prob: the probability that an agent's action is lost.
        lost_action: ``"previous"`` or ``"idle"``, what a port applies instead.

    Returns:
        ``(applied, lost)``: int32 indices and the bool mask of lost actions.
    """
    indices = jnp.asarray(indices).astype(jnp.int32)
    u = jax.random.uniform(jax.random.fold_in(key, LOSS_STREAM), indices.shape)
    lost = u < loss_prob
    fallback = previous if lost_action == "previous" else jnp.full_like(indices, idle_index)
    return jnp.where(lost, fallback, indices), lost


def communicating_act(
    env: ChargaxMARL,
    choose,
    delay_steps: int = 0,
    loss_prob: float = 0.0,
    lost_action: str = "previous",
) -> MemoryAct:
    """A multi-agent policy played on whole days as the wrappers play it: the agents see the
    observations `DelayedObservationWrapper` shows and their actions are lost as
    `ActionLossWrapper` loses them, so `chargax_marl.evaluation.run_days` scores a
    policy trained through them under the same communication.

    The policy's memory is the history of the last ``delay_steps`` observations (the day's
    first observation until then) and the action indices the ports applied last step (idle at
    the day's start). The loss draws come from ``fold_in(key, LOSS_STREAM)`` of the policy's
    step key, so ``choose`` sees the key itself; with ``delay_steps=0`` and ``loss_prob=0``
    the policy is ``choose`` on the plain observations.

    Args:
        env: the multi-agent view of the station played (its observation layout and action
            offset).
        choose: ``choose(obs, state, key) -> (num_agents,)`` action indices, from the stacked
            observations ``(num_agents, obs_size)`` the agents see and the simulator state.
        delay_steps: ``k >= 0``, how many steps late the delayed columns are seen.
        loss_prob: the probability in ``[0, 1]`` that an agent's action is lost.
        lost_action: ``"previous"`` or ``"idle"``, what a port applies instead.

    Returns:
        A `chargax_marl.evaluation.MemoryAct` giving the core's signed levels.

    Raises:
        ValueError: a bad delay, probability or lost action.
    """
    delay_steps = check_delay_steps(delay_steps)
    loss_prob, lost_action = check_loss(loss_prob, lost_action)
    columns = delayed_columns(env)
    idle = int(env.action_offset)
    params = env.params

    def init(state):
        history = start_history(env.get_obs_matrix(state), delay_steps)
        return history, jnp.full((env.num_agents,), idle, jnp.int32)

    def step(state, key, memory):
        history, previous = memory
        seen, history = delay(env.get_obs_matrix(state), history, columns, jnp.bool_(False))
        sent = jnp.asarray(choose(seen, state, key)).astype(jnp.int32)
        applied, _ = lose_actions(key, sent, previous, idle, loss_prob, lost_action)
        return actions_to_levels(applied, params, idle), (history, applied)

    return MemoryAct(init=init, step=step)


def _stack(env, obs: dict) -> jax.Array:
    return jnp.stack([obs[a] for a in env.agents])


def _unstack(env, obs: dict, matrix: jax.Array) -> dict:
    out = dict(obs)  # keeps any entry that is not an agent's (e.g. "world_state")
    out.update({a: matrix[i] for i, a in enumerate(env.agents)})
    return out


@struct.dataclass
class DelayState:
    """The wrapped env's state and the observations of the last ``delay_steps`` steps.

    Attributes:
        env_state: the wrapped env's state.
        history: ``(delay_steps, num_agents, obs_size)`` the observations of the last
            ``delay_steps`` steps, oldest first (`delay`).
    """

    env_state: Any
    history: jnp.ndarray  # (delay_steps, num_agents, obs_size), oldest first


class DelayedObservationWrapper(_Wrapper):
    """Observations delayed by ``delay_steps`` steps for the context and the node loads.

    Each agent's own port features stay current; the shared context and its ancestor nodes'
    loads (the columns of `delayed_columns`) are those of ``delay_steps`` steps before
    (the day's first observation while fewer steps have passed). ``delay_steps=0`` is the
    wrapped env bit for bit. Wrap `chargax_marl.marl.ChargaxMARL` (or an
    `ActionLossWrapper` of it) and put the MAPPO or logging wrappers outside, whose
    centralised world state stays current.

    Args:
        env: the multi-agent env.
        delay_steps: the delay in steps (``>= 0``).

    Raises:
        ValueError: a negative or non-integer ``delay_steps``.
    """

    def __init__(self, env, delay_steps: int = 1):
        super().__init__(env)
        self.delay_steps = check_delay_steps(delay_steps)
        self._columns = delayed_columns(_base(env))

    @functools.partial(jax.jit, static_argnums=(0,))
    def reset(self, key: jax.Array):
        obs, env_state = self._env.reset(key)
        history = start_history(_stack(self, obs), self.delay_steps)
        return obs, DelayState(env_state=env_state, history=history)

    @functools.partial(jax.jit, static_argnums=(0,))
    def _step(self, key: jax.Array, state: DelayState, actions: dict, reset_state=None):
        extra = () if reset_state is None else (reset_state,)
        obs, env_state, reward, done, info = self._env.step(key, state.env_state, actions, *extra)
        seen, history = delay(_stack(self, obs), state.history, self._columns, done["__all__"])
        state = DelayState(env_state=env_state, history=history)
        return _unstack(self, obs, seen), state, reward, done, info

    @functools.partial(jax.jit, static_argnums=(0,))
    def step_arrays(self, key: jax.Array, state: DelayState, indices: jax.Array, reset_state=None):
        """The wrapped env's ``step_arrays`` with the delayed observation matrix (the values
        of `step`, stacked).
        Arguments and returns as `chargax_marl.marl.ChargaxMARL.step_arrays`, with this
        wrapper's state.
        """
        obs, env_state, reward, done, info = self._env.step_arrays(
            key, state.env_state, indices, reset_state
        )
        seen, history = delay(obs, state.history, self._columns, done)
        return seen, DelayState(env_state=env_state, history=history), reward, done, info


@struct.dataclass
class ActionLossState:
    """The wrapped env's state and the action indices the ports applied last step.

    Attributes:
        env_state: the wrapped env's state.
        applied: ``(num_agents,)`` int32 the action indices the ports applied last step (idle
            at the start of a day).
    """

    env_state: Any
    applied: jnp.ndarray  # (num_agents,) int32


class ActionLossWrapper(_Wrapper):
    """Each agent's action lost with probability ``loss_prob``; the port then applies its
    previous action (``lost_action="previous"``, idle at the start of a day) or idles
    (``"idle"``). ``info["action_lost"]`` (``(num_agents,)`` bool) says which were lost.
    ``loss_prob=0`` is the wrapped env bit for bit.

    Args:
        env: the multi-agent env.
        loss_prob: the probability in ``[0, 1]`` that an agent's action is lost.
        lost_action: ``"previous"`` or ``"idle"``.

    Raises:
        ValueError: ``loss_prob`` outside ``[0, 1]`` or an unknown ``lost_action``.
    """

    def __init__(self, env, loss_prob: float = 0.1, lost_action: str = "previous"):
        super().__init__(env)
        self.loss_prob, self.lost_action = check_loss(loss_prob, lost_action)
        self._idle = int(_base(env).action_offset)

    def _idle_indices(self) -> jax.Array:
        return jnp.full((self._env.num_agents,), self._idle, jnp.int32)

    @functools.partial(jax.jit, static_argnums=(0,))
    def reset(self, key: jax.Array):
        obs, env_state = self._env.reset(key)
        return obs, ActionLossState(env_state=env_state, applied=self._idle_indices())

    @functools.partial(jax.jit, static_argnums=(0,))
    def _step(self, key: jax.Array, state: ActionLossState, actions: dict, reset_state=None):
        # the env's own reading of the dict: clipped int32 indices, NaN idle
        sent = _base(self._env)._stack([actions[a] for a in self.agents])
        applied, lost = lose_actions(
            key, sent, state.applied, self._idle, self.loss_prob, self.lost_action
        )
        extra = () if reset_state is None else (reset_state,)
        obs, env_state, reward, done, info = self._env.step(
            key, state.env_state, dict(zip(self.agents, applied)), *extra
        )
        applied = jnp.where(done["__all__"], self._idle_indices(), applied)
        info = {**info, "action_lost": lost}
        return obs, ActionLossState(env_state=env_state, applied=applied), reward, done, info

    @functools.partial(jax.jit, static_argnums=(0,))
    def step_arrays(
        self, key: jax.Array, state: ActionLossState, indices: jax.Array, reset_state=None
    ):
        """The wrapped env's ``step_arrays`` with each action lost with probability
        ``loss_prob`` (the values of `step`, stacked).
        Arguments and returns as `chargax_marl.marl.ChargaxMARL.step_arrays`, with this
        wrapper's state.
        """
        base = _base(self._env)
        sent = core_actions.to_int32(indices, 0, base.num_actions - 1, base.action_offset)
        applied, lost = lose_actions(
            key, sent, state.applied, self._idle, self.loss_prob, self.lost_action
        )
        obs, env_state, reward, done, info = self._env.step_arrays(
            key, state.env_state, applied, reset_state
        )
        applied = jnp.where(done, self._idle_indices(), applied)
        info = {**info, "action_lost": lost}
        return obs, ActionLossState(env_state=env_state, applied=applied), reward, done, info


def _base(env) -> ChargaxMARL:
    """The `ChargaxMARL` under any wrappers."""
    while not isinstance(env, ChargaxMARL):
        env = env._env
    return env
