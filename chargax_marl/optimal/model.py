"""The station's day as a linear program: one builder shared by the hindsight bound and the MPC.

Everything here is host-side numpy and SciPy's interface to the HiGHS solver
(:func:`scipy.optimize.milp`). A problem is a set of *sessions* (a car at one port for a
range of steps, or a station battery for the whole range) over ``num_steps`` steps of
``step_hours``, with the station's limits and the steps' prices. The LP chooses, per session
and step, a charging power ``p+ >= 0`` and a discharging power ``p- >= 0`` (kW, car side) and
maximises the money the simulator's profit (:func:`chargax_marl.core.reward.profit_eur`)
would book, under every limit the simulator applies:

- port ratings (``V * I_max``, ``V * I_dis`` with V2G, 0 discharge without), the car's
  ``r-bar`` and discharge limit;
- the rate curve above ``tau`` (``p+ <= r-bar (1 - SoC) / (1 - tau)``) and its mirror for
  discharging (``p- <= r-bar_dis SoC / (1 - tau)``), with the SoC at the start of the step as
  in :func:`chargax_marl.core.physics.clip_to_car`;
- the SoC window: at most the car's target, at least its arrival SoC (batteries: [0, 1]);
- every node limit on the grid side (``p+ / eta - p- * eta`` summed under the node, with the
  efficiency of the path up to and including it; dropped in ``soft`` constraint mode, where
  the simulator lets the excess flow);
- the grid price: the net draw at the buy price (time-of-use surcharge included), the net
  feed-in at the grid's sell price;
- the customer price on a car's charge, and on its discharge as a refund unless
  ``Economics.refund_discharged`` is False (then a car charges or discharges in a step, not
  both: ``p+ / cmax + p- / dmax <= 1``);
- the peak-demand charge on the highest net draw of the steps (when the params set one);
- the batteries' net energy change valued at the day's terminal price, and their wear per
  kWh into or out of the cells (:func:`chargax_marl.core.reward.battery_wear_eur`; the
  calendar ageing is a constant, booked with the fixed cost).

Relaxations, so that the optimum bounds the simulator from above: currents are continuous
(the simulator's discrete levels are a subset) and a leaf may charge and discharge in the
same step (never profitable unless prices are negative). When a step's grid sell price is
above its buy price, the import and export are each capped at the root's limit, so the
value stays finite and still an upper bound.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.optimize import Bounds, LinearConstraint, milp

from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.core.types import EnvParams

# SciPy's milp status codes (HiGHS underneath)
STATUS = {
    0: "optimal",
    1: "time or iteration limit",
    2: "infeasible",
    3: "unbounded",
    4: "other solver error",
}


class SolverError(RuntimeError):
    """HiGHS did not return an optimal solution (infeasible, unbounded, time limit, failure).

    Args:
        message: what failed, with the problem's size.
        status: the solver's status (a value of :data:`STATUS`, e.g. ``"time or iteration
            limit"``), kept as ``.status`` so that callers can report it per day.
    """

    def __init__(self, message: str, status: str = STATUS[4]):
        super().__init__(message)
        self.status = status


@dataclass
class Sessions:
    """Cars (and batteries) of a problem, arrays over sessions ``(S,)``. Steps are indices into
    the problem's step range; a session charges in steps ``first..last`` inclusive."""

    leaf: np.ndarray
    first: np.ndarray
    last: np.ndarray
    soc0: np.ndarray
    reserve_soc: np.ndarray  # lowest SoC (arrival SoC; 0 for batteries)
    target_soc: np.ndarray  # highest SoC (car's target; 1 for batteries)
    capacity_kwh: np.ndarray
    max_rate_kw: np.ndarray
    max_discharge_rate_kw: np.ndarray
    tau: np.ndarray
    must_reach: np.ndarray  # bool: end the session at the target (less the charged tolerance)
    charge_sensitive: np.ndarray  # bool (informational)

    @property
    def size(self) -> int:
        return int(self.leaf.shape[0])

    @staticmethod
    def concat(parts: list[Sessions]) -> Sessions:
        names = Sessions.__dataclass_fields__
        return Sessions(
            **{n: np.concatenate([np.asarray(getattr(p, n)) for p in parts]) for n in names}
        )


