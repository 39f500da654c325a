"""Potential-based reward shaping of the station battery: its stored energy valued as it moves.

The env books the batteries' energy change at the day's last step (the day's terminal price
times the change). With a potential ``Phi_t(E_t)`` of the stored energy ``E_t`` the shaping
term of a step is ``Phi_{t+1}(E_{t+1}) - Phi_t(E_t)`` minus that terminal booking, so each
step shows a learner what its battery action was worth now (Ng, Harada and Russell 1999).
Potentials (`BATTERY_POTENTIALS`): ``"day_mean"`` the env's terminal price times the
energy (a day's undiscounted reward is unchanged), ``"storage_value"`` the battery-only LP's
value per kWh of each step times the energy, ``"dp"`` the battery-only dynamic programme's
value of the energy level (`chargax_marl.teachers.storage_value`); the last two move a
day's sum by a constant of its first state.

These are the building blocks; `chargax_marl.wrappers.BatteryShaping` applies them to
an env's rewards.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from chargax_marl.core import clock
from chargax_marl.core.reward import battery_terminal_value_eur
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.teachers.storage_value import dp_values, level_value, storage_values

BATTERY_POTENTIALS = ("day_mean", "storage_value", "dp")
"""The battery potentials of `battery_potential`."""


def core_state(state):
    """Unwrap wrapper states (``.env_state``) down to the core ``EnvState`` (it has ``totals``).

    Args:
        state: a core state or a (nested) wrapper state with an ``env_state`` field.

    Returns:
        The core `chargax_marl.core.types.EnvState`.
    """
    while not hasattr(state, "totals"):
        state = state.env_state
    return state


def battery_value_price(state, params) -> jnp.ndarray:
    """The price (EUR/kWh) at which the env values the batteries' energy change at the end of
    the day of ``state`` (before the step; with auto-reset the next state may be a new day).

    Args:
        state: a (possibly wrapped, possibly batched) core state.
        params: the env's `chargax_marl.core.types.EnvParams`.

    Returns:
        The terminal price (EUR/kWh), shaped like the state's batch.
    """
    return battery_terminal_value_eur(jnp.float32(1.0), core_state(state).day, params)


def battery_shaping(shift_eur, terminal_eur) -> jnp.ndarray:
    """The term added to a step's reward so that the batteries' energy is valued when it moves
    instead of all at once at the day's last step.

    With one value per kWh all day (``"day_mean"``: the env's terminal price ``p``) the shift
    is ``p * battery_net_kwh``: the env books ``p * sum_t battery_net_kwh_t`` at the last step
    and this books the same amount step by step, so a day's undiscounted sum of rewards and
    the evaluated profit are unchanged. What changes is when the learner sees it: with a
    discount close to 1 per 5-minute step a reward hundreds of steps ahead weighs little, so
    energy sold from the battery in the morning looked like almost free money. With
    potentials that move through the day (``"storage_value"``, ``"dp"``) the day's sum differs
    from the env's by a constant of the day's first state.

    Args:
        shift_eur: the change of the potential over the step (EUR), from a shift of
            `battery_potential`.
        terminal_eur: the env's terminal booking of the step (EUR; non-zero at the day's last
            step only), ``info["battery_terminal_value_eur"]``.

    Returns:
        ``shift_eur - terminal_eur`` (EUR).
    """
    return shift_eur - terminal_eur


def battery_potential(env_params, mode: str = "dp"):
    """The potential of the batteries' stored energy, as its change over a step.

    Args:
        env_params: concrete `chargax_marl.core.types.EnvParams` (the tables are built
            for its days and prices).
        mode: one of `BATTERY_POTENTIALS`.

    Returns:
        ``potential(env_state) -> shift``, where ``shift(net_kwh)`` is the change of the
        potential ``Phi`` over the step of the (possibly wrapped and batched) ``env_state``,
        taken *before* the step, when the batteries take in ``net_kwh`` (terminal side,
        negative when discharging; shaped like the batch): ``Phi_{t+1}(E_t + net_kwh) -
        Phi_t(E_t)`` (EUR). Built from the state before the step, so an auto-reset does not
        hide the value after it.

    Raises:
        ValueError: an unknown ``mode``, or ``"storage_value"`` / ``"dp"`` on a station
            without a battery.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(env_params, "chargax_marl.teachers.shaping.battery_potential")
    if mode not in BATTERY_POTENTIALS:
        raise ValueError(f"battery potential must be one of {BATTERY_POTENTIALS}, got {mode!r}")
    is_battery = jnp.asarray(np.asarray(env_params.station.leaf_kind) == KIND_BATTERY)

    def stored_kwh(core):
        return jnp.sum(jnp.where(is_battery, core.soc * core.capacity_kwh, 0.0), axis=-1)

    if mode == "dp":
        grid_np, table_np = dp_values(env_params)
        table, step_kwh = jnp.asarray(table_np), float(grid_np[1] - grid_np[0])

        def potential(env_state):
            core = core_state(env_state)
            e0 = stored_kwh(core)
            phi0 = level_value(table[core.day, core.timestep], e0, step_kwh)
            after = table[core.day, core.timestep + 1]
            return lambda net_kwh: level_value(after, e0 + net_kwh, step_kwh) - phi0

        return potential

    table = None
    if mode == "storage_value":
        table = jnp.asarray(storage_values(env_params))

    def potential(env_state):
        core = core_state(env_state)
        e0 = stored_kwh(core)
        if table is None:
            v0 = v1 = battery_value_price(env_state, env_params)
        else:
            v0, v1 = table[core.day, core.timestep], table[core.day, core.timestep + 1]
        return lambda net_kwh: v1 * (e0 + net_kwh) - v0 * e0

    return potential


