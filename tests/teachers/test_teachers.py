"""The teachers as library code (`chargax_marl.teachers`): usable without the project's
``baselines/``, and obtainable as rules by name."""

from __future__ import annotations

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core import make_params, simulator
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.marl import ChargaxMARL
from chargax_marl.policies import TEACHER_RULES, for_marl, for_single, get_policy
from chargax_marl.single import Chargax
from chargax_marl.teachers import car_plan, prices, rules, storage_value

TINY_ENV = {
    "station": "single_type",
    "station_kwargs": {"num_ports": 4, "battery": True},
    "step_minutes": 60.0,
    "num_levels": 1,
}


def test_the_library_imports_nothing_from_baselines():
    code = (
        "import sys, chargax_marl.teachers, chargax_marl.wrappers, chargax_marl.policies; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'baselines'))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_teacher_rules_are_built_by_name_for_given_params():
    """``get_policy(name, params)`` builds each teacher rule; without params, or on a station
    without a battery, it says why; ``for_single`` / ``for_marl`` take the names."""
    params = make_params(**TINY_ENV)
    assert set(TEACHER_RULES) == {
        "battery_programme",
        "plan_programme",
        "grid_programme",
        "coupled_plan",
    }
    state = simulator.reset(jax.random.PRNGKey(1), params).replace(timestep=jnp.int32(3))
    expected = {
        "battery_programme": car_plan.plan_action(params, "dp", None),
        "plan_programme": car_plan.plan_action(params, "dp", car_plan.PLAN_POWER_FRACTION),
        "grid_programme": rules.grid_programme(params),
        "coupled_plan": rules.coupled_plan_rule(params),
    }
    for name in TEACHER_RULES:
        levels = np.asarray(get_policy(name, params)(state, None, params))
        np.testing.assert_array_equal(levels, np.asarray(expected[name](state, None, params)))
        with pytest.raises(ValueError, match=name):
            get_policy(name)
    bare = make_params(**{**TINY_ENV, "station_kwargs": {"num_ports": 4, "battery": False}})
    with pytest.raises(ValueError, match="battery_programme.*battery"):
        get_policy("battery_programme", bare)
    with pytest.raises(KeyError, match="plan_programme"):
        get_policy("bogus")
    single = Chargax(params=params)
    levels = expected["battery_programme"](state, None, params)
    np.testing.assert_array_equal(
        np.asarray(for_single("battery_programme", single)(state, None)),
        np.asarray(single.levels_to_action(levels, params)),
    )
    marl = ChargaxMARL(params=params)
    assert set(for_marl("plan_programme", marl)(state, None)) == set(marl.agents)


def test_dp_battery_action_takes_the_best_of_the_three_actions_values():
    """The programme's action is the argmax of `storage_value.action_values` on the next
    step's table, read at the batteries' stored energy."""
    params = make_params(**TINY_ENV)
    act = jax.jit(storage_value.dp_battery_action(params))
    grid, table = storage_value.dp_values(params)
    price = storage_value.step_buy_prices(params)
    eta, power_kw, capacity_kwh, _ = storage_value.battery_constants(params)
    is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
    state = simulator.empty_state(2, params, jax.random.PRNGKey(0))
    for t, soc in ((2, 0.1), (10, 0.5), (18, 0.9)):
        s = state.replace(timestep=jnp.int32(t), soc=jnp.where(jnp.asarray(is_bat), soc, state.soc))
        e = soc * capacity_kwh
        after = table[2, t + 1]
        q = storage_value.action_values(
            np,
            lambda x, after=after: np.interp(x, grid, after),
            e,
            price[2, t],
            eta,
            power_kw * float(params.step_hours),
            capacity_kwh,
            storage_value.battery_wear_eur_kwh(params),
        )
        a, strict = act(s)
        if bool(strict):
            assert int(a) == int(np.argmax(q)) - 1


def test_relative_prices_are_the_day_s_range_and_bounded():
    """``(p - median) / (q80 - q20)`` of the observed prices, clipped to [-5, 5], the spread
    floored at 0.01 EUR/kWh."""
    obs = jnp.asarray([[0.0, 0.3, 0.5, 0.2, 0.4, 0.6], [0.0, 9.0, 0.5, 0.5, 0.5, 0.5]], jnp.float32)
    cols = (np.array([1, 2]), 3, 4, 5)  # prices, q20, q50, q80
    got = np.asarray(prices.relative_prices(obs, *cols))
    np.testing.assert_allclose(got[0], [(0.3 - 0.4) / 0.4, (0.5 - 0.4) / 0.4], rtol=1e-6)
    assert got[1, 0] == 5.0 and got[1, 1] == 0.0
    assert prices.with_relative_prices(obs, None) is obs
    assert prices.with_relative_prices(obs, cols).shape == (2, 8)
