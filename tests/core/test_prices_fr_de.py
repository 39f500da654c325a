"""FR-2020 ... FR-2024 and DE-2020 ... DE-2024: ENTSO-E day-ahead prices via green-dcc.

The bundled files are checked on their own (shape, range, weekday, index) and, where the
shared source folder ``../shared/data/entsoe-day-ahead/`` exists, recomputed from the raw
CSVs hour by hour: every filled day must be the copy the documented rule names, every other
hour the raw price (or the DST value the rule gives).
"""

from __future__ import annotations

import csv
import datetime as dt
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from chargax_marl.core import datasets as ds

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared" / "data" / "entsoe-day-ahead"
ZONE_FILE = {"FR": "FR", "DE": "DE-LU"}
NAMES = tuple(f"{z}-{y}" for z in ("FR", "DE") for y in range(2020, 2025))


def _index() -> dict:
    return json.loads((ds.DATA_DIR / ds.ENTSOE_PRICE_INDEX_FILE).read_text(encoding="utf-8"))


def _raw_rows(name: str) -> list[tuple[dt.datetime, float]]:
    zone, year = name.split("-")
    path = SHARED / f"{ZONE_FILE[zone]}_{year}.csv"
    if not path.is_file():
        pytest.skip(f"shared source folder missing: {path}")
    with path.open(encoding="utf-8") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["Datetime", "Price (EUR/MWh)"]
    return [(dt.datetime.strptime(r[0], "%Y-%m-%d %H:%M:%S"), float(r[1])) for r in rows[1:]]


def _last_sunday(year: int, month: int) -> dt.date:
    d = dt.date(year, month, 31)
    return d - dt.timedelta(days=(d.weekday() + 1) % 7)


def test_names_and_index():
    assert ds.ENTSOE_PRICE_DATASETS == NAMES
    assert set(NAMES) <= set(ds.list_price_datasets())
    index = _index()
    assert tuple(index["datasets"]) == NAMES
    assert (
        "HewlettPackard/green-dcc" in index["source"]
        and "3f6ea95cb835b89ba50b0ef76d66d14b8037643e" in index["source"]
    )
    assert "MIT" in index["licence"] and "ENTSO-E" in index["licence"]
    for name, e in index["datasets"].items():
        assert (
            e["file"] == f"prices_{name.replace('-', '_')}.csv"
            and (ds.DATA_DIR / e["file"]).is_file()
        )
        assert e["dst_gap_filled"] == 1 and e["interpolated"] == 0


@pytest.mark.parametrize("name", NAMES)
def test_dataset_shape_range_weekday(name):
    year = int(name[-4:])
    p = ds.load_prices(name)
    a = p.prices_eur_kwh
    days = 366 if year in (2020, 2024) else 365
    assert a.shape == (days, 24) and a.dtype == np.float32
    assert np.isfinite(a).all()
    # EUR/kWh; negative prices are allowed, down to the -500 EUR/MWh floor; the day-ahead cap is 4000 EUR/MWh
    assert -0.5 <= a.min() and a.max() <= 4.0
    assert 0.02 < a.mean() < 0.3
    assert (
        p.first_weekday
        == dt.date(year, 1, 1).weekday()
        == _index()["datasets"][name]["first_weekday"]
    )
    assert a[:, 18:20].mean() > a[:, 3:5].mean()  # evenings dearer than nights


def test_price_crisis_2022_and_extremes():
    mean = {n: float(ds.load_prices(n).prices_eur_kwh.mean()) for n in NAMES}
    for zone in ("FR", "DE"):
        years = {n: m for n, m in mean.items() if n.startswith(zone)}
        assert max(years, key=years.get) == f"{zone}-2022" and years[f"{zone}-2022"] > 0.2
    fr22 = ds.load_prices("FR-2022").prices_eur_kwh
    assert fr22.max() == pytest.approx(2.98778, abs=1e-6)  # 2022-04-04 08:00
    assert ds.load_prices("DE-2023").prices_eur_kwh.min() == pytest.approx(-0.5, abs=1e-9)


