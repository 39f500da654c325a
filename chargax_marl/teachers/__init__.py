"""Teachers: what a learner on the station can be shown beyond the env's own reward.

Computed from the day's known prices (day-ahead prices are published the day before) and the
simulator state, never from the future cars:

- `storage_value`: the battery-only dynamic programme and LP over
  the day's prices, net of the battery's losses and wear (the value of the stored energy; the
  programme's best action);
- `car_plan`: each parked car's cheapest plan under the day's
  prices (its value, a potential per car, the plan advice and the plan as a rule);
- `congestion`: the parked cars planned together under the node limits and the peak
  charge (congestion prices, the joint plan, its potential per car, its advice and the plan
  as a rule);
- `shaping`: the battery potentials and the per-agent terms of
  the multi-agent view;
- `prices`: relative prices, an observation feature;
- `rules`: the teachers played as rules (also by name through
  `chargax_marl.policies.get_policy`).

`chargax_marl.wrappers` applies them to the envs as reward shaping and observation
features.
"""

from chargax_marl.teachers.car_plan import (
    PLAN_POWER_FRACTION,
    car_potential,
    car_values,
    plan_action,
    plan_advice,
    plan_energy,
    plan_value,
    price_order,
)
from chargax_marl.teachers.congestion import (
    CoupledPlan,
    coupled_advice,
    coupled_plan,
    coupled_plan_action,
    coupled_potential,
    solve_coupled_lp,
)
from chargax_marl.teachers.prices import (
    relative_price_columns,
    relative_prices,
    with_relative_prices,
)
from chargax_marl.teachers.rules import (
    RULE_BUILDERS,
    battery_programme,
    coupled_plan_rule,
    grid_programme,
    plan_programme,
)
from chargax_marl.teachers.shaping import (
    BATTERY_POTENTIALS,
    agent_potential_shaping,
    battery_potential,
    battery_shaping,
    mix_own_terms,
)
from chargax_marl.teachers.storage_value import (
    action_values,
    battery_constants,
    battery_wear_eur_kwh,
    dp_battery_action,
    dp_values,
    level_value,
    level_values,
    step_buy_prices,
    storage_values,
    terminal_prices,
)

__all__ = [
    "BATTERY_POTENTIALS",
    "PLAN_POWER_FRACTION",
    "RULE_BUILDERS",
    "CoupledPlan",
    "action_values",
    "agent_potential_shaping",
    "battery_constants",
    "battery_wear_eur_kwh",
    "battery_potential",
    "battery_programme",
    "battery_shaping",
    "car_potential",
    "car_values",
    "coupled_advice",
    "coupled_plan",
    "coupled_plan_action",
    "coupled_plan_rule",
    "coupled_potential",
    "dp_battery_action",
    "dp_values",
    "grid_programme",
    "level_value",
    "level_values",
    "mix_own_terms",
    "plan_action",
    "plan_advice",
    "plan_energy",
    "plan_programme",
    "plan_value",
    "price_order",
    "relative_price_columns",
    "relative_prices",
    "solve_coupled_lp",
    "step_buy_prices",
    "storage_values",
    "terminal_prices",
    "with_relative_prices",
]
