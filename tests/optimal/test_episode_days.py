"""The bounds, the MPC and the MILP plan one day: episodes of several days are refused at
each entry point with a ValueError naming ``episode_days``."""

from __future__ import annotations

import jax
import pytest

from chargax_marl.optimal import bound, milp, mpc, pooled
from tests.helpers import ONE_DAY_ONLY as MESSAGE
from tests.helpers import two_day_params


@pytest.fixture(scope="module")
def two_days():
    return two_day_params()


ENTRY_POINTS = {
    "bound.sessions_from_rollout": lambda p: bound.sessions_from_rollout(None, None, p),
    "bound.hindsight_bound": lambda p: bound.hindsight_bound(p, None, None),
    "bound.bound_days": lambda p: bound.bound_days(p, [0], jax.random.PRNGKey(0)),
    "milp.candidate_sessions": lambda p: milp.candidate_sessions(p, None, 4),
    "milp.admission_bound": lambda p: milp.admission_bound(p, None, 4),
    "milp.compare": lambda p: milp.compare(p, None, jax.random.PRNGKey(0), 4),
    "pooled.pooled_sessions": lambda p: pooled.pooled_sessions(p, None),
    "pooled.pooled_bound": lambda p: pooled.pooled_bound(p, None),
    "pooled.pooled_bound_days": lambda p: pooled.pooled_bound_days(p, [0], None),
    "mpc.MPC": lambda p: mpc.MPC(p),
    "mpc.mpc_policy": lambda p: mpc.mpc_policy(p),
}


@pytest.mark.parametrize("name", sorted(ENTRY_POINTS))
def test_multi_day_episodes_are_refused(two_days, name):
    with pytest.raises(ValueError, match=MESSAGE):
        ENTRY_POINTS[name](two_days)
