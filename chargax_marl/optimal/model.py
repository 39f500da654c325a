"""The station's day as a linear program: one builder shared by the hindsight bound and the MPC.

Everything here is host-side numpy and the HiGHS solver, called through ``highspy``. A
problem is a set of *sessions* (a car at one port for a range of steps, or a station battery
for the whole range) over ``num_steps`` steps of ``step_hours``, with the station's limits
and the steps' prices. The LP chooses, per session and step, a charging power ``p+ >= 0`` and
a discharging power ``p- >= 0`` (kW, car side) and maximises the money the simulator's
profit (`chargax_marl.core.reward.profit_eur`) would book, under every limit the
simulator applies:

- port ratings (``V * I_max``, ``V * I_dis`` with V2G, 0 discharge without), the car's
  ``r-bar`` and discharge limit;
- the rate curve above ``tau`` (``p+ <= r-bar (1 - SoC) / (1 - tau)``) and its mirror for
  discharging (``p- <= r-bar_dis SoC / (1 - tau)``), with the SoC at the start of the step as
  in `chargax_marl.core.physics.clip_to_car`;
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
  kWh into or out of the cells (`chargax_marl.core.reward.battery_wear_eur`; the
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

import highspy
import numpy as np
import scipy.sparse as sp

from chargax_marl.core import checks
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.core.types import EnvParams

# a solve's status by SciPy milp's status code
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
        status: the solver's status (a value of `STATUS`, e.g. ``"time or iteration
            limit"``), kept as ``.status`` so that callers can report it per day; after
            `solve_with_retries`, the last attempt's.
        attempts: ``(name, status)`` of each setting tried (`attempt_settings`'s names), in
            order; empty for a single run.
    """

    def __init__(
        self, message: str, status: str = STATUS[4], attempts: tuple[tuple[str, str], ...] = ()
    ):
        super().__init__(message)
        self.status = status
        self.attempts = tuple(attempts)


@dataclass
class Sessions:
    """Cars (and batteries) of a problem, arrays over sessions ``(S,)``. Steps are indices into
    the problem's step range; a session charges in steps ``first..last`` inclusive.

    Attributes:
        leaf: (S,) int, the leaf (port, or station battery) each session sits at.
        first: (S,) int, the session's first step.
        last: (S,) int, the session's last step (``last < first``: an empty session).
        soc0: (S,) the SoC at the start of step ``first``.
        reserve_soc: (S,) the lowest SoC allowed (the car's arrival SoC; 0 for batteries).
        target_soc: (S,) the highest SoC allowed (the car's target; 1 for batteries).
        capacity_kwh: (S,) the battery's capacity (kWh).
        max_rate_kw: (S,) the car's charging power limit ``r-bar`` (kW).
        max_discharge_rate_kw: (S,) the car's discharging power limit (kW).
        tau: (S,) the SoC above which the rate curve tapers.
        must_reach: (S,) bool, the session ends at its target, less the charged tolerance.
        charge_sensitive: (S,) bool, the car leaves once charged (informational: the LP does
            not read it).
    """

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
        """The number of sessions ``S``."""
        return int(self.leaf.shape[0])

    @staticmethod
    def concat(parts: list[Sessions]) -> Sessions:
        """The sessions of ``parts``, one after the other, as one `Sessions`."""
        names = Sessions.__dataclass_fields__
        return Sessions(
            **{n: np.concatenate([np.asarray(getattr(p, n)) for p in parts]) for n in names}
        )


@dataclass
class Pools:
    """Sessions that stand for one car at any port of a group (the port-pooled relaxation).

    Every car of a problem gets one session per port group (ports with the same rating,
    efficiency and path of nodes); the car's sessions share one SoC, and the LP decides how
    much of the car sits at each group in each step. A *holding* session keeps its share of
    a port for its whole range (a car that leaves at its planned time); any other session
    holds a port only in the steps it charges or discharges, by its power over its bound (a
    car that may leave once charged). Rows: a car takes at most one port's worth per step;
    a group holds at most its port count per step.

    Attributes:
        car: (S,) the car of each session; -1 for a session outside the pools (a battery).
            A car's sessions start in the same step (they may end in different ones).
        group: (S,) each session's port group (ignored where ``car`` is -1).
        holds: (S,) bool: the session holds its port for its whole range.
        group_ports: (G,) the number of ports of each group.
    """

    car: np.ndarray
    group: np.ndarray
    holds: np.ndarray
    group_ports: np.ndarray


