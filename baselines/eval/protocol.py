"""The car draws of the held-out protocol: which keys, and how a day's totals are averaged."""

from __future__ import annotations

import jax
import numpy as np


def draw_keys(draws: int = 1) -> list:
    """The evaluation keys of ``draws`` car draws per held-out day: ``PRNGKey(0) ... PRNGKey(draws - 1)``.
    Every policy is scored under the same keys (the same cars), and its per-day profit is the
    mean over the draws, so a paired difference's standard error over days treats the days,
    not the draws, as the independent units (the draws of one day share its prices). Draw 0
    is the single-draw evaluation's key.

    Args:
        draws: car draws per held-out day, a positive integer (not a bool).

    Returns:
        ``[PRNGKey(0), ..., PRNGKey(draws - 1)]``.

    Raises:
        ValueError: ``draws`` is not a positive integer.
    """
    if isinstance(draws, bool) or not isinstance(draws, (int, np.integer)) or int(draws) < 1:
        raise ValueError(
            f"field 'EVAL_DRAWS' (car draws per held-out day) must be a positive integer, got {draws!r}"
        )
    return [jax.random.PRNGKey(k) for k in range(int(draws))]


def mean_over_draws(evaluate, keys):
    """``evaluate(key) -> pytree of arrays`` averaged leaf by leaf over ``keys`` (one call per key).

    Args:
        evaluate: ``evaluate(key) -> pytree of arrays``, every call's pytree of the same shape.
        keys: the keys to call it with (`draw_keys`).

    Returns:
        The pytree of numpy float64 arrays: each leaf the mean over the keys.
    """
    outs = [jax.device_get(evaluate(k)) for k in keys]
    return mean_of_draws(jax.tree.map(lambda *x: np.stack(x), *outs))


def mean_of_draws(per_draw):
    """A pytree of arrays whose leading axis is the car draws, averaged over it in float64.

    Args:
        per_draw: a pytree of arrays, each of shape ``(draws, ...)``.

    Returns:
        The pytree of numpy float64 arrays of shape ``(...)``, the means over the draws.
    """
    return jax.tree.map(lambda x: np.mean(np.asarray(x, np.float64), axis=0), per_draw)
