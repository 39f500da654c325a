"""The value of the energy held in the station battery at each step of each day, from the
day's known prices: the duals of a battery-only arbitrage LP (`storage_values`, a value
per kWh) and the value function of the same problem with the battery's three full-power
actions solved by dynamic programming (`dp_values`, a value per stored energy level),
with the programme's best action read from a state (`dp_battery_action`).

Day-ahead prices are published the day before, so a station knows all of a day's prices at
midnight. For each day the LP below buys and sells the battery's energy against those
prices; the dual of its energy balance at step ``t`` is ``value[day, t]`` (EUR/kWh): what one
more kWh in the battery at the start of step ``t`` is worth for the rest of the day.

A trainer uses it as a *potential* ``Phi_t = value[day, t] * E_t`` (``E_t`` the batteries'
stored energy at the start of step ``t``; `chargax_marl.teachers.shaping.battery_potential`,
`chargax_marl.wrappers.BatteryShaping`): the shaping term of a step is ``Phi_{t+1} - Phi_t``
minus the env's terminal booking at the day's last step, where ``value[day, T]`` is the
env's own terminal price (the day's mean buy price), so a day's undiscounted shaped reward
differs from the env's by ``(terminal price - value[day, 0]) * E_0``, which no action
changes (Ng, Harada and Russell 1999). A one-step learner then sees charging at ``p`` pay
``value[t+1] - p / eta`` per kWh and discharging ``eta * p - value[t+1]``, the decisions of
the LP (complementary slackness), instead of comparisons with the day's mean price that pay
for cycling the battery at middling prices.

The LP ignores the cars: the battery's energy is priced at the buy price both ways (what a
discharged kWh saves while the station draws from the grid), losses are the battery's path
efficiency each way, and every kWh into or out of the cells pays the battery's wear
(`battery_wear_eur_kwh`), so a cycle pays only where the spread beats both. It is a
learning signal only; the evaluation scores the env's profit.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import linprog

from chargax_marl.core import clock
from chargax_marl.core.reward import battery_terminal_value_eur, price_tables
from chargax_marl.core.station import KIND_BATTERY


def battery_constants(params) -> tuple[float, float, float, float]:
    """The station's batteries as one store: ``(eta, power_kw, capacity_kwh, e0_kwh)``, the mean
    path efficiency of the battery leaves, their summed top power (kW) and capacity (kWh), and
    the energy they hold at the start of a day (the middle of the initial SoC range, kWh).

    Args:
        params: concrete `chargax_marl.core.types.EnvParams`.

    Returns:
        ``(eta, power_kw, capacity_kwh, e0_kwh)`` as Python floats.

    Raises:
        ValueError: the station has no battery.
    """
    st = params.station
    kind = np.asarray(st.leaf_kind)
    if int(np.sum(kind == KIND_BATTERY)) == 0:
        raise ValueError(
            "the battery teachers (storage value, dynamic programme) need a station with a battery; "
            "this station has none"
        )
    eta = float(np.mean(np.asarray(st.leaf_path_efficiency)[kind == KIND_BATTERY]))
    power_kw = float(np.sum(np.asarray(st.leaf_max_kw)[kind == KIND_BATTERY]))
    capacity_kwh = float(np.sum(np.asarray(st.battery_capacity_kwh)))
    soc0 = 0.5 * (
        np.asarray(params.battery_soc0_low, np.float64)
        + np.asarray(params.battery_soc0_high, np.float64)
    )
    e0 = float(np.sum(soc0 * np.asarray(st.battery_capacity_kwh)))
    return eta, power_kw, capacity_kwh, e0


def battery_wear_eur_kwh(params) -> float:
    """The wear cost per kWh into or out of the batteries' cells.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams`.

    Returns:
        The mean of ``params.battery_wear_eur_kwh`` over the batteries (EUR/kWh), a Python
        float; 0 without a battery.
    """
    wear = np.asarray(params.battery_wear_eur_kwh, np.float64)
    return float(np.mean(wear)) if wear.size else 0.0


def step_buy_prices(params) -> np.ndarray:
    """The buy price of every step, as the env prices it.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams`.

    Returns:
        ``(days, steps)`` float64 buy prices (EUR/kWh): day-ahead + grid fee + time-of-use
        (`chargax_marl.core.reward.price_tables`).

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.teachers.storage_value.step_buy_prices")
    return np.asarray(price_tables(params)[0], np.float64)


def terminal_prices(params) -> np.ndarray:
    """The env's terminal price of every day: what a stored kWh is credited at the day's end.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams`.

    Returns:
        ``(days,)`` float64 prices (EUR/kWh) of
        `chargax_marl.core.reward.battery_terminal_value_eur`.

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.teachers.storage_value.terminal_prices")
    days = jnp.arange(np.asarray(params.prices_eur_kwh).shape[0], dtype=jnp.int32)
    return np.asarray(
        jax.vmap(lambda d: battery_terminal_value_eur(jnp.float32(1.0), d, params))(days),
        np.float64,
    )


