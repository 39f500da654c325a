"""Fixtures of the baselines tests: a tiny trained IPPO run, made once per test process."""

from __future__ import annotations

import shutil

import pytest

from baselines import train as cli
from tests.helpers import TINY_CLI, toml_inline


@pytest.fixture(scope="session")
def tiny_ippo_run(tmp_path_factory):
    """The directory of a tiny IPPO run (2 seeds, one update, no optimal references)."""
    out = tmp_path_factory.mktemp("tiny_ippo") / "run"
    cli.main(
        [
            *TINY_CLI,
            "ALGO=ippo",
            f"TOTAL_TIMESTEPS={4 * 24}",
            "CHUNKS=1",
            "OPTIMAL=off",
            f"OUT={toml_inline(str(out))}",
        ]
    )
    return out


@pytest.fixture
def ippo_run(tiny_ippo_run, tmp_path):
    """A copy of :func:`tiny_ippo_run` that a test may change."""
    out = tmp_path / "run"
    shutil.copytree(tiny_ippo_run, out)
    return out
