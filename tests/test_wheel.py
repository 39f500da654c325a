"""The package as users get it: the sdist and the wheel built by ``python -m build``, checked by
``twine check``, and the wheel installed into a fresh virtual environment and run there.

``python -m build`` builds the sdist from the checkout and the wheel from the unpacked sdist,
so the wheel is what a user building from the sdist gets too. The wheel is installed with uv
(its dependencies resolved as a user's ``pip install`` resolves them; no editable install) and
the README's quick start and a `score` of a hand-written policy run from a temporary folder in
isolated mode (``python -I``: no ``PYTHONPATH``, no user site, not the script's folder), with a
clean environment: ``PATH``, ``HOME`` and the JAX/XLA settings of the test session (the
compilation cache and the fast-compile flags of ``conftest.py``, which change how fast the
programs compile, not what they compute). A score needs the shipped references and the bundled
data, so it fails where the wheel lacks either. In the same environment a task of one's own (a
task file) gets its references built and a committed checkpoint scored on it.

``CHARGAX_DIST=DIR`` builds into ``DIR`` (``make test`` passes ``dist/`` and prints the wheel's
size); by default the distributions go to a temporary folder.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

from tests.test_readme import README, ROOT, python_blocks

PACKAGE = "chargax_marl"

# What runs in the fresh environment: the README's quick start (inserted below), every task's
# shipped references checked against the installed code, and a score of a hand-written policy.
CHECK = '''
import json, math, sys
from pathlib import Path

import chargax_marl

{quick_start}

# the quick start stepped both views
assert "profit_eur" in info and "__all__" in dones, (info, dones)

import jax.numpy as jnp

from chargax_marl.benchmark import TASKS, get_normalized_score, load_references, score
from chargax_marl.core.station import KIND_BATTERY

for task_id in TASKS:
    load_references(task_id)  # shipped, and computed on this code's parameters and data


def half_power(state, key, params):
    """Every port at half its top level, the batteries idle."""
    is_battery = params.station.leaf_kind == KIND_BATTERY
    return jnp.where(is_battery, 0, (params.num_levels + 1) // 2).astype(jnp.int32)


result = score(half_power, "Chargax-shopping-v1")
assert math.isfinite(result["score"]), result["score"]
assert result["score"] == get_normalized_score("Chargax-shopping-v1", result["daily_profit"])
print(json.dumps({{
    "module": chargax_marl.__file__,
    "sys_path": sys.path,
    "score": result["score"],
    "references": sorted(result["vs"]),
}}))
'''


USER_RUN = "results/ippo_shopping_v2"
"""A committed run on the default station, scored on `USER_TASK` in the fresh environment."""
USER_TASK = """\
name = "shopping-fr2022"
version = 1
scenario = "shopping"
draws = 1
description = "FR 2022 prices (the price crisis) on the default station, session model v3"
prices = "FR-2022"
session_model = "v3"
bound = "occupancy"
num_eval_days = 2
"""
"""A task of one's own (two held-out days, one draw: the smallest that scores)."""


def section(text: str, heading: str) -> str:
    """The lines of a Markdown text under ``## heading``, up to the next ``## `` heading."""
    lines = text.splitlines()
    start = lines.index(f"## {heading}") + 1
    end = next((i for i in range(start, len(lines)) if lines[i].startswith("## ")), len(lines))
    return "\n".join(lines[start:end]) + "\n"


def quick_start() -> str:
    """The Python blocks of the README's quick start, in order, as one script."""
    blocks = [code for _, code in python_blocks(section(README.read_text(), "Quick start"))]
    assert len(blocks) >= 2, "the README's quick start has a block per view"
    return "\n".join(blocks)


def test_the_readme_renders_as_the_package_index_renders_it():
    """PyPI's renderer (readme_renderer, Markdown by its ``md`` extra): without the extra it
    renders nothing, and ``twine check`` passes any Markdown unread."""
    import tomllib

    from readme_renderer.markdown import render

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["readme"] == "README.md"
    html = render(README.read_text())
    assert html is not None, "readme_renderer has no Markdown renderer: install readme-renderer[md]"
    assert "<table>" in html and "Quick start" in html


def test_the_quick_start_is_read_from_the_readme():
    assert section("# t\n## A\na\n## B\nb\n", "A") == "a\n"
    assert section("## A\na\n", "A") == "a\n"
    code = quick_start()
    assert "chargax_marl.single" in code and "chargax_marl.marl" in code


def run(*cmd, **kwargs) -> subprocess.CompletedProcess:
    """Run a command; on failure, an assertion with its output."""
    proc = subprocess.run(cmd, capture_output=True, text=True, **kwargs)
    assert proc.returncode == 0, (
        f"{' '.join(map(str, cmd))} exited {proc.returncode}\n"
        f"stdout:\n{proc.stdout[-4000:]}\nstderr:\n{proc.stderr[-8000:]}"
    )
    return proc


