"""The hindsight bound: the best profit any policy with a given port occupancy could make on a day.

`occupancy` replays a reference policy (always-max by default) on a day's trace
(`chargax_marl.trace`) and records which car sat at which port in which step.
`hindsight_bound` then solves, with HiGHS, the LP of `chargax_marl.optimal.model`
over those sessions with the day's prices known in advance.

**What it bounds.** The day's profit (`chargax_marl.core.reward.profit_eur` summed over
the day, terminal battery value, battery wear and fixed cost included; not the reward, whose penalty
weights do not change the profit) of every policy whose occupancy is the reference's: the
same cars at the same ports for the same steps. For time-sensitive cars that is every
policy (they leave on time whatever happens); a charge-sensitive car leaves when it reaches
its target, so the class holds the policies that bring each such car to its target in the
step the reference did (the LP asks the car to reach its target by then, and relaxes "not
earlier"). A policy that frees ports earlier may admit cars the reference rejected and
exceed the bound; `chargax_marl.optimal.milp` bounds over admissions as well on small
problems. Within the class the bound is an upper bound because currents are continuous (the
discrete levels are a subset) and every limit the simulator applies is a constraint.

Under fixed departures (the session model v3, `chargax_marl.core.types.EnvParams.fixed_departures`)
every car leaves at the step set when it arrived and where it parks does not depend on the
policy, so every policy has the reference's occupancy: the bound holds for all of them.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import numpy as np

from chargax_marl import trace as trace_lib
from chargax_marl.core import checks, clock
from chargax_marl.core import reward as reward_lib
from chargax_marl.core.types import EnvParams
from chargax_marl.optimal.model import (
    Basis,
    Economics,
    Sessions,
    Solution,
    SolverError,
    StationLimits,
    build_and_solve,
)
from chargax_marl.policies import always_max, is_named_rule


@dataclass
class Occupancy:
    """Which car was at which port in which step, from a reference rollout (numpy).

    Attributes:
        sessions: the car sessions (cars only; batteries are added by the LP).
        reference_profit_eur: the reference policy's profit on the day (EUR).
        day: the day's index into the price data.
    """

    sessions: Sessions
    reference_profit_eur: float
    day: int


def sessions_from_rollout(states, infos, params: EnvParams) -> Sessions:
    """The car sessions of one replayed day (`chargax_marl.trace.replay`'s ``states``
    and ``infos``, leading axis = steps). A car present at the start of step ``t`` charges in
    ``t``; it is the same car as in ``t - 1`` unless the port received a new car in ``t - 1``.

    Args:
        states: the states at the start of each step, leaves with a leading steps axis.
        infos: the steps' infos, leaves with a leading steps axis.
        params: the environment parameters the day was replayed with.

    Returns:
        The car sessions, port by port and in step order within a port: each starts at the
        car's SoC and constants in its first step, and a charge-sensitive car that left
        before the day's end must reach its target (``must_reach``).

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.optimal.bound.sessions_from_rollout")
    occ = np.asarray(states.occupied)
    arrived = np.asarray(infos.leaf_arrived)
    num_steps = occ.shape[0]
    fields = {
        f: np.asarray(getattr(states, f), np.float64)
        for f in (
            "soc",
            "arrival_soc",
            "target_soc",
            "capacity_kwh",
            "max_rate_kw",
            "max_discharge_rate_kw",
            "tau",
        )
    }
    sensitive = np.asarray(states.charge_sensitive)
    rows = []
    for port in range(params.station.num_ports):
        t = 0
        while t < num_steps:
            if not occ[t, port]:
                t += 1
                continue
            start = t
            t += 1
            while t < num_steps and occ[t, port] and not arrived[t - 1, port]:
                t += 1
            # the car charged in start..last; a charge-sensitive car that left before the day's
            # end left because it reached its target
            rows.append((port, start, t - 1, start, bool(sensitive[start, port]) and t < num_steps))
    if not rows:
        empty = np.zeros(0)
        return Sessions(
            *(empty.astype(int),) * 3, *(empty,) * 7, empty.astype(bool), empty.astype(bool)
        )
    r = np.array([row[:4] for row in rows], dtype=np.int64)
    port, first, last, at = r.T
    return Sessions(
        leaf=port,
        first=first,
        last=last,
        soc0=fields["soc"][at, port],
        reserve_soc=fields["arrival_soc"][at, port],
        target_soc=fields["target_soc"][at, port],
        capacity_kwh=fields["capacity_kwh"][at, port],
        max_rate_kw=fields["max_rate_kw"][at, port],
        max_discharge_rate_kw=fields["max_discharge_rate_kw"][at, port],
        tau=fields["tau"][at, port],
        must_reach=np.array([row[4] for row in rows], bool),
        charge_sensitive=sensitive[at, port],
    )


