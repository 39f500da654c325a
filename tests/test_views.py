"""One transition path per view: both views auto-reset through the core's one function, report
the same info keys, the MARL view has one action validator with one error type, and the core
step does no host work."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core import actions, make_params, multiple_types, observation, simulator
from chargax_marl.marl import ChargaxMARL, FinalObservationWrapper, parallel_env
from chargax_marl.marl import env as marl_env
from chargax_marl.single import Chargax

KEY = jax.random.PRNGKey(3)
SMALL = {"station": multiple_types(2, 2), "step_minutes": 60, "traffic": 150.0}


@pytest.fixture(scope="module")
def params():
    return make_params(**SMALL)


@pytest.fixture(scope="module")
def marl(params):
    return ChargaxMARL(params)


def tree_equal(a, b) -> bool:
    """Same structure and values: integer and bool leaves exactly, floats to float32 rounding
    (eager and jitted runs of the same computation may differ in the last bit)."""

    def same(x, y):
        x, y = np.asarray(x), np.asarray(y)
        if np.issubdtype(x.dtype, np.floating):
            return x.dtype == y.dtype and np.allclose(x, y, rtol=1e-6, atol=1e-6)
        return np.array_equal(x, y)

    return jax.tree.structure(a) == jax.tree.structure(b) and all(
        same(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b))
    )


def assert_close(x, y, msg=""):
    np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-6, atol=1e-6, err_msg=msg)


def last_step_state(params):
    """A busy state one step before the end of the day."""
    state = simulator.reset(KEY, params)
    for t in range(3):
        busy = jnp.full(params.station.num_leaves, 1)
        state, _ = simulator.step(jax.random.fold_in(KEY, t), state, busy, params)
    return state.replace(timestep=jnp.asarray(params.num_steps - 1, jnp.int32))


# ------------------------------------------------------------------ one auto-reset


@pytest.mark.parametrize("at_end", [False, True])
def test_both_views_step_is_core_step_then_reset_selection(params, marl, at_end):
    state = last_step_state(params) if at_end else simulator.reset(KEY, params)
    single = Chargax(params)
    levels = jnp.asarray([2, -1, 0, 1, 1], jnp.int32)
    stepped, core_info = simulator.step(KEY, state, levels, params)
    fresh = simulator.reset(KEY, params)
    want = fresh if at_end else stepped
    assert bool(simulator.is_done(stepped, params)) == at_end
    core = simulator.step_auto_reset(KEY, state, levels, params)
    assert tree_equal(core, (want, stepped, core_info, jnp.asarray(at_end)))

    action = single.levels_to_action(levels)
    obs, got, reward, terminated, truncated, info = single.step(KEY, state, action)
    assert tree_equal(got, want) and bool(truncated) == at_end and not bool(terminated)
    assert_close(reward, core_info.reward)
    assert_close(obs, observation.flat_obs(want, params))
    assert_close(info["final_observation"], observation.flat_obs(stepped, params))

    obs, got, rewards, dones, infos = marl.step(KEY, state, marl.levels_to_actions(levels))
    assert tree_equal(got, want) and bool(dones["__all__"]) == at_end
    assert_close(jnp.stack(list(rewards.values())), jnp.full(marl.num_agents, core_info.reward))
    assert_close(jnp.stack([obs[a] for a in marl.agents]), marl.get_obs_matrix(want))
    assert "final_observation" not in infos  # JaxMARL's convention: every leaf per agent
    # opt-in: the same step with the observations of the stepped state
    final = FinalObservationWrapper(marl)
    f_obs, f_state, f_rewards, f_dones, f_infos = final.step(
        KEY, state, marl.levels_to_actions(levels)
    )
    assert tree_equal((f_obs, f_state, f_rewards, f_dones), (obs, got, rewards, dones))
    assert_close(f_infos["final_observation"], marl.get_obs_matrix(stepped))
    indices = marl.stack_actions(marl.levels_to_actions(levels))
    a_obs, a_state, _, _, a_info = final.step_arrays(KEY, state, indices)
    assert tree_equal(a_state, want)
    assert_close(a_obs, marl.get_obs_matrix(want))
    assert_close(a_info["final_observation"], marl.get_obs_matrix(stepped))


def test_both_views_auto_reset_through_the_core_function(params, monkeypatch):
    """Neither view re-implements the auto-reset: both call ``simulator.step_auto_reset``."""
    calls = []
    original = simulator.step_auto_reset

    def counted(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(simulator, "step_auto_reset", counted)
    state = simulator.reset(KEY, params)
    single = Chargax(params)  # fresh instances: nothing compiled before the patch
    single.step(KEY, state, jnp.zeros(params.station.num_leaves, jnp.int32))
    assert len(calls) == 1
    marl = ChargaxMARL(params)
    marl.step(KEY, state, {a: 0 for a in marl.agents})
    assert len(calls) == 2


# ------------------------------------------------------------------ one info key set


def test_info_keys_are_the_same_in_both_views(params, marl):
    state = simulator.reset(KEY, params)
    single = Chargax(params)
    levels = jnp.asarray([2, -1, 0, 1, 1], jnp.int32)
    action, acts = single.levels_to_action(levels), marl.levels_to_actions(levels)
    single_step = single.step(KEY, state, action)[-1]
    single_env = single.step_env(KEY, state, action, params)[-1]
    marl_step = marl.step(KEY, state, acts)[-1]
    marl_env_info = marl.step_env(KEY, state, acts)[-1]
    indices = marl.stack_actions(acts)
    arrays = marl_env.step_arrays(KEY, state, indices, params, marl.action_offset)[-1]

    report = set(simulator.INFO_KEYS) | {"leaf_energy_kwh"}
    assert set(single_env) == report
    auto = set(simulator.AUTO_RESET_INFO_KEYS)
    assert set(single_step) == report | auto | {"final_observation"}  # gymnax's three keys
    assert set(single_env) <= set(marl_env_info) and report | auto <= set(marl_step)
    extra = {"agent_energy_kwh", "agent_reward_share"}  # the MARL view's per-agent entries
    assert set(marl_env_info) - set(single_env) == extra == set(marl_env.AGENT_INFO_KEYS)
    assert set(marl_step) - (report | auto) == extra
    assert set(arrays) == set(marl_env_info)
    for k in simulator.INFO_KEYS:  # the same values (the MARL view broadcasts scalars)
        assert_close(marl_env_info[k], jnp.broadcast_to(single_env[k], (marl.num_agents,)), k)
        assert_close(arrays[k], single_env[k], k)
    assert_close(marl_env_info["leaf_energy_kwh"], single_env["leaf_energy_kwh"])


def test_step_arrays_is_the_dict_step(params, marl):
    """The array transition and the dict API give the same numbers (one path)."""
    state = last_step_state(params)
    acts = {a: i % marl.num_actions for i, a in enumerate(marl.agents)}
    indices = marl.stack_actions(acts)
    obs, got, rewards, done, info = marl_env.step_arrays(
        KEY, state, indices, params, marl.action_offset, auto_reset=True
    )
    d_obs, d_state, d_rewards, d_dones, d_infos = marl.step(KEY, state, acts)
    assert tree_equal(got, d_state) and bool(done) == bool(d_dones["__all__"])
    assert_close(obs, jnp.stack([d_obs[a] for a in marl.agents]))
    assert_close(rewards, jnp.stack([d_rewards[a] for a in marl.agents]))
    for k, v in info.items():
        assert_close(d_infos[k], v if jnp.ndim(v) else jnp.broadcast_to(v, (marl.num_agents,)), k)


# ------------------------------------------------------------------ one validator, one error type


def test_missing_or_unknown_agent_is_one_value_error_everywhere(params, marl):
    state = simulator.reset(KEY, params)
    good = {a: marl.action_offset for a in marl.agents}
    missing = {a: v for a, v in good.items() if a != "port_1"}
    unknown = dict(good, robot=1)
    pz = parallel_env(params=params)
    pz.reset(seed=0)
    entry_points = {
        "step": lambda acts: marl.step(KEY, state, acts),
        "step_env": lambda acts: marl.step_env(KEY, state, acts),
        "jit(step_env)": lambda acts: jax.jit(marl.step_env)(KEY, state, acts),
        "stack_actions": marl.stack_actions,
        "check_actions": marl.check_actions,
        "validate_actions": marl.validate_actions,
        "actions_to_levels": marl.actions_to_levels,
        "pettingzoo step": pz.step,
    }
    for name, call in entry_points.items():
        for acts, agent in ((missing, "port_1"), (unknown, "robot")):
            pattern = f"agent.*{agent}.*\\[0, {marl.num_actions - 1}\\]"
            with pytest.raises(ValueError, match=pattern) as exc:
                call(acts)
            assert exc.type is ValueError, name  # not a KeyError, whichever the entry point


@pytest.mark.parametrize(
    "value, pattern",
    [
        ("2", r"port_1.*'2'.*numbers"),
        (np.zeros(2, np.int32), r"port_1.*shape \(2,\)"),
    ],
)
def test_bad_values_are_value_errors_in_both_modes(marl, value, pattern):
    acts = dict({a: 0 for a in marl.agents}, port_1=value)
    for strict in (False, True):
        with pytest.raises(ValueError, match=pattern):
            marl.validate_actions(acts, strict=strict)


def test_strict_mode_refuses_what_the_jax_api_clips(marl):
    """Out-of-range and non-integer indices: clipped by the JAX API (documented), refused by the
    strict check (PettingZoo), with the agent, the value and the allowed range named."""
    top = marl.num_actions - 1
    for value, clipped in ((top + 5, top), (-3, 0), (np.int64(2**40), top), (1.7, 1), (True, 1)):
        acts = dict({a: 0 for a in marl.agents}, port_2=value)
        assert int(marl.stack_actions(acts)[2]) == clipped
        with pytest.raises(ValueError, match=rf"port_2.*\[0, {top}\].*got") as exc:
            marl.check_actions(acts)
        assert str(value) in str(exc.value) or repr(value) in str(exc.value)


# ------------------------------------------------------------------ no host work in the core


def test_core_step_does_no_host_work(params, monkeypatch):
    """``simulator.step`` never reaches the host-side sanitiser: it runs with
    ``actions.host_array`` broken, eagerly and on a traced action under jit."""

    def broken(*args, **kwargs):
        raise AssertionError("host_array called from the core")

    monkeypatch.setattr(actions, "host_array", broken)
    state = simulator.reset(KEY, params)
    levels = jnp.asarray([2, -1, 0, 1, 1], jnp.int32)
    eager, _ = simulator.step(KEY, state, levels, params)
    traced, _ = jax.jit(lambda k, s, a: simulator.step(k, s, a, params))(KEY, state, levels)
    auto_step = jax.jit(lambda k, s, a: simulator.step_auto_reset(k, s, a, params))
    auto, *_ = auto_step(KEY, state, levels)
    assert tree_equal(eager, traced) and tree_equal(eager, auto)
    assert not hasattr(simulator, "actions")  # the sanitisers' module is not even imported there
    # static shapes are still checked
    with pytest.raises(ValueError, match=r"'action'.*one entry per leaf.*\(5,\)"):
        simulator.step(KEY, state, jnp.zeros(4, jnp.int32), params)
