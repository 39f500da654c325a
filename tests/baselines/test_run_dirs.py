"""A run directory holds one run: a second training into it is refused unless it resumes or
overwrites, a live run's lock refuses another process, a killed run's lock is taken over, and
the experiment runners' result files follow the same rule."""

from __future__ import annotations

import contextlib
import json
import socket
import subprocess
import sys

import pytest

from baselines import pipeline, runs
from baselines import train as cli
from baselines.experiments import alpha_ablation
from tests.helpers import TINY_CLI, toml_inline

TINY_RUN = [*TINY_CLI, "ALGO=ippo", f"TOTAL_TIMESTEPS={4 * 24}", "CHUNKS=1", "OPTIMAL=off"]
"""The settings of the `tiny_ippo_run` fixture's run (compiled once per session)."""

HOLDER = r"""
import fcntl, json, os, socket, sys
f = open(sys.argv[1], "a+")
fcntl.flock(f, fcntl.LOCK_EX)
f.truncate(0)
f.write(json.dumps({"pid": os.getpid(), "host": socket.gethostname()}))
f.flush()
print("holding", flush=True)
sys.stdin.read()
"""
"""A live process holding a run directory's lock as a training does (``fcntl.flock`` on the
lock file, its PID and host in it) until its stdin closes."""


def _listing(path):
    return sorted(p.name for p in path.iterdir())


def _exited_pid() -> int:
    """The PID of a process that has ended."""
    done = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        capture_output=True,
        text=True,
        check=True,
    )
    return int(done.stdout)


def test_a_second_training_into_a_run_directory_is_refused_and_leaves_it_unchanged(ippo_run):
    before = {name: (ippo_run / name).read_bytes() for name in _listing(ippo_run)}
    with pytest.raises(FileExistsError) as refused:
        cli.main([*TINY_RUN, "LR=0.0001", f"OUT={toml_inline(str(ippo_run))}"])
    message = str(refused.value)
    # the directory, what it holds, how that run differs, and the two ways out
    assert str(ippo_run) in message and "results.json" in message and "ippo" in message
    assert "config LR=" in message and "(this run: 0.0001)" in message
    assert f"--resume {ippo_run}" in message and "--overwrite" in message
    assert {name: (ippo_run / name).read_bytes() for name in _listing(ippo_run)} == before


def test_overwrite_replaces_the_run_a_directory_holds(ippo_run):
    (ippo_run / "notes.txt").write_text("mine")
    old = json.loads((ippo_run / "results.json").read_text())
    cli.main([*TINY_RUN, "SEED=1", "--overwrite", f"OUT={toml_inline(str(ippo_run))}"])
    new = json.loads((ippo_run / "results.json").read_text())
    assert old["seed"] == 0 and new["seed"] == 1
    assert (ippo_run / "notes.txt").read_text() == "mine"  # only the run's own files go
    assert runs.LOCK not in _listing(ippo_run)  # released when the run ends


@contextlib.contextmanager
def held_lock(lock):
    """A live process holding ``lock`` (`HOLDER`) for the block; yields its PID."""
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(lock)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "holding"
        yield holder.pid
    finally:
        holder.stdin.close()
        holder.wait(timeout=60)