@dataclass
class StationLimits:
    """The station's arrays the LP needs, as numpy (see :class:`chargax_marl.core.station.StationArrays`)."""

    charge_kw: np.ndarray  # (L,) V * I_max
    discharge_kw: np.ndarray  # (L,) V * I_dis, 0 where the leaf may not discharge
    path_eff: np.ndarray  # (L,)
    eff_at_depth: np.ndarray  # (D, L)
    node_at_depth: np.ndarray  # (D, L)
    node_max_kw: np.ndarray  # (H,)
    is_battery: np.ndarray  # (L,)
    hard: bool
    root_kw: float
    wear_eur_kwh: np.ndarray | None = None  # (L,) wear per kWh of cell throughput, 0 at ports

    @staticmethod
    def of(params: EnvParams) -> StationLimits:
        st = params.station
        kind = np.asarray(st.leaf_kind)
        is_bat = kind == KIND_BATTERY
        volts = np.asarray(st.leaf_voltage_v, np.float64)
        dis_a = np.asarray(st.leaf_max_discharge_current_a, np.float64) * np.where(
            is_bat, 1.0, float(params.v2g)
        )
        node_max = np.asarray(st.node_max_kw, np.float64)
        return StationLimits(
            charge_kw=volts * np.asarray(st.leaf_max_current_a, np.float64) / 1000.0,
            discharge_kw=volts * dis_a / 1000.0,
            path_eff=np.asarray(st.leaf_path_efficiency, np.float64),
            eff_at_depth=np.asarray(st.leaf_efficiency_at_depth, np.float64),
            node_at_depth=np.asarray(st.node_of_leaf_at_depth),
            node_max_kw=node_max,
            is_battery=is_bat,
            hard=params.constraint_mode == "hard",
            root_kw=float(node_max[0]),
            wear_eur_kwh=np.concatenate(
                [np.zeros(st.num_ports), np.asarray(params.battery_wear_eur_kwh, np.float64)]
            ),
        )


@dataclass
class Economics:
    """Prices of a problem's steps (EUR/kWh) and the constants of the profit."""

    buy: np.ndarray  # (n,)
    sell: np.ndarray  # (n,)
    customer: float
    battery_value: float  # per kWh of net energy into the batteries over the problem
    step_hours: float
    peak_eur_kw: float = 0.0  # peak-demand charge per kW of the highest net draw (step average)
    peak_so_far_kw: float = 0.0  # the day's peak before the problem's first step (already paid for)
    refund_discharged: bool = (
        True  # car owners get ``customer`` back per kWh taken out of their car
    )


@dataclass
class Solution:
    """A solved problem: ``value_eur`` is the money the LP books (the fixed cost excluded),
    ``net_kw[s, k]`` the net power of session ``s`` in its ``k``-th step (car side),
    ``soc_end`` the SoC of each session after its last step."""

    value_eur: float
    status: str
    solve_s: float
    num_vars: int
    num_rows: int
    net_kw: list = field(default_factory=list)
    soc_end: np.ndarray | None = None
    x: np.ndarray | None = None


class _Builder:
    """Variables with bounds and costs, and sparse rows ``lb <= A x <= ub``."""

    def __init__(self):
        self.lb, self.ub, self.cost, self.integer = [], [], [], []
        self.rows, self.cols, self.vals = [], [], []
        self.row_lb, self.row_ub = [], []
        self.n = 0
        self.m = 0

    def vars(self, count: int, lb, ub, cost=0.0, integer: bool = False) -> np.ndarray:
        idx = np.arange(self.n, self.n + count)
        self.lb.append(np.broadcast_to(np.asarray(lb, np.float64), (count,)))
        self.ub.append(np.broadcast_to(np.asarray(ub, np.float64), (count,)))
        self.cost.append(np.broadcast_to(np.asarray(cost, np.float64), (count,)))
        self.integer.append(np.full(count, int(integer)))
        self.n += count
        return idx

    def new_rows(self, count: int, lb, ub) -> np.ndarray:
        idx = np.arange(self.m, self.m + count)
        self.row_lb.append(np.broadcast_to(np.asarray(lb, np.float64), (count,)))
        self.row_ub.append(np.broadcast_to(np.asarray(ub, np.float64), (count,)))
        self.m += count
        return idx

    def coef(self, rows, cols, vals) -> None:
        rows, cols = np.broadcast_arrays(np.asarray(rows), np.asarray(cols))
        self.rows.append(rows.ravel())
        self.cols.append(cols.ravel())
        self.vals.append(np.broadcast_to(np.asarray(vals, np.float64), rows.shape).ravel())

    def solve(self, maximise: bool = True, time_limit_s: float | None = None):
        cat = lambda parts: np.concatenate(parts) if parts else np.zeros(0)  # noqa: E731
        c = cat(self.cost)
        a = sp.csr_array(
            (cat(self.vals), (cat(self.rows).astype(np.int64), cat(self.cols).astype(np.int64))),
            shape=(self.m, self.n),
        )
        options = {"presolve": True}
        if time_limit_s is not None:
            options["time_limit"] = float(time_limit_s)
        constraints = [LinearConstraint(a, cat(self.row_lb), cat(self.row_ub))] if self.m else []
        t0 = time.perf_counter()
        res = milp(
            -c if maximise else c,
            integrality=cat(self.integer),
            bounds=Bounds(cat(self.lb), cat(self.ub)),
            constraints=constraints,
            options=options,
        )
        return res, time.perf_counter() - t0


