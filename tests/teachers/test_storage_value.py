"""The battery-only programme and LP of `chargax_marl.teachers.storage_value`: hand cases."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.teachers import storage_value
from tests.helpers import TINY_ENV

ROOT = Path(__file__).resolve().parents[2]


def test_dp_battery_action_earns_the_programme_s_value_in_its_own_model():
    """Played through the battery-only model from 50 % (a grid point), the programme's greedy
    action earns exactly ``value[day, 0](E_0)``: the action read from the state and the table
    agree."""
    from chargax_marl.core import make_params, simulator

    params = make_params()
    grid, table = storage_value.dp_values(params)
    prices = storage_value.step_buy_prices(params)
    eta, power_kw, capacity_kwh, e0 = storage_value.battery_constants(params)
    wear = storage_value.battery_wear_eur_kwh(params)
    assert wear == pytest.approx(150.0 / (2 * 6000.0))
    step_kwh = power_kw * float(params.step_hours)
    act = jax.jit(storage_value.dp_battery_action(params))
    is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
    for day in (5, 147):
        state = simulator.empty_state(jnp.int32(day), params, jax.random.PRNGKey(0))
        energy, earned, moves = e0, 0.0, set()
        for t in range(int(params.num_steps)):
            soc = jnp.where(jnp.asarray(is_bat), energy / capacity_kwh, state.soc)
            a, _ = act(state.replace(timestep=jnp.int32(t), soc=soc))
            a = int(a)
            moves.add(a)
            after = min(max(energy + a * step_kwh, 0.0), capacity_kwh)
            p = prices[day, t]
            earned += eta * p * (energy - after) if after < energy else -p * (after - energy) / eta
            earned -= wear * abs(after - energy)
            energy = after
        earned += storage_value.terminal_prices(params)[day] * energy
        np.testing.assert_allclose(earned, np.interp(e0, grid, table[day, 0]), rtol=1e-4, atol=1e-3)
        assert moves == {-1, 0, 1}  # it trades on these days


def test_storage_value_hand_case_and_bounds():
    """The battery-only LP's value of a stored kWh: where no energy bound binds, every step's
    value is the terminal price (energy moves freely through the day); with losses a kWh
    bought at ``p`` costs ``p / eta``, so the values stay within the day's prices scaled by eta."""

    v = storage_value.day_values(
        [0.1, 0.3, 0.2], 0.15, eta=1.0, power_kw=1.0, capacity_kwh=10.0, e0=5.0, step_hours=1.0
    )
    np.testing.assert_allclose(v, [0.15, 0.15, 0.15, 0.15], atol=1e-9)
    # a small battery that starts empty: the first step's kWh is worth the dearest sale it
    # can still reach (0.3 at step 1); after that sale only step 2's 0.2 remains
    v = storage_value.day_values(
        [0.1, 0.3, 0.2], 0.0, eta=1.0, power_kw=1.0, capacity_kwh=1.0, e0=0.0, step_hours=1.0
    )
    assert v[2] == pytest.approx(0.2) and v[3] == 0.0
    from chargax_marl.core import make_params

    params = make_params(**TINY_ENV)
    table = storage_value.storage_values(params)
    prices = storage_value.step_buy_prices(params)
    eta = float(np.asarray(params.station.leaf_path_efficiency)[-1])
    assert table.shape == (prices.shape[0], prices.shape[1] + 1)
    from chargax_marl.core.reward import day_mean_buy_price

    np.testing.assert_allclose(
        table[:, -1],
        [float(day_mean_buy_price(d, params)) for d in range(prices.shape[0])],
        rtol=1e-5,
    )
    lo = np.minimum(prices.min(axis=1, keepdims=True) / eta, table[:, -1:])
    hi = np.maximum(prices.max(axis=1, keepdims=True) * eta, table[:, -1:])
    assert np.all(table >= lo - 1e-5) and np.all(table <= hi + 1e-5)
    with pytest.raises(ValueError, match="battery"):
        storage_value.storage_values(
            make_params(station="single_type", station_kwargs={"num_ports": 2})
        )


