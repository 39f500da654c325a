"""Host-side checks shared by the Gymnasium and PettingZoo wrappers: forked processes,
seeds and reset options.

**Forked processes.** JAX is multithreaded; a child made by ``os.fork()`` after the parent
started JAX's runtime inherits its locks but not its threads, and its first JAX call can
hang forever. ``gymnasium.vector.AsyncVectorEnv`` and SuperSuit's
``concat_vec_envs_v1(..., num_cpus=k)`` fork by default on Linux. Importing
`chargax_marl` registers an ``os.register_at_fork`` hook; the wrappers call
`check_not_forked` before any JAX work, so such a child fails at once with
`ForkedProcessError` instead of hanging. Use the ``spawn`` (or ``forkserver``)
start method: ``AsyncVectorEnv(fns, context="spawn")``, or
``multiprocessing.set_start_method("spawn")`` before SuperSuit's ``concat_vec_envs_v1``.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import numpy as np

_FORKED_AFTER_JAX = False


class ForkedProcessError(RuntimeError):
    """Raised in a child process forked after JAX started in its parent."""


try:  # a private JAX helper: without it, assume JAX started (the safe side)
    from jax._src import xla_bridge as _xla_bridge
except ImportError:  # pragma: no cover
    _xla_bridge = None


def _jax_started() -> bool:
    try:
        return bool(_xla_bridge.backends_are_initialized())
    except Exception:  # noqa: BLE001 - a JAX without this helper: assume started (the safe side)
        return True


def _before_fork() -> None:
    global _PARENT_STARTED
    _PARENT_STARTED = _jax_started()


def _after_fork_in_child() -> None:
    global _FORKED_AFTER_JAX
    _FORKED_AFTER_JAX = _FORKED_AFTER_JAX or _PARENT_STARTED


_PARENT_STARTED = False
if hasattr(os, "register_at_fork"):
    os.register_at_fork(before=_before_fork, after_in_child=_after_fork_in_child)


def forked_after_jax() -> bool:
    """True in a process forked (directly or not) from one where JAX had started.

    Returns:
        Whether this process descends, through ``os.fork``, from a process whose JAX runtime
        had started before the fork.
    """
    return _FORKED_AFTER_JAX


def check_not_forked(where: str) -> None:
    """Raise `ForkedProcessError` when JAX work here could deadlock (see the module doc).

    Args:
        where: the caller's name, which starts the error message.

    Raises:
        ForkedProcessError: this process was forked after JAX started in its parent
            (`forked_after_jax`).
    """
    if _FORKED_AFTER_JAX:
        raise ForkedProcessError(
            f"{where}: this process was forked (os.fork) after JAX started in its parent; JAX is "
            "multithreaded and would deadlock here. Start worker processes with the 'spawn' method "
            "instead: gymnasium.vector.AsyncVectorEnv(env_fns, context='spawn'), or "
            "multiprocessing.set_start_method('spawn') before supersuit.concat_vec_envs_v1(..., num_cpus=k) "
            "(and guard the script with if __name__ == '__main__':)."
        )


def key_from_seed(seed: Any, where: str) -> jax.Array:
    """A JAX key from any non-negative integer seed (the range Gymnasium and PettingZoo accept).

    Seeds below ``2**64`` give the key ``[seed >> 32, seed & 0xffffffff]``; for seeds below
    ``2**32`` that is ``jax.random.PRNGKey(seed)``, so existing seeds keep their trajectories.
    Larger seeds are hashed to 64 bits with `numpy.random.SeedSequence`, which reads
    the whole integer. Anything else raises ``ValueError`` naming the seed.

    Args:
        seed: the seed, a Python or numpy integer ``>= 0`` (not a bool).
        where: the caller's name, which starts the error message.

    Returns:
        A ``uint32`` key of shape ``(2,)``.

    Raises:
        ValueError: ``seed`` is not an integer, is a bool, or is negative.
    """
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"{where}: seed must be a non-negative integer or None, got {seed!r}")
    seed = int(seed)
    if seed < 0:
        raise ValueError(f"{where}: seed must be a non-negative integer or None, got {seed}")
    if seed >= 2**64:
        hi, lo = (int(x) for x in np.random.SeedSequence(seed).generate_state(2, np.uint32))
    else:
        hi, lo = seed >> 32, seed & 0xFFFFFFFF
    return jax.numpy.asarray(np.array([hi, lo], np.uint32))


def check_day(day, num_days: int) -> int:
    """``day`` as an int in ``[0, num_days)``, or ``ValueError`` naming it and the range.

    Args:
        day: the day index: a scalar (Python, numpy or JAX) whose value is a whole number.
        num_days: the number of days of the price data.

    Returns:
        ``day`` as a Python int.

    Raises:
        ValueError: ``day`` is not a scalar whole number (a string, a bool, an array with a
            dimension, a fractional value), or lies outside ``[0, num_days)``.
    """
    try:
        value = (
            int(np.asarray(day).item())
            if np.ndim(day) == 0 and not isinstance(day, (str, bytes))
            else None
        )
        if value is not None and value != np.asarray(day).item():
            value = None
    except (TypeError, ValueError):
        value = None
    if value is None or isinstance(day, (bool, np.bool_)):
        raise ValueError(
            f"day must be an integer in [0, {num_days - 1}] (the days of the price data), got {day!r}"
        )
    if not 0 <= value < num_days:
        raise ValueError(
            f"day must be in [0, {num_days - 1}] (the days of the price data), got {value}"
        )
    return value


def reset_day(options: dict | None, num_days: int, where: str) -> int | None:
    """The ``day`` reset option as an int in ``[0, num_days)``, or None when not given.

    Raises ``ValueError`` naming the option, its value and what is allowed for a bad day.
    Other keys are ignored (PettingZoo's API test passes arbitrary options).

    Args:
        options: the ``options`` of a Gymnasium or PettingZoo ``reset``, or None.
        num_days: the number of days of the price data.
        where: the caller's name, which starts the error message.

    Returns:
        ``options["day"]`` as an int, or None when ``options`` is empty or None or its
        ``"day"`` is missing or None.

    Raises:
        ValueError: ``options`` is not a dict, or its ``"day"`` is not an integer (a bool
            counts as none) in ``[0, num_days)``.
    """
    if not options:
        return None
    if not isinstance(options, dict):
        raise ValueError(f"{where}: options must be a dict or None, got {type(options).__name__}")
    if "day" not in options or options["day"] is None:
        return None
    day = options["day"]
    ok = isinstance(day, (int, np.integer)) and not isinstance(day, (bool, np.bool_))
    if not ok or not 0 <= int(day) < num_days:
        raise ValueError(
            f"{where}: options['day'] must be an integer in [0, {num_days - 1}] "
            f"(a day of the price data), got {day!r}"
        )
    return int(day)
