"""``baselines.analysis``: tools that read finished runs (attribution, sensitivity)."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from baselines.analysis import (
    ablation,
    attribution,
    mpc_gap,
    plan_rule,
    read_policy,
    redraw,
    robustness,
    sensitivity,
    shaving,
)
from baselines.config import build_env_params
from baselines.eval import references
from baselines.eval.rules import evaluate_rules
from chargax_marl import policies
from chargax_marl.benchmark.references import load_references
from chargax_marl.benchmark.tasks import get_task
from chargax_marl.core import make_params, simulator
from chargax_marl.teachers import storage_value
from tests.helpers import TINY_ENV, no_arrivals

ROOT = Path(__file__).resolve().parents[2]


def test_attribution_scores_the_run_and_swaps_ports_and_battery(tiny_ippo_run):
    """``baselines.analysis.attribution``: the ``learned`` row reproduces the run's own held-out score,
    and the mixes take the battery's levels from one policy and the ports' from the other."""
    out = tiny_ippo_run
    res = json.loads((out / "results.json").read_text())
    att = attribution.attribute(out)
    learned = [s["mean"] for s in att["mixes"]["learned"]["per_seed"]]
    np.testing.assert_allclose(
        learned, [p["vs_always_max"]["mean"] for p in res["per_seed"]], rtol=1e-6, atol=1e-6
    )
    assert set(att["mixes"]) == set(
        attribution.MIXES
    ) and "learned" in attribution.format_attribution(att)
    params = make_params(**TINY_ENV)
    key = jax.random.PRNGKey(0)
    start = simulator.reset(key, params)
    mixes = attribution.mixed_policies(lambda s, k: policies.always_max(s, k, params), params)
    rule_act = lambda s, k: policies.battery_rule(s, k, params)  # noqa: E731
    from_rule = attribution.mixed_policies(rule_act, params)["always_max_ports_learned_battery"]

    @jax.jit
    @jax.vmap
    def at_hour(h):  # every hour of the day in one compiled program, not op by op
        state = start.replace(timestep=h)
        return (
            policies.battery_rule(state, key, params),
            policies.always_max(state, key, params),
            mixes["learned_ports_rule_battery"](state, key),
            mixes["always_max_ports_learned_battery"](state, key),
            from_rule(state, key),
        )

    rule, am, rule_battery, learned_battery, ports_from_rule = jax.device_get(
        at_hour(jnp.arange(24, dtype=jnp.int32))
    )
    # an hour (60-minute steps) in which the battery rule charges or discharges, so the mixes differ
    h = next(h for h in range(24) if int(rule[h, -1]) != 0)
    np.testing.assert_array_equal(rule_battery[h], rule[h])
    np.testing.assert_array_equal(learned_battery[h], am[h])
    np.testing.assert_array_equal(ports_from_rule[h], rule[h])


def test_read_policy_gives_the_battery_s_action_shares_and_its_hourly_action(tiny_ippo_run):
    """``baselines.analysis.read_policy`` reads a run: shares of the battery's actions, 24 hours."""
    reading = read_policy.read(tiny_ippo_run, num_days=3)
    assert reading["num_days"] == 3 and len(reading["per_seed"]) == 2
    for seed in reading["per_seed"]:
        assert (
            abs(sum(seed["battery_share"].values()) - 1.0) < 1e-6
            and len(seed["hourly_action"]) == 24
        )
        assert (
            all(-1.0 <= a <= 1.0 for a in seed["hourly_action"])
            and 0.0 <= seed["ports_full_power_share"] <= 1.0
        )
        assert 0.0 <= seed["ports_follow_plan_share"] <= 1.0
    assert "hourly SoC" in read_policy.format_reading(reading)
    # a day on which the programme never strictly prefers an action reads as such
    never = {**reading, "per_seed": [{**reading["per_seed"][0], "agrees_with_dp": None}]}
    assert "strict best action - (it never has one)" in read_policy.format_reading(never)


