"""The benchmark: tasks, shipped references, scores and the five kinds of policy."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl import policies
from chargax_marl.benchmark import (
    TASKS,
    ReferenceMismatchError,
    Task,
    add_mpc,
    bound_violations,
    compare,
    compute_mpc,
    compute_references,
    day_picture,
    get_normalized_score,
    load_references,
    protocol,
    refill_bound,
    save_references,
    score,
)
from chargax_marl.benchmark import references as references_module
from chargax_marl.benchmark.references import BOUND, MPC_REFERENCES, ZERO, reference_path
from chargax_marl.benchmark.references import __main__ as references_cli
from chargax_marl.core import Battery, Port, Splitter, make_params
from chargax_marl.core.observation import context_index, context_size, obs_size
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.marl import ChargaxMARL
from chargax_marl.optimal import SolverError
from chargax_marl.optimal import mpc as mpc_module
from chargax_marl.single import Chargax
from tests.helpers import count_compiles, no_arrivals, three_level_station

SCORES_DIR = Path(__file__).resolve().parents[2] / "results" / "scores"

# --- the shipped references ------------------------------------------------------------


DEEP = (
    "Chargax-shopping-v1",
    "Chargax-shopping-grid10-high-v1",
    "Chargax-shift-nl2024-v1",
    "Chargax-shopping-v2",
)
"""Tasks whose battery rule and LP bound are recomputed too (each costs a compile and a solve)."""


def _distinct_tasks():
    """One task per distinct scored env (``shift-nl2023`` is scored on the default's)."""
    seen, out = set(), []
    for task_id, task in sorted(TASKS.items()):
        key = (task.scenario, task.prices, task.draws, task.session_model)
        if key not in seen:
            seen.add(key)
            out.append(task_id)
    return out


@pytest.mark.parametrize("task_id", _distinct_tasks())
def test_shipped_references_recompute_on_this_code(task_id):
    """The first and last held-out days of every task: always-max to float32 rounding; on the
    `DEEP` tasks also the battery rule, and the first day's LP bound (draw 2, never
    taken from make optimal's results) to solver tolerance."""
    task = TASKS[task_id]
    stored = load_references(task)
    rows = [0, task.num_eval_days - 1]
    rules = (ZERO, "battery_rule") if task_id in DEEP else (ZERO,)
    fresh = compute_references(task, rules=rules, bound=False, day_index=rows, log=None)
    for name in rules:
        got = np.asarray(fresh["policies"][name]["daily_profit"])
        # float32 profits: a batch of other size (here 2 days, there 100), or another CPU's
        # vectorisation, may round a day's sum by an ulp or two where node limits bind; an ulp
        # of the day's gross flows (hundreds of EUR), where a small profit is their difference
        np.testing.assert_allclose(
            got, stored["policies"][name]["daily_profit"][rows], rtol=1e-6, atol=1e-4
        )
    if task_id in DEEP:
        lp = compute_references(
            dataclasses.replace(task, draws=2), rules=(), day_index=rows[:1], log=None
        )
        np.testing.assert_allclose(
            lp["policies"][BOUND]["daily_profit"][0][1],
            stored["policies"][BOUND]["daily_profit"][0, 1],
            rtol=1e-6,
        )


def test_every_task_has_its_references_and_the_bound_tops_every_rule():
    for task in TASKS.values():
        refs = load_references(task)
        bound = refs["policies"][BOUND]["daily_profit"].mean(axis=1)
        for name, entry in refs["policies"].items():
            per_day = entry["daily_profit"].mean(axis=1)
            assert per_day.shape == (task.num_eval_days,), (task.id, name)
            assert np.nanmean(per_day) <= np.nanmean(bound) + 1e-6, (task.id, name)


def _score_files(task_id):
    """The learned agents' committed score files of a task: ``{name: daily_profit}``."""
    out = {}
    for path in sorted(SCORES_DIR.glob(f"*_{task_id}.json")):
        data = json.loads(path.read_text())
        out[path.stem] = np.asarray(data["daily_profit"], np.float64)
    return out


def _exact_bound_tasks():
    """The tasks whose bound holds for every policy: the port-pooled bound of version 2 and
    the occupancy bound of version 3, where the occupancy does not depend on the policy."""
    return sorted(t.id for t in TASKS.values() if t.bound == "pooled" or t.session_model == "v3")


@pytest.mark.parametrize("task_id", _exact_bound_tasks())
def test_no_policy_beats_an_exact_bound_on_any_day_or_draw(task_id):
    """Every shipped reference (the rules, the coupled plan, the MPC in both action spaces) and
    every committed learned score file of the task."""
    refs = load_references(task_id)
    assert np.isfinite(refs["policies"][BOUND]["daily_profit"]).all()
    assert bound_violations(task_id, _score_files(task_id)) == []


def test_the_bound_check_fails_where_the_bound_is_not_exact():
    """On the version-1 tasks the occupancy bound holds only for policies with always-max's
    occupancy: the shipped rules and MPC are above it on many days and draws."""
    v1 = [t.id for t in TASKS.values() if t.version == 1]
    found = {task_id: bound_violations(task_id) for task_id in v1}
    assert all(found.values()), {k: len(v) for k, v in found.items()}
    assert sum(len(v) for v in found.values()) > 1000
    first = found["Chargax-shopping-v1"][0]
    assert first["profit_eur"] > first["bound_eur"] and first["excess_eur"] > 0.0


def test_bound_violations_reads_seeded_profits_and_refuses_other_shapes():
    refs = load_references("Chargax-shopping-v1")
    bound = refs["policies"][BOUND]["daily_profit"]
    above = np.stack([bound - 1.0, bound - 1.0])
    above[1, 3, 1] = bound[3, 1] + 5.0
    rows = [r for r in bound_violations("Chargax-shopping-v1", {"x": above}) if r["policy"] == "x"]
    assert [(r["seed"], r["day_index"], r["draw"]) for r in rows] == [(1, 3, 1)]
    with pytest.raises(ValueError, match=r"daily_profits\['x'\]"):
        bound_violations("Chargax-shopping-v1", {"x": bound[:, :1]})


def test_always_max_scores_exactly_zero_and_the_bound_one():
    task = TASKS["Chargax-shopping-v1"]
    refs = load_references(task)
    zero = refs["policies"][ZERO]["daily_profit"]
    assert float(get_normalized_score(task.id, zero)) == 0.0
    assert float(get_normalized_score(task.id, refs["policies"][BOUND]["daily_profit"])) == (
        pytest.approx(1.0, abs=1e-12)
    )
    # Played again, always-max books the shipped profits to float32 rounding: another CPU or
    # compiler pipeline (the tests compile with the cheap one) may round the day's sums apart
    # in the last bit.
    played = score(policies.always_max, task.id)
    np.testing.assert_allclose(played["daily_profit"], zero, rtol=1e-6)
    assert played["score"] == pytest.approx(0.0, abs=1e-6)
    assert played["vs"][ZERO]["mean"] == pytest.approx(0.0, abs=1e-3)
    assert played["profit_ratio_to_always_max"] == pytest.approx(1.0, abs=1e-6)
    assert played["metrics"]["energy_delivered_kwh"] > 0


def test_normalized_score_is_vectorised_over_leading_axes():
    task = TASKS["Chargax-shopping-v1"]
    refs = load_references(task)
    zero = refs["policies"][ZERO]["daily_profit"]
    bound = refs["policies"][BOUND]["daily_profit"]
    stacked = np.stack([zero, bound, 0.5 * (zero + bound)])
    np.testing.assert_allclose(get_normalized_score(task.id, stacked), [0.0, 1.0, 0.5])


# --- hand-made tasks --------------------------------------------------------------------


def two_price_params():
    """A 100 kWh, 50 kW battery at 50 % beside one port that no car visits, at 0.05 EUR/kWh
    until noon and 0.25 after, no losses, 0.0125 EUR/kWh of wear each way: the best day buys
    50 kWh at night and sells 100 by day, 15 - 150 * 0.0125 = 13.125 EUR; always-max (the
    battery idle) earns 0."""
    bat = Battery(
        "bat",
        capacity_kwh=100.0,
        max_kw=50.0,
        efficiency=1.0,
        tau=0.99,
        initial_soc=0.5,
        cost_eur_kwh=2 * 6000.0 * 0.0125,
        cycle_life=6000.0,
    )
    prices = np.tile(np.asarray([0.05] * 12 + [0.25] * 12, np.float32), (2, 1))
    params = make_params(
        station=Splitter("grid", 1000.0, (Port("p0", "DC", 500.0, 100.0), bat)),
        prices=prices,
        grid_fee_eur_kwh=0.0,
        fixed_cost_eur=0.0,
        feed_in_factor=1.0,
    )
    return no_arrivals(params)


def test_a_policy_that_reaches_the_bound_on_a_hand_made_day_scores_one(tmp_path):
    task = Task("two-price", 1, "custom", 1, "", num_eval_days=1, params_fn=two_price_params)
    refs = compute_references(task, rules=(ZERO,), log=None)
    bound = refs["policies"][BOUND]["daily_profit"][0][0]
    assert bound == pytest.approx(13.125, abs=1e-4)
    assert refs["policies"][ZERO]["daily_profit"][0][0] == 0.0
    save_references(refs, tmp_path)
    programme = policies.get_policy("battery_programme", task.make_params())
    result = score(programme, task, references_dir=tmp_path)
    # the programme reaches the optimum up to the rate curve's last discrete steps
    assert result["score"] == pytest.approx(1.0, abs=0.005)
    assert result["over_always_max_eur"]["mean"] == pytest.approx(13.125, abs=0.05)


def test_references_of_other_params_are_refused(tmp_path):
    def params_075():
        return make_params(station=three_level_station(), traffic=150.0)

    def params_070():
        return make_params(
            station=three_level_station(), traffic=150.0, customer_price_eur_kwh=0.70
        )

    task = Task("small", 1, "custom", 1, "", num_eval_days=1, params_fn=params_075)
    save_references(compute_references(task, rules=(ZERO,), bound=False, log=None), tmp_path)
    load_references(task, tmp_path)  # the same params: accepted
    changed = dataclasses.replace(task, params_fn=params_070)
    with pytest.raises(ReferenceMismatchError, match="fingerprint"):
        load_references(changed, tmp_path)
    with pytest.raises(ReferenceMismatchError, match="days"):
        load_references(dataclasses.replace(task, draws=2), tmp_path)
    with pytest.raises(ReferenceMismatchError, match="no references"):
        load_references(dataclasses.replace(task, name="other"), tmp_path)


# --- five kinds of policy, one policy ---------------------------------------------------


def small_params():
    """The six-port station with a battery, busy, in hourly steps (the host loops stay short)."""
    return make_params(station=three_level_station(), traffic=150.0, step_minutes=60.0)


@pytest.fixture(scope="module")
def small_task(tmp_path_factory):
    directory = tmp_path_factory.mktemp("refs")
    task = Task("small", 1, "custom", 2, "", num_eval_days=2, params_fn=small_params)
    save_references(compute_references(task, rules=(ZERO,), log=None), directory)
    return task, directory


@pytest.fixture(scope="module")
def mpc_levels1(small_task):
    """The one-process MPC reference in one level per direction, computed once: what
    `add_mpc` stores as ``mpc_levels1`` and what the split over processes must equal."""
    task, _ = small_task
    return compute_mpc(task, 1)


@pytest.fixture(scope="module")
def pooled_bound(small_task):
    """The small task's port-pooled bound, computed whole in one process, once."""
    task, _ = small_task
    pooled = dataclasses.replace(task, bound="pooled")
    return pooled, compute_references(pooled, rules=(), log=None)


def test_mpc_references_are_added_and_compared_on_the_days_they_have(
    small_task, mpc_levels1, tmp_path, monkeypatch
):
    task, directory = small_task
    work = tmp_path / "refs"
    shutil.copytree(directory, work)
    real, calls = references_module.compute_mpc, []

    def shared(t, num_levels=None, **kwargs):
        # the one-level reference is the module's, computed by the same call
        calls.append((t, num_levels, kwargs))
        if (t, num_levels, kwargs) == (task, 1, {"processes": 1}):
            return mpc_levels1
        return real(t, num_levels, **kwargs)

    monkeypatch.setattr(references_module, "compute_mpc", shared)
    add_mpc(task, work, log=None)
    assert [c[1] for c in calls] == list(MPC_REFERENCES.values())
    refs = load_references(task, work)
    for name, num_levels in MPC_REFERENCES.items():
        entry = refs["policies"][name]
        assert entry["daily_profit"].shape == (2, 2) and np.isfinite(entry["daily_profit"]).all()
        assert entry["failed_days"] == [] and entry["solves"] > 0
        expected = task.make_params().num_levels if num_levels is None else num_levels
        assert entry["num_levels"] == expected
    assert set(refs["policies"]) >= {ZERO, BOUND, *MPC_REFERENCES}  # nothing else dropped
    mpc = refs["policies"]["mpc"]["daily_profit"]
    assert compare(task, mpc, work)["vs"]["mpc"] == {"mean": 0.0, "stderr": 0.0}
    # a day without a profit (a failed solve) drops out of the score and of the comparisons
    holed = mpc.copy()
    holed[1, 0] = np.nan
    result = compare(task, holed, work)
    zero = refs["policies"][ZERO]["daily_profit"].mean(axis=1)
    assert result["days_scored"] == 1
    assert result["score"] == pytest.approx((mpc[0].mean() - zero[0]) / result["headroom_eur"])
    assert result["vs"]["mpc"]["mean"] == 0.0
    with pytest.raises(ValueError, match="field 'names' must name"):
        add_mpc(task, work, log=None, names=["mpc_levels2"])


def test_a_refilled_bound_day_is_the_full_rebuild_s(small_task, tmp_path):
    # a day stored as failed is solved again with its whole draw: it gets the number the
    # full build stored, and nothing else in the file moves
    task, directory = small_task
    work = tmp_path / "refs"
    shutil.copytree(directory, work)
    path = reference_path(task, work)
    full = json.loads(path.read_text())
    holed = json.loads(path.read_text())
    holed["policies"][BOUND]["daily_profit"][1][1] = None
    holed["policies"][BOUND]["status"][1][1] = "other solver error"
    save_references(holed, work)
    assert np.isnan(load_references(task, work)["policies"][BOUND]["daily_profit"][1, 1])
    assert refill_bound(task, work, log=None) == path
    assert json.loads(path.read_text()) == full
    before = path.stat().st_mtime_ns
    refill_bound(task, work, log=None)  # nothing failed: the file is left alone
    assert path.stat().st_mtime_ns == before
    # a file built without the bound has nothing to refill (a KeyError 'lp_bound' before)
    del full["policies"][BOUND]
    save_references(full, work)
    with pytest.raises(ReferenceMismatchError, match=r"holds no LP bound \('lp_bound'"):
        refill_bound(task, work, log=None)
    with pytest.raises(ValueError, match="field 'time_limit_s'"):
        refill_bound(task, work, time_limit_s=float("nan"), log=None)


def test_an_mpc_day_with_a_failed_solve_is_stored_without_a_profit(small_task, monkeypatch):
    task, _ = small_task

    def fail(*args, **kwargs):
        raise SolverError("HiGHS did not solve the problem: time or iteration limit")

    monkeypatch.setattr(mpc_module, "build_and_solve", fail)
    entry = compute_mpc(task, 1, day_index=[0])
    assert entry["daily_profit"] == [[None, None]]
    assert entry["failed_days"] == [int(task.eval_days()[0])]


def test_an_mpc_reference_split_over_processes_is_the_one_process_reference(
    small_task, mpc_levels1
):
    # each process plays whole days (every draw of a day), and a day's decisions depend on
    # that day alone: the same reference, number for number
    task, _ = small_task
    assert compute_mpc(task, 1, processes=2) == mpc_levels1
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="field 'processes' must be an integer >= 1"):
            compute_mpc(task, 1, processes=bad)
    local = dataclasses.replace(task, params_fn=lambda: small_params())  # does not pickle
    with pytest.raises(ValueError, match="field 'processes' must be 1 .* does not pickle"):
        compute_mpc(local, 1, processes=2)


