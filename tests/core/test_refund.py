"""Refunding energy discharged from customers' cars (``refund_discharged_energy``).

The default refunds it (customers pay for the net energy delivered); ``False`` bills only the
energy put into each car, the original Chargax accounting. The simulator's profit, the
per-leaf reward shares and the LP bound must all price the same thing. Hand cases: flat
0.10 EUR/kWh, no losses, no grid fee or fixed cost, customer price 0.75.
"""

from __future__ import annotations

import dataclasses
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl import optimal, policies, trace
from chargax_marl.core import datasets, physics, simulator
from chargax_marl.core import reward as reward_lib
from chargax_marl.core.params import make_params
from chargax_marl.core.station import Battery, Port, Splitter
from chargax_marl.optimal.mpc import MPC
from tests.helpers import no_arrivals, place_car, start

KEY = jax.random.PRNGKey(0)
PRICE, CUSTOMER = 0.10, 0.75
STEP = jax.jit(simulator.step)  # the refund flag is an array field: one compile serves both modes


def v2g_station() -> Splitter:
    """Two 50 kW DC ports that may discharge and a 100 kWh battery, all without losses."""
    ports = tuple(Port(f"p{i}", "DC", 500.0, 100.0, 100.0, 1.0) for i in range(2))
    bat = Battery("bat", capacity_kwh=100.0, max_kw=50.0, efficiency=1.0, tau=0.99, initial_soc=0.5)
    return Splitter("grid", 1000.0, ports + (bat,), efficiency=1.0)


def flat_params(refund=True, station=None, **kw):
    return make_params(
        station=station or v2g_station(),
        prices=np.full((2, 24), PRICE, np.float32),
        grid_fee_eur_kwh=0.0,
        fixed_cost_eur=0.0,
        customer_price_eur_kwh=CUSTOMER,
        refund_discharged_energy=refund,
        **kw,
    )


# --------------------------------------------------------------------------- the option


def test_refund_is_the_default():
    assert bool(make_params().refund_discharged_energy) is True
    assert bool(make_params(refund_discharged_energy=False).refund_discharged_energy) is False
    assert (
        bool(make_params(refund_discharged_energy=np.bool_(False)).refund_discharged_energy)
        is False
    )


@pytest.mark.parametrize("bad", ["yes", 1, 0, 1.0, None, "False"])
def test_a_bad_refund_flag_names_the_field_the_value_and_what_is_allowed(bad):
    with pytest.raises(
        ValueError, match=r"refund_discharged_energy.*must be a bool.*got " + re.escape(repr(bad))
    ):
        make_params(refund_discharged_energy=bad)


# --------------------------------------------------------------------------- one step by hand


def _v2g_step(refund):
    """Port 0's car (SoC 0.5, arrived at 0.2) discharges at 50 kW, port 1's charges at 20 kW."""
    p = no_arrivals(flat_params(refund, alpha={"car_degradation": 0.01}))
    s = place_car(
        start(p),
        0,
        soc=0.5,
        arrival_soc=0.2,
        capacity_kwh=100.0,
        max_rate_kw=50.0,
        tau=0.99,
        time_min=600.0,
    )
    s = place_car(s, 1, soc=0.2, capacity_kwh=100.0, max_rate_kw=50.0, tau=0.99, time_min=600.0)
    _, info = STEP(KEY, s, jnp.array([-10, 4, 0]), p)
    return info


