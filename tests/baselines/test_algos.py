"""The trainers of ``baselines.algos``: PPO / IPPO / MAPPO updates, learning aids, sharding.

Tiny budgets on a tiny station (4 DC ports + battery, 60-minute steps: 24 steps a day).
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from baselines.algos import aids, ippo, mappo, networks, ppo, ppo_core, runner
from baselines.config import build_env_params
from chargax_marl import policies
from chargax_marl.core import observation, simulator
from chargax_marl.evaluation import MemoryAct, run_days
from chargax_marl.marl import ActionLossWrapper, DelayedObservationWrapper
from chargax_marl.teachers import congestion, storage_value
from chargax_marl.teachers import prices as teacher_prices
from chargax_marl.teachers import shaping as teacher_shaping
from chargax_marl.wrappers import PriorityFill, priority_class_levels, priority_fill_levels
from tests.helpers import TINY, TINY_ENV, exact_jit, finite_losses

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def tiny_trained():
    """``trained(mod) -> (train, out)``: ``mod.make_train(TINY)`` and its `finite_losses`
    output (two seeds, one update, on the host), trained once per module for every test that
    needs the plain trainer's run."""
    runs = {}

    def trained(mod):
        if mod not in runs:
            train = mod.make_train(TINY)
            runs[mod] = (train, jax.device_get(finite_losses(train)))
        return runs[mod]

    return trained


def test_mappo_update_runs_with_finite_losses(tiny_trained):
    train, out = tiny_trained(mappo)
    assert train.policy.critic_dim == train.env.state_size  # centralised critic on the world state
    # one episode (a day of 24 steps) finished in every env during the 24-step rollout
    assert np.all(np.asarray(out["metrics"]["episodes"]) == 4)


@pytest.mark.parametrize(
    "minibatches", [2, 8]
)  # 2 < 5 agents: the update gathers from the table; 8: it does not
def test_mappo_shared_critic_matches_per_agent_critic(monkeypatch, minibatches, tiny_trained):
    """The centralised critic run once per (step, env) gives the training of one run per agent row
    (two seeds, one update: every loss of the update and the parameters it leaves)."""
    assert ippo.DEDUP_CENTRAL_CRITIC  # the default: the plain MAPPO run (2 minibatches) has it
    config = {**TINY, "NUM_MINIBATCHES": minibatches}
    if minibatches == TINY["NUM_MINIBATCHES"]:
        new = tiny_trained(mappo)[1]
    else:
        new = jax.device_get(finite_losses(mappo.make_train(config)))
    monkeypatch.setattr(ippo, "DEDUP_CENTRAL_CRITIC", False)
    ref = jax.device_get(finite_losses(mappo.make_train(config)))
    for k in ("actor_loss", "value_loss", "entropy", "approx_kl", "episode_return"):
        np.testing.assert_allclose(
            new["metrics"][k], ref["metrics"][k], rtol=1e-4, atol=1e-6, err_msg=k
        )
    for a, b in zip(
        jax.tree.leaves(new["runner_state"].params), jax.tree.leaves(ref["runner_state"].params)
    ):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)


def test_ppo_policy_is_factored_and_masked():
    train = ppo.make_train(TINY)
    pol = train.policy
    assert pol.num_leaves == 5 and pol.k == 21
    params = pol.init(jax.random.PRNGKey(0))
    logits = pol.logits(params, np.zeros((3, pol.obs_dim), np.float32))
    assert logits.shape == (3, 5, 21)
    # the joint log-prob of a MultiDiscrete action is the sum of the heads' log-probs
    a = np.zeros((3, 5), np.int32)
    lp = networks.log_prob(logits, a).sum(-1)
    np.testing.assert_allclose(lp, 5 * np.log(1 / 21), rtol=1e-3)


def test_ippo_update_finite_and_masks_unavailable_actions():
    env_kwargs = {**TINY_ENV, "station_kwargs": {"num_ports": 4, "battery": True, "v2g": False}}
    train = ippo.make_train({**TINY, "ENV_KWARGS": env_kwargs})
    out = finite_losses(train)
    assert np.all(np.asarray(out["metrics"]["episodes"]) == 4)
    params = jax.tree.map(lambda x: x[0], out["runner_state"].params)
    # ports cannot discharge: masked levels never chosen by the greedy evaluation policy
    _, full, _, days = build_env_params(train.config)
    act = train.make_act(full)(params)
    levels = jax.jit(lambda: act(simulator.empty_state(0, full), None))()  # one program
    assert np.all(np.asarray(levels)[:4] >= 0)
    probs = jax.jit(lambda p, obs, avail: jax.nn.softmax(train.policy.logits(p, obs, avail)))(
        params,
        np.zeros((5, train.policy.obs_dim), np.float32),
        np.asarray(train.env.get_avail_actions(None)["port_0"])[None].repeat(5, 0),
    )
    probs = np.asarray(probs)
    assert probs[:, :10].max() < 1e-6  # discharge indices of a no-V2G port have zero probability


def test_inverse_cdf_sampler_matches_the_softmax_and_never_picks_a_masked_action():
    """The rollouts' sampler: frequencies match softmax(logits) (chi-square), masked indices
    (first, middle, last) are never drawn, even at u = 0 and the largest float32 u < 1, and
    the returned log-probability is the chosen index's."""
    logits = jnp.asarray(
        [
            [0.3, -1.0, 2.0, 0.0, 0.7],
            [networks.NEG_INF, 1.0, networks.NEG_INF, 0.5, networks.NEG_INF],
        ],
        jnp.float32,
    )
    probs = np.asarray(jax.nn.softmax(logits, axis=-1), np.float64)
    n = 40_000
    draw = jax.jit(jax.vmap(lambda k: networks.sample_categorical(k, logits)))
    action, logp = draw(jax.random.split(jax.random.PRNGKey(3), n))
    action, logp = np.asarray(action), np.asarray(logp)
    for h in range(2):
        counts = np.bincount(action[:, h], minlength=5)
        expected = probs[h] * n
        valid = expected > 0
        assert counts[~valid].sum() == 0
        chi2 = float((((counts - expected) ** 2)[valid] / expected[valid]).sum())
        assert chi2 < 20.0, (h, counts, expected)  # 4 or 1 dof; p < 1e-3
    with np.errstate(divide="ignore"):  # the masked actions' log(0), never drawn (above)
        log_probs = np.log(probs)
    np.testing.assert_allclose(logp, log_probs[np.arange(2)[None, :], action], rtol=1e-5, atol=1e-6)
    edges = jnp.asarray([0.0, 1.0 - 2.0**-24, 0.5], jnp.float32)
    a, lp = jax.vmap(lambda u: networks.categorical_from_uniform(jnp.full((2,), u), logits))(edges)
    a = np.asarray(a)
    assert a[0, 0] == 0 and a[1, 0] == 4 and set(a[:, 1]) <= {1, 3}
    assert a[0, 1] == 1 and a[1, 1] == 3 and np.all(np.isfinite(np.asarray(lp)))


