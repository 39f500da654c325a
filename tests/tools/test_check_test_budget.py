"""The per-test budget check ``make test`` runs after pytest (``scripts/check_test_budget.py``),
on small JUnit XML reports written here."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def load():
    path = ROOT / "scripts" / "check_test_budget.py"
    spec = importlib.util.spec_from_file_location("check_test_budget", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def report(tmp_path: Path, cases: list[tuple[str, str, float]], name: str = "junit.xml") -> Path:
    """A JUnit XML report as pytest writes it, of ``(classname, name, seconds)`` test cases."""
    body = "".join(f'<testcase classname="{c}" name="{n}" time="{s}" />' for c, n, s in cases)
    path = tmp_path / name
    path.write_text(
        '<?xml version="1.0" encoding="utf-8"?><testsuites><testsuite name="pytest" '
        f'tests="{len(cases)}">{body}</testsuite></testsuites>'
    )
    return path


@pytest.fixture
def tree(tmp_path):
    """A checkout with one test module, for the node ids."""
    (tmp_path / "tests" / "core").mkdir(parents=True)
    (tmp_path / "tests" / "core" / "test_x.py").write_text("")
    return tmp_path


def test_a_test_over_the_budget_is_named_and_fails_the_check(tree, capsys):
    check = load()
    path = report(
        tree,
        [
            ("tests.core.test_x", "test_fast", 0.5),
            ("tests.core.test_x", "test_slow[a-1]", check.BUDGET_S + 1.0),
            ("tests.core.test_x.TestGroup", "test_slower", check.BUDGET_S + 9.0),
        ],
    )
    assert check.main([str(path), "--root", str(tree)]) == 1
    err = capsys.readouterr().err
    assert "2 test(s) over the per-test budget" in err
    lines = [line.strip() for line in err.splitlines() if "tests/core" in line]
    # slowest first, with the node ids pytest prints
    assert lines[0].endswith("tests/core/test_x.py::TestGroup::test_slower")
    assert lines[1].endswith("tests/core/test_x.py::test_slow[a-1]")
    assert "test_fast" not in err


def test_tests_within_the_budget_pass_and_the_slowest_is_reported(tree, capsys):
    check = load()
    path = report(
        tree,
        [("tests.core.test_x", "test_a", 1.0), ("tests.core.test_x", "test_b", check.BUDGET_S)],
    )
    assert check.main([str(path), "--root", str(tree)]) == 0
    out = capsys.readouterr().out
    assert "2 tests within the per-test budget" in out
    assert "tests/core/test_x.py::test_b" in out


def test_every_report_is_read(tree):
    check = load()
    fast = report(tree, [("tests.core.test_x", "test_a", 1.0)], "a.xml")
    slow = report(tree, [("tests.core.test_x", "test_b", check.BUDGET_S * 2)], "b.xml")
    assert check.main([str(fast), str(slow), "--root", str(tree)]) == 1


def test_node_ids_are_rebuilt_from_the_dotted_class_names(tree):
    check = load()
    assert (
        check.node_id("tests.core.test_x", "test_a[1]", tree) == "tests/core/test_x.py::test_a[1]"
    )
    assert check.node_id("tests.core.test_x.TestY", "t", tree) == "tests/core/test_x.py::TestY::t"
    # no such file: the dotted name as it is
    assert check.node_id("elsewhere.test_z", "t", tree) == "elsewhere.test_z::t"


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "no pytest report at"),
        ("not xml <", "is not a JUnit XML report"),
        ("<testsuites><testsuite /></testsuites>", "holds no test case"),
    ],
)
def test_a_missing_or_empty_report_is_an_error_naming_the_file(tmp_path, capsys, content, message):
    check = load()
    path = tmp_path / "junit.xml"
    if content is not None:
        path.write_text(content)
    assert check.main([str(path)]) == 2
    err = capsys.readouterr().err
    assert message in err and str(path) in err


def test_the_budget_is_set_once_and_make_test_runs_the_check_on_every_pytest_report():
    """`make test` writes a report per pytest run and checks each, after the run."""
    makefile = (ROOT / "Makefile").read_text()
    recipe = makefile.split("\ntest:", 1)[1].split("\n\n", 1)[0]
    runs = [line for line in recipe.splitlines() if " -m pytest " in line]
    checks = [line for line in recipe.splitlines() if "check_test_budget.py" in line]
    assert runs and len(checks) == len(runs), recipe
    lines = recipe.splitlines()
    for run, check in zip(runs, checks):
        junit = run.split("--junitxml=")[1].split()[0]
        assert junit in check and lines.index(check) > lines.index(run), (run, check)
    assert "BUDGET" not in makefile  # the budget lives in the script alone


def test_the_performance_page_gives_the_budget_the_script_sets():
    check = load()
    page = (ROOT / "docs" / "performance.md").read_text()
    assert f"the one place it is set: {check.BUDGET_S:g} s" in page