def test_a_discharging_car_is_refunded_only_with_the_refund():
    on, off = _v2g_step(True), _v2g_step(False)
    e_dis, e_chg = 50.0 / 12.0, 20.0 / 12.0
    # the same energies flow either way
    for info in (on, off):
        assert float(info.energy_discharged_kwh) == pytest.approx(e_dis, rel=1e-5)
        assert float(info.energy_charged_kwh) == pytest.approx(e_chg, rel=1e-5)
        assert float(info.grid_net_kwh) == pytest.approx(
            e_chg - e_dis, rel=1e-5
        )  # a net feed-in at 0.10
    assert float(on.profit_eur) == pytest.approx(
        CUSTOMER * (e_chg - e_dis) - PRICE * (e_chg - e_dis), rel=1e-5
    )
    assert float(off.profit_eur) == pytest.approx(
        CUSTOMER * e_chg - PRICE * (e_chg - e_dis), rel=1e-5
    )
    assert float(off.profit_eur - on.profit_eur) == pytest.approx(CUSTOMER * e_dis, rel=1e-5)
    # the shares add up to the reward in both modes, and only the discharging car's share moves
    for info in (on, off):
        assert float(np.sum(info.leaf_reward)) == pytest.approx(float(info.reward), abs=1e-5)
    d = np.asarray(off.leaf_reward) - np.asarray(on.leaf_reward)
    np.testing.assert_allclose(d, [CUSTOMER * e_dis, 0.0, 0.0], atol=1e-5)


def test_a_charging_car_and_the_battery_pay_the_same_in_both_modes():
    infos = {}
    for refund in (True, False):
        p = no_arrivals(flat_params(refund))
        s = place_car(
            start(p), 1, soc=0.2, capacity_kwh=100.0, max_rate_kw=50.0, tau=0.99, time_min=600.0
        )
        _, infos[refund] = STEP(KEY, s, jnp.array([0, 10, -10]), p)  # battery discharges: not a car
    assert float(infos[True].profit_eur) == float(infos[False].profit_eur)
    np.testing.assert_array_equal(
        np.asarray(infos[True].leaf_reward), np.asarray(infos[False].leaf_reward)
    )
    assert float(infos[True].battery_net_kwh) < 0.0


# --------------------------------------------------------------------------- a day of random levels


@pytest.fixture(scope="module")
def random_days():
    """A day of random valid levels with and without the refund (the same keys, cars and
    levels) and with the default, on a small V2G station whose cars may all discharge."""
    station = Splitter(
        "grid",
        220.0,
        (
            Splitter(
                "dc",
                200.0,
                tuple(Port(f"dc{i}", "DC", 500.0, 200.0, 200.0, 0.95) for i in range(4)),
                0.98,
            ),
            Splitter(
                "ac",
                20.0,
                tuple(Port(f"ac{i}", "AC", 400.0, 32.0, 16.0, 0.97) for i in range(2)),
                0.99,
            ),
            Battery(
                "bat", capacity_kwh=100.0, max_kw=50.0, efficiency=0.95, tau=0.8, initial_soc=0.5
            ),
        ),
    )
    eu = datasets.load_fleet("EU")
    fleet = dataclasses.replace(
        eu, max_ac_discharge_kw=eu.max_ac_kw, max_dc_discharge_kw=eu.max_dc_kw
    )
    kw = dict(
        station=station,
        traffic=150.0,
        fleet=fleet,
        alpha={"car_degradation": 0.02, "satisfaction_time": 0.1},
    )

    @jax.jit
    def day(p):
        def body(s, k):
            k1, k2 = jax.random.split(k)
            s2, info = simulator.step(k2, s, policies.random_policy(s, k1, p), p)
            return s2, info

        return jax.lax.scan(body, simulator.reset(KEY, p), jax.random.split(KEY, p.num_steps))[1]

    params = {r: make_params(**kw, refund_discharged_energy=r) for r in (True, False)}
    params["default"] = make_params(**kw)
    return params, {k: jax.device_get(day(p)) for k, p in params.items()}


def test_the_refund_changes_the_books_not_the_trajectory(random_days):
    _, infos = random_days
    on, off = infos[True], infos[False]
    np.testing.assert_array_equal(on.leaf_energy_kwh, off.leaf_energy_kwh)
    discharged = np.asarray(on.energy_discharged_kwh, np.float64)
    assert discharged.sum() > 10.0, "the random levels discharge cars"
    np.testing.assert_allclose(
        np.asarray(off.profit_eur, np.float64) - np.asarray(on.profit_eur, np.float64),
        CUSTOMER * discharged,
        rtol=1e-4,
        atol=1e-4,
    )
    assert np.all(np.asarray(off.reward) >= np.asarray(on.reward) - 1e-5)
    for info in (on, off):
        np.testing.assert_allclose(info.leaf_reward.sum(-1), info.reward, rtol=1e-5, atol=1e-4)


