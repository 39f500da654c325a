"""Physics of one step: actions to currents, rate curves, node limits, charging, energy flows.

This module is the only place that turns currents into power and energy. All functions are
pure and jittable; there is no Python loop over ports or nodes (only over tree depth, a
static number of levels).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from chargax_marl.core import actions, rng
from chargax_marl.core.station import KIND_BATTERY, StationArrays
from chargax_marl.core.types import EnvParams, EnvState

CANCEL_MARGIN = 1e-5
"""The share of a node's cancelling grid-side power (gross minus net flow) that the hard rescale
adds to the net flow before comparing it with the limit: it covers the float32 rounding of the
opposite leaf flows, which is relative to those flows and not to their small difference."""


def rate_curve_kw(soc: jnp.ndarray, max_rate_kw: jnp.ndarray, tau: jnp.ndarray) -> jnp.ndarray:
    """Charging rate limit r-hat(SoC): ``r-bar`` up to ``tau``, then a linear taper to 0 at SoC 1.

    The arguments broadcast against each other (per leaf ``(num_leaves,)`` in the step).

    Args:
        soc: state of charge in [0, 1].
        max_rate_kw: r-bar, the rate limit below ``tau`` (kW).
        tau: the SoC where the taper starts, in (0, 1).

    Returns:
        The rate limit (kW) of the broadcast shape, in ``[0, max_rate_kw]``.
    """
    taper = (1.0 - soc) * max_rate_kw / jnp.maximum(1.0 - tau, 1e-6)
    return jnp.clip(jnp.where(soc <= tau, max_rate_kw, taper), 0.0, max_rate_kw)


def discharge_curve_kw(soc: jnp.ndarray, max_rate_kw: jnp.ndarray, tau: jnp.ndarray) -> jnp.ndarray:
    """Discharging rate limit: the charging curve mirrored at SoC 0.5, ``r-hat(1 - SoC)``.

    The limit is ``max_rate_kw`` down to SoC ``1 - tau``, then tapers linearly to 0 at SoC 0.

    Args:
        soc: state of charge in [0, 1].
        max_rate_kw: the discharge rate limit before the taper (kW).
        tau: the taper parameter of the charging curve, in (0, 1).

    Returns:
        The discharge rate limit (kW, >= 0) of the broadcast shape of the arguments.
    """
    return rate_curve_kw(1.0 - soc, max_rate_kw, tau)


@functools.partial(jax.jit, static_argnums=(1, 2))
def leaf_min_level(station: StationArrays, num_levels: int, v2g: bool) -> jnp.ndarray:
    """Lowest discrete level per leaf: ``-L`` where the leaf may discharge, else 0.

    Batteries may always discharge; ports only when V2G is on and the port has a
    discharge current. Compiled as one program per station shape (the views call it on the
    host to build their action spaces and masks).

    Args:
        station: the compiled station.
        num_levels: ``L``, the discrete levels per direction (static).
        v2g: ports with a discharge current may discharge (static).

    Returns:
        ``(num_leaves,)`` int32, ``-num_levels`` or 0 per leaf.
    """
    can_discharge = (station.leaf_kind == KIND_BATTERY) | (
        jnp.asarray(v2g) & (station.leaf_max_discharge_current_a > 0)
    )
    return jnp.where(can_discharge, -num_levels, 0).astype(jnp.int32)


def target_current(action: jnp.ndarray, state: EnvState, params: EnvParams) -> jnp.ndarray:
    """Turn an action into the target current per leaf, before any car or node limit.

    ``action`` is, per leaf, a signed discrete level (modes ``absolute`` and ``delta``) or a
    fraction in [-1, 1] (mode ``continuous``). Out-of-range values are clipped to the valid
    range of that leaf (levels ``[min_level, L]``, fractions ``[-1, 1]``, no discharge where
    the leaf cannot discharge); NaN and +-inf are idle (level 0, fraction 0; see
    `chargax_marl.core.actions`).

    A level ``k`` of ``L`` (or a fraction ``f``) asks for ``k / L`` (``f``) of the leaf's max
    current when positive and of its max discharge current when negative. In ``delta`` mode
    the level is a change of ``k / L`` of the leaf's max current added to the current set in
    ``state``, in either direction and on every leaf; the result is not clipped here.

    Args:
        action: ``(num_leaves,)`` the action per leaf, ports then batteries.
        state: the current state (``delta`` mode reads its ``current_a``).
        params: the env parameters (action mode, levels, V2G, station).

    Returns:
        ``(num_leaves,)`` float32 signed target current per leaf (A; negative =
        discharging).
    """
    st = params.station
    if params.action_mode == "continuous":
        frac = actions.to_fraction(action)
        can_discharge = leaf_min_level(st, 1, params.v2g) < 0
        frac = jnp.where(can_discharge, frac, jnp.maximum(frac, 0.0))
    elif params.action_mode == "delta":
        # The paper's formal action: a change of current in steps of max_current / L. Any leaf
        # may step down; whether it may go below zero is decided by clip_to_car.
        levels = actions.to_int32(action, -params.num_levels, params.num_levels, 0)
        return (
            state.current_a + levels.astype(jnp.float32) / params.num_levels * st.leaf_max_current_a
        )
    else:
        levels = actions.to_int32(
            action, leaf_min_level(st, params.num_levels, params.v2g), params.num_levels, 0
        )
        frac = levels.astype(jnp.float32) / params.num_levels
    return frac * jnp.where(frac >= 0, st.leaf_max_current_a, st.leaf_max_discharge_current_a)


def clip_to_car(current_a: jnp.ndarray, state: EnvState, params: EnvParams) -> jnp.ndarray:
    """Clip currents to the port rating, the car's rate curve and its SoC window.

    Charging: at most the port's max current, r-hat(SoC), and the current that brings the
    car to its target SoC within the step (a car stops charging at its target, as its own
    charge limit does; batteries' target is 1). Discharging: at most the port's max
    discharge current (0 without V2G), the mirrored curve of the car's own discharge limit
    (0 for models that cannot discharge), and the current that empties the car to its
    arrival SoC within the step. Empty ports draw 0.

    The capacity window is applied here, before the node limits, and not only when charging:
    with flows of both signs under one node, cutting one leaf after the rescale could raise
    the node's net flow above its limit. `charge` keeps the same clip as a guard.

    Args:
        current_a: ``(num_leaves,)`` signed currents (A; negative = discharging).
        state: the current state (the cars' SoC, windows, rate limits and occupancy).
        params: the env parameters (station, step length, V2G).

    Returns:
        ``(num_leaves,)`` the currents clipped to those limits (A); 0 at empty ports.
    """
    st = params.station
    v = st.leaf_voltage_v
    to_amps = 1000.0 / (v * params.step_hours)  # kWh moved in one step -> A
    room_a = jnp.maximum((state.target_soc - state.soc) * state.capacity_kwh, 0.0) * to_amps
    reserve_a = jnp.maximum((state.soc - state.arrival_soc) * state.capacity_kwh, 0.0) * to_amps
    dis_limit = jnp.where(
        st.leaf_kind == KIND_BATTERY,
        st.leaf_max_discharge_current_a,
        st.leaf_max_discharge_current_a * params.v2g,
    )
    charge_a = jnp.minimum(
        st.leaf_max_current_a, rate_curve_kw(state.soc, state.max_rate_kw, state.tau) * 1000.0 / v
    )
    charge_a = jnp.minimum(charge_a, room_a)
    dis_a = jnp.minimum(
        dis_limit,
        discharge_curve_kw(state.soc, state.max_discharge_rate_kw, state.tau) * 1000.0 / v,
    )
    dis_a = jnp.minimum(dis_a, reserve_a)
    clipped = jnp.clip(current_a, -dis_a, charge_a)
    return jnp.where(state.occupied, clipped, 0.0)


def _grid_side(leaf_power_kw: jnp.ndarray, eff: jnp.ndarray, has_node: jnp.ndarray) -> jnp.ndarray:
    """A leaf's flow on the grid side of a node: power / eff charging, power * eff discharging."""
    return jnp.where(
        has_node, jnp.where(leaf_power_kw > 0, leaf_power_kw / eff, leaf_power_kw * eff), 0.0
    )


def path_grid_side(leaf_values: jnp.ndarray, station: StationArrays) -> jnp.ndarray:
    """Each leaf's power (or energy) on the grid side of the whole path to the grid connection:
    divided by the path efficiency when charging, multiplied by it when discharging.

    Args:
        leaf_values: ``(num_leaves,)`` signed power (kW) or energy (kWh) at each leaf.
        station: the compiled station (its ``leaf_path_efficiency``).

    Returns:
        ``(num_leaves,)`` the values on the grid side, in the unit of ``leaf_values``.
    """
    eta = station.leaf_path_efficiency
    return jnp.where(leaf_values > 0, leaf_values / eta, leaf_values * eta)


def grid_side_kw(leaf_power_kw: jnp.ndarray, station: StationArrays) -> jnp.ndarray:
    """``(D, L)`` the flow each leaf causes on the grid side of its ancestor at depth ``d``:
    its power divided by the efficiency of the path up to and including that node when it
    charges, multiplied by it when it discharges (0 where the leaf has no such ancestor).

    Args:
        leaf_power_kw: ``(num_leaves,)`` signed power at each leaf (kW).
        station: the compiled station.

    Returns:
        ``(D, num_leaves)`` grid-side flows (kW), ``D`` the station's depth.
    """
    return _grid_side(
        leaf_power_kw[None, :], station.leaf_efficiency_at_depth, station.node_of_leaf_at_depth >= 0
    )


def node_flows_kw(leaf_power_kw: jnp.ndarray, station: StationArrays) -> jnp.ndarray:
    """Net power through every inner node on its grid side, ``|sum of grid_side_kw|`` (H,).

    This is what the node's cable carries: the power of the leaves below it plus the losses
    of every port and node on their paths up to and including the node itself.

    Args:
        leaf_power_kw: ``(num_leaves,)`` signed power at each leaf (kW).
        station: the compiled station.

    Returns:
        ``(num_nodes,)`` float32, the absolute net grid-side flow of each node (kW).
    """
    side = grid_side_kw(leaf_power_kw, station)
    flows = jnp.zeros((station.num_nodes,), jnp.float32)
    for d in range(station.depth):
        idx = station.node_of_leaf_at_depth[d]
        flows = flows + jax.ops.segment_sum(
            side[d], jnp.maximum(idx, 0), num_segments=station.num_nodes
        )
    return jnp.abs(flows)


def constraint_excess_kw(leaf_power_kw: jnp.ndarray, station: StationArrays) -> jnp.ndarray:
    """The paper's c_constraint: the largest grid-side excess over any node limit.

    Args:
        leaf_power_kw: ``(num_leaves,)`` signed power at each leaf (kW).
        station: the compiled station.

    Returns:
        ``()`` the largest ``node_flows_kw - node_max_kw`` over the nodes (kW); 0 when every
        limit holds.
    """
    return jnp.max(jnp.maximum(node_flows_kw(leaf_power_kw, station) - station.node_max_kw, 0.0))


def rescale_to_limits(current_a: jnp.ndarray, station: StationArrays) -> jnp.ndarray:
    """Hard node constraints: scale the leaves of every violating node down, deepest nodes first.

    Nodes at one depth have disjoint leaves, so each depth is one vectorised pass. A factor
    in (0, 1] multiplies every leaf under a node; a leaf's grid-side flow depends on its
    power's sign only through the efficiency factor, so the node's grid-side net flow scales
    by the same factor: no sign flips, no magnitude grows, and deeper nodes stay within their
    limits when a shallower node rescales. After the pass every node limit holds on the grid
    side, also for the energies `charge` then moves.

    Where charging and discharging leaves meet under a node, their grid-side flows cancel and
    the net flow is a small difference of large terms; float32 rounds each term (here, in the
    energy and in the sums) by a fraction of the term, not of the net. The pass therefore
    compares the limit with the net flow plus `CANCEL_MARGIN` of the power that cancels
    (gross minus net), so that a tiny limit under large opposite flows holds too. A node whose
    leaves all flow one way has no such margin.

    Args:
        current_a: ``(L,)`` signed leaf currents (A), after the car and port limits.
        station: The compiled station.

    Returns:
        ``(L,)`` the currents scaled so that every node's grid-side net flow is within its limit.
    """
    v = station.leaf_voltage_v
    for d in reversed(range(station.depth)):
        idx = station.node_of_leaf_at_depth[d]
        seg = jnp.maximum(idx, 0)
        side = _grid_side(current_a * v / 1000.0, station.leaf_efficiency_at_depth[d], idx >= 0)
        flow_kw = jnp.abs(jax.ops.segment_sum(side, seg, num_segments=station.num_nodes))
        gross_kw = jax.ops.segment_sum(jnp.abs(side), seg, num_segments=station.num_nodes)
        bound_kw = flow_kw + CANCEL_MARGIN * jnp.maximum(gross_kw - flow_kw, 0.0)
        # A small safety margin keeps float32 round-off from leaving a flow a hair above its limit.
        factor = jnp.where(
            bound_kw > station.node_max_kw,
            station.node_max_kw / jnp.maximum(bound_kw, 1e-12) * (1.0 - 1e-6),
            1.0,
        )
        leaf_factor = jnp.where(idx >= 0, factor[seg], 1.0)
        current_a = current_a * leaf_factor
    return current_a


def requested_current(action: jnp.ndarray, state: EnvState, params: EnvParams) -> jnp.ndarray:
    """The currents the controller asks for: the action's target current within the car's and
    the port's limits, before the node limits (what `apply_actions` rescales).

    Args:
        action: ``(num_leaves,)`` the action per leaf (see `target_current`).
        state: the current state.
        params: the env parameters.

    Returns:
        ``(num_leaves,)`` signed currents (A), `clip_to_car` of `target_current`.
    """
    return clip_to_car(target_current(action, state, params), state, params)


def apply_actions(action: jnp.ndarray, state: EnvState, params: EnvParams):
    """Step 1 of the transition: action -> target -> car/port limits -> node limits.

    Returns ``(current_a, excess_kw, requested_excess_kw)``. ``requested_excess_kw`` is
    c_constraint of the currents the controller asked for (after car limits, before the hard
    rescale); ``excess_kw`` is c_constraint of the currents that flow. In hard mode the
    rescale brings the latter to 0; in soft mode nothing is rescaled and both are equal.

    Args:
        action: ``(num_leaves,)`` the action per leaf (see `target_current`).
        state: the current state.
        params: the env parameters (``constraint_mode`` picks hard or soft).

    Returns:
        ``(current_a, excess_kw, requested_excess_kw)``: ``(num_leaves,)`` the signed
        currents that flow (A), and the two ``()`` excesses (kW).
    """
    volts = params.station.leaf_voltage_v
    requested = requested_current(action, state, params)
    requested_excess = constraint_excess_kw(requested * volts / 1000.0, params.station)
    if params.constraint_mode == "hard":
        current = rescale_to_limits(requested, params.station)
        return (
            current,
            constraint_excess_kw(current * volts / 1000.0, params.station),
            requested_excess,
        )
    return requested, requested_excess, requested_excess


def charge(current_a: jnp.ndarray, state: EnvState, params: EnvParams):
    """Step 2: (dis)charge for one step at constant current, clipped to the car's capacity.

    Returns ``(new_state, leaf_energy_kwh)``: the energy actually moved into each car or
    battery (negative when discharging), which every later computation uses. The stored
    current is the current that actually flowed.

    Each occupied leaf's energy is clipped to ``[-(soc - arrival_soc) * capacity,
    (target_soc - soc) * capacity]``; empty ports move 0. Parked cars' ``energy_remaining_kwh``
    drops by the energy (not below 0) and their ``time_remaining_min`` by ``step_minutes``.

    Args:
        current_a: ``(num_leaves,)`` signed currents (A), held for the whole step.
        state: the current state.
        params: the env parameters (station voltages, step length).

    Returns:
        ``(new_state, leaf_energy_kwh)``: the state with ``current_a``, ``soc``,
        ``energy_remaining_kwh`` and ``time_remaining_min`` updated, and ``(num_leaves,)``
        the energy into each leaf (kWh, terminal side).
    """
    st = params.station
    dt_h = params.step_hours
    energy = current_a * st.leaf_voltage_v / 1000.0 * dt_h
    room = jnp.maximum((state.target_soc - state.soc) * state.capacity_kwh, 0.0)
    reserve = jnp.maximum((state.soc - state.arrival_soc) * state.capacity_kwh, 0.0)
    energy = rng.materialize(jnp.where(state.occupied, jnp.clip(energy, -reserve, room), 0.0))
    safe_cap = jnp.maximum(state.capacity_kwh, 1e-6)
    soc = jnp.where(state.occupied, jnp.clip(state.soc + energy / safe_cap, 0.0, 1.0), 0.0)
    actual_current = energy / dt_h * 1000.0 / st.leaf_voltage_v
    is_port = st.leaf_kind != KIND_BATTERY
    parked = state.occupied & is_port
    remaining = jnp.where(parked, jnp.maximum(state.energy_remaining_kwh - energy, 0.0), 0.0)
    time_left = jnp.where(
        parked, state.time_remaining_min - params.step_minutes, state.time_remaining_min
    )
    new_state = state.replace(
        current_a=actual_current,
        soc=soc,
        energy_remaining_kwh=remaining,
        time_remaining_min=time_left,
    )
    return new_state, energy


def energy_flows(leaf_energy_kwh: jnp.ndarray, station: StationArrays) -> dict:
    """Split one step's leaf energies into the paper's quantities (kWh).

    Grid side of a leaf: ``e / eta_path`` when charging, ``e * eta_path`` when discharging.
    ``grid_net = into_cars + into_batteries + losses`` holds by construction; losses >= 0.

    Args:
        leaf_energy_kwh: ``(num_leaves,)`` energy into each car or battery this step (kWh,
            terminal side; negative = discharging), as `charge` returns it.
        station: the compiled station.

    Returns:
        A dict of ``()`` kWh totals: ``delivered_kwh`` (net into cars), ``charged_kwh``,
        ``discharged_kwh`` (out of cars, positive), ``battery_net_kwh``,
        ``battery_discharged_kwh`` (positive), ``grid_to_cars_kwh`` (>= 0),
        ``cars_to_grid_kwh`` (<= 0), ``battery_grid_kwh``, ``grid_net_kwh`` and
        ``losses_kwh``; and of ``(num_leaves,)`` arrays: ``leaf_energy_kwh`` (the input),
        ``leaf_car_kwh`` (0 at batteries) and ``leaf_grid_kwh`` (grid side of each leaf).
    """
    is_port = station.leaf_kind != KIND_BATTERY
    grid_side = path_grid_side(leaf_energy_kwh, station)
    car_e = jnp.where(is_port, leaf_energy_kwh, 0.0)
    bat_e = jnp.where(is_port, 0.0, leaf_energy_kwh)
    grid_to = jnp.sum(jnp.where(is_port & (leaf_energy_kwh > 0), grid_side, 0.0))
    to_grid = jnp.sum(jnp.where(is_port & (leaf_energy_kwh < 0), grid_side, 0.0))
    bat_grid = jnp.sum(jnp.where(is_port, 0.0, grid_side))
    grid_net = grid_to + to_grid + bat_grid
    delivered = jnp.sum(car_e)
    battery_net = jnp.sum(bat_e)
    return {
        "delivered_kwh": delivered,  # Delta E_net
        "charged_kwh": jnp.sum(jnp.maximum(car_e, 0.0)),
        "discharged_kwh": -jnp.sum(jnp.minimum(car_e, 0.0)),
        "battery_net_kwh": battery_net,
        "battery_discharged_kwh": -jnp.sum(jnp.minimum(bat_e, 0.0)),
        "grid_to_cars_kwh": grid_to,  # Delta E_grid->  (>= 0)
        "cars_to_grid_kwh": to_grid,  # Delta E_->grid  (<= 0)
        "battery_grid_kwh": bat_grid,
        "grid_net_kwh": grid_net,
        "losses_kwh": grid_net - delivered - battery_net,
        "leaf_energy_kwh": leaf_energy_kwh,  # (L,) energy into each car / battery (terminal side)
        "leaf_car_kwh": car_e,  # (L,) energy into each car (0 at batteries); sums to delivered
        "leaf_grid_kwh": grid_side,  # (L,) grid side of each leaf; sums to grid_net
    }
