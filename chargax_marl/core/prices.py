"""Day-ahead prices: bundled datasets, arrays and CSV files, and the raw market exports the
bundled files are built from. Every path goes through one validator, `_validate_prices`
(shape ``(days, 24)``, finite, within +-``checks.MAX_PRICE_EUR_KWH`` EUR/kWh).
"""

from __future__ import annotations

import csv
import dataclasses
import datetime as _dt
import functools
import io
import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import numpy as np

from chargax_marl.core import checks
from chargax_marl.core.data_io import (
    DATA_DIR,
    HOURS_PER_DAY,
    PRICE_DATASETS,
    PRICE_INDEX_FILES,
    PRICE_LONG_COLUMNS,
    PRICE_WIDE_COLUMNS,
    _as_float_array,
    _check_bounds,
    _check_consecutive,
    _check_finite,
    _check_weekday,
    _data_rows,
    _looks_like_path,
    _parse_date,
    _parse_float,
    _read_text,
    _readonly,
)


@dataclass(frozen=True)
class PriceData:
    """Day-ahead prices: ``prices_eur_kwh[day, local_hour]`` in EUR/kWh (float32).

    ``first_weekday`` is the weekday of day 0 (0 = Monday ... 6 = Sunday); day
    ``d`` has weekday ``(first_weekday + d) % 7``. ``first_date`` (ISO date) is the date of
    day 0 where the data knows it (the bundled datasets), else None; ``country`` the ISO
    code of the market's country where known.

    `load_prices` validates the prices and makes the array read-only; the constructor
    itself checks nothing.

    Attributes:
        name: the dataset's name (``"custom"`` for an array, the file name without its
            suffix for a CSV).
        prices_eur_kwh: ``(days, 24)`` float32 day-ahead price per local hour (EUR/kWh).
        first_weekday: the weekday of day 0 (0 = Monday ... 6 = Sunday).
        first_date: the ISO date (``YYYY-MM-DD``) of day 0, or ``None`` where unknown.
        country: the market's country code (e.g. ``"NL"``), or ``None`` where unknown.
    """

    name: str
    prices_eur_kwh: np.ndarray
    first_weekday: int
    first_date: str | None = None
    country: str | None = None

    @property
    def num_days(self) -> int:
        return int(self.prices_eur_kwh.shape[0])


def list_price_datasets() -> list[str]:
    """Names accepted by `load_prices`.

    Returns:
        The bundled datasets' names (`PRICE_DATASETS`), a new list.
    """
    return list(PRICE_DATASETS)


def _validate_prices(value: Any, field: str = "prices") -> np.ndarray:
    arr = _as_float_array(value, field)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != HOURS_PER_DAY:
        raise ValueError(
            f"{field}: expected shape (days, 24) or (24,), got {tuple(np.shape(value))}"
        )
    if arr.shape[0] == 0:
        raise ValueError(f"{field}: expected at least one day, got shape {tuple(arr.shape)}")
    _check_finite(arr, field)
    _check_bounds(arr, field, -checks.MAX_PRICE_EUR_KWH, checks.MAX_PRICE_EUR_KWH, "EUR/kWh")
    return arr.astype(np.float32)