def test_multi_agent_shuffle_keeps_each_env_step_whole():
    """IPPO/MAPPO minibatches: the row order is a permutation of the rollout's rows, and every
    block of ``agents`` rows is one env-step (same step, same env) with all its agents in order."""
    steps, agents, envs = 7, 3, 4
    actors = agents * envs
    rows = np.asarray(ppo_core.shuffled_rows(jax.random.PRNGKey(5), steps, actors, agents))
    assert sorted(rows.tolist()) == list(range(steps * actors))
    step, actor = rows // actors, rows % actors
    agent, env = actor // envs, actor % envs
    blocks = lambda x: x.reshape(-1, agents)  # noqa: E731
    assert np.all(blocks(step) == blocks(step)[:, :1]) and np.all(blocks(env) == blocks(env)[:, :1])
    assert np.all(blocks(agent) == np.arange(agents))
    units = blocks(step)[:, 0] * envs + blocks(env)[:, 0]
    assert not np.array_equal(units, np.sort(units))  # shuffled
    single = np.asarray(ppo_core.shuffled_rows(jax.random.PRNGKey(5), steps, actors))
    assert sorted(single.tolist()) == list(range(steps * actors))


def test_gae_matches_reference():
    rng = np.random.default_rng(0)
    r, v, d = (
        rng.normal(size=(6, 2)),
        rng.normal(size=(6, 2)),
        (rng.random((6, 2)) < 0.3).astype(np.float32),
    )
    last = rng.normal(size=2)
    adv, tgt = ppo_core.gae(r, v, d, last, 0.9, 0.8)
    ref = np.zeros((6, 2))
    nxt_a, nxt_v = np.zeros(2), last
    for t in reversed(range(6)):
        delta = r[t] + 0.9 * nxt_v * (1 - d[t]) - v[t]
        nxt_a = delta + 0.9 * 0.8 * (1 - d[t]) * nxt_a
        nxt_v = v[t]
        ref[t] = nxt_a
    np.testing.assert_allclose(adv, ref, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(tgt, ref + v, rtol=1e-5, atol=1e-5)


def test_ppo_update_finite_and_short_training_improves_return():
    """From a near-uniform policy, a few dozen updates learn to charge the tiny station's cars
    (two vmapped seeds, both must improve over their own first iteration). It trains through
    ``jax.jit(jax.vmap(train))``, the form the trainers' docstrings give (the other tests
    vmap ``init`` and ``run_updates`` apart, `tests.helpers.train_seeds`)."""
    config = {
        **TINY,
        "NUM_ENVS": 8,
        "TOTAL_TIMESTEPS": 8 * 24 * 40,
        "LR": 3e-3,
        "ENT_COEF": 0.0,
        "UPDATE_EPOCHS": 4,
        "NUM_MINIBATCHES": 4,
    }
    train = ppo.make_train(config)
    out = finite_losses(train, run=lambda t, keys: jax.jit(jax.vmap(t))(keys))
    ret = np.asarray(out["metrics"]["episode_return"])  # (seeds, updates)
    first, last = ret[:, :2].mean(1), ret[:, -5:].mean(1)
    assert np.all(last > first + 0.1 * np.abs(first)), (first, last)


def test_num_envs_must_divide_devices(monkeypatch):
    class Dev:
        platform = "cpu"

    monkeypatch.setattr(jax, "devices", lambda *a: [Dev(), Dev()])
    with pytest.raises(ValueError, match="divisible by the number of devices"):
        runner.env_mesh(3)


_SHARDED = r"""
import jax, numpy as np
assert jax.device_count() == 2, jax.devices()
from baselines.algos import ippo, ppo
TINY = {"NUM_ENVS": 4, "NUM_STEPS": 24, "NUM_MINIBATCHES": 2, "UPDATE_EPOCHS": 2, "HIDDEN": 32,
        "TOTAL_TIMESTEPS": 4 * 24, "REWARD_SCALE": 0.1,
        "ENV_KWARGS": {"station": "single_type", "station_kwargs": {"num_ports": 4, "battery": True},
                       "step_minutes": 60.0}}
for mod in (ppo, ippo):
    train = mod.make_train(TINY)
    rs = jax.jit(jax.vmap(train.init))(jax.random.split(jax.random.PRNGKey(0), 2))
    leaf = jax.tree.leaves(rs.env_state)[0]
    assert len(leaf.sharding.device_set) == 2, leaf.sharding
    if mod is ppo:  # one full sharded update (IPPO shares the helper; its init is checked above)
        rs, m = jax.jit(jax.vmap(lambda r: train.run_updates(r, 1)))(rs)
        assert np.all(np.isfinite(np.asarray(m["value_loss"])))
        assert len(jax.tree.leaves(rs.env_state)[0].sharding.device_set) == 2
try:
    ppo.make_train({**TINY, "NUM_ENVS": 3})
except ValueError as e:
    assert "divisible" in str(e)
else:
    raise AssertionError("NUM_ENVS=3 on 2 devices must fail")
print("SHARDED_OK")
"""


def test_sharded_training_on_two_host_devices():
    env = {
        **os.environ,
        "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2",
        "JAX_PLATFORMS": "cpu",
        "PYTHONPATH": str(ROOT),
    }
    res = subprocess.run(
        [sys.executable, "-c", _SHARDED],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert "SHARDED_OK" in res.stdout, res.stdout[-2000:] + res.stderr[-4000:]


@pytest.mark.parametrize("mod", [ppo, ippo])
def test_always_max_prior_makes_the_untrained_greedy_policy_always_max(mod):
    """With ``ALWAYS_MAX_PRIOR`` the untrained greedy policy plays the always-max baseline
    (ports at full power, battery idle) along a whole day; without it, it does not."""
    from chargax_marl.core import simulator
    from chargax_marl.policies import always_max

    train = mod.make_train({**TINY, "ALWAYS_MAX_PRIOR": 6.0, "BATTERY_IDLE_PRIOR": 6.0})
    plain = mod.make_train(TINY)
    _, full, _, days = build_env_params(train.config)
    params = train.policy.init(jax.random.PRNGKey(3))
    act, act_plain = train.make_act(full)(params), plain.make_act(full)(params)
    state = simulator.empty_state(int(days[0]), full)

    @jax.jit
    def at(k, s):  # one compiled program per step: both acts, the rule and the step
        levels = act(s, k)
        return (
            levels,
            always_max(s, k, full),
            act_plain(s, k),
            simulator.step(k, s, levels, full)[0],
        )

    differs = False
    for t in range(full.num_steps):  # along a whole day of changing observations
        levels, ref, plain_levels, state = at(jax.random.PRNGKey(t), state)
        np.testing.assert_array_equal(np.asarray(levels), np.asarray(ref))
        differs |= not np.array_equal(np.asarray(plain_levels), np.asarray(ref))
    assert differs
    # sampling explores around it: b = 6 leaves e^0 / (e^6 + 20 e^0), about 5 %, of a head's
    # mass on the other 20 actions (the untrained network's logits are near 0)
    obs = np.zeros((1, train.policy.obs_dim), np.float32)
    if mod is ppo:
        p_max = np.asarray(jax.nn.softmax(train.policy.logits(params, obs)))[0, 0].max()
    else:
        avail = np.ones((1, train.policy.k), bool)
        p_max = np.asarray(jax.nn.softmax(train.policy.logits(params, obs, avail)))[0].max()
    assert p_max == pytest.approx(np.exp(6) / (np.exp(6) + 20), abs=0.01)


def test_always_max_prior_must_be_non_negative():
    for name in ("ALWAYS_MAX_PRIOR", "BATTERY_IDLE_PRIOR"):
        for bad in (-1.0, float("nan")):
            with pytest.raises(ValueError, match=name):
                ppo.make_train({**TINY, name: bad})


def test_ippo_learns_from_the_local_reward_weight_and_ppo_refuses_it():
    train = ippo.make_train({**TINY, "LOCAL_REWARD_WEIGHT": 1.0})
    assert train.env.local_reward_weight == 1.0
    m = jax.device_get(finite_losses(train)["metrics"])
    # agent 0 (a port) is now rewarded with its own share, not the station's profit
    assert np.all(np.isfinite(m["episode_return"])) and np.all(np.isfinite(m["episode_profit_eur"]))
    assert np.abs(m["episode_return"] - m["episode_profit_eur"]).max() > 1.0
    with pytest.raises(ValueError, match="LOCAL_REWARD_WEIGHT"):
        ppo.make_train({**TINY, "LOCAL_REWARD_WEIGHT": 0.5})
    with pytest.raises(ValueError, match=r"LOCAL_REWARD_WEIGHT=2.0 is not allowed.*\[0, 1\]"):
        ippo.make_train({**TINY, "LOCAL_REWARD_WEIGHT": 2.0})


@functools.cache
def _tiny_day_steps(w):
    """A tiny day stepped with random actions, played once per ``w`` for every shaping test:
    the env, each step's ``(pre_state, rewards (agents,), info)`` and the day's final state."""
    from chargax_marl.marl.env import ChargaxMARL

    env = ChargaxMARL(local_reward_weight=w, **TINY_ENV)
    _, state = env.reset_to_day(3)

    @jax.jit
    def step(key, state):  # one program for a step, its random actions included
        key, k_act, k_step = jax.random.split(key, 3)
        idx = jax.random.randint(k_act, (env.num_agents,), 0, env.num_actions)
        idx = jnp.where(
            jnp.asarray(env._avail_np)[jnp.arange(env.num_agents), idx], idx, env.action_offset
        )
        actions = {a: idx[i] for i, a in enumerate(env.agents)}
        _, new_state, rewards, _, info = env.step_env(k_step, state, actions)
        return key, new_state, jnp.stack([rewards[a] for a in env.agents]), info

    key, steps = jax.random.PRNGKey(1), []
    for _ in range(int(env.params.num_steps)):
        key, new_state, rewards, info = step(key, state)
        steps.append((state, np.asarray(rewards), info))
        state = new_state
    return env, steps, state


def _tiny_day(rewards_of, w):
    """Step a tiny day with random actions; ``rewards_of(pre_state, reward, info)`` -> the
    step's (original, shaped) rewards. Returns their sums over the day and the day's profit."""
    env, steps, final = _tiny_day_steps(w)
    raw, shaped, shaped_first = 0.0, 0.0, None
    for state, r, info in steps:
        s = r + np.asarray(rewards_of(env, state, info))
        raw, shaped = raw + r, shaped + s
        shaped_first = s - r if shaped_first is None else shaped_first
    return raw, shaped, shaped_first, float(final.totals.profit_eur)


@pytest.mark.parametrize("w", [0.0, 1.0])
def test_battery_shaping_moves_the_battery_value_but_keeps_the_days_reward(w):
    """BATTERY_SHAPING books the batteries' terminal value step by step: each agent's (and the
    station's) undiscounted day total is unchanged, the first step's reward is not."""
    from chargax_marl.core.station import KIND_BATTERY
    from chargax_marl.marl.env import ChargaxMARL

    env0 = ChargaxMARL(**TINY_ENV)
    is_bat = np.asarray(env0.params.station.leaf_kind) == KIND_BATTERY

    def rewards_of(env, state, info):
        price = teacher_shaping.battery_value_price(state, env.params)
        return teacher_shaping.agent_battery_shaping(price, info, is_bat, w)

    raw, shaped, first, profit = _tiny_day(rewards_of, w)
    np.testing.assert_allclose(shaped, raw, atol=1e-3)  # per agent, w = 0 and w = 1
    assert np.abs(first).max() > 1e-3  # the battery's first step is valued at once
    if w == 0.0:
        np.testing.assert_allclose(
            raw, profit, rtol=1e-5
        )  # the shared reward is the station's profit
    # the single-agent form is the station's term (w = 0)
    info_like = {
        "battery_net_kwh": np.ones(3),
        "battery_terminal_value_eur": np.array([0.0, 0.0, 5.0]),
    }
    np.testing.assert_allclose(
        teacher_shaping.battery_shaping(
            2.0 * info_like["battery_net_kwh"], info_like["battery_terminal_value_eur"]
        ),
        [2.0, 2.0, -3.0],
    )


def test_split_credit_gives_port_and_battery_heads_their_own_log_probability_and_value():
    """``SPLIT_CREDIT``: the joint log-probability splits into the port heads' and the battery
    heads' parts, the critic has one value per part, and training runs; a station without a
    battery is refused by name."""

    train = ppo.make_train({**TINY, "SPLIT_CREDIT": True, "BATTERY_SHAPING": "dp"})
    policy = train.policy
    head_logp = jnp.asarray(
        np.random.default_rng(0).normal(size=(3, policy.num_leaves)), jnp.float32
    )
    parts = np.asarray(policy.credit_logp(head_logp))
    bat = policy.is_battery
    assert bat.sum() == 1 and parts.shape == (3, 2)
    np.testing.assert_allclose(parts[:, 0], np.asarray(head_logp)[:, ~bat].sum(-1), rtol=1e-6)
    np.testing.assert_allclose(parts[:, 1], np.asarray(head_logp)[:, bat].sum(-1), rtol=1e-6)
    value = jax.eval_shape(  # shapes only: nothing to compile
        lambda: policy.value(policy.init(jax.random.PRNGKey(0)), jnp.zeros((5, policy.obs_dim)))
    )
    assert value.shape == (5, 2)
    out = finite_losses(train)
    assert np.all(np.isfinite(out["metrics"]["value_loss"]))
    with pytest.raises(ValueError, match="SPLIT_CREDIT"):
        ppo.make_train(
            {
                **TINY,
                "SPLIT_CREDIT": True,
                "ENV_KWARGS": {**TINY_ENV, "station_kwargs": {"num_ports": 4}},
            }
        )


def test_single_env_reports_the_batteries_share_of_the_reward():
    """``info["battery_reward_eur"]`` is the batteries' leaves' share of the step reward (the
    ports' shares are the rest), and 0 without a battery."""
    from chargax_marl.core import make_params, simulator
    from chargax_marl.core.station import KIND_BATTERY
    from chargax_marl.single.env import Chargax

    for with_battery in (True, False):
        params = make_params(
            station="single_type", station_kwargs={"num_ports": 4, "battery": with_battery}
        )
        env = Chargax(params=params)
        key = jax.random.PRNGKey(3)
        obs, state = env.reset(key, params)
        is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY

        @jax.jit
        def step(key, state, env=env, params=params):
            key, k_a, k_s = jax.random.split(key, 3)
            action = env.action_space(params).sample(k_a)
            _, core_info = simulator.step(k_s, state, env.action_to_levels(action, params), params)
            _, state, _, _, info = env.step_env(k_s, state, action, params)
            return key, state, core_info.leaf_reward, info

        seen = []
        for t in range(30):
            key, state, leaf_reward, info = step(key, state)
            expected = float(np.asarray(leaf_reward)[is_bat].sum())
            np.testing.assert_allclose(
                float(info["battery_reward_eur"]), expected, rtol=1e-5, atol=1e-5
            )
            seen.append(expected)
        assert (np.abs(seen).max() > 1e-4) == with_battery


@pytest.mark.parametrize("mod", [ppo, ippo])
def test_battery_shaping_trains_and_changes_the_return_not_the_profit(mod, tiny_trained):
    outs = {False: tiny_trained(mod)[1]["metrics"]}  # BATTERY_SHAPING is off by default
    train = mod.make_train({**TINY, "BATTERY_SHAPING": True})
    outs[True] = jax.device_get(finite_losses(train)["metrics"])
    # same seeds, same first rollout: the logged profit is the station's in both runs
    np.testing.assert_allclose(
        outs[True]["episode_profit_eur"][:, 0], outs[False]["episode_profit_eur"][:, 0], rtol=1e-5
    )


def test_a_fairness_weight_trains_and_changes_the_return_not_the_profit(tiny_trained):
    plain, plain_out = tiny_trained(ippo)
    config = {**TINY, "FAIRNESS_WEIGHT": 50.0, "FAIRNESS_METRIC": "min_satisfaction"}
    # a weight of 0 leaves the env unwrapped: its run is the plain trainer's
    assert aids.fairness({**config, "FAIRNESS_WEIGHT": 0.0}, plain.env) is plain.env
    outs = {0.0: plain_out["metrics"]}
    outs[50.0] = jax.device_get(finite_losses(ippo.make_train(config))["metrics"])
    # same seeds, same first rollout: the station's profit is the same, the return gains the term
    np.testing.assert_allclose(
        outs[50.0]["episode_profit_eur"][:, 0], outs[0.0]["episode_profit_eur"][:, 0], rtol=1e-5
    )
    assert np.all(outs[50.0]["episode_return"][:, 0] < outs[0.0]["episode_return"][:, 0])
    with pytest.raises(ValueError, match="FAIRNESS_WEIGHT=-1.0"):
        ippo.make_train({**TINY, "FAIRNESS_WEIGHT": -1.0})


def test_ippo_trains_through_delayed_observations_and_lost_actions_and_ppo_refuses_them():
    config = {**TINY, "OBS_DELAY_STEPS": 2, "ACTION_LOSS_PROB": 0.3, "LOST_ACTION": "idle"}
    train = ippo.make_train(config)
    stack = aids.communication(config, train.env)  # what make_train puts under its LogWrapper
    assert isinstance(stack, ActionLossWrapper) and stack.loss_prob == 0.3
    assert isinstance(stack._env, DelayedObservationWrapper) and stack._env.delay_steps == 2
    assert aids.communication(TINY, train.env) is train.env
    out = finite_losses(train)
    # the held-out evaluation plays the policy under the same delay and loss
    seed0 = jax.tree.map(lambda x: x[0], out["runner_state"].params)
    act = train.make_act(train.env_params)(seed0)
    assert isinstance(act, MemoryAct)
    totals = run_days(act, train.env_params, jnp.arange(2), jax.random.PRNGKey(0))
    assert np.isfinite(np.asarray(totals.profit_eur)).all()
    assert not isinstance(ippo.make_train(TINY).make_act(train.env_params)(seed0), MemoryAct)
    with pytest.raises(ValueError, match="ACTION_LOSS_PROB=1.5"):
        ippo.make_train({**TINY, "ACTION_LOSS_PROB": 1.5})
    with pytest.raises(ValueError, match="OBS_DELAY_STEPS=2 applies to the multi-agent"):
        ppo.make_train({**TINY, "OBS_DELAY_STEPS": 2})


def test_ippo_trains_through_the_priority_fill_and_plays_it_when_scored():
    config = {**TINY, "PRIORITY_FILL": True}
    train = ippo.make_train(config)
    stack = aids.priority_fill(config, train.env)  # what make_train puts under its LogWrapper
    assert isinstance(stack, PriorityFill) and aids.priority_fill(TINY, train.env) is train.env
    out = finite_losses(train)
    seed0 = jax.tree.map(lambda x: x[0], out["runner_state"].params)
    plain = ippo.make_train(TINY).make_act(train.env_params)(seed0)
    filled = train.make_act(train.env_params)(seed0)
    state = simulator.reset(jax.random.PRNGKey(3), train.env_params)

    @jax.jit
    def at(key, s):  # one compiled program per step
        want = priority_fill_levels(plain(s, key), s, train.env_params)
        return filled(s, key), want, simulator.step(key, s, want, train.env_params)[0]

    for _ in range(6):  # a few busy steps of the same greedy policy, with and without the fill
        got, want, state = at(jax.random.PRNGKey(0), state)
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    with pytest.raises(ValueError, match="PRIORITY_FILL=true .* OBS_DELAY_STEPS=2"):
        ippo.make_train({**config, "OBS_DELAY_STEPS": 2})
    with pytest.raises(ValueError, match="PRIORITY_FILL=true applies to the multi-agent"):
        ppo.make_train(config)


def test_ippo_trains_in_priority_classes_and_plays_them_at_the_envs_levels_when_scored():
    config = {**TINY, "PRIORITY_FILL": True, "PRIORITY_CLASSES": 2}
    train = ippo.make_train(config)
    # the policy's heads are the classes' (discharge, idle, two classes), not the view's levels
    assert train.policy.k == 4 and train.env.num_actions == 2 * train.env_params.num_levels + 1
    out = finite_losses(train)
    seed0 = jax.tree.map(lambda x: x[0], out["runner_state"].params)
    act = train.make_act(train.env_params)(seed0)
    classes = PriorityFill(train.env, 2)
    state = simulator.reset(jax.random.PRNGKey(3), train.env_params)

    @jax.jit
    def at(key, state):  # one compiled program per step
        obs = train.policy.with_plan(train.env.get_obs_matrix(state), state)
        avail = jnp.asarray(classes._avail_np)
        idx = jnp.argmax(train.policy.logits(seed0, obs, avail), axis=-1)
        want = priority_class_levels(idx, state, train.env_params, 2)
        return act(state, key), want, simulator.step(key, state, want, train.env_params)[0]

    for _ in range(6):  # the scored levels are the classes the greedy policy picks, filled
        got, want, state = at(jax.random.PRNGKey(0), state)
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    with pytest.raises(ValueError, match="PRIORITY_CLASSES=2 needs PRIORITY_FILL=true"):
        ippo.make_train({**TINY, "PRIORITY_CLASSES": 2})


@pytest.mark.parametrize("mod", [ippo, ppo])
def test_the_coupled_teacher_shapes_and_advises_the_trainers(mod):
    """``PORT_SHAPING="coupled"`` shapes with the coupled plan's per-car potential and
    ``PLAN_OBS="coupled"`` appends its two advice columns per leaf, in the rollout and in the
    greedy evaluation act."""
    config = {**TINY, "PORT_SHAPING": "coupled", "PLAN_OBS": "coupled"}
    if mod is ippo:
        config["LOCAL_REWARD_WEIGHT"] = 1.0
    train = mod.make_train(config)
    out = finite_losses(train)
    params = train.env_params
    state = simulator.reset(jax.random.PRNGKey(3), params)
    step = jax.jit(
        lambda s: simulator.step(
            jax.random.PRNGKey(0), s, policies.always_max(s, None, params), params
        )[0]
    )
    for _ in range(12):  # cars arrive over the morning
        state = step(state)
    energy = jnp.full((params.station.num_leaves,), 3.0)
    seed0 = jax.tree.map(lambda x: x[0], out["runner_state"].params)
    # built for the concrete params, played in one program
    coupled_advice, coupled_potential = (
        congestion.coupled_advice(params),
        congestion.coupled_potential(params),
    )
    car_potential, make_act = aids.car_potential(config, params), train.make_act(params)

    @jax.jit
    def read(state, seed0):  # the advice, the observations, potentials and act: one program
        if mod is ippo:
            obs = train.policy.with_plan(train.env.get_obs_matrix(state), state)
        else:
            obs = train.policy.with_plan(observation.flat_obs(state, params), state)
        return (
            coupled_advice(state),
            obs,
            car_potential(state)(energy),
            coupled_potential(state)(energy),
            make_act(seed0)(state, None),
        )

    advice, obs, potential, coupled, levels = jax.device_get(read(state, seed0))
    assert advice.shape == (params.station.num_leaves, 2) and advice[:, 0].max() > 0
    if mod is ippo:
        assert train.policy.obs_dim == train.env.obs_size + 2
        np.testing.assert_allclose(obs[:, -2:], advice, rtol=1e-6)
    else:
        np.testing.assert_allclose(obs[-advice.size :], advice.reshape(-1), rtol=1e-6)
    np.testing.assert_allclose(potential, coupled, rtol=1e-6)
    assert levels.shape == advice[:, 0].shape
    with pytest.raises(ValueError, match="PLAN_OBS must be a bool or one of"):
        aids.plan_obs_mode({"PLAN_OBS": "later"})


@pytest.mark.parametrize("mod", [ippo, mappo])
def test_battery_net_and_agent_advantage_normalisation_train(mod):
    train = mod.make_train(
        {
            **TINY,
            "AGENT_ADV_NORM": True,
            "BATTERY_SHAPING": True,
            "LOCAL_REWARD_WEIGHT": 1.0,
            "BATTERY_NET": True,
            "ENV_KWARGS": {**TINY_ENV, "num_levels": 1},
        }
    )
    out = finite_losses(train)
    params = out["runner_state"].params
    assert "battery_actor" in params
    assert ("battery_critic" in params) == (mod is ippo)  # MAPPO's critic reads the world state
    # the battery's logits come from its own actor: changing it moves the battery row only
    policy, env = train.policy, train.env
    logits = jax.jit(policy.logits, static_argnames="rows")  # compiled, not op by op
    p0 = jax.tree.map(lambda x: x[0], params)
    obs = jax.jit(lambda: env.get_obs_matrix(env.reset_to_day(0)[1]))()
    avail = jnp.asarray(env._avail_np)
    p1 = {**p0, "battery_actor": jax.tree.map(lambda x: x + 1.0, p0["battery_actor"])}
    moved = np.abs(np.asarray(logits(p1, obs, avail)) - np.asarray(logits(p0, obs, avail))).max(
        axis=1
    )
    assert moved[-1] > 0 and np.all(moved[:-1] == 0)
    # The trainers run each actor (and, in IPPO, each critic) on its own rows only: the same
    # logits and values as both nets on every row, in both row layouts (3 env-steps here).
    n = env.num_agents
    x = jnp.concatenate([obs, obs * 1.1, obs * 0.9])  # env-step-major: step * agents + agent
    x_agent_major = x.reshape((3, n, -1)).swapaxes(0, 1).reshape((3 * n, -1))
    av = jnp.tile(avail, (3, 1))
    for rows, rows_x in (("env_step_major", x), ("agent_major", x_agent_major)):
        np.testing.assert_allclose(
            logits(p1, rows_x, av, rows=rows), logits(p1, rows_x, av), rtol=1e-6, atol=1e-6
        )
        if mod is ippo:
            value = jax.jit(policy.value, static_argnames="rows")
            np.testing.assert_allclose(
                value(p1, rows_x, rows=rows), value(p1, rows_x), rtol=1e-6, atol=1e-6
            )
    with pytest.raises(ValueError, match="rows must be"):
        policy.logits(p1, x, av, rows="by_agent")


def test_battery_gamma_discounts_the_battery_rows_only():
    """``BATTERY_GAMMA``: GAE with a per-row discount equals GAE with each row's own scalar."""
    rng = np.random.default_rng(0)
    r, v, d = (jnp.asarray(rng.normal(size=(6, 3)), jnp.float32) for _ in range(3))
    d = (d > 1.0).astype(jnp.float32)
    last = jnp.asarray(rng.normal(size=(3,)), jnp.float32)
    gammas = jnp.asarray([0.9, 0.9, 0.99])
    adv, tgt = ppo_core.gae(r, v, d, last, gammas, 0.95)
    for i, g in enumerate((0.9, 0.9, 0.99)):
        a_i, t_i = ppo_core.gae(
            r[:, i : i + 1], v[:, i : i + 1], d[:, i : i + 1], last[i : i + 1], g, 0.95
        )
        np.testing.assert_allclose(adv[:, i], a_i[:, 0], rtol=1e-6)
        np.testing.assert_allclose(tgt[:, i], t_i[:, 0], rtol=1e-6)
    assert not np.allclose(adv[:, 2], ppo_core.gae(r, v, d, last, 0.9, 0.95)[0][:, 2])
    out = finite_losses(ippo.make_train({**TINY, "BATTERY_GAMMA": 0.99}))
    assert out["metrics"]["actor_loss"].shape == (2, 1)
    with pytest.raises(ValueError, match="BATTERY_GAMMA"):
        ippo.make_train({**TINY, "BATTERY_GAMMA": 1.5})


def test_battery_ent_coef_weighs_the_battery_rows_entropy_only():
    """``BATTERY_ENT_COEF``: the loss's entropy bonus is each row's coefficient times its
    entropy, averaged; without it every row has ``ENT_COEF``."""
    rng = np.random.default_rng(1)
    logp, old, adv, val, oldv, tgt, ent = (
        jnp.asarray(rng.normal(size=6), jnp.float32) for _ in range(7)
    )
    config = {"CLIP_EPS": 0.2, "VF_CLIP": 10.0, "VF_COEF": 0.5, "ENT_COEF": 0.01}
    coef = jnp.asarray([0.01] * 5 + [0.2])
    base, _ = ppo_core.ppo_loss(logp, old, adv, val, oldv, tgt, ent, config)
    rows, parts = ppo_core.ppo_loss(logp, old, adv, val, oldv, tgt, ent, config, coef)
    np.testing.assert_allclose(rows - base, -(0.2 - 0.01) * float(ent[5]) / 6, rtol=1e-5)
    np.testing.assert_allclose(parts["entropy"], float(ent.mean()), rtol=1e-6)
    finite_losses(ippo.make_train({**TINY, "BATTERY_ENT_COEF": 0.05}))
    for bad in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="BATTERY_ENT_COEF"):
            ippo.make_train({**TINY, "BATTERY_ENT_COEF": bad})


def test_relative_prices_read_the_observed_prices_and_quantiles():
    """``RELATIVE_PRICES``: the columns are the context's prices and day quantiles, and each
    feature is ``(p - median) / (q80 - q20)``."""
    from chargax_marl.core import observation
    from chargax_marl.marl import ChargaxMARL

    for agent_id in ("onehot", "scalar"):
        env = ChargaxMARL(agent_id=agent_id, **TINY_ENV)
        state = env.reset_to_day(3)[1]
        obs = np.asarray(env.get_obs_matrix(state))
        ctx = np.asarray(
            observation.context_features(teacher_shaping.core_state(state), env.params)
        )
        ctx0 = (
            env.obs_size - np.shape(env._layout.agent_id)[1] - observation.context_size(env.params)
        )
        price_cols, q20, q50, q80 = teacher_prices.relative_price_columns(env.params, ctx0)
        i = observation.context_index(env.params, "price_quantiles")
        np.testing.assert_array_equal(obs[0, price_cols], ctx[: env.params.price_horizon_hours + 1])
        np.testing.assert_array_equal(obs[0, [q20, q50, q80]], ctx[i + 1 : i + 4])
        rel = np.asarray(
            teacher_prices.relative_prices(jnp.asarray(obs), price_cols, q20, q50, q80)
        )
        np.testing.assert_allclose(
            rel[1],
            np.clip((obs[1, price_cols] - obs[1, q50]) / (obs[1, q80] - obs[1, q20]), -5, 5),
            rtol=1e-5,
        )
    assert observation.context_size(env.params) == ctx.shape[0]
    train = ippo.make_train({**TINY, "RELATIVE_PRICES": True})
    assert train.policy.obs_dim == train.env.obs_size + len(price_cols)
    finite_losses(train)
    assert (
        mappo.make_train({**TINY, "RELATIVE_PRICES": True}).policy.critic_dim
        == train.env.state_size
    )
    # single-agent PPO: the same features from the flat observation, which ends with the context
    ppo_train = ppo.make_train({**TINY, "RELATIVE_PRICES": True})
    flat = np.asarray(observation.flat_obs(teacher_shaping.core_state(state), ppo_train.env_params))
    cols = teacher_prices.relative_price_columns(ppo_train.env_params, flat.shape[0] - ctx.shape[0])
    np.testing.assert_array_equal(flat[cols[0]], ctx[: env.params.price_horizon_hours + 1])
    np.testing.assert_allclose(
        np.asarray(teacher_prices.relative_prices(jnp.asarray(flat), *cols)), rel[0], rtol=1e-5
    )
    assert ppo_train.policy.input_dim == ppo_train.policy.obs_dim + len(price_cols)
    finite_losses(ppo_train)


@pytest.mark.parametrize("w", [0.0, 1.0])
def test_storage_value_shaping_changes_the_day_by_a_constant_of_its_first_state(w):
    """``BATTERY_SHAPING="storage_value"``: a potential, so each agent's day total moves by
    ``(terminal price - value[day, 0]) * E_0`` (the battery's, shared as the shares are), which
    no action changes."""
    from chargax_marl.core.station import KIND_BATTERY
    from chargax_marl.marl.env import ChargaxMARL

    env0 = ChargaxMARL(**TINY_ENV)
    is_bat = np.asarray(env0.params.station.leaf_kind) == KIND_BATTERY
    potential = aids.battery_potential({"BATTERY_SHAPING": "storage_value"}, env0.params)
    table = storage_value.storage_values(env0.params)
    start = {}

    def rewards_of(env, state, info):
        if not start:
            e0 = float(np.sum(np.asarray(state.soc * state.capacity_kwh)[is_bat]))
            start.update(
                v0=float(table[int(state.day), int(state.timestep)]), e0=e0, day=int(state.day)
            )
        return teacher_shaping.agent_potential_shaping(potential(state), info, is_bat, w)

    raw, shaped, first, _ = _tiny_day(rewards_of, w)
    from chargax_marl.core.reward import day_mean_buy_price

    const = (float(day_mean_buy_price(start["day"], env0.params)) - start["v0"]) * start["e0"]
    expected = raw + np.where(is_bat, w * const, 0.0) + (1.0 - w) * const
    np.testing.assert_allclose(shaped, expected, atol=2e-3)
    assert abs(const) > 1e-3  # the case is not trivial


@pytest.mark.parametrize("mode", ["storage_value", "dp"])
def test_potential_shapings_train_with_finite_losses(mode):
    out = finite_losses(ippo.make_train({**TINY, "BATTERY_SHAPING": mode}))
    assert np.all(np.isfinite(out["metrics"]["episode_return"]))
    finite_losses(ppo.make_train({**TINY, "BATTERY_SHAPING": mode}))
    with pytest.raises(ValueError, match="BATTERY_SHAPING"):
        aids.shaping_mode({"BATTERY_SHAPING": "hourly"})


@pytest.mark.parametrize("w", [0.0, 1.0])
def test_dp_shaping_changes_the_day_by_a_constant_of_its_first_state(w):
    """``BATTERY_SHAPING="dp"``: a potential of the stored energy level, so each agent's day
    total moves by ``terminal price * E_0 - value[day, 0](E_0)``, which no action changes."""
    from chargax_marl.core.station import KIND_BATTERY
    from chargax_marl.marl.env import ChargaxMARL

    env0 = ChargaxMARL(**TINY_ENV)
    is_bat = np.asarray(env0.params.station.leaf_kind) == KIND_BATTERY
    potential = aids.battery_potential({"BATTERY_SHAPING": "dp"}, env0.params)
    grid, table = storage_value.dp_values(env0.params)
    start = {}

    def rewards_of(env, state, info):
        if not start:
            e0 = float(np.sum(np.asarray(state.soc * state.capacity_kwh)[is_bat]))
            start.update(
                phi0=float(np.interp(e0, grid, table[int(state.day), int(state.timestep)])),
                e0=e0,
                day=int(state.day),
            )
        return teacher_shaping.agent_potential_shaping(potential(state), info, is_bat, w)

    raw, shaped, first, _ = _tiny_day(rewards_of, w)
    const = (
        float(storage_value.terminal_prices(env0.params)[start["day"]]) * start["e0"]
        - start["phi0"]
    )
    expected = raw + np.where(is_bat, w * const, 0.0) + (1.0 - w) * const
    np.testing.assert_allclose(shaped, expected, atol=2e-3)
    assert abs(const) > 1e-3  # the case is not trivial


def test_a_chunk_reports_every_update_to_the_host_and_trains_as_the_trainer_does():
    """The progress bar moves once per update (a host callback inside the compiled chunk, with
    the update's training return and profit per seed), and the chunk trains exactly as
    ``vmap(run_updates(., n))``: the same parameters and metrics, bit for bit."""
    train = ppo.make_train({**TINY, "TOTAL_TIMESTEPS": 3 * 4 * 24})
    rs = jax.jit(jax.vmap(train.init))(jax.random.split(jax.random.PRNGKey(0), 2))
    calls = []
    chunk = functools.partial(
        runner._chunk, train, 3, lambda r, p: calls.append((np.asarray(r), np.asarray(p)))
    )
    rs_c, m_c = exact_jit(chunk)(rs)
    rs_t, m_t = exact_jit(jax.vmap(lambda r: train.run_updates(r, 3)))(rs)
    assert len(calls) == 3 and all(r.shape == p.shape == (2,) for r, p in calls)
    for k in m_t:
        assert m_c[k].shape == (2, 3)
        np.testing.assert_array_equal(np.asarray(m_c[k]), np.asarray(m_t[k]))
    np.testing.assert_array_equal(
        np.stack([r for r, _ in calls], 1), np.asarray(m_t["episode_return"])
    )
    for a, b in zip(jax.tree.leaves(rs_c.params), jax.tree.leaves(rs_t.params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("mod", [ippo, ppo])
@pytest.mark.parametrize("mode", [True, "coupled"])
def test_the_greedy_act_reads_the_plan_of_the_prices_it_is_played_on(mod, mode, monkeypatch):
    """A policy trained with ``PLAN_OBS`` and played on other prices (a shift task's held-out
    year) reads the plan advice of the prices it is played on, not the training env's."""
    from chargax_marl.core import make_params

    config = {**TINY, "PLAN_OBS": mode}
    train = mod.make_train(config)
    other = make_params(**{**TINY_ENV, "prices": "NL-2024"})
    assert not np.array_equal(
        np.asarray(other.prices_eur_kwh), np.asarray(train.env_params.prices_eur_kwh)
    )
    advice, trained_advice = (aids.plan_features(config, p)[0] for p in (other, train.env_params))

    def a_state(differ: bool):
        """A busy state of a day of ``other``; with ``differ``, one at which the two price
        years' plans differ."""

        @jax.jit
        def step(key, state):  # one compiled program per step
            levels = policies.always_max(state, None, other)
            state, _ = simulator.step(key, state, levels, other)
            return state, advice(state), trained_advice(state)

        for seed in range(10):
            state = simulator.reset(jax.random.PRNGKey(seed), other)
            for _ in range(other.num_steps):
                state, x, y = step(jax.random.PRNGKey(seed), state)
                x, y = np.asarray(x), np.asarray(y)
                if not differ and state.occupied.any() or differ and not np.allclose(x, y):
                    return state
        raise AssertionError("the two price years' plans agree on every day tried")

    # the coupled plan's advice (its congestion prices) moves with the prices at some step
    state = a_state(differ=mode == "coupled")
    built_for, seen = [], []
    plan_features, with_plan = aids.plan_features, train.policy.with_plan

    def features_spy(cfg, env_params):
        built_for.append(env_params)
        return plan_features(cfg, env_params)

    def with_plan_spy(obs, core, plan=None):
        seen.append(plan)
        return with_plan(obs, core, plan)

    monkeypatch.setattr(aids, "plan_features", features_spy)
    monkeypatch.setattr(train.policy, "with_plan", with_plan_spy)
    params = train.policy.init(jax.random.PRNGKey(1))
    train.make_act(other)(params)(state, jax.random.PRNGKey(2))
    assert any(p is other for p in built_for), "the act's plan was not built from its params"
    assert seen and seen[-1] is not None, "the act read the training env's plan"
    np.testing.assert_allclose(np.asarray(seen[-1](state)), np.asarray(advice(state)), rtol=1e-6)


@pytest.mark.parametrize("mod", [ippo, mappo])
def test_residual_starts_at_the_coupled_plan_and_explores_its_neighbouring_levels(mod):
    """With ``RESIDUAL="coupled_plan"`` every agent reads the coupled plan's level as its last
    column, the untrained greedy policy plays the coupled plan along a whole day (without the
    residual it does not), the sampled policy puts most mass on the plan's action and less on
    levels further from it, and it trains with finite losses."""
    from chargax_marl.teachers.rules import coupled_plan_rule

    config = {**TINY, "RESIDUAL": "coupled_plan", "RESIDUAL_PRIOR": 2.0}
    train = mod.make_train(config)
    plain = mod.make_train(TINY)
    assert train.policy.obs_dim == plain.policy.obs_dim + 1
    finite_losses(train)
    full = train.env_params
    rule = coupled_plan_rule(full)
    params = train.policy.init(jax.random.PRNGKey(3))
    act = train.make_act(full)(params)
    act_plain = plain.make_act(full)(plain.policy.init(jax.random.PRNGKey(3)))
    state = simulator.reset(jax.random.PRNGKey(5), full)

    @jax.jit
    def at(k, s):  # one compiled program per step: both acts, the rule and the step
        levels = act(s, k)
        return levels, rule(s, k, full), act_plain(s, k), simulator.step(k, s, levels, full)[0]

    differs, moved = False, False
    for t in range(full.num_steps):
        levels, ref, plain_levels, state = jax.device_get(at(jax.random.PRNGKey(t), state))
        np.testing.assert_array_equal(levels, ref)
        differs |= not np.array_equal(plain_levels, ref)
        moved |= bool(np.any(ref != 0))
    assert differs and moved
    # the offsets: -2 per level of distance from the plan's action (index idle + level)
    rows, ref = jax.device_get(
        jax.jit(
            lambda s: (train.policy.with_plan(train.env.get_obs_matrix(s), s), rule(s, None, full))
        )(state)
    )
    np.testing.assert_allclose(rows[:, -1], ref / full.num_levels, rtol=1e-6)
    obs = np.zeros((1, train.policy.obs_dim), np.float32)
    avail = np.ones((1, train.policy.k), bool)
    p = np.asarray(jax.nn.softmax(train.policy.logits(params, obs, avail)))[0]
    idle = train.env.action_offset
    assert p.argmax() == idle and p[idle] > p[idle + 1] > p[idle + 2] > 0
    assert p[idle + 1] / p[idle] == pytest.approx(np.exp(-2.0), rel=0.05)
    # the batteries' own strength: a battery row (its kind flag set) centres more loosely
    battery = train.policy.battery_col
    obs[0, battery] = 1.0
    loose = mod.make_train({**config, "RESIDUAL_BATTERY_PRIOR": 0.5})
    params_b = loose.policy.init(jax.random.PRNGKey(3))
    q = np.asarray(jax.nn.softmax(loose.policy.logits(params_b, obs, avail)))[0]
    assert q[idle + 1] / q[idle] == pytest.approx(np.exp(-0.5), rel=0.05)


def test_residual_settings_are_refused_by_name():
    for name in ("RESIDUAL_PRIOR", "RESIDUAL_BATTERY_PRIOR"):
        for bad in (0.0, -1.0, float("nan")):
            with pytest.raises(ValueError, match=name):
                ippo.make_train({**TINY, "RESIDUAL": "coupled_plan", name: bad})
    with pytest.raises(ValueError, match="RESIDUAL must be one of"):
        aids.residual_mode({"RESIDUAL": "plan"})
    with pytest.raises(ValueError, match="RESIDUAL='coupled_plan' applies to the multi-agent"):
        ppo.make_train({**TINY, "RESIDUAL": "coupled_plan"})
    with pytest.raises(ValueError, match="PRIORITY_FILL"):
        ippo.make_train({**TINY, "RESIDUAL": "coupled_plan", "PRIORITY_FILL": True})
