"""User profiles (arrival weights, stay and demand quantiles) and traffic levels. Every path
(bundled name, overrides, custom arrays) goes through `make_user_profile`; traffic
through `traffic_cars_per_day`.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np

from chargax_marl.core import checks
from chargax_marl.core.data_io import (
    ALL_USER_PROFILES,
    DATA_DIR,
    HOURS_PER_DAY,
    NUM_QUANTILES,
    QUANTILE_PROBS,
    SESSION_MODELS,
    SLOTS_PER_DAY,
    TRAFFIC_LEVELS,
    US_USER_PROFILES,
    US_USER_PROFILES_FILE,
    USER_PROFILES_FILE,
    USER_PROFILES_V2_FILE,
    _as_float_array,
    _check_bounds,
    _check_finite,
    _readonly,
    _validate_name,
    _validate_unit_scalar,
)


def traffic_cars_per_day(traffic: str | float) -> float:
    """Mean number of arriving cars per day: a level name or a positive number.

    Args:
        traffic: a level of `TRAFFIC_LEVELS` (``"low"``, ``"medium"``, ``"high"``) or a
            number of cars per day in ``(0, checks.MAX_CARS_PER_DAY]``.

    Returns:
        The cars per day as a float.

    Raises:
        KeyError: ``traffic`` is a string that is not a level's name.
        ValueError: ``traffic`` is a bool or not a real number, not finite, <= 0, or above
            ``checks.MAX_CARS_PER_DAY``.
    """
    if isinstance(traffic, str):
        if traffic not in TRAFFIC_LEVELS:
            raise KeyError(
                f"traffic: unknown level {traffic!r}; valid levels are {sorted(TRAFFIC_LEVELS)} or a positive number"
            )
        return float(TRAFFIC_LEVELS[traffic])
    if isinstance(traffic, bool) or not isinstance(traffic, numbers.Real):
        raise ValueError(
            f"traffic: expected one of {sorted(TRAFFIC_LEVELS)} or a positive number of cars per day, got {traffic!r}"
        )
    value = float(traffic)
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(
            f"traffic: cars per day must be a finite number > 0 (at most {checks.MAX_CARS_PER_DAY:g}), "
            f"got {traffic!r}"
        )
    if value > checks.MAX_CARS_PER_DAY:
        raise ValueError(
            f"traffic: cars per day must be <= {checks.MAX_CARS_PER_DAY:g} (the per-step arrival draw is "
            f"int32), got {traffic!r}"
        )
    return value


@dataclass(frozen=True)
class UserProfileData:
    """Where cars arrive and how their users behave.

    ``arrival_weights`` (float32, (2, 288)): share of a day's arrivals per
    5-minute slot, row 0 workday, row 1 weekend; each row sums to 1. The weekend
    daily volume is ``weekend_volume_factor`` times the workday volume.
    ``stay_quantiles_min`` / ``demand_quantiles_kwh`` (float32, (101,) or (24, 101)):
    inverse CDFs at probabilities 0, 0.01, ..., 1 of the stay (minutes) and of
    the energy the car takes (kWh), one table for every arrival hour or one per
    arrival hour (the conditional distributions); ``*_scale_by_hour`` (float32, (24,))
    multiply a sample by the arrival hour's factor. ``arrival_soc_range``: uniform range
    of the arrival SoC; ``charge_sensitive_prob``: P(u = 1) at AC ports, i.e. the user
    leaves when charged rather than at the end of the stay; ``dc_charge_sensitive_prob``:
    the same at DC ports (None: ``charge_sensitive_prob``).

    ``request_ratio_quantiles`` (float32, (101,), values in (0, 1]): inverse CDF of the
    ratio of the energy a car takes to the energy its user asks for; the user's request is
    the car's energy over a draw of it (all ones: users ask for what their car takes).
    ``daily_volume_cv``: coefficient of variation of a day's arrival intensity (a
    log-normal factor drawn once per episode, mean 1; 0: every day has the same Poisson
    rate). ``weekday_volume_factors`` (float32, (7,), Monday first): the volume of each
    weekday relative to its day type's (mean 1 over Monday-Friday and over the weekend).
    ``stay_demand_corr``: the correlation of the Gaussian copula that joins a car's stay
    and its energy draws (0: independent; in (-1, 1)).

    Build it with `make_user_profile` (or `load_user_profile`), which validates the fields
    and makes the arrays read-only; the constructor itself checks nothing.

    Attributes:
        name: the profile's name.
        arrival_weights: ``(2, 288)`` float32 share of a day's arrivals per 5-minute slot;
            row 0 workday, row 1 weekend, each summing to 1.
        weekend_volume_factor: the weekend daily volume over the workday volume.
        stay_quantiles_min: ``(101,)`` or ``(24, 101)`` float32 inverse CDF of the planned
            stay (minutes), for all arrival hours or per arrival hour.
        stay_scale_by_hour: ``(24,)`` float32 multiplier of a stay by arrival hour.
        demand_quantiles_kwh: ``(101,)`` or ``(24, 101)`` float32 inverse CDF of the energy
            the car takes (kWh).
        demand_scale_by_hour: ``(24,)`` float32 multiplier of a demand by arrival hour.
        arrival_soc_range: ``(lo, hi)`` bounds of the uniform arrival SoC.
        charge_sensitive_prob: P(u = 1) at AC ports, in [0, 1].
        dc_charge_sensitive_prob: P(u = 1) at DC ports, or ``None`` for
            ``charge_sensitive_prob`` (see the property ``dc_charge_sensitive``).
        request_ratio_quantiles: ``(101,)`` float32 inverse CDF of taken over requested
            energy, in (0, 1]; ``None``: all ones (see ``request_ratios``).
        daily_volume_cv: coefficient of variation of a day's arrival intensity, in
            ``[0, MAX_VOLUME_CV]``.
        weekday_volume_factors: ``(7,)`` float32 volume of each weekday, Monday first;
            ``None``: all ones (see ``weekday_factors``).
        stay_demand_corr: the copula correlation of stay and demand, in (-1, 1).
    """

    name: str
    arrival_weights: np.ndarray
    weekend_volume_factor: float
    stay_quantiles_min: np.ndarray
    stay_scale_by_hour: np.ndarray
    demand_quantiles_kwh: np.ndarray
    demand_scale_by_hour: np.ndarray
    arrival_soc_range: tuple[float, float]
    charge_sensitive_prob: float
    dc_charge_sensitive_prob: float | None = None
    request_ratio_quantiles: np.ndarray | None = None
    daily_volume_cv: float = 0.0
    weekday_volume_factors: np.ndarray | None = None
    stay_demand_corr: float = 0.0

    @property
    def dc_charge_sensitive(self) -> float:
        """P(u = 1) at DC ports."""
        if self.dc_charge_sensitive_prob is None:
            return self.charge_sensitive_prob
        return self.dc_charge_sensitive_prob

    @property
    def stay_table_min(self) -> np.ndarray:
        """The stay quantiles per arrival hour, (24, 101) minutes (before the hourly scale)."""
        return _by_hour(self.stay_quantiles_min)

    @property
    def demand_table_kwh(self) -> np.ndarray:
        """The demand quantiles per arrival hour, (24, 101) kWh (before the hourly scale)."""
        return _by_hour(self.demand_quantiles_kwh)

    @property
    def stay_marginal_min(self) -> np.ndarray:
        """The stay quantiles over a workday's arrivals, (101,) minutes (`marginal_quantiles`)."""
        return marginal_quantiles(self.stay_table_min, self.stay_scale_by_hour, self.hour_weights)

    @property
    def demand_marginal_kwh(self) -> np.ndarray:
        """The demand quantiles over a workday's arrivals, (101,) kWh (`marginal_quantiles`)."""
        return marginal_quantiles(
            self.demand_table_kwh, self.demand_scale_by_hour, self.hour_weights
        )

    @property
    def hour_weights(self) -> np.ndarray:
        """The share of a workday's arrivals per hour, (24,)."""
        return self.arrival_weights[0].reshape(HOURS_PER_DAY, -1).sum(axis=1)

    @property
    def request_ratios(self) -> np.ndarray:
        """``request_ratio_quantiles`` with its default (all ones), (101,)."""
        if self.request_ratio_quantiles is None:
            return np.ones(NUM_QUANTILES, np.float32)
        return self.request_ratio_quantiles

    @property
    def weekday_factors(self) -> np.ndarray:
        """``weekday_volume_factors`` with its default (all ones), (7,)."""
        if self.weekday_volume_factors is None:
            return np.ones(7, np.float32)
        return self.weekday_volume_factors


