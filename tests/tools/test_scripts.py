"""Smoke tests of the command-line entry points on the smallest settings."""

from __future__ import annotations

import importlib.util
from pathlib import Path

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