def test_a_pooled_bound_split_over_processes_is_the_one_process_bound(small_task, pooled_bound):
    # the port-pooled bound's days are independent LPs: split by day, the same numbers
    task, _ = small_task
    pooled, one = pooled_bound
    two = compute_references(pooled, rules=(), log=None, processes=2)
    assert one["policies"][BOUND] == two["policies"][BOUND]
    assert np.isfinite(np.asarray(one["policies"][BOUND]["daily_profit"], float)).all()
    # the occupancy bound starts each day from the day before's basis: one process
    occupancy = dataclasses.replace(task, bound="occupancy")
    with pytest.raises(ValueError, match="field 'processes' must be 1 .* occupancy bound"):
        compute_references(occupancy, rules=(), log=None, processes=2)
    with pytest.raises(ValueError, match="field 'processes' must be an integer >= 1"):
        compute_references(pooled, rules=(), log=None, processes=0)


def test_a_pooled_bound_kept_in_chunks_resumes_and_is_the_whole_bound(
    small_task, pooled_bound, tmp_path, monkeypatch
):
    # each chunk of days is written when solved; a rerun reads the chunks, solves nothing,
    # and gives the numbers of the bound computed whole
    task, _ = small_task
    pooled, whole = pooled_bound
    kept = compute_references(pooled, rules=(), log=None, bound_dir=tmp_path, bound_chunk_days=1)
    assert kept["policies"][BOUND] == whole["policies"][BOUND]
    files = sorted(tmp_path.glob("*.bound.*.json"))
    assert len(files) == pooled.num_eval_days

    def unsolvable(*args, **kwargs):
        raise AssertionError("a kept chunk was solved again")

    monkeypatch.setattr(references_module, "_pooled_part", unsolvable)
    again = compute_references(pooled, rules=(), log=None, bound_dir=tmp_path, bound_chunk_days=1)
    assert again["policies"][BOUND] == whole["policies"][BOUND]
    # a chunk of other parameters is refused, by file
    other = json.loads(files[0].read_text())
    other["params_fingerprint"] = "0" * 16
    files[0].write_text(json.dumps(other))
    with pytest.raises(ValueError, match="field 'bound_dir': .* holds another bound"):
        compute_references(pooled, rules=(), log=None, bound_dir=tmp_path, bound_chunk_days=1)
    occupancy = dataclasses.replace(task, bound="occupancy")
    with pytest.raises(ValueError, match="field 'bound_dir' needs a port-pooled bound"):
        compute_references(occupancy, rules=(), log=None, bound_dir=tmp_path)
    with pytest.raises(ValueError, match="field 'bound_chunk_days' must be an integer >= 1"):
        compute_references(pooled, rules=(), log=None, bound_dir=tmp_path, bound_chunk_days=0)


