"""Shared fixtures: small stations and their parameters, built once per session."""

from __future__ import annotations

import gc
import os
from pathlib import Path

# One persistent JAX compilation cache for the whole session, set before JAX is imported: the
# test processes (pytest-xdist workers) and the command-line runs they start in subprocesses
# (which inherit the environment) compile each program once between them. The folder is
# git-ignored; a fresh clone starts with it empty.
_CACHE = Path(__file__).resolve().parents[1] / ".pytest_cache" / "jax-compilation"
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(_CACHE))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.1")
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
# The tests' programs are small and compiled once or twice each, so compiling dominates: the
# cheap LLVM pipeline, with fusions emitted by XLA's elemental emitter rather than its MLIR
# fusion emitters (which dominate compile time once LLVM's optimisation is off). It leaves
# XLA's own passes (fusion, algebraic simplification) as they are. Each program's machine code
# is generated as one piece, not split for parallel code generation: the test workers already
# keep every core busy, and the split's threads cost more than they save. The processes the
# tests start inherit these flags, unless a test sets XLA_FLAGS for its process itself.
FAST_COMPILE = (
    "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
    " --xla_cpu_use_fusion_emitters=false --xla_cpu_parallel_codegen_split_count=1"
)
os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {FAST_COMPILE}".strip()

# Each test process traces and compiles thousands of programs and keeps them cached, so its
# heap grows large; at Python's default thresholds the cyclic garbage collector ran thousands
# of collections over it. Collecting the youngest generation every 50,000 allocations, not
# 700, and the older ones correspondingly less often leaves what a collection frees the same
# (cycles are still collected) and the processes' memory within the machine's.
gc.set_threshold(50_000, 20, 100)

import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

from chargax_marl.core import make_params  # noqa: E402
from tests.helpers import mixed_station, three_level_station  # noqa: F401, E402

# CI runs the property tests on a fixed example sequence, so a red CI is reproducible;
# locally they explore new examples on every run.
settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


@pytest.fixture(autouse=True)
def _environment_left_as_found():
    """Fail a test that leaves ``os.environ`` changed (use ``monkeypatch.setenv``): every later
    test of its worker, and every process those tests start (command-line runs inherit the
    environment), would run under the change: a host device count left in ``XLA_FLAGS``, for
    one, gives every later subprocess that many devices, and a sharded program's numbers.

    A variable that was set must keep its value; a new one is an error only when it is JAX's
    or XLA's, since a third-party package adds its own settings the first time a test imports
    it (pygame's ``SDL_AUDIODRIVER``). pytest's ``PYTEST_CURRENT_TEST`` is left out."""
    before = dict(os.environ)
    yield
    after = dict(os.environ)
    changed = sorted(
        k
        for k in before.keys() | after.keys()
        if k != "PYTEST_CURRENT_TEST"
        and before.get(k) != after.get(k)
        and (k in before or k.startswith(("JAX_", "XLA_")))
    )
    if changed:
        pytest.fail(
            "the test left os.environ changed: "
            + ", ".join(f"{k}: {before.get(k)!r} -> {after.get(k)!r}" for k in changed)
        )


@pytest.fixture(scope="session")
def small_params():
    """A 6-port, 3-level station with a battery, busy traffic so cars come and go."""
    return make_params(station=three_level_station(), traffic=150.0)


@pytest.fixture(scope="session")
def default_params():
    return make_params()
