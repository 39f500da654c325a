"""The single-agent view and whole-trajectory properties of the simulator."""

from __future__ import annotations

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hypothesis import HealthCheck, Phase, given, settings

from chargax_marl.core import make_params, multiple_splitters, reward, single_type
from chargax_marl.single import SCENARIOS, Chargax, GymnasiumEnv, LogWrapper, make
from tests.helpers import count_compiles, random_rollout, three_level_station, trees


def tree_equal(a, b):
    return all(
        jax.tree.leaves(
            jax.tree.map(lambda x, y: bool(np.array_equal(np.asarray(x), np.asarray(y))), a, b)
        )
    )


@pytest.fixture(scope="module")
def env():
    return Chargax(station=three_level_station(), traffic=150.0)


def run_env(env, params, key, num_steps):
    """Scan the env with random actions; return the stacked (obs, reward, infos) and final state."""

    def body(state, k):
        ka, ks = jax.random.split(k)
        action = env.action_space(params).sample(ka)
        obs, state, reward, term, trunc, info = env.step(ks, state, action, params)
        return state, (obs, reward, info["profit_eur"])

    k0, k1 = jax.random.split(key)
    _, state = env.reset(k0, params)
    return jax.lax.scan(body, state, jax.random.split(k1, num_steps))


# ------------------------------------------------------------------ energy bookkeeping


def check_energy_closes(params, key, num_steps=288):
    before, levels, after, info = random_rollout(params, key, num_steps)
    st = params.station
    eta = np.asarray(st.leaf_path_efficiency)
    e = np.asarray(info.leaf_energy_kwh)  # (T, L)
    is_port = np.asarray(st.leaf_kind) != 2
    grid_hand = np.where(e > 0, e / eta, e * eta).sum(axis=1)
    np.testing.assert_allclose(np.asarray(info.grid_net_kwh), grid_hand, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(
        np.asarray(info.energy_delivered_kwh), (e * is_port).sum(1), rtol=1e-5, atol=1e-4
    )
    np.testing.assert_allclose(
        np.asarray(info.battery_net_kwh), (e * ~is_port).sum(1), rtol=1e-5, atol=1e-4
    )
    closes = (
        np.asarray(info.grid_net_kwh)
        - np.asarray(info.energy_delivered_kwh)
        - np.asarray(info.battery_net_kwh)
    )
    np.testing.assert_allclose(closes, np.asarray(info.losses_kwh), atol=1e-4)
    assert np.all(np.asarray(info.losses_kwh) >= -1e-5)
    # The energy each car received is its SoC change times capacity (cars that stayed the whole step:
    # parked before and after, and no new car placed at the port this step; comparing the cars'
    # arrival SoC and capacity instead took a leaver and a newcomer with equal ones for one car).
    same_car = (
        np.asarray(before.occupied) & np.asarray(after.occupied) & ~np.asarray(info.leaf_arrived)
    )
    d_soc = (np.asarray(after.soc) - np.asarray(before.soc)) * np.asarray(before.capacity_kwh)
    np.testing.assert_allclose(
        np.where(same_car, d_soc, 0.0), np.where(same_car, e, 0.0), atol=2e-3
    )
    # SoC windows: never above 1, never below the arrival SoC.
    soc, arr = np.asarray(after.soc), np.asarray(after.arrival_soc)
    assert np.all(soc <= 1.0 + 1e-6) and np.all(soc >= arr - 1e-6)
    # Every node limit holds after the hard rescale.
    from chargax_marl.core.physics import node_flows_kw

    power = e / params.step_hours
    flows = np.asarray(jax.jit(jax.vmap(lambda p: node_flows_kw(p, st)))(jnp.asarray(power)))
    assert np.all(flows <= np.asarray(st.node_max_kw) * (1 + 1e-4) + 1e-3)
    return info, after


@pytest.mark.parametrize("builder", ["default", "three_level", "splitters", "single"])
def test_energy_closes_on_random_rollouts(builder):
    station = {
        "default": "multiple_types",
        "three_level": three_level_station(),
        "splitters": multiple_splitters(),
        "single": single_type(4, battery=True),
    }[builder]
    params = make_params(station=station, traffic=200.0)
    info, after = check_energy_closes(params, jax.random.PRNGKey(3))
    assert float(info.cars_arrived.sum()) > 0 and float(np.abs(info.energy_delivered_kwh).sum()) > 0


# Each example compiles a new station, so keep few and skip shrinking (a failure prints its tree).
@settings(
    max_examples=6,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
    phases=[Phase.explicit, Phase.reuse, Phase.generate],
)
@given(tree=trees(max_depth=3))
def test_energy_closes_on_generated_trees(tree):
    check_energy_closes(
        make_params(station=tree, traffic=150.0, step_minutes=30.0), jax.random.PRNGKey(1)
    )


def test_episode_totals_equal_the_sum_of_step_reports(small_params):
    _, _, after, info = random_rollout(small_params, jax.random.PRNGKey(5))
    totals = jax.tree.map(lambda x: x[-1], after.totals)
    e = np.asarray(info.leaf_energy_kwh)[:, : small_params.station.num_ports]
    assert float(totals.energy_charged_kwh) == pytest.approx(np.maximum(e, 0).sum(), rel=1e-4)
    assert float(totals.energy_discharged_kwh) == pytest.approx(-np.minimum(e, 0).sum(), rel=1e-4)
    assert float(totals.energy_delivered_kwh) == pytest.approx(e.sum(), rel=1e-4, abs=1e-3)
    assert float(totals.profit_eur) == pytest.approx(
        float(np.asarray(info.profit_eur).sum()), rel=1e-4
    )
    assert float(totals.cars_served) == float(np.asarray(info.cars_departed).sum())
    assert float(totals.cars_arrived) == float(np.asarray(info.cars_arrived).sum())
    # Every car that arrived is parked, or has left.
    parked = np.asarray(after.occupied)[-1, : small_params.station.num_ports].sum()
    assert float(totals.cars_arrived) == float(totals.cars_served) + parked


# ------------------------------------------------------------------ determinism and transforms


def test_jit_equals_no_jit(env):
    params = env.default_params
    key = jax.random.PRNGKey(7)
    jitted = jax.jit(run_env, static_argnums=(0, 3))(env, params, key, 6)
    with jax.disable_jit():
        eager = run_env(env, params, key, 6)
    jax.tree.map(
        lambda a, b: np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-5),
        jitted,
        eager,
    )