def test_the_references_command_passes_its_time_limit(tmp_path, monkeypatch):
    # --time-limit reaches the LP solves of a build and of a refill; a limit <= 0 is refused
    seen = []

    def fake_compute(task_id, **kwargs):
        seen.append(("compute", kwargs["time_limit_s"]))
        raise SystemExit(0)

    def fake_refill(task_id, directory, **kwargs):
        seen.append(("refill", kwargs["time_limit_s"]))
        raise SystemExit(0)

    monkeypatch.setattr(references_cli, "compute_references", fake_compute)
    monkeypatch.setattr(references_cli, "refill_bound", fake_refill)
    task_id = "Chargax-shopping-v2"
    for extra in ([], ["--refill-bound"]):
        with pytest.raises(SystemExit):
            references_cli.main(
                ["--task", task_id, "--out", str(tmp_path), "--time-limit", "600"] + extra
            )
    assert seen == [("compute", 600.0), ("refill", 600.0)]
    with pytest.raises(SystemExit) as refused:
        references_cli.main(["--task", task_id, "--time-limit", "0"])
    assert refused.value.code == 2
    (tmp_path / "a_file").write_text("x")
    for bad in (
        ["--time-limit", "inf"],  # HiGHS read it as no limit
        ["--processes", "0"],
        ["--out", str(tmp_path / "a_file")],
        ["--bound-dir", str(tmp_path / "a_file" / "bound")],
    ):
        with pytest.raises(SystemExit) as refused:
            references_cli.main(["--task", task_id, *bad])
        assert refused.value.code == 2, bad
    assert len(seen) == 2  # nothing was built for a refused command line


