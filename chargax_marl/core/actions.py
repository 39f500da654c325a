"""Sanitising actions: the one place that turns whatever a controller emits into valid levels.

Rules (the same in every view):

- **Non-finite values are idle.** A NaN or +-inf entry is read as idle: level 0 in the
  ``absolute`` mode (no current), a change of 0 in ``delta`` mode (the current is kept), a
  fraction of 0 in ``continuous`` mode. In index spaces (the single-agent MultiDiscrete, the
  multi-agent Discrete) it is the index of level 0.
- **Out-of-range values are clipped** to the leaf's range, in the value's own dtype
  *before* any int32 cast, so a host integer like ``np.int64(2**32 + 3)`` clips to the top
  level instead of wrapping to 3, and a float like ``1e30`` clips instead of overflowing.
- **Wrong sizes and non-numbers are errors.** An action must have exactly one entry per
  leaf (ports then batteries); a scalar is not broadcast. Strings, objects and complex
  numbers raise ``ValueError`` naming the field, the value and what is allowed.

`to_int32` and `to_fraction` work under ``jit``; `host_array` runs outside
``jit`` on numpy / Python input (and passes jax arrays and tracers through).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1
HOST_FLOAT_BOUND = 1e9
"""Finite host floats are clipped to +-this before the float32 cast (any level range is far smaller)."""


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def check_dtype(action: Any, field: str = "action") -> None:
    """Raise ``ValueError`` unless ``action`` (array or tracer) holds real numbers or bools.

    Args:
        action: the action; anything with a ``dtype`` (numpy or jax array, tracer).
        field: the name the error message gives the action.

    Raises:
        ValueError: ``action`` has no ``dtype``, or its dtype is not an integer, floating or
            bool dtype (a string, object or complex array).
    """
    dtype = getattr(action, "dtype", None)
    if dtype is None or not (
        np.issubdtype(dtype, np.integer)
        or np.issubdtype(dtype, np.floating)
        or np.issubdtype(dtype, np.bool_)
    ):
        raise ValueError(
            f"field '{field}' must hold numbers (integer levels or indices, or float fractions), "
            f"got {_short(action)} of dtype {dtype}"
        )


def check_size(action: Any, num_leaves: int, field: str = "action") -> None:
    """Raise ``ValueError`` unless ``action`` has exactly ``num_leaves`` entries.

    Static shapes only. The size is the product of the shape, so an action of shape
    ``(1, num_leaves)`` passes; a scalar has one entry.

    Args:
        action: the action (array, tracer or anything `numpy.shape` reads).
        num_leaves: the number of leaves, ports then batteries.
        field: the name the error message gives the action.

    Raises:
        ValueError: ``action`` has a number of entries other than ``num_leaves``.
    """
    size = int(np.prod(np.shape(action), dtype=np.int64))
    if size != num_leaves:
        raise ValueError(
            f"field '{field}' must have one entry per leaf (ports, then batteries): shape "
            f"({num_leaves},), got shape {tuple(np.shape(action))}"
        )


def to_int32(x: jnp.ndarray, low, high, idle) -> jnp.ndarray:
    """Integers in ``[low, high]`` as int32 (traceable): floats clipped (non-finite -> ``idle``),
    then truncated toward zero; integers clipped in their own dtype before the cast.

    Bools count as the integers 0 and 1; unsigned integers are only capped at ``high`` before
    the cast (they cannot be below a ``low`` of 0 or less), and every result is clipped to
    ``[low, high]`` again after it.

    Args:
        x: the action entries, any real dtype, any shape.
        low: the lowest level (scalar, or an array broadcasting against ``x``).
        high: the highest level (same).
        idle: the level a non-finite float entry becomes.

    Returns:
        An int32 array of the broadcast shape of ``x``, ``low`` and ``high``, every entry in
        ``[low, high]``.
    """
    x = jnp.asarray(x)
    if jnp.issubdtype(x.dtype, jnp.floating):
        low_f = jnp.asarray(low).astype(x.dtype)
        high_f = jnp.asarray(high).astype(x.dtype)
        x = jnp.where(
            jnp.isfinite(x), jnp.clip(x, low_f, high_f), jnp.asarray(idle).astype(x.dtype)
        )
        return x.astype(jnp.int32)
    if x.dtype == jnp.bool_:
        x = x.astype(jnp.int32)
    elif jnp.issubdtype(x.dtype, jnp.unsignedinteger):
        x = jnp.minimum(x, jnp.asarray(high).astype(x.dtype))  # high >= 0
    else:
        x = jnp.clip(x, jnp.asarray(low).astype(x.dtype), jnp.asarray(high).astype(x.dtype))
    return jnp.clip(x.astype(jnp.int32), low, high).astype(jnp.int32)


def to_fraction(x: jnp.ndarray) -> jnp.ndarray:
    """Fractions in ``[-1, 1]`` as float32 (traceable); non-finite -> 0 (idle).

    Args:
        x: the action entries, any real dtype, any shape; integers are clipped to ``[-1, 1]``
            before the cast.

    Returns:
        A float32 array of the shape of ``x``: each entry clipped to ``[-1, 1]``, NaN and
        +-inf entries 0.
    """
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = jnp.clip(x, -1, 1)
    x = x.astype(jnp.float32)
    return jnp.where(jnp.isfinite(x), jnp.clip(x, -1.0, 1.0), 0.0)


def host_array(action: Any, num_leaves: int | None = None, field: str = "action"):
    """Host-side check of an action before it enters ``jit``.

    Jax arrays and tracers pass through (only the dtype and, with ``num_leaves``, the size
    are checked). Anything else becomes a numpy array: integers are clipped to the int32
    range and cast to int32; finite floats are clipped to +-`HOST_FLOAT_BOUND` and
    cast to float32 (NaN and +-inf are kept, the traced step reads them as idle).

    Bools become int32 0 / 1 and unsigned integers are capped at the int32 maximum. An object
    array (Python integers beyond int64) is read as floats. The shape is kept.

    Args:
        action: the action as the controller emitted it: a jax array or tracer, a numpy
            array, a Python number or a (nested) sequence of numbers.
        num_leaves: the number of leaves (ports, then batteries) the action must have entries
            for; ``None`` skips the size check.
        field: the name error messages give the action.

    Returns:
        ``action`` itself when it is a jax array or tracer; otherwise a numpy array of its
        shape, int32 for bool and integer input, float32 for float input.

    Raises:
        ValueError: ``action`` is a string or bytes, cannot be read as an array, does not hold
            real numbers or bools, or (with ``num_leaves``) has another number of entries.
    """
    if isinstance(action, (jax.Array, jax.core.Tracer)):
        check_dtype(action, field)
        if num_leaves is not None:
            check_size(action, num_leaves, field)
        return action
    if isinstance(action, (str, bytes)):
        raise ValueError(
            f"field '{field}' must hold numbers (integer levels or indices, or float fractions), "
            f"got the string {_short(action)}"
        )
    try:
        arr = np.asarray(action)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ValueError(
            f"field '{field}' must be an array of numbers, got {_short(action)} ({exc})"
        ) from None
    if arr.dtype == object:
        try:  # Python ints beyond int64
            arr = np.asarray([float(v) for v in arr.reshape(-1)]).reshape(arr.shape)
        except (TypeError, ValueError):
            pass
    check_dtype(arr, field)
    if num_leaves is not None:
        check_size(arr, num_leaves, field)
    if np.issubdtype(arr.dtype, np.bool_):
        return arr.astype(np.int32)
    if np.issubdtype(arr.dtype, np.unsignedinteger):
        return np.minimum(arr, INT32_MAX).astype(np.int32)
    if np.issubdtype(arr.dtype, np.integer):
        return np.clip(arr, INT32_MIN, INT32_MAX).astype(np.int32)
    arr = arr.astype(np.float64)
    finite = np.isfinite(arr)
    return np.where(
        finite, np.clip(np.where(finite, arr, 0.0), -HOST_FLOAT_BOUND, HOST_FLOAT_BOUND), arr
    ).astype(np.float32)
