"""The contract JaxMARL's own IPPO and MAPPO baselines rely on, checked on the multi-agent view.

JaxMARL's ``ippo_ff_*``, ``ippo_rnn*`` and ``mappo_rnn*`` scripts run ``NUM_ENVS`` envs under
``jax.vmap`` and treat every (env, agent) pair as one of ``NUM_ACTORS = NUM_ENVS * num_agents``
actors. The shape operations they apply to the env's outputs, written here from JaxMARL's
documented conventions:

- observations, rewards and dones: stacked over the agent list and reshaped to
  ``(NUM_ACTORS, -1)`` (agent-major), rewards and dones squeezed to ``(NUM_ACTORS,)``;
- actions: ``(NUM_ACTORS,)`` reshaped to ``(num_agents, NUM_ENVS, -1)`` and split by agent, so
  each env receives actions of shape ``(1,)``;
- infos: *every* leaf reshaped to ``(NUM_ACTORS,)`` (env-major), then the mean of each leaf
  logged, ``returned_episode_returns[-1, :]`` read after the rollout;
- MAPPO: ``obs["world_state"]`` ``(NUM_ENVS, num_agents, state)`` swapped to agent-major and
  reshaped to ``(NUM_ACTORS, state)``;
- action masks: ``get_avail_actions`` of the state under JaxMARL's ``LogWrapper``, vmapped and
  stacked like observations to ``(NUM_ACTORS, num_actions)``.

The rollouts run through JaxMARL's own ``LogWrapper`` and ``MPELogWrapper`` (and this
package's `LogWrapper`), over every wrapper stack the docs build on the view.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jaxmarl.wrappers.baselines import LogWrapper as JaxMARLLogWrapper
from jaxmarl.wrappers.baselines import MPELogWrapper

from chargax_marl.core import make_params
from chargax_marl.marl import (
    ActionLossWrapper,
    ChargaxMARL,
    DelayedObservationWrapper,
    FinalObservationWrapper,
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
from tests.helpers import mixed_station

NUM_ENVS = 2
DAY_STEPS = 24  # hourly steps
NUM_STEPS = DAY_STEPS + 3  # one auto-reset inside the rollout


@pytest.fixture(scope="module")
def params():
    return make_params(station=mixed_station(), step_minutes=60.0, traffic=150.0)


def to_actors(x: dict, agents: list, num_actors: int) -> jax.Array:
    """Agent-keyed ``(NUM_ENVS, ...)`` values as ``(num_actors, -1)``, agent-major."""
    return jnp.stack([x[a] for a in agents]).reshape((num_actors, -1))


def from_actors(x: jax.Array, agents: list, num_envs: int) -> dict:
    """``(num_actors,)`` values split back by agent, each ``(num_envs, 1)``."""
    x = x.reshape((len(agents), num_envs, -1))
    return {a: x[i] for i, a in enumerate(agents)}


def inner_state(state):
    """The state JaxMARL's baselines hand to ``get_avail_actions``: the one under the log
    wrapper."""
    return state.env_state


def rollout(env, key, world_state: bool):
    """``NUM_STEPS`` vmapped steps of ``env`` with masked random actions, applying to every
    output the shape operations of JaxMARL's baselines. Returns the per-step transitions."""
    agents, n_act = env.agents, NUM_ENVS * env.num_agents
    obs, state = jax.vmap(env.reset)(jax.random.split(key, NUM_ENVS))

    def one_step(carry, step_key):
        obs, state = carry
        obs_batch = to_actors(obs, agents, n_act)
        avail = jax.vmap(env.get_avail_actions)(inner_state(state))
        avail_batch = to_actors(avail, agents, n_act)
        act_key, env_key = jax.random.split(step_key)
        logits = jnp.where(avail_batch, 0.0, -1e9)
        action = jax.random.categorical(act_key, logits)  # (NUM_ACTORS,)
        env_act = from_actors(action, agents, NUM_ENVS)
        new_obs, state, reward, done, info = jax.vmap(env.step)(
            jax.random.split(env_key, NUM_ENVS), state, env_act
        )
        info = jax.tree.map(lambda x: x.reshape((n_act,)), info)
        out = {
            "obs": obs_batch,
            "avail": avail_batch,
            "action": action,
            "reward": to_actors(reward, agents, n_act).squeeze(),
            "done": to_actors(done, agents, n_act).squeeze(),
            "info": info,
        }
        if world_state:
            out["world_state"] = obs["world_state"].swapaxes(0, 1).reshape((n_act, -1))
        return (new_obs, state), out

    _, traj = jax.lax.scan(one_step, (obs, state), jax.random.split(key, NUM_STEPS))
    return traj


# Every stack the docs build on the view, under JaxMARL's own LogWrapper.
STACKS = {
    "view": lambda p: ChargaxMARL(params=p),
    "world_state": lambda p: WorldStateWrapper(ChargaxMARL(params=p)),
    "project_log": lambda p: LogWrapper(WorldStateWrapper(ChargaxMARL(params=p))),
    "teachers": lambda p: RelativePriceObservation(
        PlanAdviceObservation(
            CarPlanShaping(BatteryShaping(ChargaxMARL(params=p, local_reward_weight=1.0)))
        )
    ),
    "fairness": lambda p: FairnessReward(ChargaxMARL(params=p), weight_eur=2.0),
    "communication": lambda p: ActionLossWrapper(DelayedObservationWrapper(ChargaxMARL(params=p))),
}


