"""Traces of episodes that start after midnight (`chargax_marl.trace`, `chargax_marl.core.clock`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core import make_params, reward
from chargax_marl.evaluation import run_days
from chargax_marl.policies import always_max
from chargax_marl.trace import check_trace, make_traces, params_fingerprint, replay_days
from tests.helpers import three_level_station

HOURLY = dict(station=three_level_station(), traffic=150.0, step_minutes=60.0)


@pytest.fixture(scope="module")
def noon():
    return make_params(**HOURLY, episode_start_hour=12)


def test_a_trace_records_the_episode_at_its_clock_time_and_replays_run_days(noon):
    days = list(range(7))  # every weekday: the day type changes at midnight in two of them
    traces = make_traces(noon, days, jax.random.PRNGKey(2))
    assert traces.episode_start_hour == 12
    for i, day in enumerate(days):
        buy = jax.vmap(lambda t, d=day: reward.grid_prices(jnp.int32(d), t, noon)[0])(
            jnp.arange(noon.num_steps)
        )
        np.testing.assert_array_equal(traces.price_buy_eur_kwh[i], buy)

    def act(state, key):
        return always_max(state, key, noon)

    replayed = replay_days(act, noon, traces, jax.random.PRNGKey(2))
    played = run_days(act, noon, days, jax.random.PRNGKey(2))
    for a, b in zip(jax.tree.leaves(replayed), jax.tree.leaves(played)):
        np.testing.assert_array_equal(a, b)


def test_a_trace_is_refused_by_params_with_another_start_hour(noon):
    midnight = make_params(**HOURLY)
    trace = make_traces(midnight, [3])
    with pytest.raises(ValueError, match="'episode_start_hour' is 0 but params have"):
        check_trace(trace, noon)
    with pytest.raises(ValueError, match="'days'.*next day"):
        make_traces(noon, [noon.num_days - 1])


def test_the_start_hour_is_part_of_the_params_fingerprint(noon):
    assert params_fingerprint(noon) != params_fingerprint(make_params(**HOURLY))
