"""The multi-agent view (JaxMARL API): spaces, observations, masks, joint-action equivalence with
the single-agent view, node coupling, jit/vmap, wrappers, bad input and the JAX example."""

from __future__ import annotations

import runpy
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jaxmarl.environments import spaces as jm_spaces

from chargax_marl.core import make_params, observation, physics, simulator
from chargax_marl.marl import ChargaxMARL, LogWrapper, WorldStateWrapper
from chargax_marl.marl.env import ancestor_loads, ancestor_table, obs_layout
from chargax_marl.policies import always_max
from chargax_marl.single import Chargax
from tests.helpers import (
    count_compiles,
    exact_jit,
    mixed_station,
    no_arrivals,
    place_car,
    start,
    three_level_station,
)

ROOT = Path(__file__).resolve().parents[2]
KEY = jax.random.PRNGKey(0)
L = 10


@pytest.fixture(scope="module")
def small():
    """6 ports (4 DC with V2G, 2 AC without) and a battery, 3 levels, busy traffic."""
    return ChargaxMARL(station=mixed_station(), traffic=150.0)


@pytest.fixture(scope="module")
def small_step(small):
    return jax.jit(small.step_env)


@pytest.fixture(scope="module")
def quiet(small):
    """The small station without arrivals, for hand-built states."""
    return ChargaxMARL(params=no_arrivals(small.params))


@pytest.fixture(scope="module")
def quiet_step(quiet):
    return jax.jit(quiet.step_env)


def idx_actions(env, **by_agent):
    """Action dict with every agent idle except the given indices."""
    idle = env.action_offset
    return {a: jnp.int32(by_agent.get(a, idle)) for a in env.agents}


# ------------------------------------------------------------------ API and spaces


def test_names_classes_and_spaces(small):
    assert small.agents == [f"port_{i}" for i in range(6)] + ["battery_0"]
    assert small.num_agents == 7
    assert small.agent_classes == {
        "dc_ports": ["port_0", "port_1", "port_2", "port_3"],
        "ac_ports": ["port_4", "port_5"],
        "batteries": ["battery_0"],
    }
    assert small.num_actions == 2 * L + 1
    depth, context = (
        3,
        observation.context_features(simulator.empty_state(0, small.params), small.params).shape[0],
    )
    assert small.obs_size == 8 + 3 + depth + context + 7
    for a in small.agents:
        assert isinstance(small.observation_space(a), jm_spaces.Box)
        assert isinstance(small.action_space(a), jm_spaces.Discrete)
        assert small.observation_space(a) is small.observation_spaces[a]
        assert small.action_space(a).n == 2 * L + 1
        assert small.observation_space(a).shape == (small.obs_size,)
    assert small.state_size == observation.obs_size(small.params)


def test_default_station_base_api():
    env = ChargaxMARL()
    assert env.agents == [f"port_{i}" for i in range(16)] + ["battery_0"]
    assert len(env.agent_classes["dc_ports"]) == 10 and len(env.agent_classes["ac_ports"]) == 6
    obs, state = env.reset(KEY)
    for a in env.agents:
        assert bool(env.observation_space(a).contains(obs[a])), a
        assert obs[a].dtype == jnp.float32
    actions = {
        a: env.action_space(a).sample(k)
        for a, k in zip(env.agents, jax.random.split(KEY, env.num_agents))
    }
    out = env.step(jax.random.PRNGKey(1), state, actions)
    assert len(out) == 5
    obs, state, rewards, dones, infos = out
    assert set(dones) == set(env.agents) | {"__all__"}
    assert set(rewards) == set(obs) == set(env.agents)
    assert len({float(r) for r in rewards.values()}) == 1  # the shared station reward
    for k, v in infos.items():  # one value per agent, nothing else (JaxMARL's baselines)
        assert v.shape == (env.num_agents,), k
    for k in (
        "profit_eur",
        "energy_delivered_kwh",
        "grid_net_kwh",
        "cars_arrived",
        "cars_rejected",
        "agent_energy_kwh",
    ) + tuple(f"penalty_{t}" for t in ("constraint", "satisfaction_time", "rejected")):
        assert k in infos, k
    avail = env.get_avail_actions(state)
    assert set(avail) == set(env.agents)
    assert all(
        m.shape == (2 * L + 1,) and m.dtype == jnp.bool_ and bool(m.all()) for m in avail.values()
    )
    assert env.get_global_state(state).shape == (env.state_size,)