def battery_sessions(params: EnvParams, soc0, first: int, last: int) -> Sessions:
    """The station batteries as sessions over steps ``first..last`` (always present).

    Args:
        params: the environment parameters.
        soc0: the batteries' SoC at the start of step ``first``, one per battery.
        first: the first step.
        last: the last step (inclusive).

    Returns:
        One session per station battery, SoC window [0, 1], with charging and discharging
        rates ``V * I_max`` of its leaf (kW; the LP caps them at the leaf's ratings).
    """
    st = params.station
    nb = st.num_batteries
    kw = np.asarray(st.leaf_voltage_v * st.leaf_max_current_a / 1000.0, np.float64)[st.num_ports :]
    one = np.ones(nb)
    return Sessions(
        leaf=np.arange(st.num_ports, st.num_ports + nb),
        first=np.full(nb, first),
        last=np.full(nb, last),
        soc0=np.asarray(soc0, np.float64).reshape(nb),
        reserve_soc=0 * one,
        target_soc=one,
        capacity_kwh=np.asarray(st.battery_capacity_kwh, np.float64),
        max_rate_kw=kw,
        max_discharge_rate_kw=kw,
        tau=np.asarray(st.battery_tau, np.float64),
        must_reach=np.zeros(nb, bool),
        charge_sensitive=np.zeros(nb, bool),
    )


def economics(
    params: EnvParams, trace: trace_lib.DayTrace, first: int = 0, last: int | None = None
) -> Economics:
    """The trace's prices for steps ``first..last`` and the params' customer price (and
    whether discharged car energy is refunded).

    Args:
        params: the environment parameters.
        trace: one day's trace (its buy, sell and terminal battery prices).
        first: the first step.
        last: the last step (inclusive); None: the trace's last.

    Returns:
        The `Economics` of steps ``first..last``, with no peak paid so far.
    """
    last = trace.num_steps - 1 if last is None else last
    sl = slice(first, last + 1)
    return Economics(
        buy=np.asarray(trace.price_buy_eur_kwh, np.float64)[sl],
        sell=np.asarray(trace.price_sell_grid_eur_kwh, np.float64)[sl],
        customer=float(params.customer_price_eur_kwh),
        battery_value=float(trace.battery_value_eur_kwh),
        step_hours=params.step_hours,
        peak_eur_kw=float(params.peak_demand_eur_kw),
        refund_discharged=bool(params.refund_discharged_energy),
    )


_REPLAY_CACHE: dict = {}
"""The replay of the last (params, policy) that is not a named rule, compiled with the params
as constants."""


def _replay_program(reference, params: EnvParams, trace: trace_lib.DayTrace, day_key):
    """The traced body of `occupancy`'s replay, with the params an argument."""
    return trace_lib.replay(lambda s, kk: reference(s, kk, params), params, trace, day_key)


_replay_named = jax.jit(_replay_program, static_argnums=0)
"""`_replay_program` compiled once per named rule of `chargax_marl.policies.POLICIES` and
station shape: any prices, traffic or fees of that shape reuse it."""


