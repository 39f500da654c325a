"""Helpers to build hand-made states for the model tests."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from chargax_marl.core import simulator


def place_car(state, i, *, soc=0.3, capacity_kwh=60.0, max_rate_kw=100.0, tau=0.8, remaining_kwh=20.0,
              time_min=60.0, charge_sensitive=False, arrival_soc=None, current_a=0.0, target_soc=1.0,
              max_discharge_rate_kw=None, earliest_min=0.0):
    """Return ``state`` with a car parked at leaf ``i`` (by default it may charge to full and
    discharge at its charging rate)."""
    arrival_soc = soc if arrival_soc is None else arrival_soc
    max_discharge_rate_kw = max_rate_kw if max_discharge_rate_kw is None else max_discharge_rate_kw
    return state.replace(
        target_soc=state.target_soc.at[i].set(target_soc),
        max_discharge_rate_kw=state.max_discharge_rate_kw.at[i].set(max_discharge_rate_kw),
        slack_min=state.slack_min.at[i].set(time_min - earliest_min),
        occupied=state.occupied.at[i].set(True),
        soc=state.soc.at[i].set(soc),
        capacity_kwh=state.capacity_kwh.at[i].set(capacity_kwh),
        max_rate_kw=state.max_rate_kw.at[i].set(max_rate_kw),
        tau=state.tau.at[i].set(tau),
        energy_remaining_kwh=state.energy_remaining_kwh.at[i].set(remaining_kwh),
        time_remaining_min=state.time_remaining_min.at[i].set(time_min),
        charge_sensitive=state.charge_sensitive.at[i].set(charge_sensitive),
        arrival_soc=state.arrival_soc.at[i].set(arrival_soc),
        current_a=state.current_a.at[i].set(current_a),
    )


def no_arrivals(params):
    """The same params with zero arrival rate, so hand-built states evolve without new cars."""
    return params.replace(arrival_rate=jnp.zeros_like(params.arrival_rate))


def start(params, day=0):
    return simulator.empty_state(jnp.asarray(day), params)


def random_rollout(params, key, num_steps=None, policy="random"):
    """Scan ``num_steps`` steps with uniform random levels; return (states_before, infos)."""
    from chargax_marl.policies import POLICIES

    num_steps = num_steps or params.num_steps
    pol = POLICIES[policy]

    def body(state, k):
        k1, k2 = jax.random.split(k)
        levels = pol(state, k1, params)
        new_state, info = simulator.step(k2, state, levels, params)
        return new_state, (state, levels, new_state, info)

    state = simulator.reset(key, params)
    _, out = jax.lax.scan(body, state, jax.random.split(key, num_steps))
    return out
