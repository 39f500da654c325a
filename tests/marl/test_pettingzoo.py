"""The PettingZoo ``ParallelEnv`` adapter: PettingZoo's own API and seed tests, masks, errors,
determinism, state, rendering and the PettingZoo example."""

from __future__ import annotations

import runpy
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from chargax_marl.core import make_params, observation
from chargax_marl.marl import ChargaxParallelEnv, parallel_env
from tests.helpers import mixed_station

ROOT = Path(__file__).resolve().parents[2]
L = 10


SMALL = dict(station=mixed_station(), traffic=150.0, step_minutes=60)


@pytest.fixture(scope="module")
def small_params():
    return make_params(**SMALL)


@pytest.fixture(scope="module")
def small_env(small_params):
    return parallel_env(params=small_params)


def play_day(env, seed, actions_fn):
    obs, infos = env.reset(seed=seed)
    trajectory = [(obs, infos)]
    t = 0
    while env.agents:
        trajectory.append(env.step(actions_fn(env, t)))
        t += 1
    return trajectory


# ------------------------------------------------------------------ PettingZoo's own tests


def test_parallel_api_default_station():
    env = parallel_env()
    assert env.metadata == {
        "name": "chargax_v0",
        "render_modes": ["ansi", "human", "rgb_array"],
        "is_parallelizable": True,
        "render_fps": 4,
    }
    assert len(env.possible_agents) == 17 and env.params.num_steps == 288
    parallel_api_test(env, num_cycles=1000)
    parallel_seed_test(lambda: parallel_env())


def test_parallel_api_custom_three_level_station(small_params):
    env = parallel_env(params=small_params)
    parallel_api_test(env, num_cycles=1000)
    parallel_seed_test(lambda: parallel_env(**SMALL))


# ------------------------------------------------------------------ spaces, masks, observations


def test_spaces_masks_and_observations(small_env):
    env = small_env
    assert env.possible_agents == [f"port_{i}" for i in range(6)] + ["battery_0"]
    for a in env.possible_agents:
        assert env.observation_space(a) is env.observation_space(a)
        assert env.action_space(a) is env.action_space(a)
        assert (
            isinstance(env.action_space(a), gymnasium.spaces.Discrete)
            and env.action_space(a).n == 2 * L + 1
        )
    obs, infos = env.reset(seed=3)
    assert env.agents == env.possible_agents
    for a in env.agents:
        assert obs[a].dtype == np.float32 and env.observation_space(a).contains(obs[a])
        mask = infos[a]["action_mask"]
        assert mask.dtype == np.int8 and mask.shape == (2 * L + 1,)
    np.testing.assert_array_equal(
        infos["port_4"]["action_mask"], (np.arange(2 * L + 1) >= L).astype(np.int8)
    )
    assert infos["port_0"]["action_mask"].all() and infos["battery_0"]["action_mask"].all()
    obs, rewards, terms, truncs, infos = env.step({a: L for a in env.agents})
    assert len(set(rewards.values())) == 1 and isinstance(rewards["port_0"], float)
    assert not any(terms.values()) and not any(truncs.values())
    for key in (
        "profit_eur",
        "penalty_constraint",
        "energy_delivered_kwh",
        "cars_arrived",
        "energy_kwh",
    ):
        assert isinstance(infos["port_0"][key], float), key
    assert infos["port_0"]["action_mask"].dtype == np.int8
    state = env.state()
    assert state.shape == env.state_space.shape == (observation.obs_size(env.params),)
    assert env.state_space.contains(state)


def test_masked_action_is_idle(small_env):
    env = small_env
    actions = {ag: L for ag in env.possible_agents}
    env.reset(seed=5)
    idle = env.step(actions)
    env.reset(seed=5)
    masked = env.step(
        dict(actions, port_4=0, port_5=3)
    )  # discharge at AC ports without V2G -> idle
    for x, y in zip(idle[:4], masked[:4]):
        for ag in env.possible_agents:
            np.testing.assert_array_equal(x[ag], y[ag])


def test_same_seed_same_trajectory_and_truncation(small_env, small_params):
    rng = np.random.default_rng(0)
    table = rng.integers(0, 2 * L + 1, size=(small_params.num_steps, 7))

    def actions(env, t):
        return {a: int(table[t, i]) for i, a in enumerate(env.possible_agents)}

    first = play_day(small_env, 7, actions)
    other = parallel_env(**SMALL)
    second = play_day(other, 7, actions)
    assert len(first) == len(second) == small_params.num_steps + 1
    for step1, step2 in zip(first, second):
        for a in small_env.possible_agents:
            np.testing.assert_array_equal(step1[0][a], step2[0][a])  # observations
            info1, info2 = step1[-1][a], step2[-1][a]
            assert info1.keys() == info2.keys()
            assert all(np.array_equal(info1[k], info2[k]) for k in info1)
        assert step1[1:-1] == step2[1:-1]  # rewards, terminations, truncations
    _, rewards, terms, truncs, _ = first[-1]
    assert all(truncs.values()) and not any(terms.values())
    assert small_env.agents == []
    assert sum(step[1]["port_0"] for step in first[1:]) != 0.0
    # a different seed gives a different day or different cars
    third = play_day(other, 8, actions)
    assert any(not np.array_equal(x[0]["port_0"], y[0]["port_0"]) for x, y in zip(first, third))


