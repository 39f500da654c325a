"""The Gymnasium adapter's lifecycle: seeds, episode end, reset options,
rendering, pickling, shared compilation, gymnasium.make ids, finite observation bounds,
forked workers, and the single-agent env's spaces for gymnax code."""

from __future__ import annotations

import functools
import multiprocessing
import os
import pickle
import warnings

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnax.wrappers.purerl import LogWrapper as GymnaxLogWrapper

import chargax_marl  # noqa: F401  (registers the gymnasium ids)
from chargax_marl.lifecycle import ForkedProcessError, key_from_seed
from chargax_marl.marl import ChargaxMARL
from chargax_marl.single import Chargax, FlatDiscrete, GymnasiumEnv
from chargax_marl.single import wrappers as single_wrappers

HOURLY = dict(step_minutes=60.0)  # 24 steps per day


@pytest.fixture(scope="module")
def genv():
    return GymnasiumEnv(**HOURLY)


def first_obs_and_reward(env, seed):
    obs, _ = env.reset(seed=seed)
    out = env.step(np.full(env.action_space.shape, 15))
    return env.unwrapped._state.day, out[1]


# ------------------------------------------------------------------ seeds


def test_seeds_use_the_whole_integer(genv):
    assert np.array_equal(
        np.asarray(key_from_seed(7, "t")), np.asarray(jax.random.PRNGKey(7))
    )  # old seeds kept
    keys = {
        tuple(np.asarray(key_from_seed(s, "t")).tolist())
        for s in (0, 2**32, 2**64, 2**64 + 1, 2**100)
    }
    assert len(keys) == 5  # 2**32 is not seed 0, 2**64 does not overflow
    day0, r0 = first_obs_and_reward(genv, 0)
    day32, r32 = first_obs_and_reward(genv, 2**32)
    assert (int(day0), r0) != (int(day32), r32)
    first_obs_and_reward(genv, 2**64)
    assert first_obs_and_reward(genv, 2**70) == first_obs_and_reward(genv, 2**70)


@pytest.mark.parametrize("seed", [-1, 1.5, "3", True])
def test_bad_seeds_raise_naming_the_seed(genv, seed):
    with pytest.raises(
        ValueError, match=r"seed must be a non-negative integer.*" + repr(seed).replace(".", r"\.")
    ):
        genv.reset(seed=seed)


# ------------------------------------------------------------------ episode end and options


def test_step_after_truncation_raises(genv):
    genv.reset(seed=1)
    truncated, steps = False, 0
    while not truncated:
        _, _, _, truncated, _ = genv.step(genv.action_space.sample())
        steps += 1
    assert steps == 24
    with pytest.raises(RuntimeError, match="truncated.*reset"):
        genv.step(genv.action_space.sample())
    genv.reset()
    genv.step(genv.action_space.sample())


@pytest.mark.parametrize("day", [400, -1, "x", 2.5, None])
def test_day_option_is_range_checked(genv, day):
    if day is None:  # None means "no day": a random one
        genv.reset(options={"day": None})
        return
    with pytest.raises(
        ValueError, match=r"options\['day'\] must be an integer in \[0, 364\].*" + repr(day)
    ):
        genv.reset(options={"day": day})


def test_day_option_starts_that_day(genv):
    genv.reset(options={"day": 40})
    assert int(genv._state.day) == 40


@pytest.mark.parametrize("day", [-1, 365, 3.5, "x"])
def test_reset_to_day_is_range_checked(day):
    marl = ChargaxMARL(**HOURLY)
    with pytest.raises(ValueError, match=r"day must be .*\[0, 364\].*" + repr(day)[:2]):
        marl.reset_to_day(day)
    with pytest.raises(ValueError, match=r"\[0, 364\]"):
        Chargax(**HOURLY).reset_to_day(day)
    marl.reset_to_day(364)
    jax.jit(marl.reset_to_day)(jnp.asarray(3))  # traced days are not checked


@pytest.mark.parametrize("bad", [np.array(["a"] * 17), ["x"] * 17, [None] * 17, np.ones(17) * 1j])
def test_a_non_numeric_action_names_the_action_and_the_space(genv, bad):
    genv.reset(seed=0)
    with pytest.raises(ValueError, match=r"action .*action space MultiDiscrete.*numbers"):
        genv.step(bad)


# ------------------------------------------------------------------ render and pickle


