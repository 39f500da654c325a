"""The benchmark plays and scores one-day episodes: its play (which `score` and the
references go through) refuses episodes of several days with a ValueError naming
``episode_days``."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from chargax_marl.benchmark import protocol
from chargax_marl.core import make_params, multiple_types
from chargax_marl.policies import always_max


def test_play_refuses_multi_day_episodes():
    params = make_params(station=multiple_types(2, 2), step_minutes=60, episode_days=2)
    keys = jax.random.split(jax.random.PRNGKey(0), 1)[:, None]
    with pytest.raises(ValueError, match=r"field 'episode_days' is 2, but only episode_days=1"):
        protocol.play(always_max, params, np.array([0]), keys)