def test_redraw_scores_the_run_on_more_cars_and_refuses_a_run_it_does_not_reproduce(
    ippo_run, monkeypatch
):
    """``baselines.analysis.redraw`` scores a run on more cars: draw 0 is the run's own
    evaluation, draw 1 the rules' evaluation under ``PRNGKey(1)``, averaged per day."""
    out = ippo_run
    res = json.loads((out / "results.json").read_text())
    two = redraw.redraw(out, draws=2, bound=False)
    assert two["draws"] == 2 and two["seeds"] == 2 and two["replay_check_max_abs_eur"] < 1e-3
    for i, p in enumerate(res["per_seed"]):
        assert two["vs"]["always_max"]["draw0_per_seed"][i]["mean"] == pytest.approx(
            p["vs_always_max"]["mean"], abs=1e-4
        )
        assert two["vs"]["always_max"]["draw0_per_seed"][i]["stderr"] == pytest.approx(
            p["vs_always_max"]["stderr"], rel=1e-4
        )
    _, eval_params, _, days = build_env_params(
        json.loads((out / "results.json").read_text())["config"]
    )
    by_key = [
        evaluate_rules(eval_params, days, ("always_max", "battery_rule"), key=jax.random.PRNGKey(k))
        for k in (0, 1)
    ]
    rule_gain = np.mean(
        [r["battery_rule"]["daily_profit"] - r["always_max"]["daily_profit"] for r in by_key]
    )
    assert two["references_vs_always_max"]["battery_rule"]["mean"] == pytest.approx(
        rule_gain, abs=1e-4
    )
    assert not np.allclose(
        by_key[0]["always_max"]["daily_profit"], by_key[1]["always_max"]["daily_profit"]
    )
    assert "2 car draws" in redraw.format_redraw(two)

    # the MPC's draws (a stand-in that earns always-max + 1 EUR/day here, so the wiring shows):
    # paired on the first mpc_draws draws only, with the bound's headroom on the same draws
    def fake_mpc(params, days, key):
        return {
            "daily_profit": evaluate_rules(params, days, ("always_max",), key=key)["always_max"][
                "daily_profit"
            ]
            + 1.0
        }

    monkeypatch.setattr(references, "evaluate_mpc", fake_mpc)
    with_mpc = redraw.redraw(out, draws=2, bound=True, mpc_draws=1)
    vs_am, vs_mpc = (
        with_mpc["vs"]["always_max"]["draw0_per_seed"],
        with_mpc["vs"]["mpc"]["per_seed"],
    )
    for i in range(2):
        assert vs_mpc[i]["mean"] == pytest.approx(vs_am[i]["mean"] - 1.0, abs=1e-4)
    assert with_mpc["references_vs_always_max"]["mpc"]["mean"] == pytest.approx(1.0, abs=1e-4)
    frac = with_mpc["headroom_fraction"]
    assert (
        frac["references"]["lp_bound"] == pytest.approx(1.0)
        and frac["references"]["always_max"] == 0.0
    )
    assert frac["mpc_on_its_draws"]["mpc"] == pytest.approx(
        1.0 / with_mpc["headroom_eur_per_draw"][0], rel=1e-5
    )
    assert with_mpc["headroom_eur"] == pytest.approx(np.mean(with_mpc["headroom_eur_per_draw"]))
    with pytest.raises(ValueError, match="mpc_draws must be an integer in"):
        redraw.redraw(out, draws=1, mpc_draws=2)
    # a run whose stored score this code does not reproduce is refused, as are zero draws
    res["per_seed"][0]["mean_profit_eur"] += 1.0
    (out / "results.json").write_text(json.dumps(res))
    with pytest.raises(ValueError, match="another model"):
        redraw.redraw(out, draws=1)
    with pytest.raises(ValueError, match="draws must be a positive integer"):
        redraw.redraw(out, draws=0)