def test_render_modes(capsys):
    for mode in ("ansi", "human", "rgb_array"):
        env = GymnasiumEnv(render_mode=mode, **HOURLY)
        env.reset(seed=0)
        env.step(env.action_space.sample())
        out = env.render()
        if mode == "ansi":
            assert "port_0" in out and "battery_0" in out
        elif mode == "human":
            assert out is None and "port_0" in capsys.readouterr().out
        else:
            assert out.dtype == np.uint8 and out.ndim == 3 and out.shape[2] == 3
    with pytest.raises(ValueError, match="render_mode.*'video'"):
        GymnasiumEnv(render_mode="video", **HOURLY)


def test_pickle_round_trip_continues_the_same_trajectory(genv):
    genv.reset(seed=4)
    genv.step(np.full(genv.action_space.shape, 12))
    clone = pickle.loads(pickle.dumps(genv))
    a = np.full(genv.action_space.shape, 18)
    o1, r1, *_ = genv.step(a)
    o2, r2, *_ = clone.step(a)
    np.testing.assert_array_equal(o1, o2)
    assert r1 == r2


def test_two_instances_compile_once():
    kw = dict(step_minutes=120.0, num_levels=3)  # a configuration no other test compiles
    a = GymnasiumEnv(**kw)
    a.reset(seed=0)
    a.step(a.action_space.sample())
    after_first = single_wrappers.compile_count()
    b = GymnasiumEnv(**kw)
    b.reset(seed=1)
    b.step(b.action_space.sample())
    assert single_wrappers.compile_count() == after_first


# ------------------------------------------------------------------ gymnasium.make


def test_gymnasium_make_ids():
    ids = [k for k in gymnasium.registry if k.startswith("chargax_marl/")]
    assert "chargax_marl/Chargax-v0" in ids and "chargax_marl/Chargax-workplace-high-v0" in ids
    env = gymnasium.make("chargax_marl/Chargax-highway-low-v0", render_mode="ansi", **HOURLY)
    assert env.unwrapped.params.num_steps == 24
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert isinstance(env.render(), str)
    env = gymnasium.make(
        "chargax_marl:chargax_marl/Chargax-v0", **HOURLY
    )  # the module-prefixed form
    env.reset(seed=0)


def test_importing_the_package_leaves_jax_unstarted():
    """``import chargax_marl`` (which registers the ids) and the view-free modules must not
    start JAX's backend, so a script may still set the host device count or call
    ``jax.distributed.initialize`` afterwards. The registration used to import the single
    view, hence gymnax, whose modules build arrays at import time: the flag set below was
    then ignored and JAX saw one device."""
    import subprocess
    import sys

    code = (
        "import os, chargax_marl, chargax_marl.core, chargax_marl.evaluation, chargax_marl.policies, "
        "chargax_marl.trace, chargax_marl.optimal\n"
        "import gymnasium\n"
        "assert 'chargax_marl/Chargax-v0' in gymnasium.registry\n"
        "os.environ['XLA_FLAGS'] = '--xla_force_host_platform_device_count=3'\n"
        "import jax\n"
        "print(len(jax.devices('cpu')))\n"
    )
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "XLA_FLAGS": ""}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-1] == "3", out.stdout


# ------------------------------------------------------------------ finite bounds


def _random_single_obs(env: Chargax, key, num_envs=4, num_steps=600):
    params = env.default_params
    space = env.action_space(params)

    def one(key):
        obs, state = env.reset(key, params)

        def body(carry, k):
            obs, state = carry
            k1, k2 = jax.random.split(k)
            obs, state, *_ = env.step(k2, state, space.sample(k1), params)
            return (obs, state), obs

        return jax.lax.scan(body, (obs, state), jax.random.split(key, num_steps))[1]

    obs = np.asarray(jax.jit(jax.vmap(one))(jax.random.split(key, num_envs)))
    return obs.reshape(-1, obs.shape[-1])


@pytest.mark.parametrize(
    "overrides", [{}, dict(constraint_mode="soft", observe_moer=True, v2g=False)]
)
def test_observations_respect_finite_bounds(overrides):
    env = Chargax(**overrides)
    space = env.observation_space()
    assert np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))
    obs = _random_single_obs(env, jax.random.PRNGKey(0))  # two days x 4 envs
    assert obs.std(axis=0).max() > 0.1
    below, above = obs < space.low, obs > space.high
    assert not below.any() and not above.any(), (
        np.flatnonzero(below.any(0)),
        np.flatnonzero(above.any(0)),
    )
    gspace = GymnasiumEnv(**overrides).observation_space
    np.testing.assert_array_equal(gspace.low, np.asarray(space.low))


