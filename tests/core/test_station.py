"""The station tree: builders, compilation, validation and the hard node-limit rescale."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from chargax_marl.core import (
    Battery,
    Port,
    Splitter,
    compile_station,
    multiple_splitters,
    multiple_types,
    physics,
    single_type,
)
from chargax_marl.core.station import KIND_AC, KIND_BATTERY, KIND_DC, build_station
from tests.helpers import grid_side_node_flows_kw, three_level_station, tiny_root_station, trees

# jitted: the property tests call them on a new station shape per example, and one compile per
# shape costs less than compiling each of their operations for it
rescale_to_limits = jax.jit(physics.rescale_to_limits)
node_flows_kw = jax.jit(physics.node_flows_kw)


def test_default_station_is_the_papers():
    st_ = compile_station(multiple_types())
    kinds = np.asarray(st_.leaf_kind)
    assert st_.num_ports == 16 and st_.num_batteries == 1
    assert (
        (kinds[:10] == KIND_DC).all()
        and (kinds[10:16] == KIND_AC).all()
        and kinds[16] == KIND_BATTERY
    )
    names = st_.node_names
    caps = dict(zip(names, np.asarray(st_.node_max_kw)))
    assert sum(n.startswith("dc_evse_") for n in names) == 5
    assert sum(n.startswith("ac_evse_") for n in names) == 3
    assert all(caps[n] == pytest.approx(150.0) for n in names if n.startswith("dc_evse_"))
    assert all(caps[n] == pytest.approx(11.5) for n in names if n.startswith("ac_evse_"))
    assert caps["dc_splitter"] == pytest.approx(750.0) and caps["ac_splitter"] == pytest.approx(
        34.5
    )
    assert caps["grid"] == pytest.approx(750.0 + 34.5 + 100.0)
    # Each DC connector alone may draw the whole 150 kW of its EVSE group.
    np.testing.assert_allclose(np.asarray(st_.leaf_max_kw)[:10], 150.0, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(st_.leaf_max_kw)[10:16], 11.5, rtol=1e-6)


def test_incidence_depth_and_path_efficiency():
    st_ = compile_station(three_level_station())
    inc = np.asarray(st_.incidence)
    names = st_.node_names
    assert st_.depth == 3 and st_.num_ports == 6 and st_.num_batteries == 1
    assert inc[names.index("grid")].sum() == 7
    assert inc[names.index("evse1")].tolist() == [0, 0, 1, 1, 0, 0, 0]
    # dc0 path: port 0.95 * evse 0.99 * dc_split 0.98 * grid 1.0
    assert float(st_.leaf_path_efficiency[0]) == pytest.approx(0.95 * 0.99 * 0.98, rel=1e-6)
    assert float(st_.leaf_path_efficiency[6]) == pytest.approx(0.95, rel=1e-6)
    at_depth = np.asarray(st_.node_of_leaf_at_depth)
    assert at_depth[2, 6] == -1 and at_depth[1, 6] == -1 and at_depth[0, 6] == names.index("grid")


def test_other_builders_and_custom_depth():
    assert compile_station(single_type(4)).num_ports == 4
    ms = compile_station(multiple_splitters())
    assert ms.depth == 4 and ms.num_ports == 16
    deep = Splitter(
        "a", 10.0, (Splitter("b", 9.0, (Splitter("c", 8.0, (Splitter("d", 7.0, (Port("p"),)),)),)),)
    )
    assert compile_station(deep).depth == 4
    with pytest.raises(KeyError, match="unknown architecture"):
        build_station("ring")


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: Port("p", voltage_v=0.0), "Port 'p'.*voltage_v.*> 0"),
        (lambda: Port("p", max_current_a=-5.0), "Port 'p'.*max_current_a"),
        (lambda: Port("p", max_discharge_current_a=-1.0), "max_discharge_current_a.*>= 0"),
        (lambda: Port("p", efficiency=1.2), "Port 'p'.*efficiency.*\\(0, 1\\]"),
        (lambda: Port("p", efficiency=0.0), "efficiency"),
        (lambda: Port("p", kind="XX"), "kind"),
        (lambda: Splitter("s", max_kw=0.0, children=(Port("p"),)), "Splitter 's'.*max_kw"),
        (lambda: Splitter("s", max_kw=10.0, children=()), "Splitter 's'.*children.*empty"),
        (lambda: Splitter("s", 10.0, (Port("p"),), efficiency=-0.1), "efficiency"),
        (lambda: Battery(capacity_kwh=0.0), "capacity_kwh"),
        (lambda: Battery(tau=1.0), "tau"),
        (lambda: Battery(initial_soc=1.5), "initial_soc"),
        (
            lambda: compile_station(Splitter("g", 10.0, (Port("p"), Port("p")))),
            "duplicate node name 'p'",
        ),
        (lambda: compile_station(Splitter("g", 10.0, (Battery("b"),))), "at least one Port"),
        (lambda: compile_station(Port("p")), "root must be a Splitter"),
        (lambda: multiple_types(num_dc=0, num_ac=0), "num_dc"),
        (lambda: single_type(0), "num_ports"),
    ],
)
def test_validation_errors_name_the_field(make, match):
    with pytest.raises(ValueError, match=match):
        make()


# ----------------------------------------------------------------- hypothesis: random trees


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(tree=trees(), seed=st.integers(0, 2**31 - 1))
def test_rescale_holds_every_limit_and_never_flips_or_grows(tree, seed):
    station = compile_station(tree)
    rng = np.random.default_rng(seed)
    lo = -np.asarray(station.leaf_max_discharge_current_a)
    hi = np.asarray(station.leaf_max_current_a)
    current = jnp.asarray(rng.uniform(lo, hi).astype(np.float32))
    out = rescale_to_limits(current, station)
    flows = np.asarray(node_flows_kw(out * station.leaf_voltage_v / 1000.0, station))
    caps = np.asarray(station.node_max_kw)
    assert np.all(flows <= caps * (1 + 1e-5) + 1e-6), (flows, caps)
    c, o = np.asarray(current), np.asarray(out)
    assert np.all(np.sign(o) * np.sign(c) >= 0), "a rescale flipped a sign"
    assert np.all(np.abs(o) <= np.abs(c) + 1e-6), "a rescale raised a magnitude"
    # With charging only (one sign), rescaling a subtree can only lower its ancestors' flows, so
    # a leaf none of whose ancestors violates its limit before the pass is left untouched.
    # (With both signs a deeper rescale may raise a parent's net flow: then it rescales too.)
    charging = jnp.abs(current)
    o_pos = np.asarray(rescale_to_limits(charging, station))
    flows_before = np.asarray(node_flows_kw(charging * station.leaf_voltage_v / 1000.0, station))
    inc = np.asarray(station.incidence).astype(bool)
    untouched = ~np.any(inc[flows_before > caps], axis=0)
    np.testing.assert_allclose(o_pos[untouched], np.asarray(charging)[untouched], rtol=1e-6)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(tree=tiny_root_station(), seed=32, cancel=True)
@given(
    tree=trees(max_depth=4, tiny_limits=True, max_leaves=64),
    seed=st.integers(0, 2**31 - 1),
    cancel=st.booleans(),
)
def test_rescale_holds_tiny_limits_under_leaves_of_both_signs(tree, seed, cancel):
    """Limits down to 0.001 kW over leaves that charge and discharge in the same step, up to
    ones whose grid-side flows cancel at the root: the rescaled flows hold every limit up to a
    relative float tolerance, with no absolute slack."""
    station = compile_station(tree)
    rng = np.random.default_rng(seed)
    lo = -np.asarray(station.leaf_max_discharge_current_a, np.float64)
    hi = np.asarray(station.leaf_max_current_a, np.float64)
    # each leaf at full power or a random share of it, charging or discharging
    share = np.where(rng.random(lo.shape) < 0.5, 1.0, rng.random(lo.shape))
    current = np.where(rng.random(lo.shape) < 0.5, hi, lo) * share
    volts = np.asarray(station.leaf_voltage_v, np.float64)
    if cancel:
        # one leaf nearly cancels the others' grid-side flow through the root: what is left is a
        # few times the root's limit, a small difference of large flows
        eta = np.asarray(station.leaf_path_efficiency, np.float64)
        j = int(np.argmax(np.maximum(hi, -lo)))
        others = current * volts / 1000.0
        others[j] = 0.0
        net_kw = float(np.where(others > 0, others / eta, others * eta).sum())
        left_kw = float(station.node_max_kw[0]) * rng.uniform(0.5, 3.0) * rng.choice([-1, 1])
        side_kw = left_kw - net_kw
        p_kw = side_kw * eta[j] if side_kw > 0 else side_kw / eta[j]
        current[j] = np.clip(p_kw * 1000.0 / volts[j], lo[j], hi[j])
    out = rescale_to_limits(jnp.asarray(current.astype(np.float32)), station)
    o = np.asarray(out, np.float64)
    flows = grid_side_node_flows_kw(o * volts / 1000.0, station)[0]
    caps = np.asarray(station.node_max_kw, np.float64)
    assert np.all(flows <= caps * (1 + 1e-6)), (flows / caps).max()
    c = current.astype(np.float32)
    assert np.all(np.sign(o) * np.sign(c) >= 0), "a rescale flipped a sign"
    assert np.all(np.abs(o) <= np.abs(c)), "a rescale raised a magnitude"