def test_observation_layout(small):
    p = no_arrivals(small.params)
    env = ChargaxMARL(params=p)
    s = start(p)
    s = place_car(s, 0, soc=0.4, current_a=120.0)
    s = place_car(s, 1, soc=0.6, current_a=-80.0, arrival_soc=0.2)
    s = place_car(s, 4, soc=0.5, current_a=20.0)
    s = s.replace(current_a=s.current_a.at[6].set(50.0))  # battery charging at 50 A, 800 V = 40 kW
    obs = env.get_obs(s)
    feats = np.asarray(observation.leaf_features(s, p))
    ctx = np.asarray(observation.context_features(s, p))
    # node loads by hand: kW = V * I / 1000 at the leaves; on a node's grid side each leaf's
    # power / (charging) or * (discharging) the efficiencies from the leaf up to the node; / max_kw
    dc0, dc1, ac0, bat = 500 * 120 / 1e3, -500 * 80 / 1e3, 400 * 20 / 1e3, 800 * 50 / 1e3
    e_evse, e_dc, e_ac = 0.95 * 0.99, 0.95 * 0.99 * 0.98, 0.97 * 0.99
    evse0 = abs(dc0 / e_evse + dc1 * e_evse) / 150.0
    evse1 = 0.0
    dc_split = abs(dc0 / e_dc + dc1 * e_dc) / 200.0
    ac_split = ac0 / e_ac / 20.0
    grid = abs(dc0 / e_dc + dc1 * e_dc + ac0 / e_ac + bat / 0.95) / 220.0
    loads = {
        0: [evse0, dc_split, grid],
        1: [evse0, dc_split, grid],
        2: [evse1, dc_split, grid],
        4: [ac_split, grid, 0.0],
        6: [grid, 0.0, 0.0],
    }
    kinds = {0: [0, 1, 0], 4: [1, 0, 0], 6: [0, 0, 1]}
    for i, a in enumerate(env.agents):
        o = np.asarray(obs[a])
        assert o.shape == (env.obs_size,)
        np.testing.assert_array_equal(o[:8], feats[i])
        if i in kinds:
            np.testing.assert_array_equal(o[8:11], kinds[i])
        if i in loads:
            np.testing.assert_allclose(o[11:14], loads[i], rtol=1e-5, atol=1e-7)
        np.testing.assert_array_equal(o[14 : 14 + ctx.shape[0]], ctx)
        np.testing.assert_array_equal(o[14 + ctx.shape[0] :], np.eye(7)[i])
    np.testing.assert_array_equal(
        np.asarray(ancestor_table(p))[6], [0, -1, -1]
    )  # battery hangs under the grid
    np.testing.assert_array_equal(env.get_global_state(s), observation.flat_obs(s, p))


def test_a_new_station_s_env_compiles_a_program_per_table_not_per_operation():
    # 39 ports and 20-minute steps: shapes no other test builds, so nothing is cached
    params = make_params(station="single_type", station_kwargs={"num_ports": 39}, step_minutes=20.0)
    # the masks, the observation layout and the bounds: a few programs, not one per operation
    assert count_compiles(lambda: ChargaxMARL(params=params)) <= 8
    # with traced params the layout is traced too (inlined into the caller's program)
    layout = obs_layout(params, "scalar")
    traced = jax.jit(lambda p: obs_layout(p, "scalar"))(params)
    for a, b in zip(jax.tree.leaves(layout), jax.tree.leaves(traced)):
        assert isinstance(a, np.ndarray)
        np.testing.assert_array_equal(a, b)


