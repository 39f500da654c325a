"""Tasks a user defines: `make_params` overrides on a `Task`, task files, and their references
built and scored like a registered task's."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from chargax_marl import policies
from chargax_marl.benchmark import (
    TASKS,
    ReferenceMismatchError,
    Task,
    get_task,
    load_references,
    score,
)
from chargax_marl.benchmark.references import BOUND, ZERO, reference_path
from chargax_marl.benchmark.references import __main__ as references_cli
from chargax_marl.benchmark.tasks import OVERRIDE_KEYS, TASK_FILE_FIELDS, load_task
from chargax_marl.core import make_params
from chargax_marl.core.scenarios import scenario_kwargs
from chargax_marl.trace import params_fingerprint

DOCS = Path(__file__).resolve().parents[2] / "docs" / "benchmark.md"

FR_2022 = """\
name = "shopping-fr2022"
version = 1
scenario = "shopping"
draws = 2
description = "FR 2022 prices (the price crisis) on the default station"
prices = "FR-2022"
session_model = "v2"
bound = "pooled"

[overrides]
grid_fraction = 0.15
"""

TINY = """\
name = "tiny-user"
version = 1
scenario = "shopping"
draws = 1
num_eval_days = 3
description = "two ports in hourly steps: a task cheap to build and score"

