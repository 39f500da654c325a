"""Distillation of the MPC into the IPPO actor (`baselines.algos.distill`)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from baselines.algos import distill, ippo, ppo
from baselines.config import ConfigError, resolve
from chargax_marl.marl.wrappers import LogWrapper
from tests.helpers import TINY, TINY_ENV, finite_losses

DISTILL = {
    "DISTILL": "mpc",
    "DISTILL_ROUNDS": 2,
    "DISTILL_ENVS": 4,
    "DISTILL_STEPS": 300,
    "DISTILL_BATCH": 64,
    "DISTILL_LR": 3e-3,
    "BATTERY_NET": True,
}


def _distill(config: dict):
    """``(distill, trainer)`` for the tiny station (4 ports, a battery, 24 steps a day)."""
    config = resolve({**TINY, **config})
    train = ippo.make_train(config)
    env = train.env
    avail = np.stack([np.asarray(env.get_avail_actions(None)[a]) for a in env.agents])
    fn = distill.make_distill(
        config,
        train.policy,
        LogWrapper(env),
        env.agents,
        lambda obs, state: ippo.agent_major(obs),
        avail,
        env.action_offset,
        train.env_params,
    )
    return fn, train


def test_the_fitted_actor_takes_the_mpcs_actions_on_a_day_it_did_not_see():
    """Round 0 measures the untrained actor against the MPC's labels on the MPC's own day;
    round 1 measures the actor fitted to round 0's labels on new days (half of them played by
    the actor itself) before it fits them: it agrees with the MPC far more often."""
    fn, train = _distill(DISTILL)
    params = train.policy.init(jax.random.PRNGKey(0))
    fitted, metrics = jax.jit(fn)(params, jax.random.PRNGKey(1))
    agree = np.asarray(metrics["agreement"])
    assert agree.shape == (2,)
    assert agree[1] > 0.9 and agree[1] > agree[0] + 0.2, agree
    assert np.all(np.isfinite(np.asarray(metrics["loss"])))
    # only the actors move: the critics are left as they were
    for name in ("critic", "battery_critic"):
        same = jax.tree.map(np.array_equal, params[name], fitted[name])
        assert all(jax.tree.leaves(same))


def test_battery_only_distillation_leaves_the_ports_actor_as_it_was():
    fn, train = _distill({**DISTILL, "DISTILL_AGENTS": "battery", "DISTILL_ROUNDS": 1})
    params = train.policy.init(jax.random.PRNGKey(0))
    fitted, _ = jax.jit(fn)(params, jax.random.PRNGKey(1))
    assert all(jax.tree.leaves(jax.tree.map(np.array_equal, params["actor"], fitted["actor"])))
    moved = jax.tree.map(np.array_equal, params["battery_actor"], fitted["battery_actor"])
    assert not all(jax.tree.leaves(moved))


def test_the_trainer_starts_from_the_distilled_actor():
    """With ``DISTILL="mpc"`` the trainer's initial parameters are the distilled ones (from
    the same network initialisation), so PPO's updates start there."""
    distilled = ippo.make_train(resolve({**TINY, **DISTILL, "DISTILL_ROUNDS": 1}))
    key = jax.random.PRNGKey(0)
    a = distilled.policy.init(jax.random.split(key, 3)[0])  # the networks the trainer draws
    b = jax.jit(distilled.init)(key).params
    gap = lambda x, y: max(jax.tree.leaves(jax.tree.map(lambda u, v: np.abs(u - v).max(), x, y)))  # noqa: E731
    assert gap(a["critic"], b["critic"]) < 1e-6  # the same draw (to the rounding of its program)
    assert gap(a["actor"], b["actor"]) > 1e-2


def test_bad_distillation_settings_are_refused_naming_the_key():
    with pytest.raises(ConfigError, match="DISTILL"):
        resolve({"DISTILL": "lp"})
    with pytest.raises(ConfigError, match="DISTILL_BETA"):
        resolve({"DISTILL_BETA": 1.5})
    with pytest.raises(ValueError, match="DISTILL='mpc' applies to the multi-agent trainers"):
        ppo.make_train(resolve({**TINY, "DISTILL": "mpc"}))
    with pytest.raises(ValueError, match="BATTERY_NET=true"):
        ippo.make_train(
            resolve({**TINY, **DISTILL, "DISTILL_AGENTS": "battery", "BATTERY_NET": False})
        )
    with pytest.raises(ValueError, match="PRIORITY_FILL"):
        ippo.make_train(resolve({**TINY, **DISTILL, "PRIORITY_FILL": True}))
    no_battery = {**TINY_ENV, "station_kwargs": {"num_ports": 4, "battery": False}}
    with pytest.raises(ValueError, match="DISTILL_AGENTS"):
        ippo.make_train(
            resolve({**TINY, **DISTILL, "DISTILL_AGENTS": "battery", "ENV_KWARGS": no_battery})
        )


def test_station_obs_columns_are_the_parked_cars_demand():
    """``STATION_OBS``: every agent's row ends (before the advice) with the station's parked
    demand, computed here by hand from the state's cars."""
    from chargax_marl.core.station import KIND_BATTERY
    from chargax_marl.marl import ChargaxMARL
    from chargax_marl.teachers import shaping as teacher_shaping

    train = ippo.make_train(resolve({**TINY, "STATION_OBS": True}))
    assert train.policy.obs_dim == train.env.obs_size + 5
    env = ChargaxMARL(**TINY_ENV)
    state = env.reset_to_day(3)[1]
    for _ in range(10):  # cars arrive
        state = env.step_arrays(jax.random.PRNGKey(_), state, np.full(5, env.action_offset))[1]
    core = teacher_shaping.core_state(state)
    rows = np.asarray(train.policy.with_plan(env.get_obs_matrix(state), core))
    port = np.asarray(env.params.station.leaf_kind) != KIND_BATTERY
    occ = np.asarray(core.occupied) & port
    assert occ.sum() >= 2  # the case is not trivial
    want = np.where(occ, np.maximum(core.target_soc - core.soc, 0) * core.capacity_kwh, 0)
    left = np.where(occ, np.maximum(core.time_remaining_min, 0), 0)
    rating = np.asarray(env.params.station.leaf_max_kw)[port].sum()
    finish = want / np.maximum(left / 60.0, env.params.step_hours)
    expected = [
        want.sum() / (port.sum() * 100.0),
        occ.sum() / port.sum(),
        left.sum() / occ.sum() / 1440.0,
        finish.sum() / rating,
        want[left < 60].sum() / (port.sum() * 100.0),
    ]
    for row in rows:  # the same for every agent
        np.testing.assert_allclose(row[-5:], expected, rtol=1e-5, atol=1e-7)
    finite_losses(train)
    with pytest.raises(ValueError, match="STATION_OBS"):
        ppo.make_train(resolve({**TINY, "STATION_OBS": True}))