def test_the_default_books_exactly_what_it_did_before(random_days):
    params, infos = random_days
    on = infos[True]
    # the default is the refund, bit for bit
    for a, b in zip(jax.tree_util.tree_leaves(infos["default"]), jax.tree_util.tree_leaves(on)):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()
    # and it books the net energy delivered at the customer price, the formula before the option;
    # evaluated op by op, the same float32 operations give the same bits
    p = params[True]
    steps = np.nonzero(np.asarray(on.energy_discharged_kwh) > 0)[0]
    assert steps.size > 5
    for t in steps[:5]:
        flows = physics.energy_flows(jnp.asarray(on.leaf_energy_kwh[t]), p.station)
        buy, sell = jnp.asarray(on.price_buy_eur_kwh[t]), jnp.asarray(on.price_sell_grid_eur_kwh[t])
        grid_price = reward_lib.station_grid_price(flows, buy, sell)
        before = (
            p.customer_price_eur_kwh * flows["delivered_kwh"]
            - grid_price * flows["grid_net_kwh"]
            - p.fixed_cost_eur
        )
        assert (
            np.asarray(reward_lib.profit_eur(flows, buy, sell, p)).tobytes()
            == np.asarray(before).tobytes()
        )
        billed, _ = reward_lib.billed_car_kwh(flows, p)
        assert np.asarray(billed).tobytes() == np.asarray(flows["leaf_car_kwh"]).tobytes()
        # the step's profit is that, less the battery's wear (booked beside it)
        assert float(on.profit_eur[t]) == pytest.approx(
            float(before) - float(on.battery_wear_eur[t]), rel=1e-6, abs=1e-6
        )


# --------------------------------------------------------------------------- the LP bound

ONE_PORT = Splitter("grid", 1000.0, (Port("p0", "DC", 500.0, 100.0, 100.0, 1.0),), efficiency=1.0)
CAR = dict(
    arrival_step=0,
    capacity_kwh=100.0,
    dc_kw=50.0,
    dc_discharge_kw=50.0,
    tau=0.99,
    arrival_soc=0.2,
    target_soc=0.6,
    stay_min=60.0,
)


def _one_car(refund, policy):
    p = flat_params(refund, station=ONE_PORT)
    tr = trace.trace_from_cars(p, [CAR])
    return optimal.hindsight_bound(p, tr, optimal.occupancy(p, tr, KEY, reference=policy))


def test_the_lp_prices_the_refund_by_hand():
    # one car, 12 steps at up to 50 kW (4.17 kWh a step either way), SoC between its arrival 0.2
    # and its target 0.6 (40 kWh apart). With the refund it pays the net: 40 kWh * 0.65 = 26.
    # Without it a kWh charged earns 0.65 and a kWh discharged 0.10; charged C and discharged D
    # share the 50 kWh a port can pass in the hour (it charges or discharges in a step, not both)
    # and C - D <= 40: C = 45, D = 5 -> 29.25 + 0.5 = 29.75.
    on = _one_car(True, policies.always_max)
    off = _one_car(False, policies.always_max)
    assert on.profit_eur == pytest.approx(26.0, abs=1e-4)
    assert off.profit_eur == pytest.approx(29.75, abs=1e-4)
    assert on.reference_profit_eur == pytest.approx(
        off.reference_profit_eur, abs=1e-6
    )  # always-max never discharges
    # discharging the car in its last two steps (8.33 kWh) loses 0.65 a kWh with the refund and
    # earns 0.10 a kWh without; the bound stays above it
    dep_on = _one_car(True, policies.discharge_departing)
    dep_off = _one_car(False, policies.discharge_departing)
    assert dep_on.reference_profit_eur == pytest.approx(26.0 - 0.65 * 50 / 6, abs=1e-3)
    assert dep_off.reference_profit_eur == pytest.approx(26.0 + 0.10 * 50 / 6, abs=1e-3)
    assert dep_off.profit_eur >= dep_off.reference_profit_eur > on.profit_eur