def test_sensitivity_battery_step_on_an_empty_station_is_the_hand_computed_trade():
    """With no cars, charging the battery for one step changes each day by exactly what the
    step costs at that step's price, plus what the stored energy is worth at the day's end,
    minus the wear of the kWh into the cells; a port idling changes nothing, and neither does a
    step outside the day."""
    params = no_arrivals(make_params(**{**TINY_ENV, "step_minutes": 15.0}))
    days, step = np.array([3, 40, 200]), 30
    out = sensitivity.sensitivity(params, days, step=step)
    eta, power_kw, capacity_kwh, e0 = storage_value.battery_constants(params)
    assert (
        e0 + power_kw * float(params.step_hours) < 0.8 * capacity_kwh
    )  # below the taper: the full charge
    stored = power_kw * float(params.step_hours)
    prices = storage_value.step_buy_prices(params)[days, step]
    wear = storage_value.battery_wear_eur_kwh(params) * stored
    expected = -prices * stored / eta + storage_value.terminal_prices(params)[days] * stored - wear
    np.testing.assert_allclose(
        out["battery_charges"]["daily_difference_eur"], expected, rtol=1e-4, atol=1e-4
    )
    assert np.all(np.asarray(out["port_idles"]["daily_difference_eur"]) == 0.0)
    assert out["battery_charges"]["days_served_cars_differ"] == 0
    outside = sensitivity.sensitivity(params, days, step=-5)
    assert all(
        np.all(np.asarray(outside[p]["daily_difference_eur"]) == 0.0)
        for p in sensitivity.PERTURBATIONS
    )
    with pytest.raises(ValueError, match="perturbation"):
        sensitivity.perturbed_always_max(params, "battery_discharges", 0)


def test_the_ablation_table_pairs_methods_with_the_base_and_the_rules(tmp_path):
    """Score files made of two shipped references (EDF as a one-seed method, always-max as
    the base): the method's difference with the base is EDF's with always-max, paired over
    days, and its differences with the rules are the scoreboard's."""
    task_id = "Chargax-shopping-grid10-high-v1"
    refs = load_references(get_task(task_id))["policies"]

    def score_file(name, policy):
        profit = np.asarray(refs[policy]["daily_profit"])[None]  # (1 seed, days, draws)
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps({"task": task_id, "daily_profit": profit.tolist()}))
        return f"{name}={path}"

    out = tmp_path / "table"
    result = ablation.main(
        [
            "--task",
            task_id,
            "--base",
            score_file("base", "always_max"),
            "--method",
            score_file("edf", "edf"),
            "--out",
            str(out),
            "--rules",
            "edf,coupled_plan",
        ]
    )
    base, edf = result["rows"]
    assert base["vs_base"] is None and base["score"] == pytest.approx(0.0, abs=1e-9)
    diff = (
        np.asarray(refs["edf"]["daily_profit"]) - np.asarray(refs["always_max"]["daily_profit"])
    ).mean(1)
    assert edf["vs_base"]["mean"] == pytest.approx(diff.mean(), rel=1e-9)
    assert edf["vs_base"]["stderr"] == pytest.approx(
        diff.std(ddof=1) / np.sqrt(diff.size), rel=1e-9
    )
    assert edf["vs_rules"]["edf"]["mean"] == pytest.approx(0.0, abs=1e-9)
    assert edf["vs_rules"]["always_max"]["mean"] == pytest.approx(diff.mean(), rel=1e-9)
    best = max(result["rules"], key=lambda r: np.nanmean(refs[r]["daily_profit"]))
    assert result["strongest_rule"] == best and "lp_bound" not in result["rules"]
    assert edf["vs_strongest_rule"] == edf["vs_rules"][best]
    table = out.with_suffix(".md").read_text()
    assert "| method | seeds | score | vs base | vs `edf` | vs `coupled_plan` |" in table
    assert "| edf | 1 |" in table and "+0.0 ± 0.0 |" in table
    assert json.loads(out.with_suffix(".json").read_text())["rows"][1]["name"] == "edf"
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"task": "Chargax-shopping-v1", "daily_profit": [[[0.0]]]}))
    with pytest.raises(ValueError, match="field 'task' is 'Chargax-shopping-v1'"):
        ablation.ablation(task_id, ("base", str(other)), [])


@pytest.mark.parametrize("table", ["grid10", "shopping", "grid25", "peak", "shopping_v3"])
def test_the_committed_ablation_tables_are_what_their_score_files_give(table):
    stored = json.loads((ROOT / "results" / "ablation" / f"{table}.json").read_text())
    base, *methods = [(row["name"], str(ROOT / row["file"])) for row in stored["rows"]]
    again = ablation.ablation(stored["task"], base, methods)
    assert [row["score"] for row in again["rows"]] == [row["score"] for row in stored["rows"]]
    assert again["rows"][1:] and all(
        a["vs_base"] == s["vs_base"] for a, s in zip(again["rows"], stored["rows"])
    )
    text = (ROOT / "results" / "ablation" / f"{table}.md").read_text()
    shown = ("coupled_plan",) if table == "shopping_v3" else ("edf",)  # make_tables.sh's --rules
    assert text == ablation.to_markdown(again, shown)


