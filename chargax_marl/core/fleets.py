"""Car fleets: bundled fleets and CSV files. Every path goes through one validator,
`_make_fleet`.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from chargax_marl.core import checks
from chargax_marl.core.data_io import (
    DATA_DIR,
    FLEET_COLUMNS,
    FLEET_DISCHARGE_COLUMNS,
    FLEET_FILES,
    FLEETS,
    _as_float_array,
    _check_bounds,
    _check_finite,
    _data_rows,
    _looks_like_path,
    _parse_float,
    _read_text,
    _readonly,
    _validate_name,
)


@dataclass(frozen=True)
class FleetData:
    """Car models and their shares: ``share``, ``capacity_kwh``, ``max_ac_kw``,
    ``max_dc_kw``, ``tau``, ``max_ac_discharge_kw`` and ``max_dc_discharge_kw`` are float32
    arrays of shape (K,); ``share`` sums to 1. A discharge limit of 0 means the model cannot
    feed energy back (no V2G) at that kind of port.

    `load_fleet` and the CSV readers validate the columns, normalise ``share`` and make the
    arrays read-only; the constructor itself checks nothing and only fills a missing
    discharge column with zeros.

    Attributes:
        name: the fleet's name.
        models: the ``K`` car model names.
        share: ``(K,)`` share of each model among arriving cars (sums to 1).
        capacity_kwh: ``(K,)`` battery capacity of each model (kWh).
        max_ac_kw: ``(K,)`` charging limit of each model at AC ports (kW).
        max_dc_kw: ``(K,)`` charging limit of each model at DC ports (kW).
        tau: ``(K,)`` SoC above which each model's charge rate tapers, in (0, 1).
        max_ac_discharge_kw: ``(K,)`` discharge (V2G) limit at AC ports (kW; 0 = cannot
            discharge); ``None`` becomes zeros.
        max_dc_discharge_kw: ``(K,)`` discharge (V2G) limit at DC ports (kW); ``None``
            becomes zeros.
    """

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


def _make_fleet(
    name: str,
    models: Any,
    share: Any,
    capacity_kwh: Any,
    max_ac_kw: Any,
    max_dc_kw: Any,
    tau: Any,
    max_ac_discharge_kw: Any = None,
    max_dc_discharge_kw: Any = None,
) -> FleetData:
    models = tuple(models)
    k = len(models)
    if k == 0:
        raise ValueError("models: a fleet needs at least one car model")
    for m in models:
        _validate_name(m, "models")
    cols = {}
    zeros = np.zeros(k)
    for field, value in (
        ("share", share),
        ("capacity_kwh", capacity_kwh),
        ("max_ac_kw", max_ac_kw),
        ("max_dc_kw", max_dc_kw),
        ("tau", tau),
        ("max_ac_discharge_kw", zeros if max_ac_discharge_kw is None else max_ac_discharge_kw),
        ("max_dc_discharge_kw", zeros if max_dc_discharge_kw is None else max_dc_discharge_kw),
    ):
        arr = _as_float_array(value, field)
        if arr.shape != (k,):
            raise ValueError(
                f"{field}: expected shape ({k},) (one per model), got {tuple(arr.shape)}"
            )
        _check_finite(arr, field)
        cols[field] = arr
    if (cols["share"] < 0).any():
        raise ValueError(f"share: must be >= 0, got {float(cols['share'].min())!r}")
    if not cols["share"].sum() > 0:
        raise ValueError(f"share: must have a positive sum, got {float(cols['share'].sum())!r}")
    for field in ("capacity_kwh", "max_ac_kw", "max_dc_kw"):
        if (cols[field] <= 0).any():
            i = int(np.argmax(cols[field] <= 0))
            raise ValueError(
                f"{field}: must be > 0, got {float(cols[field][i])!r} for model {models[i]!r}"
            )
    for field, high, unit in (
        ("capacity_kwh", checks.MAX_CAPACITY_KWH, "kWh"),
        ("max_ac_kw", checks.MAX_POWER_KW, "kW"),
        ("max_dc_kw", checks.MAX_POWER_KW, "kW"),
        ("max_ac_discharge_kw", checks.MAX_POWER_KW, "kW"),
        ("max_dc_discharge_kw", checks.MAX_POWER_KW, "kW"),
        ("share", None, ""),
    ):
        _check_bounds(cols[field], field, None, high, unit)
    for field in FLEET_DISCHARGE_COLUMNS:
        if (cols[field] < 0).any():
            i = int(np.argmax(cols[field] < 0))
            raise ValueError(
                f"{field}: must be >= 0 (0 = cannot discharge), got {float(cols[field][i])!r} for model {models[i]!r}"
            )
    t = cols["tau"]
    if ((t <= 0) | (t >= 1)).any():
        i = int(np.argmax((t <= 0) | (t >= 1)))
        raise ValueError(f"tau: must be in (0, 1), got {float(t[i])!r} for model {models[i]!r}")
    cols["share"] = cols["share"] / cols["share"].sum()
    return FleetData(
        name=_validate_name(name),
        models=models,
        **{f: _readonly(a.astype(np.float32)) for f, a in cols.items()},
    )


def read_fleet_csv(path: str | os.PathLike, name: str | None = None) -> FleetData:
    """Read a fleet CSV with columns ``model,share,capacity_kwh,max_ac_kw,max_dc_kw,tau`` and
    optionally ``max_ac_discharge_kw,max_dc_discharge_kw`` (absent: 0, no model discharges);
    any order, extra columns ignored, '#' lines are comments.

    Args:
        path: the CSV file (UTF-8).
        name: the fleet's name; ``None`` takes the file name without its suffix.

    Returns:
        The validated fleet (see `parse_fleet_csv_text`).

    Raises:
        FileNotFoundError: ``path`` is not a file.
        ValueError: the file is not UTF-8, or its content is not a valid fleet.
    """
    text = _read_text(path)
    return parse_fleet_csv_text(text, name=name or Path(path).stem, source=str(path))


def parse_fleet_csv_text(text: str, name: str = "custom", source: str = "<csv>") -> FleetData:
    """Parse the text of a fleet CSV (the format of `read_fleet_csv`) into a validated fleet.

    Blank lines, '#' comment lines and a leading BOM are skipped; the header is matched
    case-insensitively. ``share`` is normalised to sum to 1.

    Args:
        text: the CSV text: a header row, then one row per car model.
        name: the fleet's name.
        source: where the text comes from, for error messages.

    Returns:
        The fleet, its arrays read-only float32 of shape ``(K,)``.

    Raises:
        ValueError: the text is empty, lacks a required column or any data row, a row has
            another number of fields than the header, a value is not a finite number, a
            model name is empty, or a value is out of range (negative or all-zero shares,
            a capacity or charging limit <= 0, a negative discharge limit, ``tau`` outside
            (0, 1), or a magnitude beyond `chargax_marl.core.checks`' bounds).
    """
    rows = _data_rows(text)
    if not rows:
        raise ValueError(f"fleet: {source} is empty; expected a header {','.join(FLEET_COLUMNS)}")
    header = [c.strip().lower() for c in rows[0]]
    missing = [c for c in FLEET_COLUMNS if c not in header]
    if missing:
        raise ValueError(
            f"fleet: {source} lacks column(s) {missing}; expected columns {list(FLEET_COLUMNS)}"
        )
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
    """A bundled fleet by name (`FLEETS`), a `FleetData`, or a CSV path.

    Args:
        source: a bundled fleet's name (``"EU"``, ``"US"``, ``"World"``), a `FleetData`
            (validated again, its shares renormalised), or the path of a fleet CSV (a
            string ending in ``.csv``, containing a path separator or naming a file, or an
            `os.PathLike`).

    Returns:
        The validated fleet; bundled fleets are read once and cached.

    Raises:
        KeyError: ``source`` is a string that is neither a bundled fleet's name nor looks
            like a path.
        ValueError: ``source`` is of another type, or the fleet or CSV is invalid.
        FileNotFoundError: the CSV path is not a file.
    """
    if isinstance(source, FleetData):
        return _make_fleet(
            source.name,
            source.models,
            source.share,
            source.capacity_kwh,
            source.max_ac_kw,
            source.max_dc_kw,
            source.tau,
            source.max_ac_discharge_kw,
            source.max_dc_discharge_kw,
        )
    if isinstance(source, str) and source in FLEETS:
        return _load_bundled_fleet(source)
    if isinstance(source, (str, os.PathLike)):
        if isinstance(source, str) and not _looks_like_path(source):
            raise KeyError(
                f"fleet: unknown fleet {source!r}; valid names are {list(FLEETS)} (or pass a CSV path)"
            )
        return read_fleet_csv(source)
    raise ValueError(
        f"fleet: expected one of {list(FLEETS)}, a FleetData or a CSV path, got {type(source).__name__}"
    )


@functools.cache
def _load_bundled_fleet(name: str) -> FleetData:
    return read_fleet_csv(DATA_DIR / FLEET_FILES[name], name=name)
