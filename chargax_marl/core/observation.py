"""Observation features, shared by the single-agent view and the multi-agent views.

Every feature is scaled to roughly [-1, 1] or [0, 1]: currents by the leaf's rating, rates by
the leaf's max power, energies by ``ENERGY_SCALE_KWH``, minutes by a day, prices by
``PRICE_SCALE_EUR_KWH``.
"""

from __future__ import annotations

import jax.numpy as jnp

from chargax_marl.core import physics
from chargax_marl.core.reward import day_ahead_price, moer_now
from chargax_marl.core.types import EnvParams, EnvState

ENERGY_SCALE_KWH = 100.0
MINUTES_PER_DAY = 1440.0
PRICE_SCALE_EUR_KWH = 0.25
MOER_SCALE_KG_KWH = 1.0

PORT_FEATURES = ("occupied", "soc", "energy_remaining", "time_remaining", "rate_now", "capacity",
                 "charge_sensitive", "current")
BATTERY_FEATURES = ("soc", "current")


def leaf_features(state: EnvState, params: EnvParams) -> jnp.ndarray:
    """Per-leaf features ``(L, len(PORT_FEATURES))`` in the order of :data:`PORT_FEATURES`."""
    st = params.station
    rate_kw = physics.rate_curve_kw(state.soc, state.max_rate_kw, state.tau)
    signed_max = jnp.where(state.current_a >= 0, st.leaf_max_current_a,
                           jnp.maximum(st.leaf_max_discharge_current_a, 1e-6))
    return jnp.stack(
        [
            state.occupied.astype(jnp.float32),
            state.soc,
            state.energy_remaining_kwh / ENERGY_SCALE_KWH,
            jnp.clip(state.time_remaining_min / MINUTES_PER_DAY, -1.0, 1.0),
            jnp.where(state.occupied, rate_kw / st.leaf_max_kw, 0.0),
            state.capacity_kwh / ENERGY_SCALE_KWH,
            state.charge_sensitive.astype(jnp.float32),
            state.current_a / signed_max,
        ],
        axis=-1,
    )


def context_features(state: EnvState, params: EnvParams) -> jnp.ndarray:
    """Shared context: price now and the next H hours, customer price, time of day (sin, cos),
    workday flag, day of the data, and MOER now when ``params.observe_moer``."""
    prices = jnp.stack([day_ahead_price(state.day, state.timestep, params, h)
                        for h in range(params.price_horizon_hours + 1)])
    angle = 2.0 * jnp.pi * state.timestep / params.num_steps
    parts = [
        prices / PRICE_SCALE_EUR_KWH,
        jnp.atleast_1d(params.customer_price_eur_kwh / PRICE_SCALE_EUR_KWH),
        jnp.stack([jnp.sin(angle), jnp.cos(angle)]),
        jnp.atleast_1d(state.is_workday.astype(jnp.float32)),
        jnp.atleast_1d(state.day / jnp.maximum(params.num_days - 1, 1)),
    ]
    if params.observe_moer:
        parts.append(jnp.atleast_1d(moer_now(state.day, state.timestep, params) / MOER_SCALE_KG_KWH))
    return jnp.concatenate(parts).astype(jnp.float32)


def obs_dict(state: EnvState, params: EnvParams) -> dict:
    """Named parts of the single-agent observation: ``ports (P, 8)``, ``batteries (B, 2)``, ``context``."""
    feats = leaf_features(state, params)
    n = params.station.num_ports
    soc_i, cur_i = PORT_FEATURES.index("soc"), PORT_FEATURES.index("current")
    return {
        "ports": feats[:n],
        "batteries": feats[n:][:, jnp.array([soc_i, cur_i])],
        "context": context_features(state, params),
    }


def flat_obs(state: EnvState, params: EnvParams) -> jnp.ndarray:
    """The single-agent observation: ports, then batteries, then context, as one float32 vector."""
    parts = obs_dict(state, params)
    return jnp.concatenate([parts["ports"].reshape(-1), parts["batteries"].reshape(-1), parts["context"]])


def obs_size(params: EnvParams) -> int:
    st = params.station
    context = params.price_horizon_hours + 1 + 1 + 2 + 1 + 1 + int(params.observe_moer)
    return st.num_ports * len(PORT_FEATURES) + st.num_batteries * len(BATTERY_FEATURES) + context
