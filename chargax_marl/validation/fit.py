"""The session model fitted to real sessions (numpy only).

`fit_profile` turns a site's sessions into a `UserProfileData` of the session model:

* **arrival times**: the share of a day's arrivals per 5-minute slot, workdays and
  weekend days (public holidays count as weekend days), smoothed over +-15 minutes;
* **day-to-day volume**: the weekend's volume relative to workdays, each weekday's volume
  relative to its day type (`weekday_volume_factors`), and the coefficient of variation of
  the daily intensity beyond Poisson noise (`daily_volume_cv`): per period, the workday
  counts' variance around their local level (a moving median over +-`TREND_HALF_WINDOW`
  workdays) in excess of the Poisson variance, over the squared level, after dividing out
  the weekday factors; the median over the periods. A level that moves within a period (the
  spring of 2020) is not day-to-day dispersion, and the model does not reproduce it;
* **stays and energies by arrival hour**: for every hour, the quantiles of the stays and of
  the delivered energies of the sessions that arrived within a window around it, widened
  until it holds `MIN_SESSIONS_PER_HOUR` sessions. The realised stays of the data already
  contain the users who leave when charged, so every AC user of the fitted profile leaves
  at the end of its stay (``charge_sensitive_prob = 0``);
* **stay and energy together**: within an arrival hour, longer stays take more energy; the
  profile's Gaussian copula joins the two draws with the correlation of the data's rank
  correlation within the hours' windows (`stay_demand_corr`);
* **requests**: the quantiles of delivered over requested energy (1 where the user entered
  no request), so that a car's request is its energy over a draw of the ratio.
"""

from __future__ import annotations

import numpy as np

from chargax_marl.core import calendar_days
from chargax_marl.core.data_io import HOURS_PER_DAY, QUANTILE_PROBS, SLOTS_PER_DAY
from chargax_marl.core.profiles import UserProfileData, make_user_profile
from chargax_marl.validation.real import PERIODS, Sessions, weekday

TREND_HALF_WINDOW = 7
"""Workdays on either side of a day in the moving median that sets its local level."""
MIN_SESSIONS_PER_HOUR = 300
"""The fewest sessions behind one arrival hour's stay and energy tables."""
SMOOTH_KERNEL = np.array([1, 2, 3, 4, 3, 2, 1], dtype=float)
"""Circular smoothing of the arrival histograms (+-15 minutes at 5-minute slots)."""
STAY_RANGE_MIN = (5.0, 1440.0)
"""Stays are clipped to one step and one day."""
MIN_ENERGY_KWH = 0.1
MIN_REQUEST_RATIO = 0.01
ARRIVAL_SOC_RANGE = (0.3, 0.7)
"""Arrival SoC range of the fitted profiles (the data has no SoC; an assumption)."""


def smooth(v: np.ndarray) -> np.ndarray:
    """``v`` (a histogram over the day's slots) smoothed circularly with `SMOOTH_KERNEL`.

    Args:
        v: ``(slots,)`` a histogram over the day's slots (the last slot wraps to the first).

    Returns:
        ``(slots,)`` the smoothed histogram (the kernel is normalised, so the sum is kept).
    """
    k = SMOOTH_KERNEL / SMOOTH_KERNEL.sum()
    half = len(k) // 2
    return sum(k[i] * np.roll(v, i - half) for i in range(len(k)))


def day_types(sessions: Sessions, country: str = "US"):
    """Every day of the sessions' periods with its count of arrivals.

    Args:
        sessions: real sessions.
        country: whose public holidays count as weekend days.

    Returns:
        ``(dates, counts, weekdays, workday, period)``: ``(D,)`` arrays over the days.
    """
    dates = sessions.days()
    first = str(dates[0])
    holiday_all = calendar_days.holiday_days(
        country, first, int((dates[-1] - dates[0]).astype(int)) + 1
    )
    holiday = holiday_all[(dates - dates[0]).astype(int)]
    wd = weekday(dates)
    workday = (wd < 5) & ~holiday
    idx = np.searchsorted(dates, sessions.arrival_date)
    inside = (idx < dates.shape[0]) & (
        dates[np.minimum(idx, dates.shape[0] - 1)] == sessions.arrival_date
    )
    counts = np.bincount(idx[inside], minlength=dates.shape[0]).astype(float)
    period = np.empty(dates.shape[0], dtype=object)
    for p in sessions.periods:
        first_p, last_p = (np.datetime64(x, "D") for x in PERIODS[p])
        period[(dates >= first_p) & (dates <= last_p)] = p
    return dates, counts, wd, workday, period


