"""``python -m baselines.train`` and the pipeline: config files, overrides, run directories, references."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np
import pytest

from baselines import runs
from baselines import train as cli
from baselines.algos import ppo
from baselines.config import ConfigError, build_env_params, resolve
from baselines.eval import heldout
from tests.helpers import TINY, TINY_CLI, toml_inline

ROOT = Path(__file__).resolve().parents[2]


def test_cli_smoke_writes_png_json_checkpoint(tmp_path, monkeypatch):
    out = tmp_path / "run"
    evaluations = []  # the days of every evaluation of the agent's parameters
    evaluate = heldout.evaluate_batched

    def counting(*args, **kwargs):
        evaluations.append(np.asarray(args[3]).tolist())
        return evaluate(*args, **kwargs)

    monkeypatch.setattr(heldout, "evaluate_batched", counting)
    cli.main(
        [
            *TINY_CLI,
            "ALGO=ppo",
            f"TOTAL_TIMESTEPS={4 * 24 * 2}",
            "CHUNKS=2",
            "SEED=1",
            f"OUT={toml_inline(str(out))}",
        ]
    )
    for name in ("curve.png", "results.json", "params.msgpack"):
        assert (out / name).stat().st_size > 0, name
    res = json.loads((out / "results.json").read_text())
    table = res["evaluation"]["table"]
    # the LP hindsight bound is a baseline by default (--optimal bound), and every policy,
    # the agent included, carries its fraction of the headroom between always-max and it
    # on a station with a battery, the battery shaping's teacher played as a rule is a baseline too
    assert set(table) == {
        "always_max",
        "battery_rule",
        "price_threshold",
        "battery_programme",
        "plan_programme",
        "lp_bound",
        "ppo",
    }
    bound, am = (
        np.asarray(table["lp_bound"]["daily_profit"]),
        np.asarray(table["always_max"]["daily_profit"]),
    )
    assert np.all(bound >= am - 1e-3)
    assert table["lp_bound"]["headroom"]["fraction"] == pytest.approx(1.0)
    assert np.isfinite(res["headroom"]["fraction"]) and res["headroom"]["headroom_eur"] > 0
    assert table["ppo"]["num_days"] == 20 and res["timesteps"] == 4 * 24 * 2
    assert len(res["eval_curve"]) == 2 and len(res["curve"]["timesteps"]) == 2
    # one evaluation per chunk on the validation days, then the final policy's on the held-out
    validation = res["validation"]
    assert evaluations == [validation["days"]] * 2 + [res["evaluation"]["days"]]
    assert validation["num_days"] == 20 and validation["draws"] == 1
    assert set(validation["references"]) == set(table) - {"lp_bound", "ppo"}
    # paired comparison with always-max on the same days and cars, per evaluation point
    vs = res["vs_always_max"]
    assert len(vs["per_seed_mean"]) == 2 and np.isfinite(vs["mean"]) and vs["stderr"] >= 0
    assert all(e["vs_always_max"] is not None for e in res["eval_curve"])
    # and with always-max + the battery price rule
    rule = res["vs_battery_rule"]
    assert len(rule["per_seed_mean"]) == 2 and np.isfinite(rule["mean"])
    assert all(e["vs_battery_rule"] is not None for e in res["eval_curve"])
    # per seed: both paired differences, the headroom fraction and when it first beats each rule
    assert res["scenario"]["name"] == "shopping" and res["scenario"]["held_out_days"] == 20
    assert len(res["per_seed"]) == 2
    for i, p in enumerate(res["per_seed"]):
        assert p["vs_always_max"]["mean"] == pytest.approx(vs["per_seed_mean"][i])
        assert p["vs_battery_rule"]["mean"] == pytest.approx(rule["per_seed_mean"][i])
        assert np.isfinite(p["headroom_fraction"])
        for k in ("first_beats_always_max", "first_beats_battery_rule"):
            assert p[k] is None or (p[k]["timesteps"] > 0 and p[k]["wall_minutes"] > 0)
    assert res["over_seeds"]["vs_always_max"]["mean"] == pytest.approx(vs["mean"])
    assert list(res["over_seeds"]) == [
        "vs_always_max",
        "vs_battery_rule",
        "vs_battery_programme",
        "vs_plan_programme",
        "headroom_fraction",
    ]
    for name in ("battery_programme", "plan_programme"):
        gap = np.mean(table[name]["daily_profit"]) - np.mean(table["always_max"]["daily_profit"])
        assert table[name]["vs_always_max"]["mean"] == pytest.approx(gap, abs=1e-3)
        for i, p in enumerate(res["per_seed"]):
            assert p[f"vs_{name}"]["mean"] == pytest.approx(res[f"vs_{name}"]["per_seed_mean"][i])
            # a seed's differences agree with the references' own profits
            assert p["vs_always_max"]["mean"] - p[f"vs_{name}"]["mean"] == pytest.approx(
                gap, abs=1e-3
            )
    _check_add_teacher_rules_reproduces(out / "results.json", res)
    # the checkpoint restores into the parameter pytree (leading axis = seed)
    train = ppo.make_train({**TINY, "HIDDEN": 16})
    template = jax.vmap(train.policy.init)(jax.random.split(jax.random.PRNGKey(0), 2))
    restored = runs.load_params(template, out / "params.msgpack")
    assert jax.tree.structure(restored) == jax.tree.structure(template)


def _check_add_teacher_rules_reproduces(path, res):
    """``baselines.experiments.add_teacher_rules`` on the run's file with the teachers' rules
    taken out (as a run made before they were baselines) puts back what the run recorded; a
    file whose always-max differs from a replay on this code is refused and left as it was."""
    from baselines.experiments import add_teacher_rules

    rules = ("battery_programme", "plan_programme")
    old = json.loads(path.read_text())
    for name in rules:
        del old["evaluation"]["table"][name], old[f"vs_{name}"], old[f"first_beats_{name}"]
        del old["over_seeds"][f"vs_{name}"]
        for p in old["per_seed"]:
            del p[f"vs_{name}"], p[f"first_beats_{name}"]
    path.write_text(json.dumps(old))
    add_teacher_rules.main([str(path)])
    new = json.loads(path.read_text())
    assert list(new["evaluation"]["table"])[-1] == "ppo"
    assert list(new["over_seeds"]) == list(res["over_seeds"])
    for name in rules:
        fresh = res["evaluation"]["table"][name]
        # scored beside other rules than in the run (one program for the rules it plays), so
        # equal to float32 rounding of a day's sum
        np.testing.assert_allclose(
            new["evaluation"]["table"][name]["daily_profit"],
            fresh["daily_profit"],
            rtol=1e-6,
            atol=1e-4,
        )
        assert new["evaluation"]["table"][name]["headroom"]["fraction"] == pytest.approx(
            fresh["headroom"]["fraction"], rel=1e-5
        )
        for a, b in zip(new["per_seed"], res["per_seed"]):
            assert a[f"vs_{name}"] == pytest.approx(b[f"vs_{name}"], rel=1e-5)
            assert list(a).index(f"vs_{name}") < list(a).index("headroom_fraction")
        assert new["over_seeds"][f"vs_{name}"]["mean"] == pytest.approx(
            res["over_seeds"][f"vs_{name}"]["mean"], rel=1e-5
        )
        assert new[f"vs_{name}"]["mean"] == pytest.approx(res[f"vs_{name}"]["mean"], rel=1e-5)
    # another model's always-max: refused, nothing written
    bad = json.loads(path.read_text())
    bad["evaluation"]["table"]["always_max"]["daily_profit"][3] += 1.0
    path.write_text(json.dumps(bad))
    with pytest.raises(
        ValueError, match="always_max replayed on this code differs .* by up to 1.000"
    ):
        add_teacher_rules.main([str(path)])
    assert json.loads(path.read_text()) == bad


def test_cli_overrides_reach_the_config_and_unknown_keys_raise(monkeypatch):
    """``KEY=value`` arguments override the config file's keys; a misspelt key raises, naming
    it and the allowed keys, before anything trains."""
    from baselines import pipeline

    seen = {}
    monkeypatch.setattr(
        pipeline,
        "run",
        lambda algo, config, **kw: (
            seen.update(config, ALGO=algo, **kw) or pipeline.RunOutput({}, None, None)
        ),
    )
    cli.main(
        [
            "RELATIVE_PRICES=true",
            "BATTERY_NET=false",
            "BATTERY_GAMMA=0.95",
            "BATTERY_SHAPING=dp",
            "PORT_SHAPING=plan",
            "TOTAL_TIMESTEPS=7200",
        ]
    )
    assert (
        seen["RELATIVE_PRICES"] is True and seen["BATTERY_NET"] is False and seen["ALGO"] == "ippo"
    )
    assert (
        seen["BATTERY_GAMMA"] == 0.95
        and seen["BATTERY_SHAPING"] == "dp"
        and seen["PORT_SHAPING"] == "plan"
    )
    assert seen["TOTAL_TIMESTEPS"] == 7200 and seen["out"] == "outputs/train_ippo_v2"
    with pytest.raises(ConfigError, match=r"TOTAL_TIMESTEPS=100 .*at least one rollout"):
        cli.main(["TOTAL_TIMESTEPS=100"])
    with pytest.raises(ConfigError, match="BATTERY_NETT.*allowed.*BATTERY_NET"):
        cli.main(["BATTERY_NETT=true"])
    with pytest.raises(ConfigError, match="PORT_SHAPING='planned'.*one of"):
        cli.main(["PORT_SHAPING=planned"])


def test_replot_adds_the_stored_mpc_for_exactly_the_runs_params(ippo_run, tmp_path, monkeypatch):
    """``python -m baselines.train --replot RUN`` finds the MPC stored for the run's params and
    held-out days, adds it to the run's table with the paired difference, and redraws the
    curve; without a matching stored result it raises ``LookupError``."""
    from chargax_marl.trace import params_fingerprint

    out = ippo_run
    res = json.loads((out / "results.json").read_text())
    (tmp_path / "optimal").mkdir()
    with pytest.raises(LookupError, match="no stored MPC"):
        cli.main(["--replot", str(out), "--references", str(tmp_path / "optimal")])
    config = resolve(res["config"])
    _, eval_params, _, days = build_env_params(config)
    days = [int(d) for d in days]
    mpc_daily = np.linspace(10.0, 20.0, len(days))
    stored = {
        "params_fingerprint": params_fingerprint(eval_params),
        "days": days,
        "policies": {"mpc": {"daily_profit": mpc_daily.tolist()}},
    }
    (tmp_path / "optimal" / "other.json").write_text(
        json.dumps({**stored, "params_fingerprint": "0" * 16})
    )
    (tmp_path / "optimal" / "tiny.json").write_text(json.dumps(stored))
    before = (out / "curve.png").stat().st_mtime_ns
    cli.main(["--replot", str(out), "--references", str(tmp_path / "optimal")])
    new = json.loads((out / "results.json").read_text())
    table = new["evaluation"]["table"]
    assert table["mpc"]["daily_profit"] == pytest.approx(mpc_daily.tolist())
    learned = np.asarray(table["ippo"]["daily_profit"])  # (seeds, days)
    assert new["vs_mpc"]["mean"] == pytest.approx(float((learned - mpc_daily[None, :]).mean()))
    assert len(new["vs_mpc"]["per_seed_mean"]) == 2
    assert new["per_seed"] == res["per_seed"]  # nothing else of the run changes
    assert (out / "curve.png").stat().st_mtime_ns > before


def test_eval_draws_score_every_policy_on_the_mean_over_car_draws_of_each_day(tmp_path):
    """``EVAL_DRAWS=2``: the rules, the bound and the agent are scored under PRNGKey(0) and
    PRNGKey(1), each day's profit the mean of the two; the run says so, ``baselines.analysis.redraw``
    replays it only with at least its draws, and the one-draw stored MPC is refused."""
    from baselines import pipeline
    from baselines.analysis import redraw
    from baselines.eval.rules import evaluate_rules

    out = tmp_path / "run"
    cli.main(
        [
            *TINY_CLI,
            "ALGO=ppo",
            f"TOTAL_TIMESTEPS={4 * 24}",
            "CHUNKS=1",
            "EVAL_DRAWS=2",
            f"OUT={toml_inline(str(out))}",
        ]
    )
    res = json.loads((out / "results.json").read_text())
    assert res["evaluation"]["draws"] == 2 and res["scenario"]["car_draws_per_day"] == 2
    assert "PRNGKey(1)" in res["evaluation"]["key"]
    table = res["evaluation"]["table"]
    _, eval_params, _, days = build_env_params(res["config"])
    by_key = [
        evaluate_rules(eval_params, days, ("always_max",), key=jax.random.PRNGKey(k))["always_max"][
            "daily_profit"
        ]
        for k in (0, 1)
    ]
    assert not np.allclose(by_key[0], by_key[1])  # the draws differ ...
    np.testing.assert_allclose(
        table["always_max"]["daily_profit"], np.mean(by_key, axis=0), rtol=1e-6, atol=1e-4
    )
    assert np.all(
        np.asarray(table["lp_bound"]["daily_profit"])
        >= np.asarray(table["always_max"]["daily_profit"]) - 1e-3
    )
    assert "2 car draws" in table["lp_bound"]["source"]
    # ... and the agent's stored score is the mean over the same two draws (redraw's replay check)
    again = redraw.redraw(out, draws=2, bound=False)
    assert again["replay_check_max_abs_eur"] < 1e-3
    with pytest.raises(ValueError, match="draws >= 2"):
        redraw.redraw(out, draws=1, bound=False)
    with pytest.raises(LookupError, match="car draws"):
        pipeline.add_stored_mpc(out, tmp_path)
    with pytest.raises(ValueError, match="either a key or draws"):
        heldout.evaluate_batched(None, None, eval_params, days, key=jax.random.PRNGKey(0), draws=2)
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="EVAL_DRAWS"):
            resolve({"EVAL_DRAWS": bad})
