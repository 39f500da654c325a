"""Action wrappers: how the agents' actions become the core's levels where nodes couple them.

`PriorityFill` turns the multi-agent view's charging actions into priorities and fills each
node's capacity in that order (`priority_fill_levels`), so the env's proportional rescale of
an overloaded node never applies.
"""

from __future__ import annotations

import jax.numpy as jnp

from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.core.types import EnvParams, EnvState
from chargax_marl.marl.env import actions_to_levels, levels_to_indices
from chargax_marl.policies import fill_in_priority_order
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


class PriorityFill(TeacherWrapper):
    """Charging actions as priorities, filled into each node's capacity in priority order.

    For the JaxMARL view (`chargax_marl.marl.ChargaxMARL`, possibly wrapped); every agent
    keeps its ``Discrete(n)`` space. A port agent's charging index (the view's level ``k`` in
    ``1..L``) asks for power with priority ``k``; idle and discharging indices, and the battery
    agents' indices, mean what they mean in the view. The step plays
    `priority_fill_levels`: the charging cars are served from the highest priority down (ties
    to the car that leaves first), each at the most power the car, its port and every node of
    its path still allow, so a node that holds two cars of three serves the two with the
    highest priority fully rather than all three at two thirds. Every agent choosing full
    power is earliest-deadline-first for the ports.

    A car that a node cannot serve at its priority's full want gets the level below what the
    node has left; with one level per direction (``num_levels = 1``) that is idle, so on a
    tight connection most cars get nothing where the view's rescale would share the power.
    Use it with the finer levels that let a partial grant be played.

    The wrapper is part of the policy it plays: score a policy trained through it with the
    same mapping (``kind="core"``: ``priority_fill_levels(env.actions_to_levels(act(obs,
    key)), state, params)``). Other wrappers go on top of it or under it; it reads the core
    state under any wrapper state.

    Args:
        env: a `chargax_marl.marl.ChargaxMARL`, possibly wrapped.

    Raises:
        TypeError: ``env`` is the gymnax view (no agents).
    """

    def __init__(self, env):
        super().__init__(env)
        if not self.is_marl:
            raise TypeError(
                "PriorityFill: field 'env' must be the JaxMARL view (ChargaxMARL, possibly "
                f"wrapped), got {type(env).__name__}"
            )
        self._offset = int(env.action_offset)

    def fill(self, state, indices: jnp.ndarray) -> jnp.ndarray:
        """The action indices ``(num_agents,)`` the wrapped env is stepped with for the agents'
        ``indices`` in ``state`` (a core or wrapper state)."""
        params = self.env_params
        levels = actions_to_levels(jnp.asarray(indices), params, self._offset)
        filled = priority_fill_levels(levels, core_state(state), params)
        return levels_to_indices(filled, params, self._offset)

    def step(self, key, state, actions: dict, reset_state=None):
        """The wrapped env's ``step`` with the actions filled (`fill`).

        Raises:
            ValueError: a bad action dict (`chargax_marl.marl.ChargaxMARL.validate_actions`).
        """
        indices = self.fill(state, self._env.stack_actions(actions))
        filled = dict(zip(self._env.agents, indices))
        if reset_state is None:
            return self._env.step(key, state, filled)
        return self._env.step(key, state, filled, reset_state)

    def step_arrays(self, key, state, indices, reset_state=None):
        """The wrapped env's ``step_arrays`` with the actions filled (`fill`).
        Arguments and returns as `chargax_marl.marl.ChargaxMARL.step_arrays`, with this
        wrapper's state.
        """
        return self._env.step_arrays(key, state, self.fill(state, indices), reset_state)


__all__ = ["DEPARTURE_TIE_BREAK_MIN", "PriorityFill", "priority_fill_levels"]
