"""The port-pooled bound: hand-computed optima and the bound above every policy's profit and
every occupancy's LP, on both session models."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from chargax_marl import optimal, policies, trace
from chargax_marl.benchmark import references as references_module
from chargax_marl.benchmark.tasks import Task, get_task
from chargax_marl.core.params import make_params
from chargax_marl.core.station import Port, Splitter
from chargax_marl.optimal import model as model_module
from chargax_marl.optimal.pooled import pooled_bound, pooled_limits, pooled_sessions, port_groups
from tests.helpers import hand_params

KEY = jax.random.PRNGKey(0)
ONE_PORT = Splitter("grid", 1000.0, (Port("p0", "DC", 500.0, 100.0),))  # 50 kW


CAR = dict(capacity_kwh=100.0, dc_kw=50.0, tau=0.99, arrival_soc=0.2)


def test_the_bound_turns_away_a_car_that_would_block_a_better_one():
    # one port; car A (5 kWh, stays 2 h) arrives first and blocks car B (30 kWh, 1 h) ten
    # minutes later. Either A (5 * 0.65 = 3.25 EUR) or B (30 * 0.65 = 19.5 EUR) holds the port;
    # half of each would be 11.4 EUR: a share of a port carries that share of a car's energy
    params = hand_params(ONE_PORT)
    tr = trace.trace_from_cars(
        params,
        [
            dict(CAR, arrival_step=0, target_soc=0.25, stay_min=120.0),
            dict(CAR, arrival_step=2, target_soc=0.5, stay_min=60.0),
        ],
    )
    b = pooled_bound(params, tr)
    assert b.status == "optimal" and b.num_cars == 2
    assert b.profit_eur == pytest.approx(19.5, abs=1e-4)
    # always-max's occupancy keeps A, so its LP is 3.25: the pooled bound is above it
    occ = optimal.occupancy(params, tr, KEY)
    assert optimal.hindsight_bound(params, tr, occ).profit_eur == pytest.approx(3.25, abs=1e-4)


@pytest.mark.parametrize(("sensitive", "expected_eur"), [(True, 2 * 25 * 0.65), (False, 25 * 0.65)])
def test_a_car_that_leaves_when_charged_frees_its_port_one_that_stays_holds_it(
    sensitive, expected_eur
):
    # one 50 kW port, two cars of 25 kWh each staying 2 h, the second 5 minutes after the
    # first. Leaving when charged, the first is done in 30 minutes and the second takes the
    # port after it (both served); staying, the first holds the port for its 2 h
    params = hand_params(ONE_PORT)
    car = dict(CAR, target_soc=0.45, stay_min=120.0, charge_sensitive=sensitive)
    tr = trace.trace_from_cars(params, [dict(car, arrival_step=0), dict(car, arrival_step=1)])
    assert pooled_bound(params, tr).profit_eur == pytest.approx(expected_eur, abs=1e-4)


def test_a_car_split_over_port_groups_takes_its_energy_once():
    # a 50 kW DC port and an 11 kW AC port; one car wants 40 kWh in 1 h: 50 kW alone would
    # give it all (26 EUR), and it cannot take more than 40 kWh from both together
    station = Splitter(
        "grid", 1000.0, (Port("dc", "DC", 500.0, 100.0), Port("ac", "AC", 230.0, 48.0))
    )
    params = hand_params(station)
    tr = trace.trace_from_cars(
        params, [dict(CAR, arrival_step=0, target_soc=0.6, stay_min=60.0, ac_kw=11.0)]
    )
    assert port_groups(params)[2].tolist() == [1, 1]
    assert pooled_bound(params, tr).profit_eur == pytest.approx(40 * 0.65, abs=1e-4)


def test_alike_sibling_nodes_merge_into_one_group_with_their_summed_limit():
    params = get_task("Chargax-shopping-v1").make_params()
    group_of_port, first_port, group_ports = port_groups(params)
    kind = np.asarray(params.station.leaf_kind)[: params.station.num_ports]
    assert sorted(group_ports.tolist()) == [int((kind == 0).sum()), int((kind == 1).sum())]
    assert all(len(set(kind[group_of_port == g])) == 1 for g in range(len(group_ports)))
    lim, merged = model_module.StationLimits.of(params), pooled_limits(params)
    for g, port in enumerate(first_port):
        ports = np.nonzero(group_of_port == g)[0]
        for d in range(lim.node_at_depth.shape[0]):
            nodes = np.unique(lim.node_at_depth[d, ports])
            # the merged node holds the sum of the limits of the nodes it stands for
            assert merged.node_max_kw[merged.node_at_depth[d, port]] == pytest.approx(
                lim.node_max_kw[nodes].sum()
            )


@pytest.fixture(scope="module", params=["paper", "v2"])
def drawn_day(request):
    """A busy day on a small station, its trace and its pooled bound, per session model (in
    15-minute steps, which keep the LPs small)."""
    params = make_params(
        station_kwargs={"num_dc": 4, "num_ac": 2},
        traffic="high",
        step_minutes=15.0,
        battery_initial_soc=(0.2, 0.8),
        session_model=request.param,
    )
    tr = trace.day_of(trace.make_traces(params, np.array([200]), KEY), 0)
    return params, tr, pooled_bound(params, tr).profit_eur


@pytest.mark.parametrize("name", ["always_max", "edf"])
def test_the_bound_is_above_every_policy_and_every_occupancy_s_lp(drawn_day, name):
    params, tr, pooled = drawn_day
    occ = optimal.occupancy(params, tr, KEY, policies.get_policy(name, params))
    lp = optimal.hindsight_bound(params, tr, occ).profit_eur
    tol = 1e-3 * abs(lp) + 1e-3
    assert lp >= occ.reference_profit_eur - tol
    assert pooled >= lp - tol


def test_pooled_sessions_offer_each_car_at_each_group_with_the_user_type_of_its_kind(drawn_day):
    params, tr, _ = drawn_day
    sessions, pools, num_cars = pooled_sessions(params, tr)
    num_groups = port_groups(params)[2].size
    assert sessions.size == num_cars * num_groups == pools.car.size
    assert np.array_equal(np.bincount(pools.car), np.full(num_cars, num_groups))
    assert num_cars == int(np.minimum(np.asarray(tr.arrivals.requested)[:-1], 6).sum())
    assert not sessions.must_reach.any()
    np.testing.assert_array_equal(pools.holds, ~sessions.charge_sensitive)


def test_pools_refuse_a_car_of_two_first_steps_and_a_warm_start():
    params = hand_params(ONE_PORT)
    tr = trace.trace_from_cars(params, [dict(CAR, arrival_step=0, target_soc=0.5, stay_min=60.0)])
    sessions, pools, _ = pooled_sessions(params, tr)
    two = model_module.Sessions.concat([sessions, sessions])
    two.first[1] += 1
    pools2 = model_module.Pools(
        car=np.zeros(2, int), group=np.zeros(2, int), holds=np.ones(2, bool), group_ports=[1]
    )
    limits, econ = pooled_limits(params), optimal.bound.economics(params, tr)
    with pytest.raises(ValueError, match="pools.car"):
        model_module.build_and_solve(two, tr.num_steps, limits, econ, pools=pools2)
    with pytest.raises(ValueError, match="pools"):
        model_module.build_and_solve(
            sessions, tr.num_steps, limits, econ, pools=pools, keep_basis=True
        )


def test_a_task_names_its_bound_and_its_references_must_hold_it(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="field 'bound'"):
        Task("x", 2, "shopping", 2, "d", bound="tight")
    assert {t.bound for t in [get_task("Chargax-shopping-v1")]} == {"occupancy"}
    task = dataclasses.replace(get_task("Chargax-shopping-v1"), version=9, bound="pooled")
    refs = references_module.compute_references(
        task, rules=("always_max",), bound=False, day_index=[0], log=None
    )
    refs["days"] = [int(d) for d in task.eval_days()]
    refs["policies"]["lp_bound"] = {"daily_profit": [[1.0, 1.0]], "kind": "occupancy"}
    references_module.save_references(refs, tmp_path)
    with pytest.raises(references_module.ReferenceMismatchError, match="'pooled' bound"):
        references_module.load_references(task, tmp_path)