def half_day_levels(first_half, params):
    """Ports at full power; the battery charges in the first half of the day (the sine of the
    time of day above 0) and discharges in the second."""
    top = params.num_levels
    is_battery = params.station.leaf_kind == KIND_BATTERY
    return jnp.where(is_battery, jnp.where(first_half, top, -top), top).astype(jnp.int32)


def test_the_five_kinds_score_the_same_policy_identically(small_task):
    task, directory = small_task
    params = task.make_params()
    single = Chargax(params=params)
    marl = ChargaxMARL(params=params)
    n = params.station.num_leaves
    time_in_single = obs_size(params) - context_size(params) + context_index(params, "time_of_day")
    time_in_marl = marl.obs_size - n - context_size(params) + context_index(params, "time_of_day")

    def core(state, key, p):
        angle = 2.0 * jnp.pi * state.timestep / p.num_steps
        return half_day_levels(jnp.sin(angle) > 0, p)

    def single_act(obs, key):
        return single.levels_to_action(half_day_levels(obs[time_in_single] > 0, params), params)

    def marl_act(obs, key):
        first_half = next(iter(obs.values()))[time_in_marl] > 0
        return marl.levels_to_actions(half_day_levels(first_half, params))

    # the host policies call the same functions, compiled once rather than run op by op
    single_jit, marl_jit = jax.jit(single_act), jax.jit(marl_act)

    def gym_act(obs):
        return np.asarray(single_jit(jnp.asarray(obs), None)).astype(np.int64)

    def pz_act(obs):
        return {a: int(i) for a, i in marl_jit(obs, None).items()}

    results = {
        kind: score(policy, task, kind=kind, references_dir=directory)
        for kind, policy in (
            ("core", core),
            ("single", single_act),
            ("marl", marl_act),
            ("gymnasium", gym_act),
            ("pettingzoo", pz_act),
        )
    }
    base = results["core"]["daily_profit"]
    assert base.shape == (2, 2)
    always_max = load_references(task, directory)["policies"][ZERO]["daily_profit"]
    assert not np.allclose(base, always_max)  # the battery moved: not always-max in disguise
    for kind in ("single", "marl"):  # the same compiled day as the core kind: bit for bit
        np.testing.assert_array_equal(results[kind]["daily_profit"], base, err_msg=kind)
        assert results[kind]["score"] == results["core"]["score"], kind
    # the host kinds compile the step on its own; equal bit for bit under XLA's default flags,
    # but the tests' cheap compile pipeline (tests/conftest.py) may round float32 sums differently
    for kind in ("gymnasium", "pettingzoo"):
        np.testing.assert_allclose(results[kind]["daily_profit"], base, rtol=1e-6, err_msg=kind)
        assert results[kind]["score"] == pytest.approx(results["core"]["score"], rel=1e-5), kind