def marginal_quantiles(
    table: np.ndarray, scale_by_hour: np.ndarray, hour_weights: np.ndarray
) -> np.ndarray:
    """The quantiles of a value drawn from the table of a random arrival hour.

    Args:
        table: ``(24, Q)`` quantile tables per arrival hour, at evenly spaced probabilities.
        scale_by_hour: ``(24,)`` factors on each hour's draws.
        hour_weights: ``(24,)`` the share of arrivals per hour (sums to 1).

    Returns:
        ``(Q,)`` the mixture's quantiles at the same probabilities.
    """
    values = np.asarray(table, np.float64) * np.asarray(scale_by_hour, np.float64)[:, None]
    probs = np.linspace(0.0, 1.0, values.shape[1])
    grid = np.unique(values)
    cdf = sum(
        w * np.interp(grid, row, probs, left=0.0, right=1.0)
        for w, row in zip(np.asarray(hour_weights, np.float64), values, strict=True)
    )
    cdf = np.maximum.accumulate(cdf / max(float(np.sum(hour_weights)), 1e-12))
    return np.interp(probs, cdf, grid).astype(np.float32)


def _by_hour(table: np.ndarray) -> np.ndarray:
    if table.ndim == 1:
        return np.broadcast_to(table, (HOURS_PER_DAY, table.shape[0])).astype(np.float32)
    return table


