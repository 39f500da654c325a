"""The teacher wrappers (`chargax_marl.wrappers`): potential-based reward shaping and
observation features, on the gymnax and the JaxMARL views."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core import make_params, simulator
from chargax_marl.core.observation import context_size, obs_size
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.marl import ChargaxMARL, FinalObservationWrapper, LogWrapper, WorldStateWrapper
from chargax_marl.single import Chargax
from chargax_marl.teachers import car_plan, prices, shaping, storage_value
from chargax_marl.wrappers import (
    BatteryShaping,
    CarPlanShaping,
    PlanAdviceObservation,
    RelativePriceObservation,
)
from tests.helpers import no_arrivals, place_car

TINY_ENV = {
    "station": "single_type",
    "station_kwargs": {"num_ports": 4, "battery": True},
    "step_minutes": 60.0,
    "num_levels": 1,
}


@pytest.fixture(scope="module")
def params():
    return make_params(**TINY_ENV)


def _battery_state(params, t: int, soc: float):
    """An empty station at step ``t`` of day 3 with the batteries at ``soc``."""
    s = simulator.empty_state(3, params, jax.random.PRNGKey(0))
    is_bat = jnp.asarray(np.asarray(params.station.leaf_kind) == KIND_BATTERY)
    return s.replace(timestep=jnp.int32(t), soc=jnp.where(is_bat, soc, s.soc))


def _charge_battery(params):
    """The single view's action: every port idle, the battery charging at full power."""
    is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
    levels = jnp.asarray(np.where(is_bat, 1, 0), jnp.int32)
    return Chargax(params=params).levels_to_action(levels, params)


