"""Wrappers that put the teachers (`chargax_marl.teachers`) into an env, PureJaxRL / JaxMARL
style: each wraps the gymnax view (`chargax_marl.single.Chargax`, ``reset(key,
params)``, ``step(key, state, action, params)``) or the JaxMARL view
(`chargax_marl.marl.ChargaxMARL`, ``reset(key)``, ``step(key, state, actions)``), keeps its
call signatures, forwards every other attribute, and is jit and vmap friendly. The teachers'
tables are built from the env's own params (its days and prices).

Actions that fill the nodes' capacity in priority order (JaxMARL view): `PriorityFill`,
`priority_fill_levels`, `priority_class_levels`. Reward shaping (potential-based, Ng, Harada
and Russell 1999):
`BatteryShaping`, `CarPlanShaping`, `CoupledPlanShaping` (the parked cars planned together
under the node limits and the peak charge, `chargax_marl.teachers.congestion`). A fairness objective: `FairnessReward`. Observation
features: `PlanAdviceObservation`, `CoupledPlanAdviceObservation`, `RelativePriceObservation`. A JaxMARL stack::

    env = ChargaxMARL(params=params, local_reward_weight=1.0)
    env = RelativePriceObservation(PlanAdviceObservation(CarPlanShaping(BatteryShaping(env))))
    env = LogWrapper(env)  # chargax_marl.marl.LogWrapper
"""

from chargax_marl.wrappers.actions import (
    PriorityFill,
    priority_class_levels,
    priority_class_size,
    priority_fill_levels,
)
from chargax_marl.wrappers.fairness import FairnessReward
from chargax_marl.wrappers.observations import (
    CoupledPlanAdviceObservation,
    ObservationFeatures,
    PlanAdviceObservation,
    RelativePriceObservation,
)
from chargax_marl.wrappers.shaping import BatteryShaping, CarPlanShaping, CoupledPlanShaping

__all__ = [
    "BatteryShaping",
    "CarPlanShaping",
    "CoupledPlanAdviceObservation",
    "CoupledPlanShaping",
    "FairnessReward",
    "ObservationFeatures",
    "PlanAdviceObservation",
    "PriorityFill",
    "RelativePriceObservation",
    "priority_class_levels",
    "priority_class_size",
    "priority_fill_levels",
]