# --- bad input --------------------------------------------------------------------------


def test_bad_input_gets_a_clear_error(small_task):
    task, directory = small_task
    params = task.make_params()
    n = params.station.num_leaves
    with pytest.raises(KeyError, match="unknown task 'Chargax-nope-v1'"):
        get_normalized_score("Chargax-nope-v1", np.zeros((100, 2)))
    with pytest.raises(ValueError, match=r"shape \(99, 2\) does not fit task"):
        get_normalized_score("Chargax-shopping-v1", np.zeros((99, 2)))
    with pytest.raises(ValueError, match="field 'kind'"):
        score(policies.always_max, task, kind="sb3", references_dir=directory)
    with pytest.raises(ValueError, match=rf"needs shape \({n},\)"):
        score(lambda o, k: jnp.zeros(3, jnp.int32), task, kind="single", references_dir=directory)
    with pytest.raises(ValueError, match="dtype float32"):
        score(lambda o, k: jnp.zeros(n), task, kind="single", references_dir=directory)
    with pytest.raises(ValueError, match="one action per agent"):
        score(lambda o, k: {"port_0": 0}, task, kind="marl", references_dir=directory)
    with pytest.raises(ValueError, match="outside MultiDiscrete"):
        score(lambda o: np.full(n, 99), task, kind="gymnasium", references_dir=directory)
    with pytest.raises(ValueError, match="levels of shape"):
        score(lambda s, k, p: jnp.zeros(2, jnp.int32), task, references_dir=directory)


