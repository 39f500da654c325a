"""Scoring a trained checkpoint on a benchmark task."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from baselines import score as score_cli
from baselines.config import build_env_params
from baselines.runs import load_run
from chargax_marl.benchmark import Task, compute_references, save_references, score


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
        np.testing.assert_array_equal(result["daily_profit"][seed], alone["daily_profit"])
        assert result["per_seed_score"][seed] == pytest.approx(alone["score"], rel=1e-12)
    path = score_cli.write_score(result, "IPPO", tmp_path / "score.json")
    stored = json.loads(path.read_text())
    assert stored["name"] == "IPPO" and stored["seeds"] == 2 and stored["task"] == task.id


def test_a_checkpoint_of_another_station_is_refused(tiny_ippo_run):
    with pytest.raises(score_cli.CheckpointMismatchError, match="another station"):
        score_cli.score_run(tiny_ippo_run, "Chargax-shopping-v1")
