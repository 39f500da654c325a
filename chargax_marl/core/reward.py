"""Reward: profit (paper Eq. 2) minus weighted penalty terms (Eq. 4, Appendix A.3).

The only place that prices energy and weighs penalties. Prices are looked up by the step in
which the energy flowed.
"""

from __future__ import annotations

import jax.numpy as jnp

from chargax_marl.core.types import PENALTY_TERMS, EnvParams


def hour_of_step(timestep: jnp.ndarray, params: EnvParams) -> jnp.ndarray:
    return jnp.clip((timestep * params.step_minutes / 60.0).astype(jnp.int32), 0, 23)


def day_ahead_price(day: jnp.ndarray, timestep: jnp.ndarray, params: EnvParams, ahead_hours: int = 0) -> jnp.ndarray:
    """Day-ahead price (EUR/kWh) ``ahead_hours`` after the hour of ``timestep``.

    Hours past midnight read the next day's prices (the year wraps to its first day).
    """
    flat = params.prices_eur_kwh.reshape(-1)
    idx = day * 24 + hour_of_step(timestep, params) + ahead_hours
    return flat[jnp.mod(idx, flat.shape[0])]


def grid_prices(day, timestep, params: EnvParams):
    """``(p_buy, p_sell_grid)`` in EUR/kWh for the step."""
    spot = day_ahead_price(day, timestep, params)
    return spot + params.grid_fee_eur_kwh, spot * params.feed_in_factor


def moer_now(day, timestep, params: EnvParams) -> jnp.ndarray:
    """Marginal emission rate (kg CO2/kWh) for the step; the MOER data repeats over its days."""
    m = params.moer_kg_per_kwh
    return m[jnp.mod(day, m.shape[0]), jnp.clip(timestep, 0, m.shape[1] - 1)]


def profit_eur(flows: dict, p_buy, p_sell_grid, params: EnvParams) -> jnp.ndarray:
    """Paper Eq. 2: customers pay p_sell for Delta E_net; the grid is paid p_buy for a net draw
    or pays p_sell,grid for a net feed-in; minus the fixed cost per step."""
    grid = flows["grid_net_kwh"]
    grid_price = jnp.where(grid > 0, p_buy, p_sell_grid)
    return params.customer_price_eur_kwh * flows["delivered_kwh"] - grid_price * grid - params.fixed_cost_eur


def penalty_terms(flows: dict, departures: dict, arrivals: dict, excess_kw, moer, grid_demand_kwh) -> dict:
    """The unweighted penalty terms c of Appendix A.3, keyed as :data:`PENALTY_TERMS`."""
    terms = {
        "constraint": excess_kw,
        "satisfaction_time": departures["missing_kwh"],
        "satisfaction_charge": departures["satisfaction_charge"],
        "sustainability": moer * flows["grid_net_kwh"],
        "rejected": arrivals["rejected"],
        "battery_degradation": flows["battery_discharged_kwh"],
        "car_degradation": jnp.abs(flows["cars_to_grid_kwh"]),
        "grid_demand": jnp.abs(flows["delivered_kwh"] - grid_demand_kwh),
    }
    assert tuple(terms) == PENALTY_TERMS
    return terms


def reward(profit, terms: dict, params: EnvParams) -> jnp.ndarray:
    """``r = profit - sum_c alpha_c * c``."""
    penalty = sum(getattr(params.alpha, name) * terms[name] for name in PENALTY_TERMS)
    return profit - penalty
