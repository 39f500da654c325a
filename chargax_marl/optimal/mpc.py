"""A model-predictive controller: re-solve the station LP over a receding horizon, apply step one.

At each step (or every ``resolve_every`` steps, while the plan still matches the state) the
controller solves the LP of `chargax_marl.optimal.model` over the next
``horizon_hours`` with the cars present now (each staying until its planned departure, no
knowledge of future arrivals), the buy and sell prices of those hours (known in advance, as on
a day-ahead market; time-of-use surcharge included), the peak-demand charge on any draw above
the day's peak so far, and the batteries valued at the day's terminal price at the horizon's
end, and turns the first step's powers into levels.

`MPC` is a policy ``mpc(state, key, params) -> levels`` like those of
`chargax_marl.policies`: it runs on the host through `jax.pure_callback`, so it works inside
``jit``, ``scan`` and ``vmap`` (under ``vmap``, one call per step solves the batch's states
one at a time, in the batch's order) and therefore in `chargax_marl.evaluation.evaluate` and
in both views (`chargax_marl.policies.for_single`, `chargax_marl.policies.for_marl`). It is
slow next to the jitted policies: one HiGHS solve per step and state (its measured cost is in
the docs' optimal-control and performance pages), each started from the optimal basis of the
same env's previous solve (its day and position in the batch; ``warm_start``).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from chargax_marl.core import checks, clock
from chargax_marl.core import reward as reward_lib
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.core.types import EnvParams, EnvState
from chargax_marl.optimal.model import (
    FIRST_ATTEMPTS,
    STATUS,
    Economics,
    Sessions,
    StationLimits,
    build_and_solve,
)

_FIELDS = (
    "day",
    "timestep",
    "occupied",
    "soc",
    "arrival_soc",
    "target_soc",
    "capacity_kwh",
    "max_rate_kw",
    "max_discharge_rate_kw",
    "tau",
    "charge_sensitive",
    "time_remaining_min",
    "peak_grid_kw",
)


class MPC:
    """Receding-horizon LP controller (see the module docstring).

    ``horizon_hours`` (default 4) sets the look-ahead; ``resolve_every`` re-solves every k
    steps and in between applies the stored plan as long as the cars and SoCs are those the
    plan predicted (any difference re-solves). ``time_limit_s`` bounds each attempt of a
    solve. A solve that reports no optimum is tried again with other settings
    (`chargax_marl.optimal.model.attempt_settings`: presolve switched, the primal simplex,
    the interior-point method, HiGHS's defaults, each from scratch); ``retried_solves``
    counts the solves a retry solved, by the settings that did. A solve that fails with
    every setting (or hits the limit with each) falls back to charging every car at full
    power and idling the batteries for that step, is counted in ``failures`` and is recorded
    with its day, step and the last attempt's solver status in ``failed_solves`` (``{day:
    [(step, status), ...]}``): a day with one is not the MPC's result and is scored as
    failed, not as a profit (``baselines.eval.references.evaluate_mpc``). Any other error of
    the host-side step is raised through ``jax.pure_callback`` as a ``RuntimeError`` naming
    the day and the step.

    A charge-sensitive car frees its port when it is charged, which only matters for cars
    the controller cannot see yet; ``urgency_eur_kwh_h`` (default 0.1 EUR/kWh per hour)
    makes the LP charge such cars early (a bonus per kWh that falls with delay). It changes
    the plan, not the profit the simulator books. ``deadline_margin_steps`` (default 1)
    plans each car to be done that many steps before its planned departure.

    ``warm_start`` (default True) starts each solve from the optimal basis of the same day's
    previous solve (matched by leaf, row kind and step), without presolve; the optimum's
    value is the same as a solve from scratch, but where the LP has several optimal plans it
    may pick another one, so the levels (and the day's profit) can differ slightly from
    ``warm_start=False``. The bases (and the plans of ``resolve_every``) are kept per env:
    per day and per position in the vmapped batch, which stays the same from step to step.
    So each env starts from its own previous basis, and its decisions do not depend on the
    days and car draws that run beside it. A warm-started solve that the warm start does not
    solve is counted in ``warm_retries`` and solved again from scratch, then with the other
    settings, before it counts as a failure.

    Args:
        params: the environment parameters the controller acts in (its station, prices,
            step length and action space).
        horizon_hours: the look-ahead (hours), rounded up to whole steps and cut at the
            day's end.
        resolve_every: solve every this many steps, applying the stored plan in between
            while it matches the state.
        time_limit_s: HiGHS's wall-clock limit of each attempt of a solve (seconds).
        urgency_eur_kwh_h: the bonus per kWh for charging a charge-sensitive car, falling
            by this much per hour of delay (EUR/kWh per hour).
        deadline_margin_steps: each car is planned to be done this many steps before its
            planned departure.
        warm_start: start each solve from the same env's previous optimal basis.

    Raises:
        ValueError: ``horizon_hours`` not above 0, ``resolve_every`` below 1,
            ``deadline_margin_steps`` below 0, ``time_limit_s`` neither None nor a finite
            number of seconds > 0, or ``params.action_mode`` ``"delta"`` (the
            MPC acts in ``"absolute"`` or ``"continuous"``).
    """

    def __init__(
        self,
        params: EnvParams,
        horizon_hours: float = 4.0,
        resolve_every: int = 1,
        time_limit_s: float | None = 10.0,
        urgency_eur_kwh_h: float = 0.1,
        deadline_margin_steps: int = 1,
        warm_start: bool = True,
    ):
        clock.require_one_day(params, "chargax_marl.optimal.mpc.MPC")
        if not horizon_hours > 0:
            raise ValueError(f"field 'horizon_hours' must be > 0, got {horizon_hours!r}")
        for field, value, least in (
            ("resolve_every", resolve_every, 1),
            ("deadline_margin_steps", deadline_margin_steps, 0),
        ):
            if isinstance(value, bool) or not float(value).is_integer() or value < least:
                raise ValueError(f"field {field!r} must be an integer >= {least}, got {value!r}")
        self.horizon_steps = max(
            1, int(math.ceil(horizon_hours * 60.0 / params.step_minutes - 1e-9))
        )
        self.resolve_every = int(resolve_every)
        self.urgency_eur_kwh_h = float(urgency_eur_kwh_h)
        self.deadline_margin_steps = int(deadline_margin_steps)
        self.time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
        self.limits = StationLimits.of(params)
        st = params.station
        self.num_ports = st.num_ports
        self.num_leaves = st.num_ports + st.num_batteries
        self.is_battery = np.asarray(st.leaf_kind) == KIND_BATTERY
        self.step_minutes = params.step_minutes
        self.num_steps = params.num_steps
        self.num_levels = params.num_levels
        self.continuous = params.action_mode == "continuous"
        if params.action_mode == "delta":
            raise ValueError("MPC needs action_mode 'absolute' or 'continuous', got 'delta'")
        # the simulator's own prices (reward.grid_prices: time-of-use surcharge included) and
        # terminal battery value, for every day and step
        days = jnp.arange(params.num_days, dtype=jnp.int32)
        buy, sell = reward_lib.price_tables(params)
        self.buy, self.sell = np.asarray(buy, np.float64), np.asarray(sell, np.float64)  # (D, T)
        self.battery_value = np.asarray(
            jax.vmap(lambda d: reward_lib.battery_terminal_value_eur(jnp.float32(1.0), d, params))(
                days
            ),
            np.float64,
        )
        self.peak_eur_kw = float(params.peak_demand_eur_kw)
        self.customer = float(params.customer_price_eur_kwh)
        self.refund_discharged = bool(params.refund_discharged_energy)
        self.step_hours = params.step_hours
        self.solves = 0
        self.failures = 0
        self.failed_solves: dict[int, list[tuple[int, str]]] = {}
        self.solve_s = 0.0
        self._plans: dict = {}
        self.warm_start = bool(warm_start)
        self.warm_retries = 0
        self.retried_solves: dict[str, int] = {}
        self._bases: dict = {}  # (day, slot) -> (step of the solve, its optimal Basis)
        self._slot = 0  # the position in the batch of the state being solved

    # ---- host side
    def _sessions(self, s: dict, n: int) -> Sessions:
        occ = s["occupied"].astype(bool)
        leaves = np.nonzero(occ)[0]
        dt = self.step_minutes
        steps_left = np.ceil(np.maximum(s["time_remaining_min"][leaves], 0.0) / dt - 1e-6).astype(
            int
        )
        bat = self.is_battery[leaves]
        # Cars are planned to be done ``deadline_margin_steps`` (1) before their planned
        # departure (a margin against the rounding to levels and the hard rescale, which may
        # cut the last step); a
        # charge-sensitive car past its plan (it stays until charged) is planned for this step
        # only: with a longer window the LP would defer it at every re-solve and the car would
        # block its port for the rest of the day.
        last = np.where(
            bat, n - 1, np.maximum(np.minimum(steps_left - self.deadline_margin_steps, n) - 1, 0)
        )
        return Sessions(
            leaf=leaves,
            first=np.zeros(leaves.shape[0], int),
            last=last,
            soc0=s["soc"][leaves],
            reserve_soc=np.where(bat, 0.0, s["arrival_soc"][leaves]),
            target_soc=np.where(bat, 1.0, s["target_soc"][leaves]),
            capacity_kwh=s["capacity_kwh"][leaves],
            max_rate_kw=s["max_rate_kw"][leaves],
            max_discharge_rate_kw=s["max_discharge_rate_kw"][leaves],
            tau=s["tau"][leaves],
            must_reach=np.zeros(leaves.shape[0], bool),
            charge_sensitive=s["charge_sensitive"][leaves].astype(bool),
        )

    def problem(self, s: dict) -> tuple[int, Economics, Sessions]:
        """The LP of one step for the host state ``s``.

        Args:
            s: the host state (`_FIELDS` as numpy arrays).

        Returns:
            The horizon in steps, the prices and economics of those steps, and the sessions
            (the cars present and the batteries).
        """
        day, t = int(s["day"]), int(s["timestep"])
        n = max(1, min(self.horizon_steps, self.num_steps - t))
        d = day % self.buy.shape[0]
        sl = slice(t, t + n)
        econ = Economics(
            buy=self.buy[d, sl],
            sell=self.sell[d, sl],
            customer=self.customer,
            battery_value=float(self.battery_value[d]),
            step_hours=self.step_hours,
            peak_eur_kw=self.peak_eur_kw,
            peak_so_far_kw=float(s["peak_grid_kw"]),
            refund_discharged=self.refund_discharged,
        )
        return n, econ, self._sessions(s, n)

    def plan(self, s: dict) -> np.ndarray:
        """Net power per leaf and step ``(n, L)`` (kW, car side) for the host state ``s``.

        Solves the step's LP (`problem`), warm-started from the same env's previous basis
        when it is at most a horizon old. A solve that fails with every setting is counted
        in ``failures`` and ``failed_solves``, and its plan charges every port at its rating
        and idles the batteries.

        Args:
            s: the host state (`_FIELDS` as numpy arrays).

        Returns:
            ``(n, L)`` net power (kW, car side, charging positive) of every leaf in each of
            the horizon's ``n`` steps; zeros at a port without a car, and after a car's
            planned last step.
        """
        day, t = int(s["day"]), int(s["timestep"])
        n, econ, sessions = self.problem(s)
        out = np.zeros((n, self.num_leaves))
        if sessions.size == 0:
            return out
        self.solves += 1
        warm = self._bases.pop((day, self._slot), None)
        if warm is not None and not 0 < t - warm[0] <= self.horizon_steps:
            warm = None
        urgency = np.where(sessions.charge_sensitive, self.urgency_eur_kwh_h, 0.0)
        solve = lambda basis: build_and_solve(  # noqa: E731
            sessions,
            n,
            self.limits,
            econ,
            time_limit_s=self.time_limit_s,
            urgency_eur_kwh_h=urgency,
            step_offset=t,
            warm_start=basis,
            keep_basis=self.warm_start,
        )
        try:
            sol = solve(None if warm is None else warm[1])
        except RuntimeError as exc:  # SolverError
            self.warm_retries += warm is not None
            self.failures += 1
            self.failed_solves.setdefault(day, []).append((t, getattr(exc, "status", STATUS[4])))
            out[:, ~self.is_battery] = self.limits.charge_kw[~self.is_battery]
            return out
        self.warm_retries += warm is not None and sol.attempt != "warm start"
        if sol.attempt not in FIRST_ATTEMPTS:
            self.retried_solves[sol.attempt] = self.retried_solves.get(sol.attempt, 0) + 1
        self.solve_s += sol.solve_s
        if sol.basis is not None and t + 1 < self.num_steps:  # the day's last step keeps none
            self._bases[(day, self._slot)] = (t, sol.basis)
        for i, leaf in enumerate(sessions.leaf):
            net = sol.net_kw[i]
            if net is not None:
                out[: net.shape[0], leaf] = net
        return out

    def _levels(self, net_kw: np.ndarray) -> np.ndarray:
        """Levels for the plan's first-step powers. Charging rounds up (the car's own limits
        in the simulator cut the surplus, and a small remainder planned for a car's last step
        must not round to 0); discharging rounds towards 0."""
        up = np.maximum(self.limits.charge_kw, 1e-9)
        down = np.maximum(self.limits.discharge_kw, 1e-9)
        frac = np.where(net_kw >= 0, net_kw / up, net_kw / down)
        # a leaf that may not discharge plays no negative level (a solver's -1e-9 there would
        # be a level outside its range, which the play refuses)
        low = np.where(self.limits.discharge_kw > 0, -1.0, 0.0)
        frac = np.clip(frac, low, 1.0)
        frac[np.abs(frac) < 1e-6] = 0.0
        if self.continuous:
            return frac.astype(np.float32)
        scaled = frac * self.num_levels
        return np.where(scaled > 0, np.ceil(scaled - 1e-6), np.trunc(scaled)).astype(np.int32)

    def host_act(self, *arrays, slot: int = 0) -> np.ndarray:
        """The levels for one host state (the body of the ``pure_callback``).

        Args:
            *arrays: the state's fields (`_FIELDS`), in order.
            slot: the state's position in its batch; with its day, it keys the warm start and
                the plans of ``resolve_every``, so each env continues from its own solves.

        Returns:
            The signed level of every leaf.

        Raises:
            RuntimeError: the host-side step failed; the message names the day and the step
                (the cause is chained).
        """
        s = {k: np.asarray(v) for k, v in zip(_FIELDS, arrays)}
        day, t = int(s["day"]), int(s["timestep"])
        self._slot = int(slot)
        try:
            return self._act(s, day, t)
        except Exception as exc:
            raise RuntimeError(
                f"MPC failed on day {day}, step {t}: {type(exc).__name__}: {exc}"
            ) from exc

    def _act(self, s: dict, day: int, t: int) -> np.ndarray:
        cached = self._plans.get((day, self._slot))
        if cached is not None and self.resolve_every > 1:
            t0, occ, socs, plan = cached
            k = t - t0
            if (
                0 < k < min(self.resolve_every, plan.shape[0])
                and np.array_equal(occ, s["occupied"])
                and np.allclose(socs[k], s["soc"], atol=1e-4)
            ):
                return self._levels(plan[k])
        plan = self.plan(s)
        if self.resolve_every > 1:
            self._plans[(day, self._slot)] = (
                t,
                s["occupied"].copy(),
                self._predicted_soc(s, plan),
                plan,
            )
        return self._levels(plan[0])

    def _predicted_soc(self, s: dict, plan: np.ndarray) -> np.ndarray:
        cap = np.maximum(s["capacity_kwh"], 1e-6)
        steps = np.cumsum(plan * self.step_hours / cap, axis=0)
        return np.concatenate([s["soc"][None], s["soc"][None] + steps[:-1]], axis=0)

    # ---- the policy
    def _host_batch(self, layout: tuple, flat: np.ndarray) -> np.ndarray:
        """`host_act` on each state of a batch, in the batch's order, each under its position
        in the batch (leading axes of ``flat``: the batch; its last axis: the fields that
        `__call__` packed, ``layout`` giving each field's shape and dtype; every value
        round-trips exactly)."""
        flat = np.asarray(flat)
        batch = flat.shape[:-1]
        splits = np.cumsum([math.prod(shape) for shape, _ in layout])[:-1]
        levels = []
        for slot, row in enumerate(flat.reshape(-1, flat.shape[-1])):
            parts = np.split(row, splits)
            levels.append(
                self.host_act(
                    *(p.reshape(shape).astype(dtype) for p, (shape, dtype) in zip(parts, layout)),
                    slot=slot,
                )
            )
        return np.stack(levels).reshape(batch + (self.num_leaves,))

    def __call__(self, state: EnvState, key: jax.Array, params: EnvParams) -> jnp.ndarray:
        del key, params
        dtype = jnp.float32 if self.continuous else jnp.int32
        out = jax.ShapeDtypeStruct((self.num_leaves,), dtype)
        args = [
            state.totals.peak_grid_kw if f == "peak_grid_kw" else getattr(state, f) for f in _FIELDS
        ]
        # One operand, and under vmap one call per step for the whole batch (solved state by
        # state, each knowing its position, which keys its warm start): each operand and each
        # call of a host callback costs time on every step. The widest float dtype holds every
        # field exactly (the step and day as whole numbers below 2**24, the flags as 0 and 1).
        wide = jnp.result_type(*(a for a in args if jnp.issubdtype(a.dtype, jnp.floating)))
        layout = tuple((tuple(a.shape), np.dtype(a.dtype)) for a in args)
        flat = jnp.concatenate([jnp.ravel(a).astype(wide) for a in args])
        return jax.pure_callback(
            functools.partial(self._host_batch, layout), out, flat, vmap_method="broadcast_all"
        )


def mpc_policy(params: EnvParams, **kwargs) -> MPC:
    """An `MPC` for ``params`` (a policy ``(state, key, params) -> levels``).

    Args:
        params: the environment parameters.
        **kwargs: `MPC`'s other arguments (``horizon_hours``, ``resolve_every``, ...).

    Returns:
        The controller.

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.optimal.mpc.mpc_policy")
    return MPC(params, **kwargs)