@dataclass
class StationLimits:
    """The station's arrays the LP needs, as numpy (see `chargax_marl.core.station.StationArrays`).

    ``L`` leaves (ports, then batteries), ``D`` depths of the station tree, ``H`` nodes.

    Attributes:
        charge_kw: (L,) each leaf's charging rating ``V * I_max`` (kW).
        discharge_kw: (L,) each leaf's discharging rating ``V * I_dis`` (kW); 0 where the
            leaf may not discharge (a port without V2G).
        path_eff: (L,) the efficiency of each leaf's path to the grid.
        eff_at_depth: (D, L) the efficiency of each leaf's path up to and including its node
            at each depth.
        node_at_depth: (D, L) each leaf's node at each depth; -1 where it has none.
        node_max_kw: (H,) each node's limit (kW); node 0 is the root, the grid connection.
        is_battery: (L,) bool, the leaf is a station battery.
        hard: the node limits are constraints (``constraint_mode == "hard"``); False drops
            them, as the simulator's ``soft`` mode lets the excess flow.
        root_kw: the root node's limit (kW).
        wear_eur_kwh: (L,) the battery wear per kWh into or out of the cells (EUR/kWh), 0 at
            ports; None for no wear.
    """

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
        """The limits of the station of ``params`` (discharge at ports only with ``v2g``)."""
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
    """Prices of a problem's steps (EUR/kWh) and the constants of the profit.

    Attributes:
        buy: (n,) the buy price of each step (EUR/kWh).
        sell: (n,) the grid's sell (feed-in) price of each step (EUR/kWh).
        customer: the price a car's owner pays per kWh charged (EUR/kWh).
        battery_value: the value per kWh of net energy into the station batteries over the
            problem (EUR/kWh; the day's terminal price).
        step_hours: the length of a step (hours).
        peak_eur_kw: the peak-demand charge per kW of the highest net draw (step average;
            EUR/kW); 0 for none.
        peak_so_far_kw: the day's peak before the problem's first step (kW), already paid
            for.
        refund_discharged: car owners get ``customer`` back per kWh taken out of their car.
    """

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
    ``soc_end`` the SoC of each session after its last step, ``basis`` the optimal basis when
    asked for (``keep_basis``), ``attempt`` the name of the solver settings that solved it
    (`attempt_settings`: ``"warm start"`` or ``"default"`` unless a retry did).

    Attributes:
        value_eur: the money the LP books over the problem (EUR), the fixed cost excluded.
        status: the solver's status (`STATUS`), ``"optimal"``.
        solve_s: the seconds spent in HiGHS over every attempt.
        num_vars: the LP's variables (columns).
        num_rows: the LP's constraints (rows).
        net_kw: per session, the ``(last - first + 1,)`` net power of each of its steps (kW,
            car side, charging positive); None for an empty session.
        soc_end: (S,) each session's SoC after its last step; NaN for an empty session.
        x: the LP's whole primal solution, one value per column.
        basis: the optimal `Basis` when asked for (``keep_basis``), else None.
        attempt: the name of the settings that solved it (`attempt_settings`).
    """

    value_eur: float
    status: str
    solve_s: float
    num_vars: int
    num_rows: int
    net_kw: list = field(default_factory=list)
    soc_end: np.ndarray | None = None
    x: np.ndarray | None = None
    basis: Basis | None = None
    attempt: str = "default"


_MODEL_STATUS = {
    highspy.HighsModelStatus.kOptimal: STATUS[0],
    highspy.HighsModelStatus.kTimeLimit: STATUS[1],
    highspy.HighsModelStatus.kIterationLimit: STATUS[1],
    highspy.HighsModelStatus.kInfeasible: STATUS[2],
    highspy.HighsModelStatus.kUnboundedOrInfeasible: STATUS[2],
    highspy.HighsModelStatus.kUnbounded: STATUS[3],
}

# the solver object without highspy.Highs's Python callbacks (unused here, and they print a
# banner on the first instance); the public class where a highspy version lacks it
_HIGHS = getattr(highspy, "_Highs", highspy.Highs)


LP_OPTIONS = {"presolve": "off", "simplex_dual_edge_weight_strategy": 1}
"""HiGHS's options for an LP's first solve: the dual simplex (HiGHS's choice for an LP)
without presolve, which on these problems costs more than it saves, and Devex pricing. A
problem with integer columns keeps HiGHS's defaults."""

POOLED_OPTIONS = {"simplex_strategy": 4}
"""HiGHS's options for the port-pooled LP's first solve (`chargax_marl.optimal.pooled`): the
primal simplex with presolve, faster on those problems than `LP_OPTIONS`
(`benchmarks/pooled_speed.py` times both)."""

FIRST_ATTEMPTS = ("warm start", "default")
"""`attempt_settings`' names of a solve's own settings: from the basis it was given, and from
scratch. Any other name is a retry."""


def attempt_settings(first: dict, warm: bool = False) -> list[tuple[str, dict]]:
    """The solver settings a solve tries in turn, until one reports an optimum.

    Each attempt runs on a new solver object that holds the model and no basis (only
    ``"warm start"`` is given one), so a retry never starts from the basis or the state of
    the run that failed:

    - ``"warm start"`` (only when ``warm``): ``first`` with presolve off, from the basis;
    - ``"default"``: ``first``, from scratch;
    - ``"presolve on"`` (``"presolve off"`` where ``first`` has it on): ``first`` with
      presolve switched;
    - ``"primal simplex"``: ``first`` with the primal simplex in place of the dual;
    - ``"interior point"``: ``first`` with the interior-point method and crossover (a basic
      solution at the end);
    - ``"HiGHS defaults"``: none of ``first``, HiGHS's own defaults.

    Args:
        first: HiGHS options of the first attempt (e.g. `LP_OPTIONS`; ``{}`` for HiGHS's
            defaults).
        warm: whether the solve was given a basis to start from.

    Returns:
        ``(name, options)`` per attempt, in order.
    """
    presolved = first.get("presolve", "choose") != "off"
    out = [("warm start", {**first, "presolve": "off"})] if warm else []
    return out + [
        ("default", dict(first)),
        (
            "presolve off" if presolved else "presolve on",
            {**first, "presolve": "off" if presolved else "on"},
        ),
        ("primal simplex", {**first, "solver": "simplex", "simplex_strategy": 4}),
        ("interior point", {**first, "solver": "ipm", "run_crossover": "on"}),
        ("HiGHS defaults", {}),
    ]


def new_highs(time_limit_s: float | None = None, options: dict | None = None) -> highspy.Highs:
    """A silent HiGHS instance with this module's options.

    Args:
        time_limit_s: the wall-clock limit of each solve (seconds); None for none.
        options: further HiGHS options by name (e.g. `LP_OPTIONS`); None for none.

    Returns:
        The solver, with no model yet.

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        ValueError: HiGHS refuses an option's name or value.
    """
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
    h = _HIGHS()
    h.setOptionValue("output_flag", False)
    if time_limit_s is not None:
        h.setOptionValue("time_limit", float(time_limit_s))
    for name, value in (options or {}).items():
        if h.setOptionValue(name, value) == highspy.HighsStatus.kError:
            raise ValueError(f"HiGHS refused option {name!r} = {value!r}")
    return h


def pass_model(
    h: highspy.Highs,
    cost: np.ndarray,
    col_lb: np.ndarray,
    col_ub: np.ndarray,
    row_lb: np.ndarray,
    row_ub: np.ndarray,
    start: np.ndarray,
    index: np.ndarray,
    value: np.ndarray,
    integer: np.ndarray | None = None,
) -> None:
    """Hand HiGHS the problem ``min cost x`` s.t. ``row_lb <= A x <= row_ub``,
    ``col_lb <= x <= col_ub``, with ``A`` given column-wise.

    Args:
        h: the solver.
        cost: per column (minimised).
        col_lb: lower bound per column.
        col_ub: upper bound per column.
        row_lb: lower bound per row (``-inf`` for none).
        row_ub: upper bound per row (``inf`` for none).
        start: CSC column pointers, ``(num_cols + 1,)``.
        index: CSC row indices.
        value: CSC values.
        integer: bool per column, or None for an LP.

    Raises:
        SolverError: HiGHS refuses the model.
    """
    num_cols, num_rows = int(cost.shape[0]), int(row_lb.shape[0])
    kind = np.zeros(num_cols, np.int32) if integer is None else np.asarray(integer, np.int32)
    status = h.passModel(
        num_cols,
        num_rows,
        int(value.shape[0]),
        int(highspy.MatrixFormat.kColwise.value),
        int(highspy.ObjSense.kMinimize.value),
        0.0,
        cost,
        col_lb,
        col_ub,
        row_lb,
        row_ub,
        np.asarray(start, np.int32),
        np.asarray(index, np.int32),
        np.asarray(value, np.float64),
        kind,
    )
    if status == highspy.HighsStatus.kError:
        raise SolverError(
            f"HiGHS refused the model: {num_cols} variables, {num_rows} rows", STATUS[4]
        )


def run_highs(h: highspy.Highs, num_cols: int, num_rows: int) -> tuple[str, np.ndarray, float]:
    """Run ``h`` on its model and read the optimum.

    Args:
        h: a solver holding a model (minimisation).
        num_cols: the model's columns (for the error message).
        num_rows: the model's rows (for the error message).

    Returns:
        ``(status, x, objective)``: `STATUS`'s ``"optimal"``, the primal solution and
        the minimised objective.

    Raises:
        SolverError: HiGHS reports anything but an optimum (its status is kept).
    """
    h.run()
    model_status = h.getModelStatus()
    status = _MODEL_STATUS.get(model_status, STATUS[4])
    if status != STATUS[0]:
        raise SolverError(
            f"HiGHS did not solve the problem: {status} ({h.modelStatusToString(model_status)}); "
            f"{num_cols} variables, {num_rows} rows",
            status,
        )
    x = np.asarray(h.getSolution().col_value, np.float64)
    return status, x, float(h.getInfo().objective_function_value)


def solve_with_retries(
    model: tuple,
    first: dict,
    time_limit_s: float | None = None,
    basis: highspy.HighsBasis | None = None,
) -> tuple[str, np.ndarray, float, highspy.Highs, str]:
    """Solve ``model`` with the settings of `attempt_settings`, in turn, until one reports
    an optimum.

    Args:
        model: `pass_model`'s arguments after the solver (costs, bounds, matrix, integrality).
        first: HiGHS options of the first attempt (`attempt_settings`).
        time_limit_s: HiGHS's wall-clock limit of each attempt (seconds); None for none.
        basis: a basis for the first attempt (``"warm start"``); None for none.

    Returns:
        ``(status, x, objective, highs, attempt)``: `run_highs`'s first three, the solver
        that found the optimum (to read its basis) and the name of its settings.

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        SolverError: no attempt reports an optimum; its ``status`` is the last attempt's and
            its ``attempts`` every attempt's, in order.
    """
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
    num_cols, num_rows = int(model[0].shape[0]), int(model[3].shape[0])
    tried, last = [], None
    for name, options in attempt_settings(first, warm=basis is not None):
        h = new_highs(time_limit_s, options)
        pass_model(h, *model)
        if name == "warm start":
            h.setBasis(basis)
        try:
            status, x, obj = run_highs(h, num_cols, num_rows)
        except SolverError as exc:
            tried.append((name, exc.status))
            last = exc
            continue
        return status, x, obj, h, name
    settings = ", ".join(f"{name}: {status}" for name, status in tried)
    raise SolverError(f"{last} (settings tried: {settings})", tried[-1][1], tuple(tried))


# HiGHS's basis statuses by their integer value (kLower, kBasic, kUpper, kZero, kNonbasic)
_BASIS_STATUS = np.array(
    [
        highspy.HighsBasisStatus.kLower,
        highspy.HighsBasisStatus.kBasic,
        highspy.HighsBasisStatus.kUpper,
        highspy.HighsBasisStatus.kZero,
        highspy.HighsBasisStatus.kNonbasic,
    ],
    dtype=object,
)
_LOWER, _BASIC, _UPPER = 0, 1, 2


@dataclass
class Basis:
    """An optimal basis, each column and row named by a key (its kind, leaf or node, and the
    day's step), so that a later problem over overlapping steps can start from it
    (`build_and_solve`'s ``warm_start``). Keys are sorted.

    Attributes:
        col_key: (num_cols,) int64, the columns' keys, sorted.
        col_status: (num_cols,) int8, each column's status as an index of HiGHS's basis
            statuses (0 at its lower bound, 1 basic, 2 at its upper bound).
        row_key: (num_rows,) int64, the rows' keys, sorted.
        row_status: (num_rows,) int8, each row's status, as for the columns.
    """

    col_key: np.ndarray  # (num_cols,) int64
    col_status: np.ndarray  # (num_cols,) int8, HighsBasisStatus values
    row_key: np.ndarray
    row_status: np.ndarray

    @staticmethod
    def read(h: highspy.Highs, b: _Builder, col_key: np.ndarray, row_key: np.ndarray) -> Basis:
        """The optimal basis of solver ``h`` (which solved ``b``'s problem, minimising) under
        the keys of its columns and rows: its basic variables, and each nonbasic one at the
        bound where the solution puts it."""
        _, basic = h.getBasicVariables()
        basic = np.asarray(basic, np.int64)
        sol = h.getSolution()
        x, r = np.asarray(sol.col_value), np.asarray(sol.row_value)
        ub, row_ub = np.concatenate(b.ub), np.concatenate(b.row_ub)
        lb, row_lb = np.concatenate(b.lb), np.concatenate(b.row_lb)
        cs = np.where((x > lb + 1e-9) & (x >= ub - 1e-9), _UPPER, _LOWER).astype(np.int8)
        rs = np.where((r > row_lb + 1e-9) & (r >= row_ub - 1e-9), _UPPER, _LOWER).astype(np.int8)
        cs[basic[basic >= 0]] = _BASIC
        rs[-1 - basic[basic < 0]] = _BASIC
        ci, ri = np.argsort(col_key), np.argsort(row_key)
        return Basis(col_key[ci], cs[ci], row_key[ri], rs[ri])

    def guess(self, col_key: np.ndarray, row_key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Statuses for a problem with these keys: this basis's where a key is known, else a
        column at its lower bound and a basic row.

        Args:
            col_key: the new problem's column keys, in column order.
            row_key: the new problem's row keys, in row order.

        Returns:
            ``(col_status, row_status)``: int8 arrays of the keys' shapes, as
            `Basis.col_status`.
        """
        return (
            _lookup(self.col_key, self.col_status, col_key, _LOWER),
            _lookup(self.row_key, self.row_status, row_key, _BASIC),
        )


def _lookup(keys: np.ndarray, values: np.ndarray, query: np.ndarray, default: int) -> np.ndarray:
    """``values`` at ``query`` in the sorted ``keys`` (``default`` where absent)."""
    if keys.shape[0] == 0:
        return np.full(query.shape[0], default, np.int8)
    i = np.minimum(np.searchsorted(keys, query), keys.shape[0] - 1)
    return np.where(keys[i] == query, values[i], default).astype(np.int8)


def _key(kind: int, entity, step) -> np.ndarray:
    """Keys of columns or rows: a kind, a leaf or node, and the day's step."""
    return (np.int64(kind) << 40) + (np.asarray(entity, np.int64) << 20) + np.asarray(step)


def _per_item(value, count: int, shape: tuple | None = None) -> np.ndarray:
    """``value`` (a scalar or an array of ``shape``, default ``(count,)``) as ``count``
    float64s."""
    a = np.asarray(value, np.float64)
    if a.ndim == 0:
        return np.full(count, a)
    shape = shape or (count,)
    return (a if a.shape == shape else np.broadcast_to(a, shape)).ravel()


def _cat(parts: list, dtype=np.float64) -> np.ndarray:
    """The builder's blocks as one array (an empty one of ``dtype`` for none)."""
    return np.concatenate(parts) if parts else np.zeros(0, dtype)


class _Builder:
    """Variables with bounds and costs, and sparse rows ``lb <= A x <= ub``, added in blocks
    (each call takes whole arrays)."""

    def __init__(self):
        self.lb, self.ub, self.cost, self.integer = [], [], [], []
        self.rows, self.cols, self.vals = [], [], []
        self.row_lb, self.row_ub = [], []
        self.n = 0
        self.m = 0

    def vars(self, count: int, lb, ub, cost=0.0, integer: bool = False) -> np.ndarray:
        idx = np.arange(self.n, self.n + count)
        self.lb.append(_per_item(lb, count))
        self.ub.append(_per_item(ub, count))
        self.cost.append(_per_item(cost, count))
        self.integer.append(np.full(count, bool(integer)))
        self.n += count
        return idx

    def new_rows(self, count: int, lb, ub) -> np.ndarray:
        idx = np.arange(self.m, self.m + count)
        self.row_lb.append(_per_item(lb, count))
        self.row_ub.append(_per_item(ub, count))
        self.m += count
        return idx

    def coef(self, rows, cols, vals) -> None:
        rows, cols = np.asarray(rows), np.asarray(cols)
        if rows.shape != cols.shape:
            rows, cols = np.broadcast_arrays(rows, cols)
        self.rows.append(rows.ravel())
        self.cols.append(cols.ravel())
        self.vals.append(_per_item(vals, rows.size, rows.shape))

    def matrix(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rows' coefficients column-wise (CSC): ``(start, index, value)``, each
        column's rows in ascending order and a coefficient given twice summed."""
        rows = _cat(self.rows, np.int64).astype(np.int64)
        cols = _cat(self.cols, np.int64).astype(np.int64)
        vals = _cat(self.vals)
        order = np.argsort(cols * max(self.m, 1) + rows, kind="stable")
        sorted_rows, sorted_cols = rows[order], cols[order]
        if np.any((sorted_rows[1:] == sorted_rows[:-1]) & (sorted_cols[1:] == sorted_cols[:-1])):
            a = sp.csc_array((vals, (rows, cols)), shape=(self.m, self.n))
            a.sum_duplicates()
            return a.indptr, a.indices, a.data
        return np.searchsorted(sorted_cols, np.arange(self.n + 1)), sorted_rows, vals[order]

    def solve(
        self,
        maximise: bool = True,
        time_limit_s: float | None = None,
        col_status: np.ndarray | None = None,
        row_status: np.ndarray | None = None,
        first: dict | None = None,
    ) -> tuple[str, np.ndarray, float, float, highspy.Highs, str]:
        """Solve with HiGHS: from scratch, or from a guessed basis.

        An LP is first solved with `LP_OPTIONS` (unless ``first`` is given); a problem with integer
        columns with HiGHS's defaults. A run that reports no optimum is tried again with the other
        settings of `attempt_settings`, without the guessed basis (`solve_with_retries`).

        Args:
            maximise: maximise the cost (else minimise).
            time_limit_s: HiGHS's wall-clock limit of each attempt (seconds); None for none.
            col_status: a guessed basis status per column (`highspy.HighsBasisStatus`
                values), or None for a solve from scratch.
            row_status: the same per row (with ``col_status``).
            first: HiGHS options of the first attempt (e.g. `POOLED_OPTIONS`); None for the
                defaults above.

        Returns:
            ``(status, x, objective, solve_s, highs, attempt)``: the objective in the
            direction asked for, ``solve_s`` the seconds spent in HiGHS over every attempt
            (the model's hand-over included), the solver (to read its basis) and the name of
            the settings that solved it (`attempt_settings`).

        Raises:
            ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
            SolverError: no optimum with any of the settings.
        """
        time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
        c = _cat(self.cost)
        start, index, value = self.matrix()
        integer = _cat(self.integer, bool)
        basis = None
        if col_status is not None:
            # an alien basis: HiGHS completes or repairs it
            basis = highspy.HighsBasis()
            basis.col_status = _BASIS_STATUS[col_status].tolist()
            basis.row_status = _BASIS_STATUS[row_status].tolist()
            basis.alien = True
        model = (
            -c if maximise else c,
            _cat(self.lb),
            _cat(self.ub),
            _cat(self.row_lb),
            _cat(self.row_ub),
            start,
            index,
            value,
            integer,
        )
        if first is None:
            first = {} if integer.any() else LP_OPTIONS
        t0 = time.perf_counter()
        status, x, obj, h, attempt = solve_with_retries(model, first, time_limit_s, basis)
        return status, x, (-obj if maximise else obj), time.perf_counter() - t0, h, attempt


@dataclass
class _Terms:
    """Per-session constants of the LP, arrays over sessions ``(S,)`` (float64)."""

    leaf: np.ndarray
    cap_kwh: np.ndarray  # capacity, at least 1e-6
    pp_max_kw: np.ndarray  # the charging power's bound, >= 0
    pm_max_kw: np.ndarray  # the discharging power's bound, >= 0 (0: no discharge variable)
    soc_lo: np.ndarray
    soc_hi: np.ndarray
    goal_soc: np.ndarray  # the end SoC a must-reach session is held to
    price_eur_kwh: np.ndarray  # customer price (cars) or terminal value (batteries)
    refund: np.ndarray  # bool: a discharged kWh earns the price back
    wear_eur_kwh: np.ndarray
    eta: np.ndarray  # the leaf's path efficiency to the grid
    taper: np.ndarray  # bool: the rate-curve row binds somewhere (else it is implied)
    slope_kw: np.ndarray  # its slope (0 where no taper row)
    hull: np.ndarray  # bool: the charge-or-discharge row (no refund, both directions)
    mirror: np.ndarray  # bool: the discharge-curve row binds somewhere
    slope_d_kw: np.ndarray


def _terms(
    sessions: Sessions, limits: StationLimits, econ: Economics, charged_tolerance_kwh: float
) -> _Terms:
    """The per-session constants of `build_and_solve`'s LP, vectorised. Rows that the
    variables' bounds already imply (the rate curve of a car that never passes ``tau``, the
    discharge curve of one that never gets below its floor) are marked off."""
    f64 = lambda a: np.asarray(a, np.float64)  # noqa: E731
    leaf = np.asarray(sessions.leaf, np.int64)
    cap = np.maximum(f64(sessions.capacity_kwh), 1e-6)
    tau = f64(sessions.tau)
    rate, rate_d = f64(sessions.max_rate_kw), f64(sessions.max_discharge_rate_kw)
    soc0 = f64(sessions.soc0)
    cmax = np.minimum(rate, limits.charge_kw[leaf])
    dmax = np.minimum(rate_d, limits.discharge_kw[leaf])
    lo = np.minimum(f64(sessions.reserve_soc), soc0)
    target = f64(sessions.target_soc)
    hi = np.maximum(target, soc0)
    is_bat = limits.is_battery[leaf]
    price = np.where(is_bat, float(econ.battery_value), float(econ.customer))
    refund = is_bat | bool(econ.refund_discharged)
    wear = np.zeros(leaf.shape) if limits.wear_eur_kwh is None else limits.wear_eur_kwh[leaf]
    pp_max, pm_max = np.maximum(cmax, 0.0), np.maximum(dmax, 0.0)
    taper = (tau < 1.0 - 1e-6) & (cmax > 0)
    slope = np.where(taper, rate / np.where(taper, 1.0 - tau, 1.0), 0.0)
    # p+ + slope x <= slope holds for every x <= hi once p+'s bound fits under the curve at hi
    taper &= pp_max + slope * hi > slope
    slope_d = rate_d / np.maximum(1.0 - tau, 1e-6)
    # p- <= slope_d x holds for every x >= lo once p-'s bound does at lo
    mirror = (dmax > 0) & (pm_max > slope_d * lo)
    return _Terms(
        leaf=leaf,
        cap_kwh=cap,
        pp_max_kw=pp_max,
        pm_max_kw=pm_max,
        soc_lo=lo,
        soc_hi=hi,
        goal_soc=np.maximum(lo, np.minimum(hi, target - charged_tolerance_kwh / cap - 1e-5)),
        price_eur_kwh=price,
        refund=refund,
        wear_eur_kwh=wear,
        eta=limits.path_eff[leaf],
        taper=taper,
        slope_kw=slope,
        hull=~refund & (cmax > 0) & (dmax > 0),
        mirror=mirror,
        slope_d_kw=slope_d,
    )


def _grid_cap_kwh(limits: StationLimits, step_hours: float) -> float:
    """The grid import / export bound per step (kWh)."""
    if limits.hard:
        return limits.root_kw * step_hours
    return float(np.sum(limits.charge_kw / limits.path_eff)) * step_hours


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
    step_offset: int = 0,
    warm_start: Basis | None = None,
    keep_basis: bool = False,
    pools: Pools | None = None,
) -> Solution:
    """Build the LP of the module docstring for ``sessions`` and solve it with HiGHS.

    The rows and columns of all sessions are built at once (arrays over session-steps); a
    discharge variable whose bound is 0 and a row that the bounds imply (a node that its
    sessions cannot overload in a step, a rate curve a car never reaches) are left out, which
    does not change the LP's optimum.

    A solve that reports no optimum is tried again with other settings, in the order of
    `attempt_settings` (presolve switched, the primal simplex, the interior-point method,
    HiGHS's defaults), each from scratch; `Solution.attempt` names the settings that solved
    it.

    Args:
        sessions: the cars and batteries; a session with ``last < first`` is empty.
        num_steps: the problem's steps.
        limits: the station's limits.
        econ: the steps' prices and the profit's constants.
        charged_tolerance_kwh: how far below its target a must-reach session may end.
        time_limit_s: HiGHS's wall-clock limit of each attempt (seconds); None for none.
        occupancy_vars: (used by the MILP) maps a session index to a binary variable of
            ``builder`` that multiplies its power limits (the session exists only when the
            binary is 1).
        builder: a builder holding variables and rows already (the MILP's); None for a new one.
        urgency_eur_kwh_h: per session (used by the MPC): a bonus per kWh that falls by that
            much per hour of delay, so that the LP charges those sessions early among plans of
            (nearly) equal profit; None for the bound.
        step_offset: the day's step of the problem's step 0 (names the columns and rows of
            the basis).
        warm_start: the basis of an earlier problem (e.g. the MPC's previous step): HiGHS
            starts from it where the keys (kind, leaf or node, day's step) match. The
            optimum's value is the same; where several plans are optimal, the plan may differ
            from a solve from scratch. A warm start that fails is solved again from scratch
            (``"default"``), then with the other settings.
        keep_basis: return the optimal basis in `Solution.basis`.
        pools: the port-pooled relaxation (`Pools`, used by `chargax_marl.optimal.pooled`):
            which sessions are one car at several port groups; None for one car per session.

    Returns:
        The optimum: its value, each session's net power per step and end SoC.

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        SolverError: HiGHS reports no optimum with any of the settings (its ``status`` is
            the last attempt's, its ``attempts`` each attempt's).
        ValueError: ``warm_start`` or ``keep_basis`` with ``builder``, ``occupancy_vars`` or
            ``pools`` (their columns and rows have no keys); ``pools`` whose car has sessions
            that start in different steps.
    """
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
    b = builder or _Builder()
    dt = econ.step_hours
    n = num_steps
    cap = _grid_cap_kwh(limits, dt)
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

    first = np.asarray(sessions.first, np.int64)
    last = np.asarray(sessions.last, np.int64)
    valid = np.nonzero(last >= first)[0]
    t = _terms(sessions, limits, econ, charged_tolerance_kwh)
    t = _Terms(**{k: getattr(t, k)[valid] for k in _Terms.__dataclass_fields__})
    soc0 = np.asarray(sessions.soc0, np.float64)[valid]
    must = np.asarray(sessions.must_reach, bool)[valid]
    cond_of = occupancy_vars or {}
    z = np.array([cond_of.get(int(s), -1) for s in valid], np.int64)
    cond = z >= 0
    num_sess = valid.shape[0]
    # session-steps ("cells"): session cs, local step k, problem step step
    m = last[valid] - first[valid] + 1
    num_cells = int(m.sum())
    off = np.concatenate([[0], np.cumsum(m)[:-1]]).astype(np.int64)
    cs = np.repeat(np.arange(num_sess), m)
    k = np.arange(num_cells) - off[cs]
    step = first[valid][cs] + k
    # a pooled car's sessions share the SoC of its longest session ("primary"); a holding
    # session's power is bounded by its share of a port, a continuous variable
    prim = np.arange(num_sess)
    pooled = np.zeros(num_sess, bool)
    if pools is not None:
        car = np.asarray(pools.car, np.int64)[valid]
        pooled = car >= 0
        idx = np.nonzero(pooled)[0]
        # the primary is the car's longest session: every other one's steps are in its range
        idx = idx[np.lexsort((-m[idx], car[idx]))]
        cars, first_of = np.unique(car[idx], return_index=True)
        prim[idx] = idx[first_of][np.searchsorted(cars, car[idx])]
        if np.any(first[valid][prim] != first[valid]):
            raise ValueError("field 'pools.car' joins sessions that start in different steps")
        holds = pooled & np.asarray(pools.holds, bool)[valid]
        hs = np.nonzero(holds)[0]
        z[hs] = b.vars(hs.size, 0.0, 1.0)
        cond = z >= 0

    value = t.price_eur_kwh[cs]
    if urgency_eur_kwh_h is not None:
        value = value + np.asarray(urgency_eur_kwh_h, np.float64)[valid][cs] * (n - step) * dt
    wear = t.wear_eur_kwh[cs]
    pp = b.vars(num_cells, 0.0, t.pp_max_kw[cs], cost=(value - wear) * dt)
    # discharge only where its bound is positive; a car without the refund earns no price on it
    dc = np.nonzero(t.pm_max_kw[cs] > 0)[0]
    dcs = cs[dc]
    refund_value = np.where(t.refund[dcs], value[dc], value[dc] - t.price_eur_kwh[dcs])
    pm = b.vars(dc.shape[0], 0.0, t.pm_max_kw[dcs], cost=-(refund_value + wear[dc]) * dt)
    # SoC x_0..x_m per session: x_0 fixed at the start SoC; the end may be forced to the goal
    x_lo = np.repeat(t.soc_lo, m + 1)
    x_hi = np.repeat(t.soc_hi, m + 1)
    x_first = off + np.arange(num_sess)
    x_end = x_first + m
    x_lo[x_first] = x_hi[x_first] = soc0
    x_lo[x_end[must & ~cond]] = t.goal_soc[must & ~cond]
    x = b.vars(num_cells + num_sess, x_lo, x_hi)
    xs_own = x[x_first[cs] + k]
    xs = x[x_first[prim[cs]] + k]  # SoC at the start of each cell (a pooled car's shared one)
    pcell = off[prim[cs]] + k  # the cell whose SoC row takes the cell's power
    # only when the session exists: x_end - (goal - lo) z >= lo
    mc = np.nonzero(must & cond)[0]
    if mc.size:
        row = b.new_rows(mc.size, t.soc_lo[mc], np.inf)
        b.coef(row, x[x_end[mc]], 1.0)
        b.coef(row, z[mc], -(t.goal_soc[mc] - t.soc_lo[mc]))
    # SoC dynamics: x_{k+1} - x_k - (p+ - p-) dt / C = 0
    # (a pooled car's other sessions keep their own SoC at the start SoC, no power in it)
    dyn = b.new_rows(num_cells, 0.0, 0.0)
    b.coef(dyn, xs_own + 1, 1.0)
    b.coef(dyn, xs_own, -1.0)
    b.coef(dyn[pcell], pp, -dt / t.cap_kwh[cs])
    b.coef(dyn[pcell[dc]], pm, dt / t.cap_kwh[dcs])
    cc = np.nonzero(cond[cs])[0]
    if cc.size:  # p+ <= cmax z, p- <= dmax z
        lim = b.new_rows(cc.size, -np.inf, 0.0)
        b.coef(lim, pp[cc], 1.0)
        b.coef(lim, z[cs[cc]], -t.pp_max_kw[cs[cc]])
        cd = np.nonzero(cond[dcs])[0]
        lim = b.new_rows(cd.size, -np.inf, 0.0)
        b.coef(lim, pm[cd], 1.0)
        b.coef(lim, z[dcs[cd]], -t.pm_max_kw[dcs[cd]])
    tc = np.nonzero(t.taper[cs])[0]
    taper = b.new_rows(tc.size, -np.inf, t.slope_kw[cs[tc]])  # p+ + slope x <= slope
    b.coef(taper, pp[tc], 1.0)
    b.coef(taper, xs[tc], t.slope_kw[cs[tc]])
    # the simulator charges or discharges a car in a step, never both: p+ / cmax + p- / dmax
    # <= 1 (the convex hull of the two). Without it, charging and discharging at once would
    # bill the customer for energy that never stays in the car.
    hc = np.nonzero(t.hull[dcs])[0]
    hull = b.new_rows(hc.size, -np.inf, 1.0)
    b.coef(hull, pp[dc[hc]], 1.0 / t.pp_max_kw[dcs[hc]])
    b.coef(hull, pm[hc], 1.0 / t.pm_max_kw[dcs[hc]])
    mc = np.nonzero(t.mirror[dcs])[0]
    mirror = b.new_rows(mc.size, -np.inf, 0.0)  # p- - slope x <= 0
    b.coef(mirror, pm[mc], 1.0)
    b.coef(mirror, xs[dc[mc]], -t.slope_d_kw[dcs[mc]])
    b.coef(grid_rows[step], pp, -dt / t.eta[cs])
    b.coef(grid_rows[step[dc]], pm, dt * t.eta[dcs])
    node_keys = np.zeros(0, np.int64)
    if limits.hard:
        node_keys = _node_rows(b, limits, n, t, cs, step, pp, dc, pm)
    if pools is not None:
        _pool_rows(b, pools, valid, t, cs, step, pcell, pooled, holds, z, pp, dc, pm, soc0, dt)

    keyed = warm_start is not None or keep_basis
    if keyed and (builder is not None or occupancy_vars or pools is not None):
        raise ValueError(
            "fields 'builder', 'occupancy_vars' and 'pools' must be None with 'warm_start' or "
            "'keep_basis'"
        )
    if keyed:
        num_nodes = limits.node_max_kw.shape[0]
        steps = step_offset + np.arange(n)
        leaf_c, leaf_d = t.leaf[cs], t.leaf[dcs]
        x_step = step_offset + np.repeat(first[valid], m + 1) + np.arange(num_cells + num_sess)
        x_step -= np.repeat(x_first, m + 1)
        col_key = np.concatenate(
            [_key(0, 0, steps), _key(1, 0, steps)]
            + ([_key(2, 0, [0])] if econ.peak_eur_kw > 0.0 else [])
            + [
                _key(3, leaf_c, step_offset + step),
                _key(4, leaf_d, step_offset + step[dc]),
                _key(5, np.repeat(t.leaf, m + 1), x_step),
            ]
        )
        cell = step_offset + step
        row_key = np.concatenate(
            [_key(0, 0, steps)]
            + ([_key(1, 0, steps)] if econ.peak_eur_kw > 0.0 else [])
            + [
                _key(4, leaf_c, cell),
                _key(7, leaf_c[tc], cell[tc]),
                _key(8, leaf_d[hc], cell[dc[hc]]),
                _key(9, leaf_d[mc], cell[dc[mc]]),
                _key(2, node_keys % num_nodes, step_offset + node_keys // num_nodes),
            ]
        )
    guess = (None, None) if warm_start is None else warm_start.guess(col_key, row_key)
    _, xsol, value_eur, solve_s, h, attempt = b.solve(
        time_limit_s=time_limit_s,
        col_status=guess[0],
        row_status=guess[1],
        first=None if pools is None else POOLED_OPTIONS,
    )
    pm_full = np.zeros(num_cells)
    pm_full[dc] = xsol[pm]
    net_cells = np.split(xsol[pp] - pm_full, off[1:]) if num_sess else []
    net: list = [None] * sessions.size
    soc_end = np.full(sessions.size, np.nan)
    for i, s in enumerate(valid):
        net[s] = net_cells[i]
    soc_end[valid] = xsol[x[x_end[prim]]]
    return Solution(
        value_eur=value_eur,
        status=STATUS[0],
        solve_s=solve_s,
        num_vars=b.n,
        num_rows=b.m,
        net_kw=net,
        soc_end=soc_end,
        x=xsol,
        basis=Basis.read(h, b, col_key, row_key) if keep_basis else None,
        attempt=attempt,
    )


def _pool_rows(
    b: _Builder,
    pools: Pools,
    valid,
    t: _Terms,
    cs,
    step,
    pcell,
    pooled,
    holds,
    z,
    pp,
    dc,
    pm,
    soc0,
    dt: float,
) -> None:
    """`Pools`' rows: each pooled car takes at most one port's worth per step, and each
    group at most its port count per step. A holding session counts its share of a port in
    every step of its range; any other its power over its bound. A holding session's net
    energy is at most its share of what the car can take (``(hi - soc0) C``): a car at a
    port, share 1, takes at most that, and a car turned away, share 0, nothing; without
    the row, a small share of a fast port could carry a whole car's energy."""
    num_cells = cs.shape[0]
    group = np.asarray(pools.group, np.int64)[valid]
    group_ports = np.asarray(pools.group_ports, np.float64)
    # each cell's use of a port, as (cell, column, coefficient) terms
    on = pooled[cs]
    hold_c = np.nonzero(on & holds[cs])[0]
    free_c = np.nonzero(on & ~holds[cs] & (t.pp_max_kw[cs] > 0))[0]
    free_d = np.nonzero(on[dc] & ~holds[cs[dc]])[0]
    cells = np.concatenate([hold_c, free_c, dc[free_d]])
    cols = np.concatenate([z[cs[hold_c]], pp[free_c], pm[free_d]])
    vals = np.concatenate(
        [
            np.ones(hold_c.size),
            1.0 / t.pp_max_kw[cs[free_c]],
            1.0 / t.pm_max_kw[cs[dc[free_d]]],
        ]
    )
    # one port's worth per car and step: one row per primary cell
    car_row = np.full(num_cells, -1, np.int64)
    used = np.unique(pcell[cells])
    car_row[used] = b.new_rows(used.size, -np.inf, 1.0)
    b.coef(car_row[pcell[cells]], cols, vals)
    # a group's port count per step
    num_groups = group_ports.shape[0]
    key = step[cells] * num_groups + group[cs[cells]]
    keys, inverse = np.unique(key, return_inverse=True)
    rows = b.new_rows(keys.size, -np.inf, group_ports[keys % num_groups])
    b.coef(rows[inverse], cols, vals)
    # a holding session's net energy (kWh) - its share * what the car can take <= 0
    hs = np.nonzero(holds)[0]
    row_of = np.full(holds.shape[0], -1, np.int64)
    row_of[hs] = b.new_rows(hs.size, -np.inf, 0.0)
    room_kwh = (t.soc_hi[hs] - soc0[hs]) * t.cap_kwh[hs]
    b.coef(row_of[hs], z[hs], -np.maximum(room_kwh, 0.0))
    cell_h = np.nonzero(holds[cs])[0]
    b.coef(row_of[cs[cell_h]], pp[cell_h], dt)
    dis_h = np.nonzero(holds[cs[dc]])[0]
    b.coef(row_of[cs[dc[dis_h]]], pm[dis_h], -dt)


def _node_rows(
    b: _Builder, limits: StationLimits, n: int, t: _Terms, cs, step, pp, dc, pm
) -> np.ndarray:
    """The node limits on the grid side, one row per (step, node) that the sessions under the
    node could overload in that step (at every other one the bounds imply the limit).

    Returns:
        The rows' keys ``step * num_nodes + node``, in row order.
    """
    num_nodes = limits.node_max_kw.shape[0]
    # every (depth, cell) whose leaf has a node at that depth, depth by depth; a node sits at
    # one depth, so each row's sums below run over its cells in the same order either way
    node = limits.node_at_depth[:, t.leaf[cs]]  # (depths, cells)
    eff = limits.eff_at_depth[:, t.leaf[cs]]
    d_c, on_c = np.nonzero(node >= 0)
    key_c = step[on_c] * num_nodes + node[d_c, on_c]
    e_c = eff[d_c, on_c]
    d_d, on_d = np.nonzero(node[:, dc] >= 0)
    key_d = step[dc[on_d]] * num_nodes + node[d_d, dc[on_d]]
    e_d = eff[d_d, dc[on_d]]
    size = n * num_nodes
    worst_c = np.bincount(key_c, t.pp_max_kw[cs[on_c]] / e_c, size)
    worst_d = np.bincount(key_d, t.pm_max_kw[cs[dc[on_d]]] * e_d, size)
    node_max = np.tile(limits.node_max_kw, n)
    keep = np.nonzero((worst_c > node_max) | (worst_d > node_max))[0]
    row_of = np.full(size, -1, np.int64)
    row_of[keep] = b.new_rows(keep.size, -node_max[keep], node_max[keep])
    for key, col, val in ((key_c, pp[on_c], 1.0 / e_c), (key_d, pm[on_d], -e_d)):
        r = row_of[key]
        on = r >= 0
        b.coef(r[on], col[on], val[on])
    return keep