@pytest.mark.parametrize("stack", sorted(STACKS))
def test_every_info_leaf_is_one_value_per_agent(params, stack):
    env = JaxMARLLogWrapper(STACKS[stack](params))
    obs, state = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), NUM_ENVS))
    actions = {a: jnp.ones((NUM_ENVS, 1), jnp.int32) for a in env.agents}
    _, _, _, _, info = jax.vmap(env.step)(
        jax.random.split(jax.random.PRNGKey(1), NUM_ENVS), state, actions
    )
    shapes = {k: tuple(v.shape) for k, v in info.items()}
    want = (NUM_ENVS, env.num_agents)
    assert {k: s for k, s in shapes.items() if s != want} == {}
    assert {"returned_episode", "returned_episode_returns", "truncated"} <= set(info)


@functools.cache
def _run(name: str):
    """The rollouts of the three baselines' shapes, each compiled once per test session."""
    p = make_params(station=mixed_station(), step_minutes=60.0, traffic=150.0)
    if name == "ippo_ff":  # ippo_ff_mpe: MPELogWrapper (returns logged times num_agents)
        env = MPELogWrapper(ChargaxMARL(params=p))
    elif name == "ippo_rnn":  # ippo_rnn: LogWrapper, masked actions
        env = JaxMARLLogWrapper(ChargaxMARL(params=p))
    else:  # mappo_rnn: the world state under the log wrapper
        env = JaxMARLLogWrapper(WorldStateWrapper(ChargaxMARL(params=p)))
    traj = jax.jit(functools.partial(rollout, env, world_state=name == "mappo_rnn"))(
        jax.random.PRNGKey(7)
    )
    return env, jax.device_get(traj)


@pytest.mark.parametrize("name", ["ippo_ff", "ippo_rnn", "mappo_rnn"])
def test_jaxmarl_baselines_shape_operations(params, name):
    env, traj = _run(name)
    n_agents, n_act = env.num_agents, NUM_ENVS * env.num_agents
    info = traj["info"]
    assert {k: v.shape for k, v in info.items() if v.shape != (NUM_STEPS, n_act)} == {}
    assert traj["obs"].shape == (NUM_STEPS, n_act, env.obs_size)
    assert traj["reward"].shape == traj["done"].shape == (NUM_STEPS, n_act)

    # the logged metric: every leaf's mean, and the last step's returns
    means = jax.tree.map(lambda x: np.mean(x), info)
    assert all(np.isfinite(v) for v in means.values())
    assert np.isfinite(info["returned_episode_returns"][-1, :].mean())

    # the day ends on step DAY_STEPS - 1 for every actor, and only there
    ended = np.zeros((NUM_STEPS, n_act), bool)
    ended[DAY_STEPS - 1] = True
    np.testing.assert_array_equal(info["returned_episode"], ended)
    np.testing.assert_array_equal(traj["done"], ended)

    # info is env-major, rewards agent-major: the logged return of the day is the sum of the
    # rewards of that (env, agent) pair (MPELogWrapper logs num_agents times it)
    scale = n_agents if name == "ippo_ff" else 1
    day_reward = traj["reward"][:DAY_STEPS].sum(0).reshape(n_agents, NUM_ENVS).T.reshape(-1)
    np.testing.assert_allclose(
        info["returned_episode_returns"][DAY_STEPS - 1], scale * day_reward, rtol=1e-4, atol=1e-3
    )
    np.testing.assert_array_equal(info["returned_episode_lengths"][DAY_STEPS - 1], DAY_STEPS)

    # the actions reached the env as sampled: masked actions were never chosen
    avail = np.stack([np.asarray(env.get_avail_actions(None)[a]) for a in env.agents])
    np.testing.assert_array_equal(traj["avail"][0], np.repeat(avail, NUM_ENVS, axis=0))
    assert traj["avail"].shape == (NUM_STEPS, n_act, env.num_actions)
    assert np.take_along_axis(traj["avail"], traj["action"][..., None], -1).all()

    # observations are agent-major: actor i * NUM_ENVS + e is agent i in env e; the agent
    # index one-hot sits in the last num_agents columns
    agent_of_actor = np.repeat(np.arange(n_agents), NUM_ENVS)
    np.testing.assert_array_equal(traj["obs"][..., -n_agents:].argmax(-1)[0], agent_of_actor)

    if name == "mappo_rnn":
        ws = traj["world_state"]
        assert ws.shape == (NUM_STEPS, n_act, env.state_size)
        # every agent of an env sees that env's one world state
        per_env = ws.reshape(NUM_STEPS, n_agents, NUM_ENVS, -1)
        np.testing.assert_array_equal(per_env, np.repeat(per_env[:, :1], n_agents, axis=1))


def test_final_observation_wrapper_wraps_the_view_itself(params):
    with pytest.raises(TypeError, match=r"field 'env' must be a ChargaxMARL.*LogWrapper"):
        FinalObservationWrapper(LogWrapper(ChargaxMARL(params=params)))