def clean_env(venv: Path) -> dict:
    """``PATH`` (the fresh venv first), ``HOME`` and the session's JAX/XLA settings only."""
    env = {"PATH": f"{venv / 'bin'}{os.pathsep}/usr/local/bin:/usr/bin:/bin"}
    env.update({k: v for k, v in os.environ.items() if k in ("HOME", "LANG", "TMPDIR")})
    env.update({k: v for k, v in os.environ.items() if k.startswith(("JAX_", "XLA_"))})
    return env


def checkout(dest: Path) -> Path:
    """The checkout's files as a release would see them (tracked, or new and not ignored) at
    ``dest``, hard-linked where the file system allows: a build in the checkout itself reads
    its leftovers (setuptools adds every file the last build's ``*.egg-info/SOURCES.txt``
    lists to the sdist, so a file the configuration no longer ships would still ship)."""
    files = run("git", "-C", ROOT, "ls-files", "-z", "--cached", "--others", "--exclude-standard")
    for name in filter(None, files.stdout.split("\0")):
        src, dst = ROOT / name, dest / name
        if not src.is_file():  # deleted, not yet committed
            continue
        dst.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.link(src, dst)
        except OSError:
            shutil.copy2(src, dst)
    return dest


def test_the_wheel_installs_and_runs_in_a_fresh_environment(tmp_path):
    dist = Path(os.environ.get("CHARGAX_DIST") or tmp_path / "dist")
    source = checkout(tmp_path / "source")
    run(sys.executable, "-m", "build", "--installer", "uv", "--outdir", dist, source)
    (wheel,) = dist.glob(f"{PACKAGE}-*.whl")
    (sdist,) = dist.glob(f"{PACKAGE}-*.tar.gz")
    run(sys.executable, "-m", "twine", "check", "--strict", wheel, sdist)

    # the wheel holds the package, every file of it (the bundled data and the references
    # among them), and nothing of the repository besides
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {n.split("/")[0] for n in names} == {PACKAGE, wheel.name.split("-py")[0] + ".dist-info"}
    package = {
        p.relative_to(source).as_posix()
        for p in (source / PACKAGE).rglob("*")
        if p.is_file() and "__pycache__" not in p.parts
    }
    assert not package - names, f"not in the wheel: {sorted(package - names)}"
    assert any(n.startswith(f"{PACKAGE}/core/data/prices_") for n in names)
    assert any(n.startswith(f"{PACKAGE}/benchmark/references/") for n in names)
    # the licence texts: the project's, and the one of the price data the package derives from
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names), sorted(names)
    assert f"{PACKAGE}/core/data/LICENSE-green-dcc.txt" in names

    # the sdist: the package and what builds it, none of the repository's other folders
    with tarfile.open(sdist) as tar:
        top = {Path(n).parts[1] for n in tar.getnames() if len(Path(n).parts) > 1}
    assert PACKAGE in top and "pyproject.toml" in top and "README.md" in top, top
    assert not top & {"tests", "baselines", "benchmarks", "scripts", "results", "docs"}, top

    venv = tmp_path / "venv"
    uv = (sys.executable, "-m", "uv")
    run(*uv, "venv", "--quiet", "--python", sys.executable, venv)
    python = venv / "bin" / "python"
    run(*uv, "pip", "install", "--quiet", "--python", python, wheel)

    work = tmp_path / "work"
    work.mkdir()
    (work / "check.py").write_text(CHECK.format(quick_start=quick_start()))
    proc = run(python, "-I", "check.py", cwd=work, env=clean_env(venv), timeout=900)
    out = json.loads(proc.stdout.strip().splitlines()[-1])

    assert Path(out["module"]).resolve().is_relative_to(venv.resolve()), out["module"]
    assert not [p for p in out["sys_path"] if p and Path(p).is_relative_to(ROOT)], out["sys_path"]
    # half power sells less energy than always-max (score 0) on the same cars
    assert out["score"] < 0, out["score"]
    assert {"always_max", "lp_bound"} <= set(out["references"]), out["references"]

    # a task of one's own, built and a committed checkpoint scored on it, in the same fresh
    # environment: the trainers' code (`baselines/`, not part of the wheel) and the run are
    # copied next to the task file, as a user copies them out of a clone
    shutil.copytree(source / "baselines", work / "baselines")
    shutil.copytree(source / USER_RUN, work / "run")
    (work / "fr2022.toml").write_text(USER_TASK)
    env = clean_env(venv)
    run(
        python,
        "-I",
        "-m",
        "chargax_marl.benchmark.references",
        "--task-file",
        "fr2022.toml",
        "--rules",
        "always_max",
        cwd=work,
        env=env,
        timeout=900,
    )
    assert (work / "Chargax-shopping-fr2022-v1.json").exists()
    # not isolated: `python -m baselines.score` imports the copied baselines/ from the folder
    run(
        python,
        "-m",
        "baselines.score",
        "run",
        "--task-file",
        "fr2022.toml",
        "--out",
        "score.json",
        cwd=work,
        env=env,
        timeout=900,
    )
    scored = json.loads((work / "score.json").read_text())
    assert scored["task"] == "Chargax-shopping-fr2022-v1" and scored["seeds"] >= 1, scored
    assert math.isfinite(scored["score"]) and scored["score"] <= 1.0 + 1e-6, scored["score"]