@pytest.mark.parametrize("name", NAMES)
def test_every_hour_follows_the_rules(name):
    """Recompute each day from the raw CSV: copied days, DST hours and plain hours."""
    year = int(name[-4:])
    raw = _raw_rows(name)
    a = ds.load_prices(name).prices_eur_kwh.astype(np.float64) * 1000.0
    start = dt.date(year, 1, 1)
    # drop rows listed out of chronological order (the 0.0 placeholders of the source)
    keep = [r for i, r in enumerate(raw) if not (i + 1 < len(raw) and r[0] > raw[i + 1][0])]
    dropped = [r for r in raw if r not in keep]
    assert all(v == 0.0 for _, v in dropped)
    by_day: dict[dt.date, dict[int, list[float]]] = {}
    for t, v in keep:
        by_day.setdefault(t.date(), {}).setdefault(t.hour, []).append(v)
    spring, autumn = _last_sunday(year, 3), _last_sunday(year, 10)
    missing = []
    for d in range(a.shape[0]):
        day = start + dt.timedelta(days=d)
        if day not in by_day:
            missing.append(day)
            continue
        hours = by_day[day]
        assert sorted(hours) == list(range(24)), day
        for h in range(24):
            if day == spring and h == 2:
                expect = (hours[1][0] + hours[3][0]) / 2  # 02:00 does not exist: interpolated
            else:
                expect = sum(hours[h]) / len(hours[h])  # a repeated autumn 02:00 would be averaged
                assert len(hours[h]) == 1 or (day == autumn and h == 2), (day, h)
            assert a[d, h] == pytest.approx(expect, abs=6e-4 + 1e-7 * abs(expect)), (day, h)
    # whole missing days: the same weekday one week later, exactly
    copies = []
    for day in missing:
        src = day + dt.timedelta(days=7)
        assert src in by_day, f"{day}: the rule would need another neighbour"
        d, s = (day - start).days, (src - start).days
        np.testing.assert_array_equal(a[d], a[s])
        copies.append(f"{day} <- {src}")
    entry = _index()["datasets"][name]
    assert entry["days_copied_from_week_neighbour"] == copies
    assert len(entry["out_of_order_rows_dropped"]) == len(dropped)


def test_filled_days_are_the_documented_ones():
    copied = {n: e["days_copied_from_week_neighbour"] for n, e in _index()["datasets"].items()}
    assert copied == {
        "FR-2020": ["2020-01-31 <- 2020-02-07", "2020-09-26 <- 2020-10-03"],
        "FR-2021": [],
        "FR-2022": ["2022-09-03 <- 2022-09-10"],
        "FR-2023": ["2023-11-30 <- 2023-12-07"],
        "FR-2024": [],
        "DE-2020": [
            "2020-09-26 <- 2020-10-03",
            "2020-11-01 <- 2020-11-08",
            "2020-11-16 <- 2020-11-23",
            "2020-11-17 <- 2020-11-24",
            "2020-11-19 <- 2020-11-26",
        ],
        "DE-2021": ["2021-04-30 <- 2021-05-07"],
        "DE-2022": ["2022-09-03 <- 2022-09-10"],
        "DE-2023": [],
        "DE-2024": ["2024-01-31 <- 2024-02-07"],
    }
    readme = (ds.DATA_DIR / "README.md").read_text(encoding="utf-8")
    for name, pairs in copied.items():
        for pair in pairs:
            day, src = pair.split(" <- ")
            assert f"| `{name}` | {day} (" in readme and f"| {src} |" in readme, pair


def _build_module():
    spec = importlib.util.spec_from_file_location(
        "_build_data_for_tests", ROOT / "scripts" / "build_data.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_missing_shared_folder_is_a_clear_error(tmp_path):
    bd = _build_module()
    assert bd.ENTSOE_DIR == ROOT.parent / "shared" / "data" / "entsoe-day-ahead"
    with pytest.raises(
        bd.SharedDataUnavailable, match=r"not found: .*\.\./shared/data/entsoe-day-ahead"
    ):
        bd.build_entsoe_prices(tmp_path / "out", src_dir=tmp_path / "nowhere")


def test_summary_describe_and_pngs():
    from chargax_marl import data

    by = {r["name"]: r for r in data.summary()}
    for name in NAMES:
        row = by[name]
        assert row["kind"] == "prices" and row["licence"] == "MIT (via green-dcc)"
        assert "ENTSO-E" in row["source"] and "HewlettPackard/green-dcc" in row["source"]
        assert ("(DE-LU)" if name.startswith("DE") else "(FR)") in row["source"]
        assert (ROOT / "docs" / f"prices_{name}.png").is_file()
    text = data.describe("DE-2022")
    assert "green-dcc" in text and "negative hours" in text
