"""The model of DESIGN.md sections 3-5, checked against hand computations on small states."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core import Battery, Port, Splitter, make_params, simulator
from chargax_marl.core.observation import PRICE_SCALE_EUR_KWH, context_features
from chargax_marl.core.physics import discharge_curve_kw, rate_curve_kw
from tests.helpers import exact_jit, no_arrivals, place_car, start, three_level_station

KEY = jax.random.PRNGKey(0)
DT_H = 5.0 / 60.0
step = jax.jit(simulator.step)


@pytest.fixture(scope="module")
def params():
    return no_arrivals(make_params(station=three_level_station()))


def levels(params, **by_leaf):
    names = params.station.leaf_names
    out = np.zeros(len(names), np.int32)
    for name, lvl in by_leaf.items():
        out[names.index(name)] = lvl
    return jnp.asarray(out)


# ------------------------------------------------------------------ rate curve


def test_rate_curve_values():
    r = np.asarray(
        rate_curve_kw(jnp.array([0.0, 0.5, 0.8, 0.9, 1.0]), jnp.float32(40.0), jnp.float32(0.8))
    )
    np.testing.assert_allclose(r, [40.0, 40.0, 40.0, 20.0, 0.0], rtol=1e-5, atol=1e-5)
    d = np.asarray(
        discharge_curve_kw(jnp.array([1.0, 0.5, 0.15, 0.0]), jnp.float32(40.0), jnp.float32(0.8))
    )
    np.testing.assert_allclose(d, [40.0, 40.0, 30.0, 0.0], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("soc, expected_kw", [(0.5, 40.0), (0.9, 20.0)])
def test_car_charges_at_rbar_below_tau_and_taper_above(params, soc, expected_kw):
    s = place_car(start(params), 0, soc=soc, capacity_kwh=1000.0, max_rate_kw=40.0, tau=0.8)
    s2, info = step(KEY, s, levels(params, dc0=10), params)
    assert float(info.leaf_energy_kwh[0]) == pytest.approx(expected_kw * DT_H, rel=1e-5)
    assert float(s2.current_a[0]) == pytest.approx(expected_kw * 1000 / 500, rel=1e-5)
    assert float(s2.soc[0]) == pytest.approx(soc + expected_kw * DT_H / 1000.0, rel=1e-5)


def test_discrete_levels_absolute_and_delta(params):
    s = place_car(start(params), 0, soc=0.2, capacity_kwh=1000.0, max_rate_kw=1000.0)
    s1, _ = step(KEY, s, levels(params, dc0=3), params)
    assert float(s1.current_a[0]) == pytest.approx(0.3 * 200.0, rel=1e-5)
    s2, _ = step(KEY, s1, levels(params, dc0=-2), params)  # absolute: discharge at 20 % of 200 A
    assert float(s2.current_a[0]) == pytest.approx(-0.2 * 200.0, rel=1e-5)
    delta = params.replace(action_mode="delta")
    s3, _ = step(KEY, s1, levels(params, dc0=2), delta)  # delta: 60 A + 2/10 * 200 A
    assert float(s3.current_a[0]) == pytest.approx(100.0, rel=1e-5)
    cont = params.replace(action_mode="continuous")
    s4, _ = step(KEY, s, jnp.zeros(7).at[0].set(0.25), cont)
    assert float(s4.current_a[0]) == pytest.approx(50.0, rel=1e-5)


def test_out_of_range_levels_are_clipped(params):
    s = place_car(start(params), 4, soc=0.2, capacity_kwh=1000.0, max_rate_kw=1000.0)
    _, info_max = step(KEY, s, levels(params, ac0=10), params)
    _, info_over = step(KEY, s, levels(params, ac0=99), params)
    assert float(info_over.leaf_energy_kwh[4]) == float(info_max.leaf_energy_kwh[4]) > 0
    no_v2g = params.replace(v2g=False)
    _, info_neg = step(KEY, s, levels(params, ac0=-10), no_v2g)
    assert float(info_neg.leaf_energy_kwh[4]) == 0.0


def test_discharge_never_below_arrival_soc(params):
    s = place_car(start(params), 0, soc=0.31, arrival_soc=0.3, capacity_kwh=60.0, max_rate_kw=100.0)
    s1, info = step(KEY, s, levels(params, dc0=-10), params)
    assert float(info.leaf_energy_kwh[0]) == pytest.approx(-0.6, rel=1e-4)
    assert float(s1.soc[0]) == pytest.approx(0.3, abs=1e-6)
    s2, info2 = step(KEY, s1, levels(params, dc0=-10), params)
    assert float(info2.leaf_energy_kwh[0]) == 0.0 and float(s2.soc[0]) >= 0.3 - 1e-7


def test_mirrored_discharge_curve_limits_current(params):
    # SoC 0.15 -> mirrored SoC 0.85 > tau: 0.15 * 40 / 0.2 = 30 kW
    s = place_car(
        start(params), 0, soc=0.15, arrival_soc=0.0, capacity_kwh=1000.0, max_rate_kw=40.0, tau=0.8
    )
    _, info = step(KEY, s, levels(params, dc0=-10), params)
    assert float(info.leaf_energy_kwh[0]) == pytest.approx(-30.0 * DT_H, rel=1e-5)


def test_capacity_clip_and_totals_use_energy_actually_moved(params):
    s = place_car(start(params), 0, soc=0.99, capacity_kwh=60.0, max_rate_kw=1000.0, tau=0.999)
    s1, info = step(KEY, s, levels(params, dc0=10), params)
    assert float(info.leaf_energy_kwh[0]) == pytest.approx(0.6, rel=1e-4)  # not 100 kW * 5 min
    assert float(s1.soc[0]) == pytest.approx(1.0)
    assert float(s1.totals.energy_charged_kwh) == pytest.approx(0.6, rel=1e-4)
    eta = float(params.station.leaf_path_efficiency[0])
    assert float(info.grid_net_kwh) == pytest.approx(0.6 / eta, rel=1e-4)
    assert float(s1.current_a[0]) == pytest.approx(0.6 / DT_H * 1000 / 500, rel=1e-4)


# ------------------------------------------------------------------ node limits and the battery


def test_battery_counts_against_node_limits_and_is_priced():
    tree = Splitter(
        "grid",
        60.0,
        (
            Port("p", "DC", 500.0, 100.0, 100.0, 0.9),
            Battery("b", capacity_kwh=500.0, max_kw=50.0, voltage_v=500.0, efficiency=0.8),
        ),
    )
    p = no_arrivals(make_params(station=tree, grid_fee_eur_kwh=0.1))
    s = place_car(start(p), 0, soc=0.2, capacity_kwh=1000.0, max_rate_kw=1000.0)
    s1, info = step(KEY, s, jnp.array([10, 10]), p)
    e = np.asarray(info.leaf_energy_kwh)
    # 2 x 50 kW asked, 50/0.9 + 50/0.8 kW on the grid side, 60 kW allowed there: both scale by k
    k = 60.0 / (50.0 / 0.9 + 50.0 / 0.8)
    np.testing.assert_allclose(e, [50.0 * k * DT_H, 50.0 * k * DT_H], rtol=1e-4)
    grid = 60.0 * DT_H
    assert float(info.grid_net_kwh) == pytest.approx(grid, rel=1e-4)
    assert float(info.battery_net_kwh) == pytest.approx(50.0 * k * DT_H, rel=1e-4)
    spot = float(p.prices_eur_kwh[0, 0])
    # the battery's cells wear per kWh moved into them (default cost and cycle life)
    wear = Battery().wear_eur_kwh * 50.0 * k * DT_H
    assert float(info.battery_wear_eur) == pytest.approx(wear, rel=1e-4)
    assert float(info.profit_eur) == pytest.approx(
        0.75 * 50.0 * k * DT_H - (spot + 0.1) * grid - float(p.fixed_cost_eur) - wear,
        rel=1e-4,
        abs=1e-5,
    )
    # Net flow: the battery discharging feeds the port, so nothing is rescaled.
    _, info2 = step(KEY, s, jnp.array([10, -10]), p)
    np.testing.assert_allclose(
        np.asarray(info2.leaf_energy_kwh), [50.0 * DT_H, -50.0 * DT_H], rtol=1e-4
    )
    assert float(info2.constraint_excess_kw) == 0.0


def test_node_limits_couple_ports(params):
    s = start(params)
    for i in range(4):
        s = place_car(s, i, soc=0.2, capacity_kwh=1000.0, max_rate_kw=1000.0)
    s1, info = step(KEY, s, levels(params, dc0=10, dc1=10, dc2=10, dc3=10), params)
    e = np.asarray(info.leaf_energy_kwh)[:4] / DT_H  # kW at the cars
    # evse groups first, then dc_split (200 kW on its grid side, where a port's kW count / (0.95*0.99*0.98)):
    # every port gets the same share.
    eta = 0.95 * 0.99 * 0.98
    np.testing.assert_allclose(e, e[0], rtol=1e-5)
    assert 4 * e[0] / eta == pytest.approx(200.0, rel=1e-4)
    # nothing flowed over a limit; the request exceeded dc_split by 400/eta - 200 on its grid side
    assert float(info.constraint_excess_kw) == 0.0
    assert float(info.requested_excess_kw) == pytest.approx(400 / eta - 200, rel=1e-4)


# ------------------------------------------------------------------ departures and arrivals


def test_time_sensitive_departure_at_the_right_step(params):
    s = place_car(start(params), 1, soc=0.2, capacity_kwh=100.0, remaining_kwh=50.0, time_min=10.0)
    s1, info1 = step(KEY, s, levels(params), params)
    assert bool(s1.occupied[1]) and float(info1.cars_departed) == 0
    s2, info2 = step(KEY, s1, levels(params), params)
    assert not bool(s2.occupied[1]) and float(info2.cars_departed) == 1
    assert float(info2.penalties["satisfaction_time"]) == pytest.approx(50.0)
    assert float(info2.missing_kwh) == pytest.approx(50.0)
    assert float(s2.soc[1]) == 0.0 and float(s2.energy_remaining_kwh[1]) == 0.0


def test_charge_sensitive_departure_records_over_and_undertime(params):
    beta = float(params.beta)
    s = place_car(
        start(params),
        0,
        soc=0.2,
        capacity_kwh=100.0,
        max_rate_kw=100.0,
        remaining_kwh=1.0,
        time_min=30.0,
        charge_sensitive=True,
    )
    s = place_car(
        s,
        2,
        soc=0.2,
        capacity_kwh=100.0,
        max_rate_kw=100.0,
        remaining_kwh=1.0,
        time_min=0.0,
        charge_sensitive=True,
    )
    s = place_car(
        s,
        3,
        soc=0.2,
        capacity_kwh=100.0,
        max_rate_kw=100.0,
        remaining_kwh=1.0,
        time_min=0.0,
        charge_sensitive=True,
    )  # not charged: stays although its time is over
    s1, info = step(KEY, s, levels(params, dc0=10, dc2=10), params)
    assert not bool(s1.occupied[0]) and not bool(s1.occupied[2]) and bool(s1.occupied[3])
    assert float(info.cars_departed) == 2
    # car 2 left 5 min past its plan; car 3 stays, and its 5 min past the plan count as well
    assert float(info.overtime_min) == pytest.approx(10.0)
    assert float(info.penalties["satisfaction_charge"]) == pytest.approx(10.0 - beta * 25.0)
    assert float(s1.time_remaining_min[3]) == pytest.approx(-5.0)


def test_a_late_charge_sensitive_car_that_is_never_charged_still_costs_its_overtime(params):
    """Overtime accrues while the car is parked past its plan: a policy that keeps a late car
    from its target (so it never leaves) pays every step of it, not nothing."""
    s = place_car(
        start(params),
        3,
        soc=0.2,
        capacity_kwh=100.0,
        max_rate_kw=100.0,
        remaining_kwh=10.0,
        time_min=7.0,
        charge_sensitive=True,
    )
    over = []
    for _ in range(6):
        s, info = step(KEY, s, levels(params), params)  # idle: the car never reaches its target
        over.append(float(info.overtime_min))
        assert float(info.cars_departed) == 0
    # 7 min of plan: the second step is 3 min past it, every later step 5
    np.testing.assert_allclose(over, [0.0, 3.0, 5.0, 5.0, 5.0, 5.0], atol=1e-5)
    assert float(s.totals.overtime_min) == pytest.approx(23.0, abs=1e-4)


def test_arrivals_fill_first_free_ports_and_count_rejections(params):
    flood = params.replace(arrival_rate=jnp.full_like(params.arrival_rate, 50.0))
    s = place_car(place_car(start(flood), 0, time_min=600.0), 2, time_min=600.0)
    s1, info = step(KEY, s, levels(flood), flood)
    assert np.asarray(s1.occupied).tolist() == [True] * 7
    assert float(info.cars_arrived) == 4
    requested = float(info.cars_arrived + info.cars_rejected)
    assert requested > 4 and float(info.penalties["rejected"]) == requested - 4
    # With a small rate and the first-free choice, new cars take the lowest free ports.
    trickle = params.replace(
        arrival_rate=jnp.full_like(params.arrival_rate, 1.5),
        random_port_choice=jnp.asarray(False),
    )
    s = place_car(place_car(start(trickle), 0, time_min=600.0), 2, time_min=600.0)
    seen = set()
    for k in jax.random.split(KEY, 40):
        s1, info = step(k, s, levels(trickle), trickle)
        n = int(info.cars_arrived)
        new = [i for i in range(6) if bool(s1.occupied[i]) and not bool(s.occupied[i])]
        assert new == [1, 3, 4, 5][:n]
        assert float(info.cars_rejected) == 0 or n == 4
        seen.add(n)
    assert len(seen) >= 3  # the check saw several arrival counts


def test_arrived_cars_follow_profile_and_fleet(params):
    flood = params.replace(arrival_rate=jnp.full_like(params.arrival_rate, 50.0))
    s1, _ = step(KEY, start(flood), levels(flood), flood)

    def member(x, table):
        return bool(np.any(np.isclose(np.asarray(table), float(x), rtol=1e-6)))

    for i in range(6):
        assert member(s1.capacity_kwh[i], flood.fleet_capacity_kwh)
        lo, hi = np.asarray(flood.arrival_soc_range)
        assert lo - 1e-6 <= float(s1.soc[i]) <= hi + 1e-6
        assert (
            float(s1.energy_remaining_kwh[i])
            <= (1 - float(s1.soc[i])) * float(s1.capacity_kwh[i]) + 1e-4
        )
        assert float(s1.time_remaining_min[i]) >= 5.0
    # DC ports get the DC rate, AC ports the AC rate of the drawn model.
    assert all(member(s1.max_rate_kw[i], flood.fleet_dc_kw) for i in range(4))
    assert all(member(s1.max_rate_kw[i], flood.fleet_ac_kw) for i in (4, 5))


def test_weekend_days_use_the_weekend_profile():
    base = make_params(station=three_level_station(), prices="NL-2023")
    # NL-2023 starts on a Sunday: day 0 weekend, day 1 Monday.
    assert not bool(simulator.is_workday(jnp.asarray(0), base))
    assert bool(simulator.is_workday(jnp.asarray(1), base))
    assert not bool(simulator.is_workday(jnp.asarray(6), base))
    rate = jnp.stack([jnp.zeros(288), jnp.full(288, 0.5)])  # workday: nobody, weekend: 0.5 per step
    p = base.replace(arrival_rate=rate)

    def arrivals_on(day):
        def body(s, k):
            s, info = simulator.step(k, s, jnp.zeros(7, jnp.int32), p)
            return s, info.cars_arrived + info.cars_rejected

        _, n = jax.lax.scan(body, start(p, day), jax.random.split(KEY, 288))
        return float(n.sum())

    assert arrivals_on(1) == 0.0 and arrivals_on(2) == 0.0
    assert arrivals_on(0) > 50 and arrivals_on(6) > 50


# ------------------------------------------------------------------ reward


def test_profit_uses_buy_price_on_draw_and_sell_price_on_feed_in():
    tree = Splitter("grid", 500.0, (Port("p", "DC", 500.0, 200.0, 200.0, 0.9),))
    p = no_arrivals(
        make_params(
            station=tree,
            grid_fee_eur_kwh=0.1,
            feed_in_factor=0.5,
            fixed_cost_eur=0.01,
            customer_price_eur_kwh=0.6,
        )
    )
    day, t = 10, 100  # hour 8
    spot = float(p.prices_eur_kwh[day, 8])
    s = place_car(
        start(p, day).replace(timestep=jnp.asarray(t)),
        0,
        soc=0.5,
        arrival_soc=0.1,
        capacity_kwh=1000.0,
        max_rate_kw=1000.0,
    )
    _, buy = step(KEY, s, jnp.array([10]), p)
    e = 100.0 * DT_H
    assert float(buy.grid_net_kwh) == pytest.approx(e / 0.9, rel=1e-5)
    assert float(buy.profit_eur) == pytest.approx(
        0.6 * e - (spot + 0.1) * e / 0.9 - 0.01, rel=1e-4, abs=1e-5
    )
    _, sell = step(KEY, s, jnp.array([-10]), p)
    assert float(sell.grid_net_kwh) == pytest.approx(-e * 0.9, rel=1e-5)
    assert float(sell.profit_eur) == pytest.approx(
        0.6 * -e - 0.5 * spot * (-e * 0.9) - 0.01, rel=1e-4, abs=1e-5
    )
    assert float(buy.price_buy_eur_kwh) == pytest.approx(spot + 0.1)


def test_each_penalty_term_equals_a_hand_computation():
    tree = three_level_station()
    moer = np.full(288, 0.4, np.float32)
    demand = np.full(288, 3.0, np.float32)
    alpha = {
        "constraint": 1.0,
        "satisfaction_time": 2.0,
        "satisfaction_charge": 0.5,
        "sustainability": 0.1,
        "rejected": 3.0,
        "battery_degradation": 0.2,
        "car_degradation": 0.3,
        "grid_demand": 0.05,
    }
    p = make_params(
        station=tree,
        constraint_mode="soft",
        moer_kg_per_kwh=moer,
        grid_demand_kwh=demand,
        alpha=alpha,
        beta=0.5,
    )
    p = p.replace(arrival_rate=jnp.full_like(p.arrival_rate, 40.0))
    s = start(p)
    s = place_car(
        s, 0, soc=0.5, arrival_soc=0.2, capacity_kwh=1000.0, max_rate_kw=1000.0, time_min=600.0
    )
    s = place_car(
        s, 1, soc=0.2, capacity_kwh=100.0, remaining_kwh=7.0, time_min=5.0
    )  # leaves, misses
    s = place_car(s, 4, soc=0.2, capacity_kwh=1000.0, max_rate_kw=1000.0, time_min=600.0)
    s = place_car(s, 5, soc=0.2, capacity_kwh=1000.0, max_rate_kw=1000.0, time_min=600.0)
    act = jnp.array(
        [-5, 0, 0, 0, 10, 10, -10]
    )  # dc0 discharges 50 A, AC both full, battery discharges
    s1, info = step(KEY, s, act, p)
    eta = np.asarray(p.station.leaf_path_efficiency)
    e_dc0 = -0.5 * 200 * 500 / 1000 * DT_H
    e_ac = 32 * 400 / 1000 * DT_H
    e_bat = -50.0 * DT_H
    np.testing.assert_allclose(
        np.asarray(info.leaf_energy_kwh), [e_dc0, 0, 0, 0, e_ac, e_ac, e_bat], rtol=1e-5
    )
    grid = e_dc0 * eta[0] + e_ac / eta[4] + e_ac / eta[5] + e_bat * eta[6]
    delivered = e_dc0 + 2 * e_ac
    # Grid-side node flows: ac_split 25.6 / (0.97 * 0.99) kW vs 20 kW (the ports' losses count); the grid
    # connection nets far below its limit. The largest excess is the AC splitter's.
    ac_excess = 2 * 12.8 / (0.97 * 0.99) - 20.0
    terms = {k: float(v) for k, v in info.penalties.items()}
    assert terms["constraint"] == pytest.approx(ac_excess, rel=1e-4)
    assert terms["satisfaction_time"] == pytest.approx(7.0, rel=1e-5)
    assert terms["satisfaction_charge"] == pytest.approx(0.0)
    assert terms["sustainability"] == pytest.approx(0.4 * grid, rel=1e-4)
    requested = float(info.cars_arrived + info.cars_rejected)
    free_after_departure = 3  # ports 1, 2, 3
    assert terms["rejected"] == pytest.approx(max(requested - free_after_departure, 0))
    assert terms["battery_degradation"] == pytest.approx(-e_bat, rel=1e-5)
    assert terms["car_degradation"] == pytest.approx(-e_dc0 * eta[0], rel=1e-5)
    assert terms["grid_demand"] == pytest.approx(abs(delivered - 3.0), rel=1e-5)
    assert float(info.grid_net_kwh) == pytest.approx(grid, rel=1e-5)
    expected_reward = float(info.profit_eur) - sum(alpha[k] * terms[k] for k in alpha)
    assert float(info.reward) == pytest.approx(expected_reward, rel=1e-5)
    # Soft mode: nothing was rescaled although the AC splitter is over its limit.
    assert float(info.leaf_energy_kwh[4]) == pytest.approx(e_ac, rel=1e-6)


def test_a_zero_weight_contributes_exactly_zero_and_its_term_is_not_computed():
    """``r = profit - sum_c alpha_c c`` with ``alpha_c = 0`` must not depend on ``c`` at all:
    not even a non-finite term may leak in (``0 * inf`` is NaN), and with the weights fixed at
    compile time the compiled step drops the unweighted terms (the default all-zero weights
    made every step compute them all)."""
    from chargax_marl.core import reward as reward_lib
    from chargax_marl.core.types import PENALTY_TERMS

    p0 = make_params(station=three_level_station())
    terms = {name: jnp.float32(jnp.inf) for name in PENALTY_TERMS}
    assert float(reward_lib.reward(jnp.float32(5.0), terms, p0)) == 5.0
    p1 = make_params(station=three_level_station(), alpha={"satisfaction_time": 2.0})
    terms = {**terms, "satisfaction_time": jnp.float32(1.5)}
    assert float(reward_lib.reward(jnp.float32(5.0), terms, p1)) == 2.0

    # The compiled step with the weights closed over: the constraint term (the node sums of the
    # currents that flow, three scatters on this 3-level station) is there only when weighted.
    action = jnp.zeros((p0.station.num_leaves,), jnp.int32)

    def scatters(prm):
        fn = exact_jit(lambda k, s_: simulator.step(k, s_, action, prm)[1].reward)
        return fn.lower(KEY, start(prm)).compile().as_text().count(" scatter(")

    weighted = make_params(station=three_level_station(), alpha={"constraint": 1.0})
    assert scatters(p0) < scatters(weighted)


def test_price_lookahead_past_midnight_reads_next_day(params):
    s = start(params, day=5).replace(timestep=jnp.asarray(287))
    ctx = np.asarray(context_features(s, params)) * PRICE_SCALE_EUR_KWH
    prices = np.asarray(params.prices_eur_kwh)
    assert ctx[0] == pytest.approx(prices[5, 23], rel=1e-5)
    np.testing.assert_allclose(ctx[1:7], prices[6, 0:6], rtol=1e-5)


def test_a_step_returns_a_state_of_the_reset_states_types():
    """Every leaf of the reset state keeps its shape, dtype and (strong) type through a step and
    an auto-reset, so a jitted loop that feeds the state back compiles once (a weakly typed leaf
    made every trainer compile its training program twice)."""
    from chargax_marl.marl import ChargaxMARL
    from chargax_marl.single import Chargax

    params = make_params(station=three_level_station())

    def avals(tree):
        return [
            (jax.tree_util.keystr(p), x.shape, x.dtype, x.aval.weak_type)
            for p, x in jax.tree_util.tree_leaves_with_path(tree)
        ]

    state = simulator.reset(KEY, params)
    levels = jnp.zeros((params.station.num_leaves,), jnp.int32)
    assert avals(jax.jit(simulator.step)(KEY, state, levels, params)[0]) == avals(state)
    assert not any(weak for *_, weak in avals(state))
    env = Chargax(params=params)
    _, s = env.reset(KEY, params)
    action = env.action_space(params).sample(KEY)
    assert avals(jax.jit(env.step)(KEY, s, action, params)[1]) == avals(s)
    marl = ChargaxMARL(params=params)
    _, s = marl.reset(KEY)
    acts = {a: jnp.int32(0) for a in marl.agents}
    assert avals(jax.jit(marl.step)(KEY, s, acts)[1]) == avals(s)
