"""What ``make test`` costs, phase by phase, on fresh clones: the environment's set-up, the lint,
the pytest run (with its slowest tests, the wheel test and the notebook test among them), the x64
pass, the per-test budget check and the strict docs build.

    python benchmarks/suite_phases.py                             # a fresh clone of HEAD
    python benchmarks/suite_phases.py --repo PATH                 # a checkout as it is
    python benchmarks/suite_phases.py --commits OLD NEW --rounds 2  # OLD, NEW, OLD, NEW
    python benchmarks/suite_phases.py --phases setup lint docs    # the others skipped
    python benchmarks/suite_phases.py --embed docs/performance.md  # the docs' table, re-made

Each run is ``make test`` itself, as ``.ci/run`` starts it, in a fresh ``git clone`` of this
repository (at ``--commits``' commits in turn, alternated, or at ``HEAD``; ``--repo`` runs in a
given checkout instead). Make runs every command of its recipes through ``SHELL``; the script
sets ``SHELL`` to a small wrapper that times each command, gives it its phase by what it runs
and, for the pytest commands, has pytest write a JUnit XML report (each test's seconds and
outcome). The commands of the phases not named by ``--phases`` are skipped (they succeed at
once), and so are those of the phases that need a skipped one; the set-up always runs. The phases are each commit's own: a commit whose Makefile runs
other commands is timed on those.

Writes ``--out``'s ``.json`` (every command's seconds, each run's phases, tests and slowest
tests, the machine, the load before and after each run, and the command line that made it)
and ``.md`` (the phase table, then the slowest tests of each commit's first run). ``--embed
PAGE`` re-makes the phase table between the markers of ``PAGE`` from the ``.json`` (``--out``)
without running anything.

Other jobs on the machine skew every figure: compare commits in one alternated run on
otherwise idle cores, never across runs.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import re
import shlex
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # benchmarks/ is not installed: run from a checkout
from chargax_marl.machine import code_version, load_info, machine_info  # noqa: E402
from scripts.check_test_budget import node_id  # noqa: E402

PHASES = ("setup", "lint", "pytest", "x64", "budget", "docs", "other")
"""The phases of ``make test``, in the order it runs them."""
PHASE_TITLES = {
    "setup": "environment set-up (`make venv`, the docs extra)",
    "lint": "ruff check and format",
    "pytest": "pytest -n 2 (the whole suite)",
    "x64": "the x64 pass (JAX_ENABLE_X64=1)",
    "budget": "per-test budget check",
    "docs": "strict docs build (mkdocs)",
    "other": "the rest (dist/ cleared, its sizes printed)",
}
INSIDE_PYTEST = {
    "wheel": "tests/test_wheel.py",
    "notebook": "tests/test_notebook.py",
}
"""Test files whose seconds the table shows beside the pytest phase they run in."""
LOG_ENV = "CHARGAX_PHASES_LOG"
SKIP_ENV = "CHARGAX_PHASES_SKIP"
MARKERS = ("<!-- suite_phases table: begin -->", "<!-- suite_phases table: end -->")
"""The lines of a docs page between which ``--embed`` writes the phase table."""


NEEDS = {"budget": ("pytest", "x64"), "other": ("pytest",)}
"""Phases that read what others write: the budget check reads pytest's reports, and the
dist/ sizes are printed from the wheel test's output."""


def skipped_phases(run: list[str]) -> list[str]:
    """The phases to skip when only ``run`` are asked for: the others, never the set-up (the
    rest needs it), and those that need a skipped one (`NEEDS`).

    Args:
        run: the phases asked for.

    Returns:
        The phases to skip, in `PHASES`' order.
    """
    skip = {ph for ph in PHASES if ph not in run and ph != "setup"}
    skip |= {ph for ph, needs in NEEDS.items() if skip & set(needs)}
    return [ph for ph in PHASES if ph in skip]


