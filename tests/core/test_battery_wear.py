"""The station battery's wear: a cost per kWh of cell throughput plus optional calendar ageing,
booked in the profit, reported every step and in the totals, and given to the battery's share."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core import Battery, Port, Splitter, make_params, simulator
from chargax_marl.core.station import KIND_BATTERY
from tests.helpers import no_arrivals, start

KEY = jax.random.PRNGKey(0)


def _station(**battery):
    return Splitter(
        "grid",
        500.0,
        (
            Port("p", "DC", 500.0, 200.0, 0.0, 0.95),
            Battery("b", **{"capacity_kwh": 10.0, "max_kw": 60.0, "tau": 0.5, **battery}),
        ),
    )


def _run(p, battery_levels, state=None):
    """Step an empty port with the battery at ``battery_levels`` (one per step); return the
    final state and the stacked infos."""
    state = start(p) if state is None else state

    def body(s, lv):
        action = jnp.where(p.station.leaf_kind == KIND_BATTERY, lv, 0).astype(jnp.int32)
        return simulator.step(KEY, s, action, p)

    return jax.lax.scan(body, state, jnp.asarray(battery_levels, jnp.int32))


def test_wear_cost_per_kwh_of_throughput_is_half_a_cycle_of_the_installed_cost():
    assert Battery().wear_eur_kwh == pytest.approx(150.0 / (2 * 6000.0))
    assert Battery(cost_eur_kwh=300.0, cycle_life=3000.0).wear_eur_kwh == pytest.approx(0.05)
    assert Battery(cost_eur_kwh=0.0).wear_eur_kwh == 0.0
    assert Battery().calendar_eur_day == 0.0
    b = Battery(capacity_kwh=200.0, cost_eur_kwh=150.0, calendar_life_years=15.0)
    assert b.calendar_eur_day == pytest.approx(150.0 * 200.0 / (15 * 365))


def test_a_full_cycle_costs_the_installed_cost_over_the_cycle_life():
    # 10 kWh at 150 EUR/kWh and 6000 cycles: one full cycle (empty, full, empty) uses 1/6000
    # of 1500 EUR, 0.25 EUR, booked step by step as the cells take in and give back energy
    p = no_arrivals(make_params(station=_station(initial_soc=0.0), first_weekday=0))
    final, info = _run(p, [10] * 60 + [-10] * 60 + [0] * 168)
    soc = np.asarray(final.soc)[-1]
    assert soc == pytest.approx(0.0, abs=1e-4)
    moved = np.abs(np.asarray(info.leaf_energy_kwh)[:, -1])
    assert moved.sum() == pytest.approx(20.0, rel=1e-4)  # into the cells and back out
    np.testing.assert_allclose(np.asarray(info.battery_wear_eur), 0.0125 * moved, rtol=1e-5)
    assert float(final.totals.battery_wear_eur) == pytest.approx(0.25, rel=1e-4)
    # and the profit is what it would be without wear, minus the wear
    free = p.replace(battery_wear_eur_kwh=jnp.zeros((1,)))
    final_free, _ = _run(free, [10] * 60 + [-10] * 60 + [0] * 168)
    assert float(final_free.totals.profit_eur - final.totals.profit_eur) == pytest.approx(
        0.25, rel=1e-3
    )
    assert float(final_free.totals.battery_wear_eur) == 0.0


def test_calendar_ageing_is_booked_every_step_whatever_the_battery_does():
    p = no_arrivals(
        make_params(station=_station(capacity_kwh=200.0, calendar_life_years=10.0), first_weekday=0)
    )
    per_day = 150.0 * 200.0 / (10 * 365)
    final, info = _run(p, [0] * p.num_steps)
    np.testing.assert_allclose(np.asarray(info.battery_wear_eur), per_day / p.num_steps, rtol=1e-5)
    assert float(final.totals.battery_wear_eur) == pytest.approx(per_day, rel=1e-4)
    # make_params overrides each battery's own: 0 years turns calendar ageing off
    off = make_params(station=_station(calendar_life_years=10.0), battery_calendar_life_years=0)
    assert float(off.battery_calendar_eur_step[0]) == 0.0
    assert float(
        make_params(station=_station(), battery_calendar_life_years=20.0).battery_calendar_eur_step[
            0
        ]
    ) == pytest.approx(150.0 * 10.0 / (20 * 365) / 288, rel=1e-5)


def test_the_wear_is_the_battery_agents_and_the_shares_still_sum_to_the_reward():
    p = no_arrivals(make_params(station=_station(initial_soc=0.5), first_weekday=0))
    free = p.replace(battery_wear_eur_kwh=jnp.zeros((1,)))
    for level in (10, -10):
        s = start(p)
        _, info = simulator.step(KEY, s, jnp.array([0, level]), p)
        _, info_free = simulator.step(KEY, s, jnp.array([0, level]), free)
        wear = 0.0125 * abs(float(info.leaf_energy_kwh[1]))
        assert wear > 0.0
        assert float(info.battery_wear_eur) == pytest.approx(wear, rel=1e-5)
        shares, shares_free = np.asarray(info.leaf_reward), np.asarray(info_free.leaf_reward)
        assert shares.sum() == pytest.approx(float(info.reward), abs=1e-5)
        assert shares[1] == pytest.approx(shares_free[1] - wear, abs=1e-5)
        assert shares[0] == pytest.approx(shares_free[0], abs=1e-6)


def test_the_wear_is_an_info_entry_and_an_episode_total():
    p = no_arrivals(make_params(station=_station(), first_weekday=0))
    s = start(p)
    s1, info = simulator.step(KEY, s, jnp.array([0, 10]), p)
    d = simulator.info_dict(info, s1, p)
    assert d["battery_wear_eur"] == pytest.approx(float(info.battery_wear_eur))
    assert d["episode_battery_wear_eur"] == pytest.approx(float(info.battery_wear_eur))
    assert "battery_wear_eur" in simulator.INFO_KEYS


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"cost_eur_kwh": -1.0}, "cost_eur_kwh"),
        ({"cost_eur_kwh": float("nan")}, "cost_eur_kwh"),
        ({"cycle_life": 0.0}, "cycle_life"),
        ({"calendar_life_years": -2.0}, "calendar_life_years"),
    ],
)
def test_bad_battery_wear_inputs_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=f"Battery 'battery': field '{field}'"):
        Battery(**kwargs)
    with pytest.raises(ValueError, match=f"field 'battery_{field}'"):
        make_params(**{f"battery_{k}": v for k, v in kwargs.items()})


def test_on_a_flat_price_day_a_cycle_loses_exactly_its_losses_and_wear():
    # one price all day, no cars, no fees: a full cycle of the empty battery buys E_in / eta
    # from the grid and sells E_out * eta back at that price, and pays the wear on both ways
    price, eta = 0.2, 0.9
    p = no_arrivals(
        make_params(
            station=_station(initial_soc=0.0, efficiency=eta),
            prices=np.full((2, 24), price, np.float32),
            grid_fee_eur_kwh=0.0,
            fixed_cost_eur=0.0,
            feed_in_factor=1.0,
            first_weekday=0,
        )
    )
    cycled, info = _run(p, [10] * 60 + [-10] * 60 + [0] * 168)
    idle, _ = _run(p, [0] * 288)
    assert float(np.asarray(cycled.soc)[-1]) == pytest.approx(0.0, abs=1e-4)
    moved = np.asarray(info.leaf_energy_kwh)[:, -1]
    e_in, e_out = float(moved[moved > 0].sum()), float(-moved[moved < 0].sum())
    assert e_in == pytest.approx(10.0, rel=1e-3) and e_out == pytest.approx(e_in, rel=1e-4)
    losses = price * (e_in / eta - e_out * eta)
    wear = 0.0125 * (e_in + e_out)
    lost = float(idle.totals.profit_eur - cycled.totals.profit_eur)
    assert lost == pytest.approx(losses + wear, rel=1e-3)
    assert lost > wear > 0.0