def test_vmap_over_keys_equals_a_loop(env):
    params = env.default_params
    keys = jax.random.split(jax.random.PRNGKey(11), 4)
    fn = jax.jit(lambda k: run_env(env, params, k, 48))
    batched = jax.vmap(fn)(keys)
    for i, k in enumerate(keys):
        single = fn(k)
        jax.tree.map(
            lambda b, s: np.testing.assert_allclose(
                np.asarray(b)[i], np.asarray(s), rtol=1e-5, atol=1e-5
            ),
            batched,
            single,
        )


def test_same_key_same_trajectory_and_constructing_twice_is_identical(env):
    params = env.default_params
    key = jax.random.PRNGKey(2)
    a = jax.jit(lambda k: run_env(env, params, k, 96))(key)
    b = jax.jit(lambda k: run_env(env, params, k, 96))(key)
    assert tree_equal(a, b)
    env2 = Chargax(station=three_level_station(), traffic=150.0)
    c = jax.jit(lambda k: run_env(env2, env2.default_params, k, 96))(key)
    assert tree_equal(a, c)
    d = jax.jit(lambda k: run_env(env, params, k, 96))(jax.random.PRNGKey(3))
    assert not tree_equal(a, d)


def test_day_ends_with_truncation_and_auto_reset(env):
    params = env.default_params
    wrapped = LogWrapper(env)
    key = jax.random.PRNGKey(0)
    obs, state = wrapped.reset(key, params)
    action = env.levels_to_action(jnp.full((7,), 10).at[6].set(0), params)

    def body(state, k):
        obs, state, r, term, trunc, info = wrapped.step(k, state, action, params)
        return state, (
            r,
            term,
            trunc,
            info["returned_episode"],
            info["returned_episode_returns"],
            info["returned_episode_profit_eur"],
            state.env_state.timestep,
        )

    state, (r, term, trunc, ret_ep, ret_r, ret_profit, t) = jax.jit(
        lambda s: jax.lax.scan(body, s, jax.random.split(key, 290))
    )(state)
    trunc = np.asarray(trunc)
    assert not np.asarray(term).any()
    assert trunc[287] and trunc.sum() == 1 and np.asarray(ret_ep)[287]
    assert int(t[287]) == 0 and int(t[288]) == 1  # auto-reset to a fresh day
    day_return = float(np.asarray(r)[:288].sum())
    assert float(ret_r[287]) == pytest.approx(day_return, rel=1e-5)
    assert float(ret_r[289]) == pytest.approx(day_return, rel=1e-5)
    assert float(ret_profit[287]) == pytest.approx(
        day_return, rel=1e-5
    )  # alpha = 0: reward = profit