def phase_of(command: str) -> str | None:
    """The phase a command of ``make test``'s recipes belongs to.

    Args:
        command: the command as make hands it to its shell.

    Returns:
        One of `PHASES`, or None for a recursive ``make`` (its commands are timed each).
    """
    words = command.split()
    if words and Path(words[0]).name == "make":
        return None
    if re.search(r"-m venv|pip install|touch \S*\.venv/|test -x \S*\.venv/", command):
        return "setup"
    if "ruff" in command:
        return "lint"
    if re.search(r"\bpytest\b", command):  # not .pytest_cache
        return "x64" if "JAX_ENABLE_X64=1" in command else "pytest"
    if "check_test_budget" in command:
        return "budget"
    if "mkdocs" in command:
        return "docs"
    return "other"


# The wrapper make runs every recipe command through (``make SHELL=...``): it times the command,
# appends a JSON line to the log, and exits with its status. Standard library only: `phase_of`'s
# source is pasted in (importing this module would import JAX in every command).
WRAPPER = textwrap.dedent(
    """\
    #!{python}
    import json, os, re, subprocess, sys, time
    from pathlib import Path

    {phase_of}

    command = sys.argv[-1]
    phase = phase_of(command)
    log = os.environ["{log}"]
    env = dict(os.environ)
    junit = None
    if phase in ("pytest", "x64"):
        given = re.search(r"--junitxml[= ](\\S+)", command)
        if given:
            junit = os.path.abspath(given.group(1))
        else:
            junit = os.path.join(os.path.dirname(log), "junit-%d.xml" % time.time_ns())
            env["PYTEST_ADDOPTS"] = (env.get("PYTEST_ADDOPTS", "") + " --junitxml=" + junit)
    skipped = phase in os.environ.get("{skip}", "").split(",")
    t0 = time.time()
    rc = 0 if skipped else subprocess.call(["/bin/sh", *sys.argv[1:]], env=env)
    record = dict(command=command, phase=phase, start=t0, seconds=time.time() - t0, rc=rc,
                  skipped=skipped, junit=None if skipped else junit)
    with open(log, "a") as f:
        f.write(json.dumps(record) + "\\n")
    sys.exit(rc)
    """
)


def read_junit(path: Path, root: Path) -> dict[str, dict]:
    """Each test's seconds and outcome in a JUnit XML report.

    Args:
        path: the report.
        root: the checkout pytest ran in.

    Returns:
        ``{node id: {"seconds", "outcome"}}``, outcome one of passed / skipped / failed.
    """
    tests = {}
    for case in ET.parse(path).getroot().iter("testcase"):
        kinds = {child.tag for child in case}
        outcome = (
            "failed"
            if kinds & {"failure", "error"}
            else "skipped"
            if "skipped" in kinds
            else "passed"
        )
        test = node_id(case.get("classname", ""), case.get("name", ""), root)
        tests[test] = {"seconds": float(case.get("time") or 0.0), "outcome": outcome}
    return tests


def summarize_run(records: list[dict], root: Path, top: int) -> dict:
    """One ``make test`` run's phases, test counts and slowest tests from the wrapper's log.

    Args:
        records: the wrapper's JSON lines, one per command.
        root: the checkout the run was made in.
        top: how many of the slowest tests to keep.

    Returns:
        ``{"phases": {phase: seconds}, "skipped_phases", "inside_pytest": {name: seconds},
        "tests": {phase: {outcome: count}}, "slowest": [[test, seconds], ...]}``.
    """
    phases = {p: 0.0 for p in PHASES}
    skipped = sorted({r["phase"] for r in records if r["skipped"]})
    tests: dict[str, dict] = {}
    every: dict[str, float] = {}
    inside = {name: 0.0 for name in INSIDE_PYTEST}
    for r in records:
        if r["phase"] is None or r["skipped"]:
            continue
        phases[r["phase"]] += r["seconds"]
        if r["junit"] and Path(r["junit"]).is_file():
            cases = read_junit(Path(r["junit"]), root)
            counts = tests.setdefault(r["phase"], {"passed": 0, "skipped": 0, "failed": 0})
            for test, case in cases.items():
                counts[case["outcome"]] += 1
                every[f"{test} (x64)" if r["phase"] == "x64" else test] = case["seconds"]
                for name, file in INSIDE_PYTEST.items():
                    if r["phase"] == "pytest" and test.startswith(file + "::"):
                        inside[name] += case["seconds"]
    slowest = sorted(every.items(), key=lambda ts: -ts[1])[:top]
    return {
        "phases": phases,
        "skipped_phases": skipped,
        "inside_pytest": inside,
        "tests": tests,
        "slowest": [[t, round(s, 2)] for t, s in slowest],
    }