def day_values(
    prices,
    terminal_price: float,
    eta: float,
    power_kw: float,
    capacity_kwh: float,
    e0: float,
    step_hours: float,
    wear_eur_kwh: float = 0.0,
) -> np.ndarray:
    """``(T + 1,)`` value of a stored kWh at the start of each step of one day, the last entry
    the terminal price: the duals of

    max sum_t (eta p_t - w) d_t - (p_t / eta + w) c_t + terminal * E_T  s.t.
    E_{t+1} = E_t + c_t - d_t,  0 <= E_t <= C,  0 <= c_t, d_t <= P dt,  E_0 = e0,

    ``w`` the wear per kWh into or out of the cells (``wear_eur_kwh``; 0: free cycling).

    Args:
        prices: ``(T,)`` the day's buy prices (EUR/kWh), the ``p_t``.
        terminal_price: the value of a kWh held at the day's end (EUR/kWh).
        eta: the store's path efficiency to the grid, each way.
        power_kw: the store's top power (kW), into or out of the cells.
        capacity_kwh: the store's capacity ``C`` (kWh).
        e0: the energy held at the day's start (kWh).
        step_hours: the length of a step (hours).
        wear_eur_kwh: the wear ``w`` per kWh into or out of the cells (EUR/kWh).

    Returns:
        ``(T + 1,)`` float64 values (EUR/kWh): entry ``t`` the dual of the energy balance of
        step ``t`` (the value of one more kWh held from step ``t`` on), the last entry
        ``terminal_price``.

    Raises:
        RuntimeError: HiGHS (`scipy.optimize.linprog`) does not solve the LP.
    """
    p = np.asarray(prices, np.float64)
    n = p.shape[0]
    w = float(wear_eur_kwh)
    # variables [c (n), d (n), E_1..E_n (n)]; minimise the negated profit
    cost = np.concatenate([p / eta + w, -eta * p + w, np.zeros(n)])
    cost[3 * n - 1] = -terminal_price
    a = np.zeros((n, 3 * n))
    rows = np.arange(n)
    a[rows, rows] = -1.0  # - c_t
    a[rows, n + rows] = 1.0  # + d_t
    a[rows, 2 * n + rows] = 1.0  # + E_{t+1}
    a[rows[1:], 2 * n + rows[1:] - 1] = -1.0  # - E_t (E_0 on the right-hand side)
    b = np.zeros(n)
    b[0] = e0
    step_kwh = power_kw * step_hours
    bounds = [(0.0, step_kwh)] * (2 * n) + [(0.0, capacity_kwh)] * n
    res = linprog(cost, A_eq=a, b_eq=b, bounds=bounds, method="highs")
    if res.status != 0:
        raise RuntimeError(f"storage-value LP failed: {res.message}")
    # one more kWh on the right-hand side of row t is one more kWh held from step t on;
    # its effect on the minimised cost is the marginal, so its value is minus that
    return np.concatenate([-np.asarray(res.eqlin.marginals, np.float64), [terminal_price]])


