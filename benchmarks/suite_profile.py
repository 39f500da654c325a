"""Where the test suite's time goes: each test's seconds and, of them, JAX's tracing, lowering
and XLA compiling, summed per test file, per test and per compiled function.

    python benchmarks/suite_profile.py                    # the suite as `make test` runs it
    python benchmarks/suite_profile.py --cold             # with an empty compilation cache
    python benchmarks/suite_profile.py --out prof.json -- tests/marl -k array

Runs pytest with `suite_profile_plugin.py` as a plugin, which charges JAX's compile events in
every test process to the test running at the time (fixtures included; collection is not
counted, and processes that a test starts itself are not seen: their time is in that test's
seconds). ``--cold`` gives the run a new, empty persistent compilation cache, as a fresh
clone's first run has; without it the run reads and fills the suite's own cache
(``tests/conftest.py``), so programs compiled by an earlier run are not compiled again.

Prints the run's machine, commit and wall time, the totals, the files and tests that take
longest, the functions whose programs took longest to compile, the compiles grouped by their
duration and the longest ones; ``--out`` also writes every record as JSON.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # benchmarks/ is not installed: run from a checkout
from benchmarks.suite_profile_plugin import OUT_DIR_ENV, OUTSIDE  # noqa: E402
from chargax_marl.machine import code_version, load_info, machine_info  # noqa: E402


def merge(records: list[dict]) -> dict:
    """The per-process records as one: seconds and JAX phases per test, every compile.

    Args:
        records: the JSON records the plugin wrote, one per process.

    Returns:
        ``{"tests": {test: {"seconds", "trace_s", "lower_s", "compile_s", "compiles"}},
        "programs": [(test, function, compile seconds), ...]}``.
    """
    tests: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    programs = []
    for r in records:
        for test, s in r["durations"].items():
            tests[test]["seconds"] += s
        for test, phases in r["jax"].items():
            tests[test].update(phases)
        programs += [tuple(p) for p in r["programs"]]
    return {"tests": {t: dict(c) for t, c in tests.items()}, "programs": programs}


def summarize(merged: dict, top: int = 20) -> str:
    """The report: totals, the files and tests with the most seconds, the functions with the
    most compile seconds, the compiles by their duration and the longest ones.

    Args:
        merged: `merge`'s output.
        top: rows per table.

    Returns:
        The report as text.
    """
    tests = merged["tests"]
    files: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    for test, c in tests.items():
        files[test.split("::")[0]].update(c)
    total = collections.Counter()
    for c in tests.values():
        total.update(c)

    def row(c, name: str) -> str:
        return (
            f"{c.get('seconds', 0.0):9.1f} {c.get('trace_s', 0.0):8.1f} "
            f"{c.get('lower_s', 0.0):8.1f} {c.get('compile_s', 0.0):9.1f} "
            f"{int(c.get('compiles', 0)):8d}  {name}"
        )

    head = f"{'seconds':>9} {'trace_s':>8} {'lower_s':>8} {'compile_s':>9} {'compiles':>8}"
    lines = [
        "tests' seconds (summed over processes) and, of them, JAX's trace, lower and compile",
        head,
        row(total, f"all {sum(1 for t in tests if t != OUTSIDE)} tests"),
    ]
    for title, table in (("files", files), ("tests", tests)):
        lines += ["", f"the {top} {title} with the most seconds", head]
        ranked = sorted(table.items(), key=lambda kv: -kv[1].get("seconds", 0.0))
        lines += [row(c, name) for name, c in ranked[:top]]
    by_fun: dict[str, list] = collections.defaultdict(lambda: [0, 0.0])
    for _, fun, seconds in merged["programs"]:
        by_fun[fun][0] += 1
        by_fun[fun][1] += seconds
    lines += ["", f"the {top} compiled functions with the most compile seconds"]
    lines += [f"{'compile_s':>9} {'compiles':>8}  function"]
    for fun, (n, s) in sorted(by_fun.items(), key=lambda kv: -kv[1][1])[:top]:
        lines.append(f"{s:9.1f} {n:8d}  {fun}")
    lines += ["", "compiles by their seconds", f"{'compile_s':>9} {'compiles':>8}  each"]
    edges = (0.0, 0.1, 1.0, 5.0, float("inf"))
    for lo, hi in zip(edges[:-1], edges[1:]):
        sizes = [s for _, _, s in merged["programs"] if lo <= s < hi]
        each = f">= {lo:g} s" if hi == float("inf") else f"{lo:g}-{hi:g} s"
        lines.append(f"{sum(sizes):9.1f} {len(sizes):8d}  {each}")
    lines += ["", f"the {top} longest compiles", f"{'compile_s':>9}  function  test"]
    for test, fun, s in sorted(merged["programs"], key=lambda p: -p[2])[:top]:
        lines.append(f"{s:9.1f}  {fun}  {test}")
    return "\n".join(lines)


def run_header(wall_s: float, exit_code: int, cold: bool) -> str:
    """The run's machine, code, load and wall time.

    Args:
        wall_s: the pytest run's wall-clock seconds.
        exit_code: pytest's exit code.
        cold: whether the run started from an empty compilation cache.

    Returns:
        Two lines of text.
    """
    m, code = machine_info(), code_version(ROOT)
    cache = "an empty compilation cache" if cold else "the compilation cache of tests/conftest.py"
    return (
        f"{m['cpu']}, {m['cores']} cores, jax {m['jax']}, commit {code['commit']}"
        f"{' (uncommitted changes)' if code['dirty'] else ''}, {load_info()} after the run\n"
        f"pytest exit code {exit_code}, wall {wall_s:.0f} s, {cache}"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--cold", action="store_true", help="start from an empty compilation cache")
    p.add_argument("--workers", type=int, default=2, help="pytest-xdist workers (0: none)")
    p.add_argument("--top", type=int, default=20, help="rows per table")
    p.add_argument("--out", type=Path, default=None, help="write the merged records as JSON")
    p.add_argument("pytest_args", nargs="*", help="pytest's arguments (after --)")
    args = p.parse_args(argv)
    if args.workers < 0 or args.top < 1:
        p.error(f"--workers must be >= 0 and --top >= 1, got {args.workers} and {args.top}")
    with tempfile.TemporaryDirectory() as records, tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, OUT_DIR_ENV: records}
        if args.cold:
            env["JAX_COMPILATION_CACHE_DIR"] = cache
        cmd = [sys.executable, "-m", "pytest", "-q", "-p", "benchmarks.suite_profile_plugin"]
        if args.workers:
            cmd += ["-n", str(args.workers)]
        t0 = time.perf_counter()
        code = subprocess.call([*cmd, *args.pytest_args], cwd=ROOT, env=env)
        wall_s = time.perf_counter() - t0
        merged = merge([json.loads(f.read_text()) for f in sorted(Path(records).glob("*.json"))])
    print(run_header(wall_s, code, args.cold))
    print(summarize(merged, args.top))
    if args.out is not None:
        args.out.write_text(json.dumps(merged))
        print(f"wrote {args.out}")
    return code


if __name__ == "__main__":
    sys.exit(main())