def volume_fit(sessions: Sessions, country: str = "US") -> dict:
    """The day-to-day volume of the sessions' days.

    Args:
        sessions: real sessions.
        country: whose public holidays count as weekend days.

    Returns:
        ``weekend_volume_factor``, ``weekday_volume_factors`` (7,), ``daily_volume_cv`` and
        the per-period ``cv_by_period``.
    """
    dates, counts, wd, workday, period = day_types(sessions, country)
    weekend = ~workday
    mean_work = counts[workday].mean()
    mean_weekend = counts[weekend].mean() if weekend.any() else mean_work
    factors = np.ones(7)
    for w in range(7):
        days = (wd == w) & (workday if w < 5 else (wd >= 5))
        if days.any():
            factors[w] = counts[days].mean() / (mean_work if w < 5 else mean_weekend)
    factors[:5] /= factors[:5].mean()
    factors[5:] /= factors[5:].mean()
    cv2 = {}
    for p in sessions.periods:
        days = workday & (period == p)
        x = counts[days] / factors[wd[days]]
        if x.size > 2 * TREND_HALF_WINDOW and x.mean() > 0:
            # day-to-day variation around the period's local level (a moving median), so that
            # a level that moves within the period is not read as dispersion
            level = np.array(
                [
                    np.median(x[max(0, i - TREND_HALF_WINDOW) : i + TREND_HALF_WINDOW + 1])
                    for i in range(x.size)
                ]
            )
            # the Poisson variance of a count divided by its weekday factor f is level / f
            poisson = (level / factors[wd[days]]).mean()
            excess = (x - level).var(ddof=1) - poisson
            cv2[p] = max(excess / level.mean() ** 2, 0.0)
    return {
        "weekend_volume_factor": float(mean_weekend / mean_work),
        "weekday_volume_factors": factors,
        "daily_volume_cv": float(np.sqrt(np.median(list(cv2.values())))) if cv2 else 0.0,
        "cv_by_period": {p: float(np.sqrt(v)) for p, v in cv2.items()},
    }


def hour_windows(hours: np.ndarray, minimum: int = MIN_SESSIONS_PER_HOUR) -> list[np.ndarray]:
    """For each hour 0..23, the sessions whose arrival hour lies within a window around it
    (circular), the narrowest holding at least ``minimum`` sessions (all of them if fewer).

    Args:
        hours: ``(n,)`` arrival hours (fractional).
        minimum: the fewest sessions per window.

    Returns:
        24 boolean masks over the sessions.
    """
    hour = np.floor(hours).astype(int) % HOURS_PER_DAY
    out = []
    for h in range(HOURS_PER_DAY):
        for width in range(0, 13):
            dist = np.minimum((hour - h) % 24, (h - hour) % 24)
            mask = dist <= width
            if mask.sum() >= minimum:
                break
        out.append(mask)
    return out


def _ranks(x: np.ndarray) -> np.ndarray:
    """Ranks from 0 with ties at their mean rank."""
    _, inverse, counts = np.unique(x, return_inverse=True, return_counts=True)
    return (np.cumsum(counts) - (counts + 1) / 2.0)[inverse]


