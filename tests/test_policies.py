"""Rule-based policies and the evaluation module."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl import policies as policies_lib
from chargax_marl.core import make_params, multiple_types, reward, simulator
from chargax_marl.core.physics import leaf_min_level, node_flows_kw
from chargax_marl.evaluation import (
    _policies_days,
    _policy_days,
    evaluate,
    evaluate_policy,
    play_days,
    run_days,
    run_policies_days,
    run_policy_days,
    split_days,
    summarize,
    validation_days,
    write_json,
)
from chargax_marl.policies import (
    POLICIES,
    for_single,
    get_policy,
    is_named_rule,
    minimum_power_kw,
    price_threshold,
)
from chargax_marl.single import Chargax
from tests.helpers import count_compiles, no_arrivals, place_car, start, three_level_station


@pytest.fixture(scope="module")
def params():
    return make_params(station=three_level_station(), traffic=200.0)


@pytest.fixture(scope="module")
def trajectories(params):
    """One day per policy: the levels chosen and the leaf energies that flowed. The days of
    all the policies are one compiled program, the policies taking turns through one
    simulator (``lax.map`` over them, ``lax.switch`` at each step): one compile of it."""
    branches = [functools.partial(policy, params=params) for policy in POLICIES.values()]

    def day(index):
        def body(state, k):
            k1, k2 = jax.random.split(k)
            levels = jax.lax.switch(index, branches, state, k1)
            new, info = simulator.step(k2, state, levels, params)
            return new, (levels, info.leaf_energy_kwh, info.requested_excess_kw)

        start = simulator.empty_state(jnp.asarray(3), params)
        return jax.lax.scan(body, start, jax.random.split(jax.random.PRNGKey(0), 288))[1]

    every = jax.jit(lambda: jax.lax.map(day, jnp.arange(len(branches))))()
    return {name: jax.tree.map(lambda x, i=i: x[i], every) for i, name in enumerate(POLICIES)}


@pytest.mark.parametrize("name", sorted(POLICIES))
def test_policies_choose_valid_levels_and_hold_node_limits(name, params, trajectories):
    levels, energy, excess = (np.asarray(x) for x in trajectories[name])
    low = np.asarray(leaf_min_level(params.station, params.num_levels, params.v2g))
    assert np.all(levels >= low) and np.all(levels <= params.num_levels)
    flows = np.asarray(
        jax.vmap(lambda e: node_flows_kw(e / params.step_hours, params.station))(
            jnp.asarray(energy)
        )
    )
    assert np.all(flows <= np.asarray(params.station.node_max_kw) * (1 + 1e-4) + 1e-3)
    if name in ("edf", "llf"):
        assert np.all(excess <= 1e-3), (
            "deadline policies plan within the grid-side node limits: nothing to rescale"
        )
    if name == "always_max":
        assert np.all(levels[:, :6] == 10) and np.all(levels[:, 6] == 0)


@pytest.mark.parametrize("name", ["edf", "llf"])
def test_deadline_policies_bring_a_car_close_to_its_target_home(name, params):
    """A car 1 kWh short of its target needs less than one level for a step: the level is
    rounded up (the car's target clips it), so it finishes and leaves instead of stalling."""
    p = no_arrivals(params)
    s = place_car(
        start(p),
        0,
        soc=0.49,
        capacity_kwh=100.0,
        max_rate_kw=50.0,
        target_soc=0.5,
        remaining_kwh=1.0,
        time_min=600.0,
        charge_sensitive=True,
    )
    lv = get_policy(name)(s, None, p)
    assert int(lv[0]) >= 1
    _, info = simulator.step(jax.random.PRNGKey(0), s, lv, p)
    assert float(info.cars_departed) == 1 and float(info.energy_delivered_kwh) == pytest.approx(
        1.0, rel=1e-4
    )


def test_battery_rule_is_always_max_plus_a_price_rule_for_the_battery():
    p = make_params(
        station=three_level_station(),
        prices=np.tile(np.arange(24.0) / 100.0, (3, 1)),
        first_weekday=0,
    )
    s = start(p)
    night, noon, evening = (
        np.asarray(get_policy("battery_rule")(s.replace(timestep=jnp.asarray(t)), None, p))
        for t in (12, 144, 276)
    )  # hours 1, 12, 23
    for lv in (night, noon, evening):
        assert np.all(lv[:6] == 10)
    assert night[6] == 10 and noon[6] == 0 and evening[6] == -10


@pytest.mark.parametrize(
    ("hourly", "cost_eur_kwh", "cycles"),
    [
        ([0.1] * 24, 0.0, False),  # a flat day: nothing to gain, only losses
        ([0.1] * 12 + [0.13] * 12, 150.0, False),  # 0.03 spread < losses + 0.025 of wear
        ([0.1] * 12 + [0.13] * 12, 0.0, True),  # the same spread pays when cycling is free
        ([0.1] * 12 + [0.30] * 12, 150.0, True),  # a wide spread pays for both
    ],
)
def test_battery_rule_cycles_only_where_the_spread_beats_losses_and_wear(
    hourly, cost_eur_kwh, cycles
):
    p = make_params(
        station=three_level_station(),
        prices=np.tile(np.asarray(hourly), (3, 1)),
        first_weekday=0,
        battery_cost_eur_kwh=cost_eur_kwh,
    )
    s = start(p)
    night, evening = (
        np.asarray(get_policy(name)(s.replace(timestep=jnp.asarray(t)), None, p))
        for name, t in (("battery_rule", 12), ("battery_rule", 276))
    )
    assert night[6] == (10 if cycles else 0) and evening[6] == (-10 if cycles else 0)
    assert np.all(night[:6] == 10) and np.all(evening[:6] == 10)
    # the rule blind to losses and wear charges at night whatever the spread
    naive = np.asarray(
        get_policy("battery_rule_naive")(s.replace(timestep=jnp.asarray(12)), None, p)
    )
    assert naive[6] == 10


def test_policies_respect_masks_without_v2g():
    p = make_params(station=three_level_station(), v2g=False)
    s = start(p)
    for name, policy in POLICIES.items():
        lv = np.asarray(policy(s, jax.random.PRNGKey(1), p))
        assert np.all(lv[:6] >= 0), name  # ports cannot discharge without V2G


def test_price_threshold_charges_fully_when_cheap_and_minimally_otherwise():
    p = no_arrivals(make_params(station=three_level_station()))
    prices = np.tile(np.arange(24, dtype=np.float32) / 100.0, (p.num_days, 1))  # cheapest at night
    p = p.replace(prices_eur_kwh=jnp.asarray(prices))
    s = place_car(
        start(p),
        0,
        soc=0.2,
        capacity_kwh=100.0,
        max_rate_kw=150.0,
        remaining_kwh=20.0,
        time_min=245.0,
    )
    cheap = np.asarray(price_threshold(s.replace(timestep=jnp.asarray(12)), None, p))  # 01:00
    dear = np.asarray(price_threshold(s.replace(timestep=jnp.asarray(240)), None, p))  # 20:00
    assert cheap[0] == 10 and cheap[6] == 10  # car and battery charge fully
    # 20 kWh in (245 - 5) min = 5 kW of a 100 kW port -> level ceil(0.5) = 1
    assert float(minimum_power_kw(s, p)[0]) == pytest.approx(5.0)
    assert dear[0] == 1 and dear[6] == -10 and dear[1] == 0


def test_edf_serves_the_earliest_deadline_first_on_a_tight_node():
    p = no_arrivals(make_params(station=three_level_station()))
    s = start(p)
    # evse0 (150 kW / 0.99) holds dc0 and dc1: dc1 leaves first and gets its full 100 kW.
    s = place_car(
        s, 0, soc=0.2, capacity_kwh=100.0, max_rate_kw=150.0, remaining_kwh=50.0, time_min=300.0
    )
    s = place_car(
        s, 1, soc=0.2, capacity_kwh=100.0, max_rate_kw=150.0, remaining_kwh=50.0, time_min=30.0
    )
    lv = np.asarray(get_policy("edf")(s, None, p))
    assert lv[1] == 10 and lv[0] == 4  # 150*0.99 - 100 = 48.5 kW left -> 4 levels of 10 kW


def test_evaluation_of_always_max_equals_a_hand_rolled_rollout(params):
    days = np.array([0, 5, 17])
    key = jax.random.PRNGKey(4)
    result = evaluate_policy("always_max", params, days, key)
    keys = jax.random.split(key, 3)
    profits = []
    for d, k in zip(days, keys):
        # the day's volume (and batteries) come from the day key's own key (trace.day_keys)
        state = simulator.empty_state(jnp.asarray(d), params, jax.random.fold_in(k, 1))
        for kk in jax.random.split(k, params.num_steps):
            k_act, k_step = jax.random.split(kk)
            state, info = jax.jit(simulator.step)(
                k_step, state, POLICIES["always_max"](state, k_act, params), params
            )
        profits.append(float(state.totals.profit_eur))
    assert result["metrics"]["daily_profit_eur"]["mean"] == pytest.approx(
        np.mean(profits), rel=1e-5
    )
    assert result["metrics"]["daily_profit_eur"]["std"] == pytest.approx(
        np.std(profits), rel=1e-4, abs=1e-3
    )
    assert result["days"] == [0, 5, 17]


def test_the_evaluation_refuses_levels_the_env_would_reinterpret():
    """NaN levels (played as idle) and non-integer ones (truncated) are counted inside the
    compiled play; `evaluate` and `run_policy_days` refuse them, naming the steps and days;
    `play_days` hands the counts to a caller's own ``jit``."""
    p = make_params(station=three_level_station(), traffic=150.0, step_minutes=60.0)
    days, key = np.array([2, 9]), jax.random.PRNGKey(1)
    n = p.station.num_leaves

    def nan_on_day_9(state, key):  # two NaN steps on day 9, else full power as floats
        bad = (state.day == 9) & ((state.timestep == 4) | (state.timestep == 20))
        return jnp.where(bad, jnp.nan, jnp.full(n, p.num_levels, jnp.float32))

    with pytest.raises(
        ValueError, match=r"non-finite levels .* on 2 steps, in 1 of the 2 days played .*\[9\]"
    ):
        evaluate(nan_on_day_9, p, days, key)
    with pytest.raises(ValueError, match=r"non-integer levels .* on 24 steps, in 1 of the 2"):
        run_policy_days(lambda s, k, q: jnp.where(s.day == 2, 0.5, 1.0) * jnp.ones(n), p, days, key)
    keys = jax.random.split(key, 2)
    totals, counts = jax.jit(lambda d, k: play_days(nan_on_day_9, p, d, k))(days, keys)
    np.testing.assert_array_equal(counts.nonfinite_steps, [0, 2])
    np.testing.assert_array_equal(counts.fractional_steps, [0, 0])
    # integer levels are never counted (no check in the program)
    _, counts = play_days(lambda s, k: jnp.full(n, p.num_levels, jnp.int32), p, days, keys)
    assert int(counts.nonfinite_steps.sum() + counts.fractional_steps.sum()) == 0


def test_only_the_functions_of_policies_are_named_rules(params):
    assert all(is_named_rule(rule) for rule in POLICIES.values())
    assert all(is_named_rule(get_policy(name)) for name in POLICIES)
    assert not is_named_rule(get_policy("battery_programme", params))  # built for the params
    assert not is_named_rule(lambda s, k, p: POLICIES["always_max"](s, k, p))


def test_a_named_rule_is_compiled_once_for_any_params_of_the_same_shapes(params):
    """`run_policy_days` takes the params as an argument of its program: other traffic and
    fees reuse the program compiled for the first params, and the totals are those of
    `run_days` with the params closed over."""
    days, key = np.array([2, 9]), jax.random.PRNGKey(7)
    rule = POLICIES["always_max"]
    busy = params.replace(arrival_rate=params.arrival_rate * 2.0)
    first = run_policy_days(rule, params, days, key)
    compiled = _policy_days._cache_size()
    again = run_policy_days(rule, busy, days, key)
    assert _policy_days._cache_size() == compiled
    for p, got in ((params, first), (busy, again)):
        closed = run_days(lambda s, k, p=p: rule(s, k, p), p, days, key)
        np.testing.assert_allclose(got.profit_eur, closed.profit_eur, rtol=1e-6, atol=1e-4)
    assert not np.allclose(first.profit_eur, again.profit_eur)


def test_several_rules_play_in_one_program_as_each_does_alone(params):
    """`run_policies_days` plays each rule on the same cars as `run_policy_days` does (to
    float32 rounding), in one program compiled once for a tuple of named rules and reused
    under other params; one policy alone is `run_policy_days` itself."""
    days, key = np.array([2, 9]), jax.random.PRNGKey(7)
    rules = (POLICIES["always_max"], POLICIES["price_threshold"])
    together = run_policies_days(rules, params, days, key)
    assert together.profit_eur.shape == (2, 2)
    for i, rule in enumerate(rules):  # each row is its own rule's (the rules differ)
        alone = run_policy_days(rule, params, days, key)
        for field in ("profit_eur", "energy_delivered_kwh", "cars_served"):
            np.testing.assert_allclose(
                getattr(together, field)[i], getattr(alone, field), rtol=1e-6, atol=1e-4
            )
    assert not np.allclose(together.profit_eur[0], together.profit_eur[1])

    compiled = _policies_days._cache_size()
    busy = params.replace(arrival_rate=params.arrival_rate * 2.0)
    assert count_compiles(lambda: run_policies_days(rules, busy, days, key)) == 0
    assert _policies_days._cache_size() == compiled

    one = run_policies_days(rules[:1], params, days, key)
    np.testing.assert_array_equal(
        one.profit_eur[0], run_policy_days(rules[0], params, days, key).profit_eur
    )
    with pytest.raises(ValueError, match="policies"):
        run_policies_days([], params, days, key)


def test_split_days_and_json(tmp_path, params):
    train, held = split_days(365, 100, seed=0)
    assert len(held) == 100 and len(train) == 265 and not set(train) & set(held)
    np.testing.assert_array_equal(split_days(365, 100, seed=0)[1], held)
    with pytest.raises(ValueError, match="num_eval"):
        split_days(10, 10)
    # a negative seed ended in numpy's "expected non-negative integer"
    with pytest.raises(ValueError, match=r"field 'seed' must be an integer >= 0, got -1"):
        split_days(10, 2, seed=-1)
    with pytest.raises(ValueError, match=r"field 'seed' must be an integer >= 0, got -1"):
        validation_days(train, 2, seed=-1)
    with pytest.raises(ValueError, match=r"field 'num_eval' must be an integer"):
        split_days(10, 2.5)
    p = make_params(station=three_level_station(), reset_days=train)
    days = [int(simulator.reset(k, p).day) for k in jax.random.split(jax.random.PRNGKey(0), 50)]
    assert set(days) <= set(train.tolist())
    with pytest.raises(ValueError, match="reset_days"):
        make_params(reset_days=[400])
    totals = run_days(
        lambda s, k: POLICIES["always_max"](s, k, params),
        params,
        jnp.array([1, 2]),
        jax.random.PRNGKey(0),
    )
    path = write_json({"always_max": summarize(totals)}, tmp_path / "out" / "eval.json")
    assert "daily_profit_eur" in path.read_text()


def test_for_single_maps_levels_to_env_actions():
    env = Chargax(station=three_level_station())
    p = env.default_params
    act = for_single("always_max", env)
    _, state = env.reset(jax.random.PRNGKey(0), p)
    a = np.asarray(act(state, jax.random.PRNGKey(1)))
    assert bool(env.action_space(p).contains(jnp.asarray(a)))
    np.testing.assert_array_equal(
        np.asarray(env.action_to_levels(jnp.asarray(a), p)), [10] * 6 + [0]
    )


def test_a_node_bound_car_that_rounds_to_idle_leaves_its_power_to_the_next():
    """At one level per direction a node-bound grant rounds to idle; the power it would have
    had stays for the cars after it. dc1 (leaves first) takes evse0's 100 kW port in full;
    dc0 (next) finds less than a port's worth left on evse0 and idles; dc2 (last, a 50 kW car
    on evse1) then still fits under dc_split, which dc0's unused grant had used up before."""
    p = no_arrivals(make_params(station=three_level_station(), num_levels=1))
    s = start(p)
    s = place_car(
        s, 1, soc=0.2, capacity_kwh=100.0, max_rate_kw=150.0, remaining_kwh=50.0, time_min=30.0
    )
    s = place_car(
        s, 0, soc=0.2, capacity_kwh=100.0, max_rate_kw=150.0, remaining_kwh=50.0, time_min=60.0
    )
    s = place_car(
        s, 2, soc=0.2, capacity_kwh=100.0, max_rate_kw=50.0, remaining_kwh=50.0, time_min=300.0
    )
    for name in ("edf", "llf"):
        lv = np.asarray(get_policy(name)(s, None, p))
        assert lv[1] == 1 and lv[0] == 0 and lv[2] == 1, (name, lv)
        _, info = simulator.step(jax.random.PRNGKey(0), s, jnp.asarray(lv), p)
        assert (
            float(info.requested_excess_kw) <= 1e-3
        )  # planned within the limits: nothing to rescale


def test_the_price_rules_read_the_current_day_of_a_multi_day_episode():
    """In an episode of two days the rules' "now" is the step's own buy price, on the second
    day too (the 24 hours of the episode's current day, not the first day's)."""
    params = make_params(station=multiple_types(2, 2), step_minutes=60, episode_days=2)
    T = params.num_steps
    state = simulator.empty_state(jnp.asarray(3), params)
    for t in (0, T - 1, T, T + 5, 2 * T - 1):
        s = state.replace(timestep=jnp.asarray(t, jnp.int32))
        day_prices, now = policies_lib._day_buy_prices(s, params)
        want = reward.grid_prices(s.day, s.timestep, params)[0]
        np.testing.assert_allclose(float(now), float(want), rtol=1e-6)
        assert day_prices.shape == (24,)
