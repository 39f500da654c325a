"""Exogenous per-step signals: marginal emission rates (MOER) and grid demand. Every path
(bundled name, array, CSV, ``make_params`` keyword) goes through `validate_moer` or
`validate_grid_demand`.
"""

from __future__ import annotations

import functools
import json
import numbers
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from chargax_marl.core import checks
from chargax_marl.core.data_io import (
    DATA_DIR,
    GRID_DEMAND_SHAPES,
    MINUTES_PER_DAY,
    MOER_DATASETS,
    MOER_INDEX_FILE,
    SLOTS_PER_DAY,
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
    _validate_unit_scalar,
)


@dataclass(frozen=True)
class MoerData:
    """Marginal operating emission rate ``moer_kg_per_kwh[day, slot]`` in kg CO2/kWh (float32).

    Columns are equal slots of the *local* day (288 = 5 minutes for the bundled
    data). ``first_weekday`` is the weekday of day 0 (0 = Monday); ``year`` the
    calendar year of the data (``None`` for custom data).

    `load_moer` validates the rates and makes the array read-only; the constructor itself
    checks nothing.

    Attributes:
        name: the dataset's name (``"custom"`` for an array, the file name without its
            suffix for a CSV).
        moer_kg_per_kwh: ``(days, slots)`` float32 rates (kg CO2/kWh).
        first_weekday: the weekday of day 0 (0 = Monday ... 6 = Sunday).
        year: the calendar year of the data, or ``None``.
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


MOER_MAX_KG_KWH = 5.0  # sanity bound for custom data (coal-only grids are ~1 kg/kWh)


def _check_resolution(n: int, field: str) -> None:
    if n <= 0 or MINUTES_PER_DAY % n:
        raise ValueError(
            f"{field}: the number of slots per day must divide 1440 minutes evenly, got {n}"
        )


def validate_moer(
    value: Any, field: str = "moer_kg_per_kwh", *, check_resolution: bool = True
) -> np.ndarray:
    """The one validator of MOER rates (kg CO2/kWh), whatever the path (bundled, CSV, array,
    `MoerData`, ``make_params``): shape ``(days, slots)`` or ``(slots,)``, finite, in
    ``[0, MOER_MAX_KG_KWH]``. ``check_resolution``: slots must divide 1440 minutes (off for
    arrays already at the simulator's step). Returns float32 ``(days, slots)``.

    Args:
        value: the rates (kg CO2/kWh), ``(days, slots)`` or ``(slots,)`` (one day).
        field: the name error messages give the rates.
        check_resolution: require the number of slots to divide 1440.

    Returns:
        ``(days, slots)`` float32; a 1-D input becomes one row.

    Raises:
        ValueError: ``value`` is not an array of numbers of one of the two shapes, has no
            day, has a number of slots that does not divide 1440 (with
            ``check_resolution``), or a rate that is not finite, negative or above
            `MOER_MAX_KG_KWH`.
    """
    arr = _as_float_array(value, field)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[0] == 0:
        raise ValueError(
            f"{field}: expected shape (days, slots) or (slots,), got {tuple(np.shape(value))}"
        )
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


def resample_moer(moer: Any, num_steps: int) -> np.ndarray:
    """Resample a rate ``(days, slots)`` to ``(days, num_steps)`` per day.

    Coarser target that nests: mean over the source slots of each step; finer target that
    nests: each source slot repeated. Rates are intensive (kg/kWh), so
    averaging / repeating preserves the daily mean. Resolutions that do not nest: the
    piecewise-constant source averaged over each target step.

    Nothing is validated (see `validate_moer`).

    Args:
        moer: the rates, ``(days, slots)`` or ``(slots,)``.
        num_steps: the steps per day to resample to.

    Returns:
        ``(days, num_steps)`` float32 (one row for a 1-D input).
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
    ``(moer_kg_per_kwh (days, N) float32, first_weekday)``.

    Args:
        path: the CSV file (UTF-8).
        unit: the unit of the file's rates; they are converted to kg CO2/kWh.

    Returns:
        ``(moer_kg_per_kwh, first_weekday)``: ``(days, N)`` float32 rates (kg CO2/kWh) and
        the weekday of the first date (0 = Monday).

    Raises:
        ValueError: an unknown ``unit``; the file is not UTF-8, is empty, has another
            header or no data rows; ``N`` does not divide 1440; a row has the wrong number
            of fields, a date or rate does not parse or is not finite; the dates are not
            consecutive; or the rates fail `validate_moer`.
        FileNotFoundError: ``path`` is not a file.
    """
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
        raise ValueError(
            f"moer: {source}: unrecognised header {','.join(rows[0])[:80]!r}; expected 'date,m0,...,m<N-1>'"
        )
    _check_resolution(n, f"moer: {source}")
    body = rows[1:]
    if not body:
        raise ValueError(f"moer: {source} has a header but no data rows")
    dates, values = [], np.empty((len(body), n))
    for i, row in enumerate(body):
        where = f"{source} data row {i + 1}"
        if len(row) != n + 1:
            raise ValueError(
                f"moer: {where}: expected {n + 1} fields (date + {n} slots), got {len(row)}"
            )
        dates.append(_parse_date(row[0], "date", where))
        for j in range(n):
            values[i, j] = _parse_float(row[1 + j], f"m{j}", where)
    _check_consecutive(dates, "date", source)
    return validate_moer(values * factors[unit], f"moer: {source}"), dates[0].weekday()


@functools.cache
def _moer_index() -> dict[str, dict[str, Any]]:
    return json.loads((DATA_DIR / MOER_INDEX_FILE).read_text(encoding="utf-8"))["datasets"]


@functools.cache
def _load_bundled_moer(name: str) -> MoerData:
    entry = _moer_index()[name]
    arr, fw = read_moer_csv(DATA_DIR / entry["file"], unit=entry["unit"])
    if fw != entry["first_weekday"] or arr.shape[0] != entry["days"]:
        raise RuntimeError(
            f"bundled MOER file {entry['file']} disagrees with {MOER_INDEX_FILE}; run `make data`"
        )
    return MoerData(name, _readonly(arr), fw, int(entry["year"]))


def load_moer(source: Any = "CAISO-SCE-2020") -> MoerData:
    """MOER data: a bundled name (`MOER_DATASETS`), a `MoerData`, an
    array in kg CO2/kWh ``(days, slots)`` or ``(slots,)``, or a CSV path (kg/kWh;
    see `read_moer_csv`).

    Args:
        source: a bundled dataset's name, a `MoerData` (validated again), an array
            (anything with ``__array__``, a list or a tuple), or a CSV path (a string ending
            in ``.csv``, containing a path separator or naming a file, or an
            `os.PathLike`).

    Returns:
        The validated data; bundled datasets are read once and cached. Arrays get weekday
        0 and no year; CSVs the weekday of their first date and no year.

    Raises:
        KeyError: ``source`` is a string that is neither a dataset's name nor looks like
            a path.
        ValueError: ``source`` is of another type, or the rates, CSV or weekday are
            invalid.
        FileNotFoundError: the CSV path is not a file.
        RuntimeError: a bundled MOER file disagrees with its index.
    """
    if isinstance(source, MoerData):
        return MoerData(
            source.name,
            _readonly(validate_moer(source.moer_kg_per_kwh)),
            _check_weekday(source.first_weekday),
            source.year,
        )
    if isinstance(source, str) and source in MOER_DATASETS:
        return _load_bundled_moer(source)
    if isinstance(source, (str, os.PathLike)):
        if isinstance(source, str) and not _looks_like_path(source):
            raise KeyError(
                f"moer: unknown dataset {source!r}; valid names are {list(MOER_DATASETS)} (or pass an array or a CSV path)"
            )
        arr, fw = read_moer_csv(source)
        return MoerData(Path(source).stem, _readonly(arr), fw, None)
    if isinstance(source, (np.ndarray, list, tuple)) or hasattr(source, "__array__"):
        return MoerData("custom", _readonly(validate_moer(source)), 0, None)
    raise ValueError(
        f"moer: expected a dataset name {list(MOER_DATASETS)}, an array (days, slots) or a CSV path, got {type(source).__name__}"
    )


# Synthetic residential load (no source data; see data/README.md): a night base
# plus a morning and an evening Gaussian peak, by local hour.
# (centre hour, sd hours, relative height); base level 1.
GRID_DEMAND_RESIDENTIAL_PEAKS: tuple[tuple[float, float, float], ...] = (
    (7.5, 1.25, 0.8),
    (19.0, 2.0, 1.5),
)
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
    ``make_params``): shape ``(num_steps,)``, finite, in ``[0, checks.MAX_GRID_DEMAND_KWH]``.

    Args:
        value: the demand per step of the day (kWh).
        num_steps: the simulator's steps per day.
        field: the name error messages give the signal.

    Returns:
        ``(num_steps,)`` float32 kWh per step.

    Raises:
        ValueError: ``value`` is not a 1-D array of numbers of length ``num_steps``, or an
            entry is not finite, negative or above ``checks.MAX_GRID_DEMAND_KWH``.
    """
    arr = _as_float_array(value, field)
    if arr.ndim != 1:
        raise ValueError(
            f"{field}: expected a 1-D array of kWh per step ({num_steps},), got shape {tuple(arr.shape)}"
        )
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
    caller.

    Args:
        path: the CSV file (UTF-8).

    Returns:
        ``(steps,)`` float64, the column's values in row order (kWh per step).

    Raises:
        ValueError: the file is not UTF-8, is empty, has no ``grid_demand_kwh`` column or
            no data rows, a row has another number of fields than the header, or a value
            does not parse or is not finite.
        FileNotFoundError: ``path`` is not a file.
    """
    source = str(path)
    rows = _data_rows(_read_text(path))
    if not rows:
        raise ValueError(
            f"grid demand: {source} is empty; expected a header with a column grid_demand_kwh"
        )
    header = [c.strip().lower() for c in rows[0]]
    if "grid_demand_kwh" not in header:
        raise ValueError(
            f"grid demand: {source}: no column 'grid_demand_kwh' in header {rows[0]!r}"
        )
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


def load_grid_demand(
    source: Any = "synthetic-residential",
    num_steps: int = SLOTS_PER_DAY,
    scale_kwh: float | None = None,
) -> np.ndarray:
    """Grid demand per step of the day in kWh, float32 ``(num_steps,)``.

    ``source``: a shape name (`GRID_DEMAND_SHAPES`), scaled so its daily
    mean is ``scale_kwh`` kWh per step (default
    `GRID_DEMAND_DEFAULT_SCALE_KWH` times 288 / ``num_steps``, i.e. the
    same daily energy at any resolution); an array ``(num_steps,)``; or a CSV
    path (`read_grid_demand_csv`). For arrays and CSVs ``scale_kwh``, if
    given, rescales to that daily mean per step.

    Args:
        source: a shape name, an array (anything with ``__array__``, a list or a tuple),
            or a CSV path (a string ending in ``.csv``, containing a path separator or
            naming a file, or an `os.PathLike`).
        num_steps: the steps per day, a positive integer dividing 1440.
        scale_kwh: the daily mean per step to scale to (kWh, in
            ``[0, checks.MAX_GRID_DEMAND_KWH]``), or ``None``.

    Returns:
        ``(num_steps,)`` float32 kWh per step.

    Raises:
        ValueError: ``num_steps`` is not a positive integer dividing 1440, ``scale_kwh`` is
            out of range, ``source`` is of another type, the array or CSV is invalid
            (`validate_grid_demand`, `read_grid_demand_csv`), or an all-zero demand is
            to be rescaled.
        KeyError: ``source`` is a string that is neither a shape's name nor looks like a
            path.
        FileNotFoundError: the CSV path is not a file.
    """
    if isinstance(num_steps, bool) or not isinstance(num_steps, numbers.Integral) or num_steps < 1:
        raise ValueError(f"num_steps: expected a positive integer, got {num_steps!r}")
    num_steps = int(num_steps)
    _check_resolution(num_steps, "num_steps")
    if scale_kwh is not None:
        scale_kwh = _validate_unit_scalar(scale_kwh, "scale_kwh", upper=checks.MAX_GRID_DEMAND_KWH)
    if isinstance(source, str) and source in GRID_DEMAND_SHAPES:
        if scale_kwh is None:
            scale_kwh = GRID_DEMAND_DEFAULT_SCALE_KWH * SLOTS_PER_DAY / num_steps
        shaped = _residential_shape(num_steps) * scale_kwh
        return validate_grid_demand(shaped, num_steps, "grid_demand_kwh (scaled by scale_kwh)")
    if isinstance(source, (str, os.PathLike)):
        if isinstance(source, str) and not _looks_like_path(source):
            raise KeyError(
                f"grid demand: unknown shape {source!r}; valid names are {list(GRID_DEMAND_SHAPES)} (or pass an array or a CSV path)"
            )
        arr = validate_grid_demand(
            read_grid_demand_csv(source), num_steps, f"grid_demand_kwh ({source})"
        )
    elif isinstance(source, (np.ndarray, list, tuple)) or hasattr(source, "__array__"):
        arr = validate_grid_demand(source, num_steps)
    else:
        raise ValueError(
            f"grid demand: expected a shape name {list(GRID_DEMAND_SHAPES)}, an array or a CSV path, got {type(source).__name__}"
        )
    if scale_kwh is not None:
        mean = float(arr.mean())
        if not mean > 0:
            raise ValueError("scale_kwh: cannot rescale an all-zero grid demand")
        # the peaks scale with the mean: checked again against the bound
        arr = validate_grid_demand(
            arr * (scale_kwh / mean), num_steps, "grid_demand_kwh (scaled by scale_kwh)"
        )
    return arr.astype(np.float32)
