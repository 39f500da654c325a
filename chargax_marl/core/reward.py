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


def station_grid_price(flows: dict, p_buy, p_sell_grid) -> jnp.ndarray:
    """The price of the step's grid energy: p_buy for a net draw, p_sell,grid for a net feed-in."""
    return jnp.where(flows["grid_net_kwh"] > 0, p_buy, p_sell_grid)


def profit_eur(flows: dict, p_buy, p_sell_grid, params: EnvParams) -> jnp.ndarray:
    """Paper Eq. 2: customers pay p_sell for Delta E_net; the grid is paid p_buy for a net draw
    or pays p_sell,grid for a net feed-in; minus the fixed cost per step."""
    grid_price = station_grid_price(flows, p_buy, p_sell_grid)
    return (params.customer_price_eur_kwh * flows["delivered_kwh"] - grid_price * flows["grid_net_kwh"]
            - params.fixed_cost_eur)


def leaf_reward_shares(flows: dict, p_buy, p_sell_grid, r, params: EnvParams) -> jnp.ndarray:
    """Each leaf's share ``(L,)`` of the step reward ``r``; the shares sum to ``r``.

    A leaf's share is the money its own energy made at the step's prices: what its car paid
    (ports; ``p_sell`` times the energy into the car) minus the grid price of its grid-side
    energy (the station's price for the step, p_buy or p_sell,grid by the sign of the net
    grid flow, so the per-leaf terms add up to Eq. 2 without the fixed cost). What no leaf
    owns alone, the fixed cost and the weighted penalties, is split evenly over the leaves.
    The multi-agent view mixes these shares into per-agent rewards when asked to
    (``ChargaxMARL(local_reward_weight=...)``).
    """
    own = (params.customer_price_eur_kwh * flows["leaf_car_kwh"]
           - station_grid_price(flows, p_buy, p_sell_grid) * flows["leaf_grid_kwh"])
    return own + (r - jnp.sum(own)) / own.shape[0]


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