def test_agent_observations_respect_finite_bounds():
    env = ChargaxMARL(constraint_mode="soft")
    space = env.observation_space(env.agents[0])
    n = env.num_actions

    def one(key):
        obs, state = env.reset(key)

        def body(state, k):
            k1, k2 = jax.random.split(k)
            idx = jax.random.randint(k1, (env.num_agents,), 0, n)
            obs, state, *_ = env.step(k2, state, {a: idx[i] for i, a in enumerate(env.agents)})
            return state, jnp.stack([obs[a] for a in env.agents])

        return jax.lax.scan(body, state, jax.random.split(key, 600))[1]

    obs = np.asarray(jax.jit(jax.vmap(one))(jax.random.split(jax.random.PRNGKey(1), 2))).reshape(
        -1, env.obs_size
    )
    assert np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))
    assert not (obs < space.low).any() and not (obs > space.high).any()


# ------------------------------------------------------------------ forked workers


def _construct_in_child(queue):
    try:
        GymnasiumEnv(**HOURLY)
        queue.put("constructed")
    except ForkedProcessError as e:
        queue.put(f"ForkedProcessError: {e}")


def test_forked_child_gets_a_clear_error_not_a_hang(genv):
    genv.reset(seed=0)  # JAX has started in this process
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # JAX's own "os.fork() was called" warning
        proc = ctx.Process(target=_construct_in_child, args=(queue,))
        proc.start()
    try:
        message = queue.get(timeout=120)  # a hang guard only
    finally:
        proc.join(timeout=30)
        if proc.is_alive():
            proc.kill()
    assert message.startswith("ForkedProcessError") and "spawn" in message


def test_spawned_async_vector_env_runs():
    make = functools.partial(gymnasium.make, "chargax_marl:chargax_marl/Chargax-v0", **HOURLY)
    venv = gymnasium.vector.AsyncVectorEnv([make, make], context="spawn")
    try:
        obs, _ = venv.reset(seed=0)
        assert obs.shape[0] == 2
        obs, reward, term, trunc, _ = venv.step(venv.action_space.sample())
        assert reward.shape == (2,) and not trunc.any()
    finally:
        venv.close()


# ------------------------------------------------------------------ spaces for gymnax code


def test_action_space_is_concrete_inside_jit_and_num_actions_is_a_choice_count():
    env = Chargax(**HOURLY)
    params = env.default_params

    @jax.jit
    def f(p):
        nvec = env.action_space(p).nvec
        assert isinstance(nvec, np.ndarray)  # concrete while tracing, also with traced params
        return jnp.zeros(int(nvec.max()))

    assert f(params).shape == (21,)
    assert env.num_actions == 21 and env.num_leaves == 17
    flat = FlatDiscrete(env)
    assert flat.num_actions == 21 * 21 == flat.action_space().n


def test_flat_discrete_through_gymnax_logwrapper():
    base = Chargax(**HOURLY)
    env = GymnaxLogWrapper(FlatDiscrete(base))
    flat = env._env
    full = flat.action_index(
        base.default_params.num_levels, 0
    )  # every port at full power, battery idle
    np.testing.assert_array_equal(np.asarray(flat.levels(full)), [10] * 16 + [0])
    with pytest.raises(ValueError, match=r"port_level 11 is not one of \[-10, .*10\]"):
        flat.action_index(11, 0)
    with pytest.raises(ValueError, match=r"battery_level 0.5 is not one of"):
        flat.action_index(10, 0.5)
    obs, state = env.reset(jax.random.PRNGKey(0))

    def body(state, k):
        obs, state, r, term, trunc, info = env.step(k, state, full)
        return state, (info["returned_episode"], info["returned_episode_returns"])

    _, (done, returns) = jax.lax.scan(body, state, jax.random.split(jax.random.PRNGKey(1), 24))
    assert bool(done[-1]) and not bool(done[:-1].any()) and np.isfinite(float(returns[-1]))
    with pytest.raises(ValueError, match="action_mode.*'continuous'"):
        FlatDiscrete(Chargax(action_mode="continuous", **HOURLY))


def test_subclass_keeps_its_own_observation_on_a_chosen_day():
    class Doubled(Chargax):
        def get_obs(self, state, params=None, key=None):
            return 2.0 * super().get_obs(state, params, key)

    plain, doubled = GymnasiumEnv(**HOURLY), GymnasiumEnv(env=Doubled(**HOURLY))
    for options in ({"day": 12}, None):
        a, _ = plain.reset(seed=3, options=options)
        b, _ = doubled.reset(seed=3, options=options)
        np.testing.assert_allclose(b, 2.0 * a)
