"""Scoring a trained checkpoint on a benchmark task."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from baselines import score as score_cli
from baselines.config import ConfigError, build_env_params, load, resolve
from baselines.runs import load_run
from chargax_marl.benchmark import (
    TASKS,
    Task,
    compare,
    compute_references,
    get_task,
    save_references,
    score,
)
from chargax_marl.benchmark.references import __main__ as references_cli
from chargax_marl.trace import params_fingerprint, station_fingerprint
from tests.helpers import TINY_ENV, toml_inline


@pytest.fixture(scope="module")
def run_task(tiny_ippo_run, tmp_path_factory):
    """A task on the tiny run's own station (2 held-out days, 2 draws) with its references."""
    results, _, _ = load_run(tiny_ippo_run)
    _, eval_params, _, _ = build_env_params(results["config"])
    task = Task("tiny", 1, "custom", 2, "", num_eval_days=2, params_fn=lambda: eval_params)
    directory = tmp_path_factory.mktemp("tiny_refs")
    save_references(compute_references(task, rules=("always_max",), log=None), directory)
    return task, directory


def test_a_checkpoint_scores_as_its_greedy_policy_does(tiny_ippo_run, run_task, tmp_path):
    task, directory = run_task
    result = score_cli.score_run(tiny_ippo_run, task, references_dir=directory)
    assert result["daily_profit"].shape == (2, 2, 2)  # seeds, days, draws
    _, train, seed_params = load_run(tiny_ippo_run)
    make_act = train.make_act(task.make_params())
    for seed in range(2):
        one = jax.tree.map(lambda x, i=seed: x[i], seed_params)
        act = make_act(one)
        alone = score(lambda s, k, p, act=act: act(s, k), task, references_dir=directory)
        # equal bit for bit under XLA's default flags; the tests' cheap compile pipeline
        # (tests/conftest.py) may round the seed-batched program's float32 sums differently
        np.testing.assert_allclose(result["daily_profit"][seed], alone["daily_profit"], rtol=1e-6)
        assert result["per_seed_score"][seed] == pytest.approx(alone["score"], rel=1e-5)
    path = score_cli.write_score(result, "IPPO", tmp_path / "score.json")
    stored = json.loads(path.read_text())
    assert stored["name"] == "IPPO" and stored["seeds"] == 2 and stored["task"] == task.id


def test_a_score_file_is_compared_again_against_references_that_moved(
    run_task, tmp_path, monkeypatch
):
    """``--rescore``: the comparison is made again from the stored profits; a reference that
    moved by 1 EUR on every day moves the policy's difference to it by 1 EUR, and nothing
    else of the file moves."""
    task, directory = run_task
    monkeypatch.setitem(TASKS, task.id, task)  # a score file names its task by id
    daily = np.random.default_rng(0).normal(100.0, 10.0, (2, 2, 2))  # seeds, days, draws
    result = {
        **compare(task, daily, directory),
        "daily_profit": daily,
        "metrics": {"daily_profit_eur": float(daily.mean())},
        "config": {"TOTAL_TIMESTEPS": 1, "SCENARIO": "custom", "TRAFFIC": None},
        "params_fingerprint": params_fingerprint(task.make_params()),
    }
    path = score_cli.write_score(result, "mine", tmp_path / "score.json")
    before = path.read_text()
    again = score_cli.rescore(path, directory)
    assert score_cli.write_score(again, "mine", tmp_path / "again.json").read_text() == before

    moved = tmp_path / "moved"
    moved.mkdir()
    refs = json.loads(next(directory.glob("*.json")).read_text())
    refs["policies"]["edf"] = json.loads(json.dumps(refs["policies"]["always_max"]))
    refs["policies"]["edf"]["daily_profit"] = [
        [x + 1.0 for x in row] for row in refs["policies"]["edf"]["daily_profit"]
    ]
    (moved / next(directory.glob("*.json")).name).write_text(json.dumps(refs))
    new = score_cli.rescore(path, moved)
    old = json.loads(before)
    assert new["vs"]["edf"]["mean"] == pytest.approx(old["vs"]["always_max"]["mean"] - 1.0)
    assert new["vs"]["always_max"] == old["vs"]["always_max"]
    assert new["score"] == old["score"] and new["metrics"] == old["metrics"]
    np.testing.assert_array_equal(new["daily_profit"], daily)

    stale = {**old, "params_fingerprint": "0000000000000000"}
    (tmp_path / "stale.json").write_text(json.dumps(stale))
    with pytest.raises(score_cli.CheckpointMismatchError, match="0000000000000000"):
        score_cli.rescore(tmp_path / "stale.json", directory)
    with pytest.raises(SystemExit):
        score_cli.main(["--rescore", str(path), "--task", task.id])
    (tmp_path / "timing.json").write_text(json.dumps({"task": task.id}))
    with pytest.raises(ValueError, match="not a score file"):
        score_cli.rescore(tmp_path / "timing.json", directory)


