"""``baselines.eval``: the rules on the held-out days, common random numbers, paired statistics."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from baselines.config import build_env_params, resolve
from baselines.eval import heldout, references, stats
from chargax_marl import evaluation, optimal
from chargax_marl.benchmark import get_task
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.policies import get_policy
from chargax_marl.teachers import car_plan, storage_value
from tests.helpers import TINY, TINY_ENV

ROOT = Path(__file__).resolve().parents[2]


def test_battery_programme_rule_is_always_max_ports_and_the_programme_s_battery():
    """The ``battery_programme`` baseline: every occupied port at full power, the battery at the
    programme's full-power action; ``plan_programme``: the ports on the plan's advice, the
    same battery. Refused, naming the policy, on a station without a battery, where the
    baselines leave them out."""
    from baselines.eval.heldout import baseline_results
    from baselines.eval.rules import PLAN_PROGRAMME, PROGRAMME, evaluate_rules, rule_policy
    from chargax_marl.core import make_params, simulator
    from chargax_marl.policies import always_max

    params = make_params(**TINY_ENV)
    act, dp = rule_policy(PROGRAMME, params), storage_value.dp_battery_action(params)
    plan, advice = rule_policy(PLAN_PROGRAMME, params), car_plan.plan_advice(params)
    is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
    state = simulator.reset(jax.random.PRNGKey(1), params)
    state = state.replace(
        occupied=jnp.ones_like(state.occupied)
    )  # a car at every port (an empty one's level acts on nothing)

    @jax.jit
    @jax.vmap
    def at_step(t):  # every step of the day in one compiled program, not op by op
        s = state.replace(timestep=t)
        return (
            act(s, None, params),
            always_max(s, None, params),
            dp(s)[0],
            plan(s, None, params),
            advice(s),
        )

    steps = jnp.arange(int(params.num_steps), dtype=jnp.int32)
    all_levels, all_ref, all_dp, all_planned, all_advice = jax.device_get(at_step(steps))
    seen = set()
    for levels, ref, dp_t, planned, adv in zip(
        all_levels, all_ref, all_dp, all_planned, all_advice, strict=True
    ):
        np.testing.assert_array_equal(levels[~is_bat], ref[~is_bat])
        assert np.all(levels[is_bat] == int(dp_t) * int(params.num_levels))
        np.testing.assert_array_equal(
            planned[~is_bat], (adv[~is_bat] > 0.5) * int(params.num_levels)
        )
        np.testing.assert_array_equal(planned[is_bat], levels[is_bat])
        seen.add(int(dp_t))
    assert len(seen) > 1  # the battery trades on this day
    bare = make_params(**{**TINY_ENV, "station_kwargs": {"num_ports": 4, "battery": False}})
    for name in (PROGRAMME, PLAN_PROGRAMME):
        with pytest.raises(ValueError, match=name):
            evaluate_rules(bare, np.arange(2), (name,))
    assert not {PROGRAMME, PLAN_PROGRAMME} & set(baseline_results(bare, np.arange(2)))


def test_grid_programme_holds_the_battery_s_charge_while_the_ports_alone_overload_the_connection():
    """``grid_programme``: always-max ports and the programme's battery, except a charge while
    the ports' full-power draw exceeds the grid connection (a 25 % connection with every port
    taken); with the full connection it is ``battery_programme`` at every step."""
    from baselines.eval.rules import GRID_PROGRAMME, PROGRAMME, evaluate_rules, rule_policy
    from chargax_marl.core import make_params, simulator

    seen = {}
    for fraction in (0.25, None):
        params = make_params(**TINY_ENV, grid_fraction=fraction)
        act, prog, dp = (
            rule_policy(GRID_PROGRAMME, params),
            rule_policy(PROGRAMME, params),
            storage_value.dp_battery_action(params),
        )
        is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
        state = simulator.reset(jax.random.PRNGKey(1), params)
        car = lambda field, value: jnp.where(jnp.asarray(is_bat), getattr(state, field), value)  # noqa: E731
        # a 100 kWh car taking 150 kW at every port: 600 kW of ports against a 175 kW connection at 25 %
        state = state.replace(
            occupied=jnp.ones_like(state.occupied),
            soc=car("soc", 0.1),
            target_soc=car("target_soc", 1.0),
            capacity_kwh=car("capacity_kwh", 100.0),
            max_rate_kw=car("max_rate_kw", 150.0),
            tau=car("tau", 0.8),
        )

        @jax.jit
        @jax.vmap
        def at_step(t, state=state, act=act, prog=prog, dp=dp, params=params):
            s = state.replace(timestep=t)  # every step of the day in one compiled program
            return act(s, None, params), prog(s, None, params), dp(s)[0]

        steps = jnp.arange(int(params.num_steps), dtype=jnp.int32)
        all_levels, all_ref, all_dp = jax.device_get(at_step(steps))
        for t, (levels, ref, dp_t) in enumerate(zip(all_levels, all_ref, all_dp, strict=True)):
            np.testing.assert_array_equal(levels[~is_bat], ref[~is_bat])  # always-max ports
            want = int(dp_t)
            want = (
                0 if (fraction is not None and want > 0) else want
            )  # every step overloads the 25 % connection
            assert np.all(levels[is_bat] == want * int(params.num_levels)), (fraction, t)
            seen.setdefault(fraction, set()).add(int(dp_t))
    assert 1 in seen[0.25]  # the programme charges at some step, where the rule holds the battery
    bare = make_params(**{**TINY_ENV, "station_kwargs": {"num_ports": 4, "battery": False}})
    with pytest.raises(ValueError, match=GRID_PROGRAMME):
        evaluate_rules(bare, np.arange(2), (GRID_PROGRAMME,))


def test_held_out_evaluation_uses_common_random_numbers():
    """Every seed, and the rule-based baselines, meet the same drawn cars: a 'network' that
    ignores its parameters and plays always-max scores exactly always-max's daily profits,
    for every seed, and a paired difference of zero."""
    from baselines.eval.heldout import baseline_results
    from chargax_marl.evaluation import evaluate_policy
    from chargax_marl.policies import always_max

    _, full, _, days = build_env_params(resolve(TINY))
    days = days[:8]
    base = baseline_results(full, days)

    def make_act(p):
        return lambda s, k: always_max(s, k, full) + 0 * p.astype(np.int32)

    ev = heldout.evaluate_batched(
        make_act,
        np.zeros((3,), np.float32),
        full,
        days,
        reference_profit=base["always_max"]["daily_profit"],
    )
    ref = evaluate_policy("always_max", full, days)["metrics"]["daily_profit_eur"]["mean"]
    np.testing.assert_allclose(ev["per_seed_profit"], [ref] * 3, rtol=1e-6)
    np.testing.assert_allclose(
        ev["daily_profit"], np.broadcast_to(base["always_max"]["daily_profit"], (3, 8)), rtol=1e-6
    )
    assert ev["paired_diff"]["mean"] == pytest.approx(0.0, abs=1e-3)
    d = stats.paired_difference(np.array([[2.0, 4.0]]), np.array([1.0, 1.0]))
    assert d["mean"] == 2.0 and d["per_seed_mean"] == [2.0] and d["stderr"] == pytest.approx(1.0)


def test_the_draws_of_the_rules_are_traced_once(monkeypatch):
    """``evaluate_rules(..., draws=2)`` traces each rule once for both draws: one program
    plays them (a teacher's rule, built for its params, was traced and compiled again for
    every draw). That each day is the mean of its draws is `test_train`'s ``EVAL_DRAWS``
    test."""
    from baselines.eval import rules

    _, full, _, days = build_env_params(resolve(TINY))
    traces = []

    def counted(name, params):
        policy = rules.get_policy(name, params)

        def traced(state, key, p):
            traces.append(name)  # runs when the program is traced, not when it runs
            return policy(state, key, p)

        return traced

    monkeypatch.setattr(rules, "rule_policy", counted)
    names = ("always_max", "battery_programme")
    out = rules.evaluate_rules(full, days[:2], names, draws=2)
    assert sorted(traces) == sorted(names)
    assert all(np.all(np.isfinite(out[name]["daily_profit"])) for name in names)


def test_redraw_clusters_the_draws_of_a_day_before_the_standard_error():
    """Two days, two draws each: the per-day means 2 and 4 give mean 3 and s.e. 1 (not the
    s.e. of four independent numbers), and 3 > 2 x 1 beats."""
    from baselines.eval.stats import day_clustered

    d = day_clustered(np.array([[1.0, 3.0], [3.0, 5.0]]))  # (draws, days)
    assert d == {"mean": 3.0, "stderr": pytest.approx(1.0), "beats": True}
    assert (
        day_clustered(np.array([[1.0, -3.0], [3.0, 1.0]]))["beats"] is False
    )  # per day 2, -1: 0.5 < 2 x 1.5


def test_a_stored_mpc_pairs_only_with_the_days_it_ran_on():
    """``make optimal --mpc-days N`` stores the MPC for the first N days: the held-out
    evaluation and ``--replot`` take it only when it covers all of their days."""
    stored = {"policies": {"mpc": {"daily_profit": [1.0, 2.0]}}}
    np.testing.assert_array_equal(references.stored_mpc(stored, [3, 5]), [1.0, 2.0])
    assert references.stored_mpc(stored, [3, 5, 7]) is None
    assert references.stored_mpc({"policies": {}}, [3]) is None
    assert references.stored_mpc(None, [3]) is None


def test_a_day_with_a_failed_mpc_solve_is_reported_and_kept_out_of_the_means(monkeypatch):
    """The MPC's solves fail on one of two days: that day is listed with the steps and the
    status, its profit is NaN and the metrics and the paired differences use the other day."""
    from chargax_marl.core.params import make_params
    from chargax_marl.optimal import SolverError
    from chargax_marl.optimal import mpc as mpc_module

    params = make_params(**{**TINY_ENV, "traffic": "low"})
    days = np.array([3, 4])
    limit = "time or iteration limit"
    real_solve, real_plan, today = mpc_module.build_and_solve, mpc_module.MPC.plan, {}

    def plan(self, s):
        today["day"] = int(s["day"])
        return real_plan(self, s)

    def fails_on_day_4(*args, **kwargs):
        if today["day"] == 4:
            raise SolverError(f"HiGHS did not solve the problem: {limit}", limit)
        return real_solve(*args, **kwargs)

    monkeypatch.setattr(mpc_module.MPC, "plan", plan)
    monkeypatch.setattr(mpc_module, "build_and_solve", fails_on_day_4)
    res = references.evaluate_mpc(params, days, horizon_hours=2.0)
    profit = res["daily_profit"]
    assert np.isfinite(profit[0]) and np.isnan(profit[1])
    [failed] = res["failed_days"]
    assert failed["day"] == 4 and failed["steps"] and set(failed["status"]) == {limit}
    assert res["failures"] == len(failed["steps"])
    m = res["metrics"]["daily_profit_eur"]
    assert m["mean"] == pytest.approx(profit[0]) and (m["days_scored"], m["days_failed"]) == (1, 1)
    d = stats.paired_difference(np.append(profit, profit[0] + 2.0), np.ones(3))
    assert d["mean"] == pytest.approx(profit[0]) and d["days_excluded"] == 1
    assert d["stderr"] == pytest.approx(1.0)


@pytest.mark.parametrize(
    "session_model, kind", [("paper", "occupancy"), ("v2", "pooled"), ("v3", "occupancy")]
)
def test_the_held_out_bound_is_the_one_that_holds_under_the_session_model(session_model, kind):
    """On the v2 session model a policy changes which port a car gets and when a DC user
    leaves, so the bound over always-max's occupancy is no bound there: the held-out
    evaluation (and a run's headroom) uses the port-pooled bound, the same cars' LP. On v3
    every policy has always-max's occupancy, so its bound, exact and the v3 tasks', is used."""
    config = resolve({**TINY, "ENV_KWARGS": {**TINY_ENV, "session_model": session_model}})
    _, full, _, days = build_env_params(config)
    days = days[:3]
    base = heldout.baseline_results(full, days, optimal="bound")
    bound = base["lp_bound"]
    assert bound["kind"] == kind
    key = jax.random.PRNGKey(0)
    if kind == "pooled":
        expected = [
            b.profit_eur
            for b in optimal.pooled_bound_days(full, days, jax.random.split(key, days.size))
        ]
    else:
        expected = evaluation.hindsight_bound(full, days, key)["daily_profit"]
    np.testing.assert_allclose(bound["daily_profit"], expected, rtol=1e-9)
    for name in ("always_max", "battery_rule"):
        assert (bound["daily_profit"] >= base[name]["daily_profit"] - 1e-3).all(), name


def test_a_stored_result_without_every_day_s_mpc_gets_the_mpc_computed(monkeypatch):
    """``optimal="mpc"`` on stored references whose MPC covers fewer days (``make optimal
    --mpc-days N``): the bound is read from them and the MPC computed, not left out."""
    config = resolve({**TINY, "ENV_KWARGS": TINY_ENV})
    _, full, _, days = build_env_params(config)
    days = days[:3]
    stored = {
        "policies": {"lp_bound": {"daily_profit": [9.0, 9.0, 9.0]}, "mpc": {"daily_profit": [5.0]}}
    }
    monkeypatch.setattr(references, "cached", lambda params, d, directory: stored)
    monkeypatch.setattr(
        references, "evaluate_mpc", lambda params, d, key: {"daily_profit": np.full(d.size, 7.0)}
    )
    base = heldout.baseline_results(full, days, optimal="mpc", references_dir="stored")
    np.testing.assert_array_equal(base["lp_bound"]["daily_profit"], [9.0, 9.0, 9.0])
    np.testing.assert_array_equal(base["mpc"]["daily_profit"], [7.0, 7.0, 7.0])
    assert base["mpc"]["source"] == "computed"


@pytest.mark.parametrize("task_id", ["Chargax-shopping-v2", "Chargax-shopping-v3"])
def test_a_run_on_a_task_reads_the_shipped_bound_it_would_solve(task_id):
    """`make train`'s held-out evaluation on a task (one car draw, three action levels where
    the task has more): the task's shipped bound is the bound solved on the run's own
    params, days and cars, so the run reads it; other days, draws or params are solved."""
    task = get_task(task_id)
    config = resolve({"TASK": task_id, "ENV_KWARGS": {"num_levels": 1}})
    _, full, _, days = build_env_params(config)
    assert int(full.num_levels) != int(task.make_params().num_levels)
    shipped = references.shipped_bound(task_id, full, days, draws=1)
    assert shipped is not None and shipped.shape == (days.size,)
    # the run's cars (run_days: day i from split(PRNGKey(0), days)[i]) are the task's draw 0
    keys = jax.random.split(jax.random.PRNGKey(0), days.size)
    np.testing.assert_array_equal(keys, task.day_keys()[:, 0])
    first = np.asarray(days[:2])
    if evaluation.bound_kind(full) == "pooled":
        solved = optimal.pooled_bound_days(full, first, keys[:2])
    else:
        solved = optimal.bound_days(
            full, first, day_keys=keys[:2], reference=get_policy("always_max", full)
        )
    np.testing.assert_allclose(shipped[:2], [b.profit_eur for b in solved], rtol=1e-5)
    two = references.shipped_bound(task_id, full, days, draws=2)
    assert two is not None and not np.allclose(two, shipped)
    assert references.shipped_bound(task_id, full, days, draws=task.draws + 1) is None
    assert references.shipped_bound(task_id, full, days[:-1], draws=1) is None
    busier = task.scored_params(num_levels=1, traffic="high")
    assert references.shipped_bound(task_id, busier, days, draws=1) is None


def test_the_held_out_references_read_a_task_s_shipped_bound(monkeypatch):
    """``baseline_results(..., task=)`` takes the bound from the task's shipped references,
    naming them, and solves nothing; without ``task`` it solves the bound."""
    task_id = "Chargax-shopping-v3"
    config = resolve({"TASK": task_id, "ENV_KWARGS": {"num_levels": 1}})
    _, full, _, days = build_env_params(config)
    played = {
        name: {"daily_profit": np.full(days.size, 500.0), "metrics": {}}
        for name in ("always_max", "battery_rule")
    }
    monkeypatch.setattr(
        heldout.rules, "evaluate_rules", lambda *a, **k: {n: dict(e) for n, e in played.items()}
    )
    solved = []

    def solve(params, d, key):
        solved.append(d)
        return {"daily_profit": np.full(np.size(d), 600.0)}

    monkeypatch.setattr(heldout, "policy_bound", solve)
    base = heldout.baseline_results(full, days, optimal="bound", task=task_id)
    assert not solved
    assert task_id in base["lp_bound"]["source"]
    np.testing.assert_array_equal(
        base["lp_bound"]["daily_profit"], references.shipped_bound(task_id, full, days)
    )
    assert base["lp_bound"]["kind"] == "occupancy"
    base = heldout.baseline_results(full, days, optimal="bound")
    assert len(solved) == 1 and base["lp_bound"]["source"] == "computed"


def test_days_played_in_chunks_meet_the_same_cars_through_one_program():
    """``evaluate_batched(..., chunk_days=C)``: every day on the key it has in the whole batch
    (a random policy, whose levels read the key, scores what it scores unchunked, on every
    draw; the last chunk padded), and another number of days runs the same compiled program."""
    from chargax_marl.policies import get_policy

    _, full, _, days = build_env_params(resolve(TINY))
    days = days[:7]
    rand = get_policy("random", full)

    def make_act(p):
        return lambda s, k: rand(s, k, full) + 0 * p.astype(np.int32)

    seeds = np.zeros((2,), np.float32)
    whole = heldout.evaluate_batched(make_act, seeds, full, days, draws=2)
    chunked = heldout.evaluate_batched(make_act, seeds, full, days, draws=2, chunk_days=3)
    np.testing.assert_allclose(chunked["daily_profit"], whole["daily_profit"], rtol=1e-6)
    assert chunked["daily_profit"].shape == (2, 7)
    fn = heldout.compiled_keyed_evaluation(make_act, full)
    compiled = fn._cache_size()
    heldout.evaluate_batched(make_act, seeds, full, days[:5], chunk_days=3)
    assert fn._cache_size() == compiled
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="chunk_days"):
            heldout.evaluate_batched(make_act, seeds, full, days, chunk_days=bad)