def test_the_bound_without_the_refund_is_above_the_bound_with_it_and_the_rules():
    # the default station (4 DC, 2 AC) on a busy day: a tenth of the EU fleet may discharge at DC
    # the paper's sessions: time-sensitive users at the DC ports, whom discharging reaches
    kw = dict(station_kwargs={"num_dc": 4, "num_ac": 2}, traffic="high", session_model="paper")
    on, off = make_params(**kw), make_params(**kw, refund_discharged_energy=False)
    tr = trace.day_of(trace.make_traces(on, np.array([30]), KEY), 0)
    b_on = optimal.hindsight_bound(on, tr, optimal.occupancy(on, tr, KEY))
    b_off = optimal.hindsight_bound(off, tr, optimal.occupancy(off, tr, KEY))
    assert b_off.reference_profit_eur == pytest.approx(b_on.reference_profit_eur, abs=1e-3)
    assert b_on.profit_eur >= b_on.reference_profit_eur - 1e-3 * abs(b_on.reference_profit_eur)
    assert b_off.profit_eur > b_on.profit_eur + 1.0
    # discharging departing cars earns money without the refund, and stays under that bound
    dep = optimal.hindsight_bound(
        off, tr, optimal.occupancy(off, tr, KEY, reference=policies.discharge_departing)
    )
    assert dep.reference_profit_eur > b_off.reference_profit_eur
    assert dep.profit_eur >= dep.reference_profit_eur - 1e-3 * abs(dep.reference_profit_eur)


def test_the_mpc_prices_the_refund_too(monkeypatch):
    # the hand case above: with the refund the MPC's first plan is worth the 40 kWh charged (26
    # EUR), and it books that; without it, the plan is worth more (taking energy back and
    # charging it again bills the car twice). The LP has several optimal plans then, and which
    # one the solver returns decides the booked profit, between the 26 EUR charge and the
    # bound's 29.75.
    from chargax_marl.optimal import mpc as mpc_module

    solve = mpc_module.build_and_solve
    values = []

    def recording(*args, **kwargs):
        solution = solve(*args, **kwargs)
        values.append(solution.value_eur)
        return solution

    monkeypatch.setattr(mpc_module, "build_and_solve", recording)
    profit, first_plan = {}, {}
    for refund in (True, False):
        values.clear()
        p = flat_params(refund, station=ONE_PORT)
        tr = trace.trace_from_cars(p, [CAR])
        mpc = MPC(p)
        _, _, final = jax.jit(lambda t, k: trace.replay(lambda s, kk: mpc(s, kk, p), p, t, k))(
            tr, KEY
        )
        profit[refund], first_plan[refund] = float(final.totals.profit_eur), values[0]
        assert mpc.failures == 0
    assert first_plan[True] == pytest.approx(26.0, abs=1e-3)
    assert profit[True] == pytest.approx(26.0, abs=0.05)
    assert first_plan[False] > first_plan[True] + 1.0
    assert 26.0 - 0.05 <= profit[False] <= 29.75 + 1e-3


def test_the_measurement_script_runs_on_a_few_days():
    from baselines.experiments import refund

    profits = refund.daily_profits(
        "shopping", rules=("always_max", "discharge_departing"), num_eval=3, fleet=refund.all_v2g()
    )
    on, off = profits["discharge_departing", True], profits["discharge_departing", False]
    assert on.shape == (3,) and np.all(off > on)
    np.testing.assert_array_equal(profits["always_max", True], profits["always_max", False])
    table = refund.format_table(profits, rules=("always_max", "discharge_departing"))
    assert "off - on" in table and table.count("\n") == 2
