"""Names every test whose seconds are over the per-test budget, from pytest's JUnit XML reports,
and fails when there is one: ``make test`` runs it after each pytest run, so a test that grows
past the budget stops the suite with its name instead of adding a minute unnoticed.

    python scripts/check_test_budget.py .pytest_cache/junit.xml [MORE.xml ...]

A test's seconds are those its report gives it (``junit_duration_report = total``, pytest's
default: its setup, call and teardown, the fixtures it is first to use included), measured
under ``make test``'s two workers. `BUDGET_S` is the budget, the one place it is set.
"""

from __future__ import annotations

import argparse
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

BUDGET_S = 90.0
"""The most seconds one test may take in ``make test`` (setup, call and teardown)."""


def node_id(classname: str, name: str, root: Path) -> str:
    """A JUnit test case's pytest node id (``tests/core/test_x.py::TestY::test_z[p]``).

    JUnit XML names a test by a dotted ``classname`` (module, then class) and its ``name``; the
    module is the longest dotted prefix that is a ``.py`` file under ``root``.

    Args:
        classname: the test case's ``classname`` attribute.
        name: its ``name`` attribute (the test function, with its parameters).
        root: the directory pytest ran in.

    Returns:
        The node id; ``classname::name`` where no prefix is a file under ``root``.
    """
    parts = classname.split(".")
    for cut in range(len(parts), 0, -1):
        path = "/".join(parts[:cut]) + ".py"
        if (root / path).is_file():
            return "::".join([path, *parts[cut:], name])
    return f"{classname}::{name}"


def read_report(path: Path, root: Path) -> dict[str, float]:
    """Each test's seconds in one JUnit XML report.

    Args:
        path: the report pytest wrote (``--junitxml``).
        root: the directory pytest ran in (to rebuild the node ids).

    Returns:
        ``{node id: seconds}`` for every test case of the report.

    Raises:
        ValueError: the file is missing, is not XML, or holds no test case, naming the file.
    """
    if not path.is_file():
        raise ValueError(f"no pytest report at {path}: run pytest with --junitxml={path}")
    try:
        tree = ET.parse(path)
    except ET.ParseError as exc:
        raise ValueError(f"{path} is not a JUnit XML report: {exc}") from None
    cases = list(tree.getroot().iter("testcase"))
    if not cases:
        raise ValueError(f"{path} holds no test case: pytest ran no test")
    seconds = {}
    for case in cases:
        test = node_id(case.get("classname", ""), case.get("name", ""), root)
        seconds[test] = seconds.get(test, 0.0) + float(case.get("time") or 0.0)
    return seconds


def over_budget(seconds: dict[str, float], budget_s: float) -> list[tuple[str, float]]:
    """The tests over the budget, slowest first.

    Args:
        seconds: ``{test: seconds}``.
        budget_s: the most seconds a test may take.

    Returns:
        ``[(test, seconds), ...]`` of the tests over ``budget_s``, slowest first.
    """
    return sorted(((t, s) for t, s in seconds.items() if s > budget_s), key=lambda ts: -ts[1])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("reports", nargs="+", type=Path, help="pytest's JUnit XML reports")
    p.add_argument("--root", type=Path, default=Path.cwd(), help="where pytest ran (default: .)")
    args = p.parse_args(argv)
    seconds: dict[str, float] = {}
    try:
        for report in args.reports:
            seconds.update(read_report(report, args.root))
    except ValueError as exc:
        print(f"check_test_budget: {exc}", file=sys.stderr)
        return 2
    over = over_budget(seconds, BUDGET_S)
    slowest = max(seconds.items(), key=lambda ts: ts[1])
    if over:
        print(
            f"{len(over)} test(s) over the per-test budget of {BUDGET_S:g} s "
            "(scripts/check_test_budget.py: BUDGET_S); make them cheaper or split them:",
            file=sys.stderr,
        )
        for test, s in over:
            print(f"  {s:7.1f} s  {test}", file=sys.stderr)
        return 1
    print(
        f"{len(seconds)} tests within the per-test budget of {BUDGET_S:g} s; "
        f"the slowest {slowest[1]:.1f} s ({slowest[0]})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
