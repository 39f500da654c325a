"""The config's validation split: `validation_env` for a task and a scenario, and the keys a
task fixes."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from baselines.config import (
    CONFIG_DIR,
    SCHEMA,
    ConfigError,
    build_env_params,
    load,
    parse_override,
    resolve,
    validation_env,
)
from chargax_marl.benchmark.tasks import TASKS
from chargax_marl.evaluation import run_policy_days, validation_days
from chargax_marl.policies import always_max
from chargax_marl.trace import params_fingerprint
from tests.helpers import CONFIG_TEXT, TINY_ENV, allowed_by_schema

HIGH = "Chargax-shopping-grid25-high-v1"
SHIFT = "Chargax-shift-nl2024-v1"


def test_a_task_configs_validation_split_is_the_tasks():
    for task_id, kwargs in ((HIGH, {}), (SHIFT, {"num_levels": 1})):
        task = TASKS[task_id]
        config = resolve({"TASK": task_id, "ENV_KWARGS": kwargs})
        assert config["VALIDATION_DRAWS"] == task.validation_draws
        params, days, draws = validation_env(config)
        np.testing.assert_array_equal(days, task.validation_days())
        assert draws == task.validation_draws
        assert params_fingerprint(params) == params_fingerprint(task.validation_params(**kwargs))
    assert TASKS[HIGH].validation_draws == 2  # not the key's default: the task sets it


def test_a_scenario_configs_validation_days_are_drawn_from_its_training_days():
    config = resolve({"NUM_EVAL_DAYS": 30, "NUM_VALIDATION_DAYS": 7, "VALIDATION_SEED": 3})
    train, _, train_days, eval_days = build_env_params(config)
    params, days, draws = validation_env(config)
    np.testing.assert_array_equal(days, validation_days(train_days, 7, 3))
    assert np.isin(days, train_days).all() and not np.isin(days, eval_days).any()
    assert draws == 1 and params_fingerprint(params) == params_fingerprint(
        build_env_params(config)[1]
    )


def test_a_validation_day_plays_the_same_in_the_training_and_the_scored_env():
    """Validation plays in the scored env (where the price data are the same): a day starts
    from an empty station on that day, so the training env's reset days change nothing."""
    config = resolve({"ENV_KWARGS": TINY_ENV, "NUM_VALIDATION_DAYS": 3})
    train, full, _, _ = build_env_params(config)
    params, days, _ = validation_env(config)
    assert np.shape(train.reset_days) != np.shape(full.reset_days)
    key = jax.random.PRNGKey(4)
    a = run_policy_days(always_max, train, days, key)
    b = run_policy_days(always_max, params, days, key)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert [resolve({})[k] for k in ("NUM_VALIDATION_DAYS", "VALIDATION_DRAWS")] == [20, 1]
    with pytest.raises(ConfigError, match=r"NUM_VALIDATION_DAYS=400.*\[1, 335\]"):
        validation_env(resolve({"NUM_EVAL_DAYS": 30, "NUM_VALIDATION_DAYS": 400}))


@pytest.mark.parametrize(
    "key, value", [("NUM_VALIDATION_DAYS", 10), ("VALIDATION_DRAWS", 1), ("VALIDATION_SEED", 2)]
)
def test_a_validation_key_other_than_the_tasks_is_refused_naming_it(key, value):
    config = resolve({"TASK": HIGH, key: value})
    with pytest.raises(ConfigError, match=rf"{key}={value}"):
        validation_env(config)


@pytest.mark.parametrize("key", ["NUM_VALIDATION_DAYS", "VALIDATION_DRAWS", "VALIDATION_SEED"])
def test_a_validation_key_below_one_is_refused(key):
    with pytest.raises(ConfigError, match=key):
        resolve({key: 0})