def test_a_policy_with_non_finite_or_non_integer_levels_gets_no_score(small_task):
    """The play counts, in its compiled program, the steps whose levels the env had to
    reinterpret (NaN played as idle, 3.7 as 3) and ``score`` refuses to give a number."""
    task, directory = small_task
    params = task.make_params()
    days = task.eval_days()
    n = params.station.num_leaves

    def nan_early_on_one_day(state, key, p):  # NaN on the first 3 steps of days[1] only
        bad = (state.day == days[1]) & (state.timestep < 3)
        return jnp.where(bad, jnp.nan, jnp.full(n, p.num_levels, jnp.float32))

    steps = 3 * task.draws
    with pytest.raises(
        ValueError,
        match=rf"non-finite levels .* on {steps} steps, in {task.draws} of the "
        rf"{2 * task.draws} days played .*day indices \[{int(days[1])}\]",
    ):
        score(nan_early_on_one_day, task, references_dir=directory)
    with pytest.raises(ValueError, match=r"non-integer levels \(truncated toward zero"):
        score(lambda s, k, p: jnp.full(n, 3.7), task, references_dir=directory)

    # whole float levels are integers: scored as the int32 levels are
    def as_floats(s, k, p):
        return policies.always_max(s, k, p).astype(jnp.float32)

    whole = score(as_floats, task, references_dir=directory)["daily_profit"]
    # compiled as as_floats is (with its params), so bit for bit: a named rule's own program
    # takes the params as an argument and may round float32 sums apart
    ints = score(lambda s, k, p: policies.always_max(s, k, p), task, references_dir=directory)[
        "daily_profit"
    ]
    np.testing.assert_array_equal(whole, ints)