def test_ancestor_loads_match_the_core_node_flows(default_params):
    st = default_params.station
    frac = jax.random.uniform(
        KEY, (st.num_leaves,), minval=-1.0, maxval=1.0
    )  # mixed charging and V2G
    state = start(default_params).replace(current_a=frac * st.leaf_max_current_a)
    flows = physics.node_flows_kw(state.current_a * st.leaf_voltage_v / 1000.0, st) / st.node_max_kw
    anc = np.asarray(ancestor_table(default_params))
    expected = np.where(anc >= 0, np.asarray(flows)[np.maximum(anc, 0)], 0.0)
    assert expected.max() > 0.1
    env = ChargaxMARL(params=default_params)
    np.testing.assert_allclose(
        ancestor_loads(state, default_params, env._layout), expected, rtol=1e-5, atol=1e-6
    )
    traced = jax.jit(lambda s, p: ancestor_loads(s, p))(
        state, default_params
    )  # station constants traced
    np.testing.assert_allclose(traced, expected, rtol=1e-5, atol=1e-6)


# ------------------------------------------------------------------ actions and masks


def test_masks_and_level_mapping(small):
    avail = {
        a: np.asarray(m)
        for a, m in small.get_avail_actions(simulator.empty_state(0, small.params)).items()
    }
    for a in ("port_0", "port_3", "battery_0"):  # V2G ports and the battery: every level
        assert avail[a].all()
    for a in ("port_4", "port_5"):  # AC ports without V2G: discharging levels masked
        np.testing.assert_array_equal(avail[a], np.arange(2 * L + 1) >= L)
    idx = jnp.array([0, 5, 10, 15, 20, 0, 99, -3], jnp.int32)[:7]
    np.testing.assert_array_equal(small.actions_to_levels(idx), [-10, -5, 0, 5, 10, 0, 10])
    # masked (port_5 at index 0 = level -10 without V2G) -> idle; 99 clipped to 20 = full power
    np.testing.assert_array_equal(
        small.actions_to_levels(jnp.array([-4, 0, 0, 0, 0, 3, 25])), [-10, -10, -10, -10, 0, 0, 10]
    )
    levels = always_max(None, None, small.params)
    acts = small.levels_to_actions(levels)
    np.testing.assert_array_equal(small.actions_to_levels(acts), levels)


def test_masked_action_falls_back_to_idle(quiet, quiet_step):
    s = place_car(
        start(quiet.params), 4, soc=0.8, arrival_soc=0.1, capacity_kwh=100.0, max_rate_kw=50.0
    )
    s = place_car(s, 0, soc=0.8, arrival_soc=0.1, capacity_kwh=100.0, max_rate_kw=200.0)
    masked = quiet_step(KEY, s, idx_actions(quiet, port_4=0))  # discharge at an AC port without V2G
    idle = quiet_step(KEY, s, idx_actions(quiet))
    for x, y in zip(jax.tree.leaves(masked), jax.tree.leaves(idle)):
        np.testing.assert_array_equal(x, y)
    assert float(masked[4]["agent_energy_kwh"][4]) == 0.0
    # the same index on a V2G port discharges
    assert float(quiet_step(KEY, s, idx_actions(quiet, port_0=0))[4]["agent_energy_kwh"][0]) < 0.0


def test_action_shapes_and_clipping(small, small_step):
    acts = idx_actions(small, port_0=17)
    as_1 = {a: v.reshape(1) for a, v in acts.items()}
    np.testing.assert_array_equal(small.stack_actions(as_1), small.stack_actions(acts))
    _, s = small.reset(KEY)
    top = small_step(KEY, s, idx_actions(small, port_1=2 * L))
    over = small_step(KEY, s, idx_actions(small, port_1=99))  # inside jit: clipped to the top index
    for x, y in zip(jax.tree.leaves(top), jax.tree.leaves(over)):
        np.testing.assert_array_equal(x, y)


