"""Episodes of several days (``make_params(episode_days=N)``): cars stay parked over
midnight, each calendar day brings its own prices and day type, the episode ends after
``N * num_steps`` steps with the batteries' value and the peak charge booked once, the first
day is the one-day episode's, and both views step the same transition."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core import clock, make_params, multiple_types, observation, simulator
from chargax_marl.core import reward as reward_lib
from chargax_marl.marl import ChargaxMARL
from chargax_marl.single import Chargax
from tests.helpers import no_arrivals, place_car

KEY = jax.random.PRNGKey(7)
# hourly steps keep the programs and the rollouts small: a day is 24 steps
SMALL = {"station": multiple_types(2, 2), "step_minutes": 60, "traffic": 150.0}


@pytest.fixture(scope="module")
def one_day():
    return make_params(**SMALL)


@pytest.fixture(scope="module")
def two_days():
    return make_params(**SMALL, episode_days=2)


def friday(params) -> int:
    """A day of the price data that is a Friday and not a holiday, nor is the day after."""
    days = np.arange(params.num_days - 1)
    weekday = np.asarray(clock.weekday(days, params))
    holiday = np.asarray(params.holiday)
    ok = (weekday == 4) & ~holiday[days] & ~holiday[days + 1]
    return int(days[ok][0])


def random_levels(params, key, t):
    """Levels that depend on the key and the step only, so two rollouts play the same ones."""
    n = params.station.num_leaves
    k = jax.random.fold_in(key, t)
    return jax.random.randint(k, (n,), -params.num_levels, params.num_levels + 1)


def rollout(params, day, key, num_steps):
    """``num_steps`` core steps from the empty station of ``day`` (its volume and batteries
    drawn from ``key``), random levels; returns the states before each step (their
    observations), the infos and the states after each step."""

    def body(state, t):
        levels = random_levels(params, key, t)
        new_state, info = simulator.step(jax.random.fold_in(key, 1000 + t), state, levels, params)
        return new_state, (observation.flat_obs(state, params), state, info, new_state)

    start = simulator.empty_state(jnp.asarray(day), params, key)
    return jax.lax.scan(body, start, jnp.arange(num_steps))[1]


_rollout = jax.jit(rollout, static_argnums=(3,))


@pytest.fixture(scope="module")
def two_day_run(two_days):
    day = friday(two_days)
    return day, _rollout(two_days, day, KEY, 2 * two_days.num_steps)


# ------------------------------------------------------------------ 1. cars stay over midnight


def test_a_car_parked_at_22h_keeps_charging_after_midnight(two_days):
    params = no_arrivals(two_days)
    T = params.num_steps
    state = simulator.empty_state(jnp.asarray(friday(params)), params)
    state = state.replace(timestep=jnp.asarray(22 * 60 // int(params.step_minutes), jnp.int32))
    state = place_car(
        state, 0, soc=0.1, capacity_kwh=100.0, max_rate_kw=11.0, remaining_kwh=90.0, time_min=360
    )
    full = jnp.where(jnp.arange(params.station.num_leaves) == 0, params.num_levels, 0)
    socs, occupied, done = [], [], []
    for t in range(5):  # 22:00, 23:00, 00:00, 01:00, 02:00 (hourly steps)
        socs.append(float(state.soc[0]))
        occupied.append(bool(state.occupied[0]))
        state, _ = simulator.step(jax.random.fold_in(KEY, t), state, full, params)
        done.append(bool(simulator.is_done(state, params)))
    assert int(state.timestep) == T + 3  # 03:00 of the second day, the same episode
    assert all(occupied) and bool(state.occupied[0])  # parked at 02:00 and still after
    assert np.all(np.diff(socs) > 0), socs  # it charges before and after midnight
    assert socs[-1] > socs[2] > socs[1]  # 02:00 > 00:00 > 23:00
    assert not any(done)  # step num_steps does not end the episode


# ------------------------------------------------------------------ 2. the first day is a day


def test_the_first_day_is_the_one_day_episode_bit_for_bit(one_day, two_days):
    """Before midnight a two-day episode computes what the one-day episode does with the same
    key: the same rewards, infos and observations (less the two-day observation's last two
    columns, the weekday, which one-day episodes do not have). The last step before
    midnight (step ``num_steps - 1``) is the one-day episode's last: it books the batteries'
    terminal value and the peak-demand charge there, the two-day episode only at its own
    end, so that step's reward and profit may differ; its other reports do not."""
    T = one_day.num_steps
    day = friday(one_day)
    obs1, _, info1, _ = _rollout(one_day, day, KEY, T)
    obs2, _, info2, _ = _rollout(two_days, day, KEY, T)
    assert obs2.shape[1] == obs1.shape[1] + 2
    np.testing.assert_array_equal(np.asarray(obs2[:, :-2]), np.asarray(obs1))
    np.testing.assert_array_equal(np.asarray(info2.reward[:-1]), np.asarray(info1.reward[:-1]))
    for name in ("energy_charged_kwh", "grid_net_kwh", "cars_arrived", "price_buy_eur_kwh"):
        np.testing.assert_array_equal(
            np.asarray(getattr(info2, name)), np.asarray(getattr(info1, name)), err_msg=name
        )
    assert float(info2.battery_terminal_value_eur[-1]) == 0.0  # not the two-day episode's end


