"""``FairnessReward``: zero weight is the env, the day's terms add up to the weight times the
metric's shortfall, the term is the same in both views, and bad settings are refused."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core.types import EpisodeTotals
from chargax_marl.evaluation import service_metrics
from chargax_marl.marl import ChargaxMARL
from chargax_marl.single import Chargax
from chargax_marl.wrappers import FairnessReward
from chargax_marl.wrappers.fairness import FAIRNESS_METRICS, fairness_metric
from tests.helpers import exact_jit, three_level_station

STEPS = 30  # one-hour steps: a day of 24 and the start of the next
SETTINGS = {"station": three_level_station(), "traffic": 150.0, "step_minutes": 60.0}


@pytest.fixture(scope="module")
def env():
    return Chargax(**SETTINGS)


def rollout(env, key=jax.random.PRNGKey(2)):
    """Rewards, terms, dones and the stepped day's totals of random actions in the gymnax view."""
    params = env.default_params

    def body(state, k):
        k_act, k_step = jax.random.split(k)
        action = env.action_space(params).sample(k_act)
        _, state, reward, _, truncated, info = env.step(k_step, state, action, params)
        return state, (reward, info.get("fairness_reward_eur", 0.0), truncated, info)

    @exact_jit  # compared bit for bit
    def run(key):
        _, state = env.reset(key, params)
        return jax.lax.scan(body, state, jax.random.split(key, STEPS))[1]

    return run(key)


def test_zero_weight_is_the_env_bit_for_bit(env):
    rewards, _, dones, info = rollout(env)
    w_rewards, terms, w_dones, w_info = rollout(FairnessReward(env, 0.0))
    assert bool(jnp.array_equal(rewards, w_rewards)) and bool(jnp.array_equal(dones, w_dones))
    assert not np.any(np.asarray(terms))
    assert all(bool(jnp.array_equal(info[k], w_info[k])) for k in info)


@pytest.mark.parametrize("metric", FAIRNESS_METRICS)
def test_a_day_s_terms_add_up_to_the_weight_times_the_metric_s_shortfall(env, metric):
    weight = 40.0
    rewards, _, dones, _ = rollout(env)
    w_rewards, terms, _, info = rollout(FairnessReward(env, weight, metric))
    end = int(np.argmax(np.asarray(dones)))  # the step that ended the first day
    assert 0 < end < STEPS - 1
    day = EpisodeTotals(
        **{k: info[f"episode_{k}"][end] for k in EpisodeTotals.__dataclass_fields__}
    )
    day_metric = float(service_metrics(day)[metric])
    assert day_metric < 1.0  # the random policy served the day's cars unevenly
    np.testing.assert_allclose(
        np.sum(np.asarray(terms)[: end + 1]), weight * (day_metric - 1.0), rtol=1e-4, atol=1e-4
    )
    np.testing.assert_allclose(np.asarray(w_rewards) - np.asarray(rewards), terms, atol=1e-5)
    # the next day starts afresh: its first step's term is measured from 1, not from the last day
    first = EpisodeTotals(
        **{k: info[f"episode_{k}"][end + 1] for k in EpisodeTotals.__dataclass_fields__}
    )
    expected = weight * (float(service_metrics(first)[metric]) - 1.0)
    assert float(np.asarray(terms)[end + 1]) == pytest.approx(expected, abs=1e-4)


def test_the_multi_agent_view_gives_every_agent_the_station_s_term():
    marl = FairnessReward(ChargaxMARL(**SETTINGS), 40.0, "min_satisfaction")
    obs, state = marl.reset(jax.random.PRNGKey(0))
    step = jax.jit(marl.step)
    idle = {a: jnp.int32(marl.action_offset) for a in marl.agents}
    seen = []
    for t in range(12):
        obs, state, rewards, dones, infos = step(jax.random.PRNGKey(t), state, idle)
        term = np.asarray(infos["fairness_reward_eur"])
        assert term.shape == (marl.num_agents,) and np.all(term == term[0])
        np.testing.assert_allclose(
            [rewards[a] for a in marl.agents], np.asarray(infos["reward"]) + term, atol=1e-5
        )
        seen.append(term[0])
    assert min(seen) < 0.0  # idle ports: a car left unserved and the minimum fell


def test_the_traced_metric_is_the_evaluation_s():
    t = EpisodeTotals.zeros().replace(
        cars_served=jnp.float32(4.0),
        satisfaction_sum=jnp.float32(2.75),
        satisfaction_sq_sum=jnp.float32(2.3125),
        satisfaction_shortfall_max=jnp.float32(0.75),
    )
    m = service_metrics(t)
    for metric in FAIRNESS_METRICS:
        assert float(fairness_metric(t, metric)) == pytest.approx(float(m[metric]), abs=1e-6)
    zero = EpisodeTotals.zeros()
    assert all(float(fairness_metric(zero, metric)) == 1.0 for metric in FAIRNESS_METRICS)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"weight_eur": -1.0}, "weight_eur"),
        ({"weight_eur": float("nan")}, "weight_eur"),
        ({"metric": "gini"}, "metric"),
    ],
)
def test_bad_settings_are_refused_naming_the_field(env, kwargs, field):
    with pytest.raises(ValueError, match=f"field '{field}'"):
        FairnessReward(env, **kwargs)
