"""Smoke tests of the command-line entry points on the smallest settings."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load(path: str):
    spec = importlib.util.spec_from_file_location(Path(path).stem, ROOT / path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_throughput_benchmark_runs(capsys):
    rows = load("benchmarks/throughput.py").main(["--envs", "1", "2", "--steps", "288", "--repeats", "1"])
    assert [r["envs"] for r in rows] == [1, 2]
    assert all(r["env_steps_per_s"] > 0 and r["compile_s"] > 0 for r in rows)
    assert "env-steps/s" in capsys.readouterr().out


def test_rollout_prints_the_days_figures(capsys):
    from chargax_marl.rollout import main

    main(["--days", "2", "--scenario", "highway-low"])
    out = capsys.readouterr().out
    for label in ("daily profit", "energy delivered", "cars served"):
        assert label in out
