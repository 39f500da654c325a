"""The port-pooled bound: the best profit any policy could make on a day, whatever the ports
its cars park at.

The hindsight bound of `chargax_marl.optimal.bound` fixes a reference policy's occupancy. Where
a policy changes which port a car gets (a random free port, and a charge-sensitive car that
leaves sooner frees its port sooner), another policy can beat it. This bound drops the
occupancy: every car of the day's trace is offered at every *port group* (ports of the same
rating, efficiency and path of nodes), and the LP decides, continuously, how much of the car
sits at each group (`chargax_marl.optimal.model.Pools`):

- a car that leaves at its planned time (the user type the trace draws for the group's kind)
  holds its share of a port from its arrival to its planned departure;
- a car that leaves once charged (and only then: it stays past its planned time until it
  is) holds a port only in the steps it charges or discharges, by its power over its bound;
- a car takes at most one port's worth per step, a group at most its port count; a car may be
  turned away.

Everything else is the LP of `chargax_marl.optimal.model`, the car's SoC shared by its groups.

**What it bounds.** The day's profit (as `chargax_marl.optimal.bound`'s) of every policy:
every trajectory the simulator can take (each admitted car at one port of one group, from
its arrival to its planned departure, or until charged) is a point of this LP. The relaxations are
the bound's (continuous currents) and those above (a car split over groups, an early leaver
holding its port only while it charges, any car turned away), so it can be loose where a
station is full; it is never below a policy's profit.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np

from chargax_marl import trace as trace_lib
from chargax_marl.core import checks, clock
from chargax_marl.core import reward as reward_lib
from chargax_marl.core.station import KIND_AC
from chargax_marl.core.types import EnvParams
from chargax_marl.optimal.bound import Bound, battery_sessions, economics
from chargax_marl.optimal.model import Pools, Sessions, SolverError, StationLimits, build_and_solve


def pooled_limits(params: EnvParams) -> StationLimits:
    """The station's limits with alike sibling nodes merged: nodes of one parent whose ports
    are alike (kind, ratings, efficiencies, the limits below) become one node whose limit is
    the sum of theirs. Every flow the station allows, the merged one allows (a sum of flows
    each under its limit is under the sum of the limits), and the ports of merged nodes form
    one group (`port_groups`) instead of one per node.

    Args:
        params: the environment parameters.

    Returns:
        `chargax_marl.optimal.model.StationLimits` with each merged node's ports under its
        first node, which holds the summed limit.
    """
    lim = StationLimits.of(params)
    num_ports = params.station.num_ports
    node = lim.node_at_depth.copy()
    node_max = lim.node_max_kw.copy()
    deeper_max = np.where(node >= 0, lim.node_max_kw[np.maximum(node, 0)], -1.0)
    kind = np.asarray(params.station.leaf_kind)
    leaf_sig = [
        (
            int(kind[i]),
            float(lim.charge_kw[i]),
            float(lim.discharge_kw[i]),
            float(lim.path_eff[i]),
            *lim.eff_at_depth[:, i].tolist(),
        )
        for i in range(node.shape[1])
    ]
    for d in range(1, node.shape[0]):
        merged: dict = {}
        for nd in np.unique(node[d][node[d] >= 0]):
            leaves = np.nonzero(node[d] == nd)[0]
            if np.any(leaves >= num_ports):  # a battery below: left as it is
                continue
            key = (
                int(node[d - 1, leaves[0]]),
                tuple(sorted(leaf_sig[i] + tuple(deeper_max[d + 1 :, i]) for i in leaves)),
            )
            merged.setdefault(key, []).append((int(nd), leaves))
        for members in merged.values():
            first = members[0][0]
            node_max[first] = sum(lim.node_max_kw[nd] for nd, _ in members)
            for _, leaves in members:
                node[d, leaves] = first
    return dataclasses.replace(lim, node_at_depth=node, node_max_kw=node_max)


def port_groups(params: EnvParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The station's ports grouped by what the port-pooled LP sees of a port: kind, charging
    and discharging rating, efficiencies and nodes on the path to the grid, alike sibling
    nodes merged (`pooled_limits`).

    Args:
        params: the environment parameters.

    Returns:
        ``(group_of_port (P,), first_port (G,), group_ports (G,))``: each port's group, the
        first port of each group (it stands for the group in the LP) and each group's size.
    """
    lim = pooled_limits(params)
    num_ports = params.station.num_ports
    kind = np.asarray(params.station.leaf_kind)[:num_ports]
    rows = np.column_stack(
        [
            kind,
            lim.charge_kw[:num_ports],
            lim.discharge_kw[:num_ports],
            lim.path_eff[:num_ports],
            lim.eff_at_depth[:, :num_ports].T,
            lim.node_at_depth[:, :num_ports].T,
        ]
    )
    _, first_port, group_of_port, group_ports = np.unique(
        rows, axis=0, return_index=True, return_inverse=True, return_counts=True
    )
    return group_of_port.reshape(num_ports), first_port, group_ports


