"""Episodes that start at another hour than midnight (`chargax_marl.core.clock`).

An episode that starts on day ``d`` at hour ``h`` prices, draws and observes step ``t`` at
clock time ``h + t * step_minutes / 60`` of day ``d``, on day ``d + 1`` past midnight.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core import (
    clock,
    make_params,
    observation,
    reward,
    simulator,
    traffic,
    validate_params,
    validated_replace,
)
from chargax_marl.core.scenarios import scenario_kwargs
from chargax_marl.evaluation import run_policy_days
from chargax_marl.policies import always_max
from tests.helpers import three_level_station

NOON = 12
STEPS_TO_MIDNIGHT = 144  # 12 hours of 5-minute steps


@pytest.fixture(scope="module")
def params0():
    return make_params(station=three_level_station(), traffic=150.0)


@pytest.fixture(scope="module")
def params12():
    return make_params(station=three_level_station(), traffic=150.0, episode_start_hour=NOON)


def _idle(params):
    return jnp.zeros((params.station.num_leaves,), jnp.int32)


def _play(params, day, key=jax.random.PRNGKey(0)):
    """One idle episode from ``day``: the start state of every step and every step's info."""

    def body(state, k):
        new_state, info = simulator.step(k, state, _idle(params), params)
        return new_state, (state, info)

    keys = jax.random.split(key, params.num_steps)
    _, (states, infos) = jax.lax.scan(body, simulator.empty_state(jnp.int32(day), params), keys)
    return states, infos


def _day_with_weekday(params, weekday: int) -> int:
    """The first day of the data (not the last) on the given weekday (0 = Monday)."""
    first = int(params.first_weekday)
    return next(d for d in range(params.num_days - 1) if (first + d) % 7 == weekday)


# ------------------------------------------------------------------ settings


def test_default_start_hour_is_midnight_and_the_clock_is_the_step(params0):
    assert params0.episode_start_hour == 0
    t = jnp.arange(params0.num_steps + 1)
    np.testing.assert_array_equal(
        clock.slot_of_day(t, params0), np.minimum(t, params0.num_steps - 1)
    )
    np.testing.assert_array_equal(clock.calendar_day(jnp.int32(7), t, params0), 7)
    np.testing.assert_array_equal(params0.reset_days, np.arange(params0.num_days))


@pytest.mark.parametrize("bad", [24, -1, 1.5, True, "12", None])
def test_start_hour_outside_0_to_23_is_refused_naming_the_field(bad):
    with pytest.raises(ValueError, match=r"'episode_start_hour'.*\[0, 23\].*got"):
        make_params(episode_start_hour=bad)


def test_start_hour_must_fall_on_a_step_boundary():
    make_params(step_minutes=45.0, episode_start_hour=3)  # 180 min = 4 steps
    with pytest.raises(ValueError, match="'episode_start_hour'.*step boundary.*45-minute"):
        make_params(step_minutes=45.0, episode_start_hour=1)


def test_validator_rechecks_the_start_hour(params0, params12):
    validate_params(params12)
    with pytest.raises(ValueError, match=r"'episode_start_hour'.*\[0, 23\]"):
        validate_params(params12.replace(episode_start_hour=30))
    # the derived price quantiles are the episode's: changing the hour alone is refused
    with pytest.raises(ValueError, match="day_price_quantiles_eur_kwh.*episode_start_hour"):
        validated_replace(params0, episode_start_hour=NOON)


# ------------------------------------------------------------------ prices


def test_step_0_is_priced_at_the_start_hour_and_step_144_at_the_next_midnight(params12):
    day = 5
    spot = np.asarray(params12.prices_eur_kwh)
    fee = float(params12.grid_fee_eur_kwh)
    buy0, _ = reward.grid_prices(jnp.int32(day), 0, params12)
    buy144, _ = reward.grid_prices(jnp.int32(day), STEPS_TO_MIDNIGHT, params12)
    assert float(buy0) == pytest.approx(spot[day, NOON] + fee, abs=1e-6)
    assert float(buy144) == pytest.approx(spot[day + 1, 0] + fee, abs=1e-6)
    # and so does every step of a played episode
    _, infos = _play(params12, day)
    hours = NOON + np.arange(params12.num_steps) // 12
    expected = spot.reshape(-1)[day * 24 + hours] + fee
    np.testing.assert_allclose(infos.price_buy_eur_kwh, expected, atol=1e-6)


