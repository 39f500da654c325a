"""The tasks' validation split: days drawn from the training days, reproducibly, never held out."""

from __future__ import annotations

import numpy as np
import pytest

from chargax_marl.benchmark.tasks import TASKS, Task
from chargax_marl.core import make_params
from chargax_marl.evaluation import split_days, validation_days
from chargax_marl.trace import params_fingerprint


@pytest.mark.parametrize("task_id", sorted(TASKS))
def test_validation_days_are_training_days_drawn_reproducibly(task_id):
    task = TASKS[task_id]
    days = task.validation_days()
    assert days.dtype == np.int32 and days.shape == (task.num_validation_days,)
    assert np.all(np.diff(days) > 0)  # sorted, no day twice
    train = task.train_params()
    assert np.isin(days, np.asarray(train.reset_days)).all()
    played_in = task.train_params() if task.is_shift else task.make_params()
    assert params_fingerprint(task.validation_params()) == params_fingerprint(played_in)
    assert days.max() < int(train.num_days)
    if task.is_shift:  # every day of the training years
        assert int(train.num_days) == np.asarray(train.reset_days).size
    else:
        assert not np.intersect1d(days, task.eval_days()).size
    # the draw of `validation_days` on the training days, the same on every call and process
    train_days = np.arange(int(train.num_days)) if task.is_shift else split_days(365, 100)[0]
    expected = np.sort(
        np.random.default_rng(task.validation_seed).choice(
            train_days, task.num_validation_days, replace=False
        )
    )
    np.testing.assert_array_equal(days, expected)
    assert task.validation_draws == (2 if task.draws == 8 else 1)


def test_the_validation_fields_leave_the_id_and_the_held_out_days_as_they_were():
    task = TASKS["Chargax-shopping-v1"]
    other = Task(
        task.name,
        task.version,
        task.scenario,
        task.draws,
        task.description,
        num_validation_days=5,
        validation_draws=3,
        validation_seed=7,
    )
    assert other.id == task.id
    np.testing.assert_array_equal(other.eval_days(), task.eval_days())
    assert other.validation_days().size == 5
    assert not np.array_equal(other.validation_days(), task.validation_days()[:5])


@pytest.mark.parametrize(
    "field, value",
    [
        ("num_validation_days", 0),
        ("num_validation_days", 2.5),
        ("validation_draws", 0),
        ("validation_draws", True),
        ("validation_seed", -1),
        ("validation_seed", "1"),
    ],
)
def test_a_bad_validation_field_is_refused_naming_it(field, value):
    with pytest.raises(ValueError, match=rf"{field}.*{value!r}"):
        Task("bad", 1, "shopping", 1, "", **{field: value})


def test_more_validation_days_than_training_days_is_refused_when_drawn():
    params = make_params(station="single_type", station_kwargs={"num_ports": 2})

    task = Task("few", 1, "custom", 1, "", num_eval_days=360, params_fn=lambda: params)
    with pytest.raises(ValueError, match=r"num_validation_days.*\[1, 5\].*20"):
        task.validation_days()
    few = Task(
        "few",
        1,
        "custom",
        1,
        "",
        num_eval_days=360,
        num_validation_days=5,
        params_fn=lambda: params,
    )
    np.testing.assert_array_equal(few.validation_days(), split_days(365, 360)[0])


def test_validation_days_draws_from_the_given_days():
    train = np.array([3, 9, 4, 100, 7], np.int32)
    days = validation_days(train, 3, seed=2)
    assert days.dtype == np.int32 and np.isin(days, train).all() and np.all(np.diff(days) > 0)
    np.testing.assert_array_equal(days, validation_days(train, 3, seed=2))
    with pytest.raises(ValueError, match="num_validation_days"):
        validation_days(train, 6)
