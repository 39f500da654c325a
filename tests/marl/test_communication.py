"""Imperfect communication (``chargax_marl.marl.communication``): the identities at zero delay
and zero loss, the exact delay, the lost actions' replacement, stacking and bad input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl import evaluation
from chargax_marl.core import simulator
from chargax_marl.marl import (
    ActionLossWrapper,
    ChargaxMARL,
    ChargaxParallelEnv,
    DelayedObservationWrapper,
    LogWrapper,
    WorldStateWrapper,
)
from chargax_marl.marl import env as marl_env
from chargax_marl.marl.communication import (
    LOSS_STREAM,
    LOST_ACTIONS,
    communicating_act,
    delayed_columns,
)
from chargax_marl.trace import day_keys
from tests.helpers import exact_jit, mixed_station

STEPS = 30  # 24 one-hour steps a day: the rollouts cross an auto-reset


@pytest.fixture(scope="module")
def env():
    """6 ports (4 DC with V2G, 2 AC), a battery, busy traffic, one-hour steps."""
    return ChargaxMARL(station=mixed_station(), traffic=150.0, step_minutes=60.0)


def _actions(env, seed: int = 1) -> jnp.ndarray:
    """``(STEPS, num_agents)`` random valid action indices."""
    return jax.random.randint(
        jax.random.PRNGKey(seed), (STEPS, env.num_agents), 0, env.num_actions, jnp.int32
    )


def rollout(env, actions, key=jax.random.PRNGKey(3), jit=True):
    """Observation matrices (reset's first), rewards, dones, infos and core states of a scan.
    ``jit=False`` traces it into the caller's compiled program instead of compiling its own."""

    def body(state, xs):
        k, a = xs
        obs, state, reward, done, info = env.step(k, state, dict(zip(env.agents, a)))
        core = state
        while not hasattr(core, "totals"):
            core = core.env_state
        out = (
            jnp.stack([obs[x] for x in env.agents]),
            jnp.stack([reward[x] for x in env.agents]),
            done["__all__"],
            info,
            core,
        )
        return state, out

    def run(key, actions):
        k0, k1 = jax.random.split(key)
        obs0, state = env.reset(k0)
        keys = jax.random.split(k1, actions.shape[0])
        _, out = jax.lax.scan(body, state, (keys, actions))
        return jnp.stack([obs0[x] for x in env.agents]), out

    return (exact_jit(run) if jit else run)(key, actions)  # exact: compared bit for bit


def test_zero_delay_and_zero_loss_are_the_unwrapped_env_bit_for_bit(env):
    actions = _actions(env)
    envs = (
        env,
        DelayedObservationWrapper(env, delay_steps=0),
        ActionLossWrapper(env, loss_prob=0.0),
        ActionLossWrapper(DelayedObservationWrapper(env, 0), 0.0, "idle"),
    )
    # the four rollouts in one compiled program: one compile, not four (most of the test's time)
    base, *outs = exact_jit(lambda a: [rollout(e, a, jit=False) for e in envs])(actions)
    for obs0, (obs, rewards, dones, info, core) in outs:
        assert bool(dones.any())  # the day ended inside the rollout
        info = {k: v for k, v in info.items() if k != "action_lost"}
        assert jax.tree.all(
            jax.tree.map(
                lambda a, b: bool(jnp.array_equal(a, b)),
                (obs0, obs, rewards, dones, info, core),
                (base[0], *base[1]),
            )
        )


@pytest.mark.parametrize("delay_steps", [1, 3])
def test_a_delay_shows_the_context_and_loads_of_k_steps_before(env, delay_steps):
    actions = _actions(env)
    obs0, (obs, _, dones, _, _) = rollout(env, actions)
    w_obs0, (w_obs, _, w_dones, _, _) = rollout(
        DelayedObservationWrapper(env, delay_steps), actions
    )
    obs0, obs, dones = np.asarray(obs0), np.asarray(obs), np.asarray(dones)
    w_obs0, w_obs = np.asarray(w_obs0), np.asarray(w_obs)
    np.testing.assert_array_equal(w_dones, dones)
    np.testing.assert_array_equal(w_obs0, obs0)
    columns = delayed_columns(env)
    assert columns.any() and not columns.all()
    # what the agents saw: index 0 is the reset's observation, t the t-th step's
    seen = np.concatenate([w_obs0[None], w_obs])
    truth = np.concatenate([obs0[None], obs])
    day_start = 0
    for t in range(1, STEPS + 1):
        if dones[t - 1]:  # the step auto-reset: a new day starts at t
            day_start = t
        late = truth[max(t - delay_steps, day_start)]
        np.testing.assert_array_equal(seen[t][:, ~columns], truth[t][:, ~columns], err_msg=str(t))
        np.testing.assert_array_equal(seen[t][:, columns], late[:, columns], err_msg=str(t))
        if t - delay_steps > day_start:  # the shown columns did change between the two steps
            assert not np.array_equal(truth[t][:, columns], late[:, columns]), t


@pytest.mark.parametrize("lost_action", ["previous", "idle"])
def test_a_lost_action_is_replaced_by_the_previous_one_or_idle(env, lost_action):
    actions = _actions(env)
    wrapped = ActionLossWrapper(env, loss_prob=0.5, lost_action=lost_action)
    _, (obs, rewards, dones, info, core) = rollout(wrapped, actions)
    lost = np.asarray(info["action_lost"])
    assert lost.shape == (STEPS, env.num_agents) and 0.3 < lost.mean() < 0.7
    # replay on the unwrapped env with the actions the ports applied
    idle = np.full(env.num_agents, env.action_offset, np.int32)
    previous, applied = idle, []
    for t in range(STEPS):
        fallback = previous if lost_action == "previous" else idle
        now = np.where(lost[t], fallback, np.asarray(actions[t]))
        applied.append(now)
        previous = idle if bool(dones[t]) else now
    _, (b_obs, b_rewards, b_dones, _, b_core) = rollout(env, jnp.asarray(np.stack(applied)))
    assert jax.tree.all(
        jax.tree.map(
            lambda a, b: bool(jnp.array_equal(a, b)),
            (obs, rewards, dones, core),
            (b_obs, b_rewards, b_dones, b_core),
        )
    )


def test_the_wrappers_stack_under_mappo_s_world_state_and_the_log(env):
    stacked = LogWrapper(
        WorldStateWrapper(ActionLossWrapper(DelayedObservationWrapper(env, 2), 0.2))
    )
    obs, state = stacked.reset(jax.random.PRNGKey(0))
    assert obs["world_state"].shape == (env.num_agents, env.state_size)
    actions = {a: jnp.int32(env.num_actions - 1) for a in env.agents}
    obs, state, reward, done, info = stacked.step(jax.random.PRNGKey(1), state, actions)
    assert set(env.agents) <= set(obs) and info["action_lost"].shape == (env.num_agents,)
    assert info["returned_episode_returns"].shape == (env.num_agents,)


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda e: DelayedObservationWrapper(e, -1), "delay_steps"),
        (lambda e: DelayedObservationWrapper(e, 1.5), "delay_steps"),
        (lambda e: ActionLossWrapper(e, 1.5), "loss_prob"),
        (lambda e: ActionLossWrapper(e, "0.1"), "loss_prob"),
        (lambda e: ActionLossWrapper(e, 0.1, "random"), "lost_action"),
    ],
)
def test_bad_settings_are_refused_naming_the_field(env, make, field):
    with pytest.raises(ValueError, match=f"field '{field}'"):
        make(env)


