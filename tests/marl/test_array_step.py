"""The array step through every wrapper of the multi-agent view: ``step_arrays`` (actions
``(num_agents,)`` in, observations ``(num_agents, obs)`` and rewards ``(num_agents,)`` out)
gives the values of the dict ``step``, stacked, through the end of a day and its auto-reset;
a wrapper without an array step refuses one instead of letting it pass unchanged."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.marl import (
    ActionLossWrapper,
    ChargaxMARL,
    DelayedObservationWrapper,
    LogWrapper,
    WorldStateWrapper,
)
from chargax_marl.wrappers import (
    BatteryShaping,
    CarPlanShaping,
    FairnessReward,
    PlanAdviceObservation,
    RelativePriceObservation,
)
from chargax_marl.wrappers.base import TeacherWrapper
from tests.helpers import mixed_station

STACKS = {
    # the multi-agent trainers' stack with every option on
    "trainer": lambda e: LogWrapper(
        WorldStateWrapper(
            ActionLossWrapper(
                DelayedObservationWrapper(FairnessReward(e, 10.0, "min_satisfaction"), 2), 0.5
            )
        )
    ),
    # every teacher wrapper
    "teachers": lambda e: RelativePriceObservation(
        PlanAdviceObservation(CarPlanShaping(BatteryShaping(e, "dp")))
    ),
}


@pytest.fixture(scope="module")
def base():
    """6 ports (4 DC with V2G, 2 AC), a battery, busy traffic, one-hour steps, rewards mixed
    with the agents' own shares."""
    return ChargaxMARL(
        station=mixed_station(), traffic=150.0, step_minutes=60.0, local_reward_weight=0.5
    )


def _late(state, timestep: int):
    """``state`` (wrapped or not) moved to ``timestep`` of its day."""
    if hasattr(state, "totals"):
        return state.replace(timestep=jnp.asarray(timestep, jnp.int32))
    return state.replace(env_state=_late(state.env_state, timestep))


def _close(got, want, what: str):
    got, want = np.asarray(got), np.asarray(want)
    assert got.shape == want.shape, (what, got.shape, want.shape)
    if np.issubdtype(want.dtype, np.floating):
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6, err_msg=what)
    else:
        np.testing.assert_array_equal(got, want, err_msg=what)


@pytest.mark.parametrize("name", list(STACKS))
def test_the_array_step_is_the_dict_step_stacked_through_every_wrapper(base, name):
    env = STACKS[name](base)
    agents = base.agents
    n = base.num_agents
    key = jax.random.PRNGKey(5)
    _, state = env.reset(key)
    state = _late(state, base.params.num_steps - 2)
    fresh = base.reset(jax.random.PRNGKey(6))[1]

    @jax.jit
    def both(k, s, idx):
        return env.step(k, s, dict(zip(agents, idx)), fresh), env.step_arrays(k, s, idx, fresh)

    ended = False
    for t in range(3):
        idx = jax.random.randint(jax.random.fold_in(key, t), (n,), 0, base.num_actions)
        dict_out, array_out = both(jax.random.fold_in(key, 99 + t), state, idx)
        obs_d, s_d, r_d, d_d, info_d = dict_out
        obs_a, s_a, r_a, d_a, info_a = array_out
        _close(obs_a, np.stack([obs_d[a] for a in agents]), "obs")
        _close(r_a, np.stack([r_d[a] for a in agents]), "rewards")
        assert bool(d_a) == bool(d_d["__all__"])
        ended = ended or bool(d_a)
        for (path, x), y in zip(jax.tree_util.tree_leaves_with_path(s_a), jax.tree.leaves(s_d)):
            _close(x, y, f"state{jax.tree_util.keystr(path)}")
        assert set(info_a) == set(info_d)
        for k in info_d:  # the dict view broadcasts each scalar to (num_agents,)
            _close(jnp.broadcast_to(info_a[k], jnp.shape(info_d[k])), info_d[k], f"info[{k}]")
        state = s_a
    assert ended  # the day ended and the step reset it


def test_a_wrapper_without_an_array_step_refuses_one(base):
    class Scaled(TeacherWrapper):  # changes the rewards of step only
        def step(self, key, state, actions, *args):
            obs, state, rewards, dones, infos = self._env.step(key, state, actions, *args)
            return obs, state, {a: 2.0 * r for a, r in rewards.items()}, dones, infos

    env = LogWrapper(Scaled(base))
    _, state = env.reset(jax.random.PRNGKey(0))
    idx = jnp.zeros((base.num_agents,), jnp.int32)
    with pytest.raises(NotImplementedError, match="Scaled has no array step"):
        env.step_arrays(jax.random.PRNGKey(1), state, idx)
