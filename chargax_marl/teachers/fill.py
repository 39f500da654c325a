"""Serving leaves one after another within the headroom of every node on their path: the
scan behind the priority rules (`chargax_marl.policies.fill_in_priority_order`) and the
coupled plan's action (`chargax_marl.teachers.congestion.fill_planned_power`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from chargax_marl.core import physics
from chargax_marl.core.station import KIND_BATTERY


def able_kw(state, params, batteries: bool = False) -> jnp.ndarray:
    """What each leaf's car can take this step, ``(L,)`` kW: the least of its port's limit,
    its rate curve and its room to its target (0 at empty ports, and at batteries unless
    ``batteries``).

    Args:
        state: the simulator state (one day, unbatched).
        params: the environment parameters.
        batteries: also what each battery can take, by the same limits (its target is full).

    Returns:
        ``(L,)`` kW.
    """
    st = params.station
    room_kw = (
        jnp.maximum((state.target_soc - state.soc) * state.capacity_kwh, 0.0) / params.step_hours
    )
    curve = physics.rate_curve_kw(state.soc, state.max_rate_kw, state.tau)
    able = jnp.minimum(jnp.minimum(st.leaf_max_kw, curve), room_kw)
    return jnp.where(state.occupied & (batteries | (st.leaf_kind != KIND_BATTERY)), able, 0.0)


def serve_in_order(priority, headroom_kw, station, grant):
    """Serve the leaves in ``priority`` order (lower first), each taking from every node on
    its path the grid-side power of what it draws.

    Args:
        priority: ``(L,)`` the order of service (ties by leaf index).
        headroom_kw: ``(H,)`` grid-side kW each node may still pass.
        station: the compiled station.
        grant: ``grant(leaf, free_kw) -> (level, drawn_kw)``: the level the leaf gets when
            its path leaves ``free_kw`` at the leaf (kW), and the power it draws at that level.

    Returns:
        ``(levels (L,) int32, headroom_kw (H,))``: each leaf's level and the headroom left.
    """
    ancestors = station.node_of_leaf_at_depth.T  # (L, D), -1 = none
    path_eff = station.leaf_efficiency_at_depth.T  # leaf kW = grid-side kW * these

    def give(headroom, leaf):
        anc = ancestors[leaf]
        valid = anc >= 0
        eff = path_eff[leaf]
        free = jnp.min(jnp.where(valid, headroom[jnp.maximum(anc, 0)] * eff, jnp.inf))
        level, drawn = grant(leaf, free)
        headroom = headroom.at[jnp.maximum(anc, 0)].add(jnp.where(valid, -drawn / eff, 0.0))
        return headroom, level

    order = jnp.argsort(priority)
    headroom, given = jax.lax.scan(give, headroom_kw, order)
    return jnp.zeros(priority.shape, jnp.int32).at[order].set(given), headroom
