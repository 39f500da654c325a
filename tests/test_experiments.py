"""The cross-market runner's bookkeeping (``baselines/experiments/cross_market.py``), on made-up numbers.

The training and evaluation it calls are tested in ``test_baselines.py``; an end-to-end run of a
runner compiles several programs (minutes on 2 cores), so it is not part of the suite.
"""

from __future__ import annotations

import numpy as np

from baselines.experiments import cross_market as cm

EXPERIMENTS = {"NL-2023": ("NL-2023", "DE-2023", "FR-2023")}


def _ev(daily):
    daily = np.asarray(daily, np.float64)
    return {"metrics": {"daily_profit_eur": {"mean": float(daily.mean()), "std": float(daily.std())}}, "daily_profit": daily}


def _fake():
    rng = np.random.default_rng(0)
    ref = {m: rng.normal(1000, 100, size=(2, 6)) for m in ("NL-2023", "DE-2023", "FR-2023")}
    matrix = {"NL-2023": {m: _ev(ref[m] - 10.0 * (m != "NL-2023")) for m in ref},
              "DE-2023": {"DE-2023": _ev(ref["DE-2023"])}}  # FR-2023 has no in-market agent (--no-reference)
    baselines = {m: {"always_max": _ev(ref[m][0]), "price_threshold": _ev(ref[m][1] - 300)} for m in ref}
    return matrix, baselines


def test_default_pairs_are_the_issue_s():
    assert cm.EXPERIMENTS == {"NL-2023": ("NL-2023", "DE-2023", "FR-2023"),
                              "NL-2021": ("NL-2021", "NL-2022", "DE-2022", "FR-2022")}


def test_transfer_gap_is_the_paired_difference_to_the_in_market_agent():
    matrix, _ = _fake()
    gaps = cm.transfer_gaps(matrix, EXPERIMENTS)
    assert set(gaps) == {"NL-2023"} and set(gaps["NL-2023"]) == {"DE-2023"}  # no self-gap, no missing reference
    g = gaps["NL-2023"]["DE-2023"]
    cross, ref = matrix["NL-2023"]["DE-2023"]["daily_profit"], matrix["DE-2023"]["DE-2023"]["daily_profit"]
    assert np.isclose(g["mean"], (cross - ref.mean(axis=0)).mean())
    assert len(g["per_seed_mean"]) == 2 and g["stderr"] > 0


def test_summary_and_plot(tmp_path):
    matrix, baselines = _fake()
    text = cm.summary(matrix, baselines, cm.transfer_gaps(matrix, EXPERIMENTS), EXPERIMENTS)
    assert "NL-2023 -> DE-2023" in text and "NL-2023 -> FR-2023" in text and "      -" in text
    path = tmp_path / "cm.png"
    cm.plot(matrix, baselines, EXPERIMENTS, "ppo", path)
    assert path.read_bytes()[:4] == b"\x89PNG"


def test_traffic_sweep_appendix_conditions_build_valid_params():
    """``traffic_sweep --appendix``: the four bundled profiles (EU fleet) and the US / World
    fleets (shopping), each a config whose env parameters build; the default is the main figure."""
    from baselines import common
    from baselines.experiments import traffic_sweep as ts

    assert ts.conditions() == [("shopping", "EU")]
    cells = ts.conditions(ts.PROFILES, ts.FLEETS)
    assert cells == [("shopping", "EU"), ("residential", "EU"), ("workplace", "EU"), ("highway", "EU"),
                     ("shopping", "US"), ("shopping", "World")]
    shares = {}
    for profile, fleet in cells:
        cfg = common.parse_config({}, ts.condition_config({"ENV_KWARGS": {"num_levels": 1}}, profile, fleet, "high"))
        train_params, full, _, days = common.build_env_params(cfg)
        assert cfg["ENV_KWARGS"] == {"num_levels": 1, "fleet": fleet} and np.size(days) == 100
        shares[fleet] = np.asarray(full.fleet_capacity_kwh)
    assert not np.array_equal(shares["EU"], shares["US"])  # the fleet really changes
