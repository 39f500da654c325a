"""The experiment runners' bookkeeping: the cross-market runner's
(``baselines/experiments/cross_market.py``) on made-up numbers, and the service-effects
comparison on hand-computed numbers and on the session's tiny IPPO run.

The cross-market runner's training and evaluation are tested with the trainers; an end-to-end
run of it compiles several programs (minutes on 2 cores), so it is not part of the suite.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from baselines import runs
from baselines.config import build_env_params, resolve
from baselines.experiments import cross_market as cm
from baselines.experiments import service_effects

EXPERIMENTS = {"NL-2023": ("NL-2023", "DE-2023", "FR-2023")}


def _ev(daily):
    daily = np.asarray(daily, np.float64)
    return {
        "metrics": {"daily_profit_eur": {"mean": float(daily.mean()), "std": float(daily.std())}},
        "daily_profit": daily,
    }


def _fake():
    rng = np.random.default_rng(0)
    ref = {m: rng.normal(1000, 100, size=(2, 6)) for m in ("NL-2023", "DE-2023", "FR-2023")}
    matrix = {
        "NL-2023": {m: _ev(ref[m] - 10.0 * (m != "NL-2023")) for m in ref},
        "DE-2023": {"DE-2023": _ev(ref["DE-2023"])},
    }  # FR-2023 has no in-market agent (--no-reference)
    baselines = {
        m: {"always_max": _ev(ref[m][0]), "price_threshold": _ev(ref[m][1] - 300)} for m in ref
    }
    return matrix, baselines


def test_default_pairs_are_the_issue_s():
    assert cm.EXPERIMENTS == {
        "NL-2023": ("NL-2023", "DE-2023", "FR-2023"),
        "NL-2021": ("NL-2021", "NL-2022", "DE-2022", "FR-2022"),
    }


def test_transfer_gap_is_the_paired_difference_to_the_in_market_agent():
    matrix, _ = _fake()
    gaps = cm.transfer_gaps(matrix, EXPERIMENTS)
    assert set(gaps) == {"NL-2023"} and set(gaps["NL-2023"]) == {
        "DE-2023"
    }  # no self-gap, no missing reference
    g = gaps["NL-2023"]["DE-2023"]
    cross, ref = (
        matrix["NL-2023"]["DE-2023"]["daily_profit"],
        matrix["DE-2023"]["DE-2023"]["daily_profit"],
    )
    assert np.isclose(g["mean"], (cross - ref.mean(axis=0)).mean())
    assert len(g["per_seed_mean"]) == 2 and g["stderr"] > 0


def test_summary_and_plot(tmp_path):
    matrix, baselines = _fake()
    text = cm.summary(matrix, baselines, cm.transfer_gaps(matrix, EXPERIMENTS), EXPERIMENTS)
    assert "NL-2023 -> DE-2023" in text and "NL-2023 -> FR-2023" in text and "      -" in text
    path = tmp_path / "cm.png"
    cm.plot(matrix, baselines, EXPERIMENTS, "ppo", path)
    assert path.read_bytes()[:4] == b"\x89PNG"


def test_traffic_sweep_appendix_conditions_build_valid_params():
    """``traffic_sweep --appendix``: the four bundled profiles (EU fleet) and the US / World
    fleets (shopping), each a config whose env parameters build; the default is the main figure."""
    from baselines.experiments import traffic_sweep as ts

    assert ts.conditions() == [("shopping", "EU")]
    cells = ts.conditions(ts.PROFILES, ts.FLEETS)
    assert cells == [
        ("shopping", "EU"),
        ("residential", "EU"),
        ("workplace", "EU"),
        ("highway", "EU"),
        ("shopping", "US"),
        ("shopping", "World"),
    ]
    shares = {}
    for profile, fleet in cells:
        cfg = resolve(
            ts.condition_config({"ENV_KWARGS": {"num_levels": 1}}, profile, fleet, "high")
        )
        train_params, full, _, days = build_env_params(cfg)
        assert cfg["ENV_KWARGS"] == {"num_levels": 1, "fleet": fleet} and np.size(days) == 100
        shares[fleet] = np.asarray(full.fleet_capacity_kwh)
    assert not np.array_equal(shares["EU"], shares["US"])  # the fleet really changes


def _args(argv, full_seeds=20):
    from baselines.experiments import _common

    return _common.parser("doc", full_seeds=full_seeds).parse_args(argv)


def test_runner_defaults_are_the_tuned_settings_and_full_is_the_paper_s_budget():
    from baselines.config import settings
    from baselines.experiments import _common

    cpu = settings("cpu")
    base, seeds = _common.config_of(_args([]))
    assert seeds == 4 and base["TOTAL_TIMESTEPS"] == 2_000_000
    assert (
        base["GAMMA"] == 0.95
        and base["RELATIVE_PRICES"] is True
        and base["ENV_KWARGS"] == {"session_model": "paper", "num_levels": 1}
    )
    assert all(
        base[k] == v
        for k, v in cpu.items()
        if k not in ("BATTERY_SHAPING", "TOTAL_TIMESTEPS", "ALGO", "OUT")
    )
    assert base["BATTERY_SHAPING"] == "dp" and base["SPLIT_CREDIT"] is True
    multi, _ = _common.config_of(_args(["--algo", "ippo"]))
    assert multi["LOCAL_REWARD_WEIGHT"] == 1.0 and multi["BATTERY_NET"] and multi["GAMMA"] == 0.9
    full, full_seeds = _common.config_of(_args(["--full"]))
    assert full_seeds == 20 and full["TOTAL_TIMESTEPS"] == 10_000_000 and full["GAMMA"] == 0.95
    table3, _ = _common.config_of(_args(["--full", "--settings", "table3"]))
    assert table3 == {  # resolve() fills in Table 3
        "ENV_KWARGS": {"session_model": "paper"},
        "TOTAL_TIMESTEPS": 10_000_000,
    }
    # the tuned settings are not shared mutable state: a runner adding env kwargs leaves them alone
    again = _common.with_env_kwargs(base, fleet="US")
    assert again["ENV_KWARGS"] == {
        "session_model": "paper",
        "num_levels": 1,
        "fleet": "US",
    } and _common.TUNED["ppo"]["ENV_KWARGS"] == {"num_levels": 1}
    assert "TASK" not in _common.TUNED["ppo"]  # the runners choose their own scenarios


def test_the_makefile_s_training_targets_name_a_config_and_replace_their_run():
    """``make train`` / ``train-ppo`` / ``train-mappo`` run ``baselines.train --config NAME
    --overwrite`` with no other argument (a second ``make train`` replaces the first's run);
    the runners' tuned settings are those files' learning settings."""
    import re
    from pathlib import Path

    from baselines.config import load
    from baselines.experiments import _common

    text = Path(__file__).resolve().parents[2].joinpath("Makefile").read_text()
    for target, name, algo in (
        ("train", "ippo_v3", "ippo"),
        ("train-ppo", "ppo", "ppo"),
        ("train-mappo", "mappo", "mappo"),
    ):
        line = re.search(rf"^{target}:.*\n\t(.*)$", text, flags=re.M).group(1)
        assert line == f"$(PY) -m baselines.train --config {name} --overwrite", (target, line)
        config, run = load(name)
        assert run["ALGO"] == algo
        if name == algo:
            assert all(config[k] == v for k, v in _common.TUNED[name].items())
    # make train is on the default v3 task
    assert load("ippo_v3")[0]["TASK"] == "Chargax-shopping-v3"


def test_the_record_says_when_a_run_is_cut_from_the_paper_s_scale():
    from baselines.experiments import _common

    args = _args(["--seeds", "3", "--timesteps", "5e5"])
    base, seeds = _common.config_of(args)
    rec = _common.Record(args, seeds, base, paper_seeds=20, figure="Fig. 4a").as_dict()
    assert (
        rec["cut"] is True
        and "3 seeds x 5e+05" in rec["cut_note"]
        and "20 x 1e+07" in rec["cut_note"]
    )
    assert rec["paper"] == {"timesteps_per_seed": 10_000_000, "seeds": 20}
    assert (
        rec["machine"]["cores"] >= 1
        and rec["wall_seconds"] >= 0
        and rec["timesteps_per_seed"] == 500_000
    )
    full = _args(["--full"])
    base, seeds = _common.config_of(full)
    assert (
        _common.Record(full, seeds, base, paper_seeds=20, figure="Fig. 4a").as_dict()["cut"]
        is False
    )
    # fewer seeds than the paper's at the paper's steps is still cut
    assert _common.Record(full, 5, base, paper_seeds=20, figure="Fig. 4a").as_dict()["cut"] is True
    none = _common.Record(args, seeds, base, paper_seeds=None, figure="refund").as_dict()
    assert (
        none["cut"] is False
        and none["paper"] is None
        and none["cut_note"].startswith("no paper counterpart")
    )


def test_paired_differences_over_seeds():
    from baselines.eval.stats import paired_over_seeds

    d = paired_over_seeds([3.0, 5.0, 7.0], [1.0, 1.0, 1.0])
    assert (
        d["per_seed"] == [2.0, 4.0, 6.0]
        and np.isclose(d["mean"], 4.0)
        and np.isclose(d["stderr"], 2.0 / np.sqrt(3))
    )
    a = np.array([[1.0, 3.0], [2.0, 6.0]])  # seeds x days
    r = paired_over_seeds(a, np.zeros_like(a))
    assert (
        r["per_seed"] == [2.0, 4.0] and np.isclose(r["mean"], 3.0) and np.isclose(r["stderr"], 1.0)
    )


def _cell(agent, am, rule, bound, seeds=2, days=5):
    rng = np.random.default_rng(0)
    noise = rng.normal(0, 1, size=days)

    def entry(v, per_seed=False):
        daily = np.full((seeds, days), v) + noise if per_seed else v + noise
        e = {
            "metrics": {"daily_profit_eur": {"mean": float(np.mean(daily)), "std": 1.0}},
            "daily_profit": daily,
        }
        if per_seed:
            e["per_seed_profit"] = list(np.mean(daily, axis=1))
        return e

    return {
        "evaluation": {
            "table": {
                "ppo": entry(agent, True),
                "always_max": entry(am),
                "battery_rule": entry(rule),
                "lp_bound": entry(bound),
            }
        },
        "curve": {
            "timesteps": np.array([1, 2]),
            "episode_profit_eur": np.array([[1.0, 2.0], [1.5, 2.5]]),
        },
        "vs_always_max": {"mean": agent - am, "stderr": 0.1},
        "over_seeds": {"headroom_fraction": {"mean": (agent - am) / (bound - am), "stderr": 0.01}},
    }


def test_traffic_sweep_log_line_and_plots(tmp_path):
    from baselines.experiments import traffic_sweep as ts

    sweep = {t: _cell(10.0 + i, 9.0 + i, 9.5 + i, 12.0 + i) for i, t in enumerate(ts.TRAFFIC)}
    text = ts.line(sweep["low"], "ppo")
    assert "lp_bound 12.0" in text and "vs_always_max +1.00" in text and "headroom +0.333" in text
    ts.plot(sweep, "ppo", tmp_path / "main.png")
    ts.plot_grid({"shopping/EU": sweep, "highway/EU": sweep}, "ppo", tmp_path / "grid.png")
    assert (tmp_path / "main.png").read_bytes()[:4] == b"\x89PNG" and (
        tmp_path / "grid.png"
    ).stat().st_size > 0


def _stored_run(tmp_path, config, **overrides):
    """A ``results.json`` as ``baselines.train`` writes it, for ``config`` (4 chunks, 2 seeds)."""
    from baselines.pipeline import chunked_updates

    parsed = resolve(config)
    _, n_upd = chunked_updates(parsed, 4)
    res = {
        "algo": "ppo",
        "seeds": 2,
        "seed": 0,
        "timesteps": n_upd * parsed["NUM_ENVS"] * parsed["NUM_STEPS"],
        "config": {**parsed, "TOTAL_TIMESTEPS": n_upd * parsed["NUM_ENVS"] * parsed["NUM_STEPS"]},
        "wall_seconds": 12.5,
        **overrides,
    }
    path = tmp_path / "results.json"
    path.write_text(json.dumps(res))
    return str(path)


def test_a_reused_cell_must_be_the_run_the_runner_would_make(tmp_path):
    """``traffic_sweep --reuse``: a stored run is taken only when its algorithm, seeds, budget,
    settings and parameters are the cell's; the station may be spelled with or without its
    default fleet. Anything else is an error naming the difference."""
    import pytest

    from baselines.experiments import traffic_sweep as ts
    from baselines.experiments._common import reused_run

    base, _ = _common_config(["--timesteps", "1e5"])
    cell = ts.condition_config(
        base, "shopping", "EU", "medium"
    )  # ENV_KWARGS with fleet "EU" (the default)
    stored = {**cell, "ENV_KWARGS": {"num_levels": 1}}
    got = reused_run(_stored_run(tmp_path, stored), "ppo", cell, 2, 4)
    assert got["wall_seconds"] == 12.5 and got["reused_from"]["options_added_since"] == []
    # a run stored before an option existed is that option at its default, and says so
    older = _stored_run(tmp_path, stored)
    res = json.loads(open(older).read())
    del res["config"]["PORT_SHAPING"]
    open(older, "w").write(json.dumps(res))
    assert reused_run(older, "ppo", cell, 2, 4)["reused_from"]["options_added_since"] == [
        "PORT_SHAPING"
    ]
    with pytest.raises(ValueError, match=re.escape("config PORT_SHAPING=None (this run: 'plan')")):
        reused_run(older, "ppo", {**cell, "PORT_SHAPING": "plan"}, 2, 4)
    for kwargs, (algo, seeds, config), needle in [
        ({}, ("ppo", 4, cell), "seeds=2 (this run: 4)"),
        ({}, ("ippo", 2, cell), "algo='ppo'"),
        ({}, ("ppo", 2, {**cell, "LR": 1e-4}), "config LR="),
        (
            {},
            ("ppo", 2, ts.condition_config(base, "shopping", "EU", "high")),
            "config TRAFFIC='medium'",
        ),
        (
            {},
            ("ppo", 2, ts.condition_config(base, "shopping", "US", "medium")),
            "builds another station",
        ),
        ({"timesteps": 3600}, ("ppo", 2, cell), "timesteps=3600"),
    ]:
        with pytest.raises(ValueError, match=re.escape(needle)):
            reused_run(_stored_run(tmp_path, stored, **kwargs), algo, config, seeds, 4)


def test_the_sweep_reads_reused_cells_and_refuses_cells_it_does_not_train(tmp_path):
    import argparse

    import pytest

    from baselines.experiments import traffic_sweep as ts

    cells = ts.conditions(ts.PROFILES, ts.FLEETS)
    got = ts.parse_reuse(
        argparse.ArgumentParser(),
        ["medium=a.json", "highway/EU/high=b.json", "shopping/US/low=c"],
        cells,
        list(ts.TRAFFIC),
    )
    assert got == {
        "shopping/EU/medium": "a.json",
        "highway/EU/high": "b.json",
        "shopping/US/low": "c",
    }
    for argv in (
        ["--reuse", "medium"],
        ["--reuse", "peak=x.json"],
        ["--traffic", "low", "--reuse", "high=x.json"],
        ["--reuse", "highway/EU/high=x.json"],  # not in the main figure's sweep without --appendix
        ["--appendix", "--reuse", "highway/US/high=x.json"],
        ["--reuse", "medium="],
    ):
        with pytest.raises(SystemExit):
            ts.main(argv + ["--out", str(tmp_path / "never" / "sweep")])
    assert not (tmp_path / "never").exists()  # refused before anything is written


def _common_config(argv):
    from baselines.experiments import _common

    return _common.config_of(_args(argv))


def test_the_report_counts_a_reused_cell_s_wall_time():
    from baselines.experiments.report import provenance

    machine = {"cpu": "Xeon", "cores": 2, "backend": "cpu"}
    plain = {
        "cut_note": "the paper's scale",
        "settings": "tuned",
        "wall_seconds": 600.0,
        "machine": machine,
    }
    assert provenance(plain) == "the paper's scale; settings `tuned`; 10 min wall on Xeon ×2 (cpu)"
    reused = {
        **plain,
        "wall_seconds_with_reused": 3000.0,
        "reused": {"medium": {"path": "runs/medium/results.json", "wall_seconds": 2400.0}},
    }
    assert provenance(reused) == (
        "the paper's scale; settings `tuned`; 50 min wall (with the reused medium cell "
        "(runs/medium/results.json)) on Xeon ×2 (cpu)"
    )


def test_code_version_names_the_checkout_s_commit(tmp_path):
    from chargax_marl.machine import code_version

    here = code_version()
    if here["commit"] is not None:  # an installed copy outside git has none
        assert re.fullmatch(r"[0-9a-f]{40}", here["commit"]) and isinstance(here["dirty"], bool)
    assert code_version(tmp_path) == {"commit": None, "dirty": None}


def test_result_files_keep_float32_values_exactly_and_number_lists_on_one_line(tmp_path):
    """``runs.write_json``: a float32 metric is written as its shortest decimal and reads back
    to the same float32; float64 statistics are kept as they are; number lists take one line."""

    metric = np.float32([340.23096, -0.0112, 1e-7])
    obj = {
        "curve": {"profit": metric, "seeds": [[1.5, 2.5], [3.5, 4.5]]},
        "mean": 10.358861465454103,
        "missing": float("nan"),
        "empty": {},
        "names": ["a", "b"],
    }
    path = runs.write_json(obj, tmp_path / "r.json")
    back = json.loads(path.read_text())
    np.testing.assert_array_equal(np.float32(back["curve"]["profit"]), metric)
    assert back["mean"] == 10.358861465454103 and back["missing"] is None and back["empty"] == {}
    assert back["curve"]["seeds"] == [[1.5, 2.5], [3.5, 4.5]]
    lines = path.read_text().splitlines()
    assert (
        '    "profit": [340.23096, -0.0112, 1e-07],' in lines and '  "names": ["a", "b"]' in lines
    )


def test_runner_files_keep_only_the_profit_curve():
    from baselines.experiments._common import profit_curve

    curve = {
        "timesteps": [1, 2],
        "episode_profit_eur": [[1.0, 2.0]],
        "entropy": [[0.5, 0.4]],
        "value_loss": [[1.0, 0.9]],
    }
    assert profit_curve(curve) == {"timesteps": [1, 2], "episode_profit_eur": [[1.0, 2.0]]}


def test_the_report_shows_the_teachers_rules_where_a_run_holds_them():
    """A cell's row gives the per-seed differences to both teachers' rules (mean ± s.e., seeds
    above) and a file made before they were baselines shows "–"; the rules' own line follows."""
    from baselines.experiments import report

    def seed(am, rule, prog=None, plan=None):
        s = {"vs_always_max": {"mean": am}, "vs_battery_rule": {"mean": rule}}
        if prog is not None:
            s.update(vs_battery_programme={"mean": prog}, vs_plan_programme={"mean": plan})
        return s

    cell = _cell(10.0, 9.0, 9.5, 12.0)
    cell["wall_seconds"] = 60.0
    cell["per_seed"] = [seed(1.0, 0.5, 0.2, -1.0), seed(1.2, 0.7, -0.2, -2.0)]
    row = report._cell_row("low", cell, "ppo")
    assert "| +0.00 ± 0.20 (1/2) | -1.50 ± 0.50 (0/2) |" in row and row.count("|") == 12
    old = {**cell, "per_seed": [seed(1.0, 0.5), seed(1.2, 0.7)]}
    assert "| +0.60 ± 0.10 (2/2) | – | – |" in report._cell_row("low", old, "ppo")
    assert report.CELL_HEADER.count("|") == 2 * 12 and "plan programme" in report.CELL_HEADER
    assert report.teacher_rules([("low", old)]) == ""
    for name, d in (("battery_programme", 1.0), ("plan_programme", 3.0)):
        cell["evaluation"]["table"][name] = {
            "vs_always_max": {"mean": d, "stderr": 0.5},
            "headroom": {"fraction": d / 3.0},
        }
    text = report.teacher_rules([("low", cell)])
    assert "| low | +1.00 ± 0.50 (0.333) | +3.00 ± 0.50 (1.000) |" in text


def test_service_effects_paired_differences_by_hand():
    a = np.array([[3.0, 5.0], [1.0, 3.0]])  # 2 seeds x 2 days
    p = service_effects.paired(a, np.array([1.0, 2.0]))  # against one reference per day
    assert p["per_seed"] == [2.5, 0.5] and p["mean"] == 1.5
    assert p["stderr_seeds"] == pytest.approx(1.0)  # std(2.5, 0.5) = sqrt(2), over sqrt(2)
    d = np.array([2.0, 3.0, 0.0, 1.0])
    assert p["stderr_seed_days"] == pytest.approx(d.std(ddof=1) / 2.0)
    one = service_effects.paired(a[:1], a[1:])  # one seed: no spread over seeds
    assert one["mean"] == 2.0 and np.isnan(one["stderr_seeds"])


def test_service_effects_compare_a_run_with_itself_and_with_always_max(tiny_ippo_run, tmp_path):
    out = tmp_path / "effects.json"
    run = str(tiny_ippo_run)
    record = service_effects.main(["--compare", "self", run, run, "--out", str(out)])
    (c,) = record["comparisons"]
    assert c["seeds"] == 2 and c["draws"] == 1
    for m in service_effects.METRICS:
        assert c[m]["vs_reference"]["mean"] == 0.0 and c[m]["run"] == c[m]["reference"]
        gap = c[m]["vs_always_max"]["mean"]
        assert gap == pytest.approx(c[m]["run"] - c[m]["always_max"], abs=1e-9)
    assert 0.0 < c["jain_index"]["always_max"] <= 1.0
    # each seed's profit and its gap to always-max are those the trainer's evaluation reported
    results = json.loads((tiny_ippo_run / "results.json").read_text())
    vs_am = c["daily_profit_eur"]["vs_always_max"]["per_seed"]
    for seed, reported in enumerate(results["per_seed"]):
        assert vs_am[seed] == pytest.approx(reported["vs_always_max"]["mean"], rel=1e-5, abs=1e-3)
    # a second comparison is added to the file; the table has a row per comparison and metric
    service_effects.main(["--compare", "again", run, run, "--out", str(out)])
    saved = json.loads(out.read_text())
    assert [x["name"] for x in saved["comparisons"]] == ["self", "again"]
    rows = service_effects.table(saved).splitlines()
    assert len(rows) == 2 + 2 * len(service_effects.METRICS)


def test_the_measured_effects_in_the_docs_are_those_of_the_result_file():
    root = Path(__file__).resolve().parents[2]
    record = json.loads((root / "results" / "service_effects.json").read_text())
    assert service_effects.table(record) in (root / "docs" / "training.md").read_text()
    names = [c["name"] for c in record["comparisons"]]
    for scenario in ("default", "grid25-high"):
        for option in ("fairness weight", "delay k=1", "delay k=3", "action loss p=0.1"):
            assert sum(n.startswith(f"{scenario}: {option}") for n in names) == 1
    for c in record["comparisons"]:  # each paired on two seeds, the grid on four car draws
        assert c["seeds"] == 2 and c["draws"] == (4 if c["name"].startswith("grid") else 1)


def test_the_price_shift_back_fill_rebuilds_the_paper_session_model(monkeypatch):
    """`add_teacher_rules.add_to_price_shift` replays each eval year on the params the
    price-shift runner played: the tuned settings, that year's prices and the paper's session
    model (on the default v2 model always-max would not replay)."""
    from baselines.experiments import add_teacher_rules

    built = []

    def capture(config):
        built.append(config)
        raise RuntimeError("captured")

    monkeypatch.setattr(add_teacher_rules, "build_env_params", capture)
    result = {"settings": "tuned", "algo": "ppo", "matrix": {}, "baselines": {"NL-2023": {}}}
    with pytest.raises(RuntimeError, match="captured"):
        add_teacher_rules.add_to_price_shift(result, "price_shift.json")
    (config,) = built
    assert config["ENV_KWARGS"]["session_model"] == "paper"
    assert config["ENV_KWARGS"]["prices"] == "NL-2023"