def test_a_task_override_sets_the_validation_keys_over_the_files(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text("VALIDATION_DRAWS = 3\nNUM_VALIDATION_DAYS = 5\n")
    assert load(path)[0]["VALIDATION_DRAWS"] == 3
    config, _ = load(path, [f"TASK={HIGH}"])
    assert config["VALIDATION_DRAWS"] == 2 and config["NUM_VALIDATION_DAYS"] == 20
    validation_env(config)
    with pytest.raises(ConfigError, match="VALIDATION_DRAWS=3"):
        validation_env(load(path, [f"TASK={HIGH}", "VALIDATION_DRAWS=3"])[0])


def test_a_scenario_other_than_the_configs_task_is_refused_and_task_off_frees_it():
    # the default configs train on a task; a SCENARIO override would have been ignored
    with pytest.raises(ConfigError, match="SCENARIO='shopping-grid25-high' differs from TASK="):
        load("ippo", ["SCENARIO=shopping-grid25-high"])
    config, _ = load("ippo", ["TASK=", "SCENARIO=shopping-grid25-high", "TRAFFIC=high"])
    assert config["TASK"] == "" and config["SCENARIO"] == "shopping-grid25-high"
    assert float(build_env_params(config)[1].station.node_max_kw[0]) < float(
        TASKS["Chargax-shopping-v2"].make_params().station.node_max_kw[0]
    )


def test_stored_run_configs_still_resolve():
    root = Path(__file__).resolve().parents[2] / "results"
    configs = [json.loads(p.read_text()).get("config") for p in sorted(root.rglob("results.json"))]
    for config in filter(None, configs):
        resolved = resolve(config)
        assert resolved["NUM_VALIDATION_DAYS"] >= 1 and resolved["VALIDATION_DRAWS"] >= 1


def test_a_new_run_names_its_session_model_and_an_old_one_reads_as_the_papers():
    from baselines.config import name_session_model, stored_config

    fresh = name_session_model(resolve({"ENV_KWARGS": {"num_levels": 1}}))
    assert fresh["ENV_KWARGS"] == {"num_levels": 1, "session_model": "v2"}
    old = stored_config({"ENV_KWARGS": {"num_levels": 1}})
    assert old["ENV_KWARGS"] == {"num_levels": 1, "session_model": "paper"}
    # a named model and a task's are kept as they are
    assert stored_config(fresh) is fresh
    task = {"TASK": "Chargax-shopping-v1", "ENV_KWARGS": {}}
    assert stored_config(task) is task and name_session_model(task) is task


@pytest.mark.parametrize("path", sorted(CONFIG_DIR.glob("*.toml")), ids=lambda p: p.stem)
def test_every_bundled_config_resolves_and_a_task_config_builds_its_task(path):
    config, _ = load(path.stem)
    if config["TASK"]:  # a per-task config trains on its task's training data
        _, params, _, _ = build_env_params(config)
        assert params.station.num_leaves == TASKS[config["TASK"]].make_params().station.num_leaves


def test_an_override_s_bare_word_loses_the_blanks_around_it():
    assert parse_override("SCENARIO= shopping ") == ("SCENARIO", "shopping")
    assert parse_override(" total_timesteps = 2e6") == ("TOTAL_TIMESTEPS", 2e6)
    assert parse_override("ENV_KWARGS={num_levels=1}") == ("ENV_KWARGS", {"num_levels": 1})


# --- properties of the parsers: any text parses to what the schema says, or is refused by name


@settings(max_examples=300, deadline=None)
@given(key=st.sampled_from(sorted(SCHEMA)), raw=CONFIG_TEXT)
def test_an_override_resolves_to_what_the_schema_says_or_is_refused_by_name(key, raw):
    try:
        parsed_key, value = parse_override(f"{key}={raw}")
        config = resolve({parsed_key: value})
    except ConfigError as e:
        assert key in str(e) or "override" in str(e)
        return
    assert allowed_by_schema(key, config[key]), (key, raw, config[key])


@settings(max_examples=100, deadline=None)
@given(n=st.integers(-(2**33), 2**33))
def test_an_integer_key_reads_an_integer_and_refuses_it_below_one_or_past_int32(n):
    try:
        config = resolve({"HIDDEN": parse_override(f"HIDDEN={n}")[1]})
    except ConfigError as e:
        assert not 1 <= n <= 2**31 - 1 and f"HIDDEN={n}" in str(e)
        return
    assert 1 <= n <= 2**31 - 1 and config["HIDDEN"] == n


def test_a_multi_day_episode_is_refused_before_training():
    """The trainers evaluate, shape and score one-day episodes: ``episode_days`` other than 1
    is refused when the env params are built, with the field and value named, on a scenario
    and on a task."""
    from baselines.config import ConfigError, build_env_params, resolve

    for extra in ({}, {"TASK": "Chargax-shopping-v3"}):
        config = resolve({**extra, "ENV_KWARGS": {"episode_days": 2}})
        with pytest.raises(ConfigError, match=r"episode_days=2.*episode_days=1"):
            build_env_params(config)