def test_action_dtypes_clip_alike_stacked_or_mixed(small):
    """Actions of one dtype and of mixed dtypes (float, int64, bool) become the same clipped
    int32 indices, eagerly and under jit."""
    raw = [-5, 3, 2 * L + 7, 0, 1, 99, 2]
    want = np.clip(raw, 0, small.num_actions - 1)
    same = {a: jnp.int32(v) for a, v in zip(small.agents, raw)}
    mixed = dict(
        same, port_0=jnp.float32(-5.5), port_2=np.int64(2 * L + 7), port_4=jnp.asarray(True)
    )
    want_mixed = want.copy()
    want_mixed[4] = 1
    for acts, expected in ((same, want), (mixed, want_mixed)):
        np.testing.assert_array_equal(small.stack_actions(acts), expected)
        np.testing.assert_array_equal(jax.jit(small.stack_actions)(acts), expected)


def test_step_observations_are_the_matrix_rows(small, small_step):
    """The dict's rows (built per agent inside the jitted step) equal get_obs_matrix bit for bit."""
    _, s = small.reset(KEY)
    for t in range(3):
        obs, s, _, _, _ = small_step(
            jax.random.fold_in(KEY, t), s, idx_actions(small, port_0=2 * L, battery_0=0)
        )
        matrix = np.asarray(jax.jit(small.get_obs_matrix)(s))
        for i, a in enumerate(small.agents):
            np.testing.assert_array_equal(np.asarray(obs[a]), matrix[i])


def test_delta_mode_and_no_discharge_station():
    delta = ChargaxMARL(station=mixed_station(), action_mode="delta")
    assert delta.num_actions == 2 * L + 1
    assert all(
        bool(m.all())
        for m in delta.get_avail_actions(simulator.empty_state(0, delta.params)).values()
    )
    np.testing.assert_array_equal(delta.actions_to_levels(jnp.arange(7) * 3), np.arange(7) * 3 - L)
    no_v2g = ChargaxMARL(station="single_type", station_kwargs={"num_ports": 3, "v2g": False})
    assert no_v2g.num_actions == L + 1 and no_v2g.action_offset == 0
    np.testing.assert_array_equal(no_v2g.actions_to_levels(jnp.array([0, 4, 10])), [0, 4, 10])
    with pytest.raises(ValueError, match="continuous"):
        ChargaxMARL(station=mixed_station(), action_mode="continuous")
    with pytest.raises(ValueError, match="either"):
        ChargaxMARL(params=delta.params, traffic="low")


# ------------------------------------------------------------------ equivalence with the single-agent view


def test_joint_action_equivalence_over_a_day(small):
    p = small.params
    single, marl = Chargax(params=p), small
    low = np.asarray(physics.leaf_min_level(p.station, L, p.v2g))
    key = jax.random.PRNGKey(11)
    levels = jax.random.randint(key, (p.num_steps, 7), low, L + 1)  # valid levels only
    keys = jax.random.split(jax.random.PRNGKey(12), p.num_steps)
    _, s0 = single.reset_env(key, p)

    @exact_jit
    def run_single(s):
        def body(s, x):
            k, lv = x
            _, s, r, _, _ = single.step_env(k, s, single.levels_to_action(lv, p), p)
            return s, (s, r)

        return jax.lax.scan(body, s, (keys, levels))[1]

    @exact_jit
    def run_marl(s):
        def body(s, x):
            k, lv = x
            # the same levels as independent per-agent indices
            _, s, r, d, _ = marl.step_env(
                k, s, {a: lv[i] + marl.action_offset for i, a in enumerate(marl.agents)}
            )
            return s, (s, r, d)

        return jax.lax.scan(body, s, (keys, levels))[1]

    states_s, r_s = run_single(s0)
    states_m, r_m, d_m = run_marl(s0)
    for a in marl.agents:
        np.testing.assert_array_equal(r_m[a], r_s)
    for x, y in zip(jax.tree.leaves(states_m), jax.tree.leaves(states_s)):
        np.testing.assert_array_equal(x, y)
    done = np.asarray(d_m["__all__"])
    assert not done[:-1].any() and done[-1]
    assert float(states_m.totals.energy_delivered_kwh[-1]) != 0.0  # the day actually charged cars


