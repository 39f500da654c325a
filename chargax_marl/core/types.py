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

    Each weight is in EUR per unit of the term it multiplies:

    Attributes:
        constraint: kW over the limit on the grid side (max over nodes; in hard mode the
            excess that flows after the rescale, so 0).
        satisfaction_time: kWh missing at departure (against the user's request, the
            energy to the car's target SoC plus what the user asked for beyond it).
        satisfaction_charge: minutes (overtime minus beta * undertime, undertime measured
            against the earliest finish; see `chargax_marl.core.traffic.depart`).
        sustainability: kg CO2 (MOER kg/kWh * grid kWh).
        rejected: cars rejected.
        battery_degradation: kWh discharged from station batteries.
        car_degradation: kWh fed to the grid from cars.
        grid_demand: kWh of ``|delivered - demand|``.
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

    Shapes: ``D`` days of prices, ``T`` steps per day, ``Q`` quantiles, ``K`` car models,
    ``B`` station batteries. Money in EUR, energy in kWh, power in kW.

    Attributes:
        station: the compiled station.
        prices_eur_kwh: ``(D, 24)`` day-ahead price per local hour (EUR/kWh).
        day_price_quantiles_eur_kwh: ``(D, Q)`` quantiles (``observation.PRICE_QUANTILES``)
            of each day's hourly day-ahead price plus time-of-use surcharge; derived by
            `make_params` (rebuild params to change prices).
        first_weekday: ``()`` int32, weekday of day 0 (0 = Monday).
        arrival_rate: ``(2, T)`` expected arrivals per step; row 0 workday, row 1 weekend.
        holiday: ``(D,)`` bool, the day is a public holiday (arrivals of a weekend day).
        weekday_volume_factors: ``(7,)`` volume of each weekday (Monday first) relative to
            its day type's row of ``arrival_rate``.
        daily_volume_cv: ``()`` coefficient of variation of a day's arrival intensity (0:
            the rate is the same every day).
        stay_quantiles_min: ``(24, Q)`` inverse CDF of the planned stay (minutes) per
            arrival hour.
        stay_scale_by_hour: ``(24,)`` multiplier of the stay by arrival hour.
        demand_quantiles_kwh: ``(24, Q)`` inverse CDF of the energy a car takes (kWh) per
            arrival hour.
        demand_scale_by_hour: ``(24,)`` multiplier of the demand by arrival hour.
        stay_demand_corr: ``()`` correlation of the Gaussian copula that joins a car's stay
            and demand draws (0: independent).
        request_ratio_quantiles: ``(Q,)`` inverse CDF of the energy a car takes over the
            energy its user requests, in (0, 1].
        arrival_soc_range: ``(2,)`` uniform arrival SoC bounds.
        charge_sensitive_prob: ``()`` probability of u = 1 (a charge-sensitive user) at AC
            ports.
        dc_charge_sensitive_prob: ``()`` the same at DC ports.
        random_port_choice: ``()`` bool: an arriving car parks at a uniformly random free
            port (else at the first free port in port order).
        dc_share: ``()`` the probability that an arriving car wants a DC port (read only
            with ``fixed_departures``).
        dc_margin_min: ``(2,)`` the range of the uniform margin (minutes, rounded to whole
            steps) a DC user stays beyond the earliest finish of its charge (read only with
            ``fixed_departures``).
        fleet_share: ``(K,)`` share of each car model; sums to 1.
        fleet_capacity_kwh: ``(K,)`` battery capacity of each model (kWh).
        fleet_ac_kw: ``(K,)`` charging limit of each model at AC ports (kW).
        fleet_dc_kw: ``(K,)`` charging limit of each model at DC ports (kW).
        fleet_tau: ``(K,)`` SoC above which each model's charge rate tapers.
        fleet_ac_discharge_kw: ``(K,)`` discharge (V2G) limit at AC ports (kW), 0 = cannot
            discharge.
        fleet_dc_discharge_kw: ``(K,)`` discharge (V2G) limit at DC ports (kW).
        moer_kg_per_kwh: ``(Dm, T)`` marginal emission rate (kg CO2/kWh); zeros when no
            MOER data.
        grid_demand_kwh: ``(T,)`` grid demand signal per step for the grid-demand penalty
            (kWh).
        reset_days: ``(R,)`` int32 day indices ``reset`` draws from (by default all days an
            episode can start on, `chargax_marl.core.clock.num_episode_starts`).
        battery_soc0_low: ``(B,)`` the initial SoC of each station battery is uniform in
            ``[low, high]``.
        battery_soc0_high: ``(B,)`` the high end of that range.
        battery_wear_eur_kwh: ``(B,)`` wear cost per kWh into or out of each battery's cells
            (EUR/kWh).
        battery_calendar_eur_step: ``(B,)`` calendar ageing cost of each battery per step
            (EUR).
        customer_price_eur_kwh: ``()`` p_sell, price charged to (and refunded to) car owners
            (EUR/kWh).
        refund_discharged_energy: ``()`` bool: car owners get p_sell back for energy taken
            out of their car (default); False: they pay for energy put in and get nothing
            back (the original Chargax).
        grid_fee_eur_kwh: ``()`` added to the day-ahead price when buying (EUR/kWh).
        tou_fee_eur_kwh: ``(24,)`` time-of-use surcharge on the buy price per local hour
            (EUR/kWh; zeros: none).
        peak_demand_eur_kw: ``()`` EUR per kW of the day's highest net grid draw (0: no peak
            charge).
        peak_demand_incremental: ``()`` bool: book the peak charge as the running peak
            rises, else at the last step.
        feed_in_factor: ``()`` p_sell,grid = factor * day-ahead price.
        fixed_cost_eur: ``()`` c_dt, the fixed cost per step (EUR).
        alpha: the penalty weights.
        battery_value_day_mean: ``()`` bool: value the batteries' energy change at the day's
            mean buy price.
        battery_value_eur_kwh: ``()`` fixed price of that energy change when the flag is off
            (EUR/kWh; 0 = no value).
        beta: ``()`` weight of undertime in the charge-sensitive satisfaction term (default
            0).
        charged_tolerance_kwh: ``()`` a charge-sensitive car leaves when the energy it still
            wants is at most this (kWh).
        step_minutes: the step length (minutes).
        num_steps: ``T``, the steps per day.
        num_levels: ``L``, the discrete action levels per direction.
        action_mode: ``"absolute"``, ``"delta"`` or ``"continuous"``.
        v2g: ports with a discharge current may discharge cars.
        constraint_mode: ``"hard"`` (rescale to the node limits) or ``"soft"`` (report the
            excess).
        price_horizon_hours: hours of upcoming prices in the observation.
        observe_moer: MOER now is part of the observation.
        episode_start_hour: the local hour (0..23) an episode starts at on its day; step
            ``t`` is at ``episode_start_hour + t * step_minutes / 60`` hours of ``state.day``,
            hours of 24 and more on the next day (`chargax_marl.core.clock`). 0: the
            calendar day.
        fixed_departures: every car's departure is set when it arrives (the session model
            v3): a car parks at a free port of the kind it wants (``dc_share``), an AC
            user stays its drawn stay, a DC user the earliest finish of its charge at its
            port plus a margin (``dc_margin_min``), and no user leaves when charged; so the
            occupancy of a day does not depend on the policy.
        episode_days: the consecutive days an episode spans (1: one day); the episode is
            ``num_steps * episode_days`` steps long (`chargax_marl.core.clock`).
    """

    station: StationArrays
    # --- exogenous data
    prices_eur_kwh: jnp.ndarray
    day_price_quantiles_eur_kwh: jnp.ndarray
    first_weekday: jnp.ndarray
    arrival_rate: jnp.ndarray
    holiday: jnp.ndarray
    weekday_volume_factors: jnp.ndarray
    daily_volume_cv: jnp.ndarray
    stay_quantiles_min: jnp.ndarray
    stay_scale_by_hour: jnp.ndarray
    demand_quantiles_kwh: jnp.ndarray
    demand_scale_by_hour: jnp.ndarray
    stay_demand_corr: jnp.ndarray
    request_ratio_quantiles: jnp.ndarray
    arrival_soc_range: jnp.ndarray
    charge_sensitive_prob: jnp.ndarray
    dc_charge_sensitive_prob: jnp.ndarray
    random_port_choice: jnp.ndarray
    dc_share: jnp.ndarray
    dc_margin_min: jnp.ndarray
    fleet_share: jnp.ndarray
    fleet_capacity_kwh: jnp.ndarray
    fleet_ac_kw: jnp.ndarray
    fleet_dc_kw: jnp.ndarray
    fleet_tau: jnp.ndarray
    fleet_ac_discharge_kw: jnp.ndarray
    fleet_dc_discharge_kw: jnp.ndarray
    moer_kg_per_kwh: jnp.ndarray
    grid_demand_kwh: jnp.ndarray
    reset_days: jnp.ndarray
    battery_soc0_low: jnp.ndarray
    battery_soc0_high: jnp.ndarray
    battery_wear_eur_kwh: jnp.ndarray
    battery_calendar_eur_step: jnp.ndarray
    # --- economics
    customer_price_eur_kwh: jnp.ndarray
    refund_discharged_energy: jnp.ndarray
    grid_fee_eur_kwh: jnp.ndarray
    tou_fee_eur_kwh: jnp.ndarray
    peak_demand_eur_kw: jnp.ndarray
    peak_demand_incremental: jnp.ndarray
    feed_in_factor: jnp.ndarray
    fixed_cost_eur: jnp.ndarray
    alpha: PenaltyWeights
    battery_value_day_mean: jnp.ndarray
    battery_value_eur_kwh: jnp.ndarray
    beta: jnp.ndarray
    charged_tolerance_kwh: jnp.ndarray
    # --- static settings (changing them recompiles)
    step_minutes: float = struct.field(pytree_node=False, default=5.0)
    num_steps: int = struct.field(pytree_node=False, default=288)
    num_levels: int = struct.field(pytree_node=False, default=10)
    action_mode: str = struct.field(pytree_node=False, default="absolute")
    v2g: bool = struct.field(pytree_node=False, default=True)
    constraint_mode: str = struct.field(pytree_node=False, default="hard")
    price_horizon_hours: int = struct.field(pytree_node=False, default=6)
    observe_moer: bool = struct.field(pytree_node=False, default=False)
    episode_start_hour: int = struct.field(pytree_node=False, default=0)
    fixed_departures: bool = struct.field(pytree_node=False, default=False)
    episode_days: int = struct.field(pytree_node=False, default=1)

    @property
    def num_days(self) -> int:
        return self.prices_eur_kwh.shape[0]

    @property
    def step_hours(self) -> float:
        return self.step_minutes / 60.0


@struct.dataclass
class EpisodeTotals:
    """Running totals of the episode (reset with the state). Energies in kWh, money in EUR.

    Each field is a ``()`` float32 over the steps of the episode so far.

    Attributes:
        reward: the reward.
        profit_eur: the profit.
        energy_charged_kwh: energy into cars (charging leaves only).
        energy_discharged_kwh: energy out of cars (V2G), a positive number.
        energy_delivered_kwh: net energy into cars = charged - discharged.
        battery_net_kwh: net energy into station batteries.
        grid_import_kwh: energy drawn from the grid in steps with net draw > 0.
        grid_export_kwh: energy fed to the grid in steps with net draw <= 0, a positive
            number.
        losses_kwh: energy lost between the grid and the cars and batteries (path
            efficiencies).
        cars_arrived: cars that arrived and parked.
        cars_served: departed cars.
        cars_rejected: cars turned away for want of a free port.
        missing_kwh: energy still wanted by time-sensitive cars at departure.
        overtime_min: minutes that parked charge-sensitive cars spent beyond their plan.
        constraint_excess_kw: summed over steps of the excess that flowed (max over nodes;
            0 in hard mode).
        requested_excess_kw: summed over steps of the excess the controller asked for.
        battery_terminal_value_eur: value of the batteries' energy change, booked at the
            last step.
        peak_grid_kw: running maximum of the net grid draw (kW, step average) so far today.
        peak_demand_charge_eur: peak-demand charge booked so far (part of ``profit_eur``,
            positive = paid).
        battery_wear_eur: battery wear booked so far (part of ``profit_eur``, positive =
            paid).
        satisfaction_sum: sum over departed cars of their satisfaction in [0, 1].
        satisfaction_sq_sum: sum over departed cars of their satisfaction squared.
        satisfaction_shortfall_max: max over departed cars of 1 - satisfaction.
        cars_served_time_sensitive: departed time-sensitive cars (u = 0).
        satisfaction_sum_time_sensitive: their satisfaction summed.
    """

    reward: jnp.ndarray
    profit_eur: jnp.ndarray
    energy_charged_kwh: jnp.ndarray
    energy_discharged_kwh: jnp.ndarray
    energy_delivered_kwh: jnp.ndarray
    battery_net_kwh: jnp.ndarray
    grid_import_kwh: jnp.ndarray
    grid_export_kwh: jnp.ndarray
    losses_kwh: jnp.ndarray
    cars_arrived: jnp.ndarray
    cars_served: jnp.ndarray
    cars_rejected: jnp.ndarray
    missing_kwh: jnp.ndarray
    overtime_min: jnp.ndarray
    constraint_excess_kw: jnp.ndarray
    requested_excess_kw: jnp.ndarray
    battery_terminal_value_eur: jnp.ndarray
    peak_grid_kw: jnp.ndarray
    peak_demand_charge_eur: jnp.ndarray
    battery_wear_eur: jnp.ndarray
    satisfaction_sum: jnp.ndarray
    satisfaction_sq_sum: jnp.ndarray
    satisfaction_shortfall_max: jnp.ndarray
    cars_served_time_sensitive: jnp.ndarray
    satisfaction_sum_time_sensitive: jnp.ndarray

    @classmethod
    def zeros(cls) -> EpisodeTotals:
        z = jnp.zeros((), jnp.float32)
        return cls(**{f: z for f in cls.__dataclass_fields__})


@struct.dataclass
class EnvState:
    """The station state. Per-leaf fields have shape ``(L,)``: ports, then batteries.

    Batteries are leaves that are always occupied, never depart and have arrival SoC 0.
    A free port holds zeros in every car field.

    Attributes:
        current_a: signed current set at the leaf (A; negative = discharging).
        occupied: bool, a car (or a battery) is at the leaf.
        soc: state of charge in [0, 1].
        energy_remaining_kwh: energy the user still wants, ``(target_soc - soc) * capacity``
            (kWh, >= 0).
        time_remaining_min: minutes until the planned departure (may go negative).
        slack_min: planned stay minus the earliest finish the car's curve allows at its port
            (minutes, set at arrival).
        capacity_kwh: battery capacity C of the car (kWh).
        max_rate_kw: r-bar of the car for this port's kind (kW).
        max_discharge_rate_kw: the car's discharge limit for this port's kind (kW; 0 =
            cannot discharge).
        target_soc: SoC at which the car stops charging: arrival SoC + demand / capacity
            (<= 1).
        tau: bulk/absorption transition SoC.
        charge_sensitive: bool, u = 1.
        arrival_soc: SoC at arrival: discharging never goes below it.
        request_extra_kwh: what the car's user asked for beyond the energy the car takes
            (kWh, >= 0; the request is ``(target_soc - arrival_soc) * capacity`` plus this).
        day: ``()`` int32 index into the price data of the day the episode starts on.
        timestep: ``()`` int32 step of the episode, ``0..num_steps * episode_days`` (its
            clock time: `chargax_marl.core.clock`).
        is_workday: ``()`` bool, the day type of the calendar day the step falls on.
        day_volume: ``()`` the day's arrival intensity factor (weekday factor times the
            day's draw, see `chargax_marl.core.traffic.day_volume`): the start day's for a
            one-day episode, the calendar day of the step's for ``episode_days > 1``.
        totals: the episode's running totals.
    """

    current_a: jnp.ndarray
    occupied: jnp.ndarray
    soc: jnp.ndarray
    energy_remaining_kwh: jnp.ndarray
    time_remaining_min: jnp.ndarray
    slack_min: jnp.ndarray
    capacity_kwh: jnp.ndarray
    max_rate_kw: jnp.ndarray
    max_discharge_rate_kw: jnp.ndarray
    target_soc: jnp.ndarray
    tau: jnp.ndarray
    charge_sensitive: jnp.ndarray
    arrival_soc: jnp.ndarray
    request_extra_kwh: jnp.ndarray
    day: jnp.ndarray
    timestep: jnp.ndarray
    is_workday: jnp.ndarray
    day_volume: jnp.ndarray
    totals: EpisodeTotals

    @property
    def time(self) -> jnp.ndarray:
        """gymnax's name for the step counter."""
        return self.timestep


