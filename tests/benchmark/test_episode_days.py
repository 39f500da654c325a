"""The benchmark plays and scores one-day episodes: its play (which `score` and the
references go through) refuses episodes of several days with a ValueError naming
``episode_days``."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from chargax_marl.benchmark import protocol
from chargax_marl.policies import always_max
from tests.helpers import ONE_DAY_ONLY, two_day_params


def test_play_refuses_multi_day_episodes():
    keys = jax.random.split(jax.random.PRNGKey(0), 1)[:, None]
    with pytest.raises(ValueError, match=ONE_DAY_ONLY):
        protocol.play(always_max, two_day_params(), np.array([0]), keys)