def test_a_named_rule_is_played_by_one_program_for_any_prices(small_task):
    """A rule of `policies.POLICIES` is played with the params an argument of its program:
    other prices of the same station shape compile nothing again, and the profits are those
    of the rule compiled with its params (to float32 rounding)."""
    task, _ = small_task
    params = task.make_params()
    days, keys = task.eval_days(), task.day_keys()
    rule = policies.battery_rule
    dear = params.replace(prices_eur_kwh=params.prices_eur_kwh * 1.5)
    first = protocol.play(rule, params, days, keys)
    assert count_compiles(lambda: protocol.play(rule, dear, days, keys)) == 0
    again = protocol.play(rule, dear, days, keys)
    assert not np.allclose(again.profit_eur, first.profit_eur)  # the prices were read
    closed = protocol.play(lambda s, k, p: rule(s, k, dear), dear, days, keys)
    np.testing.assert_allclose(again.profit_eur, closed.profit_eur, rtol=1e-6, atol=1e-4)
    np.testing.assert_array_equal(again.cars_arrived, closed.cars_arrived)


def test_continuous_policies_with_nan_fractions_get_no_score(small_task):
    """The same count for a single-agent policy in the continuous mode, jitted and on the
    host (Gymnasium kind)."""
    task, _ = small_task
    params = dataclasses.replace(task.make_params(), action_mode="continuous")
    days, keys = task.eval_days(), task.day_keys()
    n = params.station.num_leaves
    with pytest.raises(ValueError, match=r"single policy returned non-finite levels"):
        protocol.play(lambda o, k: jnp.full(n, jnp.nan), params, days, keys, kind="single")
    with pytest.raises(ValueError, match=r"gymnasium policy returned non-finite levels"):
        protocol.play(
            lambda o: np.full(n, np.nan, np.float32), params, days, keys, kind="gymnasium"
        )
    # finite fractions are floats by nature: played and totalled
    totals = protocol.play(lambda o, k: jnp.full(n, 0.5), params, days, keys, kind="single")
    assert np.all(np.isfinite(totals.profit_eur))


def test_a_policy_with_actions_outside_the_action_space_gets_no_score(small_task):
    """A level above the top, an index outside Discrete(n) or MultiDiscrete, a fraction
    outside the Box: the env clips them, so the play counts them in its compiled program (and
    the host loop on the host) and no kind of policy gets a score for the clipped play."""
    task, directory = small_task
    params = task.make_params()
    days, keys = task.eval_days(), task.day_keys()
    n = params.station.num_leaves
    env = ChargaxMARL(params=params)
    played = 2 * task.draws
    steps = params.num_steps * played

    def refused(kind, policy, p=params, steps=steps):
        with pytest.raises(
            ValueError,
            match=rf"the {kind} policy returned actions outside the action space .* on "
            rf"{steps} steps, in {played} of the {played} days played",
        ):
            protocol.play(policy, p, days, keys, kind=kind)

    top = params.num_levels

    def above_then_below(s, k, p):
        # above the top level on the first day, below the bottom on the second, in one play:
        # "every day played" holds only if each of the two is counted
        return jnp.where(s.day == days[0], 1000, -top - 1) * jnp.ones(n, jnp.int32)

    refused("core", above_then_below)
    with pytest.raises(ValueError, match="outside the action space"):  # through score too
        score(above_then_below, task, references_dir=directory)
    refused("core", lambda s, k, p: jnp.full(n, top + 1.0))
    refused("marl", lambda o, k: {a: jnp.int32(env.num_actions + 78) for a in env.agents})
    refused("marl", lambda o, k: {a: jnp.int32(-1) for a in env.agents})
    refused("single", lambda o, k: jnp.full(n, 99, jnp.int32))
    continuous = dataclasses.replace(params, action_mode="continuous")
    refused("single", lambda o, k: jnp.full(n, 7.0), continuous)
    refused("gymnasium", lambda o: np.full(n, 7.0, np.float32), continuous)
    refused("core", lambda s, k, p: jnp.full(n, -1.5), continuous)
    # the top and bottom levels themselves are in the space: played and totalled
    totals = protocol.play(lambda s, k, p: jnp.full(n, top, jnp.int32), params, days, keys)
    assert np.all(np.isfinite(totals.profit_eur))