@struct.dataclass
class StepInfo:
    """What one transition reports. Energies in kWh, money in EUR, scalars unless noted.

    Attributes:
        reward: the step's reward.
        profit_eur: the step's profit.
        penalties: name -> ``()`` value of each term c (unweighted), keys = `PENALTY_TERMS`.
        energy_charged_kwh: energy into cars (charging leaves only).
        energy_discharged_kwh: energy out of cars (V2G), a positive number.
        energy_delivered_kwh: Delta E_net, net energy into cars.
        battery_net_kwh: Delta E_b, net energy into station batteries (terminal side).
        grid_net_kwh: Delta E_grid,net, net energy drawn from the grid (negative = fed in).
        losses_kwh: energy lost between the grid and the cars and batteries.
        price_buy_eur_kwh: the step's buy price (EUR/kWh).
        price_sell_grid_eur_kwh: the step's feed-in price (EUR/kWh).
        cars_arrived: cars that arrived and parked this step.
        cars_departed: cars that left this step.
        cars_rejected: cars turned away this step for want of a free port.
        missing_kwh: energy still wanted by the time-sensitive cars that left this step.
        overtime_min: minutes this step that parked charge-sensitive cars spent beyond their
            plan.
        constraint_excess_kw: grid-side excess that flowed (0 in hard mode).
        requested_excess_kw: grid-side excess of the currents the controller asked for.
        battery_terminal_value_eur: nonzero at the last step only; included in
            ``profit_eur``.
        peak_demand_charge_eur: peak-demand charge booked this step (subtracted in
            ``profit_eur``).
        battery_wear_eur: battery wear this step, cycling and calendar (subtracted in
            ``profit_eur``).
        satisfaction_sum: summed satisfaction of the cars that left this step.
        satisfaction_min: the least satisfied of them (1 when none left).
        leaf_energy_kwh: ``(L,)`` energy into each car / battery this step (terminal side).
        leaf_arrived: ``(L,)`` bool, the ports that received a new car at the end of this
            step.
        leaf_reward: ``(L,)`` each leaf's share of reward (``reward.leaf_reward_shares``);
            sums to reward.
    """

    reward: jnp.ndarray
    profit_eur: jnp.ndarray
    penalties: dict
    energy_charged_kwh: jnp.ndarray
    energy_discharged_kwh: jnp.ndarray
    energy_delivered_kwh: jnp.ndarray
    battery_net_kwh: jnp.ndarray
    grid_net_kwh: jnp.ndarray
    losses_kwh: jnp.ndarray
    price_buy_eur_kwh: jnp.ndarray
    price_sell_grid_eur_kwh: jnp.ndarray
    cars_arrived: jnp.ndarray
    cars_departed: jnp.ndarray
    cars_rejected: jnp.ndarray
    missing_kwh: jnp.ndarray
    overtime_min: jnp.ndarray
    constraint_excess_kw: jnp.ndarray
    requested_excess_kw: jnp.ndarray
    battery_terminal_value_eur: jnp.ndarray
    peak_demand_charge_eur: jnp.ndarray
    battery_wear_eur: jnp.ndarray
    satisfaction_sum: jnp.ndarray
    satisfaction_min: jnp.ndarray
    leaf_energy_kwh: jnp.ndarray
    leaf_arrived: jnp.ndarray
    leaf_reward: jnp.ndarray