def fresh_clone(source: Path, commit: str, into: Path) -> Path:
    """A ``git clone`` of ``source`` checked out at ``commit``, with the folder ``shared``
    beside ``source`` (the data the tests read from ``../shared``, as CI has it beside its
    clone) linked beside the clone.

    Args:
        source: the repository to clone.
        commit: a commit, branch or tag of it.
        into: the (new) directory to clone into.

    Returns:
        ``into``.
    """
    subprocess.run(["git", "clone", "--quiet", str(source), str(into)], check=True)
    subprocess.run(["git", "-C", str(into), "checkout", "--quiet", commit], check=True)
    shared = source.resolve().parent / "shared"
    beside = into.parent / "shared"
    if shared.is_dir() and not beside.exists():
        beside.symlink_to(shared, target_is_directory=True)
    return into


def make_test(checkout: Path, skip: list[str], work: Path, top: int) -> dict:
    """Runs ``make test`` in ``checkout`` with every command timed.

    Args:
        checkout: the repository to run it in.
        skip: the phases whose commands are skipped.
        work: a directory for the wrapper, its log, the reports and make's output.
        top: how many of the slowest tests to keep.

    Returns:
        `summarize_run`'s dict, with the run's ``commit``, ``wall_s``, ``exit_code``, the load
        before and after, every command's record and the file holding make's output.
    """
    work.mkdir(parents=True, exist_ok=True)
    wrapper = work / "shell.py"
    wrapper.write_text(
        WRAPPER.format(
            python=sys.executable,
            phase_of=inspect.getsource(phase_of),
            log=LOG_ENV,
            skip=SKIP_ENV,
        )
    )
    wrapper.chmod(0o755)
    log, output = work / "commands.jsonl", work / "make.log"
    log.write_text("")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_", "XLA_", "PYTEST_"))}
    env.pop("VIRTUAL_ENV", None)
    env.update({LOG_ENV: str(log), SKIP_ENV: ",".join(skip)})
    load_before = load_info()
    t0 = time.perf_counter()
    with output.open("w") as out:
        code = subprocess.call(
            ["make", "test", f"SHELL={wrapper}"], cwd=checkout, env=env, stdout=out, stderr=out
        )
    wall_s = time.perf_counter() - t0
    records = [json.loads(line) for line in log.read_text().splitlines() if line.strip()]
    run = summarize_run(records, checkout, top)
    run.update(
        commit=code_version(checkout)["commit"],
        wall_s=round(wall_s, 1),
        exit_code=code,
        load_before=load_before,
        load_after=load_info(),
        commands=[
            {k: r[k] for k in ("command", "phase", "seconds", "rc", "skipped")} for r in records
        ],
        make_output=str(output),
    )
    return run


def _s(seconds: float) -> str:
    return f"{seconds:.0f}"


def _clock(seconds: float) -> str:
    return f"{int(seconds // 60)} min {int(round(seconds % 60)):02d} s"


