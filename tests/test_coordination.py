"""Scenarios where the agents must coordinate: a constrained grid connection
(``grid_fraction``), a time-of-use surcharge and a peak-demand charge in the profit, the LP
bound and MPC pricing them, the context features the agents need, the named scenarios in
both views, and the node-binding table."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from baselines.config import build_env_params, resolve
from chargax_marl import binding, optimal, policies
from chargax_marl import trace as trace_lib
from chargax_marl.core import observation, simulator, tariffs
from chargax_marl.core import reward as reward_lib
from chargax_marl.core.params import make_params
from chargax_marl.core.scenarios import COORDINATION_SCENARIOS, SCENARIOS
from chargax_marl.core.station import Port, Splitter
from chargax_marl.marl import ChargaxMARL
from chargax_marl.optimal.model import Economics, Sessions, StationLimits, build_and_solve
from chargax_marl.single import make
from tests.helpers import no_arrivals, place_car, start

KEY = jax.random.PRNGKey(0)
DEFAULT_ROOT_CHILDREN_KW = 750.0 + 34.5 + 100.0  # DC cable + AC cable + battery of multiple_types


def one_port_station(port_kw=50.0, root_kw=1000.0):
    port = Port(
        "p0", kind="DC", voltage_v=500.0, max_current_a=port_kw * 2.0, max_discharge_current_a=0.0
    )
    return Splitter("grid", max_kw=root_kw, children=(port,), efficiency=1.0)


def flat_params(station, price=0.10, **kw):
    prices = np.full((2, 24), price, np.float32)
    return make_params(
        station=station,
        prices=prices,
        grid_fee_eur_kwh=0.0,
        fixed_cost_eur=0.0,
        customer_price_eur_kwh=0.75,
        **kw,
    )


# --------------------------------------------------------------------------- grid fraction


def test_grid_fraction_sets_the_root_to_a_fraction_of_its_children():
    for f in (0.1, 0.25, 1.0):
        p = make_params(grid_fraction=f)
        assert float(p.station.node_max_kw[0]) == pytest.approx(
            f * DEFAULT_ROOT_CHILDREN_KW, rel=1e-6
        )
        np.testing.assert_array_equal(
            np.asarray(p.station.node_max_kw[1:]), np.asarray(make_params().station.node_max_kw[1:])
        )
    # a custom tree: the root's children are one 50 kW port
    p = make_params(station=one_port_station(), grid_fraction=0.5)
    assert float(p.station.node_max_kw[0]) == pytest.approx(25.0)
    # the leaf can take no more than the root allows alone
    assert float(p.station.leaf_solo_max_kw[0]) == pytest.approx(25.0)


@pytest.mark.parametrize("bad", [0.0, -0.1, 1.5, float("nan"), "half", True])
def test_grid_fraction_out_of_range_names_the_field(bad):
    with pytest.raises(ValueError, match="grid_fraction"):
        make_params(grid_fraction=bad)


def test_grid_fraction_and_grid_kw_together_are_refused():
    with pytest.raises(ValueError, match="grid_fraction.*grid_kw"):
        make_params(grid_fraction=0.5, station_kwargs={"grid_kw": 300.0})
    with pytest.raises(ValueError, match="grid_fraction"):
        make_params(station=make_params().station, grid_fraction=0.5)


# --------------------------------------------------------------------------- time of use


def test_tou_surcharge_is_added_to_the_buy_price_by_hour():
    p = make_params(tou_fee_eur_kwh="evening-peak")
    spot = np.asarray(p.prices_eur_kwh)
    fee = float(p.grid_fee_eur_kwh)
    for hour, extra in ((10, 0.0), (17, 0.12), (20, 0.12), (21, 0.0)):
        t = jnp.int32(hour * 12)
        buy, sell = reward_lib.grid_prices(jnp.int32(3), t, p)
        assert float(buy) == pytest.approx(spot[3, hour] + fee + extra, rel=1e-6)
        assert float(sell) == pytest.approx(spot[3, hour], rel=1e-6)  # feed-in is not surcharged
    # the observed prices are the buy-side prices less the flat grid fee
    ctx = np.asarray(
        observation.context_features(start(p, day=3).replace(timestep=jnp.int32(16 * 12)), p)
    )
    assert ctx[1] * observation.PRICE_SCALE_EUR_KWH == pytest.approx(spot[3, 17] + 0.12, rel=1e-5)
    # the battery's terminal value includes the day's mean surcharge
    mean_buy = spot[3].mean() + fee + 4 * 0.12 / 24
    assert float(reward_lib.day_mean_buy_price(jnp.int32(3), p)) == pytest.approx(
        mean_buy, rel=1e-5
    )


@pytest.mark.parametrize(
    "bad, match",
    [
        ("rush-hour", "evening-peak"),
        (np.zeros(23), r"shape \(24,\)"),
        ([0.0] * 23 + [float("nan")], r"tou_fee_eur_kwh\[23\]"),
        ([0.0] * 23 + [5e3], r"tou_fee_eur_kwh\[23\]"),
    ],
)
def test_bad_tou_surcharge_names_the_field(bad, match):
    with pytest.raises(ValueError, match=match):
        make_params(tou_fee_eur_kwh=bad)


# --------------------------------------------------------------------------- peak demand


def test_peak_charge_by_hand_booked_at_the_end_of_the_day():
    rate = 0.5
    p = no_arrivals(flat_params(one_port_station(), step_minutes=360.0, peak_demand_eur_kw=rate))
    assert p.num_steps == 4
    s = place_car(
        start(p),
        0,
        soc=0.0,
        capacity_kwh=1000.0,
        max_rate_kw=50.0,
        tau=1.0,
        remaining_kwh=1000.0,
        time_min=1440.0,
    )
    levels = [10, 4, 0, 2]  # 50 kW, 20 kW, idle, 10 kW for 6 hours each
    charges, profits = [], []
    for t, lv in enumerate(levels):
        s, info = simulator.step(jax.random.PRNGKey(t), s, jnp.array([lv]), p)
        charges.append(float(info.peak_demand_charge_eur))
        profits.append(float(info.profit_eur))
    assert charges == pytest.approx([0.0, 0.0, 0.0, rate * 50.0])
    assert float(s.totals.peak_grid_kw) == pytest.approx(50.0)
    # profit: (0.75 - 0.10) per kWh, 6 h at 50, 20, 0, 10 kW; the peak charge at the end
    assert profits == pytest.approx([0.65 * 300, 0.65 * 120, 0.0, 0.65 * 60 - 25.0], rel=1e-5)
    assert float(s.totals.peak_demand_charge_eur) == pytest.approx(25.0)


def test_incremental_booking_has_the_same_daily_total_and_shares_add_up():
    base = make_params(traffic="high", peak_demand_eur_kw=0.2)
    inc = make_params(traffic="high", peak_demand_eur_kw=0.2, peak_demand_booking="incremental")
    free = make_params(traffic="high")

    def day(p):
        def body(s, k):
            s, info = simulator.step(k, s, policies.battery_rule(s, None, p), p)
            return s, info

        return jax.lax.scan(
            body, simulator.empty_state(jnp.int32(10), p), jax.random.split(KEY, p.num_steps)
        )

    (end_b, info_b), (end_i, info_i), (end_f, _) = jax.jit(
        lambda: (day(base), day(inc), day(free))
    )()
    peak = float(np.max(np.maximum(np.asarray(info_b.grid_net_kwh), 0.0)) / base.step_hours)
    assert float(end_b.totals.peak_grid_kw) == pytest.approx(peak, rel=1e-5)
    assert float(end_b.totals.peak_demand_charge_eur) == pytest.approx(0.2 * peak, rel=1e-5)
    assert np.count_nonzero(np.asarray(info_b.peak_demand_charge_eur)) == 1
    assert float(end_i.totals.peak_demand_charge_eur) == pytest.approx(0.2 * peak, rel=1e-5)
    assert np.all(np.asarray(info_i.peak_demand_charge_eur) >= 0.0)
    assert np.count_nonzero(np.asarray(info_i.peak_demand_charge_eur)) > 1
    # the same cars and actions: the charge is the only difference in profit
    assert float(end_f.totals.profit_eur - end_b.totals.profit_eur) == pytest.approx(
        0.2 * peak, rel=1e-4
    )
    np.testing.assert_allclose(
        np.asarray(info_i.leaf_reward).sum(axis=1), np.asarray(info_i.reward), rtol=1e-5, atol=1e-3
    )


@pytest.mark.parametrize(
    "rate, booking, match",
    [
        (-1.0, "end_of_day", "peak_demand_eur_kw"),
        (float("inf"), "end_of_day", "peak_demand_eur_kw"),
        (0.1, "monthly", "peak_demand_booking"),
    ],
)
def test_bad_peak_settings_name_the_field(rate, booking, match):
    with pytest.raises(ValueError, match=match):
        make_params(peak_demand_eur_kw=rate, peak_demand_booking=booking)


def test_lp_prices_the_peak_by_hand():
    # one car, 30 kWh over one hour (12 five-minute steps), flat 0.10 EUR/kWh: the LP spreads the
    # charge to the lowest peak, 30 kW; the peak already paid for today is sunk
    p = flat_params(one_port_station())
    one = lambda v: np.asarray([v])  # noqa: E731
    sessions = Sessions(
        leaf=one(0),
        first=one(0),
        last=one(11),
        soc0=one(0.2),
        reserve_soc=one(0.2),
        target_soc=one(0.5),
        capacity_kwh=one(100.0),
        max_rate_kw=one(50.0),
        max_discharge_rate_kw=one(0.0),
        tau=one(1.0),
        must_reach=one(True),
        charge_sensitive=one(False),
    )
    limits = StationLimits.of(p)

    def value(**peak):
        econ = Economics(
            buy=np.full(12, 0.10),
            sell=np.full(12, 0.10),
            customer=0.75,
            battery_value=0.0,
            step_hours=p.step_hours,
            **peak,
        )
        return build_and_solve(sessions, 12, limits, econ).value_eur

    assert value() == pytest.approx(0.65 * 30.0, rel=1e-3)
    assert value(peak_eur_kw=0.5) == pytest.approx(0.65 * 30.0 - 0.5 * 30.0, rel=1e-3)
    assert value(peak_eur_kw=0.5, peak_so_far_kw=40.0) == pytest.approx(
        0.65 * 30.0 - 0.5 * 40.0, rel=1e-3
    )


def test_bound_is_above_the_policies_with_tou_and_peak_charge():
    p = make_params(
        station="multiple_types",
        station_kwargs={"num_dc": 4, "num_ac": 2},
        traffic="high",
        tou_fee_eur_kwh="evening-peak",
        peak_demand_eur_kw=0.3,
        grid_fraction=0.5,
    )
    traces = trace_lib.make_traces(p, np.array([4, 40]), KEY)
    for i in range(2):
        tr = trace_lib.day_of(traces, i)
        for pol in (policies.always_max, policies.battery_rule):
            occ = optimal.occupancy(p, tr, KEY, reference=pol)
            b = optimal.hindsight_bound(p, tr, occ)
            assert b.profit_eur >= occ.reference_profit_eur - 1e-3, (i, pol.__name__)


# --------------------------------------------------------------------------- observations


def test_context_features_for_coordination():
    p = make_params(tou_fee_eur_kwh="day-night", grid_fraction=0.5)
    h = p.price_horizon_hours + 1
    base = h + 1 + 2 + 1 + 1  # prices, customer, sin/cos, workday, day
    s = start(p, day=7)
    ctx = lambda st: np.asarray(observation.context_features(st, p))  # noqa: E731
    assert ctx(s)[base] == pytest.approx(1.0)  # a whole hour before the price changes
    assert ctx(s.replace(timestep=jnp.int32(6)))[base] == pytest.approx(0.5)
    q = np.quantile(
        np.asarray(p.prices_eur_kwh[7], np.float64) + np.asarray(p.tou_fee_eur_kwh),
        observation.PRICE_QUANTILES,
    )
    np.testing.assert_allclose(
        ctx(s)[base + 1 : base + 6] * observation.PRICE_SCALE_EUR_KWH, q, rtol=1e-5
    )
    # grid-connection load from the currents, and the day's peak so far, over the root's limit
    root = float(p.station.node_max_kw[0])
    s2 = place_car(s, 0, current_a=200.0)  # 100 kW at 500 V
    eta = float(p.station.leaf_path_efficiency[0])
    assert ctx(s2)[base + 6] == pytest.approx(100.0 / eta / root, rel=1e-5)
    s3 = s.replace(totals=s.totals.replace(peak_grid_kw=jnp.float32(200.0)))
    assert ctx(s3)[base + 7] == pytest.approx(200.0 / root, rel=1e-6)
    assert ctx(s).shape[0] == base + observation.EXTRA_CONTEXT


def test_observations_stay_in_their_bounds_on_a_peak_scenario():
    env, p = make("shopping-grid50-peak-high")
    space = env.observation_space(p)

    def body(carry, k):
        obs, s = carry
        k1, k2 = jax.random.split(k)
        obs, s, *_ = env.step(k2, s, env.action_space(p).sample(k1), p)
        return (obs, s), obs

    obs0, s0 = env.reset(KEY, p)
    _, all_obs = jax.jit(lambda: jax.lax.scan(body, (obs0, s0), jax.random.split(KEY, 300)))()
    all_obs = np.asarray(all_obs)
    assert np.all(all_obs >= space.low - 1e-6) and np.all(all_obs <= space.high + 1e-6)


# --------------------------------------------------------------------------- named scenarios


def test_named_scenarios_in_both_views():
    for name in COORDINATION_SCENARIOS:  # each makes the ports share a scarce or priced resource
        kw = SCENARIOS[name]
        assert kw.get("grid_fraction", 1.0) < 1.0 or kw.get("peak_demand_eur_kw", 0.0) > 0.0, name
    _, p = make("shopping-grid25-high")
    m = ChargaxMARL(scenario="shopping-grid25-high")
    assert float(m.params.station.node_max_kw[0]) == pytest.approx(float(p.station.node_max_kw[0]))
    assert float(m.params.arrival_rate.sum()) == pytest.approx(float(p.arrival_rate.sum()))
    _, peak = make("shopping-peak")
    assert float(peak.peak_demand_eur_kw) == pytest.approx(tariffs.DEFAULT_PEAK_DEMAND_EUR_KW)
    assert float(np.max(peak.tou_fee_eur_kwh)) == pytest.approx(0.12)
    over = ChargaxMARL(
        scenario="shopping-peak", peak_demand_eur_kw=0.3
    )  # keywords override the scenario
    assert float(over.params.peak_demand_eur_kw) == pytest.approx(0.3)
    with pytest.raises(KeyError, match="unknown scenario 'shopping-grid5'"):
        ChargaxMARL(scenario="shopping-grid5")
    with pytest.raises(ValueError, match="either 'params' or a scenario"):
        ChargaxMARL(params=p, scenario="shopping")


def test_binding_table_sees_the_constrained_connection():
    days = np.arange(3)
    free = binding.node_binding(make_params(traffic="high"), days)
    tight = binding.node_binding(make_params(traffic="high", grid_fraction=0.1), days)
    assert free.shape == tight.shape == (11,)
    assert np.all((free >= 0) & (free <= 1)) and np.all((tight >= 0) & (tight <= 1))
    assert free[0] == 0.0 and tight[0] > 0.2  # the root: never binds at 884.5 kW, often at 88.5 kW
    groups = binding.grouped(make_params(), tight)
    assert set(groups) == set(binding.GROUPS)


def test_fingerprint_changes_with_the_random_stream(monkeypatch):
    # stored bound / MPC results are looked up by fingerprint: a new random stream draws other
    # cars for the same params, so it must not find the old stream's results
    from chargax_marl.core import rng

    p = make_params()
    before = trace_lib.params_fingerprint(p)
    monkeypatch.setattr(rng, "STREAM_VERSION", rng.STREAM_VERSION + 1)
    assert trace_lib.params_fingerprint(p) != before
    assert trace_lib.params_fingerprint(
        make_params(peak_demand_eur_kw=0.1)
    ) != trace_lib.params_fingerprint(p)


def test_baselines_keep_a_named_scenarios_traffic():
    # the trainers' and `make optimal`'s configs once forced "medium" over the scenario's own
    # traffic, so "shopping-grid10-high" was evaluated at medium traffic
    from baselines.analysis.references import scenario_params

    config = resolve({"SCENARIO": "shopping-grid10-high"})
    _, full, _, _ = build_env_params(config)
    assert float(full.arrival_rate.sum()) == pytest.approx(
        float(make_params(traffic="high").arrival_rate.sum())
    )
    params, _ = scenario_params("grid10_high")
    assert float(params.arrival_rate.sum()) == pytest.approx(float(full.arrival_rate.sum()))
    medium = build_env_params(resolve({"SCENARIO": "shopping-grid10-high", "TRAFFIC": "medium"}))[1]
    assert float(medium.arrival_rate.sum()) < float(full.arrival_rate.sum())