def test_the_pettingzoo_adapter_delays_and_loses_as_the_wrappers_do(env):
    """The PettingZoo options run the same functions: zero delay and loss is the plain adapter,
    a delay shows the plain adapter's columns of k steps before, a lost action is replaced."""
    params = env.params
    plain = ChargaxParallelEnv(params=params)
    delayed = ChargaxParallelEnv(params=params, observation_delay_steps=2)
    lossy = ChargaxParallelEnv(params=params, action_loss_prob=1.0, lost_action="idle")
    idle = ChargaxParallelEnv(params=params)
    columns = delayed_columns(env)
    rng = np.random.default_rng(0)
    seen = {}
    for name, e in (("plain", plain), ("delayed", delayed), ("lossy", lossy), ("idle", idle)):
        obs, _ = e.reset(seed=5)
        seen[name] = [np.stack([obs[a] for a in e.possible_agents])]
    for _ in range(6):
        acts = {a: int(rng.integers(env.num_actions)) for a in env.agents}
        idle_acts = {a: int(env.action_offset) for a in env.agents}
        for name, e in (("plain", plain), ("delayed", delayed), ("lossy", lossy), ("idle", idle)):
            obs, _, _, _, infos = e.step(idle_acts if name == "idle" else acts)
            seen[name].append(np.stack([obs[a] for a in e.possible_agents]))
            assert all(infos[a]["action_lost"] == (name == "lossy") for a in env.agents)
    plain_obs, delayed_obs = np.stack(seen["plain"]), np.stack(seen["delayed"])
    np.testing.assert_array_equal(delayed_obs[..., ~columns], plain_obs[..., ~columns])
    for t in range(len(plain_obs)):
        late = plain_obs[max(t - 2, 0)]
        np.testing.assert_array_equal(delayed_obs[t][:, columns], late[:, columns])
    np.testing.assert_array_equal(np.stack(seen["lossy"]), np.stack(seen["idle"]))
    with pytest.raises(ValueError, match="field 'loss_prob'"):
        ChargaxParallelEnv(params=params, action_loss_prob=-0.1)


