"""A straightforward build of `chargax_marl.optimal.model.build_and_solve`'s LP, one
session and one step at a time into dense arrays, solved by `scipy.optimize.linprog`:
the reference the vectorised builder is checked against. Small problems only."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from chargax_marl.optimal.model import Economics, Sessions, StationLimits


def reference_value_eur(
    sessions: Sessions,
    num_steps: int,
    limits: StationLimits,
    econ: Economics,
    charged_tolerance_kwh: float = 0.0,
    urgency_eur_kwh_h: np.ndarray | None = None,
) -> float:
    """The LP's optimum (EUR), every row written out, none left out."""
    dt, n = econ.step_hours, num_steps
    cost, lo_b, hi_b = [], [], []
    rows: list[tuple[dict, float, float]] = []  # ({column: coefficient}, lb, ub)

    def var(lb, ub, c=0.0):
        cost.append(c)
        lo_b.append(lb)
        hi_b.append(ub)
        return len(cost) - 1

    cap = (
        limits.root_kw * dt
        if limits.hard
        else float(np.sum(limits.charge_kw / limits.path_eff)) * dt
    )
    g_imp = [var(0.0, cap, -econ.buy[k]) for k in range(n)]
    g_exp = [var(0.0, cap, econ.sell[k]) for k in range(n)]
    grid = [{g_imp[k]: 1.0, g_exp[k]: -1.0} for k in range(n)]
    if econ.peak_eur_kw > 0:
        peak = var(econ.peak_so_far_kw, np.inf, -econ.peak_eur_kw)
        for k in range(n):
            rows.append(({g_imp[k]: 1 / dt, g_exp[k]: -1 / dt, peak: -1.0}, -np.inf, 0.0))
    node_flow = {}  # (step, node) -> {column: coefficient}
    for s in range(sessions.size):
        leaf = int(sessions.leaf[s])
        k0, k1 = int(sessions.first[s]), int(sessions.last[s])
        if k1 < k0:
            continue
        c_kwh = max(float(sessions.capacity_kwh[s]), 1e-6)
        tau = float(sessions.tau[s])
        cmax = min(float(sessions.max_rate_kw[s]), float(limits.charge_kw[leaf]))
        dmax = min(float(sessions.max_discharge_rate_kw[s]), float(limits.discharge_kw[leaf]))
        soc0 = float(sessions.soc0[s])
        lo = min(float(sessions.reserve_soc[s]), soc0)
        hi = max(float(sessions.target_soc[s]), soc0)
        is_bat = bool(limits.is_battery[leaf])
        price = econ.battery_value if is_bat else econ.customer
        refund = is_bat or econ.refund_discharged
        wear = 0.0 if limits.wear_eur_kwh is None else float(limits.wear_eur_kwh[leaf])
        goal = max(
            lo, min(hi, float(sessions.target_soc[s]) - charged_tolerance_kwh / c_kwh - 1e-5)
        )
        x = [var(soc0, soc0)]
        for k in range(k0, k1 + 1):
            value = price
            if urgency_eur_kwh_h is not None:
                value += float(urgency_eur_kwh_h[s]) * (n - k) * dt
            pp = var(0.0, max(cmax, 0.0), (value - wear) * dt)
            pm = var(0.0, max(dmax, 0.0), -((value if refund else value - price) + wear) * dt)
            last = k == k1
            x.append(var(goal if last and sessions.must_reach[s] else lo, hi))
            rows.append(({x[-1]: 1.0, x[-2]: -1.0, pp: -dt / c_kwh, pm: dt / c_kwh}, 0.0, 0.0))
            if tau < 1 - 1e-6 and cmax > 0:
                slope = float(sessions.max_rate_kw[s]) / (1 - tau)
                rows.append(({pp: 1.0, x[-2]: slope}, -np.inf, slope))
            if not refund and cmax > 0 and dmax > 0:
                rows.append(({pp: 1 / cmax, pm: 1 / dmax}, -np.inf, 1.0))
            if dmax > 0:
                slope_d = float(sessions.max_discharge_rate_kw[s]) / max(1 - tau, 1e-6)
                rows.append(({pm: 1.0, x[-2]: -slope_d}, -np.inf, 0.0))
            eta = float(limits.path_eff[leaf])
            grid[k][pp] = -dt / eta
            grid[k][pm] = dt * eta
            for d in range(limits.node_at_depth.shape[0]):
                node = int(limits.node_at_depth[d, leaf])
                if node >= 0:
                    e = float(limits.eff_at_depth[d, leaf])
                    flow = node_flow.setdefault((k, node), {})
                    flow[pp], flow[pm] = 1 / e, -e
    rows += [(g, 0.0, 0.0) for g in grid]
    if limits.hard:
        for (k, node), flow in node_flow.items():
            lim = float(limits.node_max_kw[node])
            rows.append((flow, -lim, lim))
    a = np.zeros((len(rows), len(cost)))
    for i, (coef, _, _) in enumerate(rows):
        for j, v in coef.items():
            a[i, j] += v
    rlb = np.array([r[1] for r in rows])
    rub = np.array([r[2] for r in rows])
    eq = rlb == rub
    up = ~eq & np.isfinite(rub)
    down = ~eq & np.isfinite(rlb)
    res = linprog(
        -np.array(cost),
        A_ub=np.vstack([a[up], -a[down]]),
        b_ub=np.concatenate([rub[up], -rlb[down]]),
        A_eq=a[eq],
        b_eq=rlb[eq],
        bounds=list(zip(lo_b, hi_b)),
        method="highs",
    )
    assert res.status == 0, res.message
    return float(-res.fun)
