"""The bound over admissions too: a MILP that also chooses which cars park where, and when
charge-sensitive cars leave. For small stations and short horizons.

The LP bound (`chargax_marl.optimal.bound`) fixes the port occupancy of a reference
policy; a policy that frees ports sooner may admit other cars. This MILP drops that
restriction on a *window* of the day's first ``num_steps`` steps (the station is empty at
the day's start): every car of the trace that asks to park in the window may be admitted at
any port or turned away (binary), a time-sensitive car then stays for its planned stay, and
a charge-sensitive car leaves in a step of its choosing, but only once it has reached its
target (or stays past the window's end). Everything else is the LP of
`chargax_marl.optimal.model`.

**What it bounds.** The *window profit* of every policy: the profit booked in the window's
steps (fixed cost included) plus the batteries' net energy change over the window at the
day's terminal price (`window_profit` computes it for a replayed policy). The
simulator admits cars first-free-port and never turns one away while a port is free; the
MILP may, so its feasible set holds every policy's trajectory.

Each (car, port[, departure step]) is one LP session with a binary that switches it on, so
the problem grows as cars × ports × steps: keep it to a handful of ports and a few hours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import numpy as np

from chargax_marl import trace as trace_lib
from chargax_marl.core import checks, clock
from chargax_marl.core import reward as reward_lib
from chargax_marl.core.types import EnvParams
from chargax_marl.optimal.bound import battery_sessions, economics, occupancy
from chargax_marl.optimal.model import Sessions, StationLimits, _Builder, build_and_solve
from chargax_marl.policies import always_max


@dataclass
class WindowBounds:
    """MILP and LP bounds of one window, with the reference policy's window profit (EUR).

    Attributes:
        milp_eur: the MILP bound of the window profit (EUR, fixed cost included).
        lp_eur: the LP bound over the reference's occupancy cut to the window (`restrict`;
            EUR, fixed cost included).
        reference_eur: the reference policy's window profit (`window_profit`; EUR).
        num_steps: the window's steps.
        num_candidates: the cars that ask to park in the window (at most one per port per
            step of arrival).
        num_binaries: the MILP's binaries, one per (car, port[, departure step]) session.
        milp_solve_s: the seconds HiGHS spent on the MILP.
        lp_solve_s: the seconds HiGHS spent on the LP.
    """

    milp_eur: float
    lp_eur: float
    reference_eur: float
    num_steps: int
    num_candidates: int
    num_binaries: int
    milp_solve_s: float
    lp_solve_s: float


def _one(**fields) -> Sessions:
    return Sessions(**{k: np.atleast_1d(np.asarray(v)) for k, v in fields.items()})


def candidate_sessions(params: EnvParams, trace: trace_lib.DayTrace, num_steps: int):
    """The (car, port[, departure]) sessions of the window and the car each belongs to."""
    clock.require_one_day(params, "chargax_marl.optimal.milp.candidate_sessions")
    a = {
        k: np.asarray(getattr(trace.arrivals, k))
        for k in (
            "requested",
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
        )
    }
    st = params.station
    kind = np.asarray(st.leaf_kind)
    parts, owner = [], []
    car = 0
    for t in range(num_steps - 1):
        for k in range(min(int(a["requested"][t]), st.num_ports)):
            stay_steps = max(
                1, int(math.ceil(float(a["stay_min"][t, k]) / params.step_minutes - 1e-6))
            )
            for port in range(st.num_ports):
                ac = kind[port] == 0
                # the user type is drawn per port kind (`traffic.Arrivals`)
                sensitive = bool(a["charge_sensitive" if ac else "charge_sensitive_dc"][t, k])
                common = dict(
                    leaf=port,
                    first=t + 1,
                    soc0=a["arrival_soc"][t, k],
                    reserve_soc=a["arrival_soc"][t, k],
                    target_soc=a["target_soc"][t, k],
                    capacity_kwh=a["capacity_kwh"][t, k],
                    max_rate_kw=a["ac_kw"][t, k] if ac else a["dc_kw"][t, k],
                    max_discharge_rate_kw=a["ac_discharge_kw"][t, k]
                    if ac
                    else a["dc_discharge_kw"][t, k],
                    tau=a["tau"][t, k],
                    charge_sensitive=sensitive,
                )
                if not sensitive:
                    parts.append(
                        _one(last=min(t + stay_steps, num_steps - 1), must_reach=False, **common)
                    )
                    owner.append(car)
                    continue
                for d in range(t + 1, num_steps - 1):  # leaves after step d, charged
                    parts.append(_one(last=d, must_reach=True, **common))
                    owner.append(car)
                parts.append(
                    _one(last=num_steps - 1, must_reach=False, **common)
                )  # still there at the end
                owner.append(car)
            car += 1
    return parts, np.asarray(owner, int), car


def admission_bound(
    params: EnvParams,
    trace: trace_lib.DayTrace,
    num_steps: int,
    *,
    time_limit_s: float | None = 120.0,
):
    """Solve the MILP of the module docstring over the window's first ``num_steps`` steps.

    Args:
        params: the environment parameters.
        trace: one day's trace (`chargax_marl.trace.make_traces`).
        num_steps: the window's steps, from the day's first.
        time_limit_s: HiGHS's wall-clock limit of each attempt (seconds); None: none.

    Returns:
        The `chargax_marl.optimal.model.Solution` (``value_eur`` without the fixed cost),
        with two more attributes: ``num_binaries``, the candidate sessions, and
        ``num_candidates``, the cars they belong to.

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        ValueError: the trace was not made for ``params``, or ``num_steps`` outside
            ``[2, params.num_steps]``.
        chargax_marl.optimal.model.SolverError: HiGHS finds no optimum with any of the
            settings it tries.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.optimal.milp.admission_bound")
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
    trace_lib.check_trace(trace, params)
    if not 2 <= num_steps <= params.num_steps:
        raise ValueError(
            f"field 'num_steps' must lie in [2, {params.num_steps}], got {num_steps!r}"
        )
    parts, owner, num_cars = candidate_sessions(params, trace, num_steps)
    bats = battery_sessions(params, trace.battery_soc0, 0, num_steps - 1)
    sessions = Sessions.concat(parts + [bats]) if parts else bats
    b = _Builder()
    z = b.vars(len(parts), 0.0, 1.0, integer=True)
    occ = {i: z[i] for i in range(len(parts))}
    # each car at most once
    if len(parts):
        rows = b.new_rows(num_cars, -np.inf, 1.0)
        b.coef(rows[owner], z, 1.0)
        # each port holds at most one car per step
        port_rows = b.new_rows(params.station.num_ports * num_steps, -np.inf, 1.0)
        for i in range(len(parts)):
            steps = np.arange(int(sessions.first[i]), int(sessions.last[i]) + 1)
            b.coef(port_rows[int(sessions.leaf[i]) * num_steps + steps], z[i], 1.0)
    sol = build_and_solve(
        sessions,
        num_steps,
        StationLimits.of(params),
        economics(params, trace, 0, num_steps - 1),
        charged_tolerance_kwh=float(params.charged_tolerance_kwh),
        time_limit_s=time_limit_s,
        occupancy_vars=occ,
        builder=b,
    )
    sol.num_binaries = len(parts)
    sol.num_candidates = num_cars
    return sol


