"""The sweep: its grid, one compiled program per structure, and each setting's numbers those of
the same setting trained alone."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from baselines import pipeline, sweep
from baselines.algos import ppo, ppo_core, runner
from baselines.config import SCHEMA, ConfigError, canonical, load, validation_env
from baselines.runs import RunDirError
from tests.helpers import CONFIG_TEXT, TINY, TINY_CLI, allowed_by_schema


def test_parse_grid_splits_swept_keys_from_fixed_ones():
    fixed, grid = sweep.parse_grid(
        ["lr=1e-3,3e-4", "SEEDS=4", "ENV_KWARGS={num_levels=2, v2g=true}", "ACTIVATION=tanh,relu"]
    )
    assert fixed == ["SEEDS=4", "ENV_KWARGS={num_levels=2, v2g=true}"]
    assert grid == {"LR": [1e-3, 3e-4], "ACTIVATION": ["tanh", "relu"]}
    assert sweep.settings_of(grid) == [
        {"LR": 1e-3, "ACTIVATION": "tanh"},
        {"LR": 1e-3, "ACTIVATION": "relu"},
        {"LR": 3e-4, "ACTIVATION": "tanh"},
        {"LR": 3e-4, "ACTIVATION": "relu"},
    ]
    assert sweep.settings_of({}) == [{}]
    assert sweep.parse_grid(["LR=1e-3,3e-4", "HIDDEN=8", "LR=1e-4", "HIDDEN=8,16"]) == (
        ["LR=1e-4"],
        {"HIDDEN": [8, 16]},
    )


@pytest.mark.parametrize(
    "args, match",
    [
        (["SEEDS=2,4"], "run key"),
        (["LR=1e-3,1e-3"], "give each value once"),
        (["LR"], "KEY=value"),
        (["TASK=Chargax-shopping-v2,"], r"TASK=.*value 2 of 2 is empty"),
        (["LR=1e-3,,3e-4"], r"value 2 of 3 is empty"),
        (["HIDDEN=64,64.0"], r"'64.0' is the same setting as '64'"),
        (["LR=1e-3,0.001"], "the same setting"),
        (["BATTERY_SHAPING=true,day_mean"], "the same setting"),
        (["HIDDEN=0,8"], r"HIDDEN=0 is not allowed: expected an integer >= 1"),
        (["GAMMA=0.9,1.5"], r"GAMMA=1.5 is not allowed: expected a finite number in \[0, 1\]"),
        (["NOPE=1,2"], "unknown config key 'NOPE'"),
    ],
)
def test_parse_grid_refuses_what_a_sweep_cannot_mean(args, match):
    with pytest.raises(ConfigError, match=match):
        sweep.parse_grid(args)


@pytest.mark.parametrize(
    "args, match",
    [
        (["SEEDS=0"], r"SEEDS=0 is not allowed: expected an integer >= 1"),
        (["SEEDS=-1"], r"SEEDS=-1 is not allowed"),
        (["CHUNKS=0"], r"CHUNKS=0 is not allowed"),
        (["OUT="], r"OUT='' is not allowed: expected a non-empty str"),
        (["OUT=outputs/"], r"field 'OUT' .*a prefix needs a file name"),
        (["NUM_MINIBATCHES=0"], r"NUM_MINIBATCHES=0 is not allowed"),
        (
            ["TOTAL_TIMESTEPS=10"],
            r"TOTAL_TIMESTEPS=10 is not allowed: expected at least one rollout",
        ),
    ],
)
def test_a_sweep_refuses_bad_run_values_before_any_work(args, match, monkeypatch):
    def no_training(*a, **k):
        raise AssertionError("the sweep started training")

    monkeypatch.setattr(sweep, "_sweep", no_training)
    with pytest.raises(ConfigError, match=match):
        sweep.sweep("cpu", [*TINY_CLI[2:], *args])


def test_a_sweep_refuses_an_out_under_a_file_and_a_bad_batch_before_any_work(tmp_path, monkeypatch):
    def no_training(*a, **k):
        raise AssertionError("the sweep started training")

    monkeypatch.setattr(sweep, "_sweep", no_training)
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(ConfigError, match=r"field 'OUT' .*a_file' is a file, not a folder"):
        sweep.sweep("cpu", [*TINY_CLI[2:], f"OUT={tmp_path}/a_file/sweep"])
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ConfigError, match=r"settings_per_batch.*expected an integer >= 1"):
            sweep.sweep("cpu", [*TINY_CLI[2:], f"OUT={tmp_path}/s"], settings_per_batch=bad)
    with pytest.raises(ConfigError, match=r"does not divide compile group 0's 3 settings"):
        sweep.sweep("cpu", [*TINY_CLI[2:], "LR=1e-3,2e-3,3e-3", f"OUT={tmp_path}/s"], 2)
    with pytest.raises(SystemExit):
        sweep.parser().parse_args(["--settings-per-batch", "0"])
    assert not list(tmp_path.glob("s*")), "nothing is written for a refused sweep"


def test_a_swept_value_the_key_does_not_allow_is_refused_before_training(tmp_path):
    with pytest.raises(ConfigError, match="ENT_COEF"):
        sweep.sweep("cpu", ["ENT_COEF=0.01,oops", f"OUT={tmp_path}/s"], write=False)


def test_settings_share_a_program_unless_a_shape_or_structure_key_differs():
    config, _ = load("cpu")
    other_values = {**config, **{k: 0.5 for k in ppo_core.HYPER_KEYS}}
    assert sweep._structure(config) == sweep._structure(other_values)
    assert sweep._structure(config) != sweep._structure({**config, "HIDDEN": 8})
    _, grid = sweep.parse_grid(["LR=1e-3,3e-4", "HIDDEN=8,16", "GAMMA=0.9,0.99"])
    configs = [
        load("cpu", [sweep._override(k, v) for k, v in s.items()])[0]
        for s in sweep.settings_of(grid)
    ]
    groups = sweep.compile_groups(configs, chunks=3)
    assert sorted(groups.values()) == [[0, 1, 4, 5], [2, 3, 6, 7]]  # by HIDDEN
    assert all(c["TOTAL_TIMESTEPS"] % (3 * c["NUM_ENVS"] * c["NUM_STEPS"]) == 0 for c in configs)


def test_a_setting_of_a_sweep_is_bit_for_bit_the_same_setting_trained_alone(tmp_path):
    """Two learning rates in one compiled program: the setting ``LR=3e-4`` trained alone by
    the pipeline, as
    ``python -m baselines.train`` trains it, ends with the same parameters, bit for bit, and
    scores the same on every validation day after every chunk."""
    base = TINY_CLI[2:] + ["ALGO=ippo", "TOTAL_TIMESTEPS=288", "CHUNKS=2", "OPTIMAL=off"]
    out = tmp_path / "sweep"
    argv = ["--config", "cpu", *base, "LR=1e-3,3e-4", f"OUT={out}"]
    results = sweep.main(argv)
    assert len(results["results"]) == 2 and len(results["groups"]) == 1
    for f in sweep.SUFFIXES:
        assert (tmp_path / f"sweep{f}").is_file()
    stored = json.loads((tmp_path / "sweep.json").read_text())
    assert stored["ranking"] == results["ranking"]
    assert sorted(stored["ranking"]) == [0, 1]
    profits = [e["mean_profit"] for e in results["results"]]
    assert [profits[i] for i in stored["ranking"]] == sorted(profits, reverse=True)
    index = next(e["index"] for e in results["results"] if e["setting"] == {"LR": 3e-4})
    entry = results["results"][index]
    config, run = load("cpu", [*base, "LR=3e-4"])
    alone = pipeline.run("ippo", config, seeds=run["SEEDS"], chunks=run["CHUNKS"], quiet=True)
    for a, b in zip(jax.tree.leaves(alone.params), jax.tree.leaves(results["params"][index])):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    curve = alone.results["eval_curve"]
    assert [e["timesteps"] for e in curve] == [e["timesteps"] for e in entry["eval_curve"]]
    for a, b in zip(curve, entry["eval_curve"]):
        np.testing.assert_array_equal(a["per_seed_profit"], b["per_seed_profit"])
    assert stored["validation"]["days"] == np.asarray(validation_env(config)[1]).tolist()
    # the settings differ: the learning rate reaches the program as a value
    other = results["results"][
        next(e["index"] for e in results["results"] if e["setting"] == {"LR": 1e-3})
    ]
    assert entry["group"] == other["group"]
    assert any(
        not np.array_equal(np.asarray(a), np.asarray(b))
        for a, b in zip(
            jax.tree.leaves(results["params"][index]),
            jax.tree.leaves(results["params"][other["index"]]),
        )
    )
    with pytest.raises(RunDirError, match="--overwrite"):
        sweep.main(argv)


def test_settings_vmapped_together_agree_to_rounding():
    train = ppo.make_train({**TINY, "HIDDEN": 16})
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    hyper = {k: np.full(2, v, np.float32) for k, v in ppo_core.hyper_values(train.config).items()}
    hyper["LR"] = np.asarray([1e-3, 3e-4], np.float32)
    one = runner.run_settings_in_chunks(train, keys, hyper, 1)[0].params
    two = runner.run_settings_in_chunks(train, keys, hyper, 1, settings_per_batch=2)[0].params
    for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(two)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-6)
    assert not np.array_equal(*np.asarray(jax.tree.leaves(one)[0])[:, 0])  # the LRs differ
    with pytest.raises(ValueError, match="settings_per_batch"):
        runner.run_settings_in_chunks(train, keys, hyper, 1, settings_per_batch=3)
    with pytest.raises(ValueError, match="missing"):
        runner.run_settings_in_chunks(train, keys, {"LR": hyper["LR"]}, 1)


@settings(max_examples=200, deadline=None)
@given(key=st.sampled_from(sorted(SCHEMA)), parts=st.lists(CONFIG_TEXT, min_size=2, max_size=4))
def test_a_grid_parses_to_distinct_allowed_values_or_is_refused_by_name(key, parts):
    raw = ",".join(parts)
    try:
        fixed, grid = sweep.parse_grid([f"{key}={raw}"])
    except ConfigError as e:
        assert key in str(e) or "argument" in str(e)
        return
    values = grid.get(key)
    if values is None:  # one value after all (a quoted or bracketed text): a fixed override
        assert len(fixed) == 1
        return
    assert len(values) == len({canonical(key, v) for v in values}) >= 2
    assert all(allowed_by_schema(key, v) for v in values), (key, raw, values)