def test_the_range_of_a_leaf_without_discharge_starts_at_zero(small_task):
    """Per leaf, not one global range: without V2G a port's bottom level is idle, so a
    discharge level there is outside the core's space (the env plays it as idle), while the
    battery may still discharge; the single-agent Box is [-1, 1] on every leaf, and a negative
    fraction there is in the space (the env plays it as 0)."""
    task, _ = small_task
    params = dataclasses.replace(task.make_params(), v2g=False)
    days, keys = task.eval_days(), task.day_keys()
    n = params.station.num_leaves
    battery = jnp.asarray(np.asarray(params.station.leaf_kind) == KIND_BATTERY)
    bottom = jnp.where(battery, -params.num_levels, 0).astype(jnp.int32)
    totals = protocol.play(lambda s, k, p: bottom, params, days, keys)  # every leaf's bottom
    assert np.all(np.isfinite(totals.profit_eur))
    with pytest.raises(ValueError, match="outside the action space"):
        protocol.play(lambda s, k, p: jnp.full(n, -1, jnp.int32), params, days, keys)
    continuous = dataclasses.replace(params, action_mode="continuous")
    totals = protocol.play(lambda o, k: jnp.full(n, -0.5), continuous, days, keys, kind="single")
    assert np.all(np.isfinite(totals.profit_eur))
    with pytest.raises(ValueError, match="outside the action space"):
        protocol.play(lambda s, k, p: jnp.full(n, -0.5), continuous, days, keys)


# --- a picture of a day -----------------------------------------------------------------


def test_the_picture_of_a_day_shows_the_scored_day(small_task, tmp_path):
    task, directory = small_task
    programme = policies.battery_rule
    played = score(programme, task, references_dir=directory)
    fig, data = day_picture(
        programme,
        task,
        day_index=1,
        draw=1,
        label="battery rule",
        path=tmp_path / "day.png",
        references_dir=directory,
    )
    assert (tmp_path / "day.png").stat().st_size > 0
    assert len(fig.axes) == 6  # five panels and the heat map's colour bar
    # The same day, cars and policy in two differently compiled programs: equal to float32
    # rounding (another day or draw differs by euros).
    assert data["policy"]["total_profit_eur"] == pytest.approx(
        played["daily_profit"][1, 1], rel=1e-6
    )
    assert data["policy"]["port_kw"].shape == (task.make_params().num_steps, 6)
    with pytest.raises(ValueError, match="draw in"):
        day_picture(programme, task, draw=2, references_dir=directory)


def test_the_picture_marks_every_car_s_departure():
    # a busy small station where ports are refilled in the step their car leaves: every car
    # that is ever parked gets one departure mark (the cars still parked at the day's end
    # leave with it; a car arriving in the last step is never parked)
    from chargax_marl.benchmark.picture import play_day

    params = make_params(
        station_kwargs={"num_dc": 4, "num_ac": 2}, traffic="high", session_model="paper"
    )
    day = play_day(
        lambda s, k: policies.always_max(s, k, params), params, 200, jax.random.PRNGKey(0)
    )
    arrived, departed = day["arrived"], day["departed"]
    assert (departed[:-1] & arrived[:-1]).any()  # a port refilled in its car's last step
    assert departed.sum() == arrived[:-1].sum()


def test_the_references_command_runs_without_importing_its_module_twice():
    """``python -m chargax_marl.benchmark.references`` runs the package's ``__main__``: the
    library module is imported once (a command inside the module that ``chargax_marl.benchmark``
    imports warned that it was found in sys.modules and ran a second copy of it)."""
    done = subprocess.run(
        [
            sys.executable,
            "-W",
            "error::RuntimeWarning",
            "-m",
            "chargax_marl.benchmark.references",
            "--help",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: python -m chargax_marl.benchmark.references")
