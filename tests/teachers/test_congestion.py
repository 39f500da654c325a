"""The coupled plan (`chargax_marl.teachers.congestion`): the parked cars planned together under
the node limits, its congestion prices, the rule that plays it and its wrappers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import linprog

from chargax_marl.core import Port, Splitter, make_params, simulator
from chargax_marl.marl import ChargaxMARL
from chargax_marl.policies import get_policy
from chargax_marl.single import Chargax
from chargax_marl.teachers import car_plan, congestion
from chargax_marl.teachers.storage_value import step_buy_prices
from chargax_marl.wrappers import CoupledPlanAdviceObservation, CoupledPlanShaping
from tests.helpers import no_arrivals, place_car

EXACT_LP = {
    "iterations": 3000,
    "delay_cost_eur_kwh": 0.0,
    "power_fraction": 1.0,
    "future_reserve": 0.0,
}
"""Plan settings that make the plan the LP's solution: no tie-breaking cost, no reserve."""


def _station(grid_kw: float, port_kw=(50.0, 50.0, 50.0)) -> Splitter:
    """One node over DC ports of ``port_kw`` (500 V, lossless)."""
    ports = tuple(Port(f"p{i}", "DC", 500.0, kw * 2.0, 0.0, 1.0) for i, kw in enumerate(port_kw))
    return Splitter("grid", grid_kw, ports)


def _params(root: Splitter, **kwargs):
    return no_arrivals(make_params(station=root, step_minutes=60.0, **kwargs))


PRICED_DAY = 19
"""A day of the bundled prices whose steps 8 to 11 differ by more than 0.01 EUR/kWh each."""


def _parked(params, cars, t: int = 8):
    """An empty station at step ``t`` of day `PRICED_DAY` with ``cars`` = ``[(remaining_kwh, time_min,
    max_rate_kw), ...]`` on ports 0, 1, ..."""
    s = simulator.empty_state(PRICED_DAY, params, jax.random.PRNGKey(0))
    s = s.replace(timestep=jnp.int32(t))
    for i, (need, minutes, rate) in enumerate(cars):
        s = place_car(
            s,
            i,
            soc=0.2,
            capacity_kwh=1000.0,
            max_rate_kw=rate,
            remaining_kwh=need,
            time_min=minutes,
            target_soc=0.2 + need / 1000.0,
        )
    return s


def test_a_connection_for_two_cars_of_three_moves_the_third_car_to_other_steps():
    """Three cars that each want two steps at full power (50 kW) and stay four, under a 100 kW
    connection: planned alone, each takes the stay's two cheapest steps, 150 kW in each; planned
    together, no step passes 100 kW, every car still gets its demand, and some charging moves
    to a dearer step."""
    params = _params(_station(100.0))
    state = _parked(params, [(100.0, 240.0, 50.0)] * 3)
    plan = jax.jit(congestion.coupled_plan(params, **EXACT_LP))(state)
    energy = np.asarray(plan.energy_kwh)[:3, :4]
    alone = np.asarray(
        car_plan.plan_energy(
            jnp.arange(4) + 8, 8, jnp.full(3, 4.0), jnp.full(3, 100.0), jnp.full(3, 50.0)
        )
    )
    assert alone.sum(axis=0).max() == pytest.approx(150.0)  # the solo plans pile up
    assert energy.sum(axis=0).max() <= 100.0 + 0.05
    np.testing.assert_allclose(energy.sum(axis=1), 100.0, atol=0.05)
    buy = np.asarray(step_buy_prices(params))[PRICED_DAY, 8:12]
    assert np.diff(np.sort(buy)).min() > 0.01
    cheapest_two = np.argsort(buy, kind="stable")[:2]
    dearer = np.setdiff1d(np.arange(4), cheapest_two)
    assert energy[:, dearer].sum() == pytest.approx(100.0, abs=0.1)
    # the congestion price is positive in the cheap steps the node fills
    assert float(np.asarray(plan.node_prices_eur_kwh)[0, cheapest_two].min()) > 0.0


def _lp_optimum(plan, node_factor, node_cap_kwh) -> float:
    """HiGHS on the plan's own LP: margins, caps, demands, one node row per step."""
    m, u, need = (
        np.asarray(x, np.float64) for x in (plan.margin_eur_kwh, plan.cap_kwh, plan.need_kwh)
    )
    cars, steps = m.shape
    need_rows = np.kron(np.eye(cars), np.ones(steps))
    node_rows = np.kron(node_factor[None, :], np.eye(steps))
    res = linprog(
        -m.ravel(),
        A_ub=np.vstack([need_rows, node_rows]),
        b_ub=np.concatenate([need, np.full(steps, node_cap_kwh)]),
        bounds=list(zip(np.zeros(u.size), u.ravel())),
        method="highs",
    )
    assert res.status == 0
    return -float(res.fun)


def test_on_one_node_the_plan_is_the_lp_optimum():
    """Cars of different powers, demands and stays under one 60 kW node: the plan's value
    equals HiGHS's optimum of the same LP, and the plan keeps the node's limit and each car's
    demand and cap."""
    params = _params(_station(60.0, (50.0, 22.0, 11.0)))
    state = _parked(params, [(120.0, 300.0, 50.0), (60.0, 180.0, 22.0), (30.0, 420.0, 11.0)])
    plan = jax.jit(congestion.coupled_plan(params, horizon_steps=8, **EXACT_LP))(state)
    x = np.asarray(plan.energy_kwh, np.float64)
    best = _lp_optimum(plan, np.ones(3), 60.0)
    got = float(np.sum(np.asarray(plan.margin_eur_kwh) * x))
    assert got == pytest.approx(best, rel=1e-3)
    assert x.sum(axis=0).max() <= 60.0 * (1 + 1e-3)
    assert np.all(x.sum(axis=1) <= np.asarray(plan.need_kwh) + 1e-2)
    assert np.all(x <= np.asarray(plan.cap_kwh) + 1e-4)


