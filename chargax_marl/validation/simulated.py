"""The simulator's charging sessions, read off played days.

`simulate_sessions` plays days with a policy (always-max by default) and returns one record
per car that parked: its arrival time, the stay it realised (until it left, or until the
episode ended: ``cut``), the energy it received and the energy its user requested, and per
day the number of cars that asked to park and of those that parked (the sessions).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from chargax_marl import policies
from chargax_marl.core import clock, simulator, traffic
from chargax_marl.core.station import KIND_AC, KIND_BATTERY
from chargax_marl.core.types import EnvParams
from chargax_marl.trace import day_keys


@dataclass(frozen=True)
class SimulatedSessions:
    """Sessions of played days (arrays over sessions unless noted).

    Attributes:
        day: the day index (into the price data) of the episode.
        arrival_hour: clock hour at which the car arrived (fractional, the middle of its
            step).
        stay_min: realised stay (minutes): the steps the car was parked.
        time_left_min: the episode's minutes left after the car's arrival (the longest stay
            it could realise).
        delivered_kwh: energy into the car over its stay (kWh, terminal side).
        requested_kwh: its user's request (kWh).
        cut: the car was still parked when the episode ended.
        ac: the car parked at an AC port.
        day_requested: ``(days,)`` cars that asked to park on each played day, those turned
            away at a full station included.
        day_sessions: ``(days,)`` cars that parked on each played day: its sessions, as the
            real data counts them.
        day_workday: ``(days,)`` bool, the played day is a workday.
    """

    day: np.ndarray
    arrival_hour: np.ndarray
    stay_min: np.ndarray
    time_left_min: np.ndarray
    delivered_kwh: np.ndarray
    requested_kwh: np.ndarray
    cut: np.ndarray
    ac: np.ndarray
    day_requested: np.ndarray
    day_sessions: np.ndarray
    day_workday: np.ndarray


def _play(params: EnvParams, days, keys, policy):
    clock.require_one_day(params, "chargax_marl.validation.simulated._play")

    def one_day(day, key):
        act_keys, step_keys, battery_key = day_keys(key, params.num_steps)

        def body(state, ks):
            k_act, k_step = ks
            state, info = simulator.step(k_step, state, policy(state, k_act, params), params)
            record = (
                state.occupied,
                info.leaf_arrived,
                info.leaf_energy_kwh,
                traffic.requested_kwh(state),
                info.cars_arrived + info.cars_rejected,
            )
            return state, record

        start = simulator.empty_state(day, params, battery_key)
        _, rec = jax.lax.scan(body, start, (act_keys, step_keys))
        return rec, start.is_workday

    return jax.vmap(one_day)(days, keys)


_play_jit = jax.jit(_play, static_argnums=(3,))


def simulate_sessions(
    params: EnvParams,
    days,
    key: jax.Array,
    policy=policies.always_max,
    batch_days: int = 64,
) -> SimulatedSessions:
    """Play ``days`` with ``policy`` and read off every car's session.

    Args:
        params: the environment parameters.
        days: day indices of the price data (one episode each).
        key: the evaluation key; day ``i`` gets ``split(key, len(days))[i]``.
        policy: ``(state, key, params) -> levels`` (default `policies.always_max`).
        batch_days: days played per compiled call (memory: days x steps x leaves x 3).

    Returns:
        The `SimulatedSessions`.
    """
    days = np.atleast_1d(np.asarray(days, np.int32))
    keys = jax.random.split(key, days.shape[0])
    kind = np.asarray(params.station.leaf_kind)
    ports = np.flatnonzero(kind != KIND_BATTERY)
    out = {k: [] for k in ("day", "t0", "steps", "energy", "request", "cut", "ac")}
    requested, parked, workday = [], [], []
    for lo in range(0, days.shape[0], batch_days):
        rec, work = _play_jit(
            params, jnp.asarray(days[lo : lo + batch_days]), keys[lo : lo + batch_days], policy
        )
        occ, arrived, energy, request, asked = (np.asarray(x) for x in rec)
        requested.append(asked.sum(axis=1))
        parked.append(arrived[:, :, ports].sum(axis=(1, 2)))
        workday.append(np.asarray(work))
        num_steps = occ.shape[1]
        for i in range(occ.shape[0]):
            for port in ports:
                # a car parked at the end of step t charges from step t + 1 and leaves in the
                # first later step whose end finds the port empty or holding a new car
                gone = ~occ[i, :, port] | arrived[i, :, port]
                for t in np.flatnonzero(arrived[i, :, port]):
                    later = np.flatnonzero(gone[t + 1 :])
                    cut = later.size == 0
                    last = num_steps - 1 if cut else t + 1 + int(later[0])
                    out["day"].append(days[lo + i])
                    out["t0"].append(t + 0.5)
                    out["steps"].append(last - t)
                    out["energy"].append(float(energy[i, t + 1 : last + 1, port].sum()))
                    out["request"].append(float(request[i, t, port]))
                    out["cut"].append(cut)
                    out["ac"].append(kind[port] == KIND_AC)
    steps = np.asarray(out["steps"], np.float64)
    t0 = np.asarray(out["t0"], np.float64)
    return SimulatedSessions(
        day=np.asarray(out["day"], np.int32),
        arrival_hour=np.mod(params.episode_start_hour + t0 * params.step_minutes / 60.0, 24.0),
        stay_min=steps * params.step_minutes,
        time_left_min=(params.num_steps - 0.5 - t0) * params.step_minutes,
        delivered_kwh=np.asarray(out["energy"], np.float64),
        requested_kwh=np.asarray(out["request"], np.float64),
        cut=np.asarray(out["cut"], bool),
        ac=np.asarray(out["ac"], bool),
        day_requested=np.concatenate(requested).astype(np.float64),
        day_sessions=np.concatenate(parked).astype(np.float64),
        day_workday=np.concatenate(workday).astype(bool),
    )