def test_delta_and_absolute_mappings_match_the_single_agent_env(small):
    idx = jax.random.randint(KEY, (50, 7), 0, 2 * L + 1)
    for marl in (small, ChargaxMARL(params=small.params.replace(action_mode="delta"))):
        single = Chargax(params=marl.params)
        valid = np.asarray(jax.vmap(lambda i: marl.actions_to_levels(i))(idx))
        keep = np.all(np.asarray(marl._avail_np)[np.arange(7), np.asarray(idx)], axis=1)
        for row, lv in zip(np.asarray(idx)[keep], valid[keep]):
            np.testing.assert_array_equal(
                single.action_to_levels(single.levels_to_action(lv, marl.params), marl.params), lv
            )
            np.testing.assert_array_equal(lv, row - L)


# ------------------------------------------------------------------ node coupling


def test_node_limits_rescale_every_agent(quiet, quiet_step):
    env = quiet
    s = start(quiet.params)
    for i in range(4):
        s = place_car(s, i, soc=0.2, capacity_kwh=1000.0, max_rate_kw=1000.0)
    full = 2 * L
    obs, s1, _, _, info = quiet_step(
        KEY, s, idx_actions(env, port_0=full, port_1=full, port_2=full, port_3=full)
    )
    kw = np.asarray(info["agent_energy_kwh"])[:4] / (5.0 / 60.0)
    # Each port asks 100 kW. On the grid side of dc_split (200 kW) a port's kW count / (0.95 * 0.99 *
    # 0.98): four ports get 50 kW there each, 46.08 kW at the cars (less the core's 1e-6 margin).
    eta = 0.95 * 0.99 * 0.98
    np.testing.assert_allclose(kw, 50.0 * eta, rtol=1e-5)
    assert float(info["penalty_constraint"][0]) == pytest.approx(
        0.0, abs=1e-4
    )  # nothing flowed over a limit
    assert float(info["requested_excess_kw"][0]) == pytest.approx(400 / eta - 200, rel=1e-4)
    # the agents now see the coupling: deepest node first, grid side
    np.testing.assert_allclose(
        np.asarray(obs["port_0"])[11:14], [100 * 0.98 / 150, 1.0, 200 / 220], rtol=1e-4
    )


# ------------------------------------------------------------------ jit and vmap


def test_vmap_reset_and_step_match_a_loop(small, small_step):
    keys = jax.random.split(jax.random.PRNGKey(5), 8)
    actions = {
        a: jax.random.randint(k, (8, 1), 0, small.num_actions)  # (1,) per env, as IPPO passes them
        for a, k in zip(small.agents, jax.random.split(KEY, small.num_agents))
    }
    obs_b, states_b = jax.jit(jax.vmap(small.reset))(keys)
    obs2_b, states2_b, rew_b, done_b, info_b = jax.jit(jax.vmap(small.step_env))(
        keys, states_b, actions
    )
    assert obs2_b["port_0"].shape == (8, small.obs_size) and info_b["profit_eur"].shape == (
        8,
        small.num_agents,
    )
    for j in range(8):
        obs, state = small.reset(keys[j])
        obs2, state2, rew, done, _ = small_step(
            keys[j], state, {a: v[j, 0] for a, v in actions.items()}
        )
        for a in small.agents:
            np.testing.assert_allclose(obs_b[a][j], obs[a], rtol=1e-6, atol=1e-6)
            np.testing.assert_allclose(obs2_b[a][j], obs2[a], rtol=1e-5, atol=1e-6)
            np.testing.assert_allclose(rew_b[a][j], rew[a], rtol=1e-5, atol=1e-6)
        assert int(states2_b.day[j]) == int(state2.day)
        np.testing.assert_array_equal(states2_b.occupied[j], state2.occupied)


# ------------------------------------------------------------------ wrappers


