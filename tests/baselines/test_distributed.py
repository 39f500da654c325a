"""The multi-host path: ``python -m baselines.train`` as two ``jax.distributed`` processes.

Two processes on this machine, one CPU device each, talk through a coordinator on a free
localhost port and gloo CPU collectives; the env batch is sharded over the two devices, so
every rollout step crosses processes. A single process with two host devices runs the same
command beside them: the sharded program must learn the same thing either way. Tiny budget:
a 4-port station with 60-minute steps, 2 updates of 4 envs x 24 steps, 2 held-out days. The
station has no battery: every process scores the references before it trains, and a battery
adds the teachers' battery and plan programmes to them (with 4 days, about a quarter of each
process's time); the sharding and the collectives are the same with or without a battery head.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import flax.serialization
import jax
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]

ARGS = [
    "--config",
    "cpu",
    "ALGO=ppo",
    f"TOTAL_TIMESTEPS={2 * 4 * 24}",
    "SEEDS=2",
    "SEED=3",
    "NUM_ENVS=4",
    "NUM_STEPS=24",
    "HIDDEN=16",
    "NUM_MINIBATCHES=2",
    "UPDATE_EPOCHS=1",
    "CHUNKS=1",
    "NUM_EVAL_DAYS=2",
    "NUM_VALIDATION_DAYS=2",  # as many as held out: both evaluations share their programs
    "OPTIMAL=off",
    'ENV_KWARGS={ station = "single_type", station_kwargs = { num_ports = 4, battery = false }, step_minutes = 60.0 }',
]
TIMEOUT_S = 480  # three compiles on 2 shared cores


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _launch(args, devices: int, log: Path) -> subprocess.Popen:
    # the session's flags (the cheap LLVM pipeline of tests/conftest.py) and the device count
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}"
    env = {
        **os.environ,
        "JAX_PLATFORMS": "cpu",
        "XLA_FLAGS": flags,
        "PYTHONPATH": str(ROOT),
        "TQDM_DISABLE": "1",
    }
    env.pop("JAX_ENABLE_X64", None)
    return subprocess.Popen(
        [sys.executable, "-m", "baselines.train", *ARGS, *args],
        cwd=ROOT,
        env=env,
        stdout=log.open("w"),
        stderr=subprocess.STDOUT,
        text=True,
    )


def _wait_all(procs: dict, logs: dict) -> None:
    """Wait for every process; on a timeout or a failure kill the others and show every log."""
    deadline = time.monotonic() + TIMEOUT_S
    try:
        for p in procs.values():
            p.wait(timeout=max(1.0, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
        pass
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    codes = {name: p.returncode for name, p in procs.items()}
    if any(codes.values()):
        pytest.fail(
            f"exit codes {codes} (a negative code: killed after {TIMEOUT_S} s)\n"
            + "\n".join(f"----- {name} -----\n{logs[name].read_text()[-4000:]}" for name in procs)
        )


def _params(path: Path):
    return jax.tree.leaves(flax.serialization.msgpack_restore(path.read_bytes()))


def test_two_process_training_matches_one_process_with_two_devices(tmp_path):
    port = _free_port()
    outs = {name: tmp_path / name for name in ("proc0", "proc1", "single")}
    logs = {name: tmp_path / f"{name}.log" for name in outs}
    dist = ["--coordinator", f"127.0.0.1:{port}", "--num-processes", "2"]
    procs = {
        f"proc{i}": _launch(
            [*dist, "--process-id", str(i), f"OUT='{outs[f'proc{i}']}'"], 1, logs[f"proc{i}"]
        )
        for i in range(2)
    }
    procs["single"] = _launch([f"OUT='{outs['single']}'"], 2, logs["single"])
    _wait_all(procs, logs)

    # only process 0 wrote outputs (process 1 got its own --out, which must not exist) and printed
    assert {p.name for p in outs["proc0"].iterdir()} == {
        "curve.png",
        "results.json",
        "params.msgpack",
    }
    assert not outs["proc1"].exists()
    assert "wrote" in logs["proc0"].read_text() and "wrote" not in logs["proc1"].read_text()

    dist_res = json.loads((outs["proc0"] / "results.json").read_text())
    single = json.loads((outs["single"] / "results.json").read_text())
    # the mesh really spanned two processes with one device each
    assert dist_res["num_processes"] == 2 and len(dist_res["devices"]) == 2
    assert single["num_processes"] == 1 and len(single["devices"]) == 2

    # the same sharded program over 2 processes or 2 local devices: same training, same policy
    for k in ("episode_return", "value_loss", "actor_loss", "entropy"):
        np.testing.assert_allclose(
            dist_res["curve"][k], single["curve"][k], rtol=1e-4, atol=1e-5, err_msg=k
        )
    for a, b in zip(
        _params(outs["proc0"] / "params.msgpack"),
        _params(outs["single"] / "params.msgpack"),
        strict=True,
    ):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(
        dist_res["eval_curve"][-1]["per_seed_profit"],
        single["eval_curve"][-1]["per_seed_profit"],
        rtol=1e-4,
        atol=1e-3,
    )
    assert dist_res["evaluation"]["num_days"] == 2 and dist_res["timesteps"] == 2 * 4 * 24
