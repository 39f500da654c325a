"""Replayable days, the HiGHS hindsight bound and the MPC controller.

Hand cases have optima computed on paper (flat efficiencies of 1, no grid fee, no fixed
cost); the property tests compare the bound with the policies' own profits on drawn days.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse
from hypothesis import given, settings
from hypothesis import strategies as st

from chargax_marl import evaluation, optimal, policies, trace
from chargax_marl.benchmark import protocol
from chargax_marl.benchmark import references as references_module
from chargax_marl.core import simulator
from chargax_marl.core.params import make_params
from chargax_marl.core.station import Battery, Port, Splitter
from chargax_marl.optimal import bound as bound_module
from chargax_marl.optimal import milp as milp_module
from chargax_marl.optimal import model as model_module
from chargax_marl.optimal import mpc as mpc_module
from chargax_marl.optimal.mpc import MPC
from tests.helpers import count_compiles, exact_jit, hand_params, place_car, three_level_station
from tests.optimal.reference_lp import reference_value_eur

KEY = jax.random.PRNGKey(0)


def _replay_profit(policy, params, tr, key):
    _, _, final = trace.replay(lambda s, kk: policy(s, kk, params), params, tr, key)
    return final.totals.profit_eur


_replay_named_profit = jax.jit(_replay_profit, static_argnums=0)


def run_on_trace(policy, params, tr):
    """The day's profit of ``policy`` replayed on ``tr``. A named rule's program takes the
    params as an argument (one compile per rule and station shape, as the parametrised
    stations share their shapes); any other policy is compiled with its params."""
    if policies.is_named_rule(policy):
        return float(_replay_named_profit(policy, params, tr, KEY))
    return float(jax.jit(functools.partial(_replay_profit, policy, params))(tr, KEY))


def bound_for(policy, params, tr):
    occ = optimal.occupancy(params, tr, KEY, reference=policy)
    return optimal.hindsight_bound(params, tr, occ)


# --- exogenous traces -------------------------------------------------------------------


@pytest.fixture(scope="module")
def default_program():
    """The default station's params, two days and their compiled trace program."""
    params = make_params(battery_initial_soc=(0.2, 0.8))
    days = np.array([5, 123])
    return params, days, exact_jit(lambda k: trace.make_traces(params, days, k))


@pytest.fixture(scope="module")
def default_setup(default_program):
    params, days, make = default_program
    return params, days, make(KEY)


def test_a_named_reference_is_replayed_by_one_program_for_any_prices(default_setup):
    """`optimal.occupancy` replays a named rule with the params an argument of its program:
    other prices reuse the program compiled for the first params, and the sessions and the
    reference's profit are those of a replay with the params closed over."""
    params, _, traces = default_setup
    tr = jax.tree.map(lambda x: x[0], traces)
    rule = policies.battery_rule
    dear = params.replace(prices_eur_kwh=params.prices_eur_kwh * 1.5)
    first = optimal.occupancy(params, tr, KEY, reference=rule)
    compiled = bound_module._replay_named._cache_size()
    again = optimal.occupancy(dear, tr, KEY, reference=rule)
    assert bound_module._replay_named._cache_size() == compiled
    for p, got in ((params, first), (dear, again)):
        closed = optimal.occupancy(p, tr, KEY, reference=lambda s, k, q: rule(s, k, q))
        assert got.reference_profit_eur == pytest.approx(closed.reference_profit_eur, rel=1e-6)
        for field in ("leaf", "first", "last", "soc0", "target_soc", "capacity_kwh"):
            np.testing.assert_allclose(
                getattr(got.sessions, field), getattr(closed.sessions, field), rtol=1e-6
            )
    assert first.reference_profit_eur != pytest.approx(again.reference_profit_eur, rel=1e-3)


@pytest.mark.parametrize("name", ["random", "battery_rule"])
def test_replay_equals_the_keyed_rollout_bit_for_bit(default_setup, name):
    params, days, traces = default_setup
    pol = policies.get_policy(name)
    act = lambda s, k: pol(s, k, params)  # noqa: E731
    keyed = exact_jit(lambda d, k: evaluation.run_days(act, params, d, k))(jnp.asarray(days), KEY)
    replayed = exact_jit(lambda t, k: trace.replay_days(act, params, t, k))(traces, KEY)
    for field in keyed.__dataclass_fields__:
        a, b = np.asarray(getattr(keyed, field)), np.asarray(getattr(replayed, field))
        assert a.tobytes() == b.tobytes(), field