def storage_values(params) -> np.ndarray:
    """The value of a stored kWh at the start of every step of every day: the duals of the
    battery-only LP of `day_values`, one LP per day.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams` of a station with a battery.

    Returns:
        ``(days, steps + 1)`` float32 values (EUR/kWh); the last column is the env's terminal
        price (the day's mean buy price, or the fixed battery price of
        ``make_params(battery_terminal_price=...)``).

    Raises:
        ValueError: the station has no battery.
        RuntimeError: an LP fails to solve.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.teachers.storage_value.storage_values")
    eta, power_kw, capacity_kwh, e0 = battery_constants(params)
    prices = step_buy_prices(params)
    terminal = terminal_prices(params)
    wear = battery_wear_eur_kwh(params)
    out = np.zeros((prices.shape[0], prices.shape[1] + 1), np.float64)
    for day in range(prices.shape[0]):
        out[day] = day_values(
            prices[day],
            terminal[day],
            eta,
            power_kw,
            capacity_kwh,
            e0,
            float(params.step_hours),
            wear_eur_kwh=wear,
        )
    return out.astype(np.float32)


def dp_values(params, points_per_step: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The value function of the battery-only problem over the battery's three full-power
    actions (discharge, idle, charge) on the day's buy prices, by backward induction.

    The same battery-only model as `day_values` (the batteries as one store of their
    summed capacity and power, energy priced at the buy price both ways, the path efficiency
    each way, the wear per kWh in and out), but with the discrete actions the
    ``num_levels=1`` agents choose among, and
    valued per energy level rather than per kWh. As a potential ``Phi_t = value[day, t](E_t)``
    (linear in between grid points, ``points_per_step`` of them per step's full-power energy)
    the shaping term of a step is ``Phi_{t+1}(E_{t+1}) - Phi_t(E_t)`` minus the env's terminal
    booking at the day's last step, so a day's undiscounted sum moves by ``terminal price *
    E_0 - Phi_0(E_0)``, a constant of the first state (Ng, Harada and Russell 1999). A
    one-step learner then sees each action's loss against the best action of the battery-only
    problem, instead of a comparison with one value per kWh that is zero wherever the LP is
    indifferent. The learner's policy still sees only its observation, not this table.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams` of a station with a battery.
        points_per_step: grid points per step's full-power energy (an integer >= 1).

    Returns:
        ``(grid, value)``, float32: ``grid (K,)`` the stored energies (kWh, from 0 to the
        capacity) and ``value (days, steps + 1, K)``, the most a battery holding ``grid[k]``
        kWh at the start of step ``t`` of ``day`` can still earn that day,
        ``value[day, t, k]`` (EUR); ``value[day, steps]`` is the env's terminal booking, the
        day's terminal price times the energy held.

    Raises:
        ValueError: the station has no battery, or ``points_per_step`` is not an integer
            >= 1.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.teachers.storage_value.dp_values")
    eta, power_kw, capacity_kwh, _ = battery_constants(params)
    grid, value = level_values(
        step_buy_prices(params),
        terminal_prices(params),
        eta,
        power_kw * float(params.step_hours),
        capacity_kwh,
        points_per_step,
        wear_eur_kwh=battery_wear_eur_kwh(params),
    )
    return grid.astype(np.float32), value.astype(np.float32)


def level_values(
    prices,
    terminal_price,
    eta: float,
    step_kwh: float,
    capacity_kwh: float,
    points_per_step: int = 4,
    wear_eur_kwh: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The tables of `dp_values` for given prices: per step, the best of discharging
    ``step_kwh`` (earns ``eta * p - w`` per kWh taken out), idling and charging ``step_kwh``
    (costs ``p / eta + w`` per kWh stored), each cut at the empty and the full battery.

    Args:
        prices: buy prices (EUR/kWh), ``(days, steps)`` (or ``(steps,)`` for one day).
        terminal_price: the price a kWh held at the day's end is credited at (EUR/kWh), a
            scalar or ``(days,)``.
        eta: the battery's efficiency each way, in (0, 1].
        step_kwh: the energy a full-power action moves in one step (kWh, > 0).
        capacity_kwh: the battery's capacity (kWh, > 0).
        points_per_step: grid points per ``step_kwh`` (an integer >= 1).
        wear_eur_kwh: ``w``, the wear per kWh into or out of the cells (EUR/kWh; 0: free
            cycling).

    Returns:
        ``(grid, value)``, float64: ``grid (K,)`` the stored energies (kWh) and
        ``value (days, steps + 1, K)`` (EUR), as in `dp_values`.

    Raises:
        ValueError: ``points_per_step`` not an integer >= 1, or ``step_kwh``,
            ``capacity_kwh`` or ``eta`` out of range.
    """
    if (
        isinstance(points_per_step, bool)
        or int(points_per_step) != points_per_step
        or points_per_step < 1
    ):
        raise ValueError(f"points_per_step must be an integer >= 1, got {points_per_step!r}")
    if not (step_kwh > 0 and capacity_kwh > 0 and 0 < eta <= 1):
        raise ValueError(
            f"need step_kwh > 0, capacity_kwh > 0 and 0 < eta <= 1, got {step_kwh!r}, "
            f"{capacity_kwh!r}, {eta!r}"
        )
    prices = np.atleast_2d(np.asarray(prices, np.float64))
    days, steps = prices.shape
    num = max(int(np.ceil(capacity_kwh / step_kwh * int(points_per_step) - 1e-9)), 1)
    grid = np.linspace(0.0, capacity_kwh, num + 1)
    value = np.zeros((days, steps + 1, grid.size), np.float64)
    value[:, steps] = (
        np.broadcast_to(np.asarray(terminal_price, np.float64), (days,))[:, None] * grid[None, :]
    )
    for t in range(steps - 1, -1, -1):
        nxt = value[:, t + 1]
        q = action_values(
            np,
            lambda e: _interp_rows(nxt, grid, e),
            grid,
            prices[:, t, None],
            eta,
            step_kwh,
            capacity_kwh,
            wear_eur_kwh,
        )
        value[:, t] = np.maximum(np.maximum(q[0], q[1]), q[2])
    return grid, value


