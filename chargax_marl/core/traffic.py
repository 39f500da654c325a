"""Cars leaving and arriving: steps 3 and 4 of the transition.

Departures follow the user type: time-sensitive users (u = 0) leave when their planned
stay is over, charge-sensitive users (u = 1) when their energy demand is met. Arrivals are
Poisson with the rate of the day type and step, clipped by the free ports (the surplus is
rejected) and placed first-free-port in port order; each car draws a car profile from the
fleet and a user profile from the location's distributions.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from chargax_marl.core.station import KIND_AC, KIND_BATTERY
from chargax_marl.core.types import EnvParams, EnvState

CAR_FIELDS = ("current_a", "soc", "energy_remaining_kwh", "time_remaining_min", "capacity_kwh", "max_rate_kw",
              "tau", "arrival_soc")


def depart(state: EnvState, params: EnvParams):
    """Step 3: remove leaving cars and report the satisfaction quantities.

    Returns ``(new_state, report)`` with ``report`` holding ``departed`` (count),
    ``missing_kwh`` (sum of unmet demand of time-sensitive leavers, c_satisfaction,0),
    ``overtime_min`` and ``undertime_min`` of charge-sensitive leavers, and
    ``satisfaction_charge`` = overtime - beta * undertime (c_satisfaction,1).
    """
    is_port = params.station.leaf_kind != KIND_BATTERY
    active = state.occupied & is_port
    time_up = active & ~state.charge_sensitive & (state.time_remaining_min <= 0.0)
    charged = active & state.charge_sensitive & (state.energy_remaining_kwh <= params.charged_tolerance_kwh)
    leaving = time_up | charged
    missing = jnp.sum(jnp.where(time_up, jnp.maximum(state.energy_remaining_kwh, 0.0), 0.0))
    overtime = jnp.sum(jnp.where(charged, jnp.maximum(-state.time_remaining_min, 0.0), 0.0))
    undertime = jnp.sum(jnp.where(charged, jnp.maximum(state.time_remaining_min, 0.0), 0.0))
    cleared = {f: jnp.where(leaving, 0.0, getattr(state, f)) for f in CAR_FIELDS}
    new_state = state.replace(
        occupied=state.occupied & ~leaving,
        charge_sensitive=state.charge_sensitive & ~leaving,
        **cleared,
    )
    report = {
        "departed": jnp.sum(leaving).astype(jnp.float32),
        "missing_kwh": missing,
        "overtime_min": overtime,
        "undertime_min": undertime,
        "satisfaction_charge": overtime - params.beta * undertime,
    }
    return new_state, report


def _inverse_cdf(table: jnp.ndarray, u: jnp.ndarray) -> jnp.ndarray:
    """Sample from a quantile table at evenly spaced probabilities by linear interpolation."""
    q = table.shape[0]
    x = u * (q - 1)
    lo = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, q - 2)
    w = x - lo
    return table[lo] * (1.0 - w) + table[lo + 1] * w


def arrival_rate(timestep: jnp.ndarray, is_workday: jnp.ndarray, params: EnvParams) -> jnp.ndarray:
    """Expected number of arrivals in this step (lambda of the Poisson draw)."""
    t = jnp.clip(timestep, 0, params.arrival_rate.shape[1] - 1)
    return params.arrival_rate[jnp.where(is_workday, 0, 1), t]


def arrive(key: jax.Array, state: EnvState, params: EnvParams):
    """Step 4: sample arrivals, reject the surplus, park the rest first-free-port.

    ``state.timestep`` is the step in which the cars arrive (its hour scales the stay and
    demand). Returns ``(new_state, report)`` with ``arrived``, ``rejected`` and
    ``requested`` counts.
    """
    st = params.station
    key_n, key_u = jax.random.split(key)
    is_port = st.leaf_kind != KIND_BATTERY
    free = is_port & ~state.occupied
    num_free = jnp.sum(free)
    requested = jax.random.poisson(key_n, arrival_rate(state.timestep, state.is_workday, params))
    admitted = jnp.minimum(requested, num_free)
    rank = jnp.cumsum(free) - 1  # rank among free ports, in port order
    new_car = free & (rank < admitted)

    num_leaves = st.leaf_kind.shape[0]
    u = jax.random.uniform(key_u, (5, num_leaves))
    # Car profile: model index by inverse CDF of the fleet shares.
    cdf = jnp.cumsum(params.fleet_share)
    model = jnp.clip(jnp.searchsorted(cdf / cdf[-1], u[0], side="right"), 0, cdf.shape[0] - 1)
    capacity = params.fleet_capacity_kwh[model]
    max_rate = jnp.where(st.leaf_kind == KIND_AC, params.fleet_ac_kw[model], params.fleet_dc_kw[model])
    tau = params.fleet_tau[model]
    # User profile: stay and demand scaled by the arrival hour, uniform arrival SoC, user type.
    hour = jnp.clip((state.timestep * params.step_minutes / 60.0).astype(jnp.int32), 0, 23)
    stay = _inverse_cdf(params.stay_quantiles_min, u[1]) * params.stay_scale_by_hour[hour]
    stay = jnp.maximum(stay, params.step_minutes)
    lo, hi = params.arrival_soc_range[0], params.arrival_soc_range[1]
    soc0 = lo + (hi - lo) * u[2]
    demand = _inverse_cdf(params.demand_quantiles_kwh, u[3]) * params.demand_scale_by_hour[hour]
    demand = jnp.clip(demand, 0.0, (1.0 - soc0) * capacity)
    sensitive = u[4] < params.charge_sensitive_prob

    def put(new, old):
        return jnp.where(new_car, new, old)

    new_state = state.replace(
        occupied=state.occupied | new_car,
        current_a=put(0.0, state.current_a),
        soc=put(soc0, state.soc),
        arrival_soc=put(soc0, state.arrival_soc),
        energy_remaining_kwh=put(demand, state.energy_remaining_kwh),
        time_remaining_min=put(stay, state.time_remaining_min),
        capacity_kwh=put(capacity, state.capacity_kwh),
        max_rate_kw=put(max_rate, state.max_rate_kw),
        tau=put(tau, state.tau),
        charge_sensitive=jnp.where(new_car, sensitive, state.charge_sensitive),
    )
    report = {
        "requested": requested.astype(jnp.float32),
        "arrived": admitted.astype(jnp.float32),
        "rejected": (requested - admitted).astype(jnp.float32),
    }
    return new_state, report
