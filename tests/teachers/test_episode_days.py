"""The teachers' plans and programmes plan over one day's 24 hours: episodes of several
days are refused at each entry point with a ValueError naming ``episode_days``."""

from __future__ import annotations

import pytest

from chargax_marl.teachers import car_plan, congestion, rules, shaping, storage_value
from tests.helpers import ONE_DAY_ONLY as MESSAGE
from tests.helpers import two_day_params


@pytest.fixture(scope="module")
def two_days():
    return two_day_params()


ENTRY_POINTS = {
    "car_plan.plan_constants": car_plan.plan_constants,
    "car_plan.car_values": car_plan.car_values,
    "car_plan.car_potential": car_plan.car_potential,
    "car_plan.plan_advice": car_plan.plan_advice,
    "car_plan.plan_action": car_plan.plan_action,
    "congestion.coupled_plan": congestion.coupled_plan,
    "congestion.coupled_plan_action": congestion.coupled_plan_action,
    "congestion.coupled_advice": congestion.coupled_advice,
    "congestion.coupled_potential": congestion.coupled_potential,
    "rules.battery_programme": rules.battery_programme,
    "rules.plan_programme": rules.plan_programme,
    "rules.grid_programme": rules.grid_programme,
    "rules.coupled_plan_rule": rules.coupled_plan_rule,
    "shaping.battery_potential": shaping.battery_potential,
    "storage_value.step_buy_prices": storage_value.step_buy_prices,
    "storage_value.terminal_prices": storage_value.terminal_prices,
    "storage_value.storage_values": storage_value.storage_values,
    "storage_value.dp_values": storage_value.dp_values,
    "storage_value.dp_battery_action": storage_value.dp_battery_action,
}


@pytest.mark.parametrize("name", sorted(ENTRY_POINTS))
def test_multi_day_episodes_are_refused(two_days, name):
    with pytest.raises(ValueError, match=MESSAGE):
        ENTRY_POINTS[name](two_days)