def occupancy(
    params: EnvParams, trace: trace_lib.DayTrace, day_key: jax.Array, reference=always_max
) -> Occupancy:
    """Replay a reference policy on one day's trace and record its car sessions.

    A named rule of `chargax_marl.policies.POLICIES` is replayed by one compiled program per
    rule and station shape, with the params an argument; any other policy is compiled with
    the params it is given.

    Args:
        params: the environment parameters.
        trace: one day's trace (`chargax_marl.trace.make_traces`).
        day_key: the day's key; the policy gets the keys evaluation gives it
            (`chargax_marl.trace.day_keys`).
        reference: the policy, ``reference(state, key, params) -> levels``; default
            always-max.

    Returns:
        The day's `Occupancy`: the car sessions and the reference's profit (EUR).

    Raises:
        ValueError: the trace was not made for ``params``.
    """
    trace_lib.check_trace(trace, params)
    if is_named_rule(reference):
        states, infos, final = _replay_named(reference, params, trace, day_key)
    else:  # a rule built for these params (a teacher's), or a caller's function
        cache_key = (id(params), reference)
        fn = _REPLAY_CACHE.get(cache_key)
        if fn is None:
            fn = jax.jit(lambda t, k: _replay_program(reference, params, t, k))
            _REPLAY_CACHE.clear()
            _REPLAY_CACHE[cache_key] = fn
        states, infos, final = fn(trace, day_key)
    return Occupancy(
        sessions=sessions_from_rollout(states, infos, params),
        reference_profit_eur=float(final.totals.profit_eur),
        day=int(trace.day),
    )


@dataclass
class Bound:
    """The hindsight bound of one day: ``profit_eur`` (EUR), the solver's status and time,
    the reference's profit on the same day and the LP's size.

    A day whose solve failed (`bound_days`) has ``status`` other than ``"optimal"`` (the
    last attempt's), ``profit_eur`` and ``solve_s`` NaN, no ``solution``, the solver's
    ``message`` and an empty ``attempt``.

    Attributes:
        profit_eur: the bound, the day's best profit (EUR), fixed cost included.
        reference_profit_eur: the reference policy's profit on the same day and cars (EUR).
        status: the solver's status, ``"optimal"`` when solved.
        solve_s: the seconds spent in HiGHS.
        num_vars: the LP's variables.
        num_rows: the LP's constraints.
        num_cars: the car sessions of the reference's occupancy.
        solution: the solved LP (`chargax_marl.optimal.model.Solution`); None when the solve
            failed.
        message: the solver's message when the solve failed, else empty.
        attempt: the solver settings that found the optimum
            (`chargax_marl.optimal.model.attempt_settings`: ``"default"`` or ``"warm start"``
            unless a retry did); empty when the solve failed.
    """

    profit_eur: float
    reference_profit_eur: float
    status: str
    solve_s: float
    num_vars: int
    num_rows: int
    num_cars: int
    solution: Solution | None
    message: str = ""
    attempt: str = ""

    @property
    def solved(self) -> bool:
        """Whether HiGHS found the optimum (else ``profit_eur`` is NaN and no bound)."""
        return self.status == "optimal"