def test_a_checkpoint_of_another_station_is_refused(tiny_ippo_run):
    with pytest.raises(score_cli.CheckpointMismatchError, match="another station"):
        score_cli.score_run(tiny_ippo_run, "Chargax-shopping-v1")


def _tiny_run_task_file(path, **overrides):
    """A task file on the tiny run's station (3 held-out days, 1 draw), ``overrides`` on top."""
    table = {**TINY_ENV, **overrides}
    lines = [
        'name = "tiny-user"',
        "version = 1",
        'scenario = "shopping"',
        "draws = 1",
        "num_eval_days = 3",
        "",
        "[overrides]",
        *(f"{k} = {toml_inline(v)}" for k, v in table.items()),
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_checkpoint_is_scored_on_a_task_file_of_a_tighter_grid(tiny_ippo_run, tmp_path):
    """Another grid connection leaves the run's spaces as they were: the run is scored on the
    task file's references (in a folder of their own, --references), and its score file
    names the task file, which --rescore reads again."""
    path = _tiny_run_task_file(tmp_path / "tight.toml", grid_fraction=0.3)
    task = get_task(path)
    results, _, _ = load_run(tiny_ippo_run)
    _, run_params, _, _ = build_env_params(results["config"])
    assert station_fingerprint(run_params) != station_fingerprint(task.make_params())
    refs = tmp_path / "refs"
    references_cli.main(
        ["--task-file", str(path), "--rules", "always_max", "--out", str(refs), "--processes", "1"]
    )
    out = tmp_path / "score.json"
    result = score_cli.main(
        [str(tiny_ippo_run), "--task-file", str(path), "--references", str(refs)]
        + ["--out", str(out)]
    )
    assert result["task"] == task.id and result["daily_profit"].shape == (2, 3, 1)
    assert result["days_scored"] == 3 and np.isfinite(result["score"])
    stored = json.loads(out.read_text())
    assert stored["task_file"] == str(path.resolve())
    again = score_cli.rescore(out, refs)
    assert again["score"] == pytest.approx(result["score"], rel=1e-12)


@pytest.mark.parametrize(
    "overrides, match",
    [
        ({"station_kwargs": {"num_ports": 3, "battery": True}}, r"ports: 4 \(the task's 3\)"),
        ({"action_mode": "delta"}, r"action mode: 'absolute' \(the task's 'delta'\)"),
        ({"price_horizon_hours": 3}, r"observation shape"),
    ],
)
def test_a_checkpoint_is_refused_where_its_spaces_differ(tiny_ippo_run, overrides, match):
    results, _, _ = load_run(tiny_ippo_run)
    _, run_params, _, _ = build_env_params(results["config"])
    task = Task("other", 1, "shopping", 1, "", overrides={**TINY_ENV, **overrides})
    with pytest.raises(score_cli.CheckpointMismatchError, match=match):
        score_cli.check_run_fits(run_params, task)


def test_a_checkpoint_fits_a_task_of_other_limits_traffic_and_prices(tiny_ippo_run):
    results, _, _ = load_run(tiny_ippo_run)
    _, run_params, _, _ = build_env_params(results["config"])
    overrides = {**TINY_ENV, "grid_fraction": 0.2, "traffic": "high"}
    task = Task("fits", 1, "shopping", 1, "", prices="DE-2023", overrides=overrides)
    assert params_fingerprint(task.make_params()) != params_fingerprint(run_params)
    score_cli.check_run_fits(run_params, task)  # no error: the spaces are the run's


def test_a_task_in_the_config_trains_on_its_training_data_and_holds_out_its_days():
    task = TASKS["Chargax-shift-nl2024-v1"]
    train, full, train_days, eval_days = build_env_params(
        resolve({"TASK": task.id, "ENV_KWARGS": {"num_levels": 1}})
    )
    assert int(train.num_days) == 365 + 365  # NL 2021 and NL 2022
    np.testing.assert_array_equal(train_days, np.arange(730))
    np.testing.assert_array_equal(eval_days, task.eval_days())
    assert int(full.num_days) == 366 and int(full.num_levels) == 1
    assert params_fingerprint(full) == params_fingerprint(task.policy_params(1))
    with pytest.raises(ConfigError, match="fixes the traffic at .medium."):
        build_env_params(resolve({"TASK": task.id, "TRAFFIC": "high"}))
    with pytest.raises(ConfigError, match="NUM_EVAL_DAYS=50"):
        build_env_params(resolve({"TASK": task.id, "NUM_EVAL_DAYS": 50}))
    with pytest.raises(ConfigError, match="TASK"):
        resolve({"TASK": "Chargax-nope-v1"})


def test_a_task_on_the_command_line_overrides_the_files_scenario_and_traffic(tmp_path):
    """``--config FILE TASK=<a high-traffic task>``: the file's scenario and medium traffic
    give way to the task's; a ``TRAFFIC`` override that contradicts the task is still
    refused."""
    task = TASKS["Chargax-shopping-grid10-high-v1"]
    path = tmp_path / "medium.toml"
    path.write_text(
        'ALGO = "ippo"\nSCENARIO = "shopping"\nTRAFFIC = "medium"\n'
        "ENV_KWARGS = { num_levels = 1 }\n"
    )
    assert load(path)[0]["TRAFFIC"] == "medium"
    config, _ = load(path, [f"TASK={task.id}"])
    assert config["SCENARIO"] == task.scenario and config["TRAFFIC"] is None
    _, full, _, _ = build_env_params(config)
    assert params_fingerprint(full) == params_fingerprint(task.policy_params(1))
    assert load(path, [f"TASK={task.id}", "TRAFFIC=high"])[0]["TRAFFIC"] == "high"
    with pytest.raises(ConfigError, match="fixes the traffic at .high."):
        build_env_params(load(path, [f"TASK={task.id}", "TRAFFIC=medium"])[0])
    with pytest.raises(ConfigError, match="TASK"):
        load(path, ["TASK=Chargax-nope-v1"])


def test_the_score_command_refuses_what_it_cannot_read_by_name(tiny_ippo_run, tmp_path, capsys):
    """An unknown task, a missing task file, a folder that holds no run, a missing references
    folder and a missing score file are refused at the door, by name, without a traceback."""
    cases = [
        ([str(tiny_ippo_run), "--task", "Chargax-nope-v3"], "unknown task 'Chargax-nope-v3'"),
        ([str(tiny_ippo_run), "--task-file", str(tmp_path / "no.toml")], "no such file"),
        ([str(tmp_path), "--task", "Chargax-shopping-v3"], "no results.json in it"),
        (
            [str(tiny_ippo_run), "--task", "Chargax-shopping-v3", "--references", "nope/"],
            "--references 'nope/': not a directory",
        ),
        (["--rescore", str(tmp_path / "gone.json")], "no such score files"),
    ]
    for argv, match in cases:
        with pytest.raises(SystemExit) as e:
            score_cli.main(argv)
        assert e.value.code == 2
        err = capsys.readouterr().err
        assert match in err and "Traceback" not in err, (argv, err)
