"""The station: a static tree of grid connection, splitters, charging ports and batteries.

A station is described with plain Python objects (`Port`, `Battery`,
`Splitter`) and compiled once by `compile_station` into
`StationArrays`, a pytree of fixed-shape arrays that the jitted step reads.
The step never walks Python objects.

Leaf order is the port order of the tree (depth-first, left to right) followed by the
batteries, so ``leaf i`` is ``port_i`` for ``i < num_ports`` and the batteries come last.

Units: voltage in V, current in A, power in kW (``P = V * I / 1000``), energy in kWh.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Sequence
from typing import Union

import jax.numpy as jnp
import numpy as np
from flax import struct

from chargax_marl.core import checks
from chargax_marl.core.arrays import device_array

KIND_AC = 0
KIND_DC = 1
KIND_BATTERY = 2
KIND_NAMES = ("AC", "DC", "battery")


def _check_positive(
    owner: str, field: str, value: float, low: float, high: float, unit: str
) -> None:
    """A finite number > 0 within ``[low, high]`` after the float32 cast (see `checks`)."""
    if (
        isinstance(value, (int, float, np.floating, np.integer))
        and math.isfinite(value)
        and value <= 0
    ):
        raise ValueError(
            f"{owner}: field '{field}' must be a finite number > 0 (in [{low:g}, {high:g}] {unit}), "
            f"got {value!r}"
        )
    checks.number(field, value, low=low, high=high, unit=unit, owner=owner)


def _check_non_negative(owner: str, field: str, value: float, high: float, unit: str) -> None:
    if (
        isinstance(value, (int, float, np.floating, np.integer))
        and math.isfinite(value)
        and value < 0
    ):
        raise ValueError(
            f"{owner}: field '{field}' must be a finite number >= 0 (in [0, {high:g}] {unit}), "
            f"got {value!r}"
        )
    checks.number(field, value, low=0.0, high=high, unit=unit, owner=owner)


def _check_efficiency(owner: str, value: float) -> None:
    if not (
        isinstance(value, (int, float, np.floating, np.integer))
        and not isinstance(value, (bool, np.bool_))
        and checks.MIN_EFFICIENCY <= value <= 1.0
    ):
        raise ValueError(
            f"{owner}: field 'efficiency' must lie in (0, 1] (at least {checks.MIN_EFFICIENCY:g}), "
            f"got {value!r}"
        )


def _check_unit_interval(
    owner: str, field: str, value: float, *, open_low: bool, open_high: bool
) -> None:
    ok_type = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(
        value, (bool, np.bool_)
    )
    ok_low = ok_type and (value > 0 if open_low else value >= 0)
    ok_high = ok_type and (value < 1 if open_high else value <= 1)
    if not (ok_low and ok_high):
        lo = "(" if open_low else "["
        hi = ")" if open_high else "]"
        raise ValueError(f"{owner}: field '{field}' must lie in {lo}0, 1{hi}, got {value!r}")
    checks.number(
        field, value, low=0.0, high=1.0, low_open=open_low, high_open=open_high, owner=owner
    )


BATTERY_COST_EUR_KWH = 150.0
"""Default installed cost of a station battery (EUR per kWh of capacity): the global average
turnkey price of a stationary storage system in 2024 (sources in the data README)."""
BATTERY_CYCLE_LIFE = 6000.0
"""Default cycle life of a station battery: full equivalent cycles of stationary LFP cells to
80 % of their capacity (sources in the data README)."""
DAYS_PER_YEAR = 365.0


def battery_wear_eur_kwh(cost_eur_kwh: float, cycle_life: float) -> float:
    """The wear cost per kWh of cell throughput (in or out), EUR/kWh.

    A full equivalent cycle moves the capacity into and out of the cells, ``2 C`` kWh of
    throughput, and uses up ``1 / cycle_life`` of the battery: ``cost * C / cycle_life`` EUR.

    Args:
        cost_eur_kwh: installed cost per kWh of capacity (EUR/kWh).
        cycle_life: full equivalent cycles to the end of life.

    Returns:
        ``cost_eur_kwh / (2 cycle_life)`` (EUR per kWh of throughput).
    """
    return float(cost_eur_kwh) / (2.0 * float(cycle_life))


def battery_calendar_eur_day(
    cost_eur_kwh: float, capacity_kwh: float, calendar_life_years: float | None
) -> float:
    """The calendar ageing cost per day, EUR/day: the installed cost spread evenly over the
    calendar life (0 when ``calendar_life_years`` is None).

    Args:
        cost_eur_kwh: installed cost per kWh of capacity (EUR/kWh).
        capacity_kwh: the battery's capacity (kWh).
        calendar_life_years: the calendar life (years), or ``None`` for no calendar ageing.

    Returns:
        ``cost_eur_kwh * capacity_kwh / (calendar_life_years * 365)`` (EUR/day), or 0.0.
    """
    if calendar_life_years is None:
        return 0.0
    return float(cost_eur_kwh) * float(capacity_kwh) / (float(calendar_life_years) * DAYS_PER_YEAR)


def check_battery_wear(
    owner: str, cost_eur_kwh: float, cycle_life: float, calendar_life_years: float | None
) -> None:
    """Validate the wear inputs of a battery.

    Args:
        owner: what the inputs belong to, for the message (e.g. ``"Battery 'b'"``).
        cost_eur_kwh: installed cost per kWh of capacity (EUR/kWh), in
            ``[0, checks.MAX_BATTERY_COST_EUR_KWH]``.
        cycle_life: full equivalent cycles to the end of life, in
            ``[checks.MIN_CYCLE_LIFE, checks.MAX_CYCLE_LIFE]``.
        calendar_life_years: the calendar life (years), ``None`` or in
            ``[checks.MIN_CALENDAR_LIFE_YEARS, checks.MAX_CALENDAR_LIFE_YEARS]``.

    Raises:
        ValueError: ``cost_eur_kwh`` not finite and >= 0, ``cycle_life`` not finite and > 0,
            ``calendar_life_years`` neither None nor finite and > 0, or a value outside the
            bounds above.
    """
    _check_non_negative(
        owner, "cost_eur_kwh", cost_eur_kwh, checks.MAX_BATTERY_COST_EUR_KWH, "EUR/kWh"
    )
    _check_positive(
        owner, "cycle_life", cycle_life, checks.MIN_CYCLE_LIFE, checks.MAX_CYCLE_LIFE, "cycles"
    )
    if calendar_life_years is not None:
        _check_positive(
            owner,
            "calendar_life_years",
            calendar_life_years,
            checks.MIN_CALENDAR_LIFE_YEARS,
            checks.MAX_CALENDAR_LIFE_YEARS,
            "years",
        )


@dataclasses.dataclass(frozen=True)
class Port:
    """A charging port (one EVSE connector): a leaf of the station tree.

    Its fields are checked when it is built (``ValueError`` naming the port and field).

    Attributes:
        name: the port's name, unique in the station.
        kind: ``"DC"`` or ``"AC"`` (which of the car's rate limits applies).
        voltage_v: the port's voltage (V).
        max_current_a: the charging current limit (A); ``voltage_v * max_current_a / 1000``
            is the port's rating in kW.
        max_discharge_current_a: the discharging current limit (A); 0 means the port cannot
            discharge (no V2G).
        efficiency: the port's own efficiency, in (0, 1]; the path efficiency to the grid
            multiplies it with every ancestor's efficiency.
    """

    name: str
    kind: str = "DC"
    voltage_v: float = 500.0
    max_current_a: float = 150.0
    max_discharge_current_a: float = 0.0
    efficiency: float = 1.0

    def __post_init__(self) -> None:
        owner = f"Port '{self.name}'"
        if self.kind not in ("AC", "DC"):
            raise ValueError(f"{owner}: field 'kind' must be 'AC' or 'DC', got {self.kind!r}")
        _check_positive(
            owner, "voltage_v", self.voltage_v, checks.MIN_VOLTAGE_V, checks.MAX_VOLTAGE_V, "V"
        )
        _check_positive(
            owner,
            "max_current_a",
            self.max_current_a,
            checks.MIN_CURRENT_A,
            checks.MAX_CURRENT_A,
            "A",
        )
        _check_non_negative(
            owner,
            "max_discharge_current_a",
            self.max_discharge_current_a,
            checks.MAX_CURRENT_A,
            "A",
        )
        _check_efficiency(owner, self.efficiency)

    @property
    def max_kw(self) -> float:
        return self.voltage_v * self.max_current_a / 1000.0


@dataclasses.dataclass(frozen=True)
class Battery:
    """A stationary station battery: a leaf controlled like a port that is always occupied.

    It charges and discharges through the same rate curve as a car (``tau``), within
    ``[0, capacity_kwh]``, at up to ``max_kw`` in both directions.

    Its cells wear with use: ``cost_eur_kwh`` (the installed cost per kWh of capacity) buys
    ``cycle_life`` full equivalent cycles, so every kWh moved into or out of the cells costs
    `wear_eur_kwh`, half a cycle's share of the cost; ``calendar_life_years`` (None: no
    calendar ageing) adds `calendar_eur_day` per day whatever the battery does. Both are
    part of the profit (`chargax_marl.core.reward.battery_wear_eur`); the defaults and
    their sources are in the data README. ``cost_eur_kwh=0`` makes cycling free.

    Attributes:
        name: the battery's name, unique in the station.
        capacity_kwh: the energy it holds when full (kWh).
        max_kw: the most power it takes or gives (kW), both directions.
        voltage_v: its voltage (V); the current limit is ``max_kw * 1000 / voltage_v``.
        efficiency: its own efficiency, in (0, 1].
        tau: the SoC above which its charge rate tapers, in (0, 1).
        initial_soc: its SoC at the start of a day, in [0, 1] (unless
            ``make_params(battery_initial_soc=...)`` overrides it).
        cost_eur_kwh: the installed cost per kWh of capacity (EUR/kWh).
        cycle_life: full equivalent cycles to the end of life.
        calendar_life_years: the calendar life (years); None: no calendar ageing.
    """

    name: str = "battery"
    capacity_kwh: float = 200.0
    max_kw: float = 100.0
    voltage_v: float = 800.0
    efficiency: float = 0.95
    tau: float = 0.8
    initial_soc: float = 0.5
    cost_eur_kwh: float = BATTERY_COST_EUR_KWH
    cycle_life: float = BATTERY_CYCLE_LIFE
    calendar_life_years: float | None = None

    def __post_init__(self) -> None:
        owner = f"Battery '{self.name}'"
        _check_positive(
            owner,
            "capacity_kwh",
            self.capacity_kwh,
            checks.MIN_CAPACITY_KWH,
            checks.MAX_CAPACITY_KWH,
            "kWh",
        )
        _check_positive(
            owner, "max_kw", self.max_kw, checks.MIN_POWER_KW, checks.MAX_POWER_KW, "kW"
        )
        _check_positive(
            owner, "voltage_v", self.voltage_v, checks.MIN_VOLTAGE_V, checks.MAX_VOLTAGE_V, "V"
        )
        _check_efficiency(owner, self.efficiency)
        _check_unit_interval(owner, "tau", self.tau, open_low=True, open_high=True)
        _check_unit_interval(
            owner, "initial_soc", self.initial_soc, open_low=False, open_high=False
        )
        check_battery_wear(owner, self.cost_eur_kwh, self.cycle_life, self.calendar_life_years)

    @property
    def max_current_a(self) -> float:
        return self.max_kw * 1000.0 / self.voltage_v

    @property
    def wear_eur_kwh(self) -> float:
        """The wear cost of one kWh into or out of the cells (EUR/kWh of throughput)."""
        return battery_wear_eur_kwh(self.cost_eur_kwh, self.cycle_life)

    @property
    def calendar_eur_day(self) -> float:
        """The calendar ageing cost per day (EUR/day; 0 without a calendar life)."""
        return battery_calendar_eur_day(
            self.cost_eur_kwh, self.capacity_kwh, self.calendar_life_years
        )


Node = Union["Splitter", Port, Battery]


@dataclasses.dataclass(frozen=True)
class Splitter:
    """An inner node (grid connection, splitter, cable or transformer) with a power limit.

    The net power through the node, measured on its grid side, must stay at or below
    ``max_kw`` (paper Eq. 3): each leaf below it contributes its power divided by the
    efficiencies on its path up to and including this node when it charges (multiplied
    when it discharges), and the contributions add with their signs.

    Attributes:
        name: the node's name, unique in the station.
        max_kw: the limit on the net power through the node, grid side (kW).
        children: the nodes below it (`Splitter`, `Port` or `Battery`), at least one.
        efficiency: the node's efficiency, in (0, 1].
    """

    name: str
    max_kw: float
    children: tuple = ()
    efficiency: float = 1.0

    def __post_init__(self) -> None:
        owner = f"Splitter '{self.name}'"
        _check_positive(
            owner, "max_kw", self.max_kw, checks.MIN_POWER_KW, checks.MAX_POWER_KW, "kW"
        )
        _check_efficiency(owner, self.efficiency)
        object.__setattr__(self, "children", tuple(self.children))
        if len(self.children) == 0:
            raise ValueError(
                f"{owner}: field 'children' must hold at least one node, got an empty tree"
            )
        for child in self.children:
            if not isinstance(child, (Splitter, Port, Battery)):
                raise ValueError(
                    f"{owner}: field 'children' must hold Splitter, Port or Battery objects, got {type(child).__name__}"
                )


@struct.dataclass
class StationArrays:
    """The compiled station: fixed-shape arrays over leaves (L) and inner nodes (H).

    Leaves are ports ``0..num_ports-1`` then batteries. ``node_of_leaf_at_depth[d, l]``
    is the index of leaf ``l``'s ancestor at depth ``d`` (``-1`` where there is none, for
    leaves that hang higher up); with it, node flows are segment sums, linear in ports.
    ``leaf_efficiency_at_depth[d, l]`` is the efficiency of the path from leaf ``l`` up to
    and including that ancestor, the factor that turns the leaf's power into the flow it
    causes on the node's grid side. ``B`` is the number of batteries, ``D`` the tree depth.

    Attributes:
        leaf_voltage_v: ``(L,)`` each leaf's voltage (V).
        leaf_max_current_a: ``(L,)`` charging limit (A).
        leaf_max_discharge_current_a: ``(L,)`` discharging limit (A), 0 where no V2G.
        leaf_efficiency: ``(L,)`` own efficiency.
        leaf_path_efficiency: ``(L,)`` product of efficiencies from the root to the leaf.
        leaf_efficiency_at_depth: ``(D, L)`` product of the efficiencies from the leaf up to
            and including its ancestor at depth d (its own efficiency included; 1 where it
            has none).
        leaf_kind: ``(L,)`` int32: 0 AC, 1 DC, 2 battery.
        battery_capacity_kwh: ``(B,)`` capacity (kWh).
        battery_tau: ``(B,)`` SoC above which the charge rate tapers.
        battery_initial_soc: ``(B,)`` SoC at the start of a day.
        battery_cost_eur_kwh: ``(B,)`` installed cost per kWh of capacity (EUR/kWh).
        battery_cycle_life: ``(B,)`` full equivalent cycles to the end of life.
        battery_calendar_life_years: ``(B,)`` calendar life (years), 0 = no calendar ageing.
        leaf_solo_max_kw: ``(L,)`` most power a leaf can take alone: its rating and every
            ancestor's limit divided by the efficiency of the path up to that ancestor (kW).
        node_max_kw: ``(H,)`` each node's limit, grid side (kW).
        node_efficiency: ``(H,)`` each node's efficiency.
        node_depth: ``(H,)`` int32, root = 0.
        node_of_leaf_at_depth: ``(D, L)`` int32, -1 = none.
        incidence: ``(H, L)`` float32, 1 if leaf under node (for analysis and tests).
        num_ports: the number of ports.
        num_batteries: ``B``.
        num_nodes: ``H``.
        depth: ``D``, the depth of the tree.
        leaf_names: the leaves' names, in leaf order.
        node_names: the nodes' names, in node order.
    """

    leaf_voltage_v: jnp.ndarray
    leaf_max_current_a: jnp.ndarray
    leaf_max_discharge_current_a: jnp.ndarray
    leaf_efficiency: jnp.ndarray
    leaf_path_efficiency: jnp.ndarray
    leaf_efficiency_at_depth: jnp.ndarray
    leaf_kind: jnp.ndarray
    battery_capacity_kwh: jnp.ndarray
    battery_tau: jnp.ndarray
    battery_initial_soc: jnp.ndarray
    battery_cost_eur_kwh: jnp.ndarray
    battery_cycle_life: jnp.ndarray
    battery_calendar_life_years: jnp.ndarray
    leaf_solo_max_kw: jnp.ndarray
    node_max_kw: jnp.ndarray
    node_efficiency: jnp.ndarray
    node_depth: jnp.ndarray
    node_of_leaf_at_depth: jnp.ndarray
    incidence: jnp.ndarray
    num_ports: int = struct.field(pytree_node=False, default=0)
    num_batteries: int = struct.field(pytree_node=False, default=0)
    num_nodes: int = struct.field(pytree_node=False, default=0)
    depth: int = struct.field(pytree_node=False, default=0)
    leaf_names: tuple = struct.field(pytree_node=False, default=())
    node_names: tuple = struct.field(pytree_node=False, default=())

    @property
    def num_leaves(self) -> int:
        return self.num_ports + self.num_batteries

    @property
    def leaf_max_kw(self) -> jnp.ndarray:
        return self.leaf_voltage_v * self.leaf_max_current_a / 1000.0


def compile_station(root: Splitter) -> StationArrays:
    """Validate a station tree and compile it to `StationArrays`.

    Args:
        root: the grid connection, a `Splitter` whose subtree holds the ports, splitters and
            batteries (each node's own fields are checked when it is built).

    Returns:
        The compiled arrays: leaves are the ports in depth-first order, then the batteries.

    Raises:
        ValueError: an invalid tree, naming the node and field: a root that is not a
            `Splitter`, no ports, duplicate names.
    """
    if not isinstance(root, Splitter):
        raise ValueError(
            f"station root must be a Splitter (the grid connection), got {type(root).__name__}"
        )

    ports: list[tuple[Port, list[int]]] = []
    batteries: list[tuple[Battery, list[int]]] = []
    nodes: list[Splitter] = []
    depths: list[int] = []
    names: set[str] = set()

    def visit(node: Node, ancestors: list[int], depth: int) -> None:
        if node.name in names:
            raise ValueError(
                f"station: duplicate node name {node.name!r}; every node needs a unique 'name'"
            )
        names.add(node.name)
        if isinstance(node, Splitter):
            idx = len(nodes)
            nodes.append(node)
            depths.append(depth)
            for child in node.children:
                visit(child, ancestors + [idx], depth + 1)
        elif isinstance(node, Port):
            ports.append((node, ancestors))
        else:
            batteries.append((node, ancestors))

    visit(root, [], 0)
    if not ports:
        raise ValueError(
            f"station '{root.name}': the tree must contain at least one Port, found none"
        )

    leaves = [p for p, _ in ports] + [b for b, _ in batteries]
    leaf_anc = [a for _, a in ports] + [a for _, a in batteries]
    num_leaves, num_nodes = len(leaves), len(nodes)
    depth = max(depths) + 1

    node_eff = np.array([n.efficiency for n in nodes], dtype=np.float64)
    incidence = np.zeros((num_nodes, num_leaves), dtype=np.float32)
    at_depth = -np.ones((depth, num_leaves), dtype=np.int32)
    path_eff = np.ones(num_leaves, dtype=np.float64)
    eff_at_depth = np.ones((depth, num_leaves), dtype=np.float64)
    for leaf, anc in enumerate(leaf_anc):
        for h in anc:
            incidence[h, leaf] = 1.0
            at_depth[depths[h], leaf] = h
            # ancestors below h (deeper) and h itself, plus the leaf's own efficiency
            below = [a for a in anc if depths[a] >= depths[h]]
            eff_at_depth[depths[h], leaf] = leaves[leaf].efficiency * float(
                np.prod(node_eff[below])
            )
        path_eff[leaf] = leaves[leaf].efficiency * float(np.prod(node_eff[anc]))

    def leaf_attr(fn):
        return np.array([fn(x) for x in leaves], dtype=np.float32)

    kind = np.array(
        [
            KIND_BATTERY if isinstance(x, Battery) else (KIND_AC if x.kind == "AC" else KIND_DC)
            for x in leaves
        ],
        dtype=np.int32,
    )
    bats = [b for b, _ in batteries]
    leaf_kw = leaf_attr(lambda x: x.voltage_v * x.max_current_a / 1000.0).astype(np.float64)
    node_kw = np.array([n.max_kw for n in nodes], dtype=np.float64)
    solo = leaf_kw.copy()
    for leaf, anc in enumerate(leaf_anc):
        for h in anc:
            solo[leaf] = min(solo[leaf], node_kw[h] * eff_at_depth[depths[h], leaf])
    return StationArrays(
        leaf_voltage_v=device_array(leaf_attr(lambda x: x.voltage_v)),
        leaf_max_current_a=device_array(leaf_attr(lambda x: x.max_current_a)),
        leaf_max_discharge_current_a=device_array(
            leaf_attr(
                lambda x: x.max_current_a if isinstance(x, Battery) else x.max_discharge_current_a
            )
        ),
        leaf_efficiency=device_array(leaf_attr(lambda x: x.efficiency)),
        leaf_path_efficiency=device_array(path_eff.astype(np.float32)),
        leaf_efficiency_at_depth=device_array(eff_at_depth.astype(np.float32)),
        leaf_kind=device_array(kind),
        battery_capacity_kwh=device_array(
            np.array([b.capacity_kwh for b in bats], dtype=np.float32)
        ),
        battery_tau=device_array(np.array([b.tau for b in bats], dtype=np.float32)),
        battery_initial_soc=device_array(np.array([b.initial_soc for b in bats], dtype=np.float32)),
        battery_cost_eur_kwh=device_array(np.array([b.cost_eur_kwh for b in bats], np.float32)),
        battery_cycle_life=device_array(np.array([b.cycle_life for b in bats], np.float32)),
        battery_calendar_life_years=device_array(
            np.array([b.calendar_life_years or 0.0 for b in bats], np.float32)
        ),
        leaf_solo_max_kw=device_array(solo.astype(np.float32)),
        node_max_kw=device_array(node_kw.astype(np.float32)),
        node_efficiency=device_array(node_eff.astype(np.float32)),
        node_depth=device_array(np.array(depths, dtype=np.int32)),
        node_of_leaf_at_depth=device_array(at_depth),
        incidence=device_array(incidence),
        num_ports=len(ports),
        num_batteries=len(batteries),
        num_nodes=num_nodes,
        depth=depth,
        leaf_names=tuple(x.name for x in leaves),
        node_names=tuple(n.name for n in nodes),
    )


# --------------------------------------------------------------------------- builders

# Paper defaults: DC EVSE of 150 kW shared by 2 connectors, AC EVSE of 11.5 kW shared by 2.
DC_VOLTAGE_V = 500.0
DC_MAX_CURRENT_A = 300.0  # 150 kW per connector at 500 V; the EVSE group caps the pair at 150 kW
AC_VOLTAGE_V = 400.0
AC_MAX_CURRENT_A = 28.75  # 11.5 kW per connector at 400 V (three-phase folded into V)
DC_GROUP_KW = 150.0
AC_GROUP_KW = 11.5


def _ports(
    prefix: str,
    n: int,
    kind: str,
    voltage_v: float,
    max_current_a: float,
    v2g: bool,
    efficiency: float,
    start: int,
) -> list[Port]:
    return [
        Port(
            name=f"{prefix}{start + i}",
            kind=kind,
            voltage_v=voltage_v,
            max_current_a=max_current_a,
            max_discharge_current_a=max_current_a if v2g else 0.0,
            efficiency=efficiency,
        )
        for i in range(n)
    ]


def _groups(
    ports: Sequence[Port], per_group: int, group_kw: float, prefix: str, efficiency: float
) -> list[Node]:
    """Wrap consecutive ports in EVSE splitters of ``per_group`` connectors sharing ``group_kw``."""
    if per_group <= 1:
        return list(ports)
    return [
        Splitter(
            f"{prefix}{g}",
            max_kw=group_kw,
            children=tuple(ports[i : i + per_group]),
            efficiency=efficiency,
        )
        for g, i in enumerate(range(0, len(ports), per_group))
    ]


def _root_children(children: list[Node], battery: Battery | bool | None) -> list[Node]:
    if battery is True:
        battery = Battery()
    if isinstance(battery, Battery):
        children = children + [battery]
    return children


def _check_count(builder: str, field: str, value: int, minimum: int) -> None:
    if not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(
            f"{builder}: field '{field}' must be an integer >= {minimum}, got {value!r}"
        )


def _check_grid_kw(builder: str, grid_kw: float | None) -> None:
    """``grid_kw`` is None (the sum of the root's children) or a rating in kW; 0 is not "default"."""
    if grid_kw is not None:
        checks.number(
            "grid_kw",
            grid_kw,
            low=checks.MIN_POWER_KW,
            high=checks.MAX_POWER_KW,
            unit="kW",
            owner=builder,
        )


@checks.known_keywords
def single_type(
    num_ports: int = 16,
    *,
    kind: str = "DC",
    voltage_v: float | None = None,
    max_current_a: float | None = None,
    v2g: bool = True,
    efficiency: float = 0.95,
    grid_kw: float | None = None,
    battery: Battery | bool | None = None,
) -> Splitter:
    """Paper Fig. 3a: ``num_ports`` ports of one kind directly under the grid connection.

    ``voltage_v``, ``max_current_a`` and ``grid_kw`` default (None) to the kind's paper values
    and the sum of the ports; 0 is rejected, not read as "default".

    Args:
        num_ports: the number of ports (>= 1).
        kind: ``"DC"`` or ``"AC"``.
        voltage_v: each port's voltage (V); None: 500 V for DC, 400 V for AC.
        max_current_a: each port's charging current limit (A); None: 300 A for DC (150 kW at
            500 V), 28.75 A for AC (11.5 kW at 400 V).
        v2g: the ports can discharge, up to ``max_current_a``; False: discharge limit 0.
        efficiency: each port's efficiency, in (0, 1].
        grid_kw: the grid connection's limit (kW); None: the sum of the ports' ratings and
            the battery's.
        battery: a `Battery` under the grid connection; True: the default `Battery`;
            None or False: no battery.

    Returns:
        The station tree: a `Splitter` named ``"grid"`` over the ports (and the battery).

    Raises:
        ValueError: ``num_ports`` not an integer >= 1, ``kind`` neither ``"AC"`` nor
            ``"DC"``, or a voltage, current, efficiency or ``grid_kw`` outside its range.
        TypeError: an unknown keyword argument.
    """
    _check_count("single_type", "num_ports", num_ports, 1)
    if kind not in ("AC", "DC"):
        raise ValueError(f"single_type: field 'kind' must be 'AC' or 'DC', got {kind!r}")
    if voltage_v is None:
        voltage_v = DC_VOLTAGE_V if kind == "DC" else AC_VOLTAGE_V
    if max_current_a is None:
        max_current_a = DC_GROUP_KW * 1000 / DC_VOLTAGE_V if kind == "DC" else AC_MAX_CURRENT_A
    checks.number(
        "voltage_v",
        voltage_v,
        low=checks.MIN_VOLTAGE_V,
        high=checks.MAX_VOLTAGE_V,
        unit="V",
        owner="single_type",
    )
    checks.number(
        "max_current_a",
        max_current_a,
        low=checks.MIN_CURRENT_A,
        high=checks.MAX_CURRENT_A,
        unit="A",
        owner="single_type",
    )
    _check_grid_kw("single_type", grid_kw)
    ports = _ports("port_", num_ports, kind, voltage_v, max_current_a, v2g, efficiency, 0)
    children = _root_children(list(ports), battery)
    if grid_kw is None:
        grid_kw = sum(p.max_kw for p in ports) + (
            children[-1].max_kw if len(children) > len(ports) else 0.0
        )
    root_kw = grid_kw
    return Splitter("grid", max_kw=root_kw, children=tuple(children))


@checks.known_keywords
def multiple_types(
    num_dc: int = 10,
    num_ac: int = 6,
    *,
    ports_per_evse: int = 2,
    dc_evse_kw: float = DC_GROUP_KW,
    ac_evse_kw: float = AC_GROUP_KW,
    v2g: bool = True,
    port_efficiency: float = 0.95,
    splitter_efficiency: float = 0.99,
    grid_kw: float | None = None,
    battery: Battery | bool | None = True,
) -> Splitter:
    """Paper Fig. 3b and the default station: DC and AC ports in EVSE groups under one splitter per kind.

    Default: 16 ports, 10 DC in 2-port groups of 150 kW and 6 AC in 2-port groups of
    11.5 kW; each kind's splitter carries the sum of its groups. The root carries the sum of
    its children. DC ports run at 500 V, AC ports at 400 V; each port's current limit is
    its group's power at that voltage.

    Args:
        num_dc: the number of DC ports (>= 0).
        num_ac: the number of AC ports (>= 0); ``num_dc + num_ac >= 1``.
        ports_per_evse: connectors per EVSE group, sharing the group's power (1: no groups).
        dc_evse_kw: the power of a DC EVSE group (kW), also each DC port's rating.
        ac_evse_kw: the power of an AC EVSE group (kW), also each AC port's rating.
        v2g: the ports can discharge, up to their charging current; False: discharge limit 0.
        port_efficiency: each port's efficiency, in (0, 1].
        splitter_efficiency: the efficiency of each EVSE group and kind splitter, in (0, 1].
        grid_kw: the grid connection's limit (kW); None: the sum of its children's.
        battery: a `Battery` under the grid connection; True (default): the default
            `Battery` (200 kWh, 100 kW), the paper's (N+1)-th controllable leaf; None or
            False: a station without one.

    Returns:
        The station tree: a `Splitter` named ``"grid"`` over the kinds' splitters (and the
        battery).

    Raises:
        ValueError: a count that is not an integer in range, no port at all, or a power,
            efficiency or ``grid_kw`` outside its range.
        TypeError: an unknown keyword argument.
    """
    _check_count("multiple_types", "num_dc", num_dc, 0)
    _check_count("multiple_types", "num_ac", num_ac, 0)
    _check_count("multiple_types", "ports_per_evse", ports_per_evse, 1)
    if num_dc + num_ac < 1:
        raise ValueError("multiple_types: fields 'num_dc' + 'num_ac' must be >= 1, got 0 ports")
    for field, value in (("dc_evse_kw", dc_evse_kw), ("ac_evse_kw", ac_evse_kw)):
        checks.number(
            field,
            value,
            low=checks.MIN_POWER_KW,
            high=checks.MAX_POWER_KW,
            unit="kW",
            owner="multiple_types",
        )
    _check_grid_kw("multiple_types", grid_kw)
    children: list[Node] = []
    dc_ports = _ports(
        "port_",
        num_dc,
        "DC",
        DC_VOLTAGE_V,
        dc_evse_kw * 1000 / DC_VOLTAGE_V,
        v2g,
        port_efficiency,
        0,
    )
    ac_ports = _ports(
        "port_",
        num_ac,
        "AC",
        AC_VOLTAGE_V,
        ac_evse_kw * 1000 / AC_VOLTAGE_V,
        v2g,
        port_efficiency,
        num_dc,
    )
    for ports, evse_kw, tag in ((dc_ports, dc_evse_kw, "dc"), (ac_ports, ac_evse_kw, "ac")):
        if not ports:
            continue
        groups = _groups(ports, ports_per_evse, evse_kw, f"{tag}_evse_", splitter_efficiency)
        n_groups = math.ceil(len(ports) / ports_per_evse)
        children.append(
            Splitter(
                f"{tag}_splitter",
                max_kw=evse_kw * n_groups,
                children=tuple(groups),
                efficiency=splitter_efficiency,
            )
        )
    children = _root_children(children, battery)
    root_kw = sum(c.max_kw for c in children) if grid_kw is None else grid_kw
    return Splitter("grid", max_kw=root_kw, children=tuple(children))


@checks.known_keywords
def multiple_splitters(
    num_dc: int = 10,
    num_ac: int = 6,
    *,
    splitters_per_kind: int = 2,
    ports_per_evse: int = 2,
    dc_evse_kw: float = DC_GROUP_KW,
    ac_evse_kw: float = AC_GROUP_KW,
    splitter_fraction: float = 0.75,
    v2g: bool = True,
    port_efficiency: float = 0.95,
    splitter_efficiency: float = 0.99,
    grid_kw: float | None = None,
    battery: Battery | bool | None = True,
) -> Splitter:
    """Paper Fig. 3c: several splitters per charger kind, each carrying only a fraction of its groups.

    Each kind's EVSE groups are divided over ``splitters_per_kind`` splitters; a splitter is
    rated at ``splitter_fraction`` of the sum of its groups, so the extra level constrains
    the currents. The root is rated at the sum of its splitters. The ports and groups are
    those of `multiple_types`.

    Args:
        num_dc: the number of DC ports (>= 0).
        num_ac: the number of AC ports (>= 0); ``num_dc + num_ac >= 1``.
        splitters_per_kind: splitters each kind's groups are divided over (>= 1; at most one
            per group).
        ports_per_evse: connectors per EVSE group, sharing the group's power (1: no groups).
        dc_evse_kw: the power of a DC EVSE group (kW), also each DC port's rating.
        ac_evse_kw: the power of an AC EVSE group (kW), also each AC port's rating.
        splitter_fraction: each splitter's limit as a fraction of the sum of its groups, in
            (0, 1].
        v2g: the ports can discharge, up to their charging current; False: discharge limit 0.
        port_efficiency: each port's efficiency, in (0, 1].
        splitter_efficiency: the efficiency of every group and splitter, in (0, 1].
        grid_kw: the grid connection's limit (kW); None: the sum of its children's.
        battery: a `Battery` under the grid connection; True (default): the default
            `Battery`; None or False: none.

    Returns:
        The station tree: a `Splitter` named ``"grid"`` over one splitter per kind, each over
        its ``splitters_per_kind`` splitters (and the battery).

    Raises:
        ValueError: a count that is not an integer in range, or a power, fraction,
            efficiency or ``grid_kw`` outside its range.
        TypeError: an unknown keyword argument.
    """
    _check_count("multiple_splitters", "splitters_per_kind", splitters_per_kind, 1)
    _check_grid_kw("multiple_splitters", grid_kw)
    _check_unit_interval(
        "multiple_splitters", "splitter_fraction", splitter_fraction, open_low=True, open_high=False
    )
    base = multiple_types(
        num_dc,
        num_ac,
        ports_per_evse=ports_per_evse,
        dc_evse_kw=dc_evse_kw,
        ac_evse_kw=ac_evse_kw,
        v2g=v2g,
        port_efficiency=port_efficiency,
        splitter_efficiency=splitter_efficiency,
        battery=None,
    )
    kinds: list[Node] = []
    for kind_node in base.children:
        groups = list(kind_node.children)
        n = min(splitters_per_kind, len(groups))
        chunks = [groups[i::n] for i in range(n)]
        subs = tuple(
            Splitter(
                f"{kind_node.name}_{j}",
                max_kw=splitter_fraction * sum(g.max_kw for g in chunk),
                children=tuple(chunk),
                efficiency=splitter_efficiency,
            )
            for j, chunk in enumerate(chunks)
        )
        kinds.append(
            Splitter(
                kind_node.name,
                max_kw=sum(s.max_kw for s in subs),
                children=subs,
                efficiency=splitter_efficiency,
            )
        )
    kinds = _root_children(kinds, battery)
    root_kw = sum(c.max_kw for c in kinds) if grid_kw is None else grid_kw
    return Splitter("grid", max_kw=root_kw, children=tuple(kinds))


ARCHITECTURES = {
    "single_type": single_type,
    "multiple_types": multiple_types,
    "multiple_splitters": multiple_splitters,
}


def with_grid_fraction(root: Splitter, grid_fraction: float) -> Splitter:
    """``root`` with its limit (the grid connection) set to ``grid_fraction`` times the sum of
    its children's limits: 0.25 makes a station whose connection carries a quarter of what
    its EVSEs, cables and batteries could draw together, so the agents must share it.

    Args:
        root: the station's grid connection.
        grid_fraction: the fraction, in ``(0, 1]``.

    Returns:
        A copy of ``root`` with the new ``max_kw`` (kW), validated as a `Splitter`.

    Raises:
        ValueError: ``grid_fraction`` is not a finite number in ``(0, 1]``, or the new
            limit is outside ``[checks.MIN_POWER_KW, checks.MAX_POWER_KW]``.
    """
    f = checks.number("grid_fraction", grid_fraction, low=0.0, low_open=True, high=1.0)
    children_kw = sum(c.max_kw for c in root.children)
    return dataclasses.replace(root, max_kw=f * children_kw)


def build_station(
    architecture: str | Splitter | StationArrays = "multiple_types",
    *,
    grid_fraction: float | None = None,
    **kwargs,
) -> StationArrays:
    """Compile a named architecture (with builder keyword arguments), a custom tree, or pass
    through arrays (checked by `check_station_arrays`).

    Args:
        architecture: a builder's name (``"single_type"``, ``"multiple_types"``,
            ``"multiple_splitters"``), a custom `Splitter` tree, or compiled `StationArrays`.
        grid_fraction: in (0, 1]: sets the root's limit to that fraction of the sum of its
            children's limits (`with_grid_fraction`); None: the tree's own limit.
        **kwargs: keyword arguments of the named architecture's builder (`single_type`,
            `multiple_types`, `multiple_splitters`).

    Returns:
        The compiled station.

    Raises:
        KeyError: an unknown architecture name.
        ValueError: ``grid_fraction`` with compiled arrays, builder keyword arguments with a
            tree, ``grid_fraction`` together with ``grid_kw``, or an invalid tree or
            arrays.
        TypeError: a keyword argument the named builder does not take.
    """
    if isinstance(architecture, StationArrays):
        if grid_fraction is not None:
            raise ValueError(
                "build_station: field 'grid_fraction' needs a named architecture or a Splitter tree, "
                "not compiled StationArrays"
            )
        return check_station_arrays(architecture)
    if isinstance(architecture, Splitter):
        if kwargs:
            raise ValueError(
                f"build_station: keyword arguments {sorted(kwargs)} only apply to named architectures"
            )
        root = architecture
    else:
        if architecture not in ARCHITECTURES:
            raise KeyError(
                f"unknown architecture {architecture!r}; allowed: {sorted(ARCHITECTURES)} or a Splitter tree"
            )
        builder = ARCHITECTURES[architecture]
        checks.keywords(
            f"station_kwargs of {architecture!r}",
            kwargs,
            tuple(inspect.signature(builder).parameters),
        )
        if grid_fraction is not None and kwargs.get("grid_kw") is not None:
            raise ValueError(
                f"give either 'grid_fraction' ({grid_fraction!r}) or station_kwargs 'grid_kw' "
                f"({kwargs['grid_kw']!r}), not both: both set the grid connection's limit"
            )
        root = builder(**kwargs)
    if grid_fraction is not None:
        root = with_grid_fraction(root, grid_fraction)
    return compile_station(root)


def _check_table(field: str, arr: np.ndarray, allowed: str, ok: np.ndarray) -> None:
    """Raise naming the first entry of an integer table where ``ok`` is False."""
    if not ok.all():
        idx = tuple(int(i) for i in np.argwhere(~ok)[0])
        where = idx[0] if len(idx) == 1 else idx
        raise ValueError(
            f"field 'station.{field}' must hold {allowed}, got {arr[idx]!r} at index {where}"
        )


def check_station_arrays(st: StationArrays) -> StationArrays:
    """Check compiled station arrays made by hand or derived with ``replace``.

    `compile_station` builds arrays that pass; this re-applies the bounds that
    `Port`, `Battery` and `Splitter` enforce (`chargax_marl.core.checks`)
    to the arrays themselves, with the shapes the static sizes imply.

    Args:
        st: the station arrays.

    Returns:
        ``st`` unchanged.

    Raises:
        ValueError: a shape that does not match ``num_ports``, ``num_batteries``, ``num_nodes``
            and ``depth``, or an entry outside its range; the message names the field
            (``station.<field>``), the value and what is allowed.
    """
    n_leaves, n_bat, n_nodes, depth = st.num_leaves, st.num_batteries, st.num_nodes, st.depth
    if st.num_ports < 1 or n_nodes < 1 or depth < 1:
        raise ValueError(
            "field 'station' must have at least one port, one node and depth >= 1, got "
            f"num_ports={st.num_ports}, num_nodes={n_nodes}, depth={depth}"
        )
    leaf, bat, node = (n_leaves,), (n_bat,), (n_nodes,)
    eff = (checks.MIN_EFFICIENCY, 1.0, False, "")
    fields = {  # field: (shape, low, high, low_open, unit)
        "leaf_voltage_v": (leaf, checks.MIN_VOLTAGE_V, checks.MAX_VOLTAGE_V, False, "V"),
        "leaf_max_current_a": (leaf, checks.MIN_CURRENT_A, checks.MAX_CURRENT_A, False, "A"),
        "leaf_max_discharge_current_a": (leaf, 0.0, checks.MAX_CURRENT_A, False, "A"),
        "leaf_efficiency": (leaf, *eff),
        "leaf_path_efficiency": (leaf, *eff),
        "leaf_efficiency_at_depth": ((depth, n_leaves), *eff),
        "battery_capacity_kwh": (
            bat,
            checks.MIN_CAPACITY_KWH,
            checks.MAX_CAPACITY_KWH,
            False,
            "kWh",
        ),
        "battery_tau": (bat, 0.0, 1.0, True, ""),
        "battery_initial_soc": (bat, 0.0, 1.0, False, ""),
        "battery_cost_eur_kwh": (bat, 0.0, checks.MAX_BATTERY_COST_EUR_KWH, False, "EUR/kWh"),
        "battery_cycle_life": (
            bat,
            checks.MIN_CYCLE_LIFE,
            checks.MAX_CYCLE_LIFE,
            False,
            "cycles",
        ),
        "battery_calendar_life_years": (
            bat,
            0.0,
            checks.MAX_CALENDAR_LIFE_YEARS,
            False,
            "years",
        ),
        "leaf_solo_max_kw": (leaf, 0.0, None, True, "kW"),
        "node_max_kw": (node, checks.MIN_POWER_KW, checks.MAX_POWER_KW, False, "kW"),
        "node_efficiency": (node, *eff),
        "incidence": ((n_nodes, n_leaves), 0.0, 1.0, False, ""),
    }
    shapes = {
        **{f: spec[0] for f, spec in fields.items()},
        "leaf_kind": leaf,
        "node_depth": node,
        "node_of_leaf_at_depth": (depth, n_leaves),
    }
    for field, shape in shapes.items():
        got = tuple(np.shape(getattr(st, field)))
        if got != shape:
            raise ValueError(
                f"field 'station.{field}' must have shape {shape} (num_ports={st.num_ports}, "
                f"num_batteries={n_bat}, num_nodes={n_nodes}, depth={depth}), got {got}"
            )
    for field, (_, low, high, low_open, unit) in fields.items():
        checks.array(
            f"station.{field}",
            np.asarray(getattr(st, field)),
            low=low,
            high=high,
            low_open=low_open,
            high_open=field == "battery_tau",
            unit=unit,
        )
    calendar = np.asarray(st.battery_calendar_life_years, np.float64)
    _check_table(
        "battery_calendar_life_years",
        calendar,
        f"0 (no calendar ageing) or years in [{checks.MIN_CALENDAR_LIFE_YEARS:g}, "
        f"{checks.MAX_CALENDAR_LIFE_YEARS:g}]",
        (calendar == 0) | (calendar >= checks.MIN_CALENDAR_LIFE_YEARS),
    )
    kind = np.asarray(st.leaf_kind)
    is_battery = np.arange(n_leaves) >= st.num_ports
    _check_table(
        "leaf_kind",
        kind,
        f"{KIND_AC} (AC) or {KIND_DC} (DC) for the {st.num_ports} ports, then {KIND_BATTERY} "
        f"(battery) for the {n_bat} batteries",
        np.where(is_battery, kind == KIND_BATTERY, (kind == KIND_AC) | (kind == KIND_DC)),
    )
    node_depth = np.asarray(st.node_depth)
    _check_table(
        "node_depth",
        node_depth,
        f"depths in [0, {depth - 1}]",
        (node_depth >= 0) & (node_depth < depth),
    )
    table = np.asarray(st.node_of_leaf_at_depth)
    _check_table(
        "node_of_leaf_at_depth",
        table,
        f"node indices in [0, {n_nodes - 1}] or -1 (none)",
        (table >= -1) & (table < n_nodes),
    )
    return st
