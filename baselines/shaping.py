"""Reward shaping of the trainers: the batteries' stored energy valued as it moves.

The env books the batteries' energy change at the day's last step. With these potentials
(``BATTERY_SHAPING``: the env's terminal price, the battery-only LP's value per kWh, or the
battery-only dynamic programme's value of the energy level, :mod:`baselines.storage_value`)
each step shows the learner what its battery action was worth now. Shared by PPO, IPPO and
MAPPO; the port shaping (a parked car's best plan) is :mod:`baselines.car_value`.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from chargax_marl.core.station import KIND_BATTERY


def core_state(state):
    """Unwrap wrapper states (``.env_state``) down to the core ``EnvState`` (it has ``totals``)."""
    while not hasattr(state, "totals"):
        state = state.env_state
    return state


def battery_value_price(state, params) -> jnp.ndarray:
    """The price (EUR/kWh) at which the env values the batteries' energy change at the end of
    the day of ``state`` (before the step; with auto-reset the next state may be a new day)."""
    from chargax_marl.core.reward import battery_terminal_value_eur

    return battery_terminal_value_eur(jnp.float32(1.0), core_state(state).day, params)


def battery_shaping(shift_eur, terminal_eur) -> jnp.ndarray:
    """``BATTERY_SHAPING``: the term added to a step's reward so that the batteries' energy is
    valued when it moves instead of all at once at the day's last step: the change of the
    potential over the step, ``shift_eur`` (from :func:`battery_potential`), minus the env's
    terminal booking ``terminal_eur`` (non-zero at the last step only).

    With one value per kWh all day (``"day_mean"``: the env's terminal price ``p``) the
    shift is ``p * battery_net_kwh``: the env books ``p * sum_t battery_net_kwh_t`` at the last
    step and this books the same amount step by step, so a day's undiscounted sum of rewards
    and the evaluated profit are unchanged. What changes is when the learner sees it: with
    gamma = 0.99 per 5-minute step a reward 288 steps ahead weighs 0.06, so energy sold from
    the battery in the morning looked like almost free money. With potentials that move
    through the day (``"storage_value"``, ``"dp"``) the day's sum differs from the env's by a
    constant of the day's first state.
    """
    return shift_eur - terminal_eur


def agent_battery_shaping(price, info, is_battery, local_reward_weight: float) -> jnp.ndarray:
    """:func:`agent_potential_shaping` with one value ``price (...)`` per stored kWh before and
    after the step (``"day_mean"``): each agent's share of ``price * net`` minus the terminal
    booking."""
    price = jnp.asarray(price)
    return agent_potential_shaping(lambda net: price * net, info, is_battery, local_reward_weight)


SHAPING_MODES = ("off", "day_mean", "storage_value", "dp")


def shaping_mode(config: dict) -> str:
    """``BATTERY_SHAPING`` as one of :data:`SHAPING_MODES` (``False`` / ``True`` are ``"off"`` /
    ``"day_mean"``)."""
    v = config.get("BATTERY_SHAPING", False)
    mode = {False: "off", True: "day_mean", None: "off"}.get(v, v) if isinstance(v, (bool, type(None))) else v
    if mode not in SHAPING_MODES:
        raise ValueError(f"BATTERY_SHAPING must be a bool or one of {SHAPING_MODES}, got {v!r}")
    return mode


def battery_potential(config: dict, env_params):
    """``None`` when ``BATTERY_SHAPING`` is off, else ``potential(env_state) -> shift``, where
    ``shift(net_kwh)`` is the change of the potential ``Phi`` of the batteries' stored energy
    over the step of the (possibly batched) ``env_state`` when the batteries take in
    ``net_kwh`` (terminal side, negative when discharging; shaped like the batch):
    ``Phi_{t+1}(E_t + net_kwh) - Phi_t(E_t)``. The shaping term of a step is ``shift(net) -
    terminal booking`` (:func:`battery_shaping`, :func:`agent_potential_shaping`).

    ``Phi`` by mode: ``"day_mean"`` the env's terminal price times the energy (the day's
    undiscounted reward is unchanged), ``"storage_value"`` the battery-only LP's value per kWh
    of each step times the energy, ``"dp"`` the battery-only dynamic programme's value of the
    energy level (:mod:`baselines.storage_value`); the last two move the day's sum by a
    constant of its first state."""
    mode = shaping_mode(config)
    if mode == "off":
        return None
    is_battery = jnp.asarray(np.asarray(env_params.station.leaf_kind) == KIND_BATTERY)

    def stored_kwh(core):
        return jnp.sum(jnp.where(is_battery, core.soc * core.capacity_kwh, 0.0), axis=-1)

    if mode == "dp":
        from baselines.storage_value import dp_values, level_value

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
        from baselines.storage_value import storage_values

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
    """The shaping term of each agent of :class:`chargax_marl.marl.ChargaxMARL`, ``(...,
    agents)``, from a ``shift`` of :func:`battery_potential` and the step's ``info`` (leaves
    ``(..., agents)``), mixed like the env's rewards ``(1 - w) * r + w * share_i``: every agent
    gets the station's term with weight ``1 - w``; with weight ``w`` the battery agents share
    it evenly (as the env shares the terminal value among them) and a port gets nothing. The
    agents' terms thus add up to the station's, as the shares do."""
    is_battery = jnp.asarray(is_battery, jnp.float32)
    net = jnp.sum(info["agent_energy_kwh"] * is_battery, axis=-1)
    station = (shift(net) - info["battery_terminal_value_eur"][..., 0])[..., None]
    own = is_battery * station / jnp.maximum(is_battery.sum(), 1.0)
    w = float(local_reward_weight)
    return (1.0 - w) * station + w * own


def mix_own_terms(own, local_reward_weight: float) -> jnp.ndarray:
    """Per-agent terms ``own (..., agents)`` mixed like the env's rewards, ``(1 - w) * sum + w *
    own``: every agent gets the station's sum with weight ``1 - w`` and its own term with
    weight ``w`` (the port shaping of :mod:`baselines.car_value` in IPPO/MAPPO)."""
    w = float(local_reward_weight)
    return (1.0 - w) * jnp.sum(own, axis=-1, keepdims=True) + w * own
