"""The committed `results/` stays lean: what the pages and the scoreboard replay, not the
resume state of runs.

The budget, checked on the files git tracks (on a fresh clone, every file there):

- no run's `checkpoint.msgpack` (the optimiser and env states a resumption reads; the command
  that made a run re-creates it, `results/README.md`);
- every file at most `FILE_BUDGET_BYTES`;
- the whole folder at most `FOLDER_BUDGET_BYTES`.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
FILE_BUDGET_BYTES = 4 * 2**20
FOLDER_BUDGET_BYTES = 64 * 2**20


def _tracked() -> list[Path]:
    """The files of `results/` that git tracks; every file there where git is absent."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z", "results"],
            cwd=ROOT,
            capture_output=True,
            check=True,
            text=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        return [p for p in RESULTS.rglob("*") if p.is_file()]
    return [ROOT / name for name in out.split("\0") if name and (ROOT / name).is_file()]


FILES = _tracked()


def test_the_walk_sees_the_committed_runs():
    assert any(p.name == "results.json" for p in FILES)
    assert any(p.name == "params.msgpack" for p in FILES)


def test_no_checkpoint_is_committed():
    checkpoints = [str(p.relative_to(ROOT)) for p in FILES if p.name == "checkpoint.msgpack"]
    assert not checkpoints, (
        f"resume state committed (git rm it; .gitignore skips it): {checkpoints}"
    )


def test_every_file_within_its_budget():
    big = {str(p.relative_to(ROOT)): p.stat().st_size for p in FILES}
    big = {name: size for name, size in big.items() if size > FILE_BUDGET_BYTES}
    assert not big, f"files over {FILE_BUDGET_BYTES} bytes in results/: {big}"


def test_the_folder_within_its_budget():
    total = sum(p.stat().st_size for p in FILES)
    assert total <= FOLDER_BUDGET_BYTES, (
        f"results/ holds {total} bytes, over its budget of {FOLDER_BUDGET_BYTES}: commit what "
        "the pages replay (results.json, params.msgpack, curve.png), not the whole run"
    )


def test_git_ignores_the_resume_state():
    path = "results/some_run/checkpoint.msgpack"
    done = subprocess.run(["git", "check-ignore", "-q", path], cwd=ROOT, check=False)
    if done.returncode == 128:
        pytest.skip("not a git checkout")
    assert done.returncode == 0, f"{path} is not ignored by .gitignore"
