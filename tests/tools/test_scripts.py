"""Smoke tests of the command-line entry points on the smallest settings."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def load(path: str):
    spec = importlib.util.spec_from_file_location(Path(path).stem, ROOT / path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_rollout_prints_the_days_figures(capsys):
    from chargax_marl.rollout import main

    main(["--days", "2", "--scenario", "highway-low"])
    out = capsys.readouterr().out
    for label in ("daily profit", "energy delivered", "cars served"):
        assert label in out


def test_the_library_commands_refuse_a_count_below_one_before_any_work(capsys):
    """``--days 0`` (or -1) reached a JAX split of zero keys, or split_days, in a traceback."""
    from chargax_marl.binding import main as binding_main
    from chargax_marl.rollout import main as rollout_main

    for main, args in (
        (rollout_main, ["--days", "0"]),
        (rollout_main, ["--days", "1", "--seed", "-1"]),
        (binding_main, ["--days", "-1"]),
    ):
        with pytest.raises(SystemExit) as refused:
            main(args)
        assert refused.value.code == 2
        assert "must be an integer" in capsys.readouterr().err


def _run_results(profit_eur: float, always_max_eur: float) -> dict:
    """A ``results.json`` of a two-seed run scored against always-max only."""
    diff = profit_eur - always_max_eur
    metrics = {"daily_profit_eur": {"mean": profit_eur}, "battery_wear_eur": {"mean": 1.5}}
    return {
        "algo": "ippo",
        "scenario": {"name": "shopping", "car_draws_per_day": 8},
        "timesteps": 600000,
        "seeds": 2,
        "wall_seconds": 90.0,
        "over_seeds": {
            "vs_always_max": {"mean": diff, "stderr": 0.5},
            "headroom_fraction": {"mean": 0.25, "stderr": 0.01},
        },
        "per_seed": [
            {"vs_always_max": {"mean": diff + 1.0, "stderr": 0.2}},
            {"vs_always_max": {"mean": diff - 1.0, "stderr": 2.0}},
        ],
        "evaluation": {
            "table": {
                "always_max": {"metrics": {"daily_profit_eur": {"mean": always_max_eur}}},
                "ippo": {"metrics": metrics},
            }
        },
    }


def test_training_table_prints_each_run_and_how_far_it_moved(tmp_path, capsys):
    script = load("scripts/training_table.py")
    for name, profit in (("run", 460.0), ("run_old", 464.0)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "results.json").write_text(json.dumps(_run_results(profit, 455.0)))
    script.main([str(tmp_path / "run"), "--compare", str(tmp_path), "--old-suffix", "_old"])
    out = capsys.readouterr().out
    # seed 0 is above always-max by two of its standard errors (6 > 0.4), seed 1 is not (4 < 4)
    assert "| `run` | IPPO | `shopping` | 8 | 6e+05 × 2 | 1.5 min | +5.00 ± 0.50 (1/2) |" in out
    assert "| — | — | — | 0.250 ± 0.010 |" in out
    assert "| battery wear EUR/day | — | 1.50 |" in out
    assert "profit 464.00 → 460.00 (−4.00); vs always-max +9.00 → +5.00 (−4.00)" in out


def test_plot_curve_redraws_a_committed_run_without_touching_it(tmp_path, capsys):
    """``scripts/plot_curve.py`` (the docs' learning curve) draws from the run's results.json
    into the given file and leaves the run's own files as they are."""
    script = load("scripts/plot_curve.py")
    run = ROOT / "results/ippo_shopping_v2"
    before = {p.name: p.stat().st_mtime_ns for p in run.iterdir()}
    path = script.main([str(run), str(tmp_path / "curve.png")])
    assert path == tmp_path / "curve.png" and path.stat().st_size > 0
    assert f"wrote {path}" in capsys.readouterr().out
    assert {p.name: p.stat().st_mtime_ns for p in run.iterdir()} == before
