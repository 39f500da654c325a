"""Fixtures of the baselines tests: a tiny trained IPPO run, made once per test session."""

from __future__ import annotations

import fcntl
import os
import shutil

import pytest

from baselines import train as cli
from tests.helpers import TINY_CLI, toml_inline


@pytest.fixture(scope="session")
def tiny_ippo_run(tmp_path_factory):
    """The directory of a tiny IPPO run (2 seeds, one update, no optimal references), trained
    once per session: under pytest-xdist the first worker to ask trains it while the others
    wait on a file lock, then read it."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the session's folder, shared by its workers
    out = base / "tiny_ippo_run"
    with open(base / "tiny_ippo_run.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (out / "results.json").exists():
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
    """A copy of `tiny_ippo_run` that a test may change."""
    out = tmp_path / "run"
    shutil.copytree(tiny_ippo_run, out)
    return out