def action_values(
    xp,
    value_after,
    energy,
    price,
    eta: float,
    step_kwh: float,
    capacity_kwh: float,
    wear_eur_kwh: float = 0.0,
):
    """What each full-power action earns this step plus the value of the level it leaves.

    Discharging earns ``eta * p - w`` per kWh taken out, charging costs ``p / eta + w`` per
    kWh stored, each cut at the empty and the full battery.

    Args:
        xp: the array module, ``numpy`` or ``jax.numpy``.
        value_after: ``value_after(energy after) -> value`` (EUR) of the level an action
            leaves.
        energy: the stored energy (kWh), any shape broadcasting with ``price``.
        price: the step's buy price ``p`` (EUR/kWh).
        eta: the battery's efficiency each way.
        step_kwh: the energy a full-power action moves in one step (kWh).
        capacity_kwh: the battery's capacity (kWh).
        wear_eur_kwh: ``w``, the wear per kWh into or out of the cells (EUR/kWh).

    Returns:
        ``(discharge, idle, charge)``: the three actions' values (EUR), each of the
        broadcast shape of ``energy`` and ``price``.
    """
    full = xp.minimum(energy + step_kwh, capacity_kwh)
    empty = xp.maximum(energy - step_kwh, 0.0)
    return (
        (eta * price - wear_eur_kwh) * (energy - empty) + value_after(empty),
        value_after(energy),
        -(price / eta + wear_eur_kwh) * (full - energy) + value_after(full),
    )


def level_value(rows, energy, step_kwh: float):
    """Values on the uniform grid of `dp_values`, read linearly between grid points (jax).

    Args:
        rows: values on the grid ``0, step_kwh, 2 step_kwh, ...``, shape ``(..., K)``.
        energy: the stored energies to read at (kWh), shape ``(...)``; clipped to the grid.
        step_kwh: the grid spacing (kWh).

    Returns:
        The interpolated values, shape ``(...)``.
    """
    x = jnp.clip(energy / step_kwh, 0.0, rows.shape[-1] - 1.0)
    i = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, rows.shape[-1] - 2)
    lo = jnp.take_along_axis(rows, i[..., None], axis=-1)[..., 0]
    hi = jnp.take_along_axis(rows, i[..., None] + 1, axis=-1)[..., 0]
    return lo + (x - i) * (hi - lo)


def _interp_rows(rows: np.ndarray, grid: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``rows (..., K)`` on the uniform ``grid (K,)``, linearly interpolated at ``x (K,)``."""
    h = grid[1] - grid[0]
    i = np.clip(np.floor(x / h).astype(np.int64), 0, grid.size - 2)
    w = (x - grid[i]) / h
    return rows[..., i] * (1.0 - w) + rows[..., i + 1] * w


def dp_battery_action(params):
    """The battery-only programme's best full-power action, read from a simulator state.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams` of a station with a battery
            (the tables of `dp_values` are built for its days and prices).

    Returns:
        ``act(state) -> (action, strict)`` for one (unbatched) core state: ``action`` int32 in
        ``{-1, 0, 1}`` (discharge, idle, charge at full power) for the batteries' summed
        stored energy, and ``strict`` bool, whether that action is strictly best (by more than
        1e-4 EUR). Jittable.

    Raises:
        ValueError: the station has no battery.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.teachers.storage_value.dp_battery_action")
    grid, table = dp_values(params)
    table, grid_kwh = jnp.asarray(table), float(grid[1] - grid[0])
    prices = jnp.asarray(step_buy_prices(params), jnp.float32)
    eta, power_kw, capacity_kwh, _ = battery_constants(params)
    wear = battery_wear_eur_kwh(params)
    step_kwh = power_kw * float(params.step_hours)
    is_battery = params.station.leaf_kind == KIND_BATTERY

    def act(state):
        e = jnp.sum(jnp.where(is_battery, state.soc * state.capacity_kwh, 0.0))
        nxt = table[state.day, state.timestep + 1]
        q = jnp.stack(
            action_values(
                jnp,
                lambda x: level_value(nxt, x, grid_kwh),
                e,
                prices[state.day, state.timestep],
                eta,
                step_kwh,
                capacity_kwh,
                wear,
            )
        )
        best = jnp.argmax(q)
        strict = jnp.sort(q)[-1] - jnp.sort(q)[-2] > 1e-4
        return best - 1, strict

    return act
