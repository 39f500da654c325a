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
    save_references,
    score,
)
from chargax_marl.trace import params_fingerprint


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