[overrides]
station = "single_type"
station_kwargs = { num_ports = 2 }
step_minutes = 60.0
"""
"""A user task cheap enough to build its references (with the bound) in a test."""


def _top(key_value: str) -> str:
    """`FR_2022` with a top-level line added (a line after ``[overrides]`` belongs to it)."""
    return FR_2022.replace("[overrides]", f"{key_value}\n\n[overrides]")


def _write(tmp_path, text, name="task.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_overrides_reach_every_env_of_the_task():
    task = Task("mine", 1, "shopping", 1, "", overrides={"grid_fraction": 0.15, "traffic": "high"})
    plain = make_params(**scenario_kwargs("shopping"))
    for params in (task.make_params(), task.train_params(), task.validation_params()):
        assert float(params.station.node_max_kw[0]) < float(plain.station.node_max_kw[0])
        assert params_fingerprint(params.replace(reset_days=plain.reset_days)) != (
            params_fingerprint(plain)
        )
    assert params_fingerprint(task.make_params()) == params_fingerprint(
        make_params(**scenario_kwargs("shopping", grid_fraction=0.15, traffic="high"))
    )
    # on top of the scenario's own keywords: the 25 % scenario at 15 %
    tighter = Task("mine", 1, "shopping-grid25-high", 1, "", overrides={"grid_fraction": 0.15})
    assert tighter.env_kwargs()["grid_fraction"] == 0.15


def test_a_registered_task_has_no_overrides_and_its_parameters_as_they_were():
    for task in TASKS.values():
        assert dict(task.overrides) == {} and task.source is None
        if task.params_fn is None:
            expected = scenario_kwargs(
                task.scenario, prices=task.prices, session_model=task.session_model
            )
            assert task.env_kwargs() == expected
    task = TASKS["Chargax-shopping-v2"]
    same = dataclasses.replace(task, overrides={})
    assert same == task and hash(same) == hash(task)
    assert params_fingerprint(same.make_params()) == load_references(task)["params_fingerprint"]


def test_overrides_are_frozen_so_the_task_stays_hashable():
    kwargs = {"num_ports": 2, "battery": True}
    task = Task(
        "mine", 1, "shopping", 1, "", overrides={"station": "single_type", "station_kwargs": kwargs}
    )
    kwargs["num_ports"] = 5  # the caller's dict changed afterwards: the task keeps its own
    same = {"station": "single_type", "station_kwargs": {"num_ports": 2, "battery": True}}
    assert hash(task) == hash(Task("mine", 1, "shopping", 1, "", overrides=same))
    assert task.env_kwargs()["station_kwargs"] == {"num_ports": 2, "battery": True}
    assert isinstance(task.env_kwargs()["station_kwargs"], dict)
    with pytest.raises(TypeError):
        task.overrides["station"] = "multiple_types"  # read-only
    assert int(task.make_params().station.num_ports) == 2


@pytest.mark.parametrize(
    "overrides, match",
    [
        ({"grid_fractoin": 0.15}, r"'grid_fractoin'.*not a make_params keyword.*'grid_fraction'"),
        ({"prices": "DE-2023"}, r"'prices'.*field 'prices'"),
        ({"session_model": "paper"}, r"'session_model'.*field 'session_model'"),
        ({"reset_days": [1, 2]}, r"'reset_days'.*training days"),
        ({"moer_kg_per_kwh": np.zeros(3)}, r"override 'moer_kg_per_kwh'.*params_fn"),
        ([("grid_fraction", 0.15)], r"field 'overrides' must be a mapping"),
    ],
)
def test_a_bad_override_is_refused_at_construction_naming_it(overrides, match):
    with pytest.raises(ValueError, match=match):
        Task("mine", 1, "shopping", 1, "", overrides=overrides)


def test_overrides_and_params_fn_are_refused_together():
    with pytest.raises(ValueError, match=r"'overrides' must be empty on a task with params_fn"):
        Task("mine", 1, "custom", 1, "", params_fn=make_params, overrides={"traffic": "high"})
    assert set(OVERRIDE_KEYS) >= {"station", "station_kwargs", "grid_fraction", "traffic"}


def test_a_task_file_reads_as_the_task_it_writes_down(tmp_path):
    path = _write(tmp_path, FR_2022)
    task = load_task(path)
    expected = Task(
        "shopping-fr2022",
        1,
        "shopping",
        2,
        "FR 2022 prices (the price crisis) on the default station",
        prices="FR-2022",
        session_model="v2",
        bound="pooled",
        overrides={"grid_fraction": 0.15},
    )
    assert task == expected and task.id == "Chargax-shopping-fr2022-v1"
    assert task.source == path.resolve()
    assert params_fingerprint(task.make_params()) == params_fingerprint(expected.make_params())
    # the same task as JSON, and by path through get_task (a string or a Path)
    as_json = {k: v for k, v in dataclasses.asdict(expected).items() if k in TASK_FILE_FIELDS}
    as_json = {**as_json, "overrides": dict(expected.overrides), "train_prices": []}
    json_path = tmp_path / "task.json"
    json_path.write_text(json.dumps(as_json))
    assert load_task(json_path) == task
    assert get_task(str(path)) == task and get_task(json_path) == task
    # a file without the optional keys: the fields' defaults
    short = _write(
        tmp_path, 'name = "a"\nversion = 2\nscenario = "workplace"\ndraws = 1\n', "a.toml"
    )
    assert load_task(short) == Task("a", 2, "workplace", 1, "")


@pytest.mark.parametrize(
    "text, match",
    [
        (_top('colour = "red"'), r"unknown key 'colour'; allowed keys: \['name', 'version'"),
        (FR_2022.replace("draws = 2\n", ""), r"missing key 'draws'; required keys"),
        (
            FR_2022.replace("draws = 2", 'draws = "2"'),
            r"field 'draws' must be an integer >= 1, got '2'",
        ),
        (FR_2022.replace("version = 1", "version = 0"), r"field 'version' must be an integer >= 1"),
        (FR_2022.replace('"shopping"\n', '"shoping"\n'), r"field 'scenario' must be a scenario"),
        (FR_2022.replace('"pooled"', '"tight"'), r"field 'bound' must be one of \['occupancy'"),
        (FR_2022.replace("shopping-fr2022", "my task"), r"field 'name' must be a string of"),
        (_top("num_eval_days = 2.5"), r"field 'num_eval_days' must be an integer"),
        (_top("traffic = 'high'"), r"unknown key 'traffic'"),  # an override outside [overrides]
        (FR_2022.replace("grid_fraction", "grid"), r"'grid'.*not a make_params keyword"),
        (FR_2022.replace("0.15", "1.5"), r"Chargax-shopping-fr2022-v1.*grid_fraction.*1.5"),
        (FR_2022.replace('name = "shopping-fr2022"', 'name = "shopping"'), r"registered task"),
        ("name = [", r"not a valid TOML file"),
    ],
)
def test_a_bad_task_file_is_refused_naming_the_key_and_the_value(tmp_path, text, match):
    path = _write(tmp_path, text)
    with pytest.raises(ValueError, match=match) as refused:
        load_task(path)
    assert str(path) in str(refused.value)


def test_a_task_file_of_another_suffix_or_a_missing_one_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"must end in one of \['.toml', '.json'\]"):
        load_task(_write(tmp_path, FR_2022, "task.yaml"))
    with pytest.raises(FileNotFoundError):
        get_task(str(tmp_path / "absent.toml"))
    with pytest.raises(KeyError, match="task file"):
        get_task("Chargax-absent-v1")


def test_a_user_task_s_references_are_built_beside_its_file_and_always_max_scores_zero(
    tmp_path, capsys
):
    """The references command builds a task file's references (the bound too) into the
    file's folder; `score` finds them there from the path alone, and always-max scores 0."""
    path = _write(tmp_path, TINY)
    task = load_task(path)
    with pytest.raises(ReferenceMismatchError, match=r"--task-file .*task.toml"):
        load_references(path)
    references_cli.main(["--task-file", str(path), "--rules", ZERO, "--processes", "1"])
    written = reference_path(task, tmp_path)
    assert str(written) in capsys.readouterr().out
    refs = load_references(str(path))
    assert sorted(refs["policies"]) == [ZERO, BOUND]
    assert refs["policies"][BOUND]["daily_profit"].shape == (3, 1)
    assert np.isfinite(refs["policies"][BOUND]["daily_profit"]).all()

    result = score(policies.always_max, str(path))
    assert result["task"] == task.id and result["days_scored"] == 3
    assert result["score"] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(
        result["daily_profit"], refs["policies"][ZERO]["daily_profit"], rtol=1e-6
    )
    # elsewhere, given by --out and references_dir
    other = tmp_path / "refs"
    references_cli.main(
        ["--task-file", str(path), "--rules", ZERO, "--no-bound", "--out", str(other)]
    )
    assert reference_path(task, other).exists()
    assert ZERO in load_references(task, other)["policies"]


def test_the_task_file_of_the_docs_reads_as_the_task_it_describes(tmp_path):
    block = re.search(r"```toml\n(.*?)```", DOCS.read_text(), re.S).group(1)
    task = load_task(_write(tmp_path, block))
    assert task.id == "Chargax-shopping-fr2022-v1" and task.prices == "FR-2022"
    assert dict(task.overrides) == {"grid_fraction": 0.15}