def test_a_run_directory_another_live_process_writes_is_refused_naming_its_pid(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    lock = out / ".lock"
    with held_lock(lock) as pid:
        with pytest.raises(FileExistsError, match=f"PID {pid} on host"):
            cli.main([*TINY_RUN, f"OUT={toml_inline(str(out))}"])
        assert json.loads(lock.read_text())["pid"] == pid  # its lock left alone
        assert _listing(out) == [".lock"]


def test_a_replot_of_a_run_another_process_writes_is_refused(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "results.json").write_text("{}")
    with held_lock(out / ".lock") as pid:
        with pytest.raises(FileExistsError, match=f"PID {pid} on host"):
            cli.main(["--replot", str(out), "--references", str(tmp_path / "refs")])
        assert (out / "results.json").read_text() == "{}"
    with pytest.raises(FileNotFoundError, match="no results.json"):
        cli.main(["--replot", str(tmp_path / "missing")])


def test_a_stale_lock_is_taken_over_with_a_message(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    dead = _exited_pid()
    (out / ".lock").write_text(json.dumps({"pid": dead, "host": socket.gethostname()}))
    with runs.claim_run_dir(out) as claimed:
        assert claimed == out
        assert json.loads((out / runs.LOCK).read_text())["pid"] != dead
    err = capsys.readouterr().err
    assert f"stale lock of PID {dead}" in err
    assert _listing(out) == []


def test_the_lock_is_released_when_the_run_raises(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(RuntimeError, match="the run failed"):
        with runs.claim_run_dir(out):
            raise RuntimeError("the run failed")
    assert _listing(out) == []
    with runs.claim_run_dir(out):  # free for the next run
        pass


def test_resume_and_overwrite_together_are_refused(tmp_path):
    with pytest.raises(ValueError, match="give one of them"):
        with runs.claim_run_dir(tmp_path, resume=True, overwrite=True):
            pass


def _refuse_training(monkeypatch):
    """Make an experiment runner fail as soon as it would score or train anything."""

    def trained(*args, **kwargs):
        raise AssertionError("the runner went on to score and train")

    monkeypatch.setattr(alpha_ablation, "baseline_results", trained)
    monkeypatch.setattr(alpha_ablation, "run", trained)


def test_an_experiment_runner_refuses_the_result_files_of_an_earlier_run(tmp_path, monkeypatch):
    _refuse_training(monkeypatch)
    prefix = tmp_path / "ablation"
    (tmp_path / "ablation.json").write_text('{"earlier": true}\n')
    with pytest.raises(FileExistsError) as refused:
        alpha_ablation.main(["--optimal", "off"], out=str(prefix))
    assert "ablation.json" in str(refused.value) and "--overwrite" in str(refused.value)
    assert (tmp_path / "ablation.json").read_text() == '{"earlier": true}\n'
    assert _listing(tmp_path) == ["ablation.json"]  # no lock left behind


def test_an_experiment_runner_with_overwrite_deletes_the_earlier_files(tmp_path, monkeypatch):
    _refuse_training(monkeypatch)
    (tmp_path / "ablation.json").write_text('{"earlier": true}\n')
    with pytest.raises(AssertionError, match="went on to score"):  # past the claim
        alpha_ablation.main(["--optimal", "off", "--overwrite"], out=str(tmp_path / "ablation"))
    assert _listing(tmp_path) == []


def test_an_unusable_run_directory_is_refused_by_name_before_any_work(tmp_path, monkeypatch):
    """An empty OUT made the working directory the run directory; OUT naming a file, or a
    directory where the lock file goes, ended in a bare FileExistsError / IsADirectoryError."""

    def trained(*args, **kwargs):
        raise AssertionError("the run went on to build and train")

    monkeypatch.setattr(pipeline, "_run", trained)
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    with pytest.raises(ValueError, match=r"OUT='' is not allowed: expected a non-empty str"):
        cli.main([*TINY_CLI, "OUT="])
    with pytest.raises(ValueError, match=r"field 'out \(OUT\)' .* an existing file, not a dir"):
        cli.main([*TINY_CLI, f"OUT={a_file}"])
    with pytest.raises(ValueError, match=r"field 'out \(OUT\)' .*a_file' is a file, not a folder"):
        cli.main([*TINY_CLI, f"OUT={a_file}/run"])
    locked = tmp_path / "run"
    (locked / runs.LOCK).mkdir(parents=True)
    with pytest.raises(runs.RunDirError, match=r"its lock file .*\.lock cannot be opened"):
        cli.main([*TINY_CLI, f"OUT={locked}"])
    for key in ("SEEDS=0", "CHUNKS=0", "SEED=-1", "NUM_ENVS=0", "HIDDEN=-4", "LR=-1"):
        with pytest.raises(ValueError, match=rf"{key} is not allowed"):
            cli.main([*TINY_CLI, key, f"OUT={tmp_path}/fresh"])
    with pytest.raises(ValueError, match=r"field 'references_dir' \(REFERENCES_DIR\) must be a"):
        cli.main([*TINY_CLI, f"REFERENCES_DIR={tmp_path}/nowhere", f"OUT={tmp_path}/fresh"])
    with pytest.raises(ValueError, match=r"field 'seeds \(SEEDS\)' must be an integer >= 1"):
        pipeline.run("ippo", {}, seeds=0, out=str(tmp_path / "api"))
    with pytest.raises(ValueError, match=r"prefix.*a prefix needs a file name"):
        with runs.claim_outputs(str(tmp_path) + "/", (".json",)):
            pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "run"]