def load_prices(source: Any = "NL-2023", *, first_weekday: int | None = None) -> PriceData:
    """Load day-ahead prices.

    ``source`` is a bundled dataset name (see `PRICE_DATASETS`), a
    `PriceData`, a numpy array of EUR/kWh with shape ``(days, 24)`` or
    ``(24,)``, or a path to a CSV in EUR/MWh (see `read_prices_csv`).
    ``first_weekday`` (0 = Monday) overrides the weekday of day 0; the default
    is the dataset's own (a CSV: the weekday of its first date; an array: 0).

    Args:
        source: a bundled dataset name, a `PriceData` (validated again), an array of
            EUR/kWh (anything with ``__array__``, a list or a tuple), or a CSV path (a
            string ending in ``.csv``, containing a path separator or naming a file, or an
            `os.PathLike`).
        first_weekday: the weekday of day 0 (0 = Monday ... 6 = Sunday), or ``None`` for
            the data's own. A weekday other than the data's own drops ``first_date``.

    Returns:
        The prices; bundled datasets are read once and cached. Prices from an array or a
        CSV have no ``first_date`` and no ``country``.

    Raises:
        KeyError: ``source`` is a string that is neither a dataset name nor looks like a
            path.
        ValueError: ``source`` is of another type; the prices are not of shape ``(days, 24)``
            or ``(24,)``, are empty, not finite or beyond +-``checks.MAX_PRICE_EUR_KWH``; the
            CSV is invalid; or ``first_weekday`` is not an integer in 0..6.
        FileNotFoundError: the CSV path is not a file.
        RuntimeError: a bundled price file disagrees with its index.
    """
    if isinstance(source, PriceData):
        data = PriceData(
            source.name,
            _readonly(_validate_prices(source.prices_eur_kwh, "prices_eur_kwh")),
            _check_weekday(source.first_weekday),
            source.first_date,
            source.country,
        )
    elif isinstance(source, str) and source in PRICE_DATASETS:
        data = _load_bundled_prices(source)
    elif isinstance(source, (str, os.PathLike)):
        if isinstance(source, str) and not _looks_like_path(source):
            raise KeyError(
                f"prices: unknown dataset {source!r}; valid names are {list(PRICE_DATASETS)} (or pass an array or a CSV path)"
            )
        prices, fw = read_prices_csv(source)
        data = PriceData(Path(source).stem, _readonly(prices), fw)
    elif isinstance(source, (np.ndarray, list, tuple)) or hasattr(source, "__array__"):
        data = PriceData("custom", _readonly(_validate_prices(source)), 0)
    else:
        raise ValueError(
            f"prices: expected a dataset name {list(PRICE_DATASETS)}, an array (days, 24), or a CSV path, got {type(source).__name__}"
        )
    if first_weekday is not None and _check_weekday(first_weekday) != data.first_weekday:
        # another weekday for day 0: the data's dates no longer hold
        data = dataclasses.replace(data, first_weekday=first_weekday, first_date=None)
    return data


@functools.cache
def _price_index() -> dict[str, dict[str, Any]]:
    merged: dict[str, dict[str, Any]] = {}
    for fname in PRICE_INDEX_FILES:
        merged.update(json.loads((DATA_DIR / fname).read_text(encoding="utf-8"))["datasets"])
    return merged