def test_redraw_reads_a_stored_mpc_only_when_it_covers_every_day(monkeypatch):
    """Draw 0's MPC comes from ``make optimal``'s stored result only when it ran on all the
    held-out days (``--mpc-days N`` stores the first N); otherwise it is computed."""
    params = make_params(**TINY_ENV)
    days = np.arange(3)
    monkeypatch.setattr(
        redraw,
        "evaluate_rules",
        lambda p, d, names, key: {n: {"daily_profit": np.zeros(d.size)} for n in names},
    )
    monkeypatch.setattr(
        references, "evaluate_mpc", lambda p, d, key: {"daily_profit": np.full(d.size, 7.0)}
    )
    for stored_days, want in ((1, 7.0), (3, 5.0)):
        stored = {"policies": {"mpc": {"daily_profit": [5.0] * stored_days}}}
        monkeypatch.setattr(references, "cached", lambda p, d, directory, s=stored: s)
        monkeypatch.setattr(redraw, "_REFERENCES", {})  # the process cache, restored after
        out = redraw.reference_profits(params, days, 1, False, mpc_draws=1, references_dir="x")
        np.testing.assert_array_equal(out["mpc"], np.full((1, 3), want))


def test_a_failed_bound_solve_leaves_its_draw_and_day_out_of_the_headroom():
    """A NaN bound (a failed LP) leaves that draw and day out of the headroom and of every
    fraction, instead of turning them all NaN."""
    am = np.array([[10.0, 10.0], [10.0, 10.0]])
    refs = {
        "always_max": am,
        "battery_rule": am + 1.0,
        "lp_bound": np.array([[14.0, np.nan], [12.0, 12.0]]),
        "mpc": np.array([[13.0, 13.0]]),
    }
    learned = np.array([[[12.0, 99.0], [11.0, 11.0]]])  # one seed; 99 on the failed day
    out = redraw.headroom_fractions(learned, refs, mpc_draws=1)
    assert out["bound_failed_days"] == 1
    assert out["headroom_eur"] == pytest.approx((4 + 2 + 2) / 3)
    assert out["headroom_eur_per_draw"] == pytest.approx([4.0, 2.0])
    assert out["headroom_fraction"]["per_seed"] == pytest.approx([(2 + 1 + 1) / 8])
    assert out["headroom_fraction"]["references"]["battery_rule"] == pytest.approx(3 / 8)
    assert out["headroom_fraction"]["references"]["lp_bound"] == pytest.approx(1.0)
    assert out["headroom_fraction"]["mpc_on_its_draws"]["mpc"] == pytest.approx(3 / 4)


def test_plan_rule_headroom_leaves_out_the_days_whose_bound_failed():
    """A failed solve (stored as None) leaves its day out of the headroom; a plain mean made
    the headroom and every fraction NaN."""
    solved, headroom = plan_rule.bound_headroom([10.0, None, 7.0], [4.0, 100.0, 5.0])
    assert solved.tolist() == [True, False, True]
    assert headroom == pytest.approx(((10 - 4) + (7 - 5)) / 2)
    with pytest.raises(ValueError, match="no day has a solved bound"):
        plan_rule.bound_headroom([None, None], [1.0, 2.0])
    with pytest.raises(ValueError, match=r"bound_profit: shape \(3,\)"):
        plan_rule.bound_headroom([1.0, 2.0, 3.0], [1.0, 2.0])


def test_plan_rule_refuses_references_of_other_parameters(tmp_path):
    """The bound is read from the stored file of the same parameters (the scenario's session
    model, one level per port); it read ``<scenario>.json`` whatever its parameters, and
    dropped the scenario's session model, so its headroom came out negative."""
    with pytest.raises(ValueError, match="no file holds the LP bound of scenario 'peak'"):
        plan_rule.main(["--scenario", "peak", "--references", str(tmp_path)])


