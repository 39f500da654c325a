"""The session model v2: stays and energies by arrival hour, users' requests, the day-to-day
volume, public holidays, the user type per port kind and the random free port; and the
paper's mechanics as the ``session_model="paper"`` option."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl import policies, trace
from chargax_marl.benchmark.references import load_references
from chargax_marl.benchmark.tasks import TASKS, Task
from chargax_marl.core import datasets as ds
from chargax_marl.core import make_params, simulator, traffic
from chargax_marl.core.params import validate_params
from chargax_marl.core.station import single_type

KEY = jax.random.PRNGKey(0)
NL_2023_KINGS_DAY = 116  # 2023-04-27, a Thursday: day 116 of NL-2023


@pytest.mark.parametrize("name", ds.ALL_USER_PROFILES)
def test_v2_profiles_have_a_table_per_arrival_hour(name):
    p = ds.load_user_profile(name)
    for table in (p.stay_table_min, p.demand_table_kwh):
        assert table.shape == (24, 101) and (np.diff(table, axis=1) >= 0).all()
        assert (table > 0).all()
    assert p.request_ratios.shape == (101,)
    assert (p.request_ratios > 0).all() and (p.request_ratios <= 1).all()
    assert p.weekday_factors.shape == (7,) and 0.0 <= p.daily_volume_cv < 1.0
    if name != "highway":  # measured: the data's departures hold every user's leaving
        assert p.charge_sensitive_prob == 0.0 and p.dc_charge_sensitive == 1.0
        # users ask for more than their car takes on about half the sessions
        assert 0.4 < p.request_ratios[50] < 0.8


@pytest.mark.parametrize("name", ["residential", "shopping", "workplace"])
def test_nl_v2_tables_mix_back_to_the_elaad_distributions(name):
    """Over a workday's arrival hours the hour tables give ElaadNL's pooled stays and energies
    (the paper's draw, pooled x hourly mean, is wider)."""
    v2, paper = ds.load_user_profile(name), ds.load_user_profile(name, session_model="paper")
    mid = slice(5, 96)
    np.testing.assert_allclose(
        v2.stay_marginal_min[mid], paper.stay_quantiles_min[mid], rtol=0.03, atol=5.0
    )
    np.testing.assert_allclose(
        v2.demand_marginal_kwh[mid], paper.demand_quantiles_kwh[mid], rtol=0.03, atol=0.3
    )
    # and the hours keep their order: the hour with the longest mean stay stays longest
    longest = int(np.argmax(paper.stay_scale_by_hour))
    shortest = int(np.argmin(paper.stay_scale_by_hour))
    assert v2.stay_table_min[longest, 50] > v2.stay_table_min[shortest, 50]


def test_a_stay_is_drawn_from_the_arrival_hours_table():
    table = np.tile(np.linspace(10.0, 20.0, 101), (24, 1))
    table[9] = np.linspace(600.0, 700.0, 101)  # cars arriving 09:00-10:00 stay 10-11 h
    prof = ds.make_user_profile("hours", np.ones(288), table, np.linspace(5, 10, 101))
    params = make_params(user_profile=prof, traffic="high")
    for t, lo, hi in ((9 * 12 + 3, 600.0, 700.0), (14 * 12, 10.0, 20.0)):
        a = traffic.draw_arrivals(KEY, jnp.int32(t), jnp.bool_(True), params)
        stay = np.asarray(a.stay_min)
        assert ((stay >= lo - 1e-3) & (stay <= hi + 1e-3)).all(), (t, stay)


def test_day_volume_is_the_weekday_factor_times_a_mean_one_draw():
    factors = np.array([1.2, 1.0, 1.0, 1.0, 0.8, 1.1, 0.9])
    prof = ds.load_user_profile("workplace", daily_volume_cv=0.3, weekday_volume_factors=factors)
    params = make_params(user_profile=prof, holidays=None)  # NL-2023: day 0 is a Sunday
    monday = jnp.int32(1)
    assert float(traffic.day_volume(monday, params)) == pytest.approx(1.2)
    draws = jax.vmap(lambda k: traffic.day_volume(monday, params, k))(jax.random.split(KEY, 4000))
    ratio = np.asarray(draws) / 1.2
    assert ratio.mean() == pytest.approx(1.0, abs=0.02)
    assert ratio.std() == pytest.approx(0.3, abs=0.02)
    flat = make_params(user_profile=ds.load_user_profile("workplace", daily_volume_cv=0.0))
    same = jax.vmap(lambda k: traffic.day_volume(monday, flat, k))(jax.random.split(KEY, 8))
    np.testing.assert_array_equal(np.asarray(same), float(flat.weekday_volume_factors[0]))


def test_the_day_volume_scales_the_days_arrivals():
    """A day of volume 2 draws about twice the cars of a day of volume 1 (same keys)."""
    params = make_params(traffic="high")
    keys = jax.random.split(KEY, 288)

    def count(volume):
        n = jax.vmap(
            lambda k, t: traffic.draw_arrivals(k, t, jnp.bool_(True), params, volume).requested
        )(keys, jnp.arange(288))
        return int(n.sum())

    assert count(2.0) == pytest.approx(2 * count(1.0), rel=0.15)


def test_public_holidays_are_not_workdays_under_v2():
    v2, paper = make_params(), make_params(session_model="paper")
    assert bool(np.asarray(v2.holiday)[NL_2023_KINGS_DAY])
    assert not bool(simulator.is_workday(jnp.int32(NL_2023_KINGS_DAY), v2))
    assert bool(simulator.is_workday(jnp.int32(NL_2023_KINGS_DAY), paper))
    assert int(np.asarray(v2.holiday).sum()) == 10  # NL public holidays of 2023 (holidays pkg)
    assert not np.asarray(make_params(holidays=None).holiday).any()
    assert bool(np.asarray(make_params(prices="DE-2023", holidays="DE").holiday)[0])  # New Year


def test_holidays_need_the_prices_dates():
    with pytest.raises(ValueError, match="field 'holidays'.*dates"):
        make_params(prices=np.full((3, 24), 0.1), holidays="NL")
    with pytest.raises(ValueError, match="field 'holidays': unknown country 'XX'"):
        make_params(holidays="XX")
    # 'auto' without dates: no holidays
    assert not np.asarray(make_params(prices=np.full((3, 24), 0.1)).holiday).any()


def _replay(params, tr):
    act = lambda s, k: policies.always_max(s, k, params)  # noqa: E731
    return jax.jit(lambda t: trace.replay(act, params, t, KEY))(tr)


@pytest.mark.parametrize("ratio", [1.0, 0.5])
def test_satisfaction_and_missing_energy_are_against_the_users_request(ratio):
    """A time-sensitive car wants 20 kWh and stays long enough to get them; its user asked
    for 20 / ratio: satisfaction is ``ratio`` and the missing energy ``20 / ratio - 20``."""
    params = make_params(station=single_type(2, kind="AC"), traffic=1e-6)
    car = dict(arrival_soc=0.2, target_soc=0.6, capacity_kwh=50.0, stay_min=600.0)
    _, infos, _ = _replay(
        params,
        trace.trace_from_cars(params, [{"arrival_step": 0, **car, "request_ratio": ratio}], day=3),
    )
    departed = np.asarray(infos.cars_departed)
    assert departed.sum() == 1
    assert float(np.asarray(infos.satisfaction_sum).sum()) == pytest.approx(ratio, abs=1e-4)
    assert float(np.asarray(infos.missing_kwh).sum()) == pytest.approx(
        20.0 / ratio - 20.0, abs=1e-3
    )
    assert float(np.asarray(infos.energy_charged_kwh).sum()) == pytest.approx(20.0, abs=0.06)


def test_the_user_type_is_drawn_per_port_kind():
    """With P(u = 1) 0 at AC and 1 at DC ports, a car at a DC port leaves when charged and
    one at an AC port at the end of its stay."""
    prof = ds.load_user_profile("shopping", charge_sensitive_prob=0.0, dc_charge_sensitive_prob=1.0)
    params = make_params(user_profile=prof, traffic="high")
    a = traffic.draw_arrivals(KEY, jnp.int32(150), jnp.bool_(True), params)
    assert not np.asarray(a.charge_sensitive).any() and np.asarray(a.charge_sensitive_dc).all()
    state = simulator.empty_state(jnp.int32(3), params)
    placed, _ = traffic.place_arrivals(state, a.replace(requested=jnp.int32(16)), params)
    is_ac = np.asarray(params.station.leaf_kind) == 0
    sensitive = np.asarray(placed.charge_sensitive)[: params.station.num_ports]
    np.testing.assert_array_equal(sensitive, ~is_ac[: params.station.num_ports])


def test_a_car_parks_at_a_random_free_port_with_the_same_attributes():
    params = make_params(station=single_type(6, kind="AC"), traffic="high")
    first_free = params.replace(random_port_choice=jnp.asarray(False))
    state = simulator.empty_state(jnp.int32(3), params)
    busy = state.replace(occupied=state.occupied.at[:2].set(True))

    def place(k):
        a = traffic.draw_arrivals(k, jnp.int32(100), jnp.bool_(True), params).replace(
            requested=jnp.int32(1)
        )
        placed, _ = traffic.place_arrivals(busy, a, params)
        ref, _ = traffic.place_arrivals(busy, a, first_free)
        return placed, ref

    placed, ref = jax.jit(jax.vmap(place))(jax.random.split(KEY, 300))
    new = np.asarray(placed.occupied & ~busy.occupied)
    assert (new.sum(axis=1) == 1).all() and not new[:, :2].any()  # one car, at a free port
    port = new.argmax(axis=1)
    ref_new = np.asarray(ref.occupied & ~busy.occupied)
    assert ref_new[:, 2].all() and ref_new.sum() == 300  # first free: always port 2
    rows = np.arange(300)
    for field in ("capacity_kwh", "time_remaining_min", "soc"):
        np.testing.assert_array_equal(
            np.asarray(getattr(placed, field))[rows, port], np.asarray(getattr(ref, field))[:, 2]
        )
    counts = np.bincount(port, minlength=6)[2:]
    assert counts.min() > 300 / 4 * 0.6  # every free port, about a quarter each


def test_the_paper_option_keeps_the_v1_fingerprints_and_v2_moves_them():
    for task in TASKS.values():
        assert task.session_model == {1: "paper", 2: "v2", 3: "v3"}[task.version]
        load_references(task)  # raises on another fingerprint
    shopping = TASKS["Chargax-shopping-v1"]
    v2 = Task("shopping", 2, "shopping", 2, "v2")
    assert trace.params_fingerprint(v2.make_params()) != trace.params_fingerprint(
        shopping.make_params()
    )


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(daily_volume_cv=-0.1), r"daily_volume_cv: expected a value in \[0, inf\)"),
        (dict(daily_volume_cv=11.0), r"daily_volume_cv: expected a value in \[0, 10\]"),
        (dict(request_ratio_quantiles=np.linspace(0.5, 1.5, 101)), "request_ratio_quantiles"),
        (dict(weekday_volume_factors=np.ones(5)), r"weekday_volume_factors: expected shape \(7,\)"),
        (dict(dc_charge_sensitive_prob=2.0), r"dc_charge_sensitive_prob: expected a value"),
        (dict(stay_quantiles_min=np.ones((23, 101))), r"stay_quantiles_min: expected a 1-D"),
        (dict(stay_demand_corr=1.0), r"stay_demand_corr: expected a number in \(-1, 1\)"),
        (dict(stay_demand_corr=float("nan")), r"stay_demand_corr: expected a number in"),
    ],
)
def test_bad_session_fields_are_refused_by_name(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ds.load_user_profile("shopping", **kwargs)


def test_bad_session_settings_are_refused_by_name():
    with pytest.raises(ValueError, match="session_model: unknown 'v4'"):
        make_params(session_model="v4")
    with pytest.raises(ValueError, match="field 'port_choice' must be one of"):
        make_params(port_choice="nearest")
    with pytest.raises(ValueError, match="field 'session_model' must be one of"):
        Task("x", 1, "shopping", 2, "x", session_model="v4")


def test_a_task_refuses_another_session_model():
    task = TASKS["Chargax-shopping-v1"]
    assert task.train_params(session_model="paper").num_days == 365  # its own: fine
    with pytest.raises(ValueError, match="session_model='paper'.*session_model='v2'"):
        task.scored_params(session_model="v2")


def _arrival_draws(params, n_keys=400):
    """Stays and demands of the cars drawn at a busy step for ``n_keys`` keys."""
    keys = jax.random.split(KEY, n_keys)
    arr = jax.vmap(lambda k: traffic.draw_arrivals(k, jnp.int32(150), jnp.bool_(True), params))(
        keys
    )
    demand_kwh = (arr.target_soc - arr.arrival_soc) * arr.capacity_kwh
    return np.asarray(arr.stay_min).ravel(), np.asarray(demand_kwh).ravel()


def _spearman(a, b):
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def test_the_stay_demand_copula_joins_the_draws_and_keeps_their_marginals():
    """A positive correlation makes long stays take more energy; each draw's distribution
    stays the profile's; at 0 the demand's uniform is the one drawn, bit for bit."""
    station = single_type(8, kind="AC", voltage_v=230.0, max_current_a=16.0)
    plain = make_params(station=station, user_profile="shopping")
    joined = make_params(
        station=station, user_profile=ds.load_user_profile("shopping", stay_demand_corr=0.8)
    )
    stay0, demand0 = _arrival_draws(plain)
    stay1, demand1 = _arrival_draws(joined)
    assert abs(_spearman(stay0, demand0)) < 0.1
    assert _spearman(stay1, demand1) > 0.6
    np.testing.assert_array_equal(stay0, stay1)  # the stays are the same draws
    # the demands' marginal is unchanged (quartiles within sampling noise)
    np.testing.assert_allclose(
        np.quantile(demand1, [0.25, 0.5, 0.75]), np.quantile(demand0, [0.25, 0.5, 0.75]), rtol=0.1
    )
    u = jax.random.uniform(KEY, (2, 1000))
    np.testing.assert_array_equal(np.asarray(traffic._joined(u[0], u[1], plain)), np.asarray(u[1]))


def test_a_stay_demand_copula_moves_the_fingerprint_and_zero_keeps_it():
    base = ds.load_user_profile("shopping")
    fp = trace.params_fingerprint(make_params(user_profile=base))
    assert fp == trace.params_fingerprint(TASKS["Chargax-shopping-v2"].make_params())
    joined = ds.load_user_profile("shopping", stay_demand_corr=0.3)
    assert trace.params_fingerprint(make_params(user_profile=joined)) != fp
    with pytest.raises(ValueError, match="stay_demand_corr"):
        validate_params(make_params().replace(stay_demand_corr=jnp.float32(1.5)))