def window_profit(
    params: EnvParams, trace: trace_lib.DayTrace, day_key: jax.Array, policy, num_steps: int
) -> float:
    """A policy's window profit (see the module docstring) on the trace's first ``num_steps``.

    Args:
        params: the environment parameters.
        trace: one day's trace.
        day_key: the day's key, as for `chargax_marl.trace.replay`.
        policy: ``policy(state, key, params) -> levels``.
        num_steps: the window's steps, from the day's first.

    Returns:
        The profit booked in the window's steps (EUR, fixed cost included), with the
        batteries' net energy over the window valued at the day's terminal price in place
        of the booked terminal value.
    """
    act = lambda s, k: policy(s, k, params)  # noqa: E731
    _, infos, _ = jax.jit(lambda t, k: trace_lib.replay(act, params, t, k))(trace, day_key)
    profit = np.asarray(infos.profit_eur, np.float64)[:num_steps]
    terminal = np.asarray(infos.battery_terminal_value_eur, np.float64)[:num_steps]
    battery = np.asarray(infos.battery_net_kwh, np.float64)[:num_steps]
    return float(profit.sum() - terminal.sum() + float(trace.battery_value_eur_kwh) * battery.sum())


def restrict(sessions: Sessions, num_steps: int) -> Sessions:
    """The sessions of a reference occupancy cut to the window's first ``num_steps`` steps (a
    charge-sensitive car keeps its target only if it left within the window).

    Args:
        sessions: the car sessions of a reference occupancy
            (`chargax_marl.optimal.bound.Occupancy.sessions`).
        num_steps: the window's steps, from the day's first.

    Returns:
        The sessions that start in the window, each ending at the window's last step at
        the latest; ``must_reach`` cleared on those cut short.
    """
    keep = sessions.first <= num_steps - 1
    out = Sessions(
        **{k: np.asarray(getattr(sessions, k))[keep] for k in Sessions.__dataclass_fields__}
    )
    cut = out.last > num_steps - 1
    out.must_reach = out.must_reach & ~cut
    out.last = np.minimum(out.last, num_steps - 1)
    return out