def test_the_mpc_gap_table_is_over_always_max_and_the_command_refuses_bad_margins():
    result = {
        "policies": {
            "lp_bound": {"energy_kwh": [110.0, 130.0], "profit_eur": [12.0, 14.0]},
            "always_max": {"energy_kwh": [100.0, 100.0], "profit_eur": [10.0, 10.0]},
            "mpc_margin1": {"energy_kwh": [105.0, 105.0], "profit_eur": [11.0, 11.5]},
        }
    }
    rows = mpc_gap.table(result).splitlines()
    assert rows[2] == "| lp_bound | +20.0 | +3.00 |"
    assert rows[3] == "| always_max | +0.0 | +0.00 |"
    assert rows[4] == "| mpc_margin1 | +5.0 | +1.25 |"
    with pytest.raises(SystemExit):
        mpc_gap.main(["--margins", "1,x"])
    with pytest.raises(SystemExit):
        mpc_gap.main(["--days", "0"])


def test_robustness_verdicts_table_and_refusals(tmp_path):
    """The verdict is two standard errors either way; the table names the setting, the rule
    and the verdict; an empty settings folder and a score file of another task are refused."""
    assert robustness.verdict({"mean": 2.1, "stderr": 1.0}) == "above"
    assert robustness.verdict({"mean": 1.9, "stderr": 1.0}) == "within"
    assert robustness.verdict({"mean": -1.9, "stderr": 1.0}) == "within"
    assert robustness.verdict({"mean": -2.1, "stderr": 1.0}) == "below"
    row = {
        "setting": "grid15",
        "description": "the grid at 15 %",
        "name": "IPPO",
        "seeds": 4,
        "score": 0.5,
        "score_stderr": 0.05,
        "vs_always_max": {"mean": 30.0, "stderr": 2.0},
        "strongest": "coupled_plan",
        "vs_strongest": {"mean": -1.0, "stderr": 0.8},
        "verdict": "within",
        "days": 50,
        "draws": 2,
    }
    text = robustness.table([row])
    assert (
        "| the grid at 15 % | IPPO (4 seeds) | 0.50 ± 0.05 | +30.0 ± 2.0 | coupled plan |" in text
    )
    assert "| -1.0 ± 0.8 | within | 50 × 2 |" in text
    with pytest.raises(FileNotFoundError, match="no task files"):
        robustness.settings(tmp_path)
    (tmp_path / "s.toml").write_text('name = "s"\nversion = 1\nscenario = "shopping"\ndraws = 1\n')
    scores = tmp_path / "scores"
    scores.mkdir()
    (scores / "x.json").write_text(
        json.dumps({"name": "IPPO", "task": "Chargax-other-v1", "daily_profit": [[1.0]]})
    )
    with pytest.raises(ValueError, match="is none of the settings"):
        robustness.rows(tmp_path, scores)
    for argv in (
        ["--settings", str(scores), "--scores", str(scores)],
        ["--settings", str(tmp_path), "--scores", str(tmp_path / "none")],
    ):
        with pytest.raises(SystemExit):
            robustness.main(argv)


def test_the_shaving_control_is_the_coupled_plan_until_the_ports_draw_passes_its_threshold(
    small_params,
):
    """``baselines.analysis.shaving``: above the ports' draw the rule is the coupled plan on
    every leaf; at a threshold of 0, with cars asking for power, the batteries discharge at
    full power and the ports keep the plan's levels; a negative threshold is refused."""
    from chargax_marl.core.station import KIND_BATTERY
    from chargax_marl.teachers.rules import coupled_plan_rule

    params = small_params
    key = jax.random.PRNGKey(0)
    state = simulator.reset(key, params)
    advance = jax.jit(
        lambda s, k: simulator.step(k, s, policies.always_max(s, k, params), params)[0]
    )
    for k in jax.random.split(key, 110):  # into the morning, cars parked
        state = advance(state, k)
    plan = np.asarray(coupled_plan_rule(params)(state, key, params))
    is_battery = np.asarray(params.station.leaf_kind) == KIND_BATTERY
    assert (plan[~is_battery] > 0).any() and (plan[is_battery] > -params.num_levels).all()
    never = np.asarray(shaving.shaving_rule(params, 1e6)(state, key, params))
    always = np.asarray(shaving.shaving_rule(params, 0.0)(state, key, params))
    np.testing.assert_array_equal(never, plan)
    np.testing.assert_array_equal(always[~is_battery], plan[~is_battery])
    assert (always[is_battery] == -params.num_levels).all()
    with pytest.raises(ValueError, match="threshold_frac"):
        shaving.shaving_rule(params, -0.1)
