"""The session model v3: every departure fixed when the car arrives, and the port kind each car
wants, so that a day's occupancy does not depend on the policy."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl import policies, trace
from chargax_marl.core import data_io, make_params, traffic
from chargax_marl.core.params import validate_params, validated_replace
from chargax_marl.core.station import KIND_AC, KIND_DC, multiple_types, single_type
from chargax_marl.trace import params_fingerprint

# a small station: 2 DC ports (one EVSE) and 2 AC ports (one EVSE), no battery
SMALL = multiple_types(num_dc=2, num_ac=2, battery=None)


def _idle(params):
    return lambda s, k: jnp.zeros_like(policies.always_max(s, k, params))


def _random(params):
    return lambda s, k: jax.random.randint(
        k, policies.always_max(s, k, params).shape, -params.num_levels, params.num_levels + 1
    )


@pytest.fixture(scope="module")
def v3_params():
    return make_params(session_model="v3", traffic="high")


def test_the_occupancy_is_the_same_whatever_the_policy(v3_params):
    p = v3_params
    traces = trace.make_traces(p, [3, 40])
    for i in range(2):
        day, key = trace.day_of(traces, i), jax.random.PRNGKey(i)
        runs = [
            trace.replay(act, p, day, key)
            for act in (lambda s, k: policies.always_max(s, k, p), _idle(p), _random(p))
        ]
        occupied = [np.asarray(states.occupied) for states, _, _ in runs]
        rejected = [np.asarray(infos.cars_rejected) for _, infos, _ in runs]
        assert occupied[0].any() and rejected[0].sum() > 0  # a busy day: the check can fail
        for occ, rej in zip(occupied[1:], rejected[1:], strict=True):
            np.testing.assert_array_equal(occ, occupied[0])
            np.testing.assert_array_equal(rej, rejected[0])
        # the policies differ: the check is not of one trajectory three times
        profits = [float(np.asarray(infos.profit_eur).sum()) for _, infos, _ in runs]
        assert len(set(profits)) == 3


def test_under_v2_the_occupancy_depends_on_the_policy():
    """The contrast that makes the test above mean something: v2's DC users leave when
    charged, so an idle policy keeps them parked."""
    p = make_params(traffic="high")
    day, key = trace.day_of(trace.make_traces(p, [3]), 0), jax.random.PRNGKey(0)
    full = trace.replay(lambda s, k: policies.always_max(s, k, p), p, day, key)[0]
    idle = trace.replay(_idle(p), p, day, key)[0]
    assert (np.asarray(full.occupied) != np.asarray(idle.occupied)).any()


def _small(**kwargs):
    return make_params(station=SMALL, session_model="v3", **kwargs)


def _day(params, cars):
    return trace.trace_from_cars(params, cars)


def _run(params, day, act):
    return trace.replay(act, params, day, jax.random.PRNGKey(0))


def _ports(params, kind):
    return np.flatnonzero(np.asarray(params.station.leaf_kind) == kind)


def test_a_car_parks_at_a_port_of_the_kind_it_wants_or_is_turned_away():
    p = _small()
    dc, ac = _ports(p, KIND_DC), _ports(p, KIND_AC)
    # step 10: three DC users (two DC ports) and one AC user
    cars = [dict(arrival_step=10, wants_dc=True, stay_min=600.0) for _ in range(3)]
    cars.append(dict(arrival_step=10, wants_dc=False, stay_min=600.0))
    states, infos, _ = _run(p, _day(p, cars), _idle(p))
    occ = np.asarray(states.occupied)[11]
    assert occ[dc].all() and occ[ac].sum() == 1
    assert float(np.asarray(infos.cars_rejected)[10]) == 1.0  # the third DC user
    assert float(np.asarray(infos.cars_arrived)[10]) == 3.0


def test_an_ac_user_stays_its_drawn_stay_even_when_charged():
    p = _small()
    ac = _ports(p, KIND_AC)
    # a small demand: charged within minutes at full power, parked 120 min
    car = dict(arrival_step=0, wants_dc=False, stay_min=120.0, arrival_soc=0.5, target_soc=0.52)
    states, infos, _ = _run(p, _day(p, [car]), lambda s, k: policies.always_max(s, k, p))
    occ = np.asarray(states.occupied)[:, ac].any(axis=1)
    assert occ[1 : 1 + 24].all() and not occ[1 + 24 :].any()  # 120 min = 24 steps
    assert float(np.asarray(infos.missing_kwh).sum()) == pytest.approx(0.0, abs=1e-3)


def test_a_dc_user_stays_its_earliest_finish_plus_its_margin_and_leaves_uncharged_if_idle():
    p = _small()
    dc = _ports(p, KIND_DC)
    car = dict(
        arrival_step=0,
        wants_dc=True,
        stay_min=900.0,  # the drawn stay is an AC stay: a DC user does not read it
        margin_min=10.0,
        capacity_kwh=60.0,
        dc_kw=50.0,
        arrival_soc=0.2,
        target_soc=0.6,
        tau=0.8,
    )
    solo = float(np.asarray(p.station.leaf_solo_max_kw)[dc[0]])
    earliest = float(traffic.earliest_finish_min(0.2, 0.6, 60.0, 50.0, 0.8, solo, p))
    stay_steps = int(round((earliest + 10.0) / p.step_minutes))
    assert earliest == pytest.approx(24 / 50 * 60, abs=p.step_minutes)  # 24 kWh at 50 kW
    for act in (lambda s, k: policies.always_max(s, k, p), _idle(p)):
        states, infos, _ = _run(p, _day(p, [car]), act)
        occ = np.asarray(states.occupied)[:, dc].any(axis=1)
        assert occ[1 : 1 + stay_steps].all() and not occ[1 + stay_steps :].any()
    # the idle policy's car left on time with its whole request missing
    assert float(np.asarray(infos.missing_kwh).sum()) >= 24.0 - 1e-3


def test_no_user_is_charge_sensitive(v3_params):
    p = v3_params
    states, _, _ = trace.replay(
        lambda s, k: policies.always_max(s, k, p),
        p,
        trace.day_of(trace.make_traces(p, [5]), 0),
        jax.random.PRNGKey(0),
    )
    assert np.asarray(states.occupied).any() and not np.asarray(states.charge_sensitive).any()


def test_the_drawn_kinds_and_margins_follow_the_shares():
    p = make_params(session_model="v3", traffic="high", dc_share=0.3, dc_margin_min=(5.0, 20.0))
    traces = trace.make_traces(p, np.arange(20))
    a = traces.arrivals
    slots = np.arange(a.model.shape[-1])
    real = slots[None, None, :] < np.asarray(a.requested)[..., None]  # the slots with a car
    wants = np.asarray(a.wants_dc)[real]
    margin = np.asarray(a.margin_min)[real]
    assert wants.size > 2000
    assert abs(wants.mean() - 0.3) < 0.03
    assert margin.min() >= 5.0 and margin.max() <= 20.0
    np.testing.assert_allclose(margin % p.step_minutes, 0.0)
    assert set(np.unique(margin)) == {5.0, 10.0, 15.0, 20.0}


def test_v2_draws_are_unchanged_by_the_v3_fields():
    """v3 draws its kinds from a stream of their own: the cars of v2 and v3 are the same."""
    v2 = make_params(traffic="high")
    v3 = make_params(traffic="high", session_model="v3")
    t2, t3 = trace.make_traces(v2, [7]), trace.make_traces(v3, [7])
    for f in traffic.SLOT_FIELDS:
        if f not in ("wants_dc", "margin_min"):
            np.testing.assert_array_equal(
                np.asarray(getattr(t2.arrivals, f)), np.asarray(getattr(t3.arrivals, f))
            )
    assert not np.asarray(t2.arrivals.wants_dc).any()


def test_the_profile_shares_and_a_one_kind_station():
    shopping = make_params(session_model="v3")
    assert float(shopping.dc_share) == pytest.approx(data_io.DC_SHARE_BY_PROFILE["shopping"])
    workplace = make_params(session_model="v3", user_profile="workplace")
    assert float(workplace.dc_share) == pytest.approx(data_io.DC_SHARE_BY_PROFILE["workplace"])
    # a station of AC ports only: every car wants AC
    ac_only = make_params(session_model="v3", station=single_type(num_ports=4))
    kinds = set(np.asarray(ac_only.station.leaf_kind).tolist()) - {2}
    assert float(ac_only.dc_share) == (1.0 if kinds == {KIND_DC} else 0.0)


def test_bad_v3_settings_are_refused_by_name():
    with pytest.raises(ValueError, match="dc_share.*no DC ports"):
        make_params(session_model="v3", station=multiple_types(num_dc=0, num_ac=4), dc_share=0.5)
    with pytest.raises(ValueError, match="dc_share"):
        make_params(session_model="v3", dc_share=1.5)
    with pytest.raises(ValueError, match="dc_margin_min"):
        make_params(session_model="v3", dc_margin_min=(10.0, 5.0))
    with pytest.raises(ValueError, match="dc_margin_min"):
        make_params(session_model="v3", dc_margin_min=5.0)
    p = make_params(session_model="v3")
    with pytest.raises(ValueError, match="dc_share"):
        validate_params(p.replace(dc_share=jnp.float32(-0.1)))
    with pytest.raises(ValueError, match="fixed_departures"):
        validate_params(p.replace(fixed_departures="yes"))
    assert validated_replace(p, dc_share=0.5).fixed_departures


def test_v3_has_its_own_fingerprint_and_v2_keeps_its_own():
    v2, v3 = make_params(), make_params(session_model="v3")
    assert params_fingerprint(v2) != params_fingerprint(v3)
    # the v3 fields are not read under v2: changing them leaves v2's fingerprint
    other = make_params(dc_share=0.2, dc_margin_min=(0.0, 30.0))
    assert params_fingerprint(other) == params_fingerprint(v2)
    assert params_fingerprint(make_params(session_model="v3", dc_share=0.2)) != (
        params_fingerprint(v3)
    )