def phase_table(result: dict) -> str:
    """The phase table of a result: a row per phase, a column per run (in the order run), then
    the median of each commit where a commit ran more than once.

    Args:
        result: the ``.json`` this script writes.

    Returns:
        A Markdown table (seconds; the total as minutes and seconds).
    """
    runs = result["runs"]
    labels = [
        f"{r['label']} {i + 1}" if r.get("label") else f"run {i + 1}" for i, r in enumerate(runs)
    ]
    commits = list(dict.fromkeys(r["commit"][:7] for r in runs))
    by_commit = {c: [r for r in runs if r["commit"][:7] == c] for c in commits}
    medians = [c for c in commits if len(by_commit[c]) > 1]
    head = [
        "phase",
        *(f"{lab} (`{r['commit'][:7]}`)" for lab, r in zip(labels, runs)),
        *(f"median `{c}`" for c in medians),
    ]
    rows = [head, ["---"] * len(head)]

    def row(title: str, values: list[str]) -> None:
        rows.append([title, *values])

    def per_run(get) -> list[str]:
        return [get(r) for r in runs] + [
            _s(statistics.median(float(get(r)) for r in by_commit[c])) for c in medians
        ]

    for phase in PHASES:
        if all(r["phases"][phase] == 0.0 for r in runs):
            continue
        row(PHASE_TITLES[phase], per_run(lambda r, p=phase: _s(r["phases"][p])))
        if phase == "pytest":
            for name, file in INSIDE_PYTEST.items():
                row(f"of which `{file}`", per_run(lambda r, n=name: _s(r["inside_pytest"][n])))
    rows.append(
        [
            "`make test`, wall",
            *(_clock(r["wall_s"]) for r in runs),
            *(_clock(statistics.median(r["wall_s"] for r in by_commit[c])) for c in medians),
        ]
    )

    def counts(r: dict) -> str:
        return (
            " + ".join(
                f"{t['passed']} passed" + (f", {t['failed']} failed" if t["failed"] else "")
                for t in (r["tests"].get(p) for p in ("pytest", "x64"))
                if t
            )
            or "-"
        )

    rows.append(["tests (pytest + x64)", *(counts(r) for r in runs), *([""] * len(medians))])
    rows.append(
        [
            "skipped phases",
            *(", ".join(r["skipped_phases"]) or "none" for r in runs),
            *([""] * len(medians)),
        ]
    )
    return "\n".join("| " + " | ".join(r) + " |" for r in rows)


def report(result: dict) -> str:
    """The ``.md`` of a result: how it was made, the phase table, each commit's slowest tests.

    Args:
        result: the ``.json`` this script writes.

    Returns:
        Markdown text.
    """
    m = result["machine"]
    lines = [
        "# `make test` by phase",
        "",
        f"`{result['command']}`",
        "",
        f"{m['cpu']}, {m['cores']} cores, Python {m['python']}, jax {m['jax']}; "
        f"{result['started']} UTC; "
        + "; ".join(
            f"run {i + 1}: {r['load_before']} before, {r['load_after']} after"
            for i, r in enumerate(result["runs"])
        ),
        "",
        "Seconds per phase (every command of the phase together).",
        "",
        phase_table(result),
    ]
    seen = set()
    for r in result["runs"]:
        if r["commit"] in seen or not r["slowest"]:
            continue
        seen.add(r["commit"])
        lines += [
            "",
            f"## The slowest tests at `{r['commit'][:7]}`",
            "",
            "| seconds | test |",
            "|---|---|",
        ]
        lines += [f"| {s:.1f} | `{t}` |" for t, s in r["slowest"]]
    return "\n".join(lines) + "\n"


def embedded(result: dict) -> str:
    """What `embed` writes into a page: a line saying how and where the runs were made (the
    command, the machine, the date, each run's load), then `phase_table`.

    Args:
        result: the ``.json`` this script writes.

    Returns:
        Markdown text.
    """
    m = result["machine"]
    loads = "; ".join(
        f"run {i + 1} {r['load_before']} before, {r['load_after']} after"
        for i, r in enumerate(result["runs"])
    )
    return (
        f"`{result['command']}`, {result['started']} UTC, on the {m['cpu']} with "
        f"{m['cores']} cores ({loads}); seconds per phase:\n\n{phase_table(result)}"
    )