def hindsight_bound(
    params: EnvParams,
    trace: trace_lib.DayTrace,
    occ: Occupancy,
    *,
    time_limit_s: float | None = 60.0,
    with_battery: bool = True,
    warm_start: Basis | None = None,
    keep_basis: bool = False,
) -> Bound:
    """Solve the LP over ``occ``'s sessions and the station batteries for the whole day of
    ``trace``. See the module docstring for what the value bounds.

    Args:
        params: the environment parameters.
        trace: one day's trace.
        occ: the reference's occupancy of the same day (`occupancy`).
        time_limit_s: HiGHS's time limit of each attempt (seconds); None: none.
        with_battery: False leaves the batteries out (no battery sessions, no calendar
            ageing): the bound of the same station and cars without its battery, so that
            the difference of the two is what the battery is worth at best.
        warm_start: the optimal basis of another day's bound on the same station
            (`Bound.solution`'s ``basis``): HiGHS starts from it where a column or row of
            this day has the same key (its kind, port or node, and step). The bound is the
            same; where several plans reach it, the plan may differ from a solve from scratch.
        keep_basis: keep the optimal basis in ``solution.basis`` (to warm-start another day).

    Returns:
        The day's `Bound`; ``profit_eur`` is the bound (EUR), fixed cost included.

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        ValueError: the trace was not made for ``params``, or ``occ`` is of another day.
        chargax_marl.optimal.model.SolverError: HiGHS finds no optimum with any of the
            settings it tries (e.g. each hits the time limit).
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.optimal.bound.hindsight_bound")
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
    trace_lib.check_trace(trace, params)
    if occ.day != int(trace.day):
        raise ValueError(
            f"occupancy field 'day' is {occ.day} but the trace is day {int(trace.day)}"
        )
    n = trace.num_steps
    parts = [occ.sessions]
    if with_battery:
        parts.append(battery_sessions(params, trace.battery_soc0, 0, n - 1))
    sessions = Sessions.concat(parts)
    sol = build_and_solve(
        sessions,
        n,
        StationLimits.of(params),
        economics(params, trace),
        charged_tolerance_kwh=float(params.charged_tolerance_kwh),
        time_limit_s=time_limit_s,
        warm_start=warm_start,
        keep_basis=keep_basis,
    )
    per_step = reward_lib.fixed_cost_per_step_eur(params) if with_battery else params.fixed_cost_eur
    fixed = float(per_step) * n
    return Bound(
        profit_eur=sol.value_eur - fixed,
        reference_profit_eur=occ.reference_profit_eur,
        status=sol.status,
        solve_s=sol.solve_s,
        num_vars=sol.num_vars,
        num_rows=sol.num_rows,
        num_cars=occ.sessions.size,
        solution=sol,
        attempt=sol.attempt,
    )


def bound_days(
    params: EnvParams,
    days,
    key: jax.Array | None = None,
    reference=always_max,
    *,
    time_limit_s: float | None = 60.0,
    with_battery: bool = True,
    day_keys: jax.Array | None = None,
    warm_start: bool = True,
) -> list[Bound]:
    """`hindsight_bound` for each of ``days`` with the cars that evaluation draws.

    Each day's LP starts from the optimal basis of the last day solved before it (the
    station's ports, nodes and steps are the same every day, so most of a basis carries
    over); a warm-started solve that fails is solved again from scratch, then with the other
    settings of `chargax_marl.optimal.model.attempt_settings` (``Bound.attempt`` names the
    one that solved it). The bounds are those of solves from scratch, to the solver's
    tolerance.

    A day whose LP fails or hits ``time_limit_s`` with every setting does not stop the
    others: its `Bound` carries the last attempt's ``status``, the solver's ``message``
    (naming each setting tried) and a NaN ``profit_eur``
    (never a number), so that every mean over days can leave it out
    (`chargax_marl.evaluation.summarize_profit`).

    Args:
        params: the environment parameters.
        days: day indices of the price data.
        key: the evaluation key, split into one key per day; None: ``PRNGKey(0)``.
        reference: the policy whose occupancy is bounded, ``reference(state, key, params)
            -> levels``; default always-max.
        time_limit_s: HiGHS's time limit per day and attempt (seconds); None: none.
        with_battery: as for `hindsight_bound`.
        day_keys: one key per day, in place of ``key``'s split, as in
            `chargax_marl.evaluation.run_days_keyed`.
        warm_start: False solves every day from scratch.

    Returns:
        One `Bound` per day, in the order of ``days``.

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.optimal.bound.bound_days")
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
    if day_keys is None:
        key = jax.random.PRNGKey(0) if key is None else key
        day_keys = jax.random.split(key, int(np.size(days)))
    traces = trace_lib.make_traces(params, days, day_keys=day_keys)
    out, basis = [], None
    for i in range(int(np.size(days))):
        tr = trace_lib.day_of(traces, i)
        occ = occupancy(params, tr, day_keys[i], reference)
        solve = functools.partial(
            hindsight_bound,
            params,
            tr,
            occ,
            time_limit_s=time_limit_s,
            with_battery=with_battery,
            keep_basis=warm_start,
        )
        b = _bound_or_failure(solve, basis, occ)
        if b.solved and b.solution.basis is not None:
            basis = b.solution.basis
        out.append(b)
    return out


def _bound_or_failure(solve, start: Basis | None, occ: Occupancy) -> Bound:
    """``solve(warm_start=start)``, or a `Bound` that carries the solver's status and message
    and a NaN profit when HiGHS finds no optimum."""
    try:
        return solve(warm_start=start)
    except SolverError as exc:
        return Bound(
            profit_eur=float("nan"),
            reference_profit_eur=occ.reference_profit_eur,
            status=exc.status,
            solve_s=float("nan"),
            num_vars=0,
            num_rows=0,
            num_cars=occ.sessions.size,
            solution=None,
            message=str(exc),
        )


__all__ = [
    "Bound",
    "Occupancy",
    "battery_sessions",
    "bound_days",
    "economics",
    "hindsight_bound",
    "occupancy",
    "sessions_from_rollout",
]