def test_time_of_use_fee_follows_the_clock_hour():
    p = make_params(
        station=three_level_station(), tou_fee_eur_kwh="evening-peak", episode_start_hour=NOON
    )
    t = jnp.arange(p.num_steps)
    hour = (NOON + np.arange(p.num_steps) // 12) % 24
    np.testing.assert_array_equal(reward.tou_fee(t, p), np.asarray(p.tou_fee_eur_kwh)[hour])


def test_price_tables_and_episode_prices_are_the_episodes(params12):
    buy, _ = reward.price_tables(params12)
    day = 9
    episode = np.asarray(reward.episode_buy_prices(jnp.int32(day), params12))
    np.testing.assert_allclose(np.asarray(buy)[day], np.repeat(episode, 12), atol=1e-6)
    flat = np.asarray(params12.prices_eur_kwh).reshape(-1)
    np.testing.assert_allclose(
        episode, flat[day * 24 + NOON : day * 24 + NOON + 24] + float(params12.grid_fee_eur_kwh)
    )
    quantiles = np.quantile(episode - float(params12.grid_fee_eur_kwh), observation.PRICE_QUANTILES)
    np.testing.assert_allclose(
        reward.day_price_quantiles(jnp.int32(day), params12), quantiles, atol=1e-6
    )


# ------------------------------------------------------------------ arrivals


def test_arrival_rate_at_step_0_is_the_midnight_start_rate_at_slot_144(params0, params12):
    t = jnp.arange(params12.num_steps)
    for workday in (True, False):
        later = traffic.arrival_rate(t, workday, params12)
        shifted = traffic.arrival_rate(jnp.mod(t + STEPS_TO_MIDNIGHT, 288), workday, params0)
        np.testing.assert_array_equal(later, shifted)
    assert float(traffic.arrival_rate(0, True, params12)) == float(
        traffic.arrival_rate(STEPS_TO_MIDNIGHT, True, params0)
    )


@pytest.mark.parametrize("weekday, before, after", [(4, True, False), (6, False, True)])
def test_the_day_type_switches_at_the_calendar_midnight_inside_the_episode(
    params12, weekday, before, after
):
    """Friday noon to Saturday noon: workday arrivals, then weekend ones (Sunday to Monday:
    the reverse). Cars arrive only in weekend (or only in workday) steps here."""
    day = _day_with_weekday(params12, weekday)
    rate = np.zeros((2, params12.num_steps), np.float32)
    rate[0 if after else 1] = 0.5  # cars only on the day type after midnight
    p = validated_replace(params12, arrival_rate=jnp.asarray(rate))
    states, infos = _play(p, day)
    workday = np.asarray(states.is_workday)
    assert (workday[:STEPS_TO_MIDNIGHT] == before).all()
    assert (workday[STEPS_TO_MIDNIGHT:] == after).all()
    arrived = np.asarray(infos.cars_arrived)
    assert arrived[:STEPS_TO_MIDNIGHT].sum() == 0 and arrived[STEPS_TO_MIDNIGHT:].sum() > 0
    np.testing.assert_array_equal(
        clock.is_workday(jnp.int32(day), jnp.arange(p.num_steps), p),
        np.where(np.arange(p.num_steps) < STEPS_TO_MIDNIGHT, before, after),
    )


def test_stay_and_demand_scale_by_the_arrival_clock_hour(params0, params12):
    """The same key draws the same cars at the same clock time whatever the start hour."""
    key = jax.random.PRNGKey(3)
    for t in (0, 100, 200):
        a = traffic.draw_arrivals(key, t, True, params12)
        b = traffic.draw_arrivals(key, (t + STEPS_TO_MIDNIGHT) % 288, True, params0)
        np.testing.assert_array_equal(a.stay_min, b.stay_min)
        np.testing.assert_array_equal(a.target_soc, b.target_soc)
        assert int(a.requested) == int(b.requested)


# ------------------------------------------------------------------ observation


def test_observation_time_features_show_the_clock_time(params0, params12):
    """Step ``t`` of an episode from noon of day ``d`` observes the time, prices and day type
    that step ``t + 144`` of the midnight episode of day ``d`` (or ``t - 144`` of day
    ``d + 1``) observes."""
    day = _day_with_weekday(params12, 4)  # Friday: the day type changes at midnight
    names = ("prices", "time_of_day", "workday", "hour_left")
    ranges = {
        n: slice(observation.context_index(params0, n), observation.context_index(params0, n) + w)
        for n, w in observation.context_parts(params0)
        if n in names
    }
    start12 = simulator.empty_state(jnp.int32(day), params12)
    for t in (0, 5, 143, 144, 150, 287):
        s12 = start12.replace(
            timestep=jnp.int32(t), is_workday=clock.is_workday(jnp.int32(day), t, params12)
        )
        d0, t0 = (day, t + STEPS_TO_MIDNIGHT) if t < STEPS_TO_MIDNIGHT else (day + 1, t - 144)
        s0 = simulator.empty_state(jnp.int32(d0), params0).replace(timestep=jnp.int32(t0))
        c12 = np.asarray(observation.context_features(s12, params12))
        c0 = np.asarray(observation.context_features(s0, params0))
        for name, sl in ranges.items():
            np.testing.assert_allclose(c12[sl], c0[sl], atol=1e-5, err_msg=f"{name} at step {t}")
    s = start12
    c = np.asarray(observation.context_features(s, params12))
    sin_cos = c[ranges["time_of_day"]]
    np.testing.assert_allclose(sin_cos, [0.0, -1.0], atol=1e-6)  # 12:00


# ------------------------------------------------------------------ reset and days


def test_reset_never_draws_a_day_without_next_day_prices(params12):
    last = params12.num_days - 1
    assert last not in np.asarray(params12.reset_days)
    days = jax.vmap(lambda k: simulator.reset(k, params12).day)(
        jax.random.split(jax.random.PRNGKey(0), 4000)
    )
    assert int(days.max()) <= last - 1 and int(days.max()) >= last - 10
    with pytest.raises(ValueError, match=r"'reset_days'.*\[0, 363\].*next day.*364"):
        make_params(episode_start_hour=NOON, reset_days=[3, last])
    with pytest.raises(ValueError, match="'reset_days'"):
        validated_replace(params12, reset_days=jnp.asarray([last], jnp.int32))
    two_days = make_params(prices=np.full((2, 24), 0.1), episode_start_hour=NOON)
    np.testing.assert_array_equal(two_days.reset_days, [0])
    with pytest.raises(ValueError, match="'episode_start_hour'.*two days"):
        make_params(prices=np.full(24, 0.1), episode_start_hour=NOON)


def test_evaluation_refuses_the_last_day_when_episodes_run_into_the_next(params12):
    with pytest.raises(ValueError, match="'days'.*next day"):
        run_policy_days(always_max, params12, [params12.num_days - 1], jax.random.PRNGKey(0))
    assert clock.num_episode_starts(params12) == params12.num_days - 1


# ------------------------------------------------------------------ compiled = eager


def test_jit_equals_no_jit_across_midnight(params12):
    key = jax.random.PRNGKey(1)
    start = simulator.empty_state(jnp.int32(4), params12)
    action = jnp.full((params12.station.num_leaves,), params12.num_levels, jnp.int32)
    for t in (0, STEPS_TO_MIDNIGHT - 1, STEPS_TO_MIDNIGHT, params12.num_steps - 1):
        state = start.replace(timestep=jnp.int32(t))
        fast = simulator.step(key, state, action, params12)
        with jax.disable_jit():
            slow = simulator.step(key, state, action, params12)
        for a, b in zip(jax.tree.leaves(fast), jax.tree.leaves(slow)):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-5)
        ctx_fast = jax.jit(observation.context_features)(state, params12)
        with jax.disable_jit():
            ctx_slow = observation.context_features(state, params12)
        np.testing.assert_allclose(ctx_fast, ctx_slow, rtol=1e-6, atol=1e-6)


# ------------------------------------------------------------------ what it is for


def test_a_noon_start_cuts_far_fewer_residential_sessions_at_the_episode_end():
    """Residential cars arrive in the evening and leave in the morning: an episode that ends
    at midnight cuts many of them, one that ends at noon far fewer. A car still parked at the
    last step is one that arrived and did not leave."""
    days = np.arange(50)
    share = {}
    for hour in (0, NOON):
        p = make_params(**scenario_kwargs("residential", episode_start_hour=hour))
        totals = run_policy_days(always_max, p, days, jax.random.PRNGKey(0))
        arrived = float(np.sum(totals.cars_arrived))
        parked = arrived - float(np.sum(totals.cars_served))
        share[hour] = parked / arrived
    assert share[NOON] < 0.7 * share[0]
