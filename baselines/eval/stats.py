"""Paired statistics: a policy against a reference on the same days and cars."""

from __future__ import annotations

import numpy as np


def mean_stderr(x) -> tuple[float, float]:
    """``(mean, standard error of the mean)`` of a sample.

    Args:
        x: the sample, e.g. per-day differences in EUR/day.

    Returns:
        The mean and ``std(ddof=1) / sqrt(n)``.
    """
    x = np.asarray(x, np.float64)
    return float(x.mean()), float(x.std(ddof=1) / np.sqrt(x.size))


def paired_difference(profit, reference_profit) -> dict:
    """Per seed, mean and standard error over days of ``profit (seeds, days) - reference (days,)``;
    and the mean over seeds with the standard error of that mean over seeds × days.

    A day with a NaN on either side (a failed solve of the LP bound or the MPC) is left out for
    every seed, so the pairs stay on the same days, and counted in ``days_excluded`` (present
    only when some are).

    Args:
        profit: ``(seeds, days)`` or ``(days,)`` daily profits in EUR/day.
        reference_profit: ``(days,)`` daily profits of the reference in EUR/day.

    Returns:
        ``{"per_seed_mean", "per_seed_stderr", "mean", "stderr"}`` in EUR/day (lists per
        seed, then floats), plus ``days_excluded`` when NaN days were left out.
    """
    d = (
        np.atleast_2d(np.asarray(profit, np.float64))
        - np.asarray(reference_profit, np.float64)[None, :]
    )
    keep = np.isfinite(d).all(axis=0)
    d = d[:, keep]
    n = d.shape[1]
    out = {
        "per_seed_mean": [float(x) for x in d.mean(axis=1)],
        "per_seed_stderr": [float(x) for x in d.std(axis=1, ddof=1) / np.sqrt(n)],
        "mean": float(d.mean()),
        "stderr": float(d.std(ddof=1) / np.sqrt(d.size)),
    }
    if not keep.all():
        out["days_excluded"] = int(keep.size - keep.sum())
    return out


def beats(paired: dict) -> bool:
    """Significantly better than the reference: the paired mean difference over seeds × days
    exceeds two standard errors.

    Args:
        paired: a `paired_difference` result.

    Returns:
        Whether ``mean > 2 * stderr``.
    """
    return paired["mean"] > 2.0 * paired["stderr"]


def seed_beats(paired: dict, i: int) -> bool:
    """Seed ``i`` is significantly better than the reference on the held-out days (its mean paired
    difference exceeds two standard errors over days).

    Args:
        paired: a `paired_difference` result.
        i: the seed's index.

    Returns:
        Whether ``per_seed_mean[i] > 2 * per_seed_stderr[i]``.
    """
    return paired["per_seed_mean"][i] > 2.0 * paired["per_seed_stderr"][i]


def over_seeds(values) -> dict:
    """Mean and standard error over seeds of per-seed numbers (``stderr`` is NaN for one seed).

    Args:
        values: one number per seed.

    Returns:
        ``{"mean", "stderr", "min", "max", "all_seeds_positive"}``.
    """
    v = np.asarray(values, np.float64)
    return {
        "mean": float(v.mean()),
        "stderr": float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else float("nan"),
        "min": float(v.min()),
        "max": float(v.max()),
        "all_seeds_positive": bool(np.all(v > 0)),
    }


def day_clustered(diff: np.ndarray) -> dict:
    """``diff`` ``(draws, days)`` of one seed: mean, standard error over days of the per-day mean
    over draws, and whether the mean exceeds two standard errors.

    Args:
        diff: ``(draws, days)`` paired differences of one seed.

    Returns:
        ``{"mean", "stderr", "beats"}``.
    """
    per_day = np.asarray(diff, np.float64).mean(axis=0)
    stderr = float(per_day.std(ddof=1) / np.sqrt(per_day.size))
    mean = float(per_day.mean())
    return {"mean": mean, "stderr": stderr, "beats": bool(mean > 2.0 * stderr)}


def paired_over_seeds(a, b) -> dict:
    """``a - b`` seed against seed (the same days and cars): mean ± standard error over seeds,
    with the per-seed differences. ``(seeds, days)`` arrays are first averaged over days.

    Args:
        a: ``(seeds,)`` or ``(seeds, days)`` numbers of the first policy.
        b: the same for the second policy, seed for seed.

    Returns:
        `over_seeds` of the differences, plus ``per_seed``: the list of per-seed differences.
    """
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    d = d.mean(axis=1) if d.ndim == 2 else d
    return {**over_seeds(d), "per_seed": d.tolist()}
