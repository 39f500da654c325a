"""Action wrappers: how the agents' actions become the core's levels where nodes couple them.

`PriorityFill` turns the multi-agent view's charging actions into priorities and fills each
node's capacity in that order (`priority_fill_levels`), so the env's proportional rescale of
an overloaded node never applies. With ``num_priorities`` the agents choose among a few
priority classes (`priority_class_levels`) while the fill grants power at the env's own,
finer levels.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from gymnax.environments import spaces

from chargax_marl.core import actions as core_actions
from chargax_marl.core import checks
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.core.types import EnvParams, EnvState
from chargax_marl.marl.env import action_offset, actions_to_levels, levels_to_indices, min_levels
from chargax_marl.policies import fill_in_priority_order
from chargax_marl.teachers.fill import able_kw
from chargax_marl.teachers.shaping import core_state
from chargax_marl.wrappers.base import TeacherWrapper

DEPARTURE_TIE_BREAK_MIN = 1e5
"""The weight of one priority step against the minutes to a car's planned departure, which
break ties within a priority (a day holds far fewer minutes)."""


def priority_fill_levels(levels: jnp.ndarray, state: EnvState, params: EnvParams) -> jnp.ndarray:
    """The levels the multi-agent view's levels become under `PriorityFill`.

    A port's charging level ``k`` in ``1..L`` is read as a priority: the cars asking to charge
    are served from the highest priority down (the car that leaves first first within a
    priority), each at the most power its car, its port and the headroom left on every node of
    its path allow, rounded down to a level where a node binds
    (`chargax_marl.policies.fill_in_priority_order`). Idle and discharging levels, and every
    battery's level, are played as given; the grid-side power the batteries' charging levels
    can take is kept from the ports first. So no node is asked for more than its limit.

    Args:
        levels: ``(num_leaves,)`` signed levels in ``[-L, L]``, as the view's actions give
            them (`chargax_marl.marl.ChargaxMARL.actions_to_levels`).
        state: the simulator state (one day, unbatched).
        params: the environment parameters.

    Returns:
        ``(num_leaves,)`` int32 levels in ``[-L, L]``.
    """
    st = params.station
    levels = jnp.asarray(levels, jnp.int32)
    is_battery = st.leaf_kind == KIND_BATTERY
    charging = (levels > 0) & ~is_battery
    priority = jnp.where(
        charging,
        (params.num_levels - levels) * DEPARTURE_TIE_BREAK_MIN + state.time_remaining_min,
        jnp.inf,
    )
    # the batteries' charging draw at their level, grid side at each node of their path
    battery_kw = jnp.where(is_battery & (levels > 0), levels / params.num_levels, 0.0)
    battery_kw = battery_kw * st.leaf_max_kw
    ancestors = st.node_of_leaf_at_depth  # (D, L), -1 = none
    grid_side = jnp.where(ancestors >= 0, battery_kw / st.leaf_efficiency_at_depth, 0.0)
    taken = jnp.zeros_like(st.node_max_kw).at[jnp.maximum(ancestors, 0)].add(grid_side)
    filled = fill_in_priority_order(priority, state, params, st.node_max_kw - taken)
    return jnp.where(charging, filled, levels).astype(jnp.int32)


def priority_class_size(params: EnvParams, num_priorities: int) -> tuple[int, int]:
    """The agents' ``Discrete(n)`` size and idle index when they choose among
    ``num_priorities`` charging classes (`priority_class_levels`).

    Args:
        params: the environment parameters (concrete).
        num_priorities: the number of charging classes, at least 1.

    Returns:
        ``(n, idle_index)``: ``n = idle_index + 1 + num_priorities``; ``idle_index`` is 1
        where some leaf may discharge (index 0 is then full discharge), else 0.

    Raises:
        ValueError: ``num_priorities`` not an integer >= 1.
    """
    checks.number("num_priorities", num_priorities, low=1, integer=True)
    with jax.ensure_compile_time_eval():  # concrete params inside a traced step
        idle = 1 if action_offset(params) > 0 else 0
    return idle + 1 + int(num_priorities), idle


def priority_class_levels(
    indices: jnp.ndarray, state: EnvState, params: EnvParams, num_priorities: int
) -> jnp.ndarray:
    """The levels played for agents that choose a priority class instead of a level.

    Each agent's index (``Discrete(n)`` of `priority_class_size`) means: below the idle index,
    full discharge (``-L``; idle for a leaf that cannot discharge); the idle index, idle;
    ``idle + k`` for ``k`` in ``1..num_priorities``, charge with priority ``k``. The charging
    leaves are served from the highest class down, each at the most power it can take (a
    car: its port, its rate curve and its room to its target; a battery: the same to full)
    and every node of its path still allows, rounded down to one of the env's own ``L``
    levels where a node binds. Within a class the ports go first, the car that leaves first
    first, then the batteries: a battery's charging takes what the cars of its class leave,
    and comes before the cars of lower classes. Indices outside ``[0, n)`` are clipped into
    it.

    Args:
        indices: ``(num_leaves,)`` integer class indices, one per agent.
        state: the simulator state (one day, unbatched).
        params: the environment parameters (concrete: the class count reads the station).
        num_priorities: the number of charging classes, at least 1.

    Returns:
        ``(num_leaves,)`` int32 levels in ``[-L, L]``.
    """
    n, idle = priority_class_size(params, num_priorities)
    indices = core_actions.to_int32(jnp.asarray(indices), 0, n - 1, idle)
    rank = jnp.maximum(indices - idle, 0)
    is_battery = params.station.leaf_kind == KIND_BATTERY
    discharge = jnp.maximum(-params.num_levels, min_levels(params))
    given = jnp.where(indices < idle, discharge, 0).astype(jnp.int32)
    # within a class: the ports by departure (minutes < the tie-break), then the batteries
    later = jnp.where(is_battery, DEPARTURE_TIE_BREAK_MIN - 1.0, state.time_remaining_min)
    priority = jnp.where(rank > 0, -rank * DEPARTURE_TIE_BREAK_MIN + later, jnp.inf)
    want_kw = able_kw(state, params, batteries=True)
    filled = fill_in_priority_order(priority, state, params, want_kw=want_kw)
    return jnp.where(rank > 0, filled, given).astype(jnp.int32)


class PriorityFill(TeacherWrapper):
    """Charging actions as priorities, filled into each node's capacity in priority order.

    For the JaxMARL view (`chargax_marl.marl.ChargaxMARL`, possibly wrapped), in the
    ``absolute`` action mode. The step serves the charging cars from the highest priority down
    (ties to the car that leaves first), each at the most power the car, its port and every
    node of its path still allow, so a node that holds two cars of three serves the two with
    the highest priority fully rather than all three at two thirds. Every agent choosing to
    charge at its top priority is earliest-deadline-first for the ports.

    Two action spaces:

    - ``num_priorities=None``: every agent keeps the view's ``Discrete(n)`` space. A port
      agent's charging index (the view's level ``k`` in ``1..L``) asks for power with priority
      ``k`` (`priority_fill_levels`); idle and discharging indices, and the battery agents'
      indices, mean what they mean in the view. A car that a node cannot serve at its full
      want gets the level below what the node has left; with one level per direction
      (``num_levels = 1``) that is idle, so on a tight connection most cars get nothing where
      the view's rescale would share the power.
    - ``num_priorities=P``: every agent chooses among full discharge, idle and ``P``
      charging classes (``Discrete(P + 2)``, or ``P + 1`` where no leaf can discharge:
      `priority_class_size`), and the fill grants power at the wrapped env's own ``L``
      levels (`priority_class_levels`); a battery's charging joins the fill in its class,
      after that class's cars. Wrap an env with fine levels (a task's own) to give
      the agents a small action set whose partial grants are still played.

    The wrapper is part of the policy it plays: score a policy trained through it with the
    same mapping (``kind="core"``: ``priority_fill_levels(env.actions_to_levels(act(obs,
    key)), state, params)``, or `priority_class_levels` of its indices). Other wrappers go on
    top of it or under it; it reads the core state under any wrapper state.

    Args:
        env: a `chargax_marl.marl.ChargaxMARL`, possibly wrapped.
        num_priorities: None, or the number of charging classes (a positive integer).

    Raises:
        TypeError: ``env`` is the gymnax view (no agents).
        ValueError: the env's action mode is not ``absolute`` (a level is then a change, not
            a power to grant), or ``num_priorities`` is not a positive integer.
    """

    def __init__(self, env, num_priorities: int | None = None):
        super().__init__(env)
        if not self.is_marl:
            raise TypeError(
                "PriorityFill: field 'env' must be the JaxMARL view (ChargaxMARL, possibly "
                f"wrapped), got {type(env).__name__}"
            )
        params = self.env_params
        if params.action_mode != "absolute":
            raise ValueError(
                "PriorityFill: field 'action_mode' of the env must be 'absolute' (levels are "
                f"powers to grant), got {params.action_mode!r}"
            )
        if num_priorities is not None and (
            isinstance(num_priorities, bool)
            or not isinstance(num_priorities, (int, np.integer))
            or num_priorities < 1
        ):
            raise ValueError(
                "PriorityFill: field 'num_priorities' must be None or a positive integer, got "
                f"{num_priorities!r}"
            )
        self._offset = int(env.action_offset)
        self.num_priorities = None if num_priorities is None else int(num_priorities)
        if self.num_priorities is not None:
            n, idle = priority_class_size(params, self.num_priorities)
            # the agents' own space: read by the trainers and JaxMARL's code through the wrapper
            self.num_actions, self.action_offset = n, idle
            self.action_spaces = {a: spaces.Discrete(n) for a in env.agents}
            classes = np.arange(n)[None, :]
            can_discharge = np.asarray(min_levels(params))[:, None] < 0
            self._avail_np = (classes >= idle) | can_discharge

    def action_space(self, agent: str):
        """The agent's ``Discrete`` space (the view's, or the classes' with ``num_priorities``).

        Args:
            agent: an agent name.

        Returns:
            The wrapped env's space without ``num_priorities``; with it
            ``Discrete(n)`` of `priority_class_size`.
        """
        if self.num_priorities is None:
            return self._env.action_space(agent)
        return self.action_spaces[agent]

    def get_avail_actions(self, state) -> dict:
        """Bool mask per agent; with ``num_priorities``, ``False`` only at full discharge for a
        leaf that cannot discharge.

        Args:
            state: the env state (the mask does not depend on it).

        Returns:
            ``{agent: (n,) bool}``: the wrapped env's masks without ``num_priorities``.
        """
        if self.num_priorities is None:
            return self._env.get_avail_actions(state)
        return {a: jnp.asarray(self._avail_np[i]) for i, a in enumerate(self._env.agents)}

    def actions_to_levels(self, actions):
        """The view's mapping of actions to levels; refused with ``num_priorities``, where an
        action's level depends on the state (use `levels`).

        Args:
            actions: an action dict or ``(num_agents,)`` index vector of the view.

        Returns:
            The wrapped env's ``(num_agents,)`` levels of ``actions``, before the fill.

        Raises:
            NotImplementedError: with ``num_priorities``.
        """
        if self.num_priorities is not None:
            raise NotImplementedError(
                "PriorityFill(num_priorities=...): an action's level depends on the state; use "
                "levels(state, indices) (priority_class_levels)"
            )
        return self._env.actions_to_levels(actions)

    def levels_to_actions(self, levels):
        """The view's mapping of levels to actions; refused with ``num_priorities``, whose
        agents choose classes, not levels.

        Args:
            levels: ``(num_agents,)`` valid signed levels.

        Returns:
            The wrapped env's action dict for ``levels``.

        Raises:
            NotImplementedError: with ``num_priorities``.
        """
        if self.num_priorities is not None:
            raise NotImplementedError(
                "PriorityFill(num_priorities=...): the agents choose priority classes, not "
                "levels; there is no action for a level"
            )
        return self._env.levels_to_actions(levels)

    def levels(self, state, indices: jnp.ndarray) -> jnp.ndarray:
        """The core levels ``(num_agents,)`` played for the agents' ``indices`` in ``state`` (a
        core or wrapper state).

        Args:
            state: the core state or a wrapper's state holding one.
            indices: ``(num_agents,)`` the agents' action indices, in agent order.

        Returns:
            ``(num_agents,)`` int32 levels in ``[-L, L]``: `priority_fill_levels` of the view's
            levels, or with ``num_priorities`` `priority_class_levels`.
        """
        params = self.env_params
        core = core_state(state)
        if self.num_priorities is not None:
            return priority_class_levels(indices, core, params, self.num_priorities)
        levels = actions_to_levels(jnp.asarray(indices), params, self._offset)
        return priority_fill_levels(levels, core, params)

    def fill(self, state, indices: jnp.ndarray) -> jnp.ndarray:
        """The action indices ``(num_agents,)`` the wrapped env is stepped with for the agents'
        ``indices`` in ``state`` (a core or wrapper state).

        Args:
            state: the core state or a wrapper's state holding one.
            indices: ``(num_agents,)`` the agents' action indices, in agent order.

        Returns:
            ``(num_agents,)`` int32 indices of the wrapped env's space, those of `levels`.
        """
        return levels_to_indices(self.levels(state, indices), self.env_params, self._offset)

    def _stack(self, actions: dict) -> jnp.ndarray:
        """The action dict in agent order: the view's clipped indices, or with
        ``num_priorities`` the validated values as given (`priority_class_levels` clips them
        into the classes and reads a non-finite value as idle)."""
        if self.num_priorities is None:
            return self._env.stack_actions(actions)
        parts = self._env.validate_actions(actions)
        return jnp.stack([jnp.asarray(x).reshape(()) for x in parts])

    def step(self, key, state, actions: dict, reset_state=None):
        """The wrapped env's ``step`` with the actions filled (`fill`).

        Args:
            key: the step's key.
            state: the wrapped env's state.
            actions: ``{agent: index}``, one entry per agent, in this wrapper's space.
            reset_state: the fresh day's state at the end of a day (None: a random one).

        Returns:
            ``(obs, state, rewards, dones, infos)`` of the wrapped env's step.

        Raises:
            ValueError: a bad action dict (`chargax_marl.marl.ChargaxMARL.validate_actions`).
        """
        indices = self.fill(state, self._stack(actions))
        filled = dict(zip(self._env.agents, indices))
        if reset_state is None:
            return self._env.step(key, state, filled)
        return self._env.step(key, state, filled, reset_state)

    def step_arrays(self, key, state, indices, reset_state=None):
        """The wrapped env's ``step_arrays`` with the actions filled (`fill`).
        Arguments and returns as `chargax_marl.marl.ChargaxMARL.step_arrays`, with this
        wrapper's state.

        Args:
            key: the step's key.
            state: the wrapped env's state.
            indices: ``(num_agents,)`` action indices in this wrapper's space, agent order.
            reset_state: the fresh day's state at the end of a day (None: a random one).

        Returns:
            ``(obs, state, rewards, done, info)`` of the wrapped env's ``step_arrays``.
        """
        return self._env.step_arrays(key, state, self.fill(state, indices), reset_state)


__all__ = [
    "DEPARTURE_TIE_BREAK_MIN",
    "PriorityFill",
    "priority_class_levels",
    "priority_class_size",
    "priority_fill_levels",
]
