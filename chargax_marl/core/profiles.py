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
    SLOTS_PER_DAY,
    TRAFFIC_LEVELS,
    US_USER_PROFILES,
    US_USER_PROFILES_FILE,
    USER_PROFILES_FILE,
    _as_float_array,
    _check_bounds,
    _check_finite,
    _readonly,
    _validate_name,
    _validate_unit_scalar,
)


def traffic_cars_per_day(traffic: str | float) -> float:
    """Mean number of arriving cars per day: a level name or a positive number."""
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
    ``stay_quantiles_min`` / ``demand_quantiles_kwh`` (float32, (101,)):
    inverse CDFs at probabilities 0, 0.01, ..., 1 of the stay (minutes) and of
    the energy demand (kWh); ``*_scale_by_hour`` (float32, (24,)) multiply a
    sample by the arrival hour's factor. ``arrival_soc_range``: uniform range
    of the arrival SoC; ``charge_sensitive_prob``: P(u = 1), i.e. the user
    leaves when charged rather than at the end of the stay.
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


def _validate_quantiles(value: Any, field: str) -> np.ndarray:
    arr = _as_float_array(value, field)
    if arr.ndim != 1 or arr.shape[0] < 2:
        raise ValueError(
            f"{field}: expected a 1-D quantile table ({NUM_QUANTILES},) (or >= 2 evenly spaced quantiles), got shape {tuple(arr.shape)}"
        )
    _check_finite(arr, field)
    if (arr < 0).any():
        raise ValueError(f"{field}: quantiles must be >= 0, got {float(arr.min())!r}")
    if (np.diff(arr) < 0).any():
        i = int(np.argmax(np.diff(arr) < 0))
        raise ValueError(
            f"{field}: quantiles must be non-decreasing, got {float(arr[i])!r} then {float(arr[i + 1])!r} at index {i + 1}"
        )
    high, unit = (
        (checks.MAX_STAY_MIN, "min") if field.endswith("_min") else (checks.MAX_DEMAND_KWH, "kWh")
    )
    _check_bounds(arr, field, 0.0, high, unit)
    if arr.shape[0] != NUM_QUANTILES:
        arr = np.interp(QUANTILE_PROBS, np.linspace(0.0, 1.0, arr.shape[0]), arr)
    return arr.astype(np.float32)


def _validate_scale(value: Any, field: str) -> np.ndarray:
    if value is None:
        return np.ones(HOURS_PER_DAY, dtype=np.float32)
    arr = _as_float_array(value, field)
    if arr.shape != (HOURS_PER_DAY,):
        raise ValueError(f"{field}: expected shape (24,), got {tuple(arr.shape)}")
    _check_finite(arr, field)
    if (arr <= 0).any():
        raise ValueError(f"{field}: factors must be > 0, got {float(arr.min())!r}")
    _check_bounds(arr, field, 0.0, checks.MAX_FACTOR, low_open=True)
    return arr.astype(np.float32)


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
) -> UserProfileData:
    """Build and validate a custom user profile.

    ``arrival_weights``: shape (288,) (same for workdays and weekends), (2, 288)
    (workday, weekend), or hourly (24,) / (2, 24), which is spread evenly over
    the hour's twelve 5-minute slots; non-negative, re-normalised per row.
    Quantile tables: inverse CDFs at evenly spaced probabilities from 0 to 1
    (101 entries, or any length >= 2, resampled linearly to 101), non-negative,
    non-decreasing, finite; stays in minutes, demands in kWh. Scale factors:
    (24,) positive, default all ones.
    """
    return UserProfileData(
        name=_validate_name(name),
        arrival_weights=_readonly(_validate_weights(arrival_weights)),
        weekend_volume_factor=_validate_weekend_factor(weekend_volume_factor),
        stay_quantiles_min=_readonly(_validate_quantiles(stay_quantiles_min, "stay_quantiles_min")),
        stay_scale_by_hour=_readonly(_validate_scale(stay_scale_by_hour, "stay_scale_by_hour")),
        demand_quantiles_kwh=_readonly(
            _validate_quantiles(demand_quantiles_kwh, "demand_quantiles_kwh")
        ),
        demand_scale_by_hour=_readonly(
            _validate_scale(demand_scale_by_hour, "demand_scale_by_hour")
        ),
        arrival_soc_range=_validate_soc_range(arrival_soc_range),
        charge_sensitive_prob=_validate_unit_scalar(charge_sensitive_prob, "charge_sensitive_prob"),
    )


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


def load_user_profile(source: Any = "shopping", **overrides: Any) -> UserProfileData:
    """A bundled profile by name (`ALL_USER_PROFILES`) or a `UserProfileData`.

    Keyword overrides replace fields (e.g. ``charge_sensitive_prob=0.5``) and
    are validated like `make_user_profile` arguments.
    """
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
        base = _load_bundled_profile(source)
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


def list_user_profiles() -> list[str]:
    """Names accepted by `load_user_profile` (the paper's four plus the US ACN-Data profiles)."""
    return list(ALL_USER_PROFILES)


@functools.cache
def _load_bundled_profile(name: str) -> UserProfileData:
    doc = _us_profiles_json() if name in US_USER_PROFILES else _profiles_json()
    return profile_from_dict(name, doc["profiles"][name])


def profile_from_dict(name: str, p: dict) -> UserProfileData:
    """A validated profile from one entry of the bundled profile JSON (the runtime loader and
    ``scripts/build_data.py`` share it, so the data is checked the same way on both sides)."""
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
    )