def test_dp_values_are_the_hand_computed_best_of_the_three_full_power_actions():
    """Prices 0.1, 0.3, 0.2, a 1 kWh battery that moves 1 kWh per step, terminal price 0.15:
    empty at the start it buys at 0.1 and sells at 0.3 (0.2); full it sells at 0.3 (0.3). With
    a path efficiency of 0.5 buying at 0.1 costs 0.2 per stored kWh and selling at 0.3 earns
    0.15, so the empty battery idles and the full one earns 0.15 (selling at 0.3 or holding)."""
    grid, v = storage_value.level_values(
        [[0.1, 0.3, 0.2]], [0.15], eta=1.0, step_kwh=1.0, capacity_kwh=1.0, points_per_step=1
    )
    np.testing.assert_allclose(grid, [0.0, 1.0])
    np.testing.assert_allclose(v[0], [[0.2, 0.3], [0.0, 0.3], [0.0, 0.2], [0.0, 0.15]], atol=1e-12)
    _, v = storage_value.level_values(
        [[0.1, 0.3, 0.2]], [0.15], eta=0.5, step_kwh=1.0, capacity_kwh=1.0, points_per_step=1
    )
    # full: sell at 0.3 for 0.15, at 0.2 for 0.1, or hold to the end for 0.15
    np.testing.assert_allclose(v[0, :, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(v[0, :, 1], [0.15, 0.15, 0.15, 0.15], atol=1e-12)
    # a finer grid interpolates half a kWh: buy 0.5 kWh at 0.1 is not possible (a full step is 1
    # kWh, cut at full), so from 0.5 kWh the best is to top up at 0.1 and sell 1 kWh at 0.3
    grid, v = storage_value.level_values(
        [[0.1, 0.3, 0.2]], [0.15], eta=1.0, step_kwh=1.0, capacity_kwh=1.0, points_per_step=2
    )
    np.testing.assert_allclose(grid, [0.0, 0.5, 1.0])
    np.testing.assert_allclose(v[0, 0, 1], -0.05 + 0.3, atol=1e-12)
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="points_per_step"):
            storage_value.level_values([[0.1]], [0.1], 1.0, 1.0, 1.0, points_per_step=bad)
    with pytest.raises(ValueError, match="eta"):
        storage_value.level_values([[0.1]], [0.1], 1.5, 1.0, 1.0)


def test_the_programme_and_the_lp_pay_for_wear():
    """Prices 0.1, 0.3, 0.2, a 1 kWh battery moving 1 kWh per step, no losses, terminal 0.15,
    wear w per kWh in and per kWh out: empty, buying at 0.1 and selling at 0.3 earns
    0.2 - 2 w, so it trades for w < 0.1 and idles above; full, selling at 0.3 earns 0.3 - w
    against 0.15 for holding."""
    for w in (0.0, 0.05, 0.1, 0.12):
        _, v = storage_value.level_values(
            [[0.1, 0.3, 0.2]],
            [0.15],
            eta=1.0,
            step_kwh=1.0,
            capacity_kwh=1.0,
            points_per_step=1,
            wear_eur_kwh=w,
        )
        assert v[0, 0, 0] == pytest.approx(max(0.2 - 2 * w, 0.0), abs=1e-12)
        assert v[0, 0, 1] == pytest.approx(max(0.3 - w, 0.15), abs=1e-12)


def test_on_a_flat_price_day_any_cycle_loses_its_losses_and_wear():
    """At one price all day, equal to the terminal price, every kWh is worth that price at
    every step: the programme holds (a cycle would lose the losses plus 2 w per kWh)."""
    grid, v = storage_value.level_values(
        [[0.2] * 6], [0.2], eta=0.95, step_kwh=1.0, capacity_kwh=3.0, wear_eur_kwh=0.01
    )
    np.testing.assert_allclose(v[0], np.broadcast_to(0.2 * grid, v[0].shape), atol=1e-12)
    q = storage_value.action_values(
        np, lambda e: 0.2 * e, 1.0, 0.2, 0.95, 1.0, 3.0, wear_eur_kwh=0.01
    )
    # from 1 kWh: discharging it earns 0.95 * 0.2 - 0.01 and leaves nothing; holding keeps a kWh
    # worth 0.2; charging one more costs 0.2 / 0.95 + 0.01 for a second kWh worth 0.2
    assert q[0] == pytest.approx(0.95 * 0.2 - 0.01, abs=1e-12)
    assert q[1] == pytest.approx(0.2, abs=1e-12)
    assert q[2] == pytest.approx(0.4 - (0.2 / 0.95 + 0.01), abs=1e-12)
    assert q[1] > max(q[0], q[2])


def test_dp_values_never_lose_to_idling_and_end_at_the_terminal_booking():
    from chargax_marl.core import make_params

    params = make_params()
    grid, v = storage_value.dp_values(params)
    terminal = storage_value.terminal_prices(params)
    np.testing.assert_allclose(v[:, -1], terminal[:, None] * grid[None, :], rtol=1e-5, atol=1e-4)
    # holding is always allowed, so a level is worth at least what it is worth one step later
    assert np.all(v[:, :-1] >= v[:, 1:] - 1e-3)
    # on days without negative prices more energy is never worth less (it can be sold or held);
    # on days with them it can be (an emptier battery is paid to charge)
    positive = np.all(storage_value.step_buy_prices(params) > 0, axis=1)
    assert 0 < positive.sum() < positive.size
    assert np.all(np.diff(v[positive], axis=-1) >= -1e-3)
    assert np.any(np.diff(v[~positive], axis=-1) < -1e-3)
