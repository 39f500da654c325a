"""``PriorityFill``: on hand-made stations a node that holds two cars of three serves the two
with the highest priority fully, ties go to the car that leaves first (earliest-deadline-first
when every agent asks for full power), the batteries' charging is kept from the ports, idle
and discharging actions pass unchanged, and the wrapped env still keeps JaxMARL's contract."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jaxmarl.wrappers.baselines import LogWrapper as JaxMARLLogWrapper

from chargax_marl.core import Battery, Port, Splitter, make_params
from chargax_marl.marl import ChargaxMARL
from chargax_marl.policies import earliest_deadline_first
from chargax_marl.single import Chargax
from chargax_marl.wrappers import (
    PriorityFill,
    priority_class_levels,
    priority_class_size,
    priority_fill_levels,
)
from tests.helpers import no_arrivals, place_car, start

KEY = jax.random.PRNGKey(0)
L = 10
PORT_KW = 50.0  # 500 V x 100 A


def station(battery: bool = False, v2g_current_a: float = 0.0) -> Splitter:
    """Three 50 kW ports (lossless) on a connection that holds two of them at full power, and
    optionally a 50 kW battery."""
    ports = tuple(Port(f"p{i}", "DC", 500.0, 100.0, v2g_current_a, 1.0) for i in range(3))
    extra = (Battery("bat", capacity_kwh=200.0, max_kw=50.0, efficiency=0.95, initial_soc=0.2),)
    # a little over two ports: a port's power is 50 kW to float32 rounding (50.000004)
    return Splitter("grid", 2 * PORT_KW + 0.01, ports + (extra if battery else ()), 1.0)


def parked(params, minutes=(600.0, 600.0, 600.0)):
    """A car on each port, far from full, leaving after ``minutes``."""
    state = start(params)
    for i, m in enumerate(minutes):
        state = place_car(
            state,
            i,
            soc=0.1,
            capacity_kwh=200.0,
            max_rate_kw=100.0,
            remaining_kwh=150.0,
            time_min=m,
        )
    return state


def params_of(**kwargs):
    return no_arrivals(make_params(step_minutes=60.0, num_levels=L, **kwargs))


def step_both(params, state, levels):
    """The stepped infos through the plain view and through `PriorityFill`, same actions."""
    env = ChargaxMARL(params=params)
    actions = env.levels_to_actions(jnp.asarray(levels, jnp.int32))
    plain = env.step_env(KEY, state, actions)[-1]
    filled = PriorityFill(env).step(KEY, state, actions)[-1]
    return plain, filled


def test_a_node_that_holds_two_cars_of_three_serves_the_two_highest_priorities_fully():
    params = params_of(station=station(), v2g=False)
    state = parked(params)
    asked = jnp.asarray([3, L, L], jnp.int32)
    np.testing.assert_array_equal(priority_fill_levels(asked, state, params), [0, L, L])
    plain, filled = step_both(params, state, asked)
    # the view rescales all three to the node's limit: 115 kW asked of 100
    assert float(plain["requested_excess_kw"][0]) > 0.0
    np.testing.assert_allclose(
        plain["agent_energy_kwh"], np.array([15, 50, 50]) * 100.01 / 115, 1e-4
    )
    # the fill serves the two priorities of L at full power and nothing is rescaled
    assert float(filled["requested_excess_kw"][0]) == 0.0
    np.testing.assert_allclose(filled["agent_energy_kwh"], [0.0, PORT_KW, PORT_KW], atol=1e-3)


def test_ties_go_to_the_car_that_leaves_first_which_is_edf_at_full_power():
    params = params_of(station=station(), v2g=False)
    state = parked(params, minutes=(300.0, 200.0, 400.0))
    full = jnp.full(3, L, jnp.int32)
    filled = priority_fill_levels(full, state, params)
    np.testing.assert_array_equal(filled, [L, L, 0])
    np.testing.assert_array_equal(filled, earliest_deadline_first(state, KEY, params))
    # a higher priority beats an earlier departure
    np.testing.assert_array_equal(
        priority_fill_levels(jnp.asarray([L, L - 1, L]), state, params), [L, 0, L]
    )


def test_the_batteries_charging_is_kept_from_the_ports():
    params = params_of(station=station(battery=True), v2g=False)
    state = parked(params)
    asked = jnp.asarray([L, L, L, L], jnp.int32)  # the battery charges at full power too
    levels = priority_fill_levels(asked, state, params)
    assert int(levels[3]) == L  # the battery's level is played as given
    # 50 / 0.95 kW grid side for the battery leaves 47.4 kW: the first port rounds down to 9
    # levels (45 kW), and the 2.4 kW left are less than a level of the next
    np.testing.assert_array_equal(levels[:3], [9, 0, 0])
    plain, filled = step_both(params, state, asked)
    assert float(plain["requested_excess_kw"][0]) > 0.0
    assert float(filled["requested_excess_kw"][0]) == 0.0


def test_idle_and_discharging_actions_pass_unchanged():
    params = params_of(station=station(v2g_current_a=100.0), v2g=True)
    state = parked(params)
    asked = jnp.asarray([-5, 0, L], jnp.int32)
    np.testing.assert_array_equal(priority_fill_levels(asked, state, params), asked)


@pytest.mark.parametrize("num_priorities", [None, 2])
def test_the_dict_and_array_steps_agree_and_keep_jaxmarls_info_contract(num_priorities):
    """In the view's levels (every agent at full power) and in two priority classes (a mix of
    classes and idle), the dict and array steps agree, no node is rescaled, and JaxMARL's
    LogWrapper steps the wrapper."""
    env = ChargaxMARL(station=wide_station(battery=True), step_minutes=60.0, traffic=150.0)
    wrapped = PriorityFill(env, num_priorities)
    full = wrapped.num_actions - 1
    asked = [full] * env.num_agents if num_priorities is None else [3, 2, 3, 1]
    obs, state = wrapped.reset(KEY)
    for _ in range(5):  # a few busy steps
        indices = jnp.asarray(asked)
        actions = dict(zip(env.agents, indices))
        d_obs, d_state, _, _, d_info = wrapped.step(KEY, state, actions)
        a_obs, _, _, _, a_info = wrapped.step_arrays(KEY, state, indices)
        np.testing.assert_allclose(a_obs, jnp.stack([d_obs[a] for a in env.agents]), 1e-6)
        np.testing.assert_allclose(a_info["agent_energy_kwh"], d_info["agent_energy_kwh"], 1e-6)
        assert float(d_info["requested_excess_kw"][0]) == 0.0
        state = d_state
    logged = JaxMARLLogWrapper(wrapped)
    _, s = jax.vmap(logged.reset)(jax.random.split(KEY, 2))
    acts = {a: jnp.full((2, 1), full) for a in env.agents}
    info = jax.vmap(logged.step)(jax.random.split(KEY, 2), s, acts)[-1]
    assert {k: v.shape for k, v in info.items() if v.shape != (2, env.num_agents)} == {}


def test_the_gymnax_view_is_refused():
    with pytest.raises(TypeError, match="field 'env' must be the JaxMARL view.*Chargax"):
        PriorityFill(Chargax(station=station(), step_minutes=60.0))


def wide_station(battery: bool = False) -> Splitter:
    """The three 50 kW ports on a connection that holds two and a half of them."""
    ports = tuple(Port(f"p{i}", "DC", 500.0, 100.0, 100.0, 1.0) for i in range(3))
    extra = (Battery("bat", capacity_kwh=200.0, max_kw=50.0, efficiency=1.0, initial_soc=0.5),)
    return Splitter("grid", 2.5 * PORT_KW + 0.01, ports + (extra if battery else ()), 1.0)


def test_priority_classes_grant_partial_power_at_the_envs_levels_where_view_levels_cannot():
    params = params_of(station=wide_station(), v2g=False)
    state = parked(params, minutes=(300.0, 200.0, 400.0))
    charge = jnp.full(3, 1, jnp.int32)  # one class: index 1 charges (no leaf discharges)
    levels = priority_class_levels(charge, state, params, 1)
    # the last car to leave gets the half port the connection has left, at the env's 10 levels
    np.testing.assert_array_equal(levels, [L, L, L // 2])
    np.testing.assert_array_equal(levels, earliest_deadline_first(state, KEY, params))
    # the same choice in the view's own levels at one level per direction rounds it to idle
    coarse = params.replace(num_levels=1)
    np.testing.assert_array_equal(priority_fill_levels(jnp.ones(3), state, coarse), [1, 1, 0])
    # a higher class is served first, whatever its departure
    np.testing.assert_array_equal(
        priority_class_levels(jnp.asarray([2, 1, 2]), state, params, 2), [L, L // 2, L]
    )


def test_priority_classes_discharge_idle_and_the_battery_mean_what_they_say():
    params = params_of(station=wide_station(battery=True), v2g=True)
    state = parked(params)
    env = PriorityFill(ChargaxMARL(params=params), num_priorities=2)
    assert env.num_actions == 4 and env.action_offset == 1
    assert all(env.action_space(a).n == 4 for a in env.agents)
    np.testing.assert_array_equal(priority_class_size(params, 2), (4, 1))
    # index 0 full discharge, 1 idle; the battery's charging classes are all full charge
    np.testing.assert_array_equal(
        priority_class_levels(jnp.asarray([0, 1, 3, 2]), state, params, 2), [-L, 0, L, L]
    )
    # out-of-range indices are clipped into [0, n)
    np.testing.assert_array_equal(
        priority_class_levels(jnp.asarray([-7, 99, 1, 1]), state, params, 2), [-L, L, 0, 0]
    )


def test_a_batterys_charging_class_comes_after_its_class_cars_and_before_lower_classes():
    params = params_of(station=wide_station(battery=True), v2g=False)
    state = parked(params, minutes=(300.0, 200.0, 400.0))
    # one class: the three cars take the 125 kW first (50, 50, 25), the battery gets nothing
    one = priority_class_levels(jnp.asarray([2, 2, 2, 2]), state, params, 1)
    np.testing.assert_array_equal(one, [L, L, L // 2, 0])
    # the battery in the top class charges first; the cars share the 75 kW left by departure
    two = priority_class_levels(jnp.asarray([2, 2, 2, 3]), state, params, 2)
    np.testing.assert_array_equal(two, [L // 2, L, 0, L])
    for levels in (one, two):
        _, _, _, _, info = ChargaxMARL(params=params).step_env(
            KEY, state, ChargaxMARL(params=params).levels_to_actions(levels)
        )
        assert float(info["requested_excess_kw"][0]) == 0.0


def test_priority_classes_mask_discharge_only_where_a_leaf_cannot_discharge():
    params = params_of(station=station(battery=True), v2g=False)
    env = PriorityFill(ChargaxMARL(params=params), num_priorities=3)
    assert env.num_actions == 5
    avail = env.get_avail_actions(None)
    np.testing.assert_array_equal(avail["port_0"], [False, True, True, True, True])
    np.testing.assert_array_equal(avail["battery_0"], [True] * 5)
    # without a leaf that may discharge there is no discharge index
    plain = PriorityFill(ChargaxMARL(params=params_of(station=station(), v2g=False)), 3)
    assert plain.num_actions == 4 and plain.action_offset == 0


def test_a_non_finite_class_action_is_idle_in_the_dict_step_as_in_the_array_step():
    params = params_of(station=wide_station(battery=True), v2g=False)
    env = ChargaxMARL(params=params)
    wrapped = PriorityFill(env, num_priorities=1)
    state = parked(params)  # a car on each port
    given = [jnp.nan, 2.0, jnp.inf, 2.0]  # NaN and +inf: idle, whatever the classes
    d_info = wrapped.step(KEY, state, dict(zip(env.agents, map(jnp.asarray, given))))[-1]
    a_info = wrapped.step_arrays(KEY, state, jnp.asarray(given))[-1]
    np.testing.assert_array_equal(d_info["agent_energy_kwh"], a_info["agent_energy_kwh"])
    np.testing.assert_array_equal(wrapped.levels(state, jnp.asarray(given)), [0, L, 0, L])
    assert (
        float(d_info["agent_energy_kwh"][0]) == 0.0 and float(d_info["agent_energy_kwh"][2]) == 0.0
    )


def test_priority_classes_refuse_the_views_level_mappings():
    env = ChargaxMARL(station=wide_station(), step_minutes=60.0)
    wrapped = PriorityFill(env, num_priorities=1)
    with pytest.raises(NotImplementedError, match="depends on the state; use levels"):
        wrapped.actions_to_levels(jnp.zeros(env.num_agents, jnp.int32))
    with pytest.raises(NotImplementedError, match="choose priority classes, not levels"):
        wrapped.levels_to_actions(jnp.zeros(env.num_agents, jnp.int32))
    # in the view's levels they are the view's
    plain = PriorityFill(env)
    levels = jnp.arange(env.num_agents, dtype=jnp.int32)
    np.testing.assert_array_equal(plain.actions_to_levels(plain.levels_to_actions(levels)), levels)


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_a_bad_number_of_priorities_is_refused_by_field(bad):
    env = ChargaxMARL(station=station(), step_minutes=60.0)
    with pytest.raises(ValueError, match="field 'num_priorities' must be None or a positive"):
        PriorityFill(env, num_priorities=bad)


def test_the_delta_action_mode_is_refused():
    env = ChargaxMARL(station=station(), step_minutes=60.0, action_mode="delta")
    with pytest.raises(ValueError, match="field 'action_mode' of the env must be 'absolute'"):
        PriorityFill(env)


@pytest.mark.parametrize("num_priorities", [-3, 0, 1.5, True])
def test_priority_class_size_refuses_what_is_not_a_count_of_classes(num_priorities):
    """-3 gave an action space of -1 classes."""
    params = params_of(station=wide_station(battery=True), v2g=True)
    with pytest.raises(ValueError, match=r"field 'num_priorities' must be an integer >= 1"):
        priority_class_size(params, num_priorities)