# ---- a policy played on held-out days under the same communication (communicating_act) ----


def _play(env, policy, day: int = 3, steps: int = 10, key=jax.random.PRNGKey(7)):
    """Play a MemoryAct step by step on a day from its first state, as ``run_days`` does;
    returns the levels applied and the core states the policy met."""
    params = env.params
    act_keys, step_keys, battery_key = day_keys(key, params.num_steps)
    state = simulator.empty_state(day, params, battery_key)
    memory = policy.init(state)
    levels, states = [], []
    for t in range(steps):
        states.append(state)
        lv, memory = policy.step(state, act_keys[t], memory)
        levels.append(np.asarray(lv))
        state, _ = simulator.step(step_keys[t], state, lv, params)
    return np.stack(levels), states, act_keys[:steps]


def test_communicating_act_shows_the_observations_of_k_steps_before(env):
    k, seen = 3, []

    def choose(obs, state, key):
        seen.append(np.asarray(obs))
        return jnp.full((env.num_agents,), env.action_offset + 1, jnp.int32)  # charge fully

    _, states, _ = _play(env, communicating_act(env, choose, delay_steps=k))
    columns = delayed_columns(env)
    assert columns.any() and not columns.all()
    obs = [np.asarray(env.get_obs_matrix(s)) for s in states]
    for t, got in enumerate(seen):
        old = obs[max(t - k, 0)]  # the day's first observation until k steps have passed
        np.testing.assert_array_equal(got, np.where(columns, old, obs[t]))
    assert any(not np.array_equal(seen[t], obs[t]) for t in range(k, len(seen)))


def test_communicating_act_loses_actions_as_the_wrapper_does(env):
    p, charge = 0.5, env.action_offset + 1

    def choose(obs, state, key):
        return jnp.full((env.num_agents,), charge, jnp.int32)

    for lost_action in LOST_ACTIONS:
        policy = communicating_act(env, choose, loss_prob=p, lost_action=lost_action)
        levels, _, keys = _play(env, policy)
        applied = np.full(env.num_agents, env.action_offset)  # idle at the day's start
        for t, key in enumerate(keys):
            u = np.asarray(jax.random.uniform(jax.random.fold_in(key, LOSS_STREAM), applied.shape))
            lost = u < p
            fallback = applied if lost_action == "previous" else env.action_offset
            applied = np.where(lost, fallback, charge)
            expected = marl_env.actions_to_levels(
                jnp.asarray(applied), env.params, env.action_offset
            )
            np.testing.assert_array_equal(levels[t], np.asarray(expected))
        assert 0 < (levels == 0).sum() < levels.size  # some lost, some not


def test_communicating_act_without_delay_or_loss_is_the_plain_policy_on_whole_days(env):
    def choose(obs, state, key):  # depends on the observation and the key
        score = obs.sum(axis=1) + jax.random.uniform(key, (env.num_agents,))
        return (score * 7).astype(jnp.int32) % env.num_actions

    def plain(state, key):
        idx = choose(env.get_obs_matrix(state), state, key)
        return marl_env.actions_to_levels(idx, env.params, env.action_offset)

    days, key = jnp.arange(3), jax.random.PRNGKey(5)
    a = evaluation.run_days(plain, env.params, days, key)
    b = evaluation.run_days(communicating_act(env, choose), env.params, days, key)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    delayed = evaluation.run_days(communicating_act(env, choose, 2, 0.2), env.params, days, key)
    assert not np.array_equal(np.asarray(a.profit_eur), np.asarray(delayed.profit_eur))
    with pytest.raises(ValueError, match="delay_steps"):
        communicating_act(env, choose, delay_steps=-1)
    with pytest.raises(ValueError, match="attribution"):
        evaluation.stateless(communicating_act(env, choose, 1), "the attribution")