def test_the_rule_is_the_same_under_jit_and_never_asks_a_node_for_more_than_its_limit():
    """A tight station (the connection at a quarter of the ports' power) over a day with
    arrivals: the rule's levels under jit equal its eager levels, and no step's requested
    currents exceed any node's limit."""
    params = make_params(
        station="single_type",
        station_kwargs={"num_ports": 4, "battery": True},
        step_minutes=60.0,
        grid_fraction=0.25,
    )
    act = get_policy("coupled_plan", params)
    state = place_car(simulator.reset(jax.random.PRNGKey(3), params), 0, time_min=180.0)
    state = place_car(state, 1, time_min=120.0, remaining_kwh=40.0)
    eager = np.asarray(act(state, None, params))
    jitted = jax.jit(lambda s: act(s, None, params))
    np.testing.assert_array_equal(np.asarray(jitted(state)), eager)
    assert eager[:2].max() > 0

    def body(s, k):
        s2, info = simulator.step(k, s, act(s, k, params), params)
        return s2, (info.requested_excess_kw, info.energy_delivered_kwh)

    _, (excess, delivered) = jax.jit(
        lambda k: jax.lax.scan(body, state, jax.random.split(k, int(params.num_steps)))
    )(jax.random.PRNGKey(4))
    assert float(np.max(np.asarray(excess))) <= 1e-3
    assert float(np.sum(np.asarray(delivered))) > 0.0


@pytest.mark.parametrize("w", [1.0, 0.5])
def test_marl_shaping_terms_add_up_to_the_station_s_term(w):
    """The shaping wrapper in either view: the gymnax reward gains the ports' terms' sum; in the
    JaxMARL view each agent gains ``(1 - w) * sum + w * own``, so at ``w = 1`` the agents'
    shaped rewards add up to their rewards plus the station's term."""
    params = _params(_station(60.0, (50.0, 22.0, 11.0)))
    state = _parked(params, [(120.0, 300.0, 50.0), (60.0, 180.0, 22.0), (30.0, 420.0, 11.0)])
    key = jax.random.PRNGKey(1)
    base = ChargaxMARL(params=params, local_reward_weight=w)
    env = CoupledPlanShaping(base, iterations=200)
    actions = {a: jnp.int32(base.num_actions - 1) for a in base.agents}
    _, _, raw, _, _ = base.step(key, state, actions)
    _, _, shaped, _, infos = env.step(key, state, actions)
    own = np.asarray(
        congestion.coupled_potential(params, iterations=200)(state)(infos["agent_energy_kwh"])
    )
    terms = np.asarray(infos["car_plan_shaping_eur"])
    np.testing.assert_allclose(terms, (1 - w) * own.sum() + w * own, rtol=1e-5, atol=1e-6)
    diff = np.array([float(shaped[a] - raw[a]) for a in base.agents])
    np.testing.assert_allclose(diff, terms, rtol=1e-5, atol=1e-6)
    if w == 1.0:
        assert float(diff.sum()) == pytest.approx(float(own.sum()), abs=1e-5)
    assert np.abs(own).max() > 1e-3
    single = Chargax(params=params)
    wrapped = CoupledPlanShaping(single, iterations=200)
    levels = jnp.full(params.station.num_leaves, params.num_levels, jnp.int32)
    action = single.levels_to_action(levels, params)
    _, _, r0, *_ = single.step(key, state, action, params)
    _, _, r1, _, _, info = wrapped.step(key, state, action, params)
    term = float(
        congestion.coupled_potential(params, iterations=200)(state)(info["leaf_energy_kwh"]).sum()
    )
    assert float(r1 - r0) == pytest.approx(term, abs=1e-5)
    assert float(info["car_plan_shaping_eur"]) == pytest.approx(term, abs=1e-5)


def test_advice_observation_columns_are_the_plan_now_in_both_views():
    """Two columns per agent (JaxMARL) or ``2 L`` (gymnax): the share of the port's power the
    plan takes now and the congestion price on its path; the spaces grow with them."""
    params = _params(_station(60.0, (50.0, 22.0, 11.0)))
    state = _parked(params, [(120.0, 300.0, 50.0), (60.0, 180.0, 22.0)])
    advice = np.asarray(congestion.coupled_advice(params, iterations=200)(state))
    assert advice.shape == (3, 2)
    assert 0.0 < advice[0, 0] <= 1.0 and advice[2].tolist() == [0.0, 0.0]
    marl = ChargaxMARL(params=params)
    env = CoupledPlanAdviceObservation(marl, iterations=200)
    assert env.obs_size == marl.obs_size + 2
    obs = env.get_obs(state)
    np.testing.assert_allclose(np.asarray(obs[marl.agents[0]])[-2:], advice[0], rtol=1e-6)
    single = CoupledPlanAdviceObservation(Chargax(params=params), iterations=200)
    flat = np.asarray(single.get_obs(state, params))
    np.testing.assert_allclose(flat[-6:], advice.T.reshape(-1), rtol=1e-6)


def test_bad_settings_name_the_field():
    params = _params(_station(60.0))
    with pytest.raises(ValueError, match="power_fraction"):
        congestion.coupled_plan(params, power_fraction=0.0)
    with pytest.raises(ValueError, match="future_reserve"):
        congestion.coupled_plan(params, future_reserve=1.0)
    with pytest.raises(ValueError, match="iterations"):
        congestion.coupled_plan(params, iterations=0)
    with pytest.raises(ValueError, match="battery"):
        congestion.coupled_plan_action(params, battery="max")