def agent_potential_shaping(shift, info, is_battery, local_reward_weight: float) -> jnp.ndarray:
    """The battery shaping term of each agent of `chargax_marl.marl.ChargaxMARL`.

    Mixed like the env's rewards ``(1 - w) * r + w * share_i``: every agent gets the station's
    term with weight ``1 - w``; with weight ``w`` the battery agents share it evenly (as the
    env shares the terminal value among them) and a port gets nothing. The agents' terms thus
    add up to the station's, as the shares do.

    Args:
        shift: a ``shift(net_kwh)`` of `battery_potential`, taken before the step.
        info: the step's infos, leaves ``(..., agents)``; reads ``agent_energy_kwh`` and
            ``battery_terminal_value_eur``.
        is_battery: bool ``(agents,)``, the battery agents.
        local_reward_weight: the env's ``local_reward_weight`` ``w`` in ``[0, 1]``.

    Returns:
        ``(..., agents)`` float32 shaping terms (EUR).
    """
    is_battery = jnp.asarray(is_battery, jnp.float32)
    net = jnp.sum(info["agent_energy_kwh"] * is_battery, axis=-1)
    station = (shift(net) - info["battery_terminal_value_eur"][..., 0])[..., None]
    own = is_battery * station / jnp.maximum(is_battery.sum(), 1.0)
    w = float(local_reward_weight)
    return (1.0 - w) * station + w * own


def agent_battery_shaping(price, info, is_battery, local_reward_weight: float) -> jnp.ndarray:
    """`agent_potential_shaping` with one value ``price (...)`` (EUR/kWh) per stored kWh
    before and after the step (``"day_mean"``): each agent's share of ``price * net`` minus the
    terminal booking.

    Args:
        price: the value of a stored kWh (EUR/kWh), shaped like the batch.
        info: as for `agent_potential_shaping`.
        is_battery: bool ``(agents,)``.
        local_reward_weight: the env's ``local_reward_weight``.

    Returns:
        ``(..., agents)`` shaping terms (EUR).
    """
    price = jnp.asarray(price)
    return agent_potential_shaping(lambda net: price * net, info, is_battery, local_reward_weight)


def mix_own_terms(own, local_reward_weight: float) -> jnp.ndarray:
    """Per-agent terms mixed like the env's rewards, ``(1 - w) * sum + w * own``: every agent
    gets the station's sum with weight ``1 - w`` and its own term with weight ``w`` (the car
    plan shaping of `chargax_marl.teachers.car_plan` in the multi-agent view).

    Args:
        own: ``(..., agents)`` each agent's own term.
        local_reward_weight: the env's ``local_reward_weight`` ``w``.

    Returns:
        ``(..., agents)`` mixed terms.
    """
    w = float(local_reward_weight)
    return (1.0 - w) * jnp.sum(own, axis=-1, keepdims=True) + w * own
