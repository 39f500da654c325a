"""Smoke tests of the benchmark entry points on their smallest settings (no timing assertions).

The peer installs are not exercised: ``peers.py`` is tested on its chargax part, the driver
protocol (``RESULT {json}``) with a fake peer driver, and its result parsing.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BENCH = ROOT / "benchmarks"


def load(name: str):
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))
    spec = importlib.util.spec_from_file_location(f"bench_{name}", BENCH / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_throughput_main_smallest(tmp_path, capsys):
    rows = load("throughput").main(
        [
            "--envs",
            "1",
            "--total",
            "8",
            "--min-steps",
            "8",
            "--repeats",
            "1",
            "--devices",
            "1",
            "--csv",
            str(tmp_path / "t.csv"),
        ]
    )
    assert (
        [r["envs"] for r in rows] == [1]
        and rows[0]["single_steps_per_s"] > 0
        and rows[0]["marl_steps_per_s"] > 0
    )
    assert (
        rows[0]["marl_over_single"] == rows[0]["marl_steps_per_s"] / rows[0]["single_steps_per_s"]
    )
    assert (tmp_path / "t.csv").read_text().startswith("envs,")
    out = capsys.readouterr().out
    assert "marl/single" in out and "single s/100k" in out
    assert (
        "memory per env: state 963 bytes" in out
    )  # 17 leaves x (12 float32 + 2 bool fields), day, step, workday, day volume, 25 totals
    # the compiled program's temporaries per env, from XLA's memory analysis, as the CSV has them
    temp = re.search(r"holds ([\d,]+) bytes of temporaries per env \(envs per device: 1;", out)
    assert temp and int(temp[1].replace(",", "")) == round(rows[0]["single_temp_bytes_per_env"])
    assert rows[0]["single_temp_bytes_per_env"] > 963


def test_throughput_uses_the_requested_host_devices():
    """``make bench`` splits the batch over one host device per core; importing chargax_marl
    (gymnax) starts JAX's backend, so the device count must be set before that import. Since
    ef03962 it was not, and every row silently ran on one device."""
    import os
    import subprocess

    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONPATH": str(ROOT)}
    # the session's cheap compile flags stay (this checks the device count, not a speed)
    out = subprocess.run(
        [
            sys.executable,
            str(BENCH / "throughput.py"),
            "--envs",
            "2",
            "--total",
            "8",
            "--min-steps",
            "8",
            "--repeats",
            "1",
            "--devices",
            "2",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert "x2 devices" in out.stdout
    row = next(line.split() for line in out.stdout.splitlines() if line.split()[:1] == ["2"])
    assert row[1] == "2", out.stdout  # the "dev" column: the batch of 2 envs ran on 2 devices


def test_throughput_refuses_a_device_count_it_cannot_have():
    import jax

    flags = os.environ.get("XLA_FLAGS")
    with pytest.raises(RuntimeError, match="--devices"):
        load("throughput").main(["--envs", "1", "--devices", str(jax.device_count() + 1)])
    # the refused count is not left in the environment: the processes this one starts later
    # (the command-line runs of other tests) would otherwise get that many host devices
    assert os.environ.get("XLA_FLAGS") == flags


def test_scaling_main_smallest(tmp_path, capsys):
    scaling = load("scaling")
    rows = scaling.main(
        [
            "--ports",
            "16",
            "--envs",
            "1",
            "2",
            "--views",
            "single",
            "--work",
            "8",
            "--min-steps",
            "4",
            "--max-steps",
            "4",
            "--repeats",
            "1",
            "--max-port-envs",
            "16",
            "--out",
            str(tmp_path),
            "--no-plot",
        ]
    )
    assert [(r["view"], r["envs"]) for r in rows] == [
        ("single", 1)
    ]  # envs=2 is over the budget of 16 port-envs
    assert rows[0]["peak_rss_mb"] > 0 and (tmp_path / "scaling.csv").exists()
    assert "skip single ports=16 envs=2" in capsys.readouterr().out


def test_scaling_fit_and_plot(tmp_path):
    scaling = load("scaling")
    rows = [
        {
            "view": "single",
            "ports": p,
            "envs": e,
            "env_steps_per_s": 1e6 / (p * e**-0.5),
            "us_per_env_step": p * e**-0.5,
        }
        for p in (16, 64, 256)
        for e in (1, 16)
    ]
    rows.append(
        {
            "view": "pettingzoo",
            "ports": 16,
            "envs": 1,
            "env_steps_per_s": 3000.0,
            "us_per_env_step": 333.0,
        }
    )
    assert scaling.fit_exponent(rows, "single", 1) == pytest.approx(1.0)
    assert scaling.fit_exponent(rows, "marl-scalar", 1) is None
    scaling.plot(rows, tmp_path / "s.png")
    assert (tmp_path / "s.png").stat().st_size > 0
    assert scaling.station_kwargs(64) == {"num_dc": 40, "num_ac": 24}


def test_profile_step_smallest(capsys):
    table = load("profile_step").main(
        [
            "--envs",
            "1",
            "--steps",
            "2",
            "--repeats",
            "1",
            "--warmup",
            "2",
            "--only",
            "simulator.step",
            "poisson",
        ]
    )
    # the inverse-CDF draw of the current step, and 0.2's jax.random.poisson timed beside it
    assert set(table[1]) == {
        "scaffold_us",
        "simulator.step",
        "    poisson draw (inverse CDF)",
        "    [0.2: jax.random.poisson]",
    }
    assert all(table[1][k] >= 0 for k in table[1])
    assert "poisson draw (inverse CDF)" in capsys.readouterr().out


def test_teacher_count_times_both_counts_and_they_agree(tmp_path):
    out = tmp_path / "count.jsonl"
    rows = load("teacher_count").main(["--envs", "2", "--reps", "1", "--out", str(out)])
    assert [r["envs"] for r in rows] == [2] and rows[0]["identical"]
    for what in ("potential", "advice"):
        assert rows[0][f"{what}_ms_blocked"] > 0 and rows[0][f"{what}_ms_cumsum"] > 0
    assert [json.loads(line)["envs"] for line in out.read_text().splitlines()] == [2]


def test_peers_chargax_part(tmp_path, capsys):
    peers = load("peers")
    results = peers.main(
        ["--skip-peers", "--chargax-steps", "32", "--repeats", "1", "--out", str(tmp_path)]
    )
    assert [r["envs"] for r in results["chargax"]] == [1, 16] and results["peers"] == []
    saved = json.loads((tmp_path / "peers.json").read_text())
    assert saved["paper_s_per_100k"]["SustainGym"] == 1554.57
    assert "chargax_marl 16 envs" in capsys.readouterr().out


def test_peers_driver_protocol_with_fake_peer(tmp_path):
    peers = load("peers")
    driver = tmp_path / "fake_driver.py"
    driver.write_text(
        "import json, sys\n"
        "steps = int(sys.argv[1])\n"
        "print('noise before the result')\n"
        "print('RESULT ' + json.dumps({'peer': 'Fake', 'version': '0.0', 'steps': steps, 'seconds': steps * 0.01,"
        " 'resets': 0, 'scenario': {'arg': sys.argv[2:]}}))\n"
    )
    res = peers.run_driver(sys.executable, driver, 500, ["x"])
    assert res["peer"] == "Fake" and res["scenario"] == {"arg": ["x"]}
    assert res["s_per_100k"] == pytest.approx(1000.0) and res["extrapolated"]
    with pytest.raises(ValueError):
        peers.parse_result("no result here\n")
    failing = tmp_path / "failing.py"
    failing.write_text("raise SystemExit('boom')\n")
    with pytest.raises(RuntimeError):
        peers.run_driver(sys.executable, failing, 1)
    # every real peer has a driver file and the install spec names the pinned version
    for spec in peers.PEERS.values():
        assert (BENCH / "peer_drivers" / spec["driver"]).exists()
        assert "==" in spec["nodeps"][0]


def test_train_speed_counts_network_work_and_rounds_to_whole_updates():
    from benchmarks import train_speed

    assert train_speed._steps_for(16, 100_000, 300) == 21 * 4800
    assert train_speed.mlp_macs([4, 8, 2]) == 4 * 8 + 8 * 2
    ppo_m, ippo_m, mappo_m = (train_speed.network_macs(a) for a in ("ppo", "ippo", "mappo"))
    assert ippo_m["rows"] == mappo_m["rows"] == 17 and ppo_m["rows"] == 1
    # 17 agents through 2 x 256 MLPs: about 9 x PPO's work per env-step; MAPPO's shared critic less
    assert 8 < ippo_m["total_macs"] / ppo_m["total_macs"] < 10
    assert ppo_m["total_macs"] < mappo_m["total_macs"] < ippo_m["total_macs"]


def test_train_speed_builds_a_base_checkout_s_trainers_beside_this_one_s():
    from benchmarks import train_speed

    names = train_speed.load_base(ROOT)  # this checkout as its own base
    assert names == ["base:ppo", "base:ippo", "base:mappo"]
    tiny = {"NUM_STEPS": 24, "HIDDEN": 16, "NUM_MINIBATCHES": 2}
    for algo in ("ppo", "mappo"):
        _, base_config = train_speed.build(f"base:{algo}", 2, 96, tiny)
        _, config = train_speed.build(algo, 2, 96, tiny)
        assert base_config == config
    rows = train_speed.add_ratios(
        [
            {"algo": a, "run_s": t, "steps_per_s": 100.0 / t}
            for a, t in (("ppo", 1.0), ("ippo", 2.0), ("base:ppo", 1.0), ("base:ippo", 3.0))
        ]
    )
    assert [r.get("speedup_vs_base") for r in rows] == [1.0, 1.5, None, None]
    assert [r["ratio_vs_ppo"] for r in rows] == [1.0, 0.5, 1.0, pytest.approx(1 / 3)]


def test_gpu_sweep_writes_a_row_per_measurement_and_stops_at_its_budget(tmp_path, capsys):
    gpu = load("gpu")
    out = tmp_path / "rows.jsonl"
    common = ["--env-steps", "64", "--min-steps", "8", "--repeats", "1", "--algos"]
    gpu.main(["--exponents", "2", "--views", "single", "marl_array", *common, "--out", str(out)])
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["kind"] for r in rows] == ["device", "state", "env", "env"]
    assert [r["view"] for r in rows[2:]] == ["single", "marl_array"]
    for r in rows[2:]:
        assert r["envs"] == 4 and r["steps_per_env"] == 16
        assert r["env_steps_per_s"] == pytest.approx(4 * 16 / r["run_s"])
    # a spent budget starts nothing and says where it stopped
    gpu.main(["--exponents", "2", *common, "--budget-s", "0", "--out", str(out)])
    last = json.loads(out.read_text().splitlines()[-1])
    assert last["kind"] == "stopped" and last["at"] == "single 2^2"


def test_the_gpu_tables_of_the_docs_are_those_of_the_result_file():
    gpu = load("gpu")
    path = BENCH / "results" / "gpu_h200.jsonl"
    table = gpu.tables([json.loads(line) for line in path.read_text().splitlines()])
    assert table in (ROOT / "docs" / "performance.md").read_text()
    assert "| 2^20 |" in table and "| IPPO | 1024 | 2 x 256 |" in table


def test_throughput_extracts_a_base_revision_for_the_training_and_mpc_a_b():
    throughput = load("throughput")
    base = Path(throughput._base_checkout("HEAD"))
    for path in ("baselines/algos/ippo.py", "chargax_marl/optimal/mpc.py"):
        committed = subprocess.run(
            ["git", "-C", str(ROOT), "show", f"HEAD:{path}"], capture_output=True, text=True
        ).stdout
        assert (base / path).read_text() == committed


def test_suite_profile_charges_jax_compile_events_to_the_running_test(tmp_path):
    """The plugin, run by pytest on a one-test file, charges the test's trace, lower and
    compile to it and names the compiled function."""
    tiny = tmp_path / "test_tiny.py"
    tiny.write_text(
        "import jax\n\n\ndef test_doubles():\n"
        "    assert float(jax.jit(lambda x: x * 2.0)(3.0)) == 6.0\n"
    )
    records = tmp_path / "records"
    records.mkdir()
    # the run is pytest's own, not part of this session's (its xdist worker, its current test)
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith("PYTEST_")},
        "CHARGAX_SUITE_PROFILE_DIR": str(records),
        "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "cache"),
        "JAX_PLATFORMS": "cpu",
    }
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "benchmarks.suite_profile_plugin", str(tiny)]
    res = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    profile = load("suite_profile")
    merged = profile.merge([json.loads((records / "main.json").read_text())])
    (test,) = [t for t in merged["tests"] if t.endswith("::test_doubles")]
    row = merged["tests"][test]
    assert row["seconds"] > 0 and row["compiles"] >= 1
    assert row["trace_s"] > 0 and row["lower_s"] > 0 and row["compile_s"] > 0
    assert any(t == test and "lambda" in fun for t, fun, _ in merged["programs"])


def test_suite_profile_sums_processes_per_test_and_file():
    profile = load("suite_profile")
    controller = {
        "durations": {"a.py::t1": 3.0, "a.py::t2": 1.0, "b.py::t3": 5.0},
        "jax": {},
        "programs": [],
    }
    worker = {
        "durations": {},
        "jax": {
            "a.py::t1": {"trace_s": 0.5, "compile_s": 2.0, "compiles": 2},
            profile.OUTSIDE: {"trace_s": 0.25},
        },
        "programs": [["a.py::t1", "jit(f)", 1.5], ["a.py::t1", "jit(g)", 0.5]],
    }
    merged = profile.merge([controller, worker])
    assert merged["tests"]["a.py::t1"] == {
        "seconds": 3.0,
        "trace_s": 0.5,
        "compile_s": 2.0,
        "compiles": 2,
    }
    report = profile.summarize(merged, top=2)
    lines = report.splitlines()
    assert "all 3 tests" in lines[2] and lines[2].split()[:2] == ["9.0", "0.8"]
    files = lines[lines.index("the 2 files with the most seconds") + 2 :][:2]
    assert [f.split()[-1] for f in files] == ["b.py", "a.py"]
    assert files[1].split()[:1] == ["4.0"]
    funs = lines[lines.index("the 2 compiled functions with the most compile seconds") + 2 :]
    assert [f.split()[-1] for f in funs[:2]] == ["jit(f)", "jit(g)"]
    sizes = lines[lines.index("compiles by their seconds") + 2 :][:4]
    assert [r.split()[:2] for r in sizes] == [
        ["0.0", "0"],
        ["0.5", "1"],
        ["1.5", "1"],
        ["0.0", "0"],
    ]
    longest = lines[lines.index("the 2 longest compiles") + 2 :]
    assert [r.split()[:2] for r in longest] == [["1.5", "jit(f)"], ["0.5", "jit(g)"]]


def test_profile_kernels_puts_each_kernel_in_the_phase_its_call_count_names():
    """``profile_kernels.py --train`` reads a kernel's phase from how often one traced call ran
    it; a count two phases share is named ambiguous, not given to one of them."""
    pk = load("profile_kernels")
    per_phase = {"rollout step": 300, "minibatch": 32, "epoch": 8, "update": 2}
    assert pk.phase_of(300, per_phase) == "rollout step"
    assert pk.phase_of(32, per_phase) == "minibatch"
    assert pk.phase_of(1500, per_phase) == "other"
    assert pk.phase_of(8, {"minibatch": 8, "epoch": 8}) == "minibatch|epoch"
    assert pk.is_matrix_product("dot.472", "")
    assert pk.is_matrix_product("ynn_fusion.31", "jit(train)/MLP/Dense_0/dot_general")
    assert not pk.is_matrix_product("ynn_fusion", "jit(train)/vmap()/reduce_sum")
    assert not pk.is_matrix_product("add_tanh_fusion.6", "jit(train)/MLP/tanh")
    hlo = '  %ynn_fusion.3 = f32[8,16]{1,0} fusion(%p), kind=kCustom, metadata={op_name="jit(f)/a/dot_general" stack_frame_id=1}'
    assert pk.source_ops(hlo) == {"ynn_fusion.3": "jit(f)/a/dot_general"}


def _mini_checkout(tmp_path: Path) -> Path:
    """A checkout whose ``make test`` runs a command of every phase, a one-file pytest run (in
    the main and the x64 phase, the second with its own report) and the docs through a
    recursive make."""
    repo = tmp_path / "repo"
    (repo / "tests").mkdir(parents=True)
    (repo / "tests" / "test_one.py").write_text(
        "def test_quick():\n    pass\n\n\ndef test_slow():\n    import time\n\n"
        "    time.sleep(0.3)\n"
    )
    (repo / "tests" / "test_wheel.py").write_text("def test_wheel():\n    pass\n")
    py = sys.executable
    (repo / "Makefile").write_text(
        "test:\n"
        "\tmkdir -p .venv && touch .venv/.installed\n"
        "\techo ruff check .\n"
        f"\t{py} -m pytest -q -p no:cacheprovider -p no:randomly tests\n"
        f"\tJAX_ENABLE_X64=1 {py} -m pytest -q -p no:cacheprovider --junitxml=x64.xml"
        " tests/test_one.py\n"
        "\techo check_test_budget\n"
        "\t$(MAKE) docs\n"
        "docs:\n"
        "\techo mkdocs build\n"
    )
    return repo


def test_suite_phases_times_each_phase_of_make_test_and_reads_its_tests(tmp_path):
    phases = load("suite_phases")
    run = phases.make_test(_mini_checkout(tmp_path), ["docs"], tmp_path / "work", top=3)
    assert run["exit_code"] == 0
    assert [(c["phase"], c["skipped"]) for c in run["commands"]] == [
        ("setup", False),
        ("lint", False),
        ("pytest", False),
        ("x64", False),
        ("budget", False),
        ("docs", True),  # skipped, as asked
        (None, False),  # the recursive make, timed through the commands it runs
    ]
    assert run["skipped_phases"] == ["docs"] and run["phases"]["docs"] == 0.0
    assert run["phases"]["pytest"] > 0.3 and run["phases"]["x64"] > 0.0
    assert run["tests"]["pytest"] == {"passed": 3, "skipped": 0, "failed": 0}
    assert run["tests"]["x64"]["passed"] == 2  # read from the report the command names
    # test_slow sleeps in both passes, so either pass's run may come first
    assert {name for name, *_ in run["slowest"][:2]} == {
        "tests/test_one.py::test_slow",
        "tests/test_one.py::test_slow (x64)",
    }
    assert run["inside_pytest"]["wheel"] >= 0.0 and len(run["slowest"]) == 3


def test_suite_phases_reports_a_failing_make_test_and_its_failed_tests(tmp_path):
    phases = load("suite_phases")
    repo = _mini_checkout(tmp_path)
    (repo / "tests" / "test_one.py").write_text("def test_broken():\n    assert False\n")
    run = phases.make_test(repo, [], tmp_path / "work", top=3)
    assert run["exit_code"] != 0
    assert run["tests"]["pytest"]["failed"] == 1
    assert run["phases"]["x64"] == 0.0  # make stopped at the failing pytest run


def test_suite_phases_skips_the_phases_that_need_a_skipped_one():
    phases = load("suite_phases")
    assert phases.skipped_phases(list(phases.PHASES)) == []
    assert phases.skipped_phases(["setup", "lint", "docs"]) == ["pytest", "x64", "budget", "other"]
    assert phases.skipped_phases(["pytest", "budget", "other"]) == ["lint", "x64", "budget", "docs"]
    assert phases.skipped_phases(["lint"]) == ["pytest", "x64", "budget", "docs", "other"]


def test_suite_phases_classifies_the_commands_of_make_test():
    phases = load("suite_phases")
    make_n = subprocess.run(
        ["make", "-n", "--always-make", "test"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.splitlines()
    found = {phases.phase_of(line) for line in make_n if not line.startswith("make[")}
    assert {"setup", "lint", "pytest", "x64", "budget", "docs"} <= found


def test_suite_phases_embeds_its_table_between_the_markers(tmp_path):
    phases = load("suite_phases")
    run = {
        "label": "A",
        "commit": "a" * 40,
        "wall_s": 400.0,
        "phases": {p: 1.0 for p in phases.PHASES},
        "inside_pytest": {"wheel": 2.0, "notebook": 3.0},
        "tests": {"pytest": {"passed": 5, "skipped": 1, "failed": 0}},
        "skipped_phases": [],
    }
    run.update(load_before="load 0.10 0.20 0.30", load_after="load 1.90 1.20 0.60")
    result = {
        "command": "python benchmarks/suite_phases.py --commits a b",
        "machine": {"cpu": "a CPU", "cores": 2},
        "started": "2026-12-01 10:00",
        "runs": [run, {**run, "label": "B", "commit": "b" * 40, "wall_s": 300.0}],
    }
    result["runs"].append({**run, "wall_s": 420.0})
    table = phases.phase_table(result)
    assert "| A 1 (`aaaaaaa`) | B 2 (`bbbbbbb`) | A 3 (`aaaaaaa`) | median `aaaaaaa` |" in table
    assert "| `make test`, wall | 6 min 40 s | 5 min 00 s | 7 min 00 s | 6 min 50 s |" in table
    page = tmp_path / "page.md"
    page.write_text(f"# P\n\n{phases.MARKERS[0]}\nold\n{phases.MARKERS[1]}\n\nafter\n")
    phases.embed(page, result)
    text = page.read_text()
    assert f"{phases.MARKERS[0]}\n{phases.embedded(result)}\n{phases.MARKERS[1]}" in text
    assert table in text and "old" not in text
    assert "`python benchmarks/suite_phases.py --commits a b`, 2026-12-01 10:00 UTC" in text
    assert "run 1 load 0.10 0.20 0.30 before, load 1.90 1.20 0.60 after" in text
    assert text.endswith("\nafter\n")
    with pytest.raises(ValueError, match="has no line"):
        plain = tmp_path / "plain.md"
        plain.write_text("# no markers\n")
        phases.embed(plain, result)


def test_the_suite_phase_table_of_the_docs_is_that_of_the_result_file():
    phases = load("suite_phases")
    result = json.loads((BENCH / "results" / "suite_phases.json").read_text())
    page = (ROOT / "docs" / "performance.md").read_text()
    assert f"{phases.MARKERS[0]}\n{phases.embedded(result)}\n{phases.MARKERS[1]}" in page


def test_suite_phases_clones_with_the_shared_folder_beside_as_ci_has_it(tmp_path):
    phases = load("suite_phases")
    source = tmp_path / "src" / "repo"
    (tmp_path / "src" / "shared" / "data").mkdir(parents=True)
    source.mkdir()
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(source)]
    subprocess.run(["git", "init", "--quiet", str(source)], check=True)
    (source / "README.md").write_text("one\n")
    subprocess.run([*git, "add", "README.md"], check=True)
    subprocess.run([*git, "commit", "--quiet", "-m", "one"], check=True)
    clone = phases.fresh_clone(source, "HEAD", tmp_path / "work" / "clone")
    assert (clone / "README.md").read_text() == "one\n"
    assert (clone.parent / "shared").resolve() == (tmp_path / "src" / "shared").resolve()
    assert (clone / ".." / "shared" / "data").is_dir()