def pooled_sessions(params: EnvParams, trace: trace_lib.DayTrace) -> tuple[Sessions, Pools, int]:
    """Every car of the day's trace at every port group, as LP sessions.

    A car asking to park in step ``t`` (at most one per port, as the simulator draws them)
    charges from step ``t + 1`` to its planned departure (the day's last step at the latest)
    at a group where it leaves at its planned time, and to the day's end at a group where it
    leaves once charged (the simulator keeps such a car until it is charged).

    Args:
        params: the environment parameters.
        trace: one day's trace made for ``params``.

    Returns:
        ``(sessions, pools, num_cars)``: one session per car and group, the `Pools` that tie
        them, and the number of cars.

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.optimal.pooled.pooled_sessions")
    _, first_port, group_ports = port_groups(params)
    a = trace.arrivals
    n = trace.num_steps
    num_ports = params.station.num_ports
    requested = np.minimum(np.asarray(a.requested)[: n - 1], num_ports)
    slot = np.arange(num_ports)
    t, k = np.nonzero(slot[None, :] < requested[:, None])
    num_cars = t.size
    field = lambda name: np.asarray(getattr(a, name), np.float64)[t, k]  # noqa: E731
    stay_steps = np.maximum(
        1, np.ceil(field("stay_min") / params.step_minutes - 1e-6).astype(np.int64)
    )
    last = np.minimum(t + stay_steps, n - 1)
    kind = np.asarray(params.station.leaf_kind)[first_port]
    parts, car, group, holds = [], [], [], []
    for g, port in enumerate(first_port):
        ac = kind[g] == KIND_AC
        sensitive = np.asarray(a.charge_sensitive if ac else a.charge_sensitive_dc, bool)[t, k]
        parts.append(
            Sessions(
                leaf=np.full(num_cars, int(port)),
                first=t + 1,
                # a car that leaves when charged stays, uncharged, to the day's end
                last=np.where(sensitive, n - 1, last),
                soc0=field("arrival_soc"),
                reserve_soc=field("arrival_soc"),
                target_soc=field("target_soc"),
                capacity_kwh=field("capacity_kwh"),
                max_rate_kw=field("ac_kw" if ac else "dc_kw"),
                max_discharge_rate_kw=field("ac_discharge_kw" if ac else "dc_discharge_kw"),
                tau=field("tau"),
                must_reach=np.zeros(num_cars, bool),
                charge_sensitive=sensitive,
            )
        )
        car.append(np.arange(num_cars))
        group.append(np.full(num_cars, g))
        holds.append(~sensitive)
    pools = Pools(
        car=np.concatenate(car),
        group=np.concatenate(group),
        holds=np.concatenate(holds),
        group_ports=group_ports,
    )
    return Sessions.concat(parts), pools, num_cars


def pooled_bound(
    params: EnvParams,
    trace: trace_lib.DayTrace,
    *,
    time_limit_s: float | None = 120.0,
    with_battery: bool = True,
) -> Bound:
    """Solve the port-pooled LP of the module docstring for one day.

    Args:
        params: the environment parameters.
        trace: one day's trace made for ``params``.
        time_limit_s: HiGHS's time limit of each attempt (seconds); None: none.
        with_battery: False leaves the station batteries out, as for
            `chargax_marl.optimal.bound.hindsight_bound`.

    Returns:
        The day's `chargax_marl.optimal.bound.Bound`: ``profit_eur`` the bound (EUR, fixed
        cost included), ``num_cars`` the cars offered, ``reference_profit_eur`` NaN (no
        reference policy is replayed).

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        ValueError: the trace was not made for ``params``.
        chargax_marl.optimal.model.SolverError: HiGHS finds no optimum with any setting.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.optimal.pooled.pooled_bound")
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
    trace_lib.check_trace(trace, params)
    n = trace.num_steps
    cars, pools, num_cars = pooled_sessions(params, trace)
    parts = [cars]
    if with_battery:
        bats = battery_sessions(params, trace.battery_soc0, 0, n - 1)
        parts.append(bats)
        pools = Pools(
            car=np.concatenate([pools.car, np.full(bats.size, -1)]),
            group=np.concatenate([pools.group, np.zeros(bats.size, np.int64)]),
            holds=np.concatenate([pools.holds, np.zeros(bats.size, bool)]),
            group_ports=pools.group_ports,
        )
    sol = build_and_solve(
        Sessions.concat(parts),
        n,
        pooled_limits(params),
        economics(params, trace),
        charged_tolerance_kwh=float(params.charged_tolerance_kwh),
        time_limit_s=time_limit_s,
        pools=pools,
    )
    per_step = reward_lib.fixed_cost_per_step_eur(params) if with_battery else params.fixed_cost_eur
    return Bound(
        profit_eur=sol.value_eur - float(per_step) * n,
        reference_profit_eur=float("nan"),
        status=sol.status,
        solve_s=sol.solve_s,
        num_vars=sol.num_vars,
        num_rows=sol.num_rows,
        num_cars=num_cars,
        solution=sol,
        attempt=sol.attempt,
    )


def pooled_bound_days(
    params: EnvParams,
    days,
    day_keys: jax.Array,
    *,
    time_limit_s: float | None = 120.0,
) -> list[Bound]:
    """`pooled_bound` for each of ``days`` with the cars evaluation draws (one key per day,
    `chargax_marl.trace.day_keys`). A day whose solve fails does not stop the others: its
    `Bound` has the solver's status and message and a NaN ``profit_eur``.

    Args:
        params: the environment parameters.
        days: day indices of the price data.
        day_keys: one key per day.
        time_limit_s: HiGHS's time limit per day and attempt (seconds); None: none.

    Returns:
        One `Bound` per day, in the order of ``days``.

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.optimal.pooled.pooled_bound_days")
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
    traces = trace_lib.make_traces(params, days, day_keys=day_keys)
    out = []
    for i in range(int(np.size(days))):
        tr = trace_lib.day_of(traces, i)
        try:
            out.append(pooled_bound(params, tr, time_limit_s=time_limit_s))
        except SolverError as exc:
            out.append(
                Bound(
                    profit_eur=math.nan,
                    reference_profit_eur=math.nan,
                    status=exc.status,
                    solve_s=math.nan,
                    num_vars=0,
                    num_rows=0,
                    num_cars=0,
                    solution=None,
                    message=str(exc),
                )
            )
    return out


__all__ = ["pooled_bound", "pooled_bound_days", "pooled_limits", "pooled_sessions", "port_groups"]
