"""Training code in ``baselines/``: PPO / IPPO / MAPPO updates, learning, sharding, the CLI.

Tiny budgets on a tiny station (4 DC ports + battery, 60-minute steps: 24 steps a day).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from baselines import runs
from baselines import train as cli
from baselines.algos import aids, ippo, mappo, ppo
from baselines.config import ConfigError, build_env_params, resolve
from baselines.algos import networks
from baselines.algos import ppo_core
from baselines.algos import runner
from baselines.eval import heldout
from baselines.eval import stats
from chargax_marl.teachers import car_plan, prices, storage_value
from chargax_marl.teachers import shaping as teacher_shaping

ROOT = Path(__file__).resolve().parents[1]

TINY_ENV = {"station": "single_type", "station_kwargs": {"num_ports": 4, "battery": True}, "step_minutes": 60.0}
TINY = {"NUM_ENVS": 4, "NUM_STEPS": 24, "NUM_MINIBATCHES": 2, "UPDATE_EPOCHS": 2, "HIDDEN": 32,
        "TOTAL_TIMESTEPS": 4 * 24, "ENV_KWARGS": TINY_ENV, "REWARD_SCALE": 0.1}


def _toml(value) -> str:
    """``value`` as a TOML inline value (for a ``KEY=value`` override)."""
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    if isinstance(value, bool):
        return "true" if value else "false"
    return json.dumps(value)


TINY_CLI = ["--config", "cpu", "SEEDS=2", "NUM_ENVS=4", "NUM_STEPS=24", "HIDDEN=16", f"ENV_KWARGS={_toml(TINY_ENV)}"]
"""The command line of a tiny run (add ``ALGO=``, ``TOTAL_TIMESTEPS=``, ``CHUNKS=``, ``OUT=``)."""


def _finite_losses(train, seeds=2):
    out = jax.jit(jax.vmap(train))(jax.random.split(jax.random.PRNGKey(0), seeds))
    m = jax.device_get(out["metrics"])
    for k in ("actor_loss", "value_loss", "entropy", "approx_kl"):
        assert m[k].shape == (seeds, train.num_updates)
        assert np.all(np.isfinite(m[k])), (k, m[k])
    return out


def test_mappo_update_runs_with_finite_losses():
    train = mappo.make_train(TINY)
    assert train.policy.critic_dim == train.env.state_size  # centralised critic on the world state
    out = _finite_losses(train)
    # one episode (a day of 24 steps) finished in every env during the 24-step rollout
    assert np.all(np.asarray(out["metrics"]["episodes"]) == 4)


@pytest.mark.parametrize("minibatches", [2, 8])  # 2 < 5 agents: the update gathers from the table; 8: it does not
def test_mappo_shared_critic_matches_per_agent_critic(monkeypatch, minibatches):
    """The centralised critic run once per (step, env) gives the training of one run per agent row."""
    config = {**TINY, "NUM_MINIBATCHES": minibatches, "TOTAL_TIMESTEPS": 2 * 4 * 24}
    outs = []
    for dedup in (False, True):
        monkeypatch.setattr(ippo, "DEDUP_CENTRAL_CRITIC", dedup)
        outs.append(jax.device_get(jax.jit(mappo.make_train(config))(jax.random.PRNGKey(3))))
    ref, new = outs
    for k in ("actor_loss", "value_loss", "entropy", "approx_kl", "episode_return"):
        np.testing.assert_allclose(new["metrics"][k], ref["metrics"][k], rtol=1e-4, atol=1e-6, err_msg=k)
    for a, b in zip(jax.tree.leaves(new["runner_state"].params), jax.tree.leaves(ref["runner_state"].params)):
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
    out = _finite_losses(train)
    assert np.all(np.asarray(out["metrics"]["episodes"]) == 4)
    params = jax.tree.map(lambda x: x[0], out["runner_state"].params)
    # ports cannot discharge: masked levels never chosen by the greedy evaluation policy
    _, full, _, days = build_env_params(train.config)
    act = train.make_act(full)(params)
    from chargax_marl.core import simulator

    levels = act(simulator.empty_state(0, full), None)
    assert np.all(np.asarray(levels)[:4] >= 0)
    logits = train.policy.logits(params, np.zeros((5, train.policy.obs_dim), np.float32),
                                 np.asarray(train.env.get_avail_actions(None)["port_0"])[None].repeat(5, 0))
    probs = np.asarray(jax.nn.softmax(logits))
    assert probs[:, :10].max() < 1e-6  # discharge indices of a no-V2G port have zero probability


def test_inverse_cdf_sampler_matches_the_softmax_and_never_picks_a_masked_action():
    """The rollouts' sampler: frequencies match softmax(logits) (chi-square), masked indices
    (first, middle, last) are never drawn, even at u = 0 and the largest float32 u < 1, and
    the returned log-probability is the chosen index's."""
    logits = jnp.asarray([[0.3, -1.0, 2.0, 0.0, 0.7],
                          [networks.NEG_INF, 1.0, networks.NEG_INF, 0.5, networks.NEG_INF]], jnp.float32)
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
    np.testing.assert_allclose(logp, np.log(probs)[np.arange(2)[None, :], action], rtol=1e-5, atol=1e-6)
    edges = jnp.asarray([0.0, 1.0 - 2.0 ** -24, 0.5], jnp.float32)
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
    r, v, d = rng.normal(size=(6, 2)), rng.normal(size=(6, 2)), (rng.random((6, 2)) < 0.3).astype(np.float32)
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
    (two vmapped seeds, both must improve over their own first iteration)."""
    config = {**TINY, "NUM_ENVS": 8, "TOTAL_TIMESTEPS": 8 * 24 * 40, "LR": 3e-3, "ENT_COEF": 0.0,
              "UPDATE_EPOCHS": 4, "NUM_MINIBATCHES": 4}
    train = ppo.make_train(config)
    out = _finite_losses(train)
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
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu",
           "PYTHONPATH": str(ROOT)}
    res = subprocess.run([sys.executable, "-c", _SHARDED], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=300)
    assert "SHARDED_OK" in res.stdout, res.stdout[-2000:] + res.stderr[-4000:]


def test_cli_smoke_writes_png_json_checkpoint(tmp_path):
    out = tmp_path / "run"
    cli.main([*TINY_CLI, "ALGO=ppo", f"TOTAL_TIMESTEPS={4 * 24 * 2}", "CHUNKS=2", "SEED=1", f"OUT={_toml(str(out))}"])
    for name in ("curve.png", "results.json", "params.msgpack"):
        assert (out / name).stat().st_size > 0, name
    res = json.loads((out / "results.json").read_text())
    table = res["evaluation"]["table"]
    # the LP hindsight bound is a baseline by default (--optimal bound), and every policy,
    # the agent included, carries its fraction of the headroom between always-max and it
    # on a station with a battery, the battery shaping's teacher played as a rule is a baseline too
    assert set(table) == {"always_max", "battery_rule", "price_threshold", "battery_programme", "plan_programme",
                          "lp_bound", "ppo"}
    bound, am = np.asarray(table["lp_bound"]["daily_profit"]), np.asarray(table["always_max"]["daily_profit"])
    assert np.all(bound >= am - 1e-3)
    assert table["lp_bound"]["headroom"]["fraction"] == pytest.approx(1.0)
    assert np.isfinite(res["headroom"]["fraction"]) and res["headroom"]["headroom_eur"] > 0
    assert table["ppo"]["num_days"] == 100 and res["timesteps"] == 4 * 24 * 2
    assert len(res["eval_curve"]) == 2 and len(res["curve"]["timesteps"]) == 2
    # paired comparison with always-max on the same days and cars, per evaluation point
    vs = res["vs_always_max"]
    assert len(vs["per_seed_mean"]) == 2 and np.isfinite(vs["mean"]) and vs["stderr"] >= 0
    assert all(e["vs_always_max"] is not None for e in res["eval_curve"])
    # and with always-max + the battery price rule
    rule = res["vs_battery_rule"]
    assert len(rule["per_seed_mean"]) == 2 and np.isfinite(rule["mean"])
    assert all(e["vs_battery_rule"] is not None for e in res["eval_curve"])
    # per seed: both paired differences, the headroom fraction and when it first beats each rule
    assert res["scenario"]["name"] == "shopping" and res["scenario"]["held_out_days"] == 100
    assert len(res["per_seed"]) == 2
    for i, p in enumerate(res["per_seed"]):
        assert p["vs_always_max"]["mean"] == pytest.approx(vs["per_seed_mean"][i])
        assert p["vs_battery_rule"]["mean"] == pytest.approx(rule["per_seed_mean"][i])
        assert np.isfinite(p["headroom_fraction"])
        for k in ("first_beats_always_max", "first_beats_battery_rule"):
            assert p[k] is None or (p[k]["timesteps"] > 0 and p[k]["wall_minutes"] > 0)
    assert res["over_seeds"]["vs_always_max"]["mean"] == pytest.approx(vs["mean"])
    assert list(res["over_seeds"]) == ["vs_always_max", "vs_battery_rule", "vs_battery_programme", "vs_plan_programme",
                                       "headroom_fraction"]
    for name in ("battery_programme", "plan_programme"):
        gap = np.mean(table[name]["daily_profit"]) - np.mean(table["always_max"]["daily_profit"])
        assert table[name]["vs_always_max"]["mean"] == pytest.approx(gap, abs=1e-3)
        for i, p in enumerate(res["per_seed"]):
            assert p[f"vs_{name}"]["mean"] == pytest.approx(res[f"vs_{name}"]["per_seed_mean"][i])
            # a seed's differences agree with the references' own profits
            assert p["vs_always_max"]["mean"] - p[f"vs_{name}"]["mean"] == pytest.approx(gap, abs=1e-3)
    _check_add_teacher_rules_reproduces(out / "results.json", res)
    # the checkpoint restores into the parameter pytree (leading axis = seed)
    train = ppo.make_train({**TINY, "HIDDEN": 16})
    template = jax.vmap(train.policy.init)(jax.random.split(jax.random.PRNGKey(0), 2))
    restored = runs.load_params(template, out / "params.msgpack")
    assert jax.tree.structure(restored) == jax.tree.structure(template)


def _check_add_teacher_rules_reproduces(path, res):
    """``baselines.experiments.add_teacher_rules`` on the run's file with the teachers' rules
    taken out (as a run made before they were baselines) puts back what the run recorded; a
    file whose always-max differs from a replay on this code is refused and left as it was."""
    from baselines.experiments import add_teacher_rules

    rules = ("battery_programme", "plan_programme")
    old = json.loads(path.read_text())
    for name in rules:
        del old["evaluation"]["table"][name], old[f"vs_{name}"], old[f"first_beats_{name}"]
        del old["over_seeds"][f"vs_{name}"]
        for p in old["per_seed"]:
            del p[f"vs_{name}"], p[f"first_beats_{name}"]
    path.write_text(json.dumps(old))
    add_teacher_rules.main([str(path)])
    new = json.loads(path.read_text())
    assert list(new["evaluation"]["table"])[-1] == "ppo"
    assert list(new["over_seeds"]) == list(res["over_seeds"])
    for name in rules:
        fresh = res["evaluation"]["table"][name]
        np.testing.assert_allclose(new["evaluation"]["table"][name]["daily_profit"], fresh["daily_profit"], rtol=1e-6)
        assert new["evaluation"]["table"][name]["headroom"]["fraction"] == pytest.approx(
            fresh["headroom"]["fraction"], rel=1e-5)
        for a, b in zip(new["per_seed"], res["per_seed"]):
            assert a[f"vs_{name}"] == pytest.approx(b[f"vs_{name}"], rel=1e-5)
            assert list(a).index(f"vs_{name}") < list(a).index("headroom_fraction")
        assert new["over_seeds"][f"vs_{name}"]["mean"] == pytest.approx(res["over_seeds"][f"vs_{name}"]["mean"], rel=1e-5)
        assert new[f"vs_{name}"]["mean"] == pytest.approx(res[f"vs_{name}"]["mean"], rel=1e-5)
    # another model's always-max: refused, nothing written
    bad = json.loads(path.read_text())
    bad["evaluation"]["table"]["always_max"]["daily_profit"][3] += 1.0
    path.write_text(json.dumps(bad))
    with pytest.raises(ValueError, match="always_max replayed on this code differs .* by up to 1.000"):
        add_teacher_rules.main([str(path)])
    assert json.loads(path.read_text()) == bad


def test_battery_programme_rule_is_always_max_ports_and_the_programme_s_battery():
    """The ``battery_programme`` baseline: every occupied port at full power, the battery at the
    programme's full-power action; ``plan_programme``: the ports on the plan's advice, the
    same battery. Refused, naming the policy, on a station without a battery, where the
    baselines leave them out."""
    from baselines.eval.rules import PLAN_PROGRAMME, PROGRAMME, evaluate_rules, rule_policy
    from baselines.eval.heldout import baseline_results
    from chargax_marl.core import make_params, simulator
    from chargax_marl.core.station import KIND_BATTERY
    from chargax_marl.policies import always_max

    params = make_params(**TINY_ENV)
    act, dp = rule_policy(PROGRAMME, params), storage_value.dp_battery_action(params)
    plan, advice = rule_policy(PLAN_PROGRAMME, params), car_plan.plan_advice(params)
    is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
    state = simulator.reset(jax.random.PRNGKey(1), params)
    state = state.replace(occupied=jnp.ones_like(state.occupied))  # a car at every port (an empty one's level acts on nothing)
    seen = set()
    for t in range(int(params.num_steps)):
        s = state.replace(timestep=jnp.int32(t))
        levels, ref = np.asarray(act(s, None, params)), np.asarray(always_max(s, None, params))
        np.testing.assert_array_equal(levels[~is_bat], ref[~is_bat])
        assert np.all(levels[is_bat] == int(dp(s)[0]) * int(params.num_levels))
        planned = np.asarray(plan(s, None, params))
        np.testing.assert_array_equal(planned[~is_bat], (np.asarray(advice(s))[~is_bat] > 0.5) * int(params.num_levels))
        np.testing.assert_array_equal(planned[is_bat], levels[is_bat])
        seen.add(int(dp(s)[0]))
    assert len(seen) > 1  # the battery trades on this day
    bare = make_params(**{**TINY_ENV, "station_kwargs": {"num_ports": 4, "battery": False}})
    for name in (PROGRAMME, PLAN_PROGRAMME):
        with pytest.raises(ValueError, match=name):
            evaluate_rules(bare, np.arange(2), (name,))
    assert not {PROGRAMME, PLAN_PROGRAMME} & set(baseline_results(bare, np.arange(2)))


def test_grid_programme_holds_the_battery_s_charge_while_the_ports_alone_overload_the_connection():
    """``grid_programme``: always-max ports and the programme's battery, except a charge while
    the ports' full-power draw exceeds the grid connection (a 25 % connection with every port
    taken); with the full connection it is ``battery_programme`` at every step."""
    from baselines.eval.rules import GRID_PROGRAMME, PROGRAMME, evaluate_rules, rule_policy
    from chargax_marl.core import make_params, simulator
    from chargax_marl.core.station import KIND_BATTERY

    seen = {}
    for fraction in (0.25, None):
        params = make_params(**TINY_ENV, grid_fraction=fraction)
        act, prog, dp = rule_policy(GRID_PROGRAMME, params), rule_policy(PROGRAMME, params), \
            storage_value.dp_battery_action(params)
        is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
        state = simulator.reset(jax.random.PRNGKey(1), params)
        car = lambda field, value: jnp.where(jnp.asarray(is_bat), getattr(state, field), value)  # noqa: E731
        # a 100 kWh car taking 150 kW at every port: 600 kW of ports against a 175 kW connection at 25 %
        state = state.replace(occupied=jnp.ones_like(state.occupied), soc=car("soc", 0.1),
                              target_soc=car("target_soc", 1.0), capacity_kwh=car("capacity_kwh", 100.0),
                              max_rate_kw=car("max_rate_kw", 150.0), tau=car("tau", 0.8))
        for t in range(int(params.num_steps)):
            s = state.replace(timestep=jnp.int32(t))
            levels, ref = np.asarray(act(s, None, params)), np.asarray(prog(s, None, params))
            np.testing.assert_array_equal(levels[~is_bat], ref[~is_bat])  # always-max ports
            want = int(dp(s)[0])
            want = 0 if (fraction is not None and want > 0) else want  # every step overloads the 25 % connection
            assert np.all(levels[is_bat] == want * int(params.num_levels)), (fraction, t)
            seen.setdefault(fraction, set()).add(int(dp(s)[0]))
    assert 1 in seen[0.25]  # the programme charges at some step, where the rule holds the battery
    bare = make_params(**{**TINY_ENV, "station_kwargs": {"num_ports": 4, "battery": False}})
    with pytest.raises(ValueError, match=GRID_PROGRAMME):
        evaluate_rules(bare, np.arange(2), (GRID_PROGRAMME,))


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
    act, act_plain = jax.jit(train.make_act(full)(params)), jax.jit(plain.make_act(full)(params))
    state = simulator.empty_state(int(days[0]), full)
    step = jax.jit(lambda k, s, a: simulator.step(k, s, a, full)[0])
    differs = False
    for t in range(full.num_steps):  # along a whole day of changing observations
        k = jax.random.PRNGKey(t)
        levels, ref = np.asarray(act(state, k)), np.asarray(always_max(state, k, full))
        np.testing.assert_array_equal(levels, ref)
        differs |= not np.array_equal(np.asarray(act_plain(state, k)), ref)
        state = step(k, state, levels)
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


def test_held_out_evaluation_uses_common_random_numbers():
    """Every seed, and the rule-based baselines, meet the same drawn cars: a 'network' that
    ignores its parameters and plays always-max scores exactly always-max's daily profits,
    for every seed, and a paired difference of zero."""
    from chargax_marl.evaluation import evaluate_policy
    from chargax_marl.policies import always_max
    from baselines.eval.heldout import baseline_results

    _, full, _, days = build_env_params(resolve(TINY))
    days = days[:8]
    base = baseline_results(full, days)

    def make_act(p):
        return lambda s, k: always_max(s, k, full) + 0 * p.astype(np.int32)

    ev = heldout.evaluate_batched(make_act, np.zeros((3,), np.float32), full, days,
                                 reference_profit=base["always_max"]["daily_profit"])
    ref = evaluate_policy("always_max", full, days)["metrics"]["daily_profit_eur"]["mean"]
    np.testing.assert_allclose(ev["per_seed_profit"], [ref] * 3, rtol=1e-6)
    np.testing.assert_allclose(ev["daily_profit"], np.broadcast_to(base["always_max"]["daily_profit"], (3, 8)),
                               rtol=1e-6)
    assert ev["paired_diff"]["mean"] == pytest.approx(0.0, abs=1e-3)
    d = stats.paired_difference(np.array([[2.0, 4.0]]), np.array([1.0, 1.0]))
    assert d["mean"] == 2.0 and d["per_seed_mean"] == [2.0] and d["stderr"] == pytest.approx(1.0)


def test_ippo_learns_from_the_local_reward_weight_and_ppo_refuses_it():
    train = ippo.make_train({**TINY, "LOCAL_REWARD_WEIGHT": 1.0})
    assert train.env.local_reward_weight == 1.0
    m = jax.device_get(_finite_losses(train)["metrics"])
    # agent 0 (a port) is now rewarded with its own share, not the station's profit
    assert np.all(np.isfinite(m["episode_return"])) and np.all(np.isfinite(m["episode_profit_eur"]))
    assert np.abs(m["episode_return"] - m["episode_profit_eur"]).max() > 1.0
    with pytest.raises(ValueError, match="LOCAL_REWARD_WEIGHT"):
        ppo.make_train({**TINY, "LOCAL_REWARD_WEIGHT": 0.5})
    with pytest.raises(ValueError, match="local_reward_weight"):
        ippo.make_train({**TINY, "LOCAL_REWARD_WEIGHT": 2.0})


def test_train_speed_counts_network_work_and_rounds_to_whole_updates():
    from benchmarks import train_speed

    assert train_speed._steps_for(16, 100_000, 300) == 21 * 4800
    assert train_speed.mlp_macs([4, 8, 2]) == 4 * 8 + 8 * 2
    ppo_m, ippo_m, mappo_m = (train_speed.network_macs(a) for a in ("ppo", "ippo", "mappo"))
    assert ippo_m["rows"] == mappo_m["rows"] == 17 and ppo_m["rows"] == 1
    # 17 agents through 2 x 256 MLPs: about 9 x PPO's work per env-step; MAPPO's shared critic less
    assert 8 < ippo_m["total_macs"] / ppo_m["total_macs"] < 10
    assert ppo_m["total_macs"] < mappo_m["total_macs"] < ippo_m["total_macs"]


def _tiny_day(rewards_of, w):
    """Step a tiny day with random actions; ``rewards_of(pre_state, reward, info)`` -> the
    step's (original, shaped) rewards. Returns their sums over the day and the day's profit."""
    from chargax_marl.marl.env import ChargaxMARL

    env = ChargaxMARL(local_reward_weight=w, **TINY_ENV)
    _, state = env.reset_to_day(3)
    key = jax.random.PRNGKey(1)
    raw, shaped, shaped_first = 0.0, 0.0, None
    for _ in range(int(env.params.num_steps)):
        key, k_act, k_step = jax.random.split(key, 3)
        idx = jax.random.randint(k_act, (env.num_agents,), 0, env.num_actions)
        idx = jnp.where(jnp.asarray(env._avail_np)[jnp.arange(env.num_agents), idx], idx, env.action_offset)
        actions = {a: idx[i] for i, a in enumerate(env.agents)}
        _, new_state, rewards, _, info = env.step_env(k_step, state, actions)
        r = np.stack([np.asarray(rewards[a]) for a in env.agents])
        s = r + np.asarray(rewards_of(env, state, info))
        raw, shaped = raw + r, shaped + s
        shaped_first = s - r if shaped_first is None else shaped_first
        state = new_state
    return raw, shaped, shaped_first, float(state.totals.profit_eur)


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
        np.testing.assert_allclose(raw, profit, rtol=1e-5)  # the shared reward is the station's profit
    # the single-agent form is the station's term (w = 0)
    info_like = {"battery_net_kwh": np.ones(3), "battery_terminal_value_eur": np.array([0.0, 0.0, 5.0])}
    np.testing.assert_allclose(teacher_shaping.battery_shaping(2.0 * info_like["battery_net_kwh"],
                                                      info_like["battery_terminal_value_eur"]), [2.0, 2.0, -3.0])


def test_split_credit_gives_port_and_battery_heads_their_own_log_probability_and_value():
    """``SPLIT_CREDIT``: the joint log-probability splits into the port heads' and the battery
    heads' parts, the critic has one value per part, and training runs; a station without a
    battery is refused by name."""
    from chargax_marl.core import make_params

    train = ppo.make_train({**TINY, "SPLIT_CREDIT": True, "BATTERY_SHAPING": "dp"})
    policy = train.policy
    head_logp = jnp.asarray(np.random.default_rng(0).normal(size=(3, policy.num_leaves)), jnp.float32)
    parts = np.asarray(policy.credit_logp(head_logp))
    bat = policy.is_battery
    assert bat.sum() == 1 and parts.shape == (3, 2)
    np.testing.assert_allclose(parts[:, 0], np.asarray(head_logp)[:, ~bat].sum(-1), rtol=1e-6)
    np.testing.assert_allclose(parts[:, 1], np.asarray(head_logp)[:, bat].sum(-1), rtol=1e-6)
    params = policy.init(jax.random.PRNGKey(0))
    assert policy.value(params, jnp.zeros((5, policy.obs_dim))).shape == (5, 2)
    out = _finite_losses(train)
    assert np.all(np.isfinite(out["metrics"]["value_loss"]))
    with pytest.raises(ValueError, match="SPLIT_CREDIT"):
        ppo.make_train({**TINY, "SPLIT_CREDIT": True, "ENV_KWARGS": {**TINY_ENV, "station_kwargs": {"num_ports": 4}}})


def test_single_env_reports_the_batteries_share_of_the_reward():
    """``info["battery_reward_eur"]`` is the batteries' leaves' share of the step reward (the
    ports' shares are the rest), and 0 without a battery."""
    from chargax_marl.core import make_params, simulator
    from chargax_marl.core.station import KIND_BATTERY
    from chargax_marl.single.env import Chargax

    for with_battery in (True, False):
        params = make_params(station="single_type", station_kwargs={"num_ports": 4, "battery": with_battery})
        env = Chargax(params=params)
        key = jax.random.PRNGKey(3)
        obs, state = env.reset(key, params)
        is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
        seen = []
        for t in range(30):
            key, k_a, k_s = jax.random.split(key, 3)
            action = env.action_space(params).sample(k_a)
            _, core_info = simulator.step(k_s, state, env.action_to_levels(action, params), params)
            obs, state, reward, _, info = env.step_env(k_s, state, action, params)
            expected = float(np.asarray(core_info.leaf_reward)[is_bat].sum())
            np.testing.assert_allclose(float(info["battery_reward_eur"]), expected, rtol=1e-5, atol=1e-5)
            seen.append(expected)
        assert (np.abs(seen).max() > 1e-4) == with_battery


@pytest.mark.parametrize("mod", [ppo, ippo])
def test_battery_shaping_trains_and_changes_the_return_not_the_profit(mod):
    outs = {}
    for on in (False, True):
        train = mod.make_train({**TINY, "BATTERY_SHAPING": on})
        outs[on] = jax.device_get(_finite_losses(train)["metrics"])
    # same seeds, same first rollout: the logged profit is the station's in both runs
    np.testing.assert_allclose(outs[True]["episode_profit_eur"][:, 0], outs[False]["episode_profit_eur"][:, 0],
                               rtol=1e-5)


@pytest.mark.parametrize("mod", [ippo, mappo])
def test_battery_net_and_agent_advantage_normalisation_train(mod):
    train = mod.make_train({**TINY, "AGENT_ADV_NORM": True, "BATTERY_SHAPING": True, "LOCAL_REWARD_WEIGHT": 1.0,
                            "BATTERY_NET": True, "ENV_KWARGS": {**TINY_ENV, "num_levels": 1}})
    out = _finite_losses(train)
    params = out["runner_state"].params
    assert "battery_actor" in params
    assert ("battery_critic" in params) == (mod is ippo)  # MAPPO's critic reads the world state
    # the battery's logits come from its own actor: changing it moves the battery row only
    policy, env = train.policy, train.env
    p0 = jax.tree.map(lambda x: x[0], params)
    obs = env.get_obs_matrix(env.reset_to_day(0)[1])
    avail = jnp.asarray(env._avail_np)
    p1 = {**p0, "battery_actor": jax.tree.map(lambda x: x + 1.0, p0["battery_actor"])}
    moved = np.abs(np.asarray(policy.logits(p1, obs, avail) - policy.logits(p0, obs, avail))).max(axis=1)
    assert moved[-1] > 0 and np.all(moved[:-1] == 0)


def test_battery_gamma_discounts_the_battery_rows_only():
    """``BATTERY_GAMMA``: GAE with a per-row discount equals GAE with each row's own scalar."""
    rng = np.random.default_rng(0)
    r, v, d = (jnp.asarray(rng.normal(size=(6, 3)), jnp.float32) for _ in range(3))
    d = (d > 1.0).astype(jnp.float32)
    last = jnp.asarray(rng.normal(size=(3,)), jnp.float32)
    gammas = jnp.asarray([0.9, 0.9, 0.99])
    adv, tgt = ppo_core.gae(r, v, d, last, gammas, 0.95)
    for i, g in enumerate((0.9, 0.9, 0.99)):
        a_i, t_i = ppo_core.gae(r[:, i:i + 1], v[:, i:i + 1], d[:, i:i + 1], last[i:i + 1], g, 0.95)
        np.testing.assert_allclose(adv[:, i], a_i[:, 0], rtol=1e-6)
        np.testing.assert_allclose(tgt[:, i], t_i[:, 0], rtol=1e-6)
    assert not np.allclose(adv[:, 2], ppo_core.gae(r, v, d, last, 0.9, 0.95)[0][:, 2])
    out = _finite_losses(ippo.make_train({**TINY, "BATTERY_GAMMA": 0.99}))
    assert out["metrics"]["actor_loss"].shape == (2, 1)
    with pytest.raises(ValueError, match="BATTERY_GAMMA"):
        ippo.make_train({**TINY, "BATTERY_GAMMA": 1.5})


def test_battery_ent_coef_weighs_the_battery_rows_entropy_only():
    """``BATTERY_ENT_COEF``: the loss's entropy bonus is each row's coefficient times its
    entropy, averaged; without it every row has ``ENT_COEF``."""
    rng = np.random.default_rng(1)
    logp, old, adv, val, oldv, tgt, ent = (jnp.asarray(rng.normal(size=6), jnp.float32) for _ in range(7))
    config = {"CLIP_EPS": 0.2, "VF_CLIP": 10.0, "VF_COEF": 0.5, "ENT_COEF": 0.01}
    coef = jnp.asarray([0.01] * 5 + [0.2])
    base, _ = ppo_core.ppo_loss(logp, old, adv, val, oldv, tgt, ent, config)
    rows, parts = ppo_core.ppo_loss(logp, old, adv, val, oldv, tgt, ent, config, coef)
    np.testing.assert_allclose(rows - base, -(0.2 - 0.01) * float(ent[5]) / 6, rtol=1e-5)
    np.testing.assert_allclose(parts["entropy"], float(ent.mean()), rtol=1e-6)
    _finite_losses(ippo.make_train({**TINY, "BATTERY_ENT_COEF": 0.05}))
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
        ctx = np.asarray(observation.context_features(teacher_shaping.core_state(state), env.params))
        ctx0 = env.obs_size - np.shape(env._layout.agent_id)[1] - observation.context_size(env.params)
        prices, q20, q50, q80 = prices.relative_price_columns(env.params, ctx0)
        i = observation.context_index(env.params, "price_quantiles")
        np.testing.assert_array_equal(obs[0, prices], ctx[:env.params.price_horizon_hours + 1])
        np.testing.assert_array_equal(obs[0, [q20, q50, q80]], ctx[i + 1:i + 4])
        rel = np.asarray(prices.relative_prices(jnp.asarray(obs), prices, q20, q50, q80))
        np.testing.assert_allclose(rel[1], np.clip((obs[1, prices] - obs[1, q50]) / (obs[1, q80] - obs[1, q20]), -5, 5),
                                   rtol=1e-5)
    assert observation.context_size(env.params) == ctx.shape[0]
    train = ippo.make_train({**TINY, "RELATIVE_PRICES": True})
    assert train.policy.obs_dim == train.env.obs_size + len(prices)
    _finite_losses(train)
    assert mappo.make_train({**TINY, "RELATIVE_PRICES": True}).policy.critic_dim == train.env.state_size
    # single-agent PPO: the same features from the flat observation, which ends with the context
    ppo_train = ppo.make_train({**TINY, "RELATIVE_PRICES": True})
    flat = np.asarray(observation.flat_obs(teacher_shaping.core_state(state), ppo_train.env_params))
    cols = prices.relative_price_columns(ppo_train.env_params, flat.shape[0] - ctx.shape[0])
    np.testing.assert_array_equal(flat[cols[0]], ctx[:env.params.price_horizon_hours + 1])
    np.testing.assert_allclose(np.asarray(prices.relative_prices(jnp.asarray(flat), *cols)), rel[0], rtol=1e-5)
    assert ppo_train.policy.input_dim == ppo_train.policy.obs_dim + len(prices)
    _finite_losses(ppo_train)


def test_attribution_scores_the_run_and_swaps_ports_and_battery(tmp_path, monkeypatch):
    """``baselines.analysis.attribution``: the ``learned`` row reproduces the run's own held-out score,
    and the mixes take the battery's levels from one policy and the ports' from the other."""
    from baselines.analysis import attribution, read_policy
    from chargax_marl import policies
    from chargax_marl.core import make_params

    out = tmp_path / "run"
    cli.main([*TINY_CLI, "ALGO=ippo", f"TOTAL_TIMESTEPS={4 * 24}", "CHUNKS=1", "OPTIMAL=off", f"OUT={_toml(str(out))}"])
    res = json.loads((out / "results.json").read_text())
    att = attribution.attribute(out)
    learned = [s["mean"] for s in att["mixes"]["learned"]["per_seed"]]
    np.testing.assert_allclose(learned, [p["vs_always_max"]["mean"] for p in res["per_seed"]], rtol=1e-6, atol=1e-6)
    assert set(att["mixes"]) == set(attribution.MIXES) and "learned" in attribution.format_attribution(att)
    from chargax_marl.core import simulator

    params = make_params(**TINY_ENV)
    key = jax.random.PRNGKey(0)
    start = simulator.reset(key, params)
    # an hour (60-minute steps) in which the battery rule charges or discharges, so the mixes differ
    state = next(s for s in (start.replace(timestep=jnp.int32(h)) for h in range(24))
                 if int(policies.battery_rule(s, key, params)[-1]) != 0)
    mixes = attribution.mixed_policies(lambda s, k: policies.always_max(s, k, params), params)
    np.testing.assert_array_equal(mixes["learned_ports_rule_battery"](state, key), policies.battery_rule(state, key, params))
    np.testing.assert_array_equal(mixes["always_max_ports_learned_battery"](state, key),
                                  policies.always_max(state, key, params))
    rule_act = lambda s, k: policies.battery_rule(s, k, params)  # noqa: E731
    ports_from_rule = attribution.mixed_policies(rule_act, params)["always_max_ports_learned_battery"](state, key)
    np.testing.assert_array_equal(ports_from_rule, policies.battery_rule(state, key, params))
    # baselines.read_policy reads the same run: shares of the battery's actions, 24 hours

    reading = read_policy.read(out, num_days=3)
    assert reading["num_days"] == 3 and len(reading["per_seed"]) == 2
    for seed in reading["per_seed"]:
        assert abs(sum(seed["battery_share"].values()) - 1.0) < 1e-6 and len(seed["hourly_action"]) == 24
        assert all(-1.0 <= a <= 1.0 for a in seed["hourly_action"]) and 0.0 <= seed["ports_full_power_share"] <= 1.0
        assert 0.0 <= seed["ports_follow_plan_share"] <= 1.0
    assert "hourly SoC" in read_policy.format_reading(reading)
    # baselines.analysis.redraw scores the same run on more cars: draw 0 is the run's own evaluation,
    # draw 1 the rules' evaluation under PRNGKey(1), averaged per day
    from baselines.analysis import redraw
    from baselines.eval.rules import evaluate_rules

    two = redraw.redraw(out, draws=2, bound=False)
    assert two["draws"] == 2 and two["seeds"] == 2 and two["replay_check_max_abs_eur"] < 1e-3
    for i, p in enumerate(res["per_seed"]):
        assert two["vs"]["always_max"]["draw0_per_seed"][i]["mean"] == pytest.approx(p["vs_always_max"]["mean"], abs=1e-4)
        assert two["vs"]["always_max"]["draw0_per_seed"][i]["stderr"] == pytest.approx(p["vs_always_max"]["stderr"],
                                                                                      rel=1e-4)
    _, eval_params, _, days = build_env_params(json.loads((out / "results.json").read_text())["config"])
    by_key = [evaluate_rules(eval_params, days, ("always_max", "battery_rule"), key=jax.random.PRNGKey(k)) for k in (0, 1)]
    rule_gain = np.mean([r["battery_rule"]["daily_profit"] - r["always_max"]["daily_profit"] for r in by_key])
    assert two["references_vs_always_max"]["battery_rule"]["mean"] == pytest.approx(rule_gain, abs=1e-4)
    assert not np.allclose(by_key[0]["always_max"]["daily_profit"], by_key[1]["always_max"]["daily_profit"])
    assert "2 car draws" in redraw.format_redraw(two)
    # the MPC's draws (a stand-in that earns always-max + 1 EUR/day here, so the wiring shows):
    # paired on the first mpc_draws draws only, with the bound's headroom on the same draws
    import baselines.analysis.references

    def fake_mpc(params, days, key):
        return {"daily_profit": evaluate_rules(params, days, ("always_max",), key=key)["always_max"]["daily_profit"] + 1.0}

    monkeypatch.setattr(baselines.analysis.references, "evaluate_mpc", fake_mpc)
    with_mpc = redraw.redraw(out, draws=2, bound=True, mpc_draws=1)
    vs_am, vs_mpc = with_mpc["vs"]["always_max"]["draw0_per_seed"], with_mpc["vs"]["mpc"]["per_seed"]
    for i in range(2):
        assert vs_mpc[i]["mean"] == pytest.approx(vs_am[i]["mean"] - 1.0, abs=1e-4)
    assert with_mpc["references_vs_always_max"]["mpc"]["mean"] == pytest.approx(1.0, abs=1e-4)
    frac = with_mpc["headroom_fraction"]
    assert frac["references"]["lp_bound"] == pytest.approx(1.0) and frac["references"]["always_max"] == 0.0
    assert frac["mpc_on_its_draws"]["mpc"] == pytest.approx(1.0 / with_mpc["headroom_eur_per_draw"][0], rel=1e-5)
    assert with_mpc["headroom_eur"] == pytest.approx(np.mean(with_mpc["headroom_eur_per_draw"]))
    with pytest.raises(ValueError, match="mpc_draws must be an integer in"):
        redraw.redraw(out, draws=1, mpc_draws=2)
    # a run whose stored score this code does not reproduce is refused, as are zero draws
    res["per_seed"][0]["mean_profit_eur"] += 1.0
    (out / "results.json").write_text(json.dumps(res))
    with pytest.raises(ValueError, match="another model"):
        redraw.redraw(out, draws=1)
    with pytest.raises(ValueError, match="draws must be a positive integer"):
        redraw.redraw(out, draws=0)


def test_redraw_clusters_the_draws_of_a_day_before_the_standard_error():
    """Two days, two draws each: the per-day means 2 and 4 give mean 3 and s.e. 1 (not the
    s.e. of four independent numbers), and 3 > 2 x 1 beats."""
    from baselines.eval.stats import day_clustered

    d = day_clustered(np.array([[1.0, 3.0], [3.0, 5.0]]))  # (draws, days)
    assert d == {"mean": 3.0, "stderr": pytest.approx(1.0), "beats": True}
    assert day_clustered(np.array([[1.0, -3.0], [3.0, 1.0]]))["beats"] is False  # per day 2, -1: 0.5 < 2 x 1.5


def test_dp_battery_action_earns_the_programme_s_value_in_its_own_model():
    """Played through the battery-only model from 50 % (a grid point), the programme's greedy
    action earns exactly ``value[day, 0](E_0)``: the action read from the state and the table
    agree."""
    from chargax_marl.core import make_params, simulator
    from chargax_marl.core.station import KIND_BATTERY

    params = make_params()
    grid, table = storage_value.dp_values(params)
    prices = storage_value.step_buy_prices(params)
    eta, power_kw, capacity_kwh, e0 = storage_value.battery_constants(params)
    step_kwh = power_kw * float(params.step_hours)
    act = jax.jit(storage_value.dp_battery_action(params))
    is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
    for day in (5, 147):
        state = simulator.empty_state(jnp.int32(day), params, jax.random.PRNGKey(0))
        energy, earned, moves = e0, 0.0, set()
        for t in range(int(params.num_steps)):
            soc = jnp.where(jnp.asarray(is_bat), energy / capacity_kwh, state.soc)
            a, _ = act(state.replace(timestep=jnp.int32(t), soc=soc))
            a = int(a)
            moves.add(a)
            after = min(max(energy + a * step_kwh, 0.0), capacity_kwh)
            p = prices[day, t]
            earned += eta * p * (energy - after) if after < energy else -p * (after - energy) / eta
            energy = after
        earned += storage_value.terminal_prices(params)[day] * energy
        np.testing.assert_allclose(earned, np.interp(e0, grid, table[day, 0]), rtol=1e-4, atol=1e-3)
        assert moves == {-1, 0, 1}  # it trades on these days


def test_storage_value_hand_case_and_bounds():
    """The battery-only LP's value of a stored kWh: where no energy bound binds, every step's
    value is the terminal price (energy moves freely through the day); with losses a kWh
    bought at ``p`` costs ``p / eta``, so the values stay within the day's prices scaled by eta."""

    v = storage_value.day_values([0.1, 0.3, 0.2], 0.15, eta=1.0, power_kw=1.0, capacity_kwh=10.0, e0=5.0,
                                 step_hours=1.0)
    np.testing.assert_allclose(v, [0.15, 0.15, 0.15, 0.15], atol=1e-9)
    # a small battery that starts empty: the first step's kWh is worth the dearest sale it
    # can still reach (0.3 at step 1); after that sale only step 2's 0.2 remains
    v = storage_value.day_values([0.1, 0.3, 0.2], 0.0, eta=1.0, power_kw=1.0, capacity_kwh=1.0, e0=0.0,
                                 step_hours=1.0)
    assert v[2] == pytest.approx(0.2) and v[3] == 0.0
    from chargax_marl.core import make_params

    params = make_params(**TINY_ENV)
    table = storage_value.storage_values(params)
    prices = storage_value.step_buy_prices(params)
    eta = float(np.asarray(params.station.leaf_path_efficiency)[-1])
    assert table.shape == (prices.shape[0], prices.shape[1] + 1)
    from chargax_marl.core.reward import day_mean_buy_price

    np.testing.assert_allclose(table[:, -1], [float(day_mean_buy_price(d, params)) for d in range(prices.shape[0])],
                               rtol=1e-5)
    lo = np.minimum(prices.min(axis=1, keepdims=True) / eta, table[:, -1:])
    hi = np.maximum(prices.max(axis=1, keepdims=True) * eta, table[:, -1:])
    assert np.all(table >= lo - 1e-5) and np.all(table <= hi + 1e-5)
    with pytest.raises(ValueError, match="battery"):
        storage_value.storage_values(make_params(station="single_type", station_kwargs={"num_ports": 2}))


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
            start.update(v0=float(table[int(state.day), int(state.timestep)]), e0=e0, day=int(state.day))
        return teacher_shaping.agent_potential_shaping(potential(state), info, is_bat, w)

    raw, shaped, first, _ = _tiny_day(rewards_of, w)
    from chargax_marl.core.reward import day_mean_buy_price

    const = (float(day_mean_buy_price(start["day"], env0.params)) - start["v0"]) * start["e0"]
    expected = raw + np.where(is_bat, w * const, 0.0) + (1.0 - w) * const
    np.testing.assert_allclose(shaped, expected, atol=2e-3)
    assert abs(const) > 1e-3  # the case is not trivial
    out = _finite_losses(ippo.make_train({**TINY, "BATTERY_SHAPING": "storage_value"}))
    assert np.all(np.isfinite(out["metrics"]["episode_return"]))
    _finite_losses(ppo.make_train({**TINY, "BATTERY_SHAPING": "storage_value"}))
    with pytest.raises(ValueError, match="BATTERY_SHAPING"):
        aids.shaping_mode({"BATTERY_SHAPING": "hourly"})


def test_dp_values_are_the_hand_computed_best_of_the_three_full_power_actions():
    """Prices 0.1, 0.3, 0.2, a 1 kWh battery that moves 1 kWh per step, terminal price 0.15:
    empty at the start it buys at 0.1 and sells at 0.3 (0.2); full it sells at 0.3 (0.3). With
    a path efficiency of 0.5 buying at 0.1 costs 0.2 per stored kWh and selling at 0.3 earns
    0.15, so the empty battery idles and the full one earns 0.15 (selling at 0.3 or holding)."""
    grid, v = storage_value.level_values([[0.1, 0.3, 0.2]], [0.15], eta=1.0, step_kwh=1.0, capacity_kwh=1.0,
                                         points_per_step=1)
    np.testing.assert_allclose(grid, [0.0, 1.0])
    np.testing.assert_allclose(v[0], [[0.2, 0.3], [0.0, 0.3], [0.0, 0.2], [0.0, 0.15]], atol=1e-12)
    _, v = storage_value.level_values([[0.1, 0.3, 0.2]], [0.15], eta=0.5, step_kwh=1.0, capacity_kwh=1.0,
                                      points_per_step=1)
    # full: sell at 0.3 for 0.15, at 0.2 for 0.1, or hold to the end for 0.15
    np.testing.assert_allclose(v[0, :, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(v[0, :, 1], [0.15, 0.15, 0.15, 0.15], atol=1e-12)
    # a finer grid interpolates half a kWh: buy 0.5 kWh at 0.1 is not possible (a full step is 1
    # kWh, cut at full), so from 0.5 kWh the best is to top up at 0.1 and sell 1 kWh at 0.3
    grid, v = storage_value.level_values([[0.1, 0.3, 0.2]], [0.15], eta=1.0, step_kwh=1.0, capacity_kwh=1.0,
                                         points_per_step=2)
    np.testing.assert_allclose(grid, [0.0, 0.5, 1.0])
    np.testing.assert_allclose(v[0, 0, 1], -0.05 + 0.3, atol=1e-12)
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="points_per_step"):
            storage_value.level_values([[0.1]], [0.1], 1.0, 1.0, 1.0, points_per_step=bad)
    with pytest.raises(ValueError, match="eta"):
        storage_value.level_values([[0.1]], [0.1], 1.5, 1.0, 1.0)


def test_dp_values_never_lose_to_idling_and_end_at_the_terminal_booking():
    from chargax_marl.core import make_params

    params = make_params()
    grid, v = storage_value.dp_values(params)
    terminal = storage_value.terminal_prices(params)
    np.testing.assert_allclose(v[:, -1], terminal[:, None] * grid[None, :], rtol=1e-5, atol=1e-4)
    # holding is always allowed, so a level is worth at least what it is worth one step later
    assert np.all(v[:, :-1] >= v[:, 1:] - 1e-3)
    # on days without negative prices more energy is never worth less (it can be sold or held);
    # on days with them it can be (an emptier battery is paid to charge)
    positive = np.all(storage_value.step_buy_prices(params) > 0, axis=1)
    assert 0 < positive.sum() < positive.size
    assert np.all(np.diff(v[positive], axis=-1) >= -1e-3)
    assert np.any(np.diff(v[~positive], axis=-1) < -1e-3)


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
            start.update(phi0=float(np.interp(e0, grid, table[int(state.day), int(state.timestep)])), e0=e0,
                         day=int(state.day))
        return teacher_shaping.agent_potential_shaping(potential(state), info, is_bat, w)

    raw, shaped, first, _ = _tiny_day(rewards_of, w)
    const = float(storage_value.terminal_prices(env0.params)[start["day"]]) * start["e0"] - start["phi0"]
    expected = raw + np.where(is_bat, w * const, 0.0) + (1.0 - w) * const
    np.testing.assert_allclose(shaped, expected, atol=2e-3)
    assert abs(const) > 1e-3  # the case is not trivial
    out = _finite_losses(ippo.make_train({**TINY, "BATTERY_SHAPING": "dp"}))
    assert np.all(np.isfinite(out["metrics"]["episode_return"]))
    _finite_losses(ppo.make_train({**TINY, "BATTERY_SHAPING": "dp"}))


def test_cli_overrides_reach_the_config_and_unknown_keys_raise(monkeypatch):
    """``KEY=value`` arguments override the config file's keys; a misspelt key raises, naming
    it and the allowed keys, before anything trains."""
    from baselines import pipeline

    seen = {}
    monkeypatch.setattr(pipeline, "run", lambda algo, config, **kw: seen.update(config, ALGO=algo, **kw)
                        or pipeline.RunOutput({}, None, None))
    cli.main(["RELATIVE_PRICES=true", "BATTERY_NET=false", "BATTERY_GAMMA=0.95", "BATTERY_SHAPING=dp",
              "PORT_SHAPING=plan", "TOTAL_TIMESTEPS=100"])
    assert seen["RELATIVE_PRICES"] is True and seen["BATTERY_NET"] is False and seen["ALGO"] == "ippo"
    assert seen["BATTERY_GAMMA"] == 0.95 and seen["BATTERY_SHAPING"] == "dp" and seen["PORT_SHAPING"] == "plan"
    assert seen["TOTAL_TIMESTEPS"] == 100 and seen["out"] == "outputs/train_ippo"
    with pytest.raises(ConfigError, match="BATTERY_NETT.*allowed.*BATTERY_NET"):
        cli.main(["BATTERY_NETT=true"])
    with pytest.raises(ConfigError, match="PORT_SHAPING='planned'.*one of"):
        cli.main(["PORT_SHAPING=planned"])


def test_replot_adds_the_stored_mpc_for_exactly_the_runs_params(tmp_path, monkeypatch):
    """``python -m baselines.train --replot RUN`` finds the MPC stored for the run's params and
    held-out days, adds it to the run's table with the paired difference, and redraws the
    curve; without a matching stored result it raises ``LookupError``."""
    from chargax_marl.trace import params_fingerprint

    out = tmp_path / "run"
    cli.main([*TINY_CLI, "ALGO=ippo", f"TOTAL_TIMESTEPS={4 * 24}", "CHUNKS=1", "OPTIMAL=off", f"OUT={_toml(str(out))}"])
    res = json.loads((out / "results.json").read_text())
    (tmp_path / "optimal").mkdir()
    with pytest.raises(LookupError, match="no stored MPC"):
        cli.main(["--replot", str(out), "--references", str(tmp_path / "optimal")])
    config = resolve(res["config"])
    _, eval_params, _, days = build_env_params(config)
    days = [int(d) for d in days]
    mpc_daily = np.linspace(10.0, 20.0, len(days))
    stored = {"params_fingerprint": params_fingerprint(eval_params), "days": days,
              "policies": {"mpc": {"daily_profit": mpc_daily.tolist()}}}
    (tmp_path / "optimal" / "other.json").write_text(json.dumps({**stored, "params_fingerprint": "0" * 16}))
    (tmp_path / "optimal" / "tiny.json").write_text(json.dumps(stored))
    before = (out / "curve.png").stat().st_mtime_ns
    cli.main(["--replot", str(out), "--references", str(tmp_path / "optimal")])
    new = json.loads((out / "results.json").read_text())
    table = new["evaluation"]["table"]
    assert table["mpc"]["daily_profit"] == pytest.approx(mpc_daily.tolist())
    learned = np.asarray(table["ippo"]["daily_profit"])  # (seeds, days)
    assert new["vs_mpc"]["mean"] == pytest.approx(float((learned - mpc_daily[None, :]).mean()))
    assert len(new["vs_mpc"]["per_seed_mean"]) == 2
    assert new["per_seed"] == res["per_seed"]  # nothing else of the run changes
    assert (out / "curve.png").stat().st_mtime_ns > before


def test_sensitivity_battery_step_on_an_empty_station_is_the_hand_computed_trade():
    """With no cars, charging the battery for one step changes each day by exactly what the
    step costs at that step's price plus what the stored energy is worth at the day's end; a
    port idling changes nothing, and neither does a step outside the day."""
    from baselines.analysis import sensitivity
    from chargax_marl.core import make_params
    from tests.helpers import no_arrivals

    params = no_arrivals(make_params(**{**TINY_ENV, "step_minutes": 15.0}))
    days, step = np.array([3, 40, 200]), 30
    out = sensitivity.sensitivity(params, days, step=step)
    eta, power_kw, capacity_kwh, e0 = storage_value.battery_constants(params)
    assert e0 + power_kw * float(params.step_hours) < 0.8 * capacity_kwh  # below the taper: the full charge
    stored = power_kw * float(params.step_hours)
    prices = storage_value.step_buy_prices(params)[days, step]
    expected = -prices * stored / eta + storage_value.terminal_prices(params)[days] * stored
    np.testing.assert_allclose(out["battery_charges"]["daily_difference_eur"], expected, rtol=1e-4, atol=1e-4)
    assert np.all(np.asarray(out["port_idles"]["daily_difference_eur"]) == 0.0)
    assert out["battery_charges"]["days_served_cars_differ"] == 0
    outside = sensitivity.sensitivity(params, days, step=-5)
    assert all(np.all(np.asarray(outside[p]["daily_difference_eur"]) == 0.0) for p in sensitivity.PERTURBATIONS)
    with pytest.raises(ValueError, match="perturbation"):
        sensitivity.perturbed_always_max(params, "battery_discharges", 0)


def test_eval_draws_score_every_policy_on_the_mean_over_car_draws_of_each_day(tmp_path):
    """``--eval-draws 2``: the rules, the bound and the agent are scored under PRNGKey(0) and
    PRNGKey(1), each day's profit the mean of the two; the run says so, ``baselines.analysis.redraw``
    replays it only with at least its draws, and the one-draw stored MPC is refused."""
    from baselines import pipeline
    from baselines.analysis import redraw
    from baselines.eval.rules import evaluate_rules

    out = tmp_path / "run"
    cli.main([*TINY_CLI, "ALGO=ppo", f"TOTAL_TIMESTEPS={4 * 24}", "CHUNKS=1", "EVAL_DRAWS=2", f"OUT={_toml(str(out))}"])
    res = json.loads((out / "results.json").read_text())
    assert res["evaluation"]["draws"] == 2 and res["scenario"]["car_draws_per_day"] == 2
    assert "PRNGKey(1)" in res["evaluation"]["key"]
    table = res["evaluation"]["table"]
    _, eval_params, _, days = build_env_params(res["config"])
    by_key = [evaluate_rules(eval_params, days, ("always_max",), key=jax.random.PRNGKey(k))["always_max"]["daily_profit"]
              for k in (0, 1)]
    assert not np.allclose(by_key[0], by_key[1])  # the draws differ ...
    np.testing.assert_allclose(table["always_max"]["daily_profit"], np.mean(by_key, axis=0), rtol=1e-6, atol=1e-4)
    assert np.all(np.asarray(table["lp_bound"]["daily_profit"]) >= np.asarray(table["always_max"]["daily_profit"]) - 1e-3)
    assert "2 car draws" in table["lp_bound"]["source"]
    # ... and the agent's stored score is the mean over the same two draws (redraw's replay check)
    again = redraw.redraw(out, draws=2, bound=False)
    assert again["replay_check_max_abs_eur"] < 1e-3
    with pytest.raises(ValueError, match="draws >= 2"):
        redraw.redraw(out, draws=1, bound=False)
    with pytest.raises(LookupError, match="car draws"):
        pipeline.add_stored_mpc(out, tmp_path)
    with pytest.raises(ValueError, match="either a key or draws"):
        heldout.evaluate_batched(None, None, eval_params, days, key=jax.random.PRNGKey(0), draws=2)
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="EVAL_DRAWS"):
            resolve({"EVAL_DRAWS": bad})