def test_the_cars_of_a_day_do_not_depend_on_the_policy(default_program, default_setup):
    params, days, traces = default_setup
    again = default_program[2](KEY)  # the same program run again: the same cars
    for a, b in zip(jax.tree_util.tree_leaves(traces), jax.tree_util.tree_leaves(again)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # the slots hold the cars that ask to park, whichever ports are free: a policy that keeps
    # ports busy (idle) admits a prefix of the same cars the always-max policy meets
    n_req = np.asarray(traces.arrivals.requested)
    assert n_req.sum() > 50 and n_req.shape == (2, params.num_steps)
    # the same key parks the same first car whichever ports are taken: on an empty station it
    # goes to port 0, with ports 0-2 busy to port 3 (per-port draws gave it other attributes);
    # with the first-free choice (a random choice: tests/core/test_sessions.py)
    from chargax_marl.core import simulator, traffic

    params = params.replace(random_port_choice=jnp.asarray(False))
    key = jax.random.PRNGKey(7)
    empty = simulator.empty_state(jnp.int32(5), params)
    busy = empty.replace(occupied=empty.occupied.at[:3].set(True))
    arrivals = traffic.draw_arrivals(key, empty.timestep, empty.is_workday, params).replace(
        requested=jnp.int32(1)
    )
    a, _ = traffic.place_arrivals(empty, arrivals, params)
    b, _ = traffic.place_arrivals(busy, arrivals, params)
    drawn_a, _ = traffic.arrive(key, empty.replace(timestep=jnp.int32(150)), params)
    drawn_b, _ = traffic.arrive(key, busy.replace(timestep=jnp.int32(150)), params)
    for field in ("soc", "target_soc", "capacity_kwh", "time_remaining_min"):
        assert float(getattr(a, field)[0]) == float(getattr(b, field)[3]) > 0, field
        first_a = np.asarray(getattr(drawn_a, field))[
            np.asarray(drawn_a.occupied & ~empty.occupied)
        ]
        first_b = np.asarray(getattr(drawn_b, field))[np.asarray(drawn_b.occupied & ~busy.occupied)]
        n = min(first_a.size, first_b.size)
        np.testing.assert_array_equal(first_a[:n], first_b[:n])


def test_traces_of_other_prices_and_traffic_reuse_the_compiled_program(small_params):
    """`make_traces` compiles once per station shape and number of days: a bound or reference
    computed under other prices, traffic or fees traces and compiles nothing again."""
    days, keys = np.array([3, 4]), jax.random.split(KEY, 2)
    first = trace.make_traces(small_params, days, day_keys=keys)
    busier = small_params.replace(arrival_rate=small_params.arrival_rate * 2)
    assert count_compiles(lambda: trace.make_traces(busier, days, day_keys=keys)) == 0
    again = trace.make_traces(busier, days, day_keys=keys)
    assert (np.asarray(again.arrivals.requested) >= np.asarray(first.arrivals.requested)).all()
    assert (np.asarray(again.arrivals.requested) > np.asarray(first.arrivals.requested)).any()


def test_a_trace_for_another_station_or_step_length_is_refused(default_setup):
    params, _, traces = default_setup
    tr = trace.day_of(traces, 0)
    other_station = make_params(station_kwargs={"num_dc": 4})
    with pytest.raises(ValueError, match="station"):
        trace.replay(lambda s, k: policies.always_max(s, k, other_station), other_station, tr, KEY)
    other_step = make_params(step_minutes=15.0)
    with pytest.raises(ValueError, match="step_minutes"):
        optimal.hindsight_bound(other_step, tr, optimal.occupancy(params, tr, KEY))


# --- hand-computed optima ---------------------------------------------------------------

ONE_PORT = Splitter("grid", 1000.0, (Port("p0", "DC", 500.0, 100.0),))  # 50 kW


def _one_car_day():
    """One 50 kW port, dear (1.00 EUR/kWh) until 06:00 and cheap (0.10) after; one car
    parks 04:05-08:05 and wants 24 kWh."""
    params = hand_params(ONE_PORT, [1.0] * 6 + [0.1] * 18)
    car = dict(
        arrival_step=48,
        capacity_kwh=60.0,
        dc_kw=50.0,
        tau=0.99,
        arrival_soc=0.2,
        target_soc=0.6,
        stay_min=240.0,
    )
    return params, trace.trace_from_cars(params, [car])


def test_one_car_waits_for_the_cheap_hours():
    # dear (1.00 EUR/kWh) until 06:00, cheap (0.10) after; the car parks 04:05-08:05 and
    # wants 24 kWh: the best plan buys all of it at 0.10 -> 24 * (0.75 - 0.10) = 15.6 EUR
    params, tr = _one_car_day()
    bound = bound_for(policies.always_max, params, tr)
    assert bound.status == "optimal"
    assert bound.profit_eur == pytest.approx(24 * (0.75 - 0.10), abs=1e-4)
    # always-max charges at once, at the dear price
    assert bound.reference_profit_eur == pytest.approx(24 * (0.75 - 1.0), abs=1e-3)
    # the MPC (4 h look-ahead) sees the cheap hours and waits for them
    assert run_on_trace(MPC(params), params, tr) == pytest.approx(15.6, abs=1e-3)


def test_two_cars_share_a_constrained_evse():
    # a 30 kW EVSE feeds two 50 kW ports for one hour: 30 kWh in all, whatever the split
    evse = Splitter("evse", 30.0, (Port("p0", "DC", 500.0, 100.0), Port("p1", "DC", 500.0, 100.0)))
    params = hand_params(Splitter("grid", 1000.0, (evse,)), [0.1] * 24)
    car = dict(
        arrival_step=0,
        capacity_kwh=100.0,
        dc_kw=50.0,
        tau=0.99,
        arrival_soc=0.2,
        target_soc=0.6,
        stay_min=60.0,
    )
    tr = trace.trace_from_cars(params, [car, car])
    bound = bound_for(policies.always_max, params, tr)
    assert bound.profit_eur == pytest.approx(30 * (0.75 - 0.10), abs=1e-4)
    assert bound.num_cars == 2
    assert bound.reference_profit_eur == pytest.approx(bound.profit_eur, rel=1e-4)
    assert bound.profit_eur >= bound.reference_profit_eur - 1e-4


def two_price_best_eur(efficiency, wear_eur_kwh):
    """The best profit of a 100 kWh, 50 kW battery at 50 % on a day at 0.05 EUR/kWh until noon
    and 0.25 after, its stored energy valued at the day's mean buy price 0.15 at the end, each
    kWh into or out of the cells paying ``w``, ``eta`` each way (grid side): the 50 kWh bought
    at night (``0.05 / eta + w`` per kWh) pays iff selling it by day (``0.25 eta - w``) or
    keeping it (0.15) is worth more, and the 50 kWh held pay iff selling them beats keeping
    them. With ``eta = 1`` every piece pays iff the 0.20 spread beats ``2 w``: ``15 - 150 w``
    below ``w = 0.10``, 0 above."""
    eta, w = efficiency, wear_eur_kwh
    bought = max(0.0, max(0.25 * eta - w, 0.15) - 0.05 / eta - w)
    held = max(0.0, 0.25 * eta - w - 0.15)
    return 50.0 * bought + 50.0 * held


@pytest.mark.parametrize(
    ("efficiency", "wear_eur_kwh"),
    [(1.0, 0.0), (1.0, 0.0125), (1.0, 0.09), (1.0, 0.11), (1.0, 0.2), (0.9, 0.0), (0.9, 0.0125)]
    + [(0.9, 0.1)],
)
def test_a_battery_on_a_two_price_day_pays_iff_the_spread_beats_losses_and_wear(
    efficiency, wear_eur_kwh
):
    best = two_price_best_eur(efficiency, wear_eur_kwh)
    cycle_life = 6000.0
    bat = Battery(
        "bat",
        capacity_kwh=100.0,
        max_kw=50.0,
        efficiency=efficiency,
        tau=0.99,
        initial_soc=0.5,
        cost_eur_kwh=2 * cycle_life * wear_eur_kwh,
        cycle_life=cycle_life,
    )
    params = hand_params(
        Splitter("grid", 1000.0, (Port("p0", "DC", 500.0, 100.0), bat)), [0.05] * 12 + [0.25] * 12
    )
    assert float(params.battery_wear_eur_kwh[0]) == pytest.approx(wear_eur_kwh, rel=1e-6)
    tr = trace.trace_from_cars(params, [])
    bound = bound_for(policies.battery_rule, params, tr)
    assert bound.profit_eur == pytest.approx(best, abs=1e-4)
    # no cars and no fixed cost: without the battery the bound is 0, so the battery is worth
    # the whole bound
    occ = optimal.occupancy(params, tr, KEY, reference=policies.battery_rule)
    alone = optimal.hindsight_bound(params, tr, occ, with_battery=False)
    assert alone.profit_eur == pytest.approx(0.0, abs=1e-6)
    # the two-line rule that prices losses and wear and the battery-only programme reach it (up
    # to the discrete last steps of the rate curve); the rule blind to both cycles anyway: it
    # buys the 50 kWh at night and sells all 100 by day
    assert bound.reference_profit_eur == pytest.approx(best, abs=0.05)
    assert bound.reference_profit_eur <= bound.profit_eur + 1e-4
    programme = policies.get_policy("battery_programme", params)
    assert run_on_trace(programme, params, tr) == pytest.approx(best, abs=0.05)
    naive = run_on_trace(policies.battery_rule_naive, params, tr)
    cycle = -50.0 * 0.05 / efficiency + 100.0 * 0.25 * efficiency - 50.0 * 0.15
    assert naive == pytest.approx(cycle - 150.0 * wear_eur_kwh, abs=0.05)
    if best == 0.0:
        assert naive < -1.0
    if (efficiency, wear_eur_kwh) in ((1.0, 0.0125), (1.0, 0.11)):  # the MPC either side
        assert run_on_trace(MPC(params, horizon_hours=24.0), params, tr) == pytest.approx(
            best, abs=0.05
        )


def test_an_unreachable_target_is_missing_energy_not_an_infeasible_problem():
    params = hand_params(ONE_PORT, [0.1] * 24)
    tr = trace.trace_from_cars(
        params,
        [
            dict(
                arrival_step=0,
                capacity_kwh=100.0,
                dc_kw=50.0,
                tau=0.99,
                arrival_soc=0.0,
                target_soc=1.0,
                stay_min=5.0,
            )
        ],
    )
    bound = bound_for(policies.always_max, params, tr)
    # one 5-minute step at 50 kW: 50/12 kWh of the 100 wanted
    assert bound.profit_eur == pytest.approx(50 / 12 * 0.65, abs=1e-4)


def test_a_solver_time_limit_is_an_error_not_a_number(default_setup):
    params, _, traces = default_setup
    tr = trace.day_of(traces, 0)
    occ = optimal.occupancy(params, tr, KEY)
    with pytest.raises(optimal.SolverError, match="limit"):
        optimal.hindsight_bound(params, tr, occ, time_limit_s=1e-9)


# --- properties on drawn days -----------------------------------------------------------


@pytest.fixture(scope="module")
def small_setup():
    params = make_params(
        station_kwargs={"num_dc": 4, "num_ac": 2}, traffic="high", battery_initial_soc=(0.2, 0.8)
    )
    return params, trace.make_traces(params, np.array([10, 200]), KEY)


@pytest.mark.parametrize("name", ["always_max", "battery_rule", "price_threshold", "edf", "random"])
def test_the_bound_is_above_every_policy_with_the_same_occupancy(small_setup, name):
    params, traces = small_setup
    for i in range(2):
        b = bound_for(policies.get_policy(name), params, trace.day_of(traces, i))
        assert b.profit_eur >= b.reference_profit_eur - 1e-3 * abs(b.reference_profit_eur) - 1e-3


@pytest.fixture(scope="module")
def mpc_day(small_setup):
    """A 2-hour MPC played through small_setup's first day (as the reference of that day's
    occupancy), once: the controller, the occupancy and what the host saw at each solve."""
    params, traces = small_setup
    mpc = MPC(params, horizon_hours=2.0)
    seen = []
    act = mpc.host_act

    def record(*arrays, slot=0):
        seen.append({k: np.asarray(v).copy() for k, v in zip(mpc_module._FIELDS, arrays)})
        return act(*arrays, slot=slot)

    mpc.host_act = record
    occ = optimal.occupancy(params, trace.day_of(traces, 0), KEY, reference=mpc)
    return mpc, occ, seen


def test_the_bound_is_above_the_mpc_with_the_same_occupancy(small_setup, mpc_day):
    params, traces = small_setup
    mpc, occ, _ = mpc_day
    b = optimal.hindsight_bound(params, trace.day_of(traces, 0), occ)
    assert mpc.solves > 0 and mpc.failures == 0
    assert b.profit_eur >= b.reference_profit_eur - 1e-3 * abs(b.reference_profit_eur)


def _cars_at_dawn():
    return [
        dict(
            arrival_step=0,
            capacity_kwh=60.0,
            dc_kw=100.0,
            tau=0.8,
            arrival_soc=0.1,
            target_soc=0.9,
            stay_min=600.0,
        ),
        dict(
            arrival_step=0,
            capacity_kwh=80.0,
            dc_kw=150.0,
            tau=0.8,
            arrival_soc=0.3,
            target_soc=0.95,
            stay_min=900.0,
        ),
        dict(
            arrival_step=0,
            capacity_kwh=40.0,
            ac_kw=11.0,
            tau=0.8,
            arrival_soc=0.2,
            target_soc=0.7,
            stay_min=1200.0,
        ),
    ]


@pytest.mark.parametrize("action_mode,tol_eur", [("continuous", 0.02), ("absolute", 1.0)])
def test_a_full_day_mpc_reaches_the_bound_when_no_car_arrives_later(action_mode, tol_eur):
    # 15-minute steps keep the host-side MPC loop short (96 solves)
    params = make_params(
        station_kwargs={"num_dc": 2, "num_ac": 2}, action_mode=action_mode, step_minutes=15.0
    )
    tr = trace.trace_from_cars(params, _cars_at_dawn())
    mpc = MPC(params, horizon_hours=24.0, deadline_margin_steps=0)
    # the MPC's day, played once: its profit and the occupancy the bound is solved over
    occ = optimal.occupancy(params, tr, KEY, reference=mpc)
    profit = occ.reference_profit_eur
    bound = optimal.hindsight_bound(params, tr, occ).profit_eur
    assert profit <= bound + 1e-3
    assert bound - profit <= tol_eur


# --- solver failures --------------------------------------------------------------------

LIMIT = "time or iteration limit"
STATUS_ERROR = "other solver error"


def test_a_failed_lp_day_is_reported_and_kept_out_of_every_mean(monkeypatch):
    # the second day's LP hits its time limit (with every setting the model tries): it is
    # reported with its status, its profit is NaN (not a number to average) and the means and
    # the headroom use the first day only
    params = hand_params(ONE_PORT, [0.2] * 24, step_minutes=60.0)
    real, calls = bound_module.build_and_solve, []

    def second_day_fails(*args, **kwargs):
        calls.append(kwargs["warm_start"] is not None)
        if len(calls) >= 2:
            raise optimal.SolverError(f"HiGHS did not solve the problem: {LIMIT}", LIMIT)
        return real(*args, **kwargs)

    monkeypatch.setattr(bound_module, "build_and_solve", second_day_fails)
    res = evaluation.hindsight_bound(params, np.array([0, 1]))
    bound, ref = res["daily_profit"], res["reference_daily_profit"]
    assert calls == [False, True]  # day 1 warm-started; the model itself retries
    assert res["status"] == ["optimal", LIMIT]
    assert res["failed_days"] == [{"day": 1, "status": LIMIT}]
    assert np.isfinite(bound[0]) and np.isnan(bound[1]) and np.isfinite(ref).all()
    stats = evaluation.summarize_profit(bound)["daily_profit_eur"]
    assert stats["mean"] == bound[0] and stats["max"] == bound[0]
    assert (stats["days_scored"], stats["days_failed"]) == (1, 1)
    h = evaluation.headroom_captured(ref, ref, bound)
    assert h["days_excluded"] == 1 and h["headroom_eur"] == pytest.approx(bound[0] - ref[0])
    assert h["captured_eur"] == 0.0


def test_an_mpc_error_in_the_callback_names_the_day_and_the_step(monkeypatch):
    params = hand_params(ONE_PORT, [0.2] * 24, step_minutes=60.0)
    state = simulator.empty_state(jnp.asarray(1), params).replace(timestep=jnp.asarray(5))
    state = place_car(state, 0, soc=0.2, remaining_kwh=20.0, time_min=180.0)

    def broken(*args, **kwargs):
        raise ValueError("a bug in the LP builder")

    monkeypatch.setattr(mpc_module, "build_and_solve", broken)
    mpc = MPC(params)
    with pytest.raises(Exception, match=r"MPC failed on day 1, step 5: ValueError: a bug"):
        jax.block_until_ready(jax.jit(lambda s: mpc(s, KEY, params))(state))


def test_an_mpc_solve_that_fails_is_recorded_with_its_day_step_and_status(monkeypatch):
    params = hand_params(ONE_PORT, [0.2] * 24, step_minutes=60.0)
    state = simulator.empty_state(jnp.asarray(1), params).replace(timestep=jnp.asarray(5))
    state = place_car(state, 0, soc=0.2, remaining_kwh=20.0, time_min=180.0)

    def limit(*args, **kwargs):
        raise optimal.SolverError(f"HiGHS did not solve the problem: {LIMIT}", LIMIT)

    monkeypatch.setattr(mpc_module, "build_and_solve", limit)
    mpc = MPC(params)
    levels = jax.jit(lambda s: mpc(s, KEY, params))(state)
    assert int(levels[0]) == params.num_levels  # the fallback: the car at full power
    assert mpc.failures == 1 and mpc.failed_solves == {1: [(5, LIMIT)]}


def _fail_from_a_basis(monkeypatch, status=STATUS_ERROR):
    """Make every HiGHS run that starts from a basis end in ``status``; returns the list of
    whether each run had one."""
    real, runs = model_module.run_highs, []

    def run(h, num_cols, num_rows):
        runs.append(bool(h.getBasis().valid))
        if runs[-1]:
            raise optimal.SolverError(f"HiGHS did not solve the problem: {status}", status)
        return real(h, num_cols, num_rows)

    monkeypatch.setattr(model_module, "run_highs", run)
    return runs


def test_a_failed_warm_start_is_solved_again_from_scratch(monkeypatch):
    # every warm-started solve fails: each is solved again without the basis, and no step
    # falls back
    params = hand_params(ONE_PORT, [0.2] * 24, step_minutes=60.0)
    state = simulator.empty_state(jnp.asarray(1), params)
    state = place_car(state, 0, soc=0.2, remaining_kwh=20.0, time_min=600.0)
    runs = _fail_from_a_basis(monkeypatch)
    mpc = MPC(params)
    act = jax.jit(lambda s: mpc(s, KEY, params))
    for t in range(3):
        jax.block_until_ready(act(state.replace(timestep=jnp.asarray(t))))
    assert mpc.solves == 3 and mpc.warm_retries == 2 and mpc.failures == 0
    assert runs == [False, True, False, True, False]  # each retry without the basis
    assert mpc.retried_solves == {}  # solved by its own settings from scratch


RETRIED = [
    # (runs that fail first, the attempt that solves, its options)
    (1, "presolve on", {"presolve": "on", "simplex_dual_edge_weight_strategy": 1}),
    (2, "primal simplex", {"presolve": "off", "solver": "simplex", "simplex_strategy": 4}),
    (3, "interior point", {"presolve": "off", "solver": "ipm", "run_crossover": "on"}),
    (4, "HiGHS defaults", {"presolve": "choose", "simplex_dual_edge_weight_strategy": -1}),
]


@pytest.mark.parametrize("failing,attempt,options", RETRIED)
def test_a_failed_highs_run_is_retried_with_other_settings(monkeypatch, failing, attempt, options):
    # HiGHS ends the first runs in an error; the next settings solve the day to the value a
    # clean solve gets, and the bound says which settings did
    params, tr = _one_car_day()
    occ = optimal.occupancy(params, tr, KEY)
    clean = optimal.hindsight_bound(params, tr, occ)
    real, runs = model_module.run_highs, []

    def run(h, num_cols, num_rows):
        runs.append({k: h.getOptionValue(k)[1] for k in options})
        if len(runs) <= failing:
            raise optimal.SolverError(f"HiGHS did not solve the problem: {STATUS_ERROR}")
        return real(h, num_cols, num_rows)

    monkeypatch.setattr(model_module, "run_highs", run)
    bound = optimal.hindsight_bound(params, tr, occ)
    assert bound.status == "optimal" and bound.attempt == attempt
    assert bound.solution.attempt == attempt
    assert len(runs) == failing + 1 and runs[-1] == options
    assert bound.profit_eur == pytest.approx(clean.profit_eur, abs=1e-6)
    assert clean.attempt == "default"
    assert references_module.bound_status(bound) == f"optimal ({attempt})"
    assert references_module.bound_status(clean) == "optimal"


def test_a_day_that_fails_every_setting_keeps_the_last_status(monkeypatch):
    # the first day solves; every run of the second day fails, the last one as infeasible:
    # the day is reported with that status and each setting tried is named
    params = hand_params(ONE_PORT, [0.2] * 24, step_minutes=60.0)
    names = [name for name, _ in model_module.attempt_settings(model_module.LP_OPTIONS, warm=True)]
    real, runs = model_module.run_highs, []

    def run(h, num_cols, num_rows):
        runs.append(h)
        if len(runs) == 1:
            return real(h, num_cols, num_rows)
        status = "infeasible" if len(runs) == 1 + len(names) else STATUS_ERROR
        raise optimal.SolverError(f"HiGHS did not solve the problem: {status}", status)

    monkeypatch.setattr(model_module, "run_highs", run)
    first, second = bound_module.bound_days(params, np.array([0, 1]))
    assert first.solved and first.attempt == "default"
    assert len(runs) == 1 + len(names) and names[0] == "warm start"
    assert second.status == "infeasible" and np.isnan(second.profit_eur)
    assert second.attempt == "" and second.solution is None
    assert all(f"{name}: " in second.message for name in names)
    assert references_module.bound_status(second) == "infeasible"
    runs.clear()
    res = evaluation.hindsight_bound(params, np.array([0, 1]))
    assert res["status"] == ["optimal", "infeasible"]
    assert res["failed_days"] == [{"day": 1, "status": "infeasible"}]


def test_a_solve_that_fails_every_setting_raises_with_each_attempt(monkeypatch):
    params, tr = _one_car_day()
    occ = optimal.occupancy(params, tr, KEY)
    statuses = iter([STATUS_ERROR, STATUS_ERROR, STATUS_ERROR, STATUS_ERROR, LIMIT])

    def run(h, num_cols, num_rows):
        status = next(statuses)
        raise optimal.SolverError(f"HiGHS did not solve the problem: {status}", status)

    monkeypatch.setattr(model_module, "run_highs", run)
    with pytest.raises(optimal.SolverError) as info:
        optimal.hindsight_bound(params, tr, occ)
    assert info.value.status == LIMIT
    assert info.value.attempts == (
        ("default", STATUS_ERROR),
        ("presolve on", STATUS_ERROR),
        ("primal simplex", STATUS_ERROR),
        ("interior point", STATUS_ERROR),
        ("HiGHS defaults", LIMIT),
    )


def test_each_bound_day_starts_from_the_previous_day_s_basis_and_keeps_its_value(
    small_params, monkeypatch
):
    """`bound_days` hands each day's LP the optimal basis of the day before; the bounds are
    those of solves from scratch, and a warm start that fails is solved again from scratch."""
    days = np.array([3, 40, 41, 200])
    cold = bound_module.bound_days(small_params, days, warm_start=False)
    real, starts = bound_module.build_and_solve, []

    def spy(*args, **kwargs):
        starts.append(kwargs["warm_start"])
        return real(*args, **kwargs)

    monkeypatch.setattr(bound_module, "build_and_solve", spy)
    warm = bound_module.bound_days(small_params, days)
    assert starts[0] is None and all(isinstance(b, model_module.Basis) for b in starts[1:])
    assert [s is w.solution.basis for s, w in zip(starts[1:], warm[:-1])] == [True] * 3
    assert all(b.solved for b in warm + cold)
    np.testing.assert_allclose(
        [b.profit_eur for b in warm], [b.profit_eur for b in cold], rtol=1e-9, atol=1e-9
    )

    monkeypatch.setattr(bound_module, "build_and_solve", real)
    runs = _fail_from_a_basis(monkeypatch, LIMIT)
    again = bound_module.bound_days(small_params, days)
    assert runs == [False] + [True, False] * 3  # each failed warm start, again from scratch
    assert [b.profit_eur for b in again] == [b.profit_eur for b in cold]
    assert [b.attempt for b in again] == ["default"] * 4


# --- reporting --------------------------------------------------------------------------


def test_headroom_fraction_by_hand():
    am = np.array([100.0, 200.0])
    bound = np.array([120.0, 230.0])  # headroom 20 and 30, mean 25
    h = evaluation.headroom_captured(np.array([110.0, 215.0]), am, bound)
    assert h["fraction"] == pytest.approx(12.5 / 25.0)
    assert h["headroom_eur"] == pytest.approx(25.0) and h["captured_eur"] == pytest.approx(12.5)
    seeds = evaluation.headroom_captured(np.array([[110.0, 215.0], [90.0, 185.0]]), am, bound)
    assert seeds["fraction"] == pytest.approx(0.0)


def test_training_baselines_carry_the_bound_and_the_headroom():
    from baselines.eval.heldout import baseline_results

    # small_setup's station and traffic in 15-minute steps, which keep the LPs small
    params = make_params(
        station_kwargs={"num_dc": 4, "num_ac": 2},
        traffic="high",
        battery_initial_soc=(0.2, 0.8),
        step_minutes=15.0,
    )
    days = np.array([10, 200])
    base = baseline_results(params, days, optimal="bound")
    am, bound = base["always_max"]["daily_profit"], base["lp_bound"]["daily_profit"]
    assert np.all(bound >= am - 1e-3)
    assert base["always_max"]["headroom"]["fraction"] == pytest.approx(0.0, abs=1e-9)
    assert base["lp_bound"]["headroom"]["fraction"] == pytest.approx(1.0)
    assert base["battery_rule"]["headroom"]["fraction"] <= 1.0
    with pytest.raises(ValueError, match="optimal"):
        baseline_results(params, days, optimal="yes")
    assert "headroom_captured" in evaluation.format_table(base)


# --- the MILP over admissions -----------------------------------------------------------


def test_the_milp_turns_away_a_car_that_would_block_a_better_one():
    # one port; car A (5 kWh, stays 2 h) arrives first and, admitted first-free-port, blocks
    # car B (30 kWh, 1 h) ten minutes later. Always-max's occupancy: A only, 5 * 0.65 = 3.25
    # EUR; the best admission: B only, 30 * 0.65 = 19.5 EUR.
    from chargax_marl.optimal import milp

    params = hand_params(ONE_PORT, [0.1] * 24)
    car = dict(capacity_kwh=100.0, dc_kw=50.0, tau=0.99, arrival_soc=0.2)
    tr = trace.trace_from_cars(
        params,
        [
            dict(car, arrival_step=0, target_soc=0.25, stay_min=120.0),
            dict(car, arrival_step=2, target_soc=0.5, stay_min=60.0),
        ],
    )
    r = milp.compare(params, tr, KEY, num_steps=36)
    assert r.reference_eur == pytest.approx(3.25, abs=1e-3)
    assert r.lp_eur == pytest.approx(3.25, abs=1e-4)
    assert r.milp_eur == pytest.approx(19.5, abs=1e-4)
    assert r.num_candidates == 2


def test_the_milp_bounds_every_policy_and_the_lp_on_a_window(small_setup):
    from chargax_marl.optimal import milp

    params = make_params(station_kwargs={"num_dc": 2, "num_ac": 2}, traffic="high")
    tr = trace.day_of(trace.make_traces(params, np.array([10]), KEY), 0)
    r = milp.compare(params, tr, KEY, num_steps=24)
    assert r.num_candidates >= 2
    assert r.milp_eur >= r.lp_eur - 1e-4 >= r.reference_eur - 2e-3
    for name in ("battery_rule", "edf", "random"):
        assert (
            r.milp_eur >= milp.window_profit(params, tr, KEY, policies.get_policy(name), 24) - 1e-3
        )
    with pytest.raises(ValueError, match="num_steps"):
        milp.admission_bound(params, tr, 1)


def test_the_mpc_drives_both_views_like_the_core():
    """The MPC is an ordinary policy: through ``for_single`` and ``for_marl`` it gives the
    single-agent and the multi-agent view the same levels as on the core state."""
    from chargax_marl.marl import ChargaxMARL
    from chargax_marl.single import make

    env, params = make("shopping", station_kwargs={"num_dc": 2, "num_ac": 2}, traffic="high")
    mpc = MPC(params, horizon_hours=1.0)
    _, state = env.reset(KEY, params)
    single_act = jax.jit(policies.for_single(mpc, env, params))
    marl = ChargaxMARL(params=params)
    marl_act = policies.for_marl(mpc, marl)
    for t in range(12):
        k = jax.random.fold_in(KEY, t)
        action = single_act(state, k)
        levels = np.asarray(mpc(state, k, params))
        np.testing.assert_array_equal(np.asarray(env.action_to_levels(action, params)), levels)
        per_agent = marl_act(state, k)
        assert len(per_agent) == params.station.num_leaves
        _, state, _, _, _, _ = env.step(k, state, action, params)
    assert mpc.solves > 0 and mpc.failures == 0


def test_refreshing_the_rules_keeps_the_bound_and_refuses_another_model(tmp_path, monkeypatch):
    """``optimal --rules-only`` puts the current rules in place of stored ones (here a stale
    EDF) with their paired differences and headroom, keeps the stored bound and MPC, and
    refuses a file whose always-max does not replay (another model) or whose params differ."""
    import json

    from baselines.analysis import references as opt
    from baselines.eval.rules import evaluate_rules

    monkeypatch.setattr(opt, "RULES", ("always_max", "edf"))
    params, days = opt.scenario_params("default_full_power")
    days = np.asarray(days)[:2]
    fresh = evaluate_rules(params, days, ("always_max", "edf"))
    am = fresh["always_max"]["daily_profit"]
    bound = [float(x) + 10.0 for x in am]
    shown = {
        "vs_always_max": {"mean": 4.0, "stderr": 0.0},
        "headroom": {"fraction": 0.4},
        "mean_eur": 1.0,
    }
    mpc = {"daily_profit": [float(x) + 4.0 for x in am], "timing": {"wall_s": 99.0}, **shown}
    stored = {
        "scenario": "default_full_power",
        "days": [int(d) for d in days],
        "root_kw": 100.0,
        "params_fingerprint": trace.params_fingerprint(params),
        "policies": {
            "always_max": {"daily_profit": [float(x) for x in am], **shown},
            "edf": {"daily_profit": [-999.0, -999.0], **shown},
            "mpc": mpc,
            "lp_bound": {"daily_profit": bound, **shown},
        },
    }
    path = tmp_path / "default_full_power.json"
    path.write_text(json.dumps(stored))
    out = opt.refresh_rules("default_full_power", tmp_path)
    edf = out["policies"]["edf"]
    np.testing.assert_allclose(edf["daily_profit"], fresh["edf"]["daily_profit"], rtol=1e-6)
    assert edf["vs_always_max"]["mean"] == pytest.approx(
        float(np.mean(fresh["edf"]["daily_profit"] - am)), abs=1e-3
    )
    assert edf["headroom"]["fraction"] == pytest.approx(
        float(np.mean(fresh["edf"]["daily_profit"] - am)) / 10.0, rel=1e-4
    )
    assert out["policies"]["mpc"] == mpc and out["policies"]["lp_bound"] == {
        "daily_profit": bound,
        **shown,
    }
    assert json.loads(path.read_text())["policies"]["edf"]["mean_eur"] == pytest.approx(
        edf["mean_eur"]
    )
    assert (tmp_path / "default_full_power.png").stat().st_size > 0
    stored["policies"]["always_max"]["daily_profit"][0] += 5.0
    path.write_text(json.dumps(stored))
    with pytest.raises(ValueError, match="always_max replayed"):
        opt.refresh_rules("default_full_power", tmp_path)
    path.write_text(json.dumps({**stored, "params_fingerprint": "other"}))
    with pytest.raises(ValueError, match="other params or days"):
        opt.refresh_rules("default_full_power", tmp_path)


# --- the vectorised builder and the warm start against straightforward solves -----------


@pytest.mark.parametrize(
    "kw",
    [
        {},
        {"refund_discharged_energy": False},
        {"constraint_mode": "soft"},
        {"peak_demand_eur_kw": 0.2},
    ],
)
def test_the_vectorised_lp_equals_a_straightforward_build(kw):
    # the hindsight LP of a 3-hour window (V2G cars, a battery, shared EVSEs, cars that
    # leave charged): the same optimum as every row written out one session and step at a
    # time and solved by SciPy's linprog
    params = make_params(
        station_kwargs={"num_dc": 4, "num_ac": 2},
        traffic="high",
        battery_initial_soc=(0.2, 0.8),
        v2g=True,
        **kw,
    )
    tr = trace.make_traces(params, np.array([10]), KEY)
    tr = trace.day_of(tr, 0)
    occ = optimal.occupancy(params, tr, KEY)
    num_steps = 36
    sessions = model_module.Sessions.concat(
        [
            milp_module.restrict(occ.sessions, num_steps),
            bound_module.battery_sessions(params, tr.battery_soc0, 0, num_steps - 1),
        ]
    )
    limits = model_module.StationLimits.of(params)
    econ = bound_module.economics(params, tr, 0, num_steps - 1)
    tol = float(params.charged_tolerance_kwh)
    urgency = np.where(sessions.charge_sensitive, 0.1, 0.0)
    for urg in (None, urgency):
        fast = model_module.build_and_solve(
            sessions, num_steps, limits, econ, charged_tolerance_kwh=tol, urgency_eur_kwh_h=urg
        )
        ref = reference_value_eur(sessions, num_steps, limits, econ, tol, urg)
        assert fast.value_eur == pytest.approx(ref, rel=1e-7, abs=1e-7)


def test_a_warm_started_mpc_solve_has_the_value_of_a_cold_one(mpc_day):
    # the MPC's LPs along a day, each started from the previous step's basis, reach the
    # optimum a solve from scratch reaches
    mpc, _, seen = mpc_day
    basis, warm_solves = None, 0
    for s in seen[60:160]:
        t = int(s["timestep"])
        n = min(mpc.horizon_steps, mpc.num_steps - t)
        econ = model_module.Economics(
            buy=mpc.buy[int(s["day"]), t : t + n],
            sell=mpc.sell[int(s["day"]), t : t + n],
            customer=mpc.customer,
            battery_value=float(mpc.battery_value[int(s["day"])]),
            step_hours=mpc.step_hours,
            peak_so_far_kw=float(s["peak_grid_kw"]),
        )
        sessions = mpc._sessions(s, n)
        urgency = np.where(sessions.charge_sensitive, mpc.urgency_eur_kwh_h, 0.0)
        args = (sessions, n, mpc.limits, econ)
        cold = model_module.build_and_solve(*args, urgency_eur_kwh_h=urgency)
        warm = model_module.build_and_solve(
            *args, urgency_eur_kwh_h=urgency, step_offset=t, warm_start=basis, keep_basis=True
        )
        warm_solves += basis is not None
        basis = warm.basis
        assert warm.value_eur == pytest.approx(cold.value_eur, rel=1e-7, abs=1e-7)
    assert warm_solves >= 99


def test_a_warm_start_with_a_foreign_builder_is_refused():
    params = hand_params(ONE_PORT, [0.2] * 24, step_minutes=60.0)
    with pytest.raises(ValueError, match="builder"):
        model_module.build_and_solve(
            bound_module.battery_sessions(params, np.zeros(0), 0, 1),
            2,
            model_module.StationLimits.of(params),
            model_module.Economics(
                buy=np.ones(2), sell=np.ones(2), customer=0.5, battery_value=0.1, step_hours=1.0
            ),
            builder=model_module._Builder(),
            keep_basis=True,
        )


def test_the_mpc_callback_hands_the_host_every_field_exactly():
    # the fields travel packed in one array; each must arrive with its own dtype and value,
    # for one state and for each state of a vmapped batch (an empty batch asks for nothing)
    params = hand_params(ONE_PORT, [0.2] * 24, step_minutes=60.0)
    state = simulator.empty_state(jnp.asarray(3), params).replace(timestep=jnp.asarray(7))
    state = place_car(state, 0, soc=0.2345678, remaining_kwh=20.0, time_min=187.5)
    state = state.replace(totals=state.totals.replace(peak_grid_kw=jnp.float32(12.345679)))
    other = place_car(state.replace(day=jnp.asarray(4)), 0, soc=0.7, remaining_kwh=5.0)
    mpc = MPC(params)
    seen = []

    def record(*arrays, slot):
        seen.append((slot, arrays))
        return np.zeros(mpc.num_leaves, np.int32)

    mpc.host_act = record
    jax.block_until_ready(jax.jit(lambda s: mpc(s, KEY, params))(state))
    batch = jax.tree.map(lambda a, b: jnp.stack([a, b]), state, other)
    jax.block_until_ready(jax.jit(jax.vmap(lambda s: mpc(s, KEY, params)))(batch))
    empty = jax.tree.map(lambda a: a[:0], batch)
    none = jax.jit(jax.vmap(lambda s: mpc(s, KEY, params)))(empty)
    assert none.shape == (0, mpc.num_leaves)
    assert [slot for slot, _ in seen] == [0, 0, 1]  # each state under its place in the batch
    for (_, arrays), s in zip(seen, [state, state, other]):
        for name, got in zip(mpc_module._FIELDS, arrays):
            want = np.asarray(s.totals.peak_grid_kw if name == "peak_grid_kw" else getattr(s, name))
            assert got.dtype == want.dtype and got.shape == want.shape, name
            np.testing.assert_array_equal(got, want, err_msg=name)


def _scipy_csc(rows, cols, vals, shape):
    a = scipy.sparse.csc_array((vals, (rows, cols)), shape=shape)
    a.sum_duplicates()
    return a.indptr, a.indices, a.data


@settings(max_examples=60, deadline=None)
@given(
    shape=st.tuples(st.integers(1, 7), st.integers(1, 7)),
    entries=st.lists(
        st.tuples(st.integers(0, 6), st.integers(0, 6), st.floats(-1e3, 1e3)), max_size=40
    ),
    blocks=st.integers(1, 4),
)
def test_the_builder_hands_highs_the_matrix_scipy_builds(shape, entries, blocks):
    # the coefficients given in blocks, in any order and with repeats, become the CSC matrix
    # SciPy makes of them (rows sorted within each column, repeats summed)
    m, n = shape
    entries = [(r % m, c % n, v) for r, c, v in entries]
    b = model_module._Builder()
    b.vars(n, 0.0, 1.0)
    b.new_rows(m, 0.0, 1.0)
    for part in np.array_split(np.arange(len(entries)), blocks):
        b.coef(
            np.array([entries[i][0] for i in part], np.int64),
            np.array([entries[i][1] for i in part], np.int64),
            np.array([entries[i][2] for i in part], np.float64),
        )
    rows = np.array([e[0] for e in entries], np.int64)
    cols = np.array([e[1] for e in entries], np.int64)
    vals = np.array([e[2] for e in entries], np.float64)
    for got, want in zip(b.matrix(), _scipy_csc(rows, cols, vals, (m, n))):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_each_env_of_a_batch_warm_starts_from_its_own_previous_solve(monkeypatch):
    # two car draws of one day, played together and alone: each env's solves after its first
    # start from its own previous basis, so it decides the same either way (the env's float32
    # sums may round by an ulp between a batch of two and of one)
    params = make_params(station=three_level_station(), traffic=150.0, step_minutes=60.0)
    keys = jax.random.split(KEY, 2)[None]  # (1 day, 2 draws, 2)
    real = mpc_module.build_and_solve
    cold = []

    def spy(*args, **kwargs):
        cold.append(kwargs.get("warm_start") is None)
        return real(*args, **kwargs)

    monkeypatch.setattr(mpc_module, "build_and_solve", spy)
    together = protocol.play(MPC(params), params, np.array([3]), keys)
    assert sum(cold) == 2 and len(cold) == 2 * params.num_steps  # one cold start per env
    alone = [protocol.play(MPC(params), params, np.array([3]), keys[:, r : r + 1]) for r in (0, 1)]
    for both, *each in zip(*map(jax.tree.leaves, [together, *alone])):
        np.testing.assert_allclose(both, np.concatenate(each, axis=1), rtol=1e-6, atol=1e-5)


def test_make_optimal_s_scenarios_are_the_params_of_its_stored_results():
    # its references are of the paper's session model (where the occupancy bound holds); a
    # scenario that resolved to the default v2 model would be another model than they state
    import json
    from pathlib import Path

    from baselines.analysis import references as opt

    root = Path(__file__).resolve().parents[2] / "results" / "optimal"
    for name in opt.SCENARIOS:
        stored = json.loads((root / f"{name}.json").read_text())["params_fingerprint"]
        params, _ = opt.scenario_params(name)
        assert trace.params_fingerprint(params) == stored, name
        assert trace.is_paper_session_model(params), name


@pytest.mark.parametrize(
    "field, value",
    [
        ("resolve_every", 1.5),
        ("resolve_every", 0),
        ("resolve_every", True),
        ("deadline_margin_steps", -1),
        ("deadline_margin_steps", 0.5),
    ],
)
def test_the_mpc_refuses_a_step_count_that_is_not_a_whole_number(field, value):
    # a fractional count was truncated silently (1.5 re-solved every step)
    params = hand_params(ONE_PORT, [0.1] * 24)
    with pytest.raises(ValueError, match=f"field '{field}' must be an integer >= "):
        MPC(params, **{field: value})
    assert MPC(params, resolve_every=2.0).resolve_every == 2


def test_the_v3_occupancy_bound_is_reached_on_a_hand_made_day():
    """Under fixed departures the occupancy is every policy's, and the LP's optimum is known:
    expensive hours 0-11 (0.25 EUR/kWh), cheap hours 12-23 (0.05). An AC user parked all day
    takes 18 kWh; a DC user arriving for 11:00 takes 20 kWh at 50 kW (24 min, 5 steps) and
    stays 60 min more, to 12:25: its five steps from 12:00 (20.8 kWh at full power) hold the
    whole charge. The optimum buys all 38 kWh at 0.05: 38 * (0.75 - 0.05) = 26.6 EUR, and
    the policy that waits for 12:00 and then charges at full power reaches it."""
    station = Splitter(
        "grid",
        1000.0,
        (Port("dc0", "DC", 500.0, 100.0), Port("ac0", "AC", 400.0, 25.0)),
    )
    prices = np.asarray([0.25] * 12 + [0.05] * 12, np.float32)
    params = make_params(
        station=station,
        prices=prices,
        session_model="v3",
        grid_fee_eur_kwh=0.0,
        fixed_cost_eur=0.0,
        battery_terminal_price=None,
    )
    common = dict(capacity_kwh=60.0, arrival_soc=0.2, tau=0.99, ac_kw=11.0, dc_kw=50.0)
    cars = [
        dict(arrival_step=0, wants_dc=False, stay_min=1400.0, target_soc=0.5, **common),
        dict(arrival_step=131, wants_dc=True, margin_min=60.0, target_soc=0.2 + 20 / 60, **common),
    ]
    day = trace.trace_from_cars(params, cars)
    key = jax.random.PRNGKey(0)
    occ = bound_module.occupancy(params, day, key)
    bound = bound_module.hindsight_bound(params, day, occ)
    assert bound.profit_eur == pytest.approx(26.6, abs=1e-3)

    def wait_for_noon(state, _key):
        full = policies.always_max(state, _key, params)
        return jnp.where(state.timestep >= 144, full, 0)

    for act, expected in (
        (wait_for_noon, 26.6),
        (lambda s, k: policies.always_max(s, k, params), None),
    ):
        states, infos, _ = trace.replay(act, params, day, key)
        profit = float(np.asarray(infos.profit_eur, np.float64).sum())
        assert profit <= bound.profit_eur + 1e-3
        if expected is not None:
            assert profit == pytest.approx(expected, abs=0.01)
    # always-max buys the AC car's energy at 0.25 and the DC car's before noon
    assert profit < 26.6 - 5.0
    assert occ.reference_profit_eur == pytest.approx(profit, abs=1e-3)


@pytest.mark.parametrize("limit", [-1, 0, float("nan"), float("inf")])
def test_the_solvers_refuse_a_time_limit_that_is_no_limit(limit):
    """-1, 0, NaN and inf reached HiGHS, which then solved without a limit: every entry point
    refuses them before it builds anything."""
    params = make_params(station=three_level_station(), step_minutes=60.0)
    days = np.array([0])
    match = r"field 'time_limit_s' must be a finite number > 0 s"
    for solve in (
        lambda: evaluation.hindsight_bound(params, days, time_limit_s=limit),
        lambda: evaluation.policy_bound(params, days, time_limit_s=limit),
        lambda: optimal.pooled_bound_days(params, days, None, time_limit_s=limit),
        lambda: bound_module.bound_days(params, days, time_limit_s=limit),
        lambda: model_module.new_highs(limit),
        lambda: MPC(params, time_limit_s=limit),
    ):
        with pytest.raises(ValueError, match=match):
            solve()
