"""Host data onto the device at construction time, without compiling anything.

``jnp.asarray`` on host data (a numpy array, a list, a Python scalar) runs a small compiled
conversion program, one per new shape and dtype in the process. The builders of a station and
its parameters create dozens of arrays whose shapes depend on the station, which would cost
dozens of compiles for each new station. `device_array` converts on the host with numpy and
copies the result to the device, which compiles nothing.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np


def device_array(value: Any, dtype: Any = None) -> jax.Array:
    """``value`` as a device array, like ``jnp.asarray(value, dtype)`` on host data.

    Args:
        value: host data: a numpy array, a nested list or a scalar (a jax array is copied
            through the host; do not pass a tracer).
        dtype: the dtype of the result; ``None`` keeps numpy's. Either way it is then
            canonicalised as JAX does (float64 becomes float32 unless ``JAX_ENABLE_X64`` is set).

    Returns:
        A jax array on the default device (uncommitted, as ``jnp.asarray`` makes it) with the
        value and dtype of ``jnp.asarray(value, dtype)``; not weak-typed, so give a Python
        scalar its ``dtype``.
    """
    return jax.device_put(np.asarray(value, dtype))