def embed(page: Path, result: dict) -> None:
    """Writes `embedded` of ``result`` into ``page`` between its `MARKERS`.

    Args:
        page: a Markdown page with both markers, each on a line of its own.
        result: the ``.json`` this script writes.

    Raises:
        ValueError: the page lacks a marker, naming the page and the marker.
    """
    text = page.read_text()
    for marker in MARKERS:
        if marker not in text:
            raise ValueError(f"{page} has no line {marker!r} to embed the phase table at")
    head, rest = text.split(MARKERS[0], 1)
    _, tail = rest.split(MARKERS[1], 1)
    page.write_text(f"{head}{MARKERS[0]}\n{embedded(result)}\n{MARKERS[1]}{tail}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument(
        "--repo",
        type=Path,
        default=None,
        help="run in this checkout as it is (default: a fresh clone per run)",
    )
    p.add_argument("--source", type=Path, default=ROOT, help="the repository to clone")
    p.add_argument(
        "--commits",
        nargs="+",
        default=["HEAD"],
        help="commits to clone, run in turn each round (default: HEAD)",
    )
    p.add_argument("--rounds", type=int, default=1, help="rounds of the commits (alternated)")
    p.add_argument(
        "--phases",
        nargs="+",
        choices=PHASES,
        default=list(PHASES),
        help="the phases to run (the set-up always runs; default: all)",
    )
    p.add_argument("--top", type=int, default=25, help="slowest tests to keep per run")
    p.add_argument(
        "--out",
        type=Path,
        default=ROOT / "benchmarks" / "results" / "suite_phases",
        help="the results' path without suffix (.json and .md are written)",
    )
    p.add_argument(
        "--embed",
        type=Path,
        default=None,
        help="re-make the phase table of this page from --out's .json; run nothing",
    )
    args = p.parse_args(argv)
    json_path, md_path = args.out.with_suffix(".json"), args.out.with_suffix(".md")
    if args.embed is not None:
        embed(args.embed, json.loads(json_path.read_text()))
        print(f"wrote the phase table of {json_path} into {args.embed}")
        return 0
    if args.rounds < 1 or args.top < 1:
        p.error(f"--rounds and --top must be >= 1, got {args.rounds} and {args.top}")
    if args.repo is not None and (len(args.commits) > 1 or args.commits != ["HEAD"]):
        p.error("--repo runs the checkout as it is: --commits needs fresh clones, drop --repo")
    skip = skipped_phases(args.phases)
    labels = "ABCDEFGH"
    result = {
        "command": shlex.join(["python", "benchmarks/suite_phases.py", *sys.argv[1:]])
        if argv is None
        else shlex.join(["python", "benchmarks/suite_phases.py", *argv]),
        "machine": machine_info(),
        "started": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "commits": {},
        "runs": [],
    }
    exit_code = 0
    with tempfile.TemporaryDirectory(prefix="suite_phases_") as tmp:
        for round_ in range(args.rounds):
            for i, commit in enumerate(args.commits):
                label = labels[i] if len(args.commits) > 1 else ""
                work = Path(tmp) / f"{round_}-{i}"
                if args.repo is not None:
                    checkout = args.repo.resolve()
                else:
                    checkout = fresh_clone(args.source, commit, work / "clone")
                print(
                    f"round {round_ + 1}, {label or 'run'} {commit}: make test in {checkout}",
                    flush=True,
                )
                run = make_test(checkout, skip, work, args.top)
                run["label"] = label
                result["commits"][label or commit] = commit
                result["runs"].append(run)
                # make's output is in the temporary folder: keep its tail in the results
                run["make_output_tail"] = Path(run.pop("make_output")).read_text()[-3000:]
                print(
                    f"  exit {run['exit_code']}, wall {_clock(run['wall_s'])}, "
                    + ", ".join(f"{ph} {_s(s)} s" for ph, s in run["phases"].items() if s),
                    flush=True,
                )
                exit_code = exit_code or run["exit_code"]
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(result, indent=1) + "\n")
    md_path.write_text(report(result))
    print(report(result))
    print(f"wrote {json_path} and {md_path}")
    return exit_code


if __name__ == "__main__":
    sys.exit(main())
