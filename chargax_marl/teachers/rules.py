"""The teachers played as rules: policies built for one station and price table.

Each builder takes concrete params and returns a `chargax_marl.policies` policy
``policy(state, key, params) -> levels``; each needs a station with a battery.
`chargax_marl.policies.get_policy` builds them by name (``get_policy(name, params)``).

- ``battery_programme``: always-max ports with the batteries on the battery-only programme (at
  each step the best of discharge / idle / charge at full power for the stored energy, by
  backward induction over the day's known buy prices,
  `chargax_marl.teachers.storage_value.dp_battery_action`). The battery shaping's teacher
  played as a rule: the reference a learner trained with that shaping has to beat to show it
  learned more than its teacher.
- ``plan_programme``: the ports on their cars' plans (full power in the steps of each car's
  cheapest plan at `chargax_marl.teachers.car_plan.PLAN_POWER_FRACTION`, idle otherwise)
  with the batteries on the battery-only programme: both teachers played as a rule.
- ``grid_programme``: ``battery_programme`` that knows the node limits: the batteries do not
  charge while the ports' full-power draw alone (grid side) exceeds the limit of a node above
  a battery, where the programme's charge would be rescaled with the ports', taking the scarce
  connection from the cars. Not a trainer's teacher.
- ``coupled_plan``: the ports on the parked cars' joint plan under the node limits and the
  peak-demand charge (`chargax_marl.teachers.congestion.coupled_plan_action`, with the
  headroom the plan leaves given to the cars that still want energy), the batteries on the
  battery-only programme within the headroom the cars leave. Needs no battery.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from chargax_marl.core import clock, physics
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.teachers.car_plan import PLAN_POWER_FRACTION, plan_action
from chargax_marl.teachers.congestion import coupled_plan_action
from chargax_marl.teachers.storage_value import dp_battery_action


def has_battery(params) -> bool:
    """Whether the station of ``params`` has a battery leaf.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams`.

    Returns:
        True when any leaf of the station is a battery.
    """
    return bool(np.any(np.asarray(params.station.leaf_kind) == KIND_BATTERY))


def _check_battery(name: str, params) -> None:
    if not has_battery(params):
        raise ValueError(f"policy {name!r} needs a station with a battery; this station has none")


def battery_programme(params):
    """Always-max ports, the batteries on the battery-only programme.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams` of a station with a battery.

    Returns:
        ``policy(state, key, params) -> levels`` (int32 ``(L,)``).

    Raises:
        ValueError: the station has no battery.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.teachers.rules.battery_programme")
    _check_battery("battery_programme", params)
    return plan_action(params, battery="dp", power_fraction=None)


def plan_programme(params):
    """The ports on their cars' plans, the batteries on the battery-only programme.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams` of a station with a battery.

    Returns:
        ``policy(state, key, params) -> levels`` (int32 ``(L,)``).

    Raises:
        ValueError: the station has no battery.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.teachers.rules.plan_programme")
    _check_battery("plan_programme", params)
    return plan_action(params, battery="dp", power_fraction=PLAN_POWER_FRACTION)


def grid_programme(params):
    """``battery_programme`` whose batteries do not charge while the ports' full-power draw
    alone exceeds the limit of a node above a battery.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams` of a station with a battery.

    Returns:
        ``policy(state, key, params) -> levels`` (int32 ``(L,)``).

    Raises:
        ValueError: the station has no battery.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.teachers.rules.grid_programme")
    _check_battery("grid_programme", params)
    st = params.station
    is_battery = np.asarray(st.leaf_kind) == KIND_BATTERY
    # the nodes above any battery (every depth of its path to the grid connection)
    above = np.asarray(st.node_of_leaf_at_depth)[:, is_battery].reshape(-1)
    above = jnp.asarray(np.unique(above[above >= 0]), jnp.int32)
    is_battery = jnp.asarray(is_battery)
    dp = dp_battery_action(params)

    def act(state, key, p):
        del key
        ports = jnp.where(is_battery, 0, p.num_levels).astype(jnp.int32)
        demand_kw = physics.requested_current(ports, state, p) * st.leaf_voltage_v / 1000.0
        binding = jnp.any(physics.node_flows_kw(demand_kw, st)[above] > st.node_max_kw[above])
        bat = dp(state)[0]
        bat = jnp.where(binding & (bat > 0), 0, bat)
        return jnp.where(is_battery, bat * p.num_levels, ports).astype(jnp.int32)

    return act


def coupled_plan_rule(params):
    """The ports on the parked cars' joint plan (congestion prices for the node limits and the
    peak charge), the headroom it leaves topped up earliest departure first, the batteries on
    the battery-only programme where the station has one.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams`.

    Returns:
        ``policy(state, key, params) -> levels`` (int32 ``(L,)``).

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.teachers.rules.coupled_plan_rule")
    return coupled_plan_action(params, battery="dp" if has_battery(params) else "idle", top_up=True)


RULE_BUILDERS = {
    "battery_programme": battery_programme,
    "plan_programme": plan_programme,
    "grid_programme": grid_programme,
    "coupled_plan": coupled_plan_rule,
}
"""Name -> ``builder(params) -> policy`` of every rule of this module."""