def rank_corr(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation of two samples (ties at their mean rank; 0 when either
    is constant).

    Args:
        a: ``(n,)`` the first sample.
        b: ``(n,)`` the second sample, paired with ``a``.

    Returns:
        The rank correlation, in [-1, 1].
    """
    ra, rb = _ranks(np.asarray(a)), _ranks(np.asarray(b))
    ra, rb = ra - ra.mean(), rb - rb.mean()
    norm = np.sqrt((ra**2).sum() * (rb**2).sum())
    return float((ra * rb).sum() / norm) if norm > 0 else 0.0


def stay_demand_corr(
    stays: np.ndarray, energies: np.ndarray, hours: np.ndarray, windows: list[np.ndarray]
) -> float:
    """The Gaussian copula's correlation between a session's stay and its energy within its
    arrival hour: Spearman's rank correlation in each hour's window, averaged with the
    weights of the sessions' arrival hours, as the normal correlation of that rank
    correlation (``2 sin(pi r / 6)``).

    Args:
        stays: ``(n,)`` stays (minutes).
        energies: ``(n,)`` energies (kWh).
        hours: ``(n,)`` arrival hours (fractional).
        windows: `hour_windows` of ``hours``.

    Returns:
        The correlation, in (-1, 1).
    """
    weights = np.bincount(np.floor(hours).astype(int) % HOURS_PER_DAY, minlength=HOURS_PER_DAY)
    r = np.array([rank_corr(stays[w], energies[w]) if w.sum() > 2 else 0.0 for w in windows])
    r_mean = float(np.average(r, weights=weights)) if weights.sum() > 0 else 0.0
    return float(np.clip(2.0 * np.sin(np.pi * r_mean / 6.0), -0.99, 0.99))


def quantiles(values: np.ndarray) -> np.ndarray:
    """The non-decreasing quantile table of ``values`` at `QUANTILE_PROBS`.

    Args:
        values: a sample (any shape, flattened).

    Returns:
        ``(len(QUANTILE_PROBS),)`` float64 quantiles, made non-decreasing by a running
        maximum.
    """
    return np.maximum.accumulate(np.quantile(np.asarray(values, np.float64), QUANTILE_PROBS))


def fit_profile(
    sessions: Sessions,
    name: str,
    country: str = "US",
    minimum_per_hour: int = MIN_SESSIONS_PER_HOUR,
) -> UserProfileData:
    """The session model's profile fitted to real sessions (see the module docstring).

    Args:
        sessions: real sessions (`chargax_marl.validation.real`).
        name: the profile's name.
        country: whose public holidays count as weekend days.
        minimum_per_hour: the fewest sessions behind one arrival hour's tables.

    Returns:
        The fitted `UserProfileData`.

    Raises:
        ValueError: fewer sessions than ``minimum_per_hour``.
    """
    if len(sessions) < minimum_per_hour:
        raise ValueError(
            f"sessions: {len(sessions)} sessions, fewer than minimum_per_hour={minimum_per_hour}"
        )
    dates, _, _, workday, _ = day_types(sessions, country)
    is_work = workday[np.searchsorted(dates, sessions.arrival_date)]
    slot = (sessions.arrival_hour * 60 // 5).astype(int) % SLOTS_PER_DAY
    weights = []
    for rows in (is_work, ~is_work):
        hist = np.bincount(slot[rows], minlength=SLOTS_PER_DAY).astype(float)
        if hist.sum() == 0:
            hist = np.bincount(slot, minlength=SLOTS_PER_DAY).astype(float)
        weights.append(smooth(hist) / hist.sum())
    volume = volume_fit(sessions, country)
    stays = np.clip(sessions.stay_min, *STAY_RANGE_MIN)
    energy = np.maximum(sessions.delivered_kwh, MIN_ENERGY_KWH)
    windows = hour_windows(sessions.arrival_hour, minimum_per_hour)
    stay_table = np.stack([quantiles(stays[m]) for m in windows])
    energy_table = np.stack([quantiles(energy[m]) for m in windows])
    return make_user_profile(
        name,
        np.stack(weights),
        stay_table,
        energy_table,
        weekend_volume_factor=volume["weekend_volume_factor"],
        arrival_soc_range=ARRIVAL_SOC_RANGE,
        charge_sensitive_prob=0.0,
        dc_charge_sensitive_prob=1.0,
        request_ratio_quantiles=quantiles(request_ratios(sessions)),
        daily_volume_cv=volume["daily_volume_cv"],
        weekday_volume_factors=volume["weekday_volume_factors"],
        stay_demand_corr=stay_demand_corr(stays, energy, sessions.arrival_hour, windows),
    )


def request_ratios(sessions: Sessions) -> np.ndarray:
    """Delivered over requested energy per session, in [`MIN_REQUEST_RATIO`, 1] (1 where
    the user entered no request).

    Args:
        sessions: real sessions.

    Returns:
        ``(n,)`` ratios.
    """
    ratio = np.where(
        sessions.entered_request,
        sessions.delivered_kwh / np.maximum(sessions.requested_kwh, 1e-9),
        1.0,
    )
    return np.clip(ratio, MIN_REQUEST_RATIO, 1.0)


def conditional_tables(
    pooled: np.ndarray, scale_by_hour: np.ndarray, hour_weights: np.ndarray
) -> np.ndarray:
    """Quantile tables per arrival hour whose mixture over the arrival hours is ``pooled``.

    Where a data source gives only the pooled distribution and the mean per arrival hour
    (the ElaadNL tables), a value drawn as ``pooled sample * scale_by_hour[h]`` follows the
    hours' means but its mixture is wider than the pooled distribution. The monotone map
    ``T = Q_pooled o F_mix`` (``F_mix`` the CDF of that mixture) takes the mixture back onto
    the pooled distribution and keeps every hour's rank order; the table of hour ``h`` is
    ``T(pooled * scale_by_hour[h])``.

    Args:
        pooled: ``(Q,)`` the pooled quantile table at `QUANTILE_PROBS`.
        scale_by_hour: ``(24,)`` positive factors (the hour's mean over the overall mean).
        hour_weights: ``(24,)`` the share of arrivals per hour (sums to 1).

    Returns:
        ``(24, Q)`` non-decreasing tables.
    """
    pooled = np.asarray(pooled, np.float64)
    probs = QUANTILE_PROBS.astype(np.float64)
    # strictly increasing support for the CDF (ties of the table get a tiny slope)
    support = pooled + np.arange(pooled.size) * 1e-9 * max(pooled[-1], 1.0)
    scaled = pooled[None, :] * scale_by_hour[:, None]
    grid = np.unique(np.concatenate([scaled.ravel(), support]))
    f_mix = sum(
        w * np.interp(grid / s, support, probs, left=0.0, right=1.0)
        for w, s in zip(hour_weights, scale_by_hour, strict=True)
    )
    mapped = np.interp(np.interp(scaled.ravel(), grid, f_mix), probs, pooled)
    return np.maximum.accumulate(mapped.reshape(scaled.shape), axis=1)
