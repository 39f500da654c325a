"""Cars leaving and arriving: steps 3 and 4 of the transition.

Departures follow the user type: time-sensitive users (u = 0) leave when their planned
stay is over, charge-sensitive users (u = 1) when they reach their target SoC. Every car
carries a target SoC (arrival SoC + demand / capacity) and stops charging there, and its
user's request (the demand over a drawn ratio in (0, 1]: users ask for more than their car
takes), against which satisfaction and missing energy are measured. Arrivals are Poisson
with the rate of the day type and step times the day's volume factor (`day_volume`: the
weekday's factor and a log-normal draw per day), clipped by the free ports (the surplus is
rejected) and placed first-free-port in port order; each car draws a car profile from the
fleet and a user profile from the location's distributions (stay and demand conditional on
the arrival hour). The draw
(`draw_arrivals`) does not look at the station, so the cars of a day do not depend on
the policy; `place_arrivals` parks them.

With ``params.fixed_departures`` (the session model v3) every car's departure is set when it
arrives: each car wants one port kind (DC with probability ``params.dc_share``) and parks at
a free port of that kind (turned away when none is free); an AC user stays its drawn stay, a
DC user the earliest finish of its charge at its port (`earliest_finish_min`) plus a drawn
margin, and no user leaves when charged. Which ports are free, where a car parks and which
cars are turned away then follow from the day's cars and key alone, whatever the policy does.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from chargax_marl.core import clock, rng
from chargax_marl.core.station import KIND_AC, KIND_BATTERY, KIND_DC
from chargax_marl.core.types import EnvParams, EnvState

CAR_FIELDS = (
    "current_a",
    "soc",
    "energy_remaining_kwh",
    "time_remaining_min",
    "slack_min",
    "capacity_kwh",
    "max_rate_kw",
    "max_discharge_rate_kw",
    "target_soc",
    "tau",
    "arrival_soc",
    "request_extra_kwh",
)


def depart(state: EnvState, params: EnvParams):
    """Step 3: remove leaving cars and report the satisfaction quantities.

    Time-sensitive cars leave when their planned stay is over; charge-sensitive cars when
    they reach their target SoC (remaining demand at most ``charged_tolerance_kwh``).

    Returns ``(new_state, report)`` with ``report`` holding ``departed`` (count),
    ``missing_kwh`` (unmet request of time-sensitive leavers, `unmet_request_kwh`: the
    energy to their target SoC plus what their users asked for beyond it;
    c_satisfaction,0), ``overtime_min`` (minutes of this step that parked charge-sensitive
    cars spent beyond their planned stay), ``undertime_min`` and ``satisfaction_charge`` =
    overtime - beta * undertime (c_satisfaction,1), plus the per-leaf ``leaf_missing_kwh``
    and ``leaf_satisfaction_charge`` (L,), and the service of the leaving cars
    (`satisfaction`): ``satisfaction_sum``, ``satisfaction_sq_sum``,
    ``satisfaction_min`` (1 when no car leaves), ``departed_time_sensitive`` and
    ``satisfaction_sum_time_sensitive`` (over the time-sensitive leavers, u = 0).

    Overtime accrues step by step while the car is parked past its plan, so over a stay it
    sums to the minutes the car overstayed. (Counting it only when the car left let a policy
    that never brought a late car to its target escape the penalty: the car stayed until
    the episode ended and its overtime was never booked.)

    ``undertime_min`` is measured against the earliest finish the car's rate curve allows at
    its port (alone on its path, see `earliest_finish_min`), not against the drawn
    planned stay, which no policy controls: it is minus the minutes, within the planned
    stay, that the car stayed beyond that earliest finish (0 when it left as early as it
    could). So with ``beta > 0`` every avoidable minute costs ``beta`` up to the planned
    departure and ``1`` after it. ``beta`` is 0 by default (the term is then the overtime).

    Args:
        state: the state after charging (`chargax_marl.core.physics.charge`).
        params: the environment parameters (``charged_tolerance_kwh``, ``beta``, the step
            length).

    Returns:
        ``(new_state, report)``: the state with the leaving cars' ports emptied (their car
        fields 0, not occupied), and the report above, its counts and sums ``()`` float32
        (kWh, minutes) and its ``leaf_*`` entries ``(L,)``.
    """
    is_port = params.station.leaf_kind != KIND_BATTERY
    active = state.occupied & is_port
    time_up = active & ~state.charge_sensitive & (state.time_remaining_min <= 0.0)
    charged = (
        active
        & state.charge_sensitive
        & (state.energy_remaining_kwh <= params.charged_tolerance_kwh)
    )
    leaving = rng.materialize(time_up | charged)
    leaf_missing = jnp.where(time_up, jnp.maximum(unmet_request_kwh(state), 0.0), 0.0)
    # this step's minutes past the plan (physics has already taken the step off the clock)
    leaf_over = jnp.where(
        active & state.charge_sensitive,
        jnp.clip(-state.time_remaining_min, 0.0, params.step_minutes),
        0.0,
    )
    slack = jnp.maximum(state.slack_min, 0.0)  # planned stay - earliest finish
    delay = jnp.maximum(
        state.slack_min - state.time_remaining_min, 0.0
    )  # minutes parked beyond the earliest finish
    leaf_under = jnp.where(charged, -jnp.minimum(delay, slack), 0.0)
    leaf_charge_term = leaf_over - params.beta * leaf_under
    sat = jnp.where(leaving, satisfaction(state, params), 0.0)
    time_sensitive = leaving & ~state.charge_sensitive
    cleared = {f: jnp.where(leaving, 0.0, getattr(state, f)) for f in CAR_FIELDS}
    new_state = state.replace(
        occupied=state.occupied & ~leaving,
        charge_sensitive=state.charge_sensitive & ~leaving,
        **cleared,
    )
    report = {
        "departed": jnp.sum(leaving).astype(jnp.float32),
        "missing_kwh": jnp.sum(leaf_missing),
        "overtime_min": jnp.sum(leaf_over),
        "undertime_min": jnp.sum(leaf_under),
        "satisfaction_charge": jnp.sum(leaf_charge_term),
        "leaf_missing_kwh": leaf_missing,
        "leaf_satisfaction_charge": leaf_charge_term,
        "satisfaction_sum": jnp.sum(sat),
        "satisfaction_sq_sum": jnp.sum(sat * sat),
        "satisfaction_min": jnp.min(jnp.where(leaving, sat, 1.0)),
        "departed_time_sensitive": jnp.sum(time_sensitive).astype(jnp.float32),
        "satisfaction_sum_time_sensitive": jnp.sum(jnp.where(time_sensitive, sat, 0.0)),
    }
    return new_state, report


def requested_kwh(state: EnvState) -> jnp.ndarray:
    """Each leaf's request, ``(L,)`` kWh: the energy the car takes, ``capacity * (target_soc -
    arrival_soc)``, plus what its user asked for beyond that (``request_extra_kwh``).

    Args:
        state: the state.

    Returns:
        ``(L,)`` kWh (0 at free ports, whose car fields are 0).
    """
    return state.capacity_kwh * (state.target_soc - state.arrival_soc) + state.request_extra_kwh


def unmet_request_kwh(state: EnvState) -> jnp.ndarray:
    """Each leaf's energy still missing from its user's request, ``(L,)`` kWh: the energy the
    car still takes plus what its user asked for beyond that (``request_extra_kwh``).

    Args:
        state: the state.

    Returns:
        ``(L,)`` kWh, ``max(energy_remaining_kwh, 0) + request_extra_kwh``.
    """
    return jnp.maximum(state.energy_remaining_kwh, 0.0) + state.request_extra_kwh


def satisfaction(state: EnvState, params: EnvParams) -> jnp.ndarray:
    """Each parked car's satisfaction if it left now, ``(L,)`` (0 where no car is parked).

    The energy delivered over the energy its user requested: ``1 - unmet / requested``
    (`unmet_request_kwh`, `requested_kwh`), clipped to ``[0, 1]``; 1 when the unmet request
    is within ``charged_tolerance_kwh`` (or the request was no more than that).

    Args:
        state: the state.
        params: the environment parameters (``charged_tolerance_kwh``).

    Returns:
        ``(L,)`` in ``[0, 1]``; 0 at free ports and at batteries.
    """
    is_car = state.occupied & (params.station.leaf_kind != KIND_BATTERY)
    remaining = unmet_request_kwh(state)
    served = remaining <= params.charged_tolerance_kwh
    share = jnp.clip(1.0 - remaining / jnp.maximum(requested_kwh(state), 1e-6), 0.0, 1.0)
    return jnp.where(is_car, jnp.where(served, 1.0, share), 0.0)


def earliest_finish_min(
    soc0, target_soc, capacity_kwh, max_rate_kw, tau, solo_max_kw, params: EnvParams
):
    """Minutes a car needs to reach its target (within ``charged_tolerance_kwh``) when it
    charges as fast as its rate curve and its port allow, alone on its path.

    Continuous time: constant power ``P = min(r-bar, solo_max_kw)`` until the taper
    ``r-bar (1 - SoC) / (1 - tau)`` falls below ``P``, then the taper (exponential approach
    to SoC 1). Rounded up to whole steps, at least one step (a car leaves at the earliest
    after one charging step). The simulator charges at the rate of the start of each step,
    which is never slower than this bound.

    The arguments are per car and broadcast against each other.

    Args:
        soc0: the arrival SoC.
        target_soc: the SoC the car charges to.
        capacity_kwh: the car's battery capacity (kWh).
        max_rate_kw: r-bar, the car's charging limit at its port's kind (kW).
        tau: the SoC where the car's taper starts.
        solo_max_kw: the most power the port can take alone on its path
            (``StationArrays.leaf_solo_max_kw``, kW).
        params: the environment parameters (``charged_tolerance_kwh``, ``step_minutes``).

    Returns:
        Minutes, a whole number of steps of ``step_minutes``, at least one step.
    """
    cap = jnp.maximum(capacity_kwh, 1e-6)
    rbar = jnp.maximum(max_rate_kw, 1e-6)
    power = jnp.maximum(jnp.minimum(rbar, solo_max_kw), 1e-6)
    goal = jnp.maximum(target_soc - params.charged_tolerance_kwh / cap, soc0)
    knee = jnp.clip(1.0 - power * (1.0 - tau) / rbar, tau, 1.0)  # where the taper falls below P
    bulk_h = cap * jnp.maximum(jnp.minimum(goal, knee) - soc0, 0.0) / power
    a = jnp.maximum(soc0, knee)
    taper_h = jnp.where(
        goal > a,
        (1.0 - tau)
        * cap
        / rbar
        * jnp.log(jnp.maximum(1.0 - a, 1e-9) / jnp.maximum(1.0 - goal, 1e-9)),
        0.0,
    )
    steps = jnp.maximum(jnp.ceil((bulk_h + taper_h) * 60.0 / params.step_minutes - 1e-4), 1.0)
    return steps * params.step_minutes


_COPULA_EPS = 1e-7  # keeps the normal quantiles of the uniforms finite


def _joined(u_stay: jnp.ndarray, u_demand: jnp.ndarray, params: EnvParams) -> jnp.ndarray:
    """The demand's uniform joined to the stay's by a Gaussian copula of correlation
    ``params.stay_demand_corr``: ``Phi(rho z_stay + sqrt(1 - rho^2) z_demand)`` with
    ``z = Phi^-1(u)``; ``u_demand`` itself, bit for bit, at a correlation of 0."""
    rho = params.stay_demand_corr
    z_stay = jax.scipy.special.ndtri(jnp.clip(u_stay, _COPULA_EPS, 1.0 - _COPULA_EPS))
    z_demand = jax.scipy.special.ndtri(jnp.clip(u_demand, _COPULA_EPS, 1.0 - _COPULA_EPS))
    joined = jax.scipy.special.ndtr(rho * z_stay + jnp.sqrt(1.0 - rho**2) * z_demand)
    return jnp.where(rho == 0.0, u_demand, joined)


def _inverse_cdf(table: jnp.ndarray, u: jnp.ndarray) -> jnp.ndarray:
    """Sample from a quantile table at evenly spaced probabilities by linear interpolation."""
    q = table.shape[0]
    x = u * (q - 1)
    lo = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, q - 2)
    w = x - lo
    return table[lo] * (1.0 - w) + table[lo + 1] * w


def arrival_rate(timestep: jnp.ndarray, is_workday: jnp.ndarray, params: EnvParams) -> jnp.ndarray:
    """Expected number of arrivals in this step on a day of volume factor 1 (the Poisson
    draw's rate is this times the day's `day_volume`): the rate of the step's slot of its
    calendar day (`chargax_marl.core.clock.slot_of_day`), for the day type ``is_workday`` of
    that calendar day (`chargax_marl.core.clock.is_workday`).

    Args:
        timestep: the step of the episode (int).
        is_workday: bool, the day type (row 0 of ``arrival_rate`` when true, row 1 else).
        params: the environment parameters (``arrival_rate``).

    Returns:
        Expected arrivals in the step, shaped as the broadcast of ``timestep`` and
        ``is_workday``.
    """
    return params.arrival_rate[jnp.where(is_workday, 0, 1), clock.slot_of_day(timestep, params)]


def day_volume(
    day: jnp.ndarray, params: EnvParams, key: jax.Array | None = None, stream: int = rng.VOLUME
) -> jnp.ndarray:
    """A day's arrival intensity factor ``()``: the volume factor of the day's weekday (1 on a
    public holiday) times a log-normal draw of mean 1 and coefficient of variation
    ``params.daily_volume_cv`` (1 without a key or with a CV of 0). A one-day episode keeps
    its first day's factor throughout (past midnight too); an episode of ``episode_days > 1``
    draws each new calendar day's at its midnight (`next_day_volume`).

    Args:
        day: the day's index into the price data.
        params: the environment parameters.
        key: the episode's reset key (the draw uses its own stream, `rng.VOLUME`), or the
            step's key at a midnight (``stream=rng.DAY_VOLUME``).
        stream: the key's stream the draw uses.

    Returns:
        ``()`` float32, the factor on the day's arrival rates.
    """
    factor = jnp.where(
        clock.is_holiday(day, params),
        1.0,
        params.weekday_volume_factors[clock.weekday(day, params)],
    )
    if key is None:
        return factor.astype(jnp.float32)
    u = rng.uniform(rng.key_seed(key), stream, (1,))[0]
    z = jax.scipy.special.ndtri(jnp.clip(u, 1e-7, 1.0 - 1e-7))
    var_log = jnp.log1p(params.daily_volume_cv**2)
    draw = jnp.exp(jnp.sqrt(var_log) * z - 0.5 * var_log)
    return (factor * draw).astype(jnp.float32)


def next_day_volume(key: jax.Array, day, timestep, volume, params: EnvParams) -> jnp.ndarray:
    """The volume factor of step ``timestep + 1`` of an episode of several days: a fresh
    `day_volume` of its calendar day when the step crosses midnight, else ``volume``.

    Args:
        key: the step's key (the draw uses its stream `rng.DAY_VOLUME`).
        day: the episode's day (``state.day``).
        timestep: the step just taken (``state.timestep`` before the step).
        volume: the factor of the step just taken (``state.day_volume``).
        params: the environment parameters (``episode_days > 1``; one-day episodes keep
            their start day's factor and do not call this).

    Returns:
        ``()`` float32, the factor for the next step. After the last step it is unchanged
        (the clock clamps to the episode).
    """
    now = clock.calendar_day(day, timestep, params)
    after = clock.calendar_day(day, timestep + 1, params)
    fresh = day_volume(after, params, key, rng.DAY_VOLUME)
    return jnp.where(after != now, fresh, volume).astype(jnp.float32)


@struct.dataclass
class Arrivals:
    """The cars that ask to park in one step, drawn without looking at the station's state.

    Slot ``k`` (of ``num_ports``) holds the ``k``-th car of the step; the station admits the
    first ``min(requested, free ports)`` of them and parks car ``k`` at the ``k``-th free port
    in port order, or with ``params.random_port_choice`` in port order rotated by a random
    number of free ports (``port_draw``): the step's first car at a uniformly random free
    port, the next ones at the free ports that follow it. Because the draw does not depend on
    the occupancy, the cars of a day are
    the same whatever the policy does (only which of them find a free port differs): this is
    what makes a day replayable (`chargax_marl.trace`). Fields over slots have shape
    ``(num_ports,)``; rates are given for both port kinds because the port is chosen later.

    Attributes:
        requested: ``()`` int32, cars asking to park this step (the surplus is rejected).
        model: ``(P,)`` int32 index of each car's model into the fleet.
        capacity_kwh: ``(P,)`` battery capacity (kWh).
        ac_kw: ``(P,)`` r-bar at an AC port (kW).
        dc_kw: ``(P,)`` r-bar at a DC port (kW).
        ac_discharge_kw: ``(P,)`` discharge limit at an AC port (kW).
        dc_discharge_kw: ``(P,)`` discharge limit at a DC port (kW).
        tau: ``(P,)`` SoC where the charge rate starts to taper.
        arrival_soc: ``(P,)`` SoC at arrival.
        target_soc: ``(P,)`` arrival SoC + demand / capacity (<= 1).
        stay_min: ``(P,)`` planned stay (minutes, at least one step).
        charge_sensitive: ``(P,)`` bool, u = 1 at an AC port.
        charge_sensitive_dc: ``(P,)`` bool, u = 1 at a DC port.
        request_ratio: ``(P,)`` energy taken over energy requested, in (0, 1].
        wants_dc: ``(P,)`` bool, the car wants a DC port (read with
            ``params.fixed_departures``; False otherwise).
        margin_min: ``(P,)`` the minutes a DC user stays beyond its earliest finish (whole
            steps; read with ``params.fixed_departures``; 0 otherwise).
        port_draw: ``()`` uniform in [0, 1): the rotation of the free ports' order.
    """

    requested: jnp.ndarray  # () int32, cars asking to park this step (the surplus is rejected)
    model: jnp.ndarray  # (P,) int32 index into the fleet
    capacity_kwh: jnp.ndarray  # (P,)
    ac_kw: jnp.ndarray  # (P,) r-bar at an AC port
    dc_kw: jnp.ndarray  # (P,) r-bar at a DC port
    ac_discharge_kw: jnp.ndarray  # (P,) discharge limit at an AC port
    dc_discharge_kw: jnp.ndarray  # (P,)
    tau: jnp.ndarray  # (P,)
    arrival_soc: jnp.ndarray  # (P,)
    target_soc: jnp.ndarray  # (P,) arrival SoC + demand / capacity (<= 1)
    stay_min: jnp.ndarray  # (P,) planned stay
    charge_sensitive: jnp.ndarray  # (P,) bool, u = 1 at an AC port
    charge_sensitive_dc: jnp.ndarray  # (P,) bool, u = 1 at a DC port
    request_ratio: jnp.ndarray  # (P,) energy taken / energy requested, in (0, 1]
    wants_dc: jnp.ndarray  # (P,) bool, the car wants a DC port (fixed departures)
    margin_min: jnp.ndarray  # (P,) a DC user's stay beyond its earliest finish (minutes)
    port_draw: jnp.ndarray  # () uniform: the rotation of the free ports' order


SLOT_FIELDS = (
    "model",
    "capacity_kwh",
    "ac_kw",
    "dc_kw",
    "ac_discharge_kw",
    "dc_discharge_kw",
    "tau",
    "arrival_soc",
    "target_soc",
    "stay_min",
    "charge_sensitive",
    "charge_sensitive_dc",
    "request_ratio",
    "wants_dc",
    "margin_min",
)
"""The per-slot fields of `Arrivals` (every field but ``requested``)."""


def draw_arrivals(
    key: jax.Array,
    timestep: jnp.ndarray,
    is_workday: jnp.ndarray,
    params: EnvParams,
    volume: jnp.ndarray | float = 1.0,
) -> Arrivals:
    """The step's arriving cars (`Arrivals`).

    A Poisson count with the rate of the day type and step times ``volume``, and per slot
    one car profile (fleet) and user profile (stay and demand from the arrival hour's
    tables, joined by the profile's Gaussian copula, arrival SoC, user type per port kind,
    request ratio). All of them come from
    ``key`` through `chargax_marl.core.rng` (one hash call; the count by inversion of the
    Poisson CDF).

    Args:
        key: the step's key.
        timestep: the step in which the cars arrive (its hour selects the stay and demand
            tables and scales).
        is_workday: ``()`` bool, the day type's row of the arrival rate.
        params: the environment parameters.
        volume: the day's volume factor (`day_volume`; the state's ``day_volume``).

    Returns:
        The step's `Arrivals`.
    """
    st = params.station
    num_slots = st.num_ports
    # One hash call gives the count's uniform, six uniforms per slot and the port rotation's
    # uniform (see `rng`).
    draws = rng.uniform(rng.key_seed(key), rng.ARRIVALS, (2 + 6 * num_slots,))
    requested = rng.poisson(draws[0], arrival_rate(timestep, is_workday, params) * volume)
    u = draws[1:-1].reshape(6, num_slots)
    # Car profile: model index by inverse CDF of the fleet shares.
    cdf = jnp.cumsum(params.fleet_share)
    # searchsorted by comparing with every entry (a fleet has tens of models): one fused
    # op, where the default binary search is a loop that costs a dispatch per iteration.
    model = jnp.clip(
        jnp.searchsorted(cdf / cdf[-1], u[0], side="right", method="compare_all"),
        0,
        cdf.shape[0] - 1,
    ).astype(jnp.int32)
    capacity = params.fleet_capacity_kwh[model]
    # User profile: stay and demand scaled by the arrival hour, user type.
    hour = clock.clock_hour(timestep, params)
    stay = _inverse_cdf(params.stay_quantiles_min[hour], u[1]) * params.stay_scale_by_hour[hour]
    stay = jnp.maximum(stay, params.step_minutes)
    # The demand fits the car: at most what fills it from the lowest arrival SoC. The
    # arrival SoC is uniform over the part of the profile's range that leaves room for the
    # demand, and the car's target is arrival SoC + demand / capacity (<= 1).
    lo, hi = params.arrival_soc_range[0], params.arrival_soc_range[1]
    demand = (
        _inverse_cdf(params.demand_quantiles_kwh[hour], _joined(u[1], u[3], params))
        * params.demand_scale_by_hour[hour]
    )
    demand = jnp.clip(demand, 0.0, (1.0 - lo) * capacity)
    hi_fit = jnp.maximum(jnp.minimum(hi, 1.0 - demand / jnp.maximum(capacity, 1e-6)), lo)
    soc0 = lo + (hi_fit - lo) * u[2]
    target = jnp.minimum(soc0 + demand / jnp.maximum(capacity, 1e-6), 1.0)
    if params.fixed_departures:
        # their own stream, so that the draws above are those of the session model v2
        kind_u, margin_u = rng.uniform(rng.key_seed(key), rng.PORT_KIND, (2, num_slots))
        wants_dc = kind_u < params.dc_share
        lo, hi = params.dc_margin_min[0], params.dc_margin_min[1]
        margin = jnp.round((lo + (hi - lo) * margin_u) / params.step_minutes) * params.step_minutes
    else:
        wants_dc = jnp.zeros((num_slots,), bool)
        margin = jnp.zeros((num_slots,), jnp.float32)
    return Arrivals(
        requested=requested,
        model=model,
        capacity_kwh=capacity,
        ac_kw=params.fleet_ac_kw[model],
        dc_kw=params.fleet_dc_kw[model],
        ac_discharge_kw=params.fleet_ac_discharge_kw[model],
        dc_discharge_kw=params.fleet_dc_discharge_kw[model],
        tau=params.fleet_tau[model],
        arrival_soc=soc0,
        target_soc=target,
        stay_min=stay,
        charge_sensitive=u[4] < params.charge_sensitive_prob,
        charge_sensitive_dc=u[4] < params.dc_charge_sensitive_prob,
        request_ratio=jnp.maximum(_inverse_cdf(params.request_ratio_quantiles, u[5]), 1e-3),
        wants_dc=wants_dc,
        margin_min=margin,
        port_draw=draws[-1],
    )


def place_arrivals(state: EnvState, arrivals: Arrivals, params: EnvParams):
    """Admit the first ``min(requested, free ports)`` cars of ``arrivals`` and park car ``k``
    at the ``k``-th free port in port order; reject the surplus.

    Returns ``(new_state, report)`` with ``arrived``, ``rejected`` and ``requested`` counts
    and ``leaf_arrived`` (L,) bool, the ports that received a car.

    With ``params.random_port_choice`` the free ports' order is rotated by
    ``arrivals.port_draw`` (see `Arrivals`). A parked car starts at current 0 with its
    planned stay, its demand ``(target_soc - arrival_soc) * capacity`` as the energy it
    still wants, the rates of its port's kind, its user type at that kind, and its slack
    (planned stay minus `earliest_finish_min`).

    With ``params.fixed_departures`` the cars that want a DC port (``arrivals.wants_dc``) and
    those that want an AC port are admitted apart, each to the free ports of its kind in the
    order above (the surplus of a kind is rejected); an AC car's stay is its planned stay, a
    DC car's its `earliest_finish_min` at its port plus ``arrivals.margin_min``, and no car
    is charge-sensitive.

    Args:
        state: the state after departures.
        arrivals: the step's cars (`draw_arrivals`).
        params: the environment parameters.

    Returns:
        ``(new_state, report)``: the state with the new cars parked, and the report, its
        counts ``()`` float32.
    """
    st = params.station
    is_port = st.leaf_kind != KIND_BATTERY
    free = is_port & ~state.occupied
    requested = arrivals.requested
    if params.fixed_departures:
        # each car parks at a free port of the kind it wants: AC and DC admitted apart
        in_step = jnp.arange(st.num_ports) < requested
        new_ac, slot_ac, admitted_ac = _admit(
            free & (st.leaf_kind == KIND_AC), in_step & ~arrivals.wants_dc, arrivals, params
        )
        new_dc, slot_dc, admitted_dc = _admit(
            free & (st.leaf_kind == KIND_DC), in_step & arrivals.wants_dc, arrivals, params
        )
        new_car = rng.materialize(new_ac | new_dc)
        slot = jnp.where(st.leaf_kind == KIND_AC, slot_ac, slot_dc)
        admitted = admitted_ac + admitted_dc
    else:
        num_free = jnp.sum(free)
        admitted = jnp.minimum(requested, num_free)
        rank = _free_port_rank(free, arrivals.port_draw, params)
        new_car = rng.materialize(free & (rank < admitted))
        slot = jnp.clip(rank, 0, st.num_ports - 1)
    car = arrivals.replace(**{f: getattr(arrivals, f)[slot] for f in SLOT_FIELDS})  # per leaf now

    is_ac = st.leaf_kind == KIND_AC
    max_rate = jnp.where(is_ac, car.ac_kw, car.dc_kw)
    max_dis = jnp.where(is_ac, car.ac_discharge_kw, car.dc_discharge_kw)
    demand = (car.target_soc - car.arrival_soc) * car.capacity_kwh
    charge_sensitive = jnp.where(is_ac, car.charge_sensitive, car.charge_sensitive_dc)
    earliest = earliest_finish_min(
        car.arrival_soc,
        car.target_soc,
        car.capacity_kwh,
        max_rate,
        car.tau,
        st.leaf_solo_max_kw,
        params,
    )

    stay = car.stay_min
    if params.fixed_departures:
        # a DC user stays as long as its charge takes at its port, plus its margin; nobody
        # leaves when charged
        stay = jnp.where(is_ac, car.stay_min, earliest + car.margin_min)
        charge_sensitive = jnp.zeros_like(charge_sensitive)

    def put(new, old):
        return jnp.where(new_car, new, old)

    new_state = state.replace(
        occupied=state.occupied | new_car,
        current_a=put(0.0, state.current_a),
        soc=put(car.arrival_soc, state.soc),
        arrival_soc=put(car.arrival_soc, state.arrival_soc),
        request_extra_kwh=put(demand / car.request_ratio - demand, state.request_extra_kwh),
        energy_remaining_kwh=put(demand, state.energy_remaining_kwh),
        time_remaining_min=put(stay, state.time_remaining_min),
        slack_min=put(stay - earliest, state.slack_min),
        capacity_kwh=put(car.capacity_kwh, state.capacity_kwh),
        max_rate_kw=put(max_rate, state.max_rate_kw),
        max_discharge_rate_kw=put(max_dis, state.max_discharge_rate_kw),
        target_soc=put(car.target_soc, state.target_soc),
        tau=put(car.tau, state.tau),
        charge_sensitive=jnp.where(new_car, charge_sensitive, state.charge_sensitive),
    )
    report = {
        "requested": requested.astype(jnp.float32),
        "arrived": admitted.astype(jnp.float32),
        "rejected": (requested - admitted).astype(jnp.float32),
        "leaf_arrived": new_car,
    }
    return new_state, report


def _free_port_rank(free: jnp.ndarray, port_draw: jnp.ndarray, params: EnvParams) -> jnp.ndarray:
    """Each free leaf's rank in the order arriving cars take the free ports, ``(L,)`` int
    (meaningless at leaves that are not free): port order, or with
    ``params.random_port_choice`` port order rotated by ``port_draw`` times the free ports."""
    num_free = jnp.sum(free)
    in_order = jnp.cumsum(free) - 1  # rank among free ports, in port order
    # random choice: the free ports' order rotated by a uniform number of them (a sort per
    # step would double the step's cost)
    offset = jnp.minimum((port_draw * num_free).astype(in_order.dtype), num_free - 1)
    rotated = jnp.mod(in_order - offset, jnp.maximum(num_free, 1))
    return jnp.where(params.random_port_choice, rotated, in_order)


def _admit(free: jnp.ndarray, wanting: jnp.ndarray, arrivals: Arrivals, params: EnvParams):
    """Park the cars of the slots ``wanting`` (``(P,)`` bool) at the leaves ``free`` (``(L,)``
    bool, the free ports of one kind): the ``k``-th of those cars at the ``k``-th of those
    ports in `_free_port_rank`'s order, the cars beyond the free ports turned away.

    Returns:
        ``(new_car, slot, admitted)``: ``(L,)`` bool, the leaves that get a car; ``(L,)``
        int, the slot of each such leaf's car; ``()`` the number of cars parked.
    """
    admitted = jnp.minimum(jnp.sum(wanting), jnp.sum(free))
    rank = _free_port_rank(free, arrivals.port_draw, params)
    new_car = free & (rank < admitted)
    car_rank = jnp.cumsum(wanting) - 1  # each wanting slot's rank among the wanting slots
    match = wanting[None, :] & (car_rank[None, :] == rank[:, None])  # (L, P)
    slot = jnp.argmax(match, axis=1)
    return new_car, slot, admitted


def arrive(key: jax.Array, state: EnvState, params: EnvParams):
    """Step 4: draw the step's cars (`draw_arrivals`) and park them
    (`place_arrivals`). ``state.timestep`` is the step in which the cars arrive.

    The day type is ``state.is_workday`` and the volume ``state.day_volume``.

    Args:
        key: the step's key.
        state: the state after departures.
        params: the environment parameters.

    Returns:
        ``(new_state, report)`` of `place_arrivals`.
    """
    return place_arrivals(
        state,
        draw_arrivals(key, state.timestep, state.is_workday, params, state.day_volume),
        params,
    )
