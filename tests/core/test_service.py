"""Service and fairness metrics: each departing car's satisfaction, the day's totals and the
derived metrics (``evaluation.service_metrics``) on days whose values are known by hand."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core import make_params, simulator
from chargax_marl.core.types import EpisodeTotals
from chargax_marl.evaluation import SERVICE_METRICS, service_metrics
from tests.helpers import no_arrivals, place_car, random_rollout, start, three_level_station

# 50 kWh cars that came at 20 % and want 60 %: 20 kWh requested each
CAR = {"capacity_kwh": 50.0, "arrival_soc": 0.2, "target_soc": 0.6}


@pytest.fixture(scope="module")
def params():
    return no_arrivals(make_params(station=three_level_station()))


def _leave_now(params, remaining_kwh, charge_sensitive=()):
    """A state whose cars all leave in the next step: time-sensitive ones at the end of their
    stay, charge-sensitive ones charged (within the tolerance)."""
    state = start(params)
    for i, remaining in enumerate(remaining_kwh):
        sensitive = i in charge_sensitive
        state = place_car(
            state,
            i,
            soc=CAR["target_soc"] - remaining / CAR["capacity_kwh"],
            remaining_kwh=remaining,
            time_min=600.0 if sensitive else params.step_minutes,
            charge_sensitive=sensitive,
            **CAR,
        )
    return state


def _idle_step(state, params):
    idle = jnp.zeros((params.station.num_leaves,), jnp.float32)
    return simulator.step(jax.random.PRNGKey(0), state, idle, params)


def test_a_day_that_serves_every_car_in_full_has_jain_1_and_minimum_1(params):
    state, info = _idle_step(
        _leave_now(params, [0.0, 0.0, 0.0, 0.0], charge_sensitive=(3,)), params
    )
    assert float(info.cars_departed) == 4
    assert float(info.satisfaction_sum) == 4.0 and float(info.satisfaction_min) == 1.0
    m = service_metrics(state.totals)
    assert m["mean_satisfaction"] == 1.0 and m["min_satisfaction"] == 1.0
    assert m["jain_index"] == pytest.approx(1.0, abs=1e-12)
    assert m["satisfaction_gap"] == 0.0  # both user types served in full
    assert m["rejected_share"] == 0.0


def test_a_hand_computed_day_of_unequal_service(params):
    """Three time-sensitive cars leave with 0, 10 and 15 of their 20 kWh missing (satisfaction
    1, 0.5, 0.25) and one charge-sensitive car leaves charged (1)."""
    state, info = _idle_step(
        _leave_now(params, [0.0, 10.0, 15.0, 0.0], charge_sensitive=(3,)), params
    )
    s = np.array([1.0, 0.5, 0.25, 1.0])
    assert float(info.satisfaction_sum) == pytest.approx(s.sum(), abs=1e-5)
    assert float(info.satisfaction_min) == pytest.approx(0.25, abs=1e-5)
    t = state.totals
    assert float(t.cars_served) == 4 and float(t.cars_served_time_sensitive) == 3
    assert float(t.satisfaction_sq_sum) == pytest.approx((s**2).sum(), abs=1e-5)
    m = service_metrics(t)
    assert m["mean_satisfaction"] == pytest.approx(0.6875, abs=1e-6)
    assert m["min_satisfaction"] == pytest.approx(0.25, abs=1e-6)
    assert m["jain_index"] == pytest.approx(2.75**2 / (4 * 2.3125), abs=1e-6)
    assert m["satisfaction_gap"] == pytest.approx(1.75 / 3 - 1.0, abs=1e-6)
    # the next step has no departure: the step reports none, the day's totals stay
    later, info = _idle_step(state, params)
    assert float(info.satisfaction_sum) == 0.0 and float(info.satisfaction_min) == 1.0
    after = service_metrics(later.totals)
    assert all(float(after[k]) == pytest.approx(float(m[k]), abs=1e-7) for k in m)


def test_the_conventions_of_a_day_without_cars_and_the_rejected_share():
    zero = EpisodeTotals.zeros()
    m = service_metrics(zero)
    assert set(m) == set(SERVICE_METRICS)
    assert m["mean_satisfaction"] == m["min_satisfaction"] == m["jain_index"] == 1.0
    assert m["rejected_share"] == 0.0 and np.isnan(m["satisfaction_gap"])
    busy = zero.replace(cars_arrived=jnp.float32(3.0), cars_rejected=jnp.float32(1.0))
    assert service_metrics(busy)["rejected_share"] == 0.25


def test_on_random_days_the_metrics_stay_in_their_ranges():
    params = make_params(station=three_level_station(), traffic=150.0, step_minutes=15.0)
    keys = jax.random.split(jax.random.PRNGKey(4), 3)
    totals = jax.jit(jax.vmap(lambda k: random_rollout(params, k)[2].totals))(keys)
    last = jax.tree.map(lambda x: np.asarray(x)[:, -1], totals)
    m = service_metrics(last)
    n = np.asarray(last.cars_served)
    assert (n > 0).all() and (np.asarray(last.cars_rejected) > 0).any()
    assert np.all(np.asarray(last.satisfaction_sum) <= n + 1e-4)
    assert np.all(m["jain_index"] >= 1.0 / n - 1e-6) and np.all(m["jain_index"] <= 1.0 + 1e-6)
    assert np.all(m["min_satisfaction"] <= m["mean_satisfaction"] + 1e-6)
    assert np.all((m["mean_satisfaction"] > 0.0) & (m["mean_satisfaction"] <= 1.0))
    assert np.all((m["rejected_share"] > 0.0) | (np.asarray(last.cars_rejected) == 0))