# ------------------------------------------------------------------ 3. the end


def test_done_after_exactly_two_days_with_the_terminal_value_booked_once(two_days, two_day_run):
    params = two_days
    T = params.num_steps
    day, (_, before, info, after) = two_day_run
    done = np.asarray(jax.vmap(lambda s: simulator.is_done(s, params))(after))
    assert done.shape == (2 * T,) and done[-1] and not done[:-1].any()
    terminal = np.asarray(info.battery_terminal_value_eur)
    assert (terminal[:-1] == 0.0).all()
    last_totals = jax.tree.map(lambda x: x[-1], after.totals)
    # booked at the end, at the mean buy price of the episode's last day
    want = reward_lib.battery_terminal_value_eur(last_totals.battery_net_kwh, day + 1, params)
    np.testing.assert_allclose(terminal[-1], float(want), rtol=1e-6)
    assert float(last_totals.battery_net_kwh) != 0.0  # the random batteries did move


def test_the_peak_charge_bills_the_episodes_peak_once_at_its_end():
    params = make_params(**SMALL, episode_days=2, peak_demand_eur_kw=2.0)
    T = params.num_steps
    _, _, info, after = _rollout(params, friday(params), KEY, 2 * T)
    charge = np.asarray(info.peak_demand_charge_eur)
    draw_kw = np.maximum(np.asarray(info.grid_net_kwh), 0.0) / params.step_hours
    assert (charge[:-1] == 0.0).all()
    np.testing.assert_allclose(charge[-1], 2.0 * draw_kw.max(), rtol=1e-5)
    assert draw_kw[T:].max() != draw_kw[:T].max()  # both days' draws count, not the first's


# ------------------------------------------------------------------ 4. each day its own


def test_the_second_day_reads_its_own_prices_and_day_type(two_days, two_day_run):
    params = two_days
    T = params.num_steps
    day, (obs, before, info, _) = two_day_run
    prices = np.asarray(params.prices_eur_kwh)
    assert not np.array_equal(prices[day], prices[day + 1])
    tou = np.asarray(params.tou_fee_eur_kwh)
    fee = float(np.asarray(params.grid_fee_eur_kwh))
    hours = np.arange(T) * int(params.step_minutes) // 60
    for offset in (0, 1):
        got = np.asarray(info.price_buy_eur_kwh[offset * T : (offset + 1) * T])
        np.testing.assert_allclose(got, prices[day + offset, hours] + fee + tou[hours], rtol=1e-6)
    workday = np.asarray(before.is_workday)
    assert workday[:T].all() and not workday[T:].any()  # Friday, then Saturday

    ctx = obs[:, -observation.context_size(params) :]
    q = observation.context_index(params, "price_quantiles")
    nq = len(observation.PRICE_QUANTILES)
    for offset in (0, 1):
        want = np.asarray(reward_lib.day_price_quantiles(day + offset, params))
        got = np.asarray(ctx[offset * T : (offset + 1) * T, q : q + nq])
        np.testing.assert_allclose(
            got * observation.PRICE_SCALE_EUR_KWH, np.broadcast_to(want, got.shape), rtol=1e-6
        )
    assert not np.array_equal(ctx[0, q : q + nq], ctx[T, q : q + nq])
    w = observation.context_index(params, "weekday")
    angle = 2 * np.pi * np.array([4, 5]) / 7  # Friday, Saturday
    np.testing.assert_allclose(ctx[0, w : w + 2], [np.sin(angle[0]), np.cos(angle[0])], atol=1e-6)
    np.testing.assert_allclose(ctx[T, w : w + 2], [np.sin(angle[1]), np.cos(angle[1])], atol=1e-6)
    d = observation.context_index(params, "day")
    scale = max(params.num_days - 1, 1)
    np.testing.assert_allclose(ctx[[0, T], d] * scale, [day, day + 1], rtol=1e-6)


def test_each_calendar_day_draws_its_own_volume():
    params = make_params(**SMALL, episode_days=3)
    T = params.num_steps
    _, before, _, _ = _rollout(params, friday(params), KEY, 3 * T)
    volume = np.asarray(before.day_volume)
    for d in range(3):  # constant within a day
        assert (volume[d * T : (d + 1) * T] == volume[d * T]).all()
    assert len({float(volume[0]), float(volume[T]), float(volume[2 * T])}) == 3


# ------------------------------------------------------------------ 5. jit, vmap, views