def test_reset_to_a_chosen_day(small_env):
    small_env.reset(options={"day": 40})
    assert "day 40 " in parallel_env_ansi(small_env)
    with pytest.raises(ValueError, match="day"):
        small_env.reset(options={"day": 10_000})


def parallel_env_ansi(env) -> str:
    mode, env.render_mode = env.render_mode, "ansi"
    try:
        return env.render()
    finally:
        env.render_mode = mode


# ------------------------------------------------------------------ bad input


def test_bad_actions_raise_clear_errors(small_env):
    env = small_env
    env.reset(seed=0)
    good = {a: L for a in env.possible_agents}
    cases = [
        ({a: L for a in env.possible_agents[1:]}, r"port_0.*\[0, 20\]"),
        (dict(good, port_9=1), r"port_9"),
        (dict(good, port_2=21), r"port_2.*\[0, 20\]"),
        (dict(good, port_2=-1), r"port_2.*\[0, 20\]"),
        (dict(good, port_3=1.5), r"port_3.*\[0, 20\]"),
        (dict(good, battery_0="max"), r"battery_0.*\[0, 20\]"),
    ]
    for actions, pattern in cases:
        with pytest.raises(ValueError, match=pattern):
            env.step(actions)
    env.step(
        dict(good, port_0=np.int64(3), port_1=np.array([4]))
    )  # numpy integers of shape () or (1,) work


def test_step_before_reset_and_after_the_day_ends(small_params):
    env = parallel_env(params=small_params)
    with pytest.raises(RuntimeError, match="reset"):
        env.step({a: L for a in env.possible_agents})
    with pytest.raises(RuntimeError, match="reset"):
        env.state()
    env.reset(seed=0)
    for _ in range(small_params.num_steps):
        env.step({a: L for a in env.agents})
    assert env.agents == []
    with pytest.raises(RuntimeError, match="ended.*reset"):
        env.step({a: L for a in env.possible_agents})
    env.reset()
    assert env.agents == env.possible_agents


def test_invalid_render_mode():
    with pytest.raises(ValueError, match="render_mode"):
        ChargaxParallelEnv(
            station=mixed_station(), render_mode="video"
        )  # "human" is a supported mode


# ------------------------------------------------------------------ rendering


def test_render_ansi_and_rgb(small_params):
    text_env = parallel_env(params=small_params, render_mode="ansi")
    text_env.reset(seed=2)
    for _ in range(8):
        text_env.step({a: 2 * L for a in text_env.agents})
    text = text_env.render()
    assert isinstance(text, str)
    for word in ("port_0", "battery_0", "occupied", "SoC", "current", "price"):
        assert word in text
    assert len(text.splitlines()) == 2 + 7

    rgb_env = parallel_env(params=small_params, render_mode="rgb_array")
    rgb_env.reset(seed=2)
    blank = rgb_env.render()
    for _ in range(8):
        rgb_env.step({a: 2 * L for a in rgb_env.agents})
    frame = rgb_env.render()
    assert (
        frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3 and frame.shape[0] > 100
    )
    assert frame.shape == blank.shape and not np.array_equal(
        frame, blank
    )  # the day so far is drawn
    rgb_env.close()
    with pytest.warns(UserWarning, match="render_mode"):
        assert (
            parallel_env(params=small_params).render() is None
        )  # no render mode: warn and return None


# ------------------------------------------------------------------ example


def test_pettingzoo_example_runs(capsys):
    example = runpy.run_path(str(ROOT / "examples" / "pettingzoo_loop.py"), run_name="example")
    results = example["main"](["--step-minutes", "60"])
    printed = capsys.readouterr().out
    assert "random" in printed and "always_max" in printed and "profit" in printed
    assert set(results) == {"random", "always_max"} and all(
        np.isfinite(v) for v in results.values()
    )


def test_local_reward_weight_gives_each_agent_its_share(small_params):
    env = parallel_env(params=small_params, local_reward_weight=1.0)
    rng = np.random.default_rng(0)
    trajectory = play_day(
        env, 3, lambda e, t: {a: int(rng.integers(e.action_space(a).n)) for a in e.agents}
    )
    spread = 0.0
    for _, rewards, _, _, infos in trajectory[1:]:
        r = np.array([rewards[a] for a in env.possible_agents])
        station = infos[env.possible_agents[0]]["reward"]
        np.testing.assert_allclose(r.sum(), station, rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(
            r, [infos[a]["reward_share"] for a in env.possible_agents], rtol=1e-6
        )
        spread = max(spread, float(r.max() - r.min()))
    assert spread > 0.1  # agents are rewarded differently


def test_parallel_api_with_episodes_from_noon():
    env = parallel_env(**SMALL, episode_start_hour=12)
    assert env.params.episode_start_hour == 12
    parallel_api_test(env, num_cycles=100)
    parallel_seed_test(lambda: parallel_env(**SMALL, episode_start_hour=12))
