"""Host data onto the device at construction time: same arrays as ``jnp.asarray``, no compile."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core import make_params
from chargax_marl.core.arrays import device_array
from tests.helpers import count_compiles


@pytest.mark.parametrize(
    "value, dtype",
    [
        (np.linspace(0.0, 1.0, 7), jnp.float32),
        (np.arange(5, dtype=np.int64), None),
        ([[1.5, 2.5], [3.5, 4.5]], jnp.float32),
        (3, jnp.int32),
        (0.25, jnp.float32),
        (True, None),
        (np.zeros((0,), np.float32), None),
    ],
)
def test_device_array_is_jnp_asarray(value, dtype):
    got, want = device_array(value, dtype), jnp.asarray(value, dtype)
    assert isinstance(got, jax.Array)
    assert (got.dtype, got.shape, got.weak_type) == (want.dtype, want.shape, want.weak_type)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_a_new_station_s_params_compile_no_program():
    # 37 ports and 20-minute steps: array shapes no other test builds, so any jnp conversion
    # on the host would compile here
    count = count_compiles(
        lambda: make_params(
            station="single_type", station_kwargs={"num_ports": 37}, step_minutes=20.0
        )
    )
    assert count == 0