def test_jit_is_no_jit_and_vmap_is_a_loop_across_midnight(two_days):
    params = two_days
    T = params.num_steps
    start = simulator.empty_state(jnp.asarray(friday(params)), params, KEY)
    start = start.replace(timestep=jnp.asarray(T - 2, jnp.int32))

    def run(state, key, n=4):
        out = []
        for t in range(n):
            state, info = simulator.step(
                jax.random.fold_in(key, t), state, random_levels(params, key, t), params
            )
            out.append((state, info.reward))
        return out

    jitted = run(start, KEY)
    with jax.disable_jit():
        eager = run(start, KEY)
    for (s1, r1), (s2, r2) in zip(jitted, eager):
        np.testing.assert_allclose(float(r1), float(r2), rtol=1e-5, atol=1e-6)
        for x, y in zip(jax.tree.leaves(s1), jax.tree.leaves(s2)):
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-5, atol=1e-5)

    keys = jax.random.split(KEY, 3)

    def rewards(key):
        return jnp.stack([r for _, r in run(start, key)])

    batched = np.asarray(jax.vmap(rewards)(keys))
    looped = np.stack([np.asarray(rewards(k)) for k in keys])
    np.testing.assert_allclose(batched, looped, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("at", ["midnight", "end"])
def test_both_views_step_the_core_transition(two_days, at):
    params = two_days
    T = params.num_steps
    t = T - 1 if at == "midnight" else 2 * T - 1
    state = simulator.empty_state(jnp.asarray(friday(params)), params, KEY)
    state = state.replace(timestep=jnp.asarray(t, jnp.int32))
    levels = jnp.asarray([2, -1, 0, 1, 1], jnp.int32)
    want, core_info, stepped, done = None, None, None, None
    want, stepped, core_info, done = simulator.step_auto_reset(KEY, state, levels, params)
    assert bool(done) == (at == "end")
    if at == "midnight":
        assert int(want.timestep) == T  # the same episode goes on

    single = Chargax(params)
    obs, got, reward, terminated, truncated, _ = single.step(
        KEY, state, single.levels_to_action(levels)
    )
    assert obs.shape == single.observation_space(params).shape
    assert bool(truncated) == (at == "end") and not bool(terminated)
    np.testing.assert_allclose(float(reward), float(core_info.reward), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(obs, observation.flat_obs(want, params), rtol=1e-6, atol=1e-6)

    marl = ChargaxMARL(params)
    m_obs, m_state, rewards, dones, _ = marl.step(KEY, state, marl.levels_to_actions(levels))
    assert bool(dones["__all__"]) == (at == "end")
    assert int(m_state.timestep) == int(got.timestep) == int(want.timestep)
    matrix = jnp.stack([m_obs[a] for a in marl.agents])
    np.testing.assert_allclose(matrix, marl.get_obs_matrix(want), rtol=1e-6, atol=1e-6)
    assert matrix.shape[1] == marl.observation_space(marl.agents[0]).shape[0]
    np.testing.assert_allclose(
        np.asarray(list(rewards.values())), float(core_info.reward), rtol=1e-6, atol=1e-6
    )


def test_the_observation_widths_follow_episode_days(one_day, two_days):
    assert "weekday" not in dict(observation.context_parts(one_day))
    assert dict(observation.context_parts(two_days))["weekday"] == 2
    assert observation.context_size(two_days) == observation.context_size(one_day) + 2
    assert observation.obs_size(two_days) == observation.obs_size(one_day) + 2


# ------------------------------------------------------------------ 6. bad input


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2", None])
def test_bad_episode_days_is_a_value_error_naming_the_field(bad):
    with pytest.raises(ValueError, match=r"field 'episode_days' must be an integer >= 1.*got"):
        make_params(**SMALL, episode_days=bad)


def test_too_few_days_of_prices_is_a_value_error(one_day):
    with pytest.raises(ValueError, match="episode_days"):
        make_params(**SMALL, episode_days=one_day.num_days + 1)


# ------------------------------------------------------------------ 7. the start days


def test_start_days_count_the_episodes_days_and_its_start_hour():
    assert clock.num_start_days(10, 0) == 10 and clock.num_start_days(10, 12) == 9
    assert clock.num_start_days(10, 0, 3) == 8  # days 0..7 have their two next days
    assert clock.num_start_days(10, 12, 3) == 7  # and noon to noon runs into a fourth day
    clock.check_days([0, 6], 10, 12, episode_days=3)
    with pytest.raises(ValueError, match=r"must lie in \[0, 6\]: an episode of 3 days from 12"):
        clock.check_days([7], 10, 12, episode_days=3)
    params = make_params(**SMALL, episode_days=2, episode_start_hour=12)
    assert clock.num_episode_starts(params) == params.num_days - 2
    assert int(params.reset_days.max()) == params.num_days - 3
    with pytest.raises(ValueError, match="reset_days"):
        make_params(**SMALL, episode_days=2, reset_days=[params.num_days - 1])
