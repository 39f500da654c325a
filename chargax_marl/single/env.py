"""Single-agent view: one controller sets every port and battery (gymnax 1.0 API).

``reset(key, params) -> (obs, state)`` and
``step(key, state, action, params) -> (obs, state, reward, terminated, truncated, info)``
follow `gymnax.environments.environment.Environment` and auto-reset at the end of the
day. This file only maps actions and builds observations; the transition is
`chargax_marl.core.simulator.step` (``step_env``) and
`chargax_marl.core.simulator.step_auto_reset` (``step``), as in the multi-agent view.

Action (discrete modes): a ``MultiDiscrete`` vector with one entry per leaf (ports, then
batteries). Entry ``k`` of leaf ``i`` means level ``k + min_level_i`` where
``min_level_i = -L`` for leaves that may discharge and 0 otherwise, so with V2G on index
``L`` is idle and ``2L`` is full power. Out-of-range entries are clipped to the leaf's range.
Continuous mode: a ``Box(-1, 1, (L,))`` of current fractions.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from gymnax.environments import environment, spaces

from chargax_marl import bounds
from chargax_marl.core import actions, clock, observation, physics, simulator
from chargax_marl.core.params import make_params, validate_params
from chargax_marl.core.types import EnvParams, EnvState
from chargax_marl.lifecycle import check_day


class MultiDiscrete(spaces.Space):
    """A jittable vector of independent discrete choices, entry ``i`` in ``[0, nvec[i])``.

    ``nvec`` is a concrete numpy array (also inside ``jit``), so ``int(space.nvec[i])`` and
    ``space.nvec.max()`` can size a network's output layer.

    Args:
        nvec: the number of choices of each entry, shape ``(n,)``; stored as int32.
    """

    def __init__(self, nvec):
        self.nvec = np.asarray(nvec, np.int32)
        self.shape = (int(self.nvec.shape[0]),)
        self.dtype = jnp.int32

    def __repr__(self) -> str:
        return f"MultiDiscrete({[int(n) for n in self.nvec]})"

    def sample(self, key: jax.Array) -> jax.Array:
        """A uniformly random element of the space.

        Args:
            key: the JAX key of the draw.

        Returns:
            ``(n,)`` int32, entry ``i`` uniform in ``[0, nvec[i])``.
        """
        return jax.random.randint(key, self.shape, 0, self.nvec, self.dtype)

    def contains(self, x: jax.Array) -> jax.Array:
        """Whether ``x`` is an element of the space.

        Args:
            x: a candidate action.

        Returns:
            A ``()`` bool: ``x`` has shape ``(n,)`` and every entry lies in ``[0, nvec[i])``.
        """
        x = jnp.asarray(x)
        if x.shape != self.shape:  # static: any other shape is not an element
            return jnp.asarray(False)
        return jnp.all((x >= 0) & (x < self.nvec))


def action_levels(action: jnp.ndarray, params: EnvParams) -> jnp.ndarray:
    """The core's per-leaf levels (or fractions) of an action array of the single-agent space.

    Traceable. Indices outside the space are clipped into it (host integers beyond int32 on
    the host first, `chargax_marl.core.actions.host_array`); NaN and +-inf entries are
    the index of idle (level 0).

    Args:
        action: ``(num_leaves,)`` indices of the ``MultiDiscrete`` space, or fractions in
            ``[-1, 1]`` in continuous mode.
        params: the environment parameters.

    Returns:
        The ``(num_leaves,)`` int32 levels (float32 fractions in continuous mode).
    """
    n = params.station.num_leaves
    action = jnp.reshape(jnp.asarray(actions.host_array(action, n)), (n,))
    if params.action_mode == "continuous":
        return actions.to_fraction(action)
    if params.action_mode == "delta":
        idle = params.num_levels
        return actions.to_int32(action, 0, 2 * params.num_levels, idle) - params.num_levels
    min_level = physics.leaf_min_level(params.station, params.num_levels, params.v2g)
    return actions.to_int32(action, 0, params.num_levels - min_level, -min_level) + min_level


class Chargax(environment.Environment[EnvState, EnvParams]):
    """The EV charging station as a gymnax environment.

    The defaults are the paper's: the 16-port ``multiple_types`` station, 5-minute steps over
    one day (288), 10 levels, V2G on, customer price 0.75 EUR/kWh, all alpha 0, shopping
    users at medium traffic, EU fleet, NL-2023 prices.

    Args:
        params: ready parameters, checked by `chargax_marl.core.params.validate_params` (so
            params derived with ``replace`` get the same checks); None: built from
            ``overrides``.
        **overrides: keyword arguments of `chargax_marl.core.params.make_params` (its
            ``Args:`` list them all).

    Raises:
        ValueError: both ``params`` and ``overrides`` given, or an invalid field (the message
            names it).
        KeyError: an unknown architecture, dataset or traffic level name (`make_params`).
        TypeError: a keyword `make_params` does not take.
    """

    def __init__(self, params: EnvParams | None = None, **overrides: Any):
        super().__init__()
        if params is not None and overrides:
            raise ValueError("Chargax: pass either 'params' or keyword overrides, not both")
        self._params = validate_params(params) if params is not None else make_params(**overrides)

    @property
    def default_params(self) -> EnvParams:
        return self._params

    # ------------------------------------------------------------------ actions
    def min_level(self, params: EnvParams | None = None) -> jnp.ndarray:
        """The lowest level of each leaf in the ``absolute`` mode's action mapping.

        Args:
            params: the environment parameters; None: the construction's.

        Returns:
            ``(num_leaves,)`` int32: ``-num_levels`` for a leaf that may discharge (batteries;
            ports with V2G), else 0.
        """
        params = params or self._params
        return physics.leaf_min_level(params.station, params.num_levels, params.v2g)

    def action_to_levels(self, action: jnp.ndarray, params: EnvParams) -> jnp.ndarray:
        """Map an action of this env's space (host or jax values) to the core's per-leaf levels.

        The host action is checked and clipped into int32 / float32 first
        (`chargax_marl.core.actions.host_array`), then mapped by `action_levels`.

        Args:
            action: ``(num_leaves,)`` indices of `action_space`, or fractions in ``[-1, 1]``
                in continuous mode.
            params: the environment parameters.

        Returns:
            ``(num_leaves,)`` int32 signed levels (float32 fractions in continuous mode).

        Raises:
            ValueError: the action does not have one entry per leaf or is not numeric.
        """
        return action_levels(actions.host_array(action, params.station.num_leaves), params)

    def levels_to_action(self, levels: jnp.ndarray, params: EnvParams | None = None) -> jnp.ndarray:
        """Inverse of `action_to_levels` (for rule-based policies written in levels).

        Args:
            levels: ``(num_leaves,)`` valid signed levels (fractions in continuous mode); not
                checked.
            params: the environment parameters; None: the construction's.

        Returns:
            ``(num_leaves,)`` the action: int32 indices (``level + num_levels`` in ``delta``
            mode, ``level - min_level`` in ``absolute`` mode), or the float32 fractions in
            continuous mode.
        """
        params = params or self._params
        if params.action_mode == "continuous":
            return jnp.asarray(levels, jnp.float32)
        if params.action_mode == "delta":
            return jnp.asarray(levels, jnp.int32) + params.num_levels
        return jnp.asarray(levels, jnp.int32) - self.min_level(params)

    # ------------------------------------------------------------------ dynamics
    def step_env(self, key: jax.Array, state: EnvState, action: jnp.ndarray, params: EnvParams):
        """One transition without auto-reset (gymnax's ``step_env``).

        Args:
            key: the step's key.
            state: the state to step.
            action: an action of `action_space` (`action_to_levels`).
            params: the environment parameters.

        Returns:
            ``(obs, state, reward, terminated, info)``: the stepped state's observation, the
            stepped state (not reset at the day's end), the step's reward, ``terminated``
            always False (the day's end is `is_truncated`), and
            `chargax_marl.core.simulator.info_dict`.

        Raises:
            ValueError: the action does not have one entry per leaf or is not numeric.
        """
        new_state, info = simulator.step(key, state, self.action_to_levels(action, params), params)
        obs = self.get_obs(new_state, params)
        info_dict = simulator.info_dict(info, new_state, params)
        return obs, new_state, info.reward, jnp.asarray(False), info_dict

    def step(
        self, key: jax.Array, state: EnvState, action: jnp.ndarray, params: EnvParams | None = None
    ):
        """gymnax's auto-resetting step: ``(obs, state, reward, terminated, truncated, info)``.

        The host action (numpy, list, Python numbers) is checked and clipped into int32 /
        float32 here, once, before it enters ``jit``
        (`chargax_marl.core.actions.host_array`), so a large host integer clips instead
        of wrapping. Under a caller's own ``jax.jit`` of this method JAX converts the
        arguments at the jit boundary, before this code runs: with ``JAX_ENABLE_X64`` off a
        numpy ``int64`` beyond int32 wraps there and a Python ``int`` beyond int32 raises
        JAX's ``OverflowError``; call ``step`` outside ``jit`` (it jits itself) or clip with
        `chargax_marl.core.actions.host_array` first. The transition is
        `chargax_marl.core.simulator.step_auto_reset`;
        the observation is built once, from the state it returns. ``info`` is
        `chargax_marl.core.simulator.info_dict` plus gymnax's ``terminated``,
        ``truncated`` and ``final_observation`` (the observation before the reset, computed
        only when a caller uses it).

        Args:
            key: the step's key.
            state: the state to step.
            action: an action of `action_space`, host or JAX values.
            params: the environment parameters; None: `default_params`.

        Returns:
            ``(obs, state, reward, terminated, truncated, info)``: the observation and state
            (a fresh day's after the day's last step), the step's reward, ``terminated``
            always False, ``truncated`` True on the day's last step, and ``info``.

        Raises:
            ValueError: the action does not have one entry per leaf or is not numeric.
        """
        n = (params or self.default_params).station.num_leaves
        return self._step(key, state, actions.host_array(action, n), params)

    @functools.partial(jax.jit, static_argnames=("self",))
    def _step(
        self, key: jax.Array, state: EnvState, action: jnp.ndarray, params: EnvParams | None = None
    ):
        params = self.default_params if params is None else params
        levels = action_levels(action, params)
        next_state, stepped, core_info, done = simulator.step_auto_reset(key, state, levels, params)
        terminated = jnp.asarray(False)
        info = {
            **simulator.info_dict(core_info, stepped, params),
            "terminated": terminated,
            "truncated": done,
            "final_observation": self.get_obs(stepped, params),
        }
        obs = self.get_obs(next_state, params)
        return obs, next_state, core_info.reward, terminated, done, info

    def reset_env(self, key: jax.Array, params: EnvParams):
        """Start an empty station on a random day (gymnax's ``reset_env``).

        Args:
            key: draws the day (of ``params.reset_days``) and the batteries' initial SoC
                (`chargax_marl.core.simulator.reset`).
            params: the environment parameters.

        Returns:
            ``(obs, state)``: the observation and the state at step 0.
        """
        state = simulator.reset(key, params)
        return self.get_obs(state, params), state

    def reset_to_day(self, day: int | jax.Array, params: EnvParams | None = None):
        """Start an empty station on a chosen day (for evaluation on fixed held-out days).

        Args:
            day: the day index, a Python int or a JAX scalar (a traced day is not checked).
            params: the environment parameters; None: the construction's.

        Returns:
            ``(obs, state)``: the observation and the state at step 0 of ``day``.

        Raises:
            ValueError: a concrete day that is not a day an episode can start on, outside
                ``[0, num_days)`` or, when episodes start after midnight, the data's last
                day (`chargax_marl.lifecycle.check_day`,
                `chargax_marl.core.clock.num_episode_starts`).
        """
        params = params or self._params
        if not isinstance(day, jax.core.Tracer):
            check_day(day, clock.num_episode_starts(params))
        state = simulator.empty_state(jnp.asarray(day, jnp.int32), params)
        return self.get_obs(state, params), state

    def get_obs(self, state: EnvState, params: EnvParams | None = None, key=None) -> jnp.ndarray:
        """The single-agent observation of a state.

        Args:
            state: the env state.
            params: the environment parameters; None: the construction's.
            key: unused (gymnax's ``get_obs`` signature).

        Returns:
            ``(obs_size,)`` float32, `chargax_marl.core.observation.flat_obs`: ports, then
            batteries, then context.
        """
        return observation.flat_obs(state, params or self._params)

    def obs_dict(self, state: EnvState, params: EnvParams | None = None) -> dict:
        """The observation's named parts: ``ports``, ``batteries``, ``context``.

        Args:
            state: the env state.
            params: the environment parameters; None: the construction's.

        Returns:
            ``{"ports", "batteries", "context"}`` arrays
            (`chargax_marl.core.observation.obs_dict`), whose flattened concatenation is
            `get_obs`.
        """
        return observation.obs_dict(state, params or self._params)

    def is_truncated(self, state: EnvState, params: EnvParams) -> jax.Array:
        """Whether the day is over (gymnax's truncation).

        Args:
            state: the env state.
            params: the environment parameters.

        Returns:
            A ``()`` bool: ``state.timestep >= num_steps * episode_days``.
        """
        return simulator.is_done(state, params)

    def is_terminated(self, state: EnvState, params: EnvParams) -> jax.Array:
        """Whether the episode ended naturally: never (a day only ends by truncation).

        Args:
            state: the env state (unused).
            params: the environment parameters (unused).

        Returns:
            A ``()`` bool, False.
        """
        return jnp.asarray(False)

    # ------------------------------------------------------------------ spaces
    @property
    def name(self) -> str:
        return "Chargax"

    @property
    def num_leaves(self) -> int:
        """Number of action entries: ports, then batteries."""
        return self._params.station.num_leaves

    @property
    def num_actions(self) -> int:
        """gymnax's meaning: the size of one discrete choice. Here the number of choices of
        each action entry, ``max(action_space().nvec)`` (``2L+1`` with V2G or a battery): a
        factored policy head has ``num_leaves x num_actions`` logits. In continuous mode the
        action dimension (``num_leaves``), as for gymnax's continuous envs. For a single
        ``Discrete`` space use `chargax_marl.single.FlatDiscrete`."""
        space = self.action_space(self._params)
        if self._params.action_mode == "continuous":
            return int(space.shape[0])
        return int(space.nvec.max())

    def _concrete(self, params: EnvParams) -> EnvParams:
        # Space sizes depend on station arrays: inside jit with traced params read them from
        # the construction params (a different station layout would not trace anyway).
        if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(params.station)):
            return self._params
        return params

    def action_space(self, params: EnvParams | None = None):
        """The action space, sized from the station (concrete also inside ``jit``).

        Args:
            params: the environment parameters; None, or traced station arrays: the
                construction's.

        Returns:
            ``Box(-1, 1, (num_leaves,))`` float32 fractions in continuous mode;
            `MultiDiscrete` with ``2L+1`` choices per leaf in ``delta`` mode, and with
            ``L + 1 - min_level`` choices per leaf in ``absolute`` mode (`min_level`).
        """
        params = self._concrete(params or self._params)
        n = params.station.num_leaves
        if params.action_mode == "continuous":
            return spaces.Box(-1.0, 1.0, (n,), jnp.float32)
        if params.action_mode == "delta":
            return MultiDiscrete(np.full((n,), 2 * params.num_levels + 1))
        with jax.ensure_compile_time_eval():  # concrete sizes also while tracing
            return MultiDiscrete(params.num_levels + 1 - np.asarray(self.min_level(params)))

    def observation_space(self, params: EnvParams | None = None):
        """``Box(low, high)`` with finite bounds the observations respect (`chargax_marl.bounds`).

        Args:
            params: the environment parameters; None, or traced station arrays: the
                construction's.

        Returns:
            ``Box(low, high, (obs_size,), float32)`` (`chargax_marl.bounds.flat_obs_bounds`).
        """
        params = self._concrete(params or self._params)
        low, high = bounds.flat_obs_bounds(params)
        return spaces.Box(low, high, (observation.obs_size(params),), jnp.float32)
