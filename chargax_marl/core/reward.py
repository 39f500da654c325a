"""Reward: profit (paper Eq. 2) minus weighted penalty terms (Eq. 4, Appendix A.3).

The only place that prices energy and weighs penalties. Prices are looked up by the step in
which the energy flowed, at its clock time (`chargax_marl.core.clock`: an episode may start
at another hour than midnight and run into the next day).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from chargax_marl.core import clock
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.core.types import PENALTY_TERMS, EnvParams


def hour_of_step(timestep: jnp.ndarray, params: EnvParams) -> jnp.ndarray:
    """The hour of the episode a step is in (`chargax_marl.core.clock.hours_since_start`),
    the column of the episode's hourly price tables (`episode_buy_prices`); with the default
    start hour 0 it is the local hour of day, the column of the day's row of
    ``prices_eur_kwh``.

    Args:
        timestep: the step of the episode (int, any shape).
        params: the environment parameters (``step_minutes``).

    Returns:
        int32 hours in ``[0, 24 * episode_days - 1]``, shaped as ``timestep``.
    """
    return clock.hours_since_start(timestep, params)


def day_ahead_price(
    day: jnp.ndarray, timestep: jnp.ndarray, params: EnvParams, ahead_hours=0
) -> jnp.ndarray:
    """Day-ahead price (EUR/kWh) ``ahead_hours`` (an int or an array of them) after the hour of
    step ``timestep`` of the episode that starts on ``day``, at its clock time
    (`chargax_marl.core.clock.episode_hour`).

    Hours past midnight read the next day's prices (the year wraps to its first day).

    Args:
        day: the episode's day (``state.day``, int).
        timestep: the step of the episode (int).
        params: the environment parameters (``prices_eur_kwh``, the clock settings).
        ahead_hours: hours after the step's hour (int, or an int array).

    Returns:
        EUR/kWh, shaped as the broadcast of ``day``, ``timestep`` and ``ahead_hours``.
    """
    flat = params.prices_eur_kwh.reshape(-1)
    idx = day * 24 + clock.episode_hour(timestep, params) + ahead_hours
    return flat[jnp.mod(idx, flat.shape[0])]


def tou_fee(timestep: jnp.ndarray, params: EnvParams, ahead_hours=0) -> jnp.ndarray:
    """The time-of-use surcharge (EUR/kWh) ``ahead_hours`` (an int or an array of them) after
    the local hour of step ``timestep`` (`chargax_marl.core.clock.episode_hour`).

    Args:
        timestep: the step of the episode (int).
        params: the environment parameters (``tou_fee_eur_kwh``, the clock settings).
        ahead_hours: hours after the step's hour (int, or an int array); wraps at 24.

    Returns:
        EUR/kWh, shaped as the broadcast of ``timestep`` and ``ahead_hours``.
    """
    return params.tou_fee_eur_kwh[jnp.mod(clock.episode_hour(timestep, params) + ahead_hours, 24)]


def episode_buy_prices(day, params: EnvParams, grid_fee: bool = True) -> jnp.ndarray:
    """The buy prices (EUR/kWh) of the 24 hours of the episode that starts on ``day``, in the
    episode's order (indexed by `hour_of_step`): day-ahead price, grid fee (unless
    ``grid_fee=False``) and time-of-use surcharge. With the default start hour 0 it is the
    day's row of ``prices_eur_kwh`` plus the fees.

    Args:
        day: the episode's day (``()`` int).
        params: the environment parameters.
        grid_fee: add ``grid_fee_eur_kwh``.

    Returns:
        ``(24,)`` EUR/kWh.
    """
    spot = clock.episode_day_ahead_prices(day, params)
    if grid_fee:
        return spot + params.grid_fee_eur_kwh + clock.episode_tou_fee(params)
    return spot + clock.episode_tou_fee(params)


def grid_prices(day, timestep, params: EnvParams):
    """``(p_buy, p_sell_grid)`` in EUR/kWh for step ``timestep`` of the episode that starts on
    ``day`` (at its clock time): the buy price is the day-ahead price
    plus the grid fee plus the hour's time-of-use surcharge; feed-in earns ``feed_in_factor``
    times the day-ahead price.

    Args:
        day: the episode's day (``state.day``, int).
        timestep: the step of the episode (int).
        params: the environment parameters.

    Returns:
        ``(p_buy, p_sell_grid)`` in EUR/kWh, each shaped as the broadcast of ``day`` and
        ``timestep``.
    """
    spot = day_ahead_price(day, timestep, params)
    return spot + params.grid_fee_eur_kwh + tou_fee(timestep, params), spot * params.feed_in_factor


@jax.jit
def price_tables(params: EnvParams):
    """``(buy, sell)``, each ``(days, steps)`` EUR/kWh: `grid_prices` of every step of
    the episode that starts on each day of the price data (row ``d``: the episode of day
    ``d``, at its clock time; with a start hour above 0 the last row wraps to the data's first
    day, an episode that ``reset`` never draws), for planners that read all of a day's
    prices at once (the MPC, the trainers' storage values). Compiled as one program per
    station shape (its planners call it on the host).

    Args:
        params: the environment parameters.

    Returns:
        ``(buy, sell)``: ``(num_days, num_steps)`` arrays of ``p_buy`` and ``p_sell_grid``
        (EUR/kWh).
    """
    days = jnp.arange(params.num_days, dtype=jnp.int32)
    steps = jnp.arange(params.num_steps, dtype=jnp.int32)
    return jax.vmap(lambda d: jax.vmap(lambda t: grid_prices(d, t, params))(steps))(days)


def day_price_quantiles(day, params: EnvParams) -> jnp.ndarray:
    """The quantiles of the hourly buy-side price (day-ahead plus time-of-use surcharge) over
    the 24 hours of the episode that starts on ``day``, EUR/kWh, precomputed by
    ``make_params`` (`EnvParams.day_price_quantiles_eur_kwh`).

    Args:
        day: the episode's day (int; wrapped around the data).
        params: the environment parameters.

    Returns:
        ``(Q,)`` EUR/kWh for a ``()`` day, at the probabilities
        ``observation.PRICE_QUANTILES``.
    """
    q = params.day_price_quantiles_eur_kwh
    return q[jnp.mod(day, q.shape[0])]


def day_mean_buy_price(day, params: EnvParams) -> jnp.ndarray:
    """The mean buy price (EUR/kWh) over the 24 hours of the episode that starts on ``day``:
    mean day-ahead price, grid fee, mean surcharge.

    Args:
        day: the episode's day (``()`` int; wrapped around the data).
        params: the environment parameters.

    Returns:
        ``()`` EUR/kWh.
    """
    spot = clock.episode_day_ahead_prices(jnp.mod(day, params.prices_eur_kwh.shape[0]), params)
    return jnp.mean(spot) + params.grid_fee_eur_kwh + jnp.mean(params.tou_fee_eur_kwh)


def peak_demand_charge(grid_net_kwh, peak_before_kw, last, params: EnvParams):
    """``(peak_after_kw, charge_eur)``: the running peak of the net grid draw (kW, the step's
    energy over its length; feed-in counts as 0) and the peak-demand charge booked this step,
    ``peak_demand_eur_kw`` times the day's peak at the last step, or times the rise of the
    running peak in every step with incremental booking (the same daily total). The peak is
    the episode's (it starts at each reset), whatever hour the episode starts at; the billing
    period of an episode of ``episode_days > 1`` is the whole episode: one running peak over
    all its days, booked at its last step (or as it rises, with incremental booking).

    Args:
        grid_net_kwh: ``()`` the step's net grid energy (kWh; negative = feed-in).
        peak_before_kw: ``()`` the running peak before the step (kW).
        last: ``()`` bool, the step is the episode's last.
        params: the environment parameters (``peak_demand_eur_kw``,
            ``peak_demand_incremental``, the step length).

    Returns:
        ``(peak_after_kw, charge_eur)``: the running peak after the step (kW) and the
        charge booked this step (EUR, >= 0 for a non-negative rate).
    """
    draw_kw = jnp.maximum(grid_net_kwh, 0.0) / params.step_hours
    peak_after = jnp.maximum(peak_before_kw, draw_kw)
    booked_kw = jnp.where(
        params.peak_demand_incremental,
        peak_after - peak_before_kw,
        jnp.where(last, peak_after, 0.0),
    )
    return peak_after, params.peak_demand_eur_kw * booked_kw


def moer_now(day, timestep, params: EnvParams) -> jnp.ndarray:
    """Marginal emission rate (kg CO2/kWh) for the step, at its calendar day and step of day
    (`chargax_marl.core.clock`); the MOER data repeats over its days.

    Args:
        day: the episode's day (``state.day``, int).
        timestep: the step of the episode (int).
        params: the environment parameters (``moer_kg_per_kwh``).

    Returns:
        kg CO2/kWh, shaped as the broadcast of ``day`` and ``timestep``.
    """
    m = params.moer_kg_per_kwh
    return m[
        jnp.mod(clock.calendar_day(day, timestep, params), m.shape[0]),
        clock.slot_of_day(timestep, params),
    ]


def grid_demand_now(timestep, params: EnvParams) -> jnp.ndarray:
    """The grid-demand signal (kWh) for the step, at its step of day
    (`chargax_marl.core.clock.slot_of_day`).

    Args:
        timestep: the step of the episode (int).
        params: the environment parameters (``grid_demand_kwh``).

    Returns:
        kWh, shaped as ``timestep``.
    """
    return params.grid_demand_kwh[clock.slot_of_day(timestep, params)]


def station_grid_price(flows: dict, p_buy, p_sell_grid) -> jnp.ndarray:
    """The price of the step's grid energy: p_buy for a net draw, p_sell,grid for a net feed-in.

    Args:
        flows: the step's energy flows (`chargax_marl.core.physics.energy_flows`).
        p_buy: the buy price (EUR/kWh).
        p_sell_grid: the feed-in price (EUR/kWh).

    Returns:
        ``p_buy`` where ``flows["grid_net_kwh"] > 0``, else ``p_sell_grid`` (EUR/kWh).
    """
    return jnp.where(flows["grid_net_kwh"] > 0, p_buy, p_sell_grid)


def billed_car_kwh(flows: dict, params: EnvParams) -> tuple[jnp.ndarray, jnp.ndarray]:
    """``(per_leaf (L,), total ())``: the car energy (kWh) the customers pay ``p_sell`` for
    in the step, the one rule behind `profit_eur` and `leaf_reward_shares`.

    With ``params.refund_discharged_energy`` (the default) each car pays for its net energy
    (charged minus discharged: energy taken out of a car by V2G is refunded at ``p_sell``),
    and the total is Delta E_net. Without it each car pays for the energy put in and gets
    nothing back for energy taken out (``max(e, 0)`` per car, the original Chargax
    accounting), and the total is the energy charged. Batteries are not cars (0 here). The
    total is the flows' own sum of the per-leaf values, so the shares add up to the profit.

    Args:
        flows: the step's energy flows (`chargax_marl.core.physics.energy_flows`).
        params: the environment parameters (``refund_discharged_energy``).

    Returns:
        ``(per_leaf, total)``: ``(L,)`` kWh billed per leaf and the ``()`` total (kWh).
    """
    refund = params.refund_discharged_energy
    car = flows["leaf_car_kwh"]
    return (
        jnp.where(refund, car, jnp.maximum(car, 0.0)),
        jnp.where(refund, flows["delivered_kwh"], flows["charged_kwh"]),
    )


def profit_eur(flows: dict, p_buy, p_sell_grid, params: EnvParams) -> jnp.ndarray:
    """Paper Eq. 2: customers pay p_sell for Delta E_net (for the energy charged alone when
    discharged energy is not refunded, `billed_car_kwh`); the grid is paid p_buy for a
    net draw or pays p_sell,grid for a net feed-in; minus the fixed cost per step.

    The step's profit in `chargax_marl.core.simulator.step` adds the batteries' terminal
    value to this and subtracts the peak-demand charge and the battery wear.

    Args:
        flows: the step's energy flows (`chargax_marl.core.physics.energy_flows`).
        p_buy: the buy price (EUR/kWh).
        p_sell_grid: the feed-in price (EUR/kWh).
        params: the environment parameters (``customer_price_eur_kwh``,
            ``fixed_cost_eur``, ``refund_discharged_energy``).

    Returns:
        ``()`` EUR.
    """
    grid_price = station_grid_price(flows, p_buy, p_sell_grid)
    _, billed = billed_car_kwh(flows, params)
    return (
        params.customer_price_eur_kwh * billed
        - grid_price * flows["grid_net_kwh"]
        - params.fixed_cost_eur
    )


def battery_terminal_value_eur(battery_day_kwh, day, params: EnvParams) -> jnp.ndarray:
    """The value of the station batteries' energy change over the episode, ``battery_day_kwh``
    (terminal side, net into the batteries), booked once, at the episode's last step (of its
    last day when ``episode_days > 1``; `chargax_marl.core.simulator.step` then passes the
    episode's last day, ``state.day + episode_days - 1``, so the mean buy price is that of
    the episode's last 24 hours).

    Priced at the day's mean buy price (`day_mean_buy_price`) when
    ``params.battery_value_day_mean``, else at ``params.battery_value_eur_kwh`` (0 turns the
    term off). Emptying the battery thus earns only what its energy fetched above the price
    it would cost to buy back, and a battery that ends fuller is credited for what it holds.

    Args:
        battery_day_kwh: ``()`` net energy into the station batteries over the day (kWh,
            terminal side; negative when they ended emptier).
        day: the episode's day (``()`` int).
        params: the environment parameters.

    Returns:
        ``()`` EUR, the price times ``battery_day_kwh``. `chargax_marl.core.simulator.step`
        books it at the last step only.
    """
    price = jnp.where(
        params.battery_value_day_mean, day_mean_buy_price(day, params), params.battery_value_eur_kwh
    )
    return price * battery_day_kwh


def battery_wear_eur(leaf_energy_kwh, params: EnvParams) -> tuple[jnp.ndarray, jnp.ndarray]:
    """The step's battery wear: ``(per_leaf (L,), total ())`` in EUR, 0 at the ports.

    Each battery pays its wear cost per kWh of cell throughput (the energy into or out of its
    cells, `EnvParams.battery_wear_eur_kwh`) plus its calendar ageing per step, whatever
    it does. Cycling one full equivalent cycle thus costs ``cost * capacity / cycle_life``.
    Throughput rather than discharge alone: a day's wear then does not depend on where the
    day ends, so charging the battery to end the day full is not free.

    Args:
        leaf_energy_kwh: ``(L,)`` energy into each leaf this step (kWh, terminal side,
            negative when discharging; batteries are the last ``B`` leaves).
        params: the environment parameters.

    Returns:
        ``(per_leaf, total)``: each leaf's wear (EUR) and their sum.
    """
    st = params.station
    zeros = jnp.zeros((st.num_ports,), jnp.float32)
    rate = jnp.concatenate([zeros, params.battery_wear_eur_kwh.astype(jnp.float32)])
    calendar = jnp.concatenate([zeros, params.battery_calendar_eur_step.astype(jnp.float32)])
    per_leaf = rate * jnp.abs(leaf_energy_kwh) + calendar
    return per_leaf, jnp.sum(per_leaf)


def fixed_cost_per_step_eur(params: EnvParams) -> jnp.ndarray:
    """The cost booked every step whatever the actions (EUR): the fixed cost plus the
    batteries' calendar ageing. Planners add it to the value of their plans.

    Args:
        params: the environment parameters (``fixed_cost_eur``,
            ``battery_calendar_eur_step``).

    Returns:
        ``()`` EUR per step.
    """
    return params.fixed_cost_eur + jnp.sum(params.battery_calendar_eur_step)


def leaf_grid_cost_eur(flows: dict, p_buy, p_sell_grid) -> jnp.ndarray:
    """Each leaf's grid cost ``(L,)``: its grid-side draw at ``p_buy``, its grid-side feed-in
    at ``p_sell_grid`` plus its pro-rata part of the netting gain. The costs sum to the
    station's grid cost of Eq. 2; a charging leaf's cost does not depend on other leaves.

    Netting: feed-in that covers another leaf's draw within the station saves ``p_buy`` rather
    than earning ``p_sell_grid``; the gain ``(p_buy - p_sell_grid) * min(draw, feed-in)`` goes
    to the feeding leaves in proportion to what they feed in.

    Args:
        flows: the step's energy flows (`chargax_marl.core.physics.energy_flows`; its
            ``leaf_grid_kwh``).
        p_buy: the buy price (EUR/kWh).
        p_sell_grid: the feed-in price (EUR/kWh).

    Returns:
        ``(L,)`` EUR, positive = paid, negative = earned.
    """
    g = flows["leaf_grid_kwh"]
    draw = jnp.sum(jnp.maximum(g, 0.0))
    feed = jnp.sum(jnp.maximum(-g, 0.0))
    gain_per_kwh = (p_buy - p_sell_grid) * jnp.minimum(draw, feed) / jnp.maximum(feed, 1e-12)
    return jnp.where(g > 0, p_buy * g, (p_sell_grid + gain_per_kwh) * g)


def leaf_penalty_terms(flows: dict, departures: dict, terms: dict, moer, station) -> dict:
    """Each penalty term split over the leaves ``{name: (L,)}``; each split sums to the term.

    A term goes to the leaf that caused it where one did: the departure terms to the
    departing car's port, battery degradation to the battery that discharged, car degradation
    to the port whose car fed the grid, emissions to each leaf's grid-side energy. The rest
    (node excess, rejected cars, the grid-demand mismatch) is split evenly over the leaves.

    Args:
        flows: the step's energy flows (`chargax_marl.core.physics.energy_flows`).
        departures: the report of `chargax_marl.core.traffic.depart` (its
            ``leaf_missing_kwh`` and ``leaf_satisfaction_charge``).
        terms: the step's unweighted terms (`penalty_terms`).
        moer: ``()`` the step's marginal emission rate (kg CO2/kWh).
        station: the compiled station.

    Returns:
        ``{name: (L,)}`` keyed as `PENALTY_TERMS`, in the units of the terms.
    """
    num_leaves = flows["leaf_grid_kwh"].shape[0]
    is_port = station.leaf_kind != KIND_BATTERY
    e = flows["leaf_energy_kwh"]
    g = flows["leaf_grid_kwh"]
    even = jnp.full((num_leaves,), 1.0 / num_leaves)
    out = {
        "constraint": even * terms["constraint"],
        "satisfaction_time": departures["leaf_missing_kwh"],
        "satisfaction_charge": departures["leaf_satisfaction_charge"],
        "sustainability": moer * g,
        "rejected": even * terms["rejected"],
        "battery_degradation": jnp.where(is_port, 0.0, jnp.maximum(-e, 0.0)),
        "car_degradation": jnp.where(is_port & (g < 0), -g, 0.0),
        "grid_demand": even * terms["grid_demand"],
    }
    assert tuple(out) == PENALTY_TERMS
    return out


def leaf_reward_shares(
    flows: dict,
    departures: dict,
    terms: dict,
    moer,
    terminal_eur,
    p_buy,
    p_sell_grid,
    r,
    params: EnvParams,
    peak_charge_eur=0.0,
    leaf_wear_eur=0.0,
) -> jnp.ndarray:
    """Each leaf's share ``(L,)`` of the step reward ``r``; the shares sum to ``r``.

    A leaf's share is the money its own energy made minus the penalties it caused: what its
    car paid (``p_sell`` times the energy into the car, `billed_car_kwh`) minus its grid cost
    (`leaf_grid_cost_eur`, which does not move with other leaves' actions), the
    batteries' terminal value to the batteries, each battery's wear (``leaf_wear_eur``,
    `battery_wear_eur`) to that battery, and the weighted penalty terms split by
    `leaf_penalty_terms`. The fixed cost and the peak-demand charge are split evenly. The
    multi-agent view mixes these shares into per-agent rewards when asked to
    (``ChargaxMARL(local_reward_weight=...)``).

    The batteries' terminal value is split evenly over the batteries. What float32 round-off
    leaves between the shares' sum and ``r`` is spread evenly over the leaves.

    Args:
        flows: the step's energy flows (`chargax_marl.core.physics.energy_flows`).
        departures: the report of `chargax_marl.core.traffic.depart`.
        terms: the step's unweighted terms (`penalty_terms`).
        moer: ``()`` the step's marginal emission rate (kg CO2/kWh).
        terminal_eur: ``()`` the batteries' terminal value booked this step (EUR).
        p_buy: the buy price (EUR/kWh).
        p_sell_grid: the feed-in price (EUR/kWh).
        r: ``()`` the step's reward (EUR).
        params: the environment parameters.
        peak_charge_eur: ``()`` the peak-demand charge booked this step (EUR).
        leaf_wear_eur: ``(L,)`` each leaf's battery wear this step (EUR; `battery_wear_eur`),
            or a scalar.

    Returns:
        ``(L,)`` EUR, summing to ``r``.
    """
    st = params.station
    num_leaves = flows["leaf_grid_kwh"].shape[0]
    is_bat = st.leaf_kind == KIND_BATTERY
    billed, _ = billed_car_kwh(flows, params)
    own = params.customer_price_eur_kwh * billed - leaf_grid_cost_eur(flows, p_buy, p_sell_grid)
    own = own + jnp.where(is_bat, terminal_eur / max(st.num_batteries, 1), 0.0) - leaf_wear_eur
    per_leaf = leaf_penalty_terms(flows, departures, terms, moer, st)
    penalty = weighted_penalty(params.alpha, per_leaf)
    shares = own - penalty - (params.fixed_cost_eur + peak_charge_eur) / num_leaves
    # float round-off only: the parts above add up to r exactly in real arithmetic
    return shares + (r - jnp.sum(shares)) / num_leaves


def penalty_terms(
    flows: dict, departures: dict, arrivals: dict, excess_kw, moer, grid_demand_kwh
) -> dict:
    """The unweighted penalty terms c of Appendix A.3, keyed as `PENALTY_TERMS`.

    Args:
        flows: the step's energy flows (`chargax_marl.core.physics.energy_flows`).
        departures: the report of `chargax_marl.core.traffic.depart`.
        arrivals: the report of `chargax_marl.core.traffic.place_arrivals` (its
            ``rejected``).
        excess_kw: ``()`` the grid-side excess over the node limits that flowed (kW).
        moer: ``()`` the step's marginal emission rate (kg CO2/kWh).
        grid_demand_kwh: ``()`` the step's grid-demand signal (kWh).

    Returns:
        ``{name: ()}``: ``constraint`` (kW), ``satisfaction_time`` (kWh),
        ``satisfaction_charge`` (minutes), ``sustainability`` (kg CO2, MOER times the net
        grid energy, negative under net feed-in), ``rejected`` (cars),
        ``battery_degradation`` (kWh discharged from batteries), ``car_degradation`` (kWh
        fed to the grid from cars) and ``grid_demand`` (kWh of ``|delivered - demand|``).
    """
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
    """``r = profit - sum_c alpha_c * c``.

    Args:
        profit: ``()`` the step's profit (EUR).
        terms: the unweighted penalty terms (`penalty_terms`).
        params: the environment parameters (``alpha``).

    Returns:
        ``()`` the reward (EUR).
    """
    return profit - weighted_penalty(params.alpha, terms)


def weighted_penalty(alpha, terms: dict):
    """``sum_c alpha_c * terms[c]`` over `PENALTY_TERMS` (scalars or per-leaf arrays).

    A zero weight contributes exactly 0, whatever its term (also a non-finite one). With the
    weights known at compile time (params closed over, as in the trainers and benchmarks) XLA
    folds the select and drops the computation of every unweighted term, which ``0 * term``
    does not allow (``0 * inf`` is NaN): with the default all-zero weights a step computed
    every penalty term for nothing (``docs/performance.md``).

    Args:
        alpha: the weights (`PenaltyWeights`, or anything with an attribute per term).
        terms: ``{name: value}`` over `PENALTY_TERMS`, scalars or per-leaf ``(L,)`` arrays.

    Returns:
        The weighted sum (EUR), shaped as the terms.
    """
    return sum(
        jnp.where(getattr(alpha, name) != 0, getattr(alpha, name) * terms[name], 0.0)
        for name in PENALTY_TERMS
    )
