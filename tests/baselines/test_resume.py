"""A killed training run continues from its checkpoint: SIGKILL at a random
point after the first chunk, ``--resume``, and the run ends as an uninterrupted one does."""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from baselines import runs
from baselines import train as cli
from baselines.config import ConfigError
from tests.helpers import toml_inline

ROOT = Path(__file__).resolve().parents[2]

# Four chunks of one update each, two held-out days, no LP bound: every chunk writes a checkpoint.
RESUME_CLI = [
    "--config",
    "cpu",
    "ALGO=ppo",
    "SEEDS=2",
    "NUM_ENVS=4",
    "NUM_STEPS=24",
    "HIDDEN=16",
    "BATTERY_SHAPING=false",
    f"ENV_KWARGS={toml_inline({'station': 'single_type', 'station_kwargs': {'num_ports': 2}, 'step_minutes': 60.0})}",
    f"TOTAL_TIMESTEPS={4 * 4 * 24}",
    "CHUNKS=4",
    "NUM_EVAL_DAYS=2",
    "NUM_VALIDATION_DAYS=2",  # as many as held out: both evaluations share their programs
    "OPTIMAL=off",
]

TIMINGS = {"wall_seconds", "train_seconds_incl_compile", "train_seconds", "wall_minutes"}
"""The keys of ``results.json`` that hold wall-clock times, which differ between any two runs."""


def _without_timings(x):
    if isinstance(x, dict):
        return {k: _without_timings(v) for k, v in x.items() if k not in TIMINGS}
    if isinstance(x, list):
        return [_without_timings(v) for v in x]
    return x


def _train_in_a_subprocess(args):
    """``python -m baselines.train ARGS`` in a subprocess, which inherits the session's
    compilation cache (``tests/conftest.py``) and so loads the programs this process compiled."""
    cmd = [sys.executable, "-m", "baselines.train", *args]
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    return subprocess.Popen(
        cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )


def test_killed_run_resumes_to_the_uninterrupted_result(tmp_path, capsys):
    """Only the run that is killed needs a process of its own: the uninterrupted run and the
    resumption run in this one, through the same entry point (``baselines.train.main``)."""
    full, killed = tmp_path / "full", tmp_path / "killed"
    cli.main([*RESUME_CLI, f"OUT={toml_inline(str(full))}"])

    proc = _train_in_a_subprocess([*RESUME_CLI, f"OUT={toml_inline(str(killed))}"])
    checkpoint = killed / runs.CHECKPOINT
    deadline = time.time() + 600
    while not checkpoint.exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    assert checkpoint.exists(), "the run wrote no checkpoint after its first chunk: " + (
        proc.communicate()[0].decode()[-3000:] if proc.poll() is not None else "still running"
    )
    time.sleep(random.uniform(0.0, 0.5))  # a random point after the first chunk
    assert proc.poll() is None, "the run finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    done = runs.load_checkpoint(checkpoint)["next_chunk"]
    assert 1 <= done <= 4

    capsys.readouterr()
    cli.main(["--resume", str(killed)])
    assert "wrote" in capsys.readouterr().out
    assert (killed / "params.msgpack").read_bytes() == (full / "params.msgpack").read_bytes()
    a = json.loads((full / "results.json").read_text())
    b = json.loads((killed / "results.json").read_text())
    assert _without_timings(b) == _without_timings(a)
    assert len(b["eval_curve"]) == 4

    # a run resumed from a checkpoint that holds every chunk trains no further and evaluates
    # the final policy itself: the same results again
    again = tmp_path / "again"
    shutil.copytree(full, again)
    (again / "results.json").unlink()
    cli.main(["--resume", str(again)])
    assert "evaluating the trained greedy policy" in capsys.readouterr().out
    c = json.loads((again / "results.json").read_text())
    assert _without_timings(c) == _without_timings(a)


def test_resume_refuses_overrides_and_a_missing_checkpoint(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        cli.main(["--resume", str(tmp_path)])
    with pytest.raises(ConfigError, match="own settings"):
        cli.main(["--resume", str(tmp_path), "SEEDS=3"])


def _state():
    return {"w": jnp.arange(6.0).reshape(2, 3), "key": jnp.zeros((2, 2), jnp.uint32)}


def test_a_kill_while_writing_leaves_the_previous_checkpoint_readable(tmp_path, monkeypatch):
    path = tmp_path / runs.CHECKPOINT
    run = {"algo": "ppo", "config": {"LR": 0.001}}
    progress = {"metrics": [{"loss": np.ones((2, 1), np.float32)}], "evals": [None], "seconds": 1.5}
    runs.save_checkpoint(path, run, 1, _state(), progress)

    # the next write dies half-way through its bytes (as a SIGKILL inside write would)
    real_open = open

    class HalfFile:
        def __init__(self, f):
            self.f = f

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def write(self, data):
            self.f.write(data[: len(data) // 2])
            raise KeyboardInterrupt("killed while writing")

    def dying_open(file, mode="r", *args, **kwargs):
        f = real_open(file, mode, *args, **kwargs)
        return HalfFile(f) if "w" in mode else f

    monkeypatch.setattr("builtins.open", dying_open)
    later = {**progress, "seconds": 9.0}
    with pytest.raises(KeyboardInterrupt):
        runs.save_checkpoint(path, run, 2, {**_state(), "w": _state()["w"] + 1}, later)
    monkeypatch.undo()

    back = runs.load_checkpoint(path, _state())
    assert back["next_chunk"] == 1 and back["run"] == run
    np.testing.assert_array_equal(back["runner_state"]["w"], _state()["w"])
    assert back["runner_state"]["key"].dtype == jnp.uint32
    assert back["progress"]["seconds"] == 1.5 and back["progress"]["evals"] == [None]
    np.testing.assert_array_equal(back["progress"]["metrics"][0]["loss"], np.ones((2, 1)))
    assert [p.name for p in tmp_path.iterdir()] == [runs.CHECKPOINT]  # no stray temp file

    # a file cut short (a copy interrupted outside these writers) is refused, not misread
    path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(ValueError, match="not a readable training checkpoint"):
        runs.load_checkpoint(path)
    # and a state of another shape is refused with the reason
    runs.save_checkpoint(path, run, 1, _state(), progress)
    with pytest.raises(ValueError, match="does not match"):
        runs.load_checkpoint(path, {"w": jnp.zeros((3,)), "key": jnp.zeros((2, 2), jnp.uint32)})