def test_battery_shaping_adds_the_dp_potential_difference_on_a_constructed_state(params):
    """Step 5 of day 3, the battery at 40 %, charging: the wrapped reward minus the env's is
    ``V[3, 6](E + net) - V[3, 5](E)`` read off the programme's table by linear interpolation
    (numpy here), with no terminal booking mid-day; ``day_mean`` adds ``price * net``."""
    env = Chargax(params=params)
    state = _battery_state(params, 5, 0.4)
    action, key = _charge_battery(params), jax.random.PRNGKey(7)
    _, _, raw, _, _, info = env.step(key, state, action, params)
    _, _, shaped, _, _, shaped_info = BatteryShaping(env, "dp").step(key, state, action, params)
    grid, table = storage_value.dp_values(params)
    e0 = 0.4 * float(np.sum(np.asarray(params.station.battery_capacity_kwh)))
    net = float(info["battery_net_kwh"])
    assert net > 1.0 and float(info["battery_terminal_value_eur"]) == 0.0
    expected = np.interp(e0 + net, grid, table[3, 6]) - np.interp(e0, grid, table[3, 5])
    np.testing.assert_allclose(float(shaped - raw), expected, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(
        float(shaped_info["battery_shaping_eur"]), float(shaped - raw), atol=1e-6
    )
    _, _, flat, _, _, _ = BatteryShaping(env, "day_mean").step(key, state, action, params)
    price = float(storage_value.terminal_prices(params)[3])
    np.testing.assert_allclose(float(flat - raw), price * net, rtol=1e-4, atol=1e-5)


def _single_day(wrapped, params, key):
    """One whole day of random actions through ``wrapped`` and the env under it with the same
    keys: the shaping terms (wrapped minus raw reward), whether the day had ended, the start."""

    def body(carry, k):
        s, done = carry
        k_a, k_s = jax.random.split(k)
        a = wrapped.action_space(params).sample(k_a)
        _, _, raw, _, _, _ = wrapped._env.step(k_s, s, a, params)
        _, s2, r, _, trunc, _ = wrapped.step(k_s, s, a, params)
        return (s2, done | trunc), (r - raw, done)

    s0 = simulator.empty_state(4, params, key)
    keys = jax.random.split(key, int(params.num_steps))
    _, (terms, after_end) = jax.lax.scan(body, (s0, False), keys)
    return terms, after_end, s0


def test_battery_shaping_over_a_day_sums_to_the_telescoped_potential(params):
    """Over a whole day the terms add up to ``terminal price * E_0 - V[day, 0](E_0)``: the
    potential telescopes, the last step's potential is the env's terminal booking."""
    env = Chargax(params=params)
    wrapped = BatteryShaping(env, "dp")
    terms, after_end, s0 = jax.jit(lambda k: _single_day(wrapped, params, k))(jax.random.PRNGKey(3))
    assert not bool(after_end.any())  # the day's steps exactly
    grid, table = storage_value.dp_values(params)
    is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
    e0 = float(np.sum(np.asarray(s0.soc * s0.capacity_kwh)[is_bat]))
    const = float(storage_value.terminal_prices(params)[4]) * e0 - np.interp(e0, grid, table[4, 0])
    assert float(jnp.abs(terms).max()) > 0.01  # the battery moved
    np.testing.assert_allclose(float(terms.sum()), const, atol=5e-3)


def test_car_plan_shaping_over_a_day_sums_to_minus_the_car_s_first_plan_value(params):
    """No arrivals, one car parked at the start: the ports' terms over the day add up to minus
    its plan value at the start (after it leaves, or at the day's end, it is worth 0)."""
    quiet = no_arrivals(params)
    env = Chargax(params=quiet)
    wrapped = CarPlanShaping(env)
    s0 = place_car(
        simulator.empty_state(4, quiet), 0, time_min=300.0, remaining_kwh=30.0, capacity_kwh=60.0
    )

    def body(s, k):
        a = env.action_space(quiet).sample(k)
        _, _, raw, _, _, _ = env.step(k, s, a, quiet)
        _, s2, r, _, _, _ = wrapped.step(k, s, a, quiet)
        return s2, r - raw

    _, terms = jax.lax.scan(body, s0, jax.random.split(jax.random.PRNGKey(1), int(quiet.num_steps)))
    v0 = car_plan.car_values(quiet)(s0, s0.timestep, s0.time_remaining_min, s0.energy_remaining_kwh)
    assert float(v0[0]) > 1.0
    np.testing.assert_allclose(float(terms.sum()), -float(v0.sum()), rtol=1e-4, atol=1e-3)


@pytest.mark.parametrize("w", [0.0, 1.0])
def test_marl_shaping_adds_each_agent_s_term_and_passes_the_dict_api_through(params, w):
    """JaxMARL view: each agent's reward gains its part of the battery and car plan terms
    (``w = 1``: the battery agent the station's battery term, each port its own car's; ``w =
    0``: every agent the station's sums); observations, dones, infos and the action masks are
    the env's."""
    base = ChargaxMARL(params=params, local_reward_weight=w)
    env = CarPlanShaping(BatteryShaping(base, "dp"))
    state = place_car(_battery_state(params, 5, 0.4), 0, time_min=180.0, remaining_kwh=30.0)
    actions = {a: jnp.int32(base.num_actions - 1) for a in base.agents}  # everything charges
    key = jax.random.PRNGKey(2)
    obs0, _, raw, dones0, _ = base.step(key, state, actions)
    obs, _, shaped, dones, infos = env.step(key, state, actions)
    assert set(obs) == set(obs0) and set(dones) == set(dones0)
    for a in base.agents:
        np.testing.assert_array_equal(np.asarray(obs[a]), np.asarray(obs0[a]))
    diff = np.array([float(shaped[a] - raw[a]) for a in base.agents])
    battery = np.asarray(infos["battery_shaping_eur"])
    cars = np.asarray(infos["car_plan_shaping_eur"])
    np.testing.assert_allclose(diff, battery + cars, rtol=1e-5, atol=1e-5)
    is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
    station_battery = float(
        shaping.battery_potential(params, "dp")(state)(
            float(np.asarray(infos["agent_energy_kwh"])[is_bat].sum())
        )
    )
    own_cars = np.asarray(car_plan.car_potential(params)(state)(infos["agent_energy_kwh"]))
    if w == 1.0:
        want_battery, want_cars = np.where(is_bat, station_battery, 0.0), own_cars
    else:
        want_battery = np.full(is_bat.shape, station_battery)
        want_cars = np.full(is_bat.shape, own_cars.sum())
    np.testing.assert_allclose(battery, want_battery, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(cars, want_cars, rtol=1e-5, atol=1e-6)
    assert abs(station_battery) > 1e-3 and abs(own_cars[0]) > 1e-3
    masks, base_masks = env.get_avail_actions(state), base.get_avail_actions(state)
    for a in base.agents:
        np.testing.assert_array_equal(np.asarray(masks[a]), np.asarray(base_masks[a]))


def test_marl_observation_columns_are_the_teachers_and_the_spaces_grow(params):
    """JaxMARL view: every agent's observation ends with its leaf's plan advice, then the
    relative prices of its own observation; ``observation_space(agent)``, ``obs_size`` and the
    world state of MAPPO's wrapper follow."""
    base = ChargaxMARL(params=params)
    env = LogWrapper(RelativePriceObservation(PlanAdviceObservation(WorldStateWrapper(base))))
    width = 1 + int(params.price_horizon_hours) + 1
    assert env.obs_size == base.obs_size + width
    assert env.observation_space(base.agents[0]).shape == (base.obs_size + width,)
    space = env.observation_space(base.agents[-1])
    assert np.all(np.asarray(space.low)[-width:] >= -5.0)
    assert np.all(np.asarray(space.high)[-width:] <= 5.0)
    obs, log_state = env.reset(jax.random.PRNGKey(0))
    state = place_car(
        log_state.env_state, 0, time_min=180.0, remaining_kwh=30.0, charge_sensitive=True
    )
    obs = env.get_obs(state)
    raw = base.get_obs(state)
    advice = np.asarray(car_plan.plan_advice(params)(state))
    ctx_start = base.obs_size - base.num_agents - context_size(params)  # one-hot agent index last
    cols = prices.relative_price_columns(params, ctx_start)
    for i, a in enumerate(base.agents):
        assert obs[a].shape == (base.obs_size + width,)
        np.testing.assert_array_equal(np.asarray(obs[a][: base.obs_size]), np.asarray(raw[a]))
        assert float(obs[a][base.obs_size]) == advice[i]
        np.testing.assert_array_equal(
            np.asarray(obs[a][base.obs_size + 1 :]),
            np.asarray(prices.relative_prices(raw[a], *cols)),
        )
    assert advice[0] == 1.0  # a charge-sensitive car always charges
    key = jax.random.PRNGKey(1)
    obs2, _, _, _, _ = env.step(key, log_state, {a: jnp.int32(1) for a in base.agents})
    assert obs2["world_state"].shape == (base.num_agents, base.state_size)
    assert all(obs2[a].shape == (base.obs_size + width,) for a in base.agents)


def test_single_observation_columns_are_the_teachers_and_agree_with_the_marl_view(params):
    """Gymnax view: the flat observation ends with every leaf's plan advice, then the relative
    prices, the same values as an agent of the JaxMARL view reads."""
    env = Chargax(params=params)
    wrapped = RelativePriceObservation(PlanAdviceObservation(env))
    n, h = params.station.num_leaves, int(params.price_horizon_hours) + 1
    assert wrapped.observation_space(params).shape == (obs_size(params) + n + h,)
    _, state = env.reset(jax.random.PRNGKey(0), params)
    state = place_car(state, 1, time_min=180.0, remaining_kwh=30.0, charge_sensitive=True)
    obs = wrapped.get_obs(state, params)
    m = obs_size(params)
    np.testing.assert_array_equal(np.asarray(obs[:m]), np.asarray(env.get_obs(state, params)))
    advice = car_plan.plan_advice(params)(state)
    np.testing.assert_array_equal(np.asarray(obs[m:-h]), np.asarray(advice))
    marl = RelativePriceObservation(ChargaxMARL(params=params))
    agent_row = marl.get_obs(state)["port_0"]
    np.testing.assert_allclose(np.asarray(obs[-h:]), np.asarray(agent_row[-h:]), rtol=1e-6)
    o, _ = wrapped.reset(jax.random.PRNGKey(0), params)
    assert o.shape == (obs_size(params) + n + h,)


def test_a_final_observation_keeps_the_observations_size_through_the_columns(params):
    """The relative prices (read from the observation) are appended to an info's
    final_observation too: it had 51 entries while the observation had 58. Columns read from
    the state cannot be: over FinalObservationWrapper they are refused."""
    marl = ChargaxMARL(params=params)
    wrapped = RelativePriceObservation(FinalObservationWrapper(marl))
    _, state = wrapped.reset(jax.random.PRNGKey(0))
    h = int(params.price_horizon_hours) + 1
    actions = {a: jnp.int32(marl.action_offset) for a in marl.agents}
    obs, _, _, _, info = wrapped.step(jax.random.PRNGKey(1), state, actions)
    final = np.asarray(info["final_observation"])
    assert final.shape == (marl.num_agents, marl.obs_size + h)
    np.testing.assert_array_equal(final, np.stack([np.asarray(obs[a]) for a in marl.agents]))
    indices = jnp.full(marl.num_agents, marl.action_offset, jnp.int32)
    rows, _, _, _, info = wrapped.step_arrays(jax.random.PRNGKey(1), state, indices)
    np.testing.assert_array_equal(np.asarray(info["final_observation"]), np.asarray(rows))
    with pytest.raises(TypeError, match="PlanAdviceObservation: its columns are read from"):
        PlanAdviceObservation(FinalObservationWrapper(marl))
    single = RelativePriceObservation(Chargax(params=params))
    _, s_state = single.reset(jax.random.PRNGKey(0), params)
    s_obs, *_, s_info = single.step(
        jax.random.PRNGKey(1), s_state, np.zeros(params.station.num_leaves, np.int32), params
    )
    np.testing.assert_array_equal(np.asarray(s_info["final_observation"]), np.asarray(s_obs))


def _stack(env):
    shaped = CarPlanShaping(BatteryShaping(env, "dp"))
    return RelativePriceObservation(PlanAdviceObservation(shaped))


def test_wrapped_single_env_jit_equals_no_jit_and_vmaps(params):
    env = _stack(Chargax(params=params))
    action = _charge_battery(params)
    obs, state = env.reset(jax.random.PRNGKey(0), params)
    state = place_car(state, 0, time_min=180.0, remaining_kwh=30.0)
    key = jax.random.PRNGKey(5)
    eager = env.step(key, state, action, params)
    jitted = jax.jit(env.step)(key, state, action, params)
    for x, y in zip(jax.tree.leaves(eager), jax.tree.leaves(jitted)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-6, atol=1e-6)
    keys = jax.random.split(key, 3)
    obs_b, state_b = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    out = jax.jit(jax.vmap(env.step, in_axes=(0, 0, None, None)))(keys, state_b, action, params)
    assert out[0].shape == (3,) + obs.shape and out[2].shape == (3,)
    one = env.step(keys[1], jax.tree.map(lambda x: x[1], state_b), action, params)
    np.testing.assert_allclose(np.asarray(out[2][1]), np.asarray(one[2]), rtol=1e-5, atol=1e-5)


def test_wrapped_marl_env_jit_equals_no_jit_vmaps_and_feeds_a_jaxmarl_loop(params):
    """The wrapped JaxMARL view under ``jit`` and ``vmap`` over envs, as JaxMARL's IPPO drives
    it: dict observations of ``observation_space(agent).shape``, masks from
    ``get_avail_actions``, rewards and dones per agent."""
    env = LogWrapper(_stack(ChargaxMARL(params=params, local_reward_weight=1.0)))
    shape = env.observation_space(env.agents[0]).shape
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    obs, state = jax.vmap(env.reset)(keys)
    assert all(obs[a].shape == (4,) + shape for a in env.agents)
    avail = env.get_avail_actions(state)
    assert all(bool(avail[a][-1]) for a in env.agents)  # full power is every agent's
    actions = {a: jnp.full((4,), env.num_actions - 1, jnp.int32) for a in env.agents}
    eager = jax.vmap(env.step)(keys, state, actions)
    jitted = jax.jit(jax.vmap(env.step))(keys, state, actions)
    for x, y in zip(jax.tree.leaves(eager), jax.tree.leaves(jitted)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-6, atol=1e-6)
    obs2, _, rewards, dones, infos = jitted
    assert all(obs2[a].shape == (4,) + shape for a in env.agents)
    assert all(rewards[a].shape == (4,) for a in env.agents) and dones["__all__"].shape == (4,)
    assert infos["returned_episode"].shape == (4, env.num_agents)