def test_log_and_world_state_wrappers():
    base = ChargaxMARL(station=mixed_station(), traffic=150.0, step_minutes=60)
    env = LogWrapper(WorldStateWrapper(base))
    n, steps = base.num_agents, base.params.num_steps

    @jax.jit
    def run(key):
        obs, state = env.reset(key)

        def body(carry, k):
            obs, state = carry
            acts = {a: jnp.int32(2 * L) for a in base.agents}
            obs, state, rew, done, info = env.step(k, state, acts)
            return (obs, state), (
                rew["port_0"],
                done["__all__"],
                info,
                obs["world_state"],
                state.env_state,
            )

        (obs, state), out = jax.lax.scan(body, (obs, state), jax.random.split(key, steps + 3))
        return obs, out

    obs0, _ = env.reset(KEY)
    assert obs0["world_state"].shape == (n, base.state_size)
    obs, (rew, done, info, ws, states) = run(KEY)
    done = np.asarray(done)
    assert done[steps - 1] and done.sum() == 1
    for k in (
        "returned_episode_returns",
        "returned_episode_lengths",
        "returned_episode",
        "returned_episode_profit_eur",
    ):
        assert info[k].shape == (steps + 3, n), k
    returned = np.asarray(info["returned_episode_returns"])
    np.testing.assert_allclose(returned[steps - 1], rew[:steps].sum(), rtol=1e-4)
    np.testing.assert_allclose(
        returned[-1], returned[steps - 1]
    )  # kept until the next episode ends
    assert np.asarray(info["returned_episode_lengths"])[steps - 1, 0] == steps
    assert (
        np.asarray(info["returned_episode"])[steps - 1].all()
        and not np.asarray(info["returned_episode"])[0].any()
    )
    np.testing.assert_allclose(
        np.asarray(info["returned_episode_profit_eur"])[steps - 1], rew[:steps].sum(), rtol=1e-4
    )
    # the world state describes the returned (post-reset) state
    last = jax.tree.map(lambda x: x[steps - 1], states)
    assert int(last.timestep) == 0
    np.testing.assert_allclose(ws[steps - 1][0], base.get_global_state(last), rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(ws[steps - 1][3], ws[steps - 1][0])


# ------------------------------------------------------------------ bad input


def test_check_actions(small):
    good = {a: 10 for a in small.agents}
    np.testing.assert_array_equal(small.check_actions(good), np.full(7, 10))
    mixed = dict(
        good, port_0=np.int64(3), port_1=np.array([4]), port_2=jnp.int32(5), port_3=jnp.array([6])
    )
    np.testing.assert_array_equal(small.check_actions(mixed)[:4], [3, 4, 5, 6])
    cases = [
        ({a: 10 for a in small.agents[1:]}, r"port_0.*\[0, 20\]"),
        (dict(good, robot=1), "robot"),
        (dict(good, port_2=21), r"port_2.*\[0, 20\].*21"),
        (dict(good, port_2=-1), r"port_2.*\[0, 20\]"),
        (dict(good, port_3=1.5), r"port_3.*\[0, 20\]"),
        (dict(good, port_3=np.float32(2.0)), r"port_3.*\[0, 20\]"),
        (dict(good, battery_0="up"), r"battery_0.*\[0, 20\]"),
        (dict(good, battery_0=True), r"battery_0.*\[0, 20\]"),
        (dict(good, port_4=np.array([1, 2])), r"port_4.*shape"),
        ([1, 2, 3], "dict"),
    ]
    for actions, pattern in cases:
        with pytest.raises(ValueError, match=pattern):
            small.check_actions(actions)


def test_missing_agent_inside_jit_names_it(small, small_step):
    _, s = small.reset(KEY)
    actions = idx_actions(small)
    del actions["port_3"]
    with pytest.raises(ValueError, match="missing agent.*port_3"):
        small_step(KEY, s, actions)
    with pytest.raises(ValueError, match="port_1.*shape"):
        small.step_env(KEY, s, dict(idx_actions(small), port_1=jnp.zeros((2,), jnp.int32)))


# ------------------------------------------------------------------ example


def test_jaxmarl_rollout_example_runs(capsys):
    example = runpy.run_path(str(ROOT / "examples" / "jaxmarl_rollout.py"), run_name="example")
    out = example["main"](["--num-envs", "4", "--step-minutes", "60"])
    printed = capsys.readouterr().out
    assert "mean day profit" in printed and "env-steps/s" in printed
    assert out["profit"].shape == (4,) and np.isfinite(out["profit"]).all()
    np.testing.assert_allclose(out["logged_profit"], out["profit"], rtol=1e-4, atol=1e-3)


def test_scalar_agent_id_keeps_observations_linear():
    from chargax_marl.marl import ChargaxMARL

    onehot = ChargaxMARL(station=three_level_station(), step_minutes=60.0)
    scalar = ChargaxMARL(station=three_level_station(), step_minutes=60.0, agent_id="scalar")
    n = onehot.num_agents
    assert scalar.obs_size == onehot.obs_size - n + 1
    obs, _ = scalar.reset(jax.random.PRNGKey(0))
    ids = [float(obs[a][-1]) for a in scalar.agents]
    np.testing.assert_allclose(ids, np.arange(n) / (n - 1), rtol=1e-6)
    with pytest.raises(ValueError, match="agent_id"):
        ChargaxMARL(agent_id="binary")


# ------------------------------------------------------------------ per-agent reward shaping


def _day_rewards(*envs, seed=21):
    """Per-agent rewards ``(T, N)``, the station reward ``(T,)`` and the shares ``(T, N)`` over a
    day of random valid levels (the same levels and keys for every ``env``); for several envs,
    a list of them from one compiled program (one compile, not one per env)."""

    def inputs(env):
        p = env.params
        low = np.asarray(physics.leaf_min_level(p.station, L, p.v2g))
        levels = jax.random.randint(
            jax.random.PRNGKey(seed), (p.num_steps, p.station.num_leaves), low, L + 1
        )
        return jax.random.split(jax.random.PRNGKey(seed + 1), p.num_steps), levels, start(p)

    def day(env, keys, levels, s0):
        def body(s, x):
            k, lv = x
            _, s, r, _, info = env.step_env(
                k, s, {a: lv[i] + env.action_offset for i, a in enumerate(env.agents)}
            )
            return s, (
                jnp.stack([r[a] for a in env.agents], -1),
                info["reward"][0],
                info["agent_reward_share"],
                s,
            )

        return jax.lax.scan(body, s0, (keys, levels))[1]

    # exact: the agents' rewards are compared bit for bit with the station's
    run = exact_jit(lambda xs: [day(env, *x) for env, x in zip(envs, xs, strict=True)])
    out = jax.device_get(run([inputs(env) for env in envs]))
    return out[0] if len(envs) == 1 else out


def test_reward_shares_add_up_and_local_weight_mixes_them(small):
    weights = (0.3, 1.0)
    # without the refund of discharged car energy (the original Chargax's books), checked below
    off = ChargaxMARL(station=mixed_station(), traffic=150.0, refund_discharged_energy=False)
    days = _day_rewards(
        small, *(ChargaxMARL(params=small.params, local_reward_weight=w) for w in weights), off
    )
    r0, station, share, states0 = days[0]
    # default: every agent gets exactly the station reward
    np.testing.assert_array_equal(r0, np.broadcast_to(station[:, None], r0.shape))
    # the shares sum to the station reward every step, and differ between agents
    np.testing.assert_allclose(share.sum(-1), station, rtol=1e-5, atol=1e-4)
    assert np.abs(share - share.mean(-1, keepdims=True)).max() > 0.1
    for w, (rw, station_w, share_w, states_w) in zip(weights, days[1:3], strict=True):
        # the weight changes the rewards only, never the trajectory or what infos report
        for x, y in zip(jax.tree.leaves(states_w), jax.tree.leaves(states0)):
            np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(station_w, station)
        np.testing.assert_allclose(rw, (1 - w) * station[:, None] + w * share, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(
            rw.sum(-1), (1 - w) * len(small.agents) * station + w * station, rtol=1e-5, atol=1e-3
        )
    # without the refund of discharged car energy (the original Chargax's books) the shares still
    # add up; the same levels now earn what the discharging cars' owners are not refunded
    _, station_off, share_off, states_off = days[3]
    for x, y in zip(jax.tree.leaves(states_off.soc), jax.tree.leaves(states0.soc)):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_allclose(share_off.sum(-1), station_off, rtol=1e-5, atol=1e-4)
    assert np.all(station_off >= station - 1e-4) and station_off.sum() > station.sum() + 0.1


def test_a_battery_share_is_the_money_its_own_energy_made(quiet, quiet_step):
    p = quiet.params
    s = start(p)
    bat = quiet.agents.index("battery_0")
    assert float(s.soc[bat]) > 0.0
    _, _, _, _, info = quiet_step(
        KEY, s, idx_actions(quiet, battery_0=0)
    )  # full discharge, no cars
    share = np.asarray(info["agent_reward_share"])
    assert float(info["agent_energy_kwh"][bat]) < 0.0
    # only the battery moved energy: its share exceeds an idle port's by its own money (its
    # feed-in less its wear), which is the whole profit before the fixed cost; idle ports share
    # the rest evenly
    ports = np.delete(share, bat)
    np.testing.assert_allclose(ports, ports[0], rtol=0, atol=1e-6)
    grid = float(info["grid_net_kwh"][0])
    assert grid < 0.0  # a net feed-in, paid at the grid's sell price
    wear = float(info["battery_wear_eur"][0])
    assert wear > 0.0
    own = -float(info["price_sell_grid_eur_kwh"][0]) * grid - wear
    np.testing.assert_allclose(
        own, float(info["profit_eur"][0]) + float(p.fixed_cost_eur), rtol=1e-5, atol=1e-6
    )
    np.testing.assert_allclose(share[bat] - ports[0], own, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan")])
def test_local_reward_weight_must_be_in_unit_interval(small, bad):
    with pytest.raises(ValueError, match="local_reward_weight.*\\[0, 1\\]"):
        ChargaxMARL(params=small.params, local_reward_weight=bad)


def test_the_array_step_is_the_dict_step_stacked(small):
    """``ChargaxMARL.step_arrays`` (actions ``(N,)`` in, observations ``(N, obs)`` and rewards
    ``(N,)`` out) gives the dict step's values, through the end of a day and its auto-reset."""
    params = small.params
    env = ChargaxMARL(params=params, local_reward_weight=0.5)
    key = jax.random.PRNGKey(5)
    _, state = env.reset(key)
    state = state.replace(timestep=jnp.asarray(params.num_steps - 3, jnp.int32))
    fresh = env.reset(jax.random.PRNGKey(6))[1]

    @exact_jit
    def both(k, s, idx):
        dict_out = env.step(k, s, {a: idx[i] for i, a in enumerate(env.agents)}, fresh)
        return dict_out, env.step_arrays(k, s, idx, fresh)

    ended = False
    for t in range(4):
        idx = jax.random.randint(jax.random.fold_in(key, t), (env.num_agents,), 0, env.num_actions)
        (obs_d, s_d, r_d, d_d, _), (obs_a, s_a, r_a, d_a, _) = both(
            jax.random.fold_in(key, 99 + t), state, idx
        )
        np.testing.assert_array_equal(np.stack([obs_d[a] for a in env.agents]), obs_a)
        np.testing.assert_array_equal(np.stack([r_d[a] for a in env.agents]), r_a)
        assert bool(d_d["__all__"]) == bool(d_a)
        ended = ended or bool(d_a)
        for x, y in zip(jax.tree.leaves(s_d), jax.tree.leaves(s_a)):
            np.testing.assert_array_equal(x, y)
        state = s_a
    assert ended  # the day ended and the step reset it