_PROFILE_FIELDS = tuple(f.name for f in dataclasses.fields(UserProfileData))


def _validate_weights(value: Any, field: str = "arrival_weights") -> np.ndarray:
    arr = _as_float_array(value, field)
    shapes = "(288,), (2, 288), (24,) or (2, 24)"
    if arr.ndim == 1:
        arr = np.stack([arr, arr])
    if arr.ndim != 2 or arr.shape[0] != 2 or arr.shape[1] not in (SLOTS_PER_DAY, HOURS_PER_DAY):
        raise ValueError(f"{field}: expected shape {shapes}, got {tuple(np.shape(value))}")
    _check_finite(arr, field)
    if (arr < 0).any():
        raise ValueError(f"{field}: weights must be >= 0, got {float(arr.min())!r}")
    if arr.shape[1] == HOURS_PER_DAY:  # hourly -> 5-minute slots, each hour split evenly
        arr = np.repeat(arr, SLOTS_PER_DAY // HOURS_PER_DAY, axis=1)
    sums = arr.sum(axis=1)
    for r, s in enumerate(sums):
        if not s > 0:
            raise ValueError(
                f"{field}: row {r} ({'workday' if r == 0 else 'weekend'}) must have a positive sum, got {float(s)!r}"
            )
    return (arr / sums[:, None]).astype(np.float32)


def _validate_quantiles(value: Any, field: str, by_hour: bool = False) -> np.ndarray:
    arr = _as_float_array(value, field)
    if by_hour and arr.ndim == 2 and arr.shape[0] == HOURS_PER_DAY:
        return np.stack([_validate_quantiles(row, f"{field}[{h}]") for h, row in enumerate(arr)])
    if arr.ndim != 1 or arr.shape[0] < 2:
        per_hour = f" or one per arrival hour ({HOURS_PER_DAY}, {NUM_QUANTILES})" if by_hour else ""
        raise ValueError(
            f"{field}: expected a 1-D quantile table ({NUM_QUANTILES},) (or >= 2 evenly spaced "
            f"quantiles){per_hour}, got shape {tuple(arr.shape)}"
        )
    _check_finite(arr, field)
    if (arr < 0).any():
        raise ValueError(f"{field}: quantiles must be >= 0, got {float(arr.min())!r}")
    if (np.diff(arr) < 0).any():
        i = int(np.argmax(np.diff(arr) < 0))
        raise ValueError(
            f"{field}: quantiles must be non-decreasing, got {float(arr[i])!r} then {float(arr[i + 1])!r} at index {i + 1}"
        )
    base = field.split("[")[0]
    high, unit = (
        (checks.MAX_STAY_MIN, "min") if base.endswith("_min") else (checks.MAX_DEMAND_KWH, "kWh")
    )
    _check_bounds(arr, field, 0.0, high, unit)
    if arr.shape[0] != NUM_QUANTILES:
        arr = np.interp(QUANTILE_PROBS, np.linspace(0.0, 1.0, arr.shape[0]), arr)
    return arr.astype(np.float32)


def _positive_factors(value: Any, field: str, n: int, note: str = "") -> np.ndarray:
    """Positive finite factors of shape ``(n,)``, at most `checks.MAX_FACTOR` (``note`` says
    in the shape error what the entries are)."""
    arr = _as_float_array(value, field)
    if arr.shape != (n,):
        raise ValueError(f"{field}: expected shape ({n},){note}, got {tuple(arr.shape)}")
    _check_finite(arr, field)
    if (arr <= 0).any():
        raise ValueError(f"{field}: factors must be > 0, got {float(arr.min())!r}")
    _check_bounds(arr, field, 0.0, checks.MAX_FACTOR, low_open=True)
    return arr.astype(np.float32)


def _validate_scale(value: Any, field: str) -> np.ndarray:
    if value is None:
        return np.ones(HOURS_PER_DAY, dtype=np.float32)
    return _positive_factors(value, field, HOURS_PER_DAY)


def _validate_request_ratios(value: Any) -> np.ndarray | None:
    field = "request_ratio_quantiles"
    if value is None:
        return None
    arr = _validate_quantiles(value, field)
    if not (arr > 0).all() or not (arr <= 1).all():
        raise ValueError(
            f"{field}: ratios of the energy taken to the energy requested must lie in (0, 1], "
            f"got values in [{float(arr.min())!r}, {float(arr.max())!r}]"
        )
    return arr


def _validate_weekday_factors(value: Any) -> np.ndarray | None:
    if value is None:
        return None
    return _positive_factors(value, "weekday_volume_factors", 7, " (Monday first)")


MAX_VOLUME_CV = 10.0
"""The largest coefficient of variation of the daily arrival intensity a profile may set."""


def _validate_volume_cv(value: Any) -> float:
    v = _validate_unit_scalar(value, "daily_volume_cv", upper=None)
    if v > MAX_VOLUME_CV:
        raise ValueError(
            f"daily_volume_cv: expected a value in [0, {MAX_VOLUME_CV:g}], got {value!r}"
        )
    return v


def _validate_corr(value: Any, field: str = "stay_demand_corr") -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{field}: expected a number in (-1, 1), got {value!r}") from None
    if not -1.0 < v < 1.0:  # also refuses NaN
        raise ValueError(f"{field}: expected a number in (-1, 1), got {value!r}")
    return v


def _validate_weekend_factor(value: Any) -> float:
    v = _validate_unit_scalar(value, "weekend_volume_factor", upper=None)
    if v > checks.MAX_FACTOR:
        raise ValueError(
            f"weekend_volume_factor: expected a value in [0, {checks.MAX_FACTOR:g}], got {value!r}"
        )
    return v


def _validate_soc_range(value: Any) -> tuple[float, float]:
    field = "arrival_soc_range"
    try:
        lo, hi = value
    except (TypeError, ValueError):
        raise ValueError(
            f"{field}: expected a pair (lo, hi) with 0 <= lo <= hi < 1, got {value!r}"
        ) from None
    lo = _validate_unit_scalar(lo, field, hi_open=True)
    hi = _validate_unit_scalar(hi, field, hi_open=True)
    if lo > hi:
        raise ValueError(f"{field}: expected lo <= hi with 0 <= lo <= hi < 1, got {value!r}")
    return (lo, hi)


def make_user_profile(
    name: str,
    arrival_weights: Any,
    stay_quantiles_min: Any,
    demand_quantiles_kwh: Any,
    *,
    weekend_volume_factor: float = 1.0,
    stay_scale_by_hour: Any = None,
    demand_scale_by_hour: Any = None,
    arrival_soc_range: tuple[float, float] = (0.2, 0.6),
    charge_sensitive_prob: float = 0.0,
    dc_charge_sensitive_prob: float | None = None,
    request_ratio_quantiles: Any = None,
    daily_volume_cv: float = 0.0,
    weekday_volume_factors: Any = None,
    stay_demand_corr: float = 0.0,
) -> UserProfileData:
    """Build and validate a custom user profile.

    Args:
        name: the profile's name.
        arrival_weights: shape (288,) (same for workdays and weekends), (2, 288)
            (workday, weekend), or hourly (24,) / (2, 24), which is spread evenly over
            the hour's twelve 5-minute slots; non-negative, re-normalised per row.
        stay_quantiles_min: inverse CDF of the planned stay (minutes) at evenly spaced
            probabilities from 0 to 1 (101 entries, or any length >= 2, resampled linearly
            to 101), non-negative, non-decreasing, finite; or one such table per arrival
            hour, shape (24, n).
        demand_quantiles_kwh: the same for the energy the car takes (kWh).
        weekend_volume_factor: weekend daily volume over the workday volume.
        stay_scale_by_hour: (24,) positive multipliers of a stay by arrival hour (default
            all ones).
        demand_scale_by_hour: the same for the demand.
        arrival_soc_range: ``(lo, hi)`` with ``0 <= lo <= hi < 1``.
        charge_sensitive_prob: P(the user leaves when charged) at AC ports, in [0, 1].
        dc_charge_sensitive_prob: the same at DC ports; None: ``charge_sensitive_prob``.
        request_ratio_quantiles: inverse CDF (like the stay table) of the energy a car takes
            over the energy its user requests, values in (0, 1]; None: all ones.
        daily_volume_cv: coefficient of variation of the day's arrival intensity, in
            [0, 10] (0: Poisson arrivals with a fixed daily rate).
        weekday_volume_factors: (7,) positive, Monday first; None: all ones.
        stay_demand_corr: correlation in (-1, 1) of the Gaussian copula that joins a car's
            stay and energy draws within its arrival hour (0: drawn independently).

    Returns:
        The validated `UserProfileData` (arrays float32, read-only).

    Raises:
        ValueError: a field is out of range or has the wrong shape; the message names it.
    """
    return UserProfileData(
        name=_validate_name(name),
        arrival_weights=_readonly(_validate_weights(arrival_weights)),
        weekend_volume_factor=_validate_weekend_factor(weekend_volume_factor),
        stay_quantiles_min=_readonly(
            _validate_quantiles(stay_quantiles_min, "stay_quantiles_min", by_hour=True)
        ),
        stay_scale_by_hour=_readonly(_validate_scale(stay_scale_by_hour, "stay_scale_by_hour")),
        demand_quantiles_kwh=_readonly(
            _validate_quantiles(demand_quantiles_kwh, "demand_quantiles_kwh", by_hour=True)
        ),
        demand_scale_by_hour=_readonly(
            _validate_scale(demand_scale_by_hour, "demand_scale_by_hour")
        ),
        arrival_soc_range=_validate_soc_range(arrival_soc_range),
        charge_sensitive_prob=_validate_unit_scalar(charge_sensitive_prob, "charge_sensitive_prob"),
        dc_charge_sensitive_prob=None
        if dc_charge_sensitive_prob is None
        else _validate_unit_scalar(dc_charge_sensitive_prob, "dc_charge_sensitive_prob"),
        request_ratio_quantiles=_readonly_or_none(
            _validate_request_ratios(request_ratio_quantiles)
        ),
        daily_volume_cv=_validate_volume_cv(daily_volume_cv),
        weekday_volume_factors=_readonly_or_none(_validate_weekday_factors(weekday_volume_factors)),
        stay_demand_corr=_validate_corr(stay_demand_corr),
    )


def _readonly_or_none(arr: np.ndarray | None) -> np.ndarray | None:
    return None if arr is None else _readonly(arr)


def _profile_from_fields(fields: dict[str, Any]) -> UserProfileData:
    f = dict(fields)
    name = f.pop("name")
    return make_user_profile(
        name,
        f.pop("arrival_weights"),
        f.pop("stay_quantiles_min"),
        f.pop("demand_quantiles_kwh"),
        **f,
    )


def load_user_profile(
    source: Any = "shopping", *, session_model: str = "v2", **overrides: Any
) -> UserProfileData:
    """A bundled profile by name (`ALL_USER_PROFILES`) or a `UserProfileData`.

    Args:
        source: a bundled profile's name or a `UserProfileData`.
        session_model: which bundled profiles a name refers to (`SESSION_MODELS`): ``"v2"``
            and ``"v3"`` (stays and energies by arrival hour, requests, day-to-day volume) or
            ``"paper"`` (the Chargax paper's profiles). Ignored for a `UserProfileData`.
        **overrides: fields to replace (e.g. ``charge_sensitive_prob=0.5``), validated like
            `make_user_profile` arguments.

    Returns:
        The validated profile.

    Raises:
        KeyError: an unknown profile name.
        ValueError: an unknown field or session model, or a bad value.
    """
    if session_model not in SESSION_MODELS:
        raise ValueError(
            f"session_model: unknown {session_model!r}; valid models are {list(SESSION_MODELS)}"
        )
    unknown = sorted(set(overrides) - set(_PROFILE_FIELDS))
    if unknown:
        raise ValueError(
            f"user profile: unknown field(s) {unknown}; valid fields are {list(_PROFILE_FIELDS)}"
        )
    if isinstance(source, UserProfileData):
        base = source
    elif isinstance(source, str):
        if source not in ALL_USER_PROFILES:
            raise KeyError(
                f"user profile: unknown profile {source!r}; valid names are {list(ALL_USER_PROFILES)}"
            )
        base = _load_bundled_profile(source, session_model)
        if not overrides:
            return base
    else:
        raise ValueError(
            f"user profile: expected one of {list(ALL_USER_PROFILES)} or a UserProfileData, got {type(source).__name__}"
        )
    fields = {k: getattr(base, k) for k in _PROFILE_FIELDS}
    fields.update(overrides)
    return _profile_from_fields(fields)


@functools.cache
def _profiles_json() -> dict[str, Any]:
    return json.loads((DATA_DIR / USER_PROFILES_FILE).read_text(encoding="utf-8"))


@functools.cache
def _us_profiles_json() -> dict[str, Any]:
    return json.loads((DATA_DIR / US_USER_PROFILES_FILE).read_text(encoding="utf-8"))


@functools.cache
def _v2_profiles_json() -> dict[str, Any]:
    return json.loads((DATA_DIR / USER_PROFILES_V2_FILE).read_text(encoding="utf-8"))


def list_user_profiles() -> list[str]:
    """Names accepted by `load_user_profile` (the paper's four plus the US ACN-Data profiles).

    Returns:
        The bundled profiles' names (`ALL_USER_PROFILES`), a new list.
    """
    return list(ALL_USER_PROFILES)


@functools.cache
def _load_bundled_profile(name: str, session_model: str = "v2") -> UserProfileData:
    if session_model in ("v2", "v3"):  # v3 draws v2's sessions
        doc = _v2_profiles_json()
    else:
        doc = _us_profiles_json() if name in US_USER_PROFILES else _profiles_json()
    return profile_from_dict(name, doc["profiles"][name])


def profile_from_dict(name: str, p: dict) -> UserProfileData:
    """A validated profile from one entry of the bundled profile JSON (the runtime loader and
    ``scripts/build_data.py`` share it, so the data is checked the same way on both sides).

    Args:
        name: the profile's name.
        p: the entry: ``arrival_weights_workday``, ``arrival_weights_weekend``,
            ``stay_quantiles_min``, ``demand_quantiles_kwh``, ``weekend_volume_factor``,
            ``stay_scale_by_hour``, ``demand_scale_by_hour``, ``arrival_soc_range`` and
            ``charge_sensitive_prob``, and optionally ``dc_charge_sensitive_prob``,
            ``request_ratio_quantiles``, ``daily_volume_cv``, ``weekday_volume_factors``
            and ``stay_demand_corr`` (the arguments of `make_user_profile`); other keys are
            ignored.

    Returns:
        The validated profile.

    Raises:
        KeyError: ``p`` lacks a required key.
        ValueError: a value fails `make_user_profile`'s checks.
    """
    return make_user_profile(
        name,
        [p["arrival_weights_workday"], p["arrival_weights_weekend"]],
        p["stay_quantiles_min"],
        p["demand_quantiles_kwh"],
        weekend_volume_factor=p["weekend_volume_factor"],
        stay_scale_by_hour=p["stay_scale_by_hour"],
        demand_scale_by_hour=p["demand_scale_by_hour"],
        arrival_soc_range=tuple(p["arrival_soc_range"]),
        charge_sensitive_prob=p["charge_sensitive_prob"],
        dc_charge_sensitive_prob=p.get("dc_charge_sensitive_prob"),
        request_ratio_quantiles=p.get("request_ratio_quantiles"),
        daily_volume_cv=p.get("daily_volume_cv", 0.0),
        weekday_volume_factors=p.get("weekday_volume_factors"),
        stay_demand_corr=p.get("stay_demand_corr", 0.0),
    )