def test_action_space_and_level_mapping():
    env, params = make("shopping")
    space = env.action_space(params)
    assert space.shape == (17,) and int(space.nvec[0]) == 21
    # membership: in range and of the space's shape; any other shape is no element
    assert bool(space.contains(jnp.zeros(17, jnp.int32)))
    assert not bool(space.contains(jnp.full(17, 21)))
    assert not bool(space.contains(jnp.zeros(3, jnp.int32)))
    assert not bool(space.contains(jnp.zeros((2, 17), jnp.int32)))
    levels = jnp.arange(-10, 7)
    np.testing.assert_array_equal(
        np.asarray(env.action_to_levels(env.levels_to_action(levels), params)), levels
    )
    no_v2g, p2 = make("shopping", v2g=False)
    nvec = np.asarray(no_v2g.action_space(p2).nvec)
    assert (nvec[:16] == 11).all() and nvec[16] == 21  # the battery may always discharge
    cont, p3 = make("shopping", action_mode="continuous")
    assert cont.action_space(p3).shape == (17,)


# ------------------------------------------------------------------ scenarios and bad input


def test_every_named_scenario_runs_a_day():
    from chargax_marl.policies import always_max
    from chargax_marl.rollout import rollout_days

    assert {"shopping", "residential-high", "workplace-low", "highway-medium"} <= set(SCENARIOS)
    names = ("residential", "shopping", "workplace", "highway")
    all_params = [make(name)[1] for name in names]
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    # the four scenarios' days as one compiled program (one compile, not four)
    runs = jax.jit(lambda: [rollout_days(always_max, p, keys) for p in all_params])()
    for name, (totals, _, _) in zip(names, runs, strict=True):
        assert np.all(np.asarray(totals.cars_arrived) > 0), name
        assert np.all(np.isfinite(np.asarray(totals.profit_eur))), name
    # run eagerly, a policy's NaN levels are refused, not played as idle and scored
    nan_policy = lambda state, key, params: jnp.full(params.station.num_leaves, jnp.nan)  # noqa: E731
    with pytest.raises(ValueError, match="non-finite levels"):
        rollout_days(nan_policy, all_params[1], keys)


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        ({"action_mode": "sideways"}, ValueError, "action_mode"),
        ({"constraint_mode": "maybe"}, ValueError, "constraint_mode"),
        ({"num_levels": 0}, ValueError, "num_levels"),
        ({"step_minutes": 7}, ValueError, "step_minutes"),
        ({"customer_price_eur_kwh": float("nan")}, ValueError, "customer_price_eur_kwh"),
        ({"fixed_cost_eur": -1.0}, ValueError, "fixed_cost_eur"),
        ({"alpha": {"happiness": 1.0}}, KeyError, "happiness"),
        ({"traffic": "rush"}, KeyError, "rush"),
        ({"traffic": -3.0}, ValueError, "traffic"),
        ({"prices": "XX-1999"}, KeyError, "XX-1999"),
        ({"prices": np.full((3, 23), 0.1)}, ValueError, "shape"),
        ({"prices": np.full((3, 24), np.nan)}, ValueError, "finite"),
        ({"user_profile": "moon"}, KeyError, "moon"),
        ({"fleet": "Mars"}, KeyError, "Mars"),
        ({"station": "ring"}, KeyError, "ring"),
        ({"moer_kg_per_kwh": np.ones(10)}, ValueError, "moer_kg_per_kwh"),
        ({"moer_kg_per_kwh": -np.ones(288)}, ValueError, "moer_kg_per_kwh"),
        ({"grid_demand_kwh": np.ones(5)}, ValueError, "grid_demand_kwh"),
    ],
)
def test_bad_parameters_raise_clear_errors(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        make_params(**kwargs)


def test_make_rejects_unknown_scenario():
    with pytest.raises(KeyError, match="unknown scenario"):
        make("beach")


def test_custom_prices_array_runs():
    prices = np.tile(np.linspace(0.05, 0.3, 24, dtype=np.float32), (7, 1))
    env, params = make("shopping", prices=prices, first_weekday=0)
    assert params.num_days == 7
    obs, state = env.reset(jax.random.PRNGKey(0), params)
    assert 0 <= int(state.day) < 7 and np.all(np.isfinite(np.asarray(obs)))


# ------------------------------------------------------------------ Gymnasium


def test_gymnasium_wrapper_passes_the_checker():
    genv = GymnasiumEnv(station=three_level_station(), step_minutes=60.0)
    check_env(genv, skip_render_check=True)
    obs, _ = genv.reset(seed=3)
    assert genv.observation_space.contains(obs)
    total, steps, truncated = 0.0, 0, False
    while not truncated:
        obs, r, term, truncated, info = genv.step(genv.action_space.sample())
        total += r
        steps += 1
    assert (
        steps == 24
        and not term
        and info["episode_profit_eur"] == pytest.approx(total, rel=1e-4, abs=1e-4)
    )
    with pytest.raises(ValueError, match="outside the action space"):
        genv.step(np.full(7, 99))
    assert isinstance(genv.action_space, gymnasium.spaces.MultiDiscrete)


def test_a_new_station_s_spaces_and_price_tables_compile_a_program_per_table():
    # 43 ports and 20-minute steps: shapes no other test builds, so nothing is cached
    params = make_params(station="single_type", station_kwargs={"num_ports": 43}, step_minutes=20.0)
    env = Chargax()
    count = count_compiles(
        lambda: (
            env.action_space(params),
            env.observation_space(params),
            reward.price_tables(params),
        )
    )
    # the min levels, the leaf powers, the node flows and the prices: a few programs, not one
    # per operation
    assert count <= 8


def test_gymnasium_wrapper_passes_the_checker_with_episodes_from_noon():
    genv = GymnasiumEnv(
        station=three_level_station(), step_minutes=60.0, episode_start_hour=12, render_mode="ansi"
    )
    check_env(genv, skip_render_check=True)
    obs, _ = genv.reset(seed=3)
    assert genv.observation_space.contains(obs) and "time 12:00 " in genv.render()
    steps, truncated = 0, False
    while not truncated:
        obs, _, term, truncated, _ = genv.step(genv.action_space.sample())
        assert genv.observation_space.contains(obs) and not term
        steps += 1
        if steps == 12:
            assert "time 00:00 (+1 day)" in genv.render()
    assert steps == 24


def test_reset_to_day_refuses_the_last_day_when_episodes_start_after_midnight():
    env = Chargax(station=three_level_station(), step_minutes=60.0, episode_start_hour=12)
    last = env.default_params.num_days - 1
    env.reset_to_day(last - 1)
    with pytest.raises(ValueError, match=rf"\[0, {last - 1}\]"):
        env.reset_to_day(last)
