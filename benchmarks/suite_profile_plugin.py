"""The pytest plugin of `suite_profile.py` (``-p benchmarks.suite_profile_plugin``): in every
process that runs tests (each pytest-xdist worker) it listens to JAX's compile events and charges
the trace, lower and compile seconds of each to the test running at the time (fixtures
included), and the process that reports to the terminal keeps each test's seconds. It starts
listening at the first test, so the compiles of collection (imports) are not counted; events
between tests go to ``<outside tests>``. Each process writes its records as JSON to the folder
named by ``CHARGAX_SUITE_PROFILE_DIR``; unset, the plugin records nothing.

This module does not import jax: imported before the tests, it would read jax's settings before
``tests/conftest.py`` sets the compilation cache.
"""

from __future__ import annotations

import collections
import json
import os
import sys
from pathlib import Path

OUT_DIR_ENV = "CHARGAX_SUITE_PROFILE_DIR"
"""The folder the plugin writes its records to; unset, the plugin records nothing."""

OUTSIDE = "<outside tests>"
PHASES = {
    "/jax/core/compile/jaxpr_trace_duration": "trace_s",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
    "/jax/core/compile/backend_compile_duration": "compile_s",
}

_jax_events: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
_programs: list[tuple[str, str, float]] = []  # (test, function, compile seconds)
_durations: collections.Counter = collections.Counter()
# "process": the xdist worker's id, or "main" for the process that reports to the terminal;
# "listening": whether the JAX listener is registered
_state: dict = {"process": "main", "listening": False}


def pytest_configure(config) -> None:
    worker = getattr(config, "workerinput", None)  # set by pytest-xdist in its workers
    _state["process"] = worker["workerid"] if worker else "main"


def _current_test() -> str:
    current = os.environ.get("PYTEST_CURRENT_TEST")
    return current.rsplit(" ", 1)[0] if current else OUTSIDE


def on_event(event: str, duration_s: float, **kwargs) -> None:
    """A ``jax.monitoring`` duration listener: charges trace, lower and compile seconds to the
    running test, and records each XLA compile with its function's name.

    Args:
        event: the JAX monitoring event name.
        duration_s: its duration (seconds).
        **kwargs: the event's fields (``fun_name`` for the compile events).
    """
    phase = PHASES.get(event)
    if phase is None:
        return
    test = _current_test()
    _jax_events[test][phase] += duration_s
    if phase == "compile_s":
        _jax_events[test]["compiles"] += 1
        _programs.append((test, str(kwargs.get("fun_name", "?")), duration_s))


def pytest_runtest_setup(item) -> None:
    jax = sys.modules.get("jax")  # as the tests imported it
    if not _state["listening"] and jax is not None and os.environ.get(OUT_DIR_ENV):
        jax.monitoring.register_event_duration_secs_listener(on_event)
        _state["listening"] = True


def pytest_runtest_logreport(report) -> None:
    if _state["process"] == "main":
        _durations[report.nodeid] += report.duration


def pytest_sessionfinish(session) -> None:
    out = os.environ.get(OUT_DIR_ENV)
    if not out:
        return
    record = {
        "durations": dict(_durations),
        "jax": {test: dict(c) for test, c in _jax_events.items()},
        "programs": _programs,
    }
    (Path(out) / f"{_state['process']}.json").write_text(json.dumps(record))