@functools.cache
def _load_bundled_prices(name: str) -> PriceData:
    entry = _price_index()[name]
    prices, first_weekday = read_prices_csv(DATA_DIR / entry["file"])
    if first_weekday != entry["first_weekday"] or prices.shape[0] != entry["days"]:
        raise RuntimeError(
            f"bundled price file {entry['file']} disagrees with its index ({PRICE_INDEX_FILES}); run `make data`"
        )
    return PriceData(
        name, _readonly(prices), first_weekday, entry.get("first_date"), name.split("-")[0]
    )


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

    Args:
        path: the CSV file (UTF-8).

    Returns:
        ``(prices_eur_kwh, first_weekday)``: ``(days, 24)`` float32 prices by local hour
        (EUR/kWh), and the weekday of the first date (0 = Monday).

    Raises:
        FileNotFoundError: ``path`` is not a file.
        ValueError: the file is not UTF-8 text, or its content is invalid (see
            `parse_prices_csv_text`).
    """
    text = _read_text(path)
    return parse_prices_csv_text(text, source=str(path))


def parse_prices_csv_text(text: str, source: str = "<csv>") -> tuple[np.ndarray, int]:
    """As `read_prices_csv`, for CSV text.

    Args:
        text: the CSV text, in either layout of `read_prices_csv` (prices in EUR/MWh).
        source: where the text comes from, for error messages.

    Returns:
        ``(prices_eur_kwh, first_weekday)``: ``(days, 24)`` float32 prices (EUR/kWh), and
        the weekday of the first date (0 = Monday).

    Raises:
        ValueError: the text is empty or has no data rows; its header is neither layout's;
            a row has the wrong number of fields, a date, timestamp or price does not
            parse or is not finite; a timestamp has a UTC offset or is not on the hour;
            days are not consecutive; a day (long layout) lacks more than one hour or
            repeats more than one hour, or one hour more than twice; or a price is beyond
            +-``checks.MAX_PRICE_EUR_KWH`` EUR/kWh.
    """
    rows = _data_rows(text)
    if not rows:
        raise ValueError(
            f"prices: {source} is empty; expected a header {','.join(PRICE_LONG_COLUMNS)} or date,h0..h23"
        )
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


def _parse_wide_prices(body: list[list[str]], source: str) -> tuple[np.ndarray, _dt.date]:
    dates: list[_dt.date] = []
    values = np.empty((len(body), HOURS_PER_DAY), dtype=np.float64)
    for i, row in enumerate(body):
        where = f"{source} data row {i + 1}"
        if len(row) != 1 + HOURS_PER_DAY:
            raise ValueError(
                f"prices: {where}: expected 25 fields (date + 24 hours), got {len(row)}"
            )
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
            raise ValueError(
                f"prices: {where}: expected 2 fields (timestamp, price_eur_mwh), got {len(row)}"
            )
        try:
            ts = _dt.datetime.fromisoformat(row[0].strip())
        except ValueError:
            raise ValueError(
                f"timestamp: {where}: expected an ISO timestamp like 2023-01-01 13:00, got {row[0]!r}"
            ) from None
        if ts.tzinfo is not None:
            raise ValueError(
                f"timestamp: {where}: give local wall-clock times without a UTC offset, got {row[0]!r}"
            )
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


_ISO_TS = re.compile(r"^(\d{4})-(\d{2})-(\d{2})[ T](\d{2}):(\d{2})(?::(\d{2}))?$")
_SLASH_TS = re.compile(r"^(\d{1,2})/(\d{1,2})/(\d{4}) (\d{1,2}):(\d{2})(?::(\d{2}))?$")


def _find_column(header: list[str], *needles: str) -> int:
    low = [h.strip().lower() for h in header]
    for i, h in enumerate(low):
        if all(n in h for n in needles):
            return i
    raise ValueError(
        f"day-ahead CSV: no column containing {' and '.join(repr(n) for n in needles)} in header {header!r}"
    )


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
        raise ValueError(
            "day-ahead CSV: slash dates are inconsistent (some need dd/mm, others mm/dd)"
        )
    return not month_first_evidence  # ambiguous (no field > 12): European day-first


def parse_day_ahead_csv(
    text: str,
    *,
    timezone: str = "Europe/Amsterdam",
    unit: str = "eur_kwh",
    stats: dict | None = None,
) -> dict[int, np.ndarray]:
    """Parse a raw day-ahead price export into per-year ``(days, 24)`` arrays by local hour.

    The input has (at least) a UTC timestamp column (the first whose header
    contains "utc") and a price column (the first whose header contains
    "price", in EUR/MWh). Timestamps are ISO ``YYYY-MM-DD HH:MM[:SS]`` or
    ``dd/mm/yyyy HH:MM`` (day-first vs month-first is decided from the data).
    Steps:

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

    Args:
        text: the CSV text (a leading BOM and leading blank lines are skipped).
        timezone: the IANA time zone of the market's local hours.
        unit: ``"eur_kwh"`` or ``"eur_mwh"``, the unit of the returned arrays.
        stats: a dict to update, or ``None``. Its keys: ``rows`` (non-blank data rows),
            ``hours`` (distinct UTC hours kept), ``duplicates``, ``conflicting_duplicates``,
            ``malformed``, ``malformed_rows`` (``(line number, reason)`` pairs),
            ``slash_dates_day_first`` and ``years`` (``{year: {"first_date",
            "first_weekday", "days", "dst_gap_filled", "dst_repeat_averaged",
            "interpolated"}}``).

    Returns:
        ``{year: (days, 24) array}``, empty when no row is usable.

    Raises:
        ValueError: ``unit`` is not one of the two; the input is empty; no header contains
            "utc" or "price"; or slash dates need day-first in some rows and month-first
            in others.
        zoneinfo.ZoneInfoNotFoundError: ``timezone`` is not a known time zone.
    """
    if unit not in ("eur_kwh", "eur_mwh"):
        raise ValueError(f"unit: expected 'eur_kwh' or 'eur_mwh', got {unit!r}")
    tz = ZoneInfo(timezone)
    utc = _dt.UTC
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
        kind = np.zeros(
            len(dates) * HOURS_PER_DAY, dtype=np.int8
        )  # 1 = DST gap, 2 = other gap, 3 = averaged
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
    back = naive.replace(tzinfo=tz).astimezone(_dt.UTC).astimezone(tz)
    return back.replace(tzinfo=None) != naive