def compare(
    params: EnvParams,
    trace: trace_lib.DayTrace,
    day_key: jax.Array,
    num_steps: int,
    reference=always_max,
    time_limit_s: float | None = 120.0,
) -> WindowBounds:
    """MILP bound, LP bound over ``reference``'s occupancy and ``reference``'s own profit, all
    on the same window (EUR, fixed cost included).

    Args:
        params: the environment parameters.
        trace: one day's trace.
        day_key: the day's key (the cars' and the reference's keys).
        num_steps: the window's steps, from the day's first.
        reference: ``reference(state, key, params) -> levels``; default always-max.
        time_limit_s: HiGHS's wall-clock limit of each attempt (seconds); None: none.

    Returns:
        The window's `WindowBounds`.

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        ValueError: the trace was not made for ``params``, or ``num_steps`` outside
            ``[2, params.num_steps]`` (`admission_bound`).
        chargax_marl.optimal.model.SolverError: HiGHS finds no optimum of the MILP or the LP.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.optimal.milp.compare")
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
    fixed = float(reward_lib.fixed_cost_per_step_eur(params)) * num_steps
    milp = admission_bound(params, trace, num_steps, time_limit_s=time_limit_s)
    occ = occupancy(params, trace, day_key, reference)
    lp_sessions = Sessions.concat(
        [
            restrict(occ.sessions, num_steps),
            battery_sessions(params, trace.battery_soc0, 0, num_steps - 1),
        ]
    )
    lp = build_and_solve(
        lp_sessions,
        num_steps,
        StationLimits.of(params),
        economics(params, trace, 0, num_steps - 1),
        charged_tolerance_kwh=float(params.charged_tolerance_kwh),
        time_limit_s=time_limit_s,
    )
    ref = window_profit(params, trace, day_key, reference, num_steps)
    return WindowBounds(
        milp_eur=milp.value_eur - fixed,
        lp_eur=lp.value_eur - fixed,
        reference_eur=ref,
        num_steps=num_steps,
        num_candidates=milp.num_candidates,
        num_binaries=milp.num_binaries,
        milp_solve_s=milp.solve_s,
        lp_solve_s=lp.solve_s,
    )


__all__ = ["WindowBounds", "admission_bound", "compare", "restrict", "window_profit"]
