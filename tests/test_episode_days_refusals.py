"""Evaluation, traces, the node-binding table and the simulated sessions play or replay one
day: episodes of several days are refused at each entry point with a ValueError naming
``episode_days``."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from chargax_marl import binding, evaluation, trace
from chargax_marl.policies import always_max
from chargax_marl.validation import simulated
from tests.helpers import ONE_DAY_ONLY as MESSAGE
from tests.helpers import two_day_params

KEY = jax.random.PRNGKey(0)


def act(state, key):
    return always_max(state, key, PARAMS)


PARAMS = two_day_params()
DAYS = np.array([0])

ENTRY_POINTS = {
    "evaluation.run_days": lambda p: evaluation.run_days(act, p, DAYS, KEY),
    "evaluation.run_policy_days": lambda p: evaluation.run_policy_days(always_max, p, DAYS, KEY),
    "evaluation.evaluate_policy": lambda p: evaluation.evaluate_policy(always_max, p, DAYS),
    "evaluation.hindsight_bound": lambda p: evaluation.hindsight_bound(p, DAYS),
    "evaluation.policy_bound": lambda p: evaluation.policy_bound(p, DAYS),
    "trace.make_traces": lambda p: trace.make_traces(p, DAYS),
    "trace.trace_from_cars": lambda p: trace.trace_from_cars(p, []),
    "trace.check_trace": lambda p: trace.check_trace(None, p),
    "trace.replay": lambda p: trace.replay(act, p, None, KEY),
    "trace.replay_days": lambda p: trace.replay_days(act, p, None),
    "binding.node_binding": lambda p: binding.node_binding(p, DAYS),
    "simulated.simulate_sessions": lambda p: simulated.simulate_sessions(p, DAYS, KEY),
}


@pytest.mark.parametrize("name", sorted(ENTRY_POINTS))
def test_multi_day_episodes_are_refused(name):
    with pytest.raises(ValueError, match=MESSAGE):
        ENTRY_POINTS[name](PARAMS)
