"""Pytrees of the core simulator: parameters, state and the per-step report.

Everything is a ``flax.struct`` dataclass. Arrays over leaves have shape ``(L,)`` with the
ports first (``0..num_ports-1``) and the station batteries last. Static settings that
change array shapes or control flow are ``pytree_node=False`` (changing them recompiles);
everything else, including all exogenous data, is traced, so a new price year or fleet
does not recompile the step.
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import struct

from chargax_marl.core.station import StationArrays

PENALTY_TERMS = (
    "constraint",
    "satisfaction_time",
    "satisfaction_charge",
    "sustainability",
    "rejected",
    "battery_degradation",
    "car_degradation",
    "grid_demand",
)
"""Names of the penalty terms c of paper Appendix A.3, in the order of `PenaltyWeights`."""

ACTION_MODES = ("absolute", "delta", "continuous")
CONSTRAINT_MODES = ("hard", "soft")


@struct.dataclass
class PenaltyWeights:
    """The weights alpha of ``r = profit - sum_c alpha_c * c`` (paper Eq. 4); all 0 by default.

    Units of the terms they multiply: constraint kW over the limit on the grid side (max over
    nodes; in hard mode the excess that flows after the rescale, so 0), satisfaction_time kWh
    missing at departure (against the car's target SoC), satisfaction_charge minutes
    (overtime minus beta * undertime, undertime measured against the earliest finish; see
    `chargax_marl.core.traffic.depart`), sustainability kg CO2 (MOER kg/kWh * grid kWh), rejected cars,
    battery_degradation kWh discharged from station batteries, car_degradation kWh fed to
    the grid from cars, grid_demand kWh of |delivered - demand|.
    """

    constraint: float = 0.0
    satisfaction_time: float = 0.0
    satisfaction_charge: float = 0.0
    sustainability: float = 0.0
    rejected: float = 0.0
    battery_degradation: float = 0.0
    car_degradation: float = 0.0
    grid_demand: float = 0.0


@struct.dataclass
class EnvParams:
    """Everything the step needs besides the state: station, exogenous data, economics, settings.

    Build it with `chargax_marl.core.params.make_params`, which validates its inputs.
    ``replace`` is unchecked: derive params with
    `chargax_marl.core.params.validated_replace` (or check them with
    `chargax_marl.core.params.validate_params`, which both views apply to the params
    they are given).
    """

    station: StationArrays
    # --- exogenous data
    prices_eur_kwh: jnp.ndarray  # (D, 24) day-ahead price per local hour
    day_price_quantiles_eur_kwh: (
        jnp.ndarray
    )  # (D, Q) quantiles (observation.PRICE_QUANTILES) of each day's
    #   hourly day-ahead price plus time-of-use surcharge; derived by make_params (rebuild params to change prices)
    first_weekday: jnp.ndarray  # () int32, weekday of day 0 (0 = Monday)
    arrival_rate: jnp.ndarray  # (2, T) expected arrivals per step; row 0 workday, row 1 weekend
    stay_quantiles_min: jnp.ndarray  # (Q,) inverse CDF of the stay duration
    stay_scale_by_hour: jnp.ndarray  # (24,) multiplier by arrival hour
    demand_quantiles_kwh: jnp.ndarray  # (Q,) inverse CDF of the energy demand
    demand_scale_by_hour: jnp.ndarray  # (24,)
    arrival_soc_range: jnp.ndarray  # (2,) uniform arrival SoC bounds
    charge_sensitive_prob: jnp.ndarray  # () probability of u = 1
    fleet_share: jnp.ndarray  # (K,) sums to 1
    fleet_capacity_kwh: jnp.ndarray  # (K,)
    fleet_ac_kw: jnp.ndarray  # (K,)
    fleet_dc_kw: jnp.ndarray  # (K,)
    fleet_tau: jnp.ndarray  # (K,)
    fleet_ac_discharge_kw: (
        jnp.ndarray
    )  # (K,) discharge (V2G) limit at AC ports, 0 = cannot discharge
    fleet_dc_discharge_kw: jnp.ndarray  # (K,) discharge (V2G) limit at DC ports
    moer_kg_per_kwh: jnp.ndarray  # (Dm, T) marginal emission rate; zeros when no MOER data
    grid_demand_kwh: jnp.ndarray  # (T,) grid demand signal per step for the grid-demand penalty
    reset_days: jnp.ndarray  # (R,) int32 day indices reset() draws from (all days by default)
    battery_soc0_low: (
        jnp.ndarray
    )  # (B,) initial SoC of each station battery is uniform in [low, high]
    battery_soc0_high: jnp.ndarray  # (B,)
    battery_wear_eur_kwh: jnp.ndarray  # (B,) wear cost per kWh into or out of each battery's cells
    battery_calendar_eur_step: jnp.ndarray  # (B,) calendar ageing cost of each battery per step
    # --- economics
    customer_price_eur_kwh: jnp.ndarray  # () p_sell, price charged to (and refunded to) car owners
    refund_discharged_energy: (
        jnp.ndarray
    )  # () bool: car owners get p_sell back for energy taken out of
    #   their car (default); False: they pay for energy put in and get nothing back (the original Chargax)
    grid_fee_eur_kwh: jnp.ndarray  # () added to the day-ahead price when buying
    tou_fee_eur_kwh: (
        jnp.ndarray
    )  # (24,) time-of-use surcharge on the buy price per local hour (zeros: none)
    peak_demand_eur_kw: (
        jnp.ndarray
    )  # () EUR per kW of the day's highest net grid draw (0: no peak charge)
    peak_demand_incremental: (
        jnp.ndarray
    )  # () bool: book the peak charge as the running peak rises, else at the last step
    feed_in_factor: jnp.ndarray  # () p_sell,grid = factor * day-ahead price
    fixed_cost_eur: jnp.ndarray  # () c_dt, per step
    alpha: PenaltyWeights
    battery_value_day_mean: (
        jnp.ndarray
    )  # () bool: value the batteries' energy change at the day's mean buy price
    battery_value_eur_kwh: (
        jnp.ndarray
    )  # () fixed price of that energy change when the flag is off (0 = no value)
    beta: (
        jnp.ndarray
    )  # () weight of undertime in the charge-sensitive satisfaction term (default 0)
    charged_tolerance_kwh: jnp.ndarray  # () a charge-sensitive car leaves when remaining <= this
    # --- static settings
    step_minutes: float = struct.field(pytree_node=False, default=5.0)
    num_steps: int = struct.field(pytree_node=False, default=288)
    num_levels: int = struct.field(pytree_node=False, default=10)
    action_mode: str = struct.field(pytree_node=False, default="absolute")
    v2g: bool = struct.field(pytree_node=False, default=True)
    constraint_mode: str = struct.field(pytree_node=False, default="hard")
    price_horizon_hours: int = struct.field(pytree_node=False, default=6)
    observe_moer: bool = struct.field(pytree_node=False, default=False)

    @property
    def num_days(self) -> int:
        return self.prices_eur_kwh.shape[0]

    @property
    def step_hours(self) -> float:
        return self.step_minutes / 60.0


@struct.dataclass
class EpisodeTotals:
    """Running totals of the episode (reset with the state). Energies in kWh, money in EUR."""

    reward: jnp.ndarray
    profit_eur: jnp.ndarray
    energy_charged_kwh: jnp.ndarray  # into cars (charging leaves only)
    energy_discharged_kwh: jnp.ndarray  # out of cars (V2G), positive number
    energy_delivered_kwh: jnp.ndarray  # net into cars = charged - discharged
    battery_net_kwh: jnp.ndarray  # net into station batteries
    grid_import_kwh: jnp.ndarray  # drawn from the grid in steps with net draw > 0
    grid_export_kwh: jnp.ndarray  # fed to the grid in steps with net draw <= 0, positive number
    losses_kwh: jnp.ndarray
    cars_arrived: jnp.ndarray
    cars_served: jnp.ndarray  # departed cars
    cars_rejected: jnp.ndarray
    missing_kwh: jnp.ndarray  # energy still wanted by time-sensitive cars at departure
    overtime_min: (
        jnp.ndarray
    )  # minutes this step that parked charge-sensitive cars spent beyond their plan
    constraint_excess_kw: (
        jnp.ndarray
    )  # summed over steps of the excess that flowed (max over nodes; 0 in hard mode)
    requested_excess_kw: jnp.ndarray  # summed over steps of the excess the controller asked for
    battery_terminal_value_eur: (
        jnp.ndarray
    )  # value of the batteries' energy change, booked at the last step
    peak_grid_kw: (
        jnp.ndarray
    )  # running maximum of the net grid draw (kW, step average) so far today
    peak_demand_charge_eur: (
        jnp.ndarray
    )  # peak-demand charge booked so far (part of profit_eur, positive = paid)
    battery_wear_eur: (
        jnp.ndarray
    )  # battery wear booked so far (part of profit_eur, positive = paid)
    satisfaction_sum: jnp.ndarray  # sum over departed cars of their satisfaction in [0, 1]
    satisfaction_sq_sum: jnp.ndarray  # sum over departed cars of their satisfaction squared
    satisfaction_shortfall_max: jnp.ndarray  # max over departed cars of 1 - satisfaction
    cars_served_time_sensitive: jnp.ndarray  # departed time-sensitive cars (u = 0)
    satisfaction_sum_time_sensitive: jnp.ndarray  # their satisfaction summed

    @classmethod
    def zeros(cls) -> EpisodeTotals:
        z = jnp.zeros((), jnp.float32)
        return cls(**{f: z for f in cls.__dataclass_fields__})


@struct.dataclass
class EnvState:
    """The station state. Per-leaf fields have shape ``(L,)``: ports, then batteries.

    Batteries are leaves that are always occupied, never depart and have arrival SoC 0.
    A free port holds zeros in every car field.
    """

    current_a: jnp.ndarray  # signed current set at the leaf, A (negative = discharging)
    occupied: jnp.ndarray  # bool
    soc: jnp.ndarray  # state of charge in [0, 1]
    energy_remaining_kwh: (
        jnp.ndarray
    )  # energy the user still wants, (target_soc - soc) * capacity (>= 0)
    time_remaining_min: jnp.ndarray  # minutes until the planned departure (may go negative)
    slack_min: (
        jnp.ndarray
    )  # planned stay minus the earliest finish the car's curve allows at its port (set at arrival)
    capacity_kwh: jnp.ndarray  # battery capacity C of the car
    max_rate_kw: jnp.ndarray  # r-bar of the car for this port's kind
    max_discharge_rate_kw: (
        jnp.ndarray
    )  # the car's discharge limit for this port's kind (0 = cannot discharge)
    target_soc: (
        jnp.ndarray
    )  # SoC at which the car stops charging: arrival SoC + demand / capacity (<= 1)
    tau: jnp.ndarray  # bulk/absorption transition SoC
    charge_sensitive: jnp.ndarray  # bool, u = 1
    arrival_soc: jnp.ndarray  # SoC at arrival: discharging never goes below it
    day: jnp.ndarray  # () int32 index into the price data
    timestep: jnp.ndarray  # () int32 step of the day, 0..num_steps
    is_workday: jnp.ndarray  # () bool
    totals: EpisodeTotals

    @property
    def time(self) -> jnp.ndarray:
        """gymnax's name for the step counter."""
        return self.timestep


@struct.dataclass
class StepInfo:
    """What one transition reports. Energies in kWh, money in EUR, scalars unless noted."""

    reward: jnp.ndarray
    profit_eur: jnp.ndarray
    penalties: dict  # name -> () value of each term c (unweighted), keys = PENALTY_TERMS
    energy_charged_kwh: jnp.ndarray
    energy_discharged_kwh: jnp.ndarray
    energy_delivered_kwh: jnp.ndarray  # Delta E_net
    battery_net_kwh: jnp.ndarray  # Delta E_b (terminal side)
    grid_net_kwh: jnp.ndarray  # Delta E_grid,net
    losses_kwh: jnp.ndarray
    price_buy_eur_kwh: jnp.ndarray
    price_sell_grid_eur_kwh: jnp.ndarray
    cars_arrived: jnp.ndarray
    cars_departed: jnp.ndarray
    cars_rejected: jnp.ndarray
    missing_kwh: jnp.ndarray
    overtime_min: jnp.ndarray
    constraint_excess_kw: jnp.ndarray  # grid-side excess that flowed (0 in hard mode)
    requested_excess_kw: jnp.ndarray  # grid-side excess of the currents the controller asked for
    battery_terminal_value_eur: jnp.ndarray  # nonzero at the last step only; included in profit_eur
    peak_demand_charge_eur: (
        jnp.ndarray
    )  # peak-demand charge booked this step (subtracted in profit_eur)
    battery_wear_eur: (
        jnp.ndarray
    )  # battery wear this step, cycling and calendar (subtracted in profit_eur)
    satisfaction_sum: jnp.ndarray  # summed satisfaction of the cars that left this step
    satisfaction_min: jnp.ndarray  # the least satisfied of them (1 when none left)
    leaf_energy_kwh: jnp.ndarray  # (L,) energy into each car / battery this step (terminal side)
    leaf_arrived: (
        jnp.ndarray
    )  # (L,) bool, the ports that received a new car at the end of this step
    leaf_reward: (
        jnp.ndarray
    )  # (L,) each leaf's share of reward (reward.leaf_reward_shares); sums to reward