def build_and_solve(
    sessions: Sessions,
    num_steps: int,
    limits: StationLimits,
    econ: Economics,
    *,
    charged_tolerance_kwh: float = 0.0,
    time_limit_s: float | None = 60.0,
    occupancy_vars: dict | None = None,
    builder: _Builder | None = None,
    urgency_eur_kwh_h: np.ndarray | None = None,
) -> Solution:
    """Build the LP of the module docstring for ``sessions`` and solve it with HiGHS.

    ``occupancy_vars`` (used by the MILP) maps a session index to a binary variable that
    multiplies its power limits (the session exists only when the binary is 1).
    ``urgency_eur_kwh_h`` (per session, used by the MPC) adds to each kWh a bonus that falls
    by that much per hour of delay, so the LP charges those sessions early among plans of
    (nearly) equal profit; leave it None for the bound.
    Raises :class:`SolverError` when HiGHS does not report an optimum.
    """
    b = builder or _Builder()
    dt = econ.step_hours
    n = num_steps
    num_nodes = limits.node_max_kw.shape[0]
    # grid import / export per step, kWh
    cap = (
        limits.root_kw * dt
        if limits.hard
        else float(np.sum(limits.charge_kw / limits.path_eff)) * dt
    )
    g_imp = b.vars(n, 0.0, cap, cost=-econ.buy)
    g_exp = b.vars(n, 0.0, cap, cost=econ.sell)
    grid_rows = b.new_rows(n, 0.0, 0.0)  # g_imp - g_exp - sum(grid side) = 0
    b.coef(grid_rows, g_imp, 1.0)
    b.coef(grid_rows, g_exp, -1.0)
    if econ.peak_eur_kw > 0.0:
        # the day's peak: peak >= net draw of every step (and >= the peak so far), priced per kW
        peak = b.vars(1, econ.peak_so_far_kw, np.inf, cost=-econ.peak_eur_kw)
        peak_rows = b.new_rows(n, -np.inf, 0.0)  # (g_imp - g_exp) / dt - peak <= 0
        b.coef(peak_rows, g_imp, 1.0 / dt)
        b.coef(peak_rows, g_exp, -1.0 / dt)
        b.coef(peak_rows, np.repeat(peak, n), -1.0)
    node_rows = None
    if limits.hard:
        node_rows = b.new_rows(
            n * num_nodes, -np.tile(limits.node_max_kw, n), np.tile(limits.node_max_kw, n)
        )

    net_index, soc_end_index = [], []
    for s in range(sessions.size):
        leaf = int(sessions.leaf[s])
        k0, k1 = int(sessions.first[s]), int(sessions.last[s])
        if k1 < k0:
            net_index.append((None, None))
            soc_end_index.append(None)
            continue
        steps = np.arange(k0, k1 + 1)
        m = steps.shape[0]
        cap_kwh = max(float(sessions.capacity_kwh[s]), 1e-6)
        tau = float(sessions.tau[s])
        cmax = min(float(sessions.max_rate_kw[s]), float(limits.charge_kw[leaf]))
        dmax = min(float(sessions.max_discharge_rate_kw[s]), float(limits.discharge_kw[leaf]))
        lo = min(float(sessions.reserve_soc[s]), float(sessions.soc0[s]))
        hi = max(float(sessions.target_soc[s]), float(sessions.soc0[s]))
        is_bat = bool(limits.is_battery[leaf])
        price = econ.battery_value if is_bat else econ.customer
        value = np.full(m, price)
        if urgency_eur_kwh_h is not None:
            value = value + float(urgency_eur_kwh_h[s]) * (n - steps) * dt
        # without the refund a car's discharge earns no customer price (the urgency bonus stays)
        refund = is_bat or econ.refund_discharged
        # a battery's cells wear per kWh in and per kWh out (p+ and p- are cell side)
        wear = 0.0 if limits.wear_eur_kwh is None else float(limits.wear_eur_kwh[leaf])
        pp = b.vars(m, 0.0, max(cmax, 0.0), cost=(value - wear) * dt)
        pm = b.vars(
            m, 0.0, max(dmax, 0.0), cost=-((value if refund else value - price) + wear) * dt
        )
        # SoC x_0..x_m: x_0 fixed at the start SoC; the end may be forced to the target
        x_lo, x_hi = np.full(m + 1, lo), np.full(m + 1, hi)
        x_lo[0] = x_hi[0] = float(sessions.soc0[s])
        goal = max(
            lo, min(hi, float(sessions.target_soc[s]) - charged_tolerance_kwh / cap_kwh - 1e-5)
        )
        conditional = occupancy_vars is not None and s in occupancy_vars
        if sessions.must_reach[s] and not conditional:
            x_lo[m] = goal
        x = b.vars(m + 1, x_lo, x_hi)
        if sessions.must_reach[s] and conditional:
            # only when the session exists: x_end - (goal - lo) z >= lo
            row = b.new_rows(1, lo, np.inf)
            b.coef(row, x[m : m + 1], 1.0)
            b.coef(row, occupancy_vars[s][None], -(goal - lo))
        # SoC dynamics: x_{k+1} - x_k - (p+ - p-) dt / C = 0
        dyn = b.new_rows(m, 0.0, 0.0)
        b.coef(dyn, x[1:], 1.0)
        b.coef(dyn, x[:-1], -1.0)
        b.coef(dyn, pp, -dt / cap_kwh)
        b.coef(dyn, pm, dt / cap_kwh)
        if occupancy_vars is not None and s in occupancy_vars:
            z = occupancy_vars[s]
            lim = b.new_rows(2 * m, -np.inf, 0.0)  # p+ <= cmax z, p- <= dmax z
            b.coef(lim[:m], pp, 1.0)
            b.coef(lim[:m], z, -max(cmax, 0.0))
            b.coef(lim[m:], pm, 1.0)
            b.coef(lim[m:], z, -max(dmax, 0.0))
        if tau < 1.0 - 1e-6 and cmax > 0:
            slope = float(sessions.max_rate_kw[s]) / (1.0 - tau)
            taper = b.new_rows(m, -np.inf, slope)  # p+ + slope x <= slope
            b.coef(taper, pp, 1.0)
            b.coef(taper, x[:-1], slope)
        if not refund and cmax > 0 and dmax > 0:
            # the simulator charges or discharges a car in a step, never both: p+ / cmax + p- / dmax
            # <= 1 (the convex hull of the two). Without it, charging and discharging at once would
            # bill the customer for energy that never stays in the car.
            hull = b.new_rows(m, -np.inf, 1.0)
            b.coef(hull, pp, 1.0 / cmax)
            b.coef(hull, pm, 1.0 / dmax)
        if dmax > 0:
            slope_d = float(sessions.max_discharge_rate_kw[s]) / max(1.0 - tau, 1e-6)
            mirror = b.new_rows(m, -np.inf, 0.0)  # p- - slope x <= 0
            b.coef(mirror, pm, 1.0)
            b.coef(mirror, x[:-1], -slope_d)
        eta = float(limits.path_eff[leaf])
        b.coef(grid_rows[steps], pp, -dt / eta)
        b.coef(grid_rows[steps], pm, dt * eta)
        if node_rows is not None:
            for d in range(limits.node_at_depth.shape[0]):
                node = int(limits.node_at_depth[d, leaf])
                if node < 0:
                    continue
                e = float(limits.eff_at_depth[d, leaf])
                rows = node_rows[steps * num_nodes + node]
                b.coef(rows, pp, 1.0 / e)
                b.coef(rows, pm, -e)
        net_index.append((pp, pm))
        soc_end_index.append(x[m])

    res, solve_s = b.solve(time_limit_s=time_limit_s)
    status = STATUS.get(res.status, f"status {res.status}")
    if res.status != 0 or res.x is None:
        raise SolverError(
            f"HiGHS did not solve the problem: {status} ({res.message}); "
            f"{b.n} variables, {b.m} rows",
            status,
        )
    xs = res.x
    net = [None if pp is None else xs[pp] - xs[pm] for pp, pm in net_index]
    soc_end = np.array([np.nan if i is None else xs[i] for i in soc_end_index])
    return Solution(
        value_eur=float(-res.fun),
        status=status,
        solve_s=solve_s,
        num_vars=b.n,
        num_rows=b.m,
        net_kw=net,
        soc_end=soc_end,
        x=xs,
    )
