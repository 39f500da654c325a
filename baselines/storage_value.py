"""The value of a kWh held in the station battery at each step of each day: the duals of a
battery-only arbitrage LP on the day's known prices, for ``BATTERY_SHAPING="storage_value"``.

Day-ahead prices are published the day before, so a station knows all of a day's prices at
midnight. For each day the LP below buys and sells the battery's energy against those
prices; the dual of its energy balance at step ``t`` is ``value[day, t]`` (EUR/kWh): what one
more kWh in the battery at the start of step ``t`` is worth for the rest of the day.

The trainers use it as a *potential* ``Phi_t = value[day, t] * E_t`` (``E_t`` the batteries'
stored energy at the start of step ``t``): the shaping term of a step is ``Phi_{t+1} - Phi_t``
minus the env's terminal booking at the day's last step, where ``value[day, T]`` is the
env's own terminal price (the day's mean buy price), so a day's undiscounted shaped reward
differs from the env's by ``(terminal price - value[day, 0]) * E_0``, which no action
changes (Ng, Harada and Russell 1999). A one-step learner then sees charging at ``p`` pay
``value[t+1] - p / eta`` per kWh and discharging ``eta * p - value[t+1]``, the decisions of
the LP (complementary slackness), instead of comparisons with the day's mean price that pay
for cycling the battery at middling prices.

The LP ignores the cars: the battery's energy is priced at the buy price both ways (what a
discharged kWh saves while the station draws from the grid), and losses are the battery's
path efficiency each way. It is a learning signal only; the evaluation scores the env's
profit.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from chargax_marl.core.station import KIND_BATTERY


def _battery_constants(params):
    st = params.station
    kind = np.asarray(st.leaf_kind)
    if int(np.sum(kind == KIND_BATTERY)) == 0:
        raise ValueError("BATTERY_SHAPING='storage_value' needs a station with a battery; this station has none")
    eta = float(np.mean(np.asarray(st.leaf_path_efficiency)[kind == KIND_BATTERY]))
    power_kw = float(np.sum(np.asarray(st.leaf_max_kw)[kind == KIND_BATTERY]))
    capacity_kwh = float(np.sum(np.asarray(st.battery_capacity_kwh)))
    soc0 = 0.5 * (np.asarray(params.battery_soc0_low, np.float64) + np.asarray(params.battery_soc0_high, np.float64))
    e0 = float(np.sum(soc0 * np.asarray(st.battery_capacity_kwh)))
    return eta, power_kw, capacity_kwh, e0


def step_buy_prices(params) -> np.ndarray:
    """``(days, steps)`` buy price (EUR/kWh) of every step, as the env prices it
    (:func:`chargax_marl.core.reward.price_tables`: day-ahead + grid fee + time-of-use)."""
    from chargax_marl.core.reward import price_tables

    return np.asarray(price_tables(params)[0], np.float64)


def day_values(prices, terminal_price: float, eta: float, power_kw: float, capacity_kwh: float, e0: float,
               step_hours: float) -> np.ndarray:
    """``(T + 1,)`` value of a stored kWh at the start of each step of one day, the last entry
    the terminal price: the duals of

    max sum_t eta p_t d_t - p_t c_t / eta + terminal * E_T  s.t.
    E_{t+1} = E_t + c_t - d_t,  0 <= E_t <= C,  0 <= c_t, d_t <= P dt,  E_0 = e0.
    """
    p = np.asarray(prices, np.float64)
    n = p.shape[0]
    # variables [c (n), d (n), E_1..E_n (n)]; minimise the negated profit
    cost = np.concatenate([p / eta, -eta * p, np.zeros(n)])
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
    """``(days, steps + 1)`` float32 value of a stored kWh at the start of every step of every
    day of ``params`` (last column: the env's terminal price, the day's mean buy price, or the
    fixed battery price of ``make_params(battery_terminal_price=...)``)."""
    import jax
    import jax.numpy as jnp

    from chargax_marl.core.reward import battery_terminal_value_eur

    eta, power_kw, capacity_kwh, e0 = _battery_constants(params)
    prices = step_buy_prices(params)
    days = jnp.arange(prices.shape[0], dtype=jnp.int32)
    terminal = np.asarray(jax.vmap(lambda d: battery_terminal_value_eur(jnp.float32(1.0), d, params))(days), np.float64)
    out = np.zeros((prices.shape[0], prices.shape[1] + 1), np.float64)
    for day in range(prices.shape[0]):
        out[day] = day_values(prices[day], terminal[day], eta, power_kw, capacity_kwh, e0, float(params.step_hours))
    return out.astype(np.float32)
