"""The parked cars planned together: congestion prices for the node limits and the peak charge.

The car plan (`chargax_marl.teachers.car_plan`) plans each car alone on the day's prices, so
every car picks the same cheap steps and a tight node then rescales all of them. This teacher
plans the parked cars jointly, over the next ``W`` steps (the horizon), as the LP::

    max  sum_(i,j) m_ij x_ij  -  pi * P
    s.t. sum_j x_ij <= need_i                        (each car's remaining demand)
         0 <= x_ij <= u_ij                           (its port's and its own power, its stay)
         sum_(i under h) x_ij / e_hi <= C_h * dt     (every node h of the tree, every step j)
         sum_i x_ij / eta_i <= (P0 + P) * dt, P >= 0 (the day's peak draw, P0 so far)

with ``x_ij`` the kWh car ``i`` takes at step ``t + j``, ``m_ij = c - p_(t+j) / eta_i`` its
margin (customer price less the step's buy price over the path efficiency), ``e_hi`` the
efficiency of its path up to and including node ``h`` and ``pi`` the peak-demand charge per
kW (0 on a day without one). The dual prices of the node rows are the congestion prices
(EUR/kWh, grid side); a car's plan is the best plan for it alone on ``price + the congestion
prices on its path`` (its margin less them), which is how the plan splits over the cars.

It is solved in JAX with a fixed number of iterations of the restarted primal-dual hybrid
gradient (PDHG: Chambolle and Pock 2011, diagonal steps of Pock and Chambolle 2011, restarts
to the average as in PDLP): static shapes, no solver inside the step, jittable and vmappable.
More iterations bring the plan closer to the LP's optimum; the action repairs what is left
(below).

Future cars are not known: the plan holds the parked cars only and is made again every step,
like the car plan. ``future_reserve`` keeps that share of every node's limit in the steps
after the current one for cars that have not arrived, so a parked car does not count on
capacity they will take. Charge-sensitive cars leave when charged and free the port for the
next car: their margin falls by ``charge_sensitive_premium_eur_kwh`` per step of delay, so the
plan charges them as early as the limits allow.

`coupled_plan_action` plays the plan's current step as a rule: each car asks for its planned
power, served earliest departure first within every node's headroom (a grant a node cuts is
rounded down to a level), so no node needs the env's proportional rescale. `coupled_advice`
and `coupled_potential` are the observation feature and the shaping potential
(`chargax_marl.wrappers.CoupledPlanAdviceObservation`, `chargax_marl.wrappers.CoupledPlanShaping`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from chargax_marl.core import clock, physics
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.teachers.car_plan import batched, steps_of
from chargax_marl.teachers.fill import able_kw, serve_in_order
from chargax_marl.teachers.shaping import core_state
from chargax_marl.teachers.storage_value import dp_battery_action, step_buy_prices

COUPLED_HORIZON_STEPS = 96
"""The steps the coupled plan looks ahead (the current one included; fewer at the day's end):
8 hours of 5-minute steps. A stay beyond it is planned within it."""

COUPLED_ITERATIONS = 100
"""PDHG iterations per plan."""

COUPLED_RESTART_EVERY = 50
"""The PDHG iterates restart at their average after this many iterations."""

COUPLED_POWER_FRACTION = 0.8
"""The share of a car's top power (the lower of its port's and its own) the plan counts on in
the steps after the current one: the taper near full and the levels' rounding cut what a car
takes. The current step counts on what the car can take now."""

COUPLED_FUTURE_RESERVE = 0.3
"""The share of every node's limit kept free for future cars in the steps after the current
one."""

CHARGE_SENSITIVE_PREMIUM_EUR_KWH = 0.01
"""What a charge-sensitive car's margin falls per step of delay (EUR/kWh)."""

DELAY_COST_EUR_KWH = 0.001
"""What every car's margin falls per step of delay (EUR/kWh): among steps of (nearly) the same
price the plan charges the earliest, leaving the later capacity to cars that have not
arrived; the LP alone is indifferent and may spread a car thinly over its stay."""


@struct.dataclass
class CoupledPlan:
    """The coupled plan of one state. ``W`` steps from the current one (``steps``).

    Attributes:
        energy_kwh: ``(L, W)`` the kWh each leaf's car takes at each step (0 for batteries,
            empty ports and steps outside its stay).
        node_prices_eur_kwh: ``(H, W)`` each node's congestion price (EUR per grid-side kWh).
        peak_prices_eur_kwh: ``(W,)`` the peak charge's price of each step (EUR per grid-side
            kWh at the connection).
        path_prices_eur_kwh: ``(L, W)`` the congestion prices on each leaf's path, node and
            peak, per kWh into its car.
        margin_eur_kwh: ``(L, W)`` each car's margin ``c - p / eta`` (less the charge-sensitive
            premium).
        cap_kwh: ``(L, W)`` the most each car can take per step in the plan (0 outside its
            stay).
        need_kwh: ``(L,)`` each car's remaining demand (0 where none is planned).
        steps: ``(W,)`` int32 the steps of the columns (``t .. t + W - 1``; past the day's end
            their caps are 0).
    """

    energy_kwh: jnp.ndarray
    node_prices_eur_kwh: jnp.ndarray
    peak_prices_eur_kwh: jnp.ndarray
    path_prices_eur_kwh: jnp.ndarray
    margin_eur_kwh: jnp.ndarray
    cap_kwh: jnp.ndarray
    need_kwh: jnp.ndarray
    steps: jnp.ndarray


CAPPED_SIMPLEX_BISECTIONS = 20
"""Bisection steps of `capped_simplex`."""


def capped_simplex(z, total) -> jnp.ndarray:
    """The nearest point to ``z`` with entries ``>= 0`` that sum to at most ``total``.

    The peak charge's prices: the day's peak costs ``total`` per unit of a step's draw, and a
    price above it at the peak's steps would pay for a peak that costs less. Found by bisection
    on the shift ``theta`` of ``max(z - theta, 0)`` (`CAPPED_SIMPLEX_BISECTIONS` steps).

    Args:
        z: ``(W,)`` the point.
        total: ``()`` the most the entries may sum to (``>= 0``).

    Returns:
        ``(W,)`` the projection.
    """
    clipped = jnp.maximum(z, 0.0)

    def halve(_, bounds):
        low, high = bounds
        mid = 0.5 * (low + high)
        over = jnp.sum(jnp.maximum(z - mid, 0.0)) > total
        return jnp.where(over, mid, low), jnp.where(over, high, mid)

    _, high = jax.lax.fori_loop(
        0, CAPPED_SIMPLEX_BISECTIONS, halve, (jnp.zeros(()), jnp.maximum(jnp.max(z), 0.0))
    )
    return jnp.where(jnp.sum(clipped) > total, jnp.maximum(z - high, 0.0), clipped)


def solve_coupled_lp(
    margin_eur_kwh,
    cap_kwh,
    need_kwh,
    node_factor,
    node_cap_kwh,
    peak_factor,
    peak_cap_kwh,
    peak_eur_kwh,
    iterations: int = COUPLED_ITERATIONS,
    restart_every: int = COUPLED_RESTART_EVERY,
):
    """The LP of the module docstring by restarted PDHG, for arrays.

    Args:
        margin_eur_kwh: ``(L, W)`` each car's margin per kWh at each step.
        cap_kwh: ``(L, W)`` the most each car takes per step (0: not at that step).
        need_kwh: ``(L,)`` each car's remaining demand.
        node_factor: ``(H, L)`` the grid-side kWh a kWh into leaf ``l`` puts through node ``h``
            (``1 / e_hl`` below the node, else 0).
        node_cap_kwh: ``(H, W)`` each node's limit per step, grid side.
        peak_factor: ``(L,)`` the grid-side kWh at the connection per kWh into each leaf.
        peak_cap_kwh: ``()`` the draw per step the day's peak so far already allows (kWh).
        peak_eur_kwh: ``()`` the peak charge per kWh of a step's draw above it (the charge per
            kW over the step in hours; 0: no peak charge).
        iterations: PDHG iterations (a multiple of ``restart_every``; more are rounded down).
        restart_every: iterations between restarts at the average.

    Returns:
        ``(energy_kwh (L, W), node_prices (H, W), peak_prices (W,))``: the plan and the duals
        of the node and peak rows (EUR per grid-side kWh).

    Raises:
        ValueError: ``iterations`` or ``restart_every`` not a positive integer.
    """
    for name, value in (("iterations", iterations), ("restart_every", restart_every)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"field {name!r} must be a positive integer, got {value!r}")
    m = jnp.asarray(margin_eur_kwh, jnp.float32)
    # energies in units of the largest cap, so the primal and dual steps are of one scale
    # (the right-hand sides scaled alike leave the duals as they are)
    scale = jnp.maximum(jnp.max(jnp.asarray(cap_kwh, jnp.float32)), 1e-6)
    u = jnp.asarray(cap_kwh, jnp.float32) / scale
    need = jnp.asarray(need_kwh, jnp.float32) / scale
    nf = jnp.asarray(node_factor, jnp.float32)
    ncap = jnp.asarray(node_cap_kwh, jnp.float32) / scale
    pf = jnp.asarray(peak_factor, jnp.float32)
    pcap = jnp.asarray(peak_cap_kwh, jnp.float32) / scale
    pprice = jnp.asarray(peak_eur_kwh, jnp.float32)
    live = (u > 0).astype(jnp.float32)
    # diagonal steps: 1 / the absolute column sums (primal) and row sums (dual)
    tau = 1.0 / (jnp.sum(nf, axis=0) + pf + 1.0)[:, None]
    sig_node = 1.0 / (nf @ live + 1e-6)
    sig_peak = 1.0 / (pf @ live + 1e-6)
    sig_need = 1.0 / (jnp.sum(live, axis=1) + 1e-6)

    def step(state):
        x, lam, lam_peak, mu = state
        price = nf.T @ lam + pf[:, None] * lam_peak[None, :] + mu[:, None]
        x_new = jnp.clip(x + tau * (m - price), 0.0, u)
        x_bar = 2.0 * x_new - x
        lam = jnp.maximum(lam + sig_node * (nf @ x_bar - ncap), 0.0)
        lam_peak = capped_simplex(lam_peak + sig_peak * (pf @ x_bar - pcap), pprice)
        mu = jnp.maximum(mu + sig_need * (jnp.sum(x_bar, axis=1) - need), 0.0)
        return x_new, lam, lam_peak, mu

    def restart(_, state):
        def inner(_, carry):
            s, total = carry
            s = step(s)
            return s, jax.tree.map(jnp.add, total, s)

        zero = jax.tree.map(jnp.zeros_like, state)
        _, total = jax.lax.fori_loop(0, restart_every, inner, (state, zero))
        return jax.tree.map(lambda a: a / restart_every, total)

    state = (
        jnp.zeros_like(m),
        jnp.zeros_like(ncap),
        jnp.zeros((m.shape[1],), jnp.float32),
        jnp.zeros_like(need),
    )
    x, lam, lam_peak, _ = jax.lax.fori_loop(0, iterations // restart_every, restart, state)
    return x * scale, lam, lam_peak


def _check_settings(power_fraction, horizon_steps, future_reserve, iterations) -> None:
    checks = (
        ("power_fraction", power_fraction, 0.0 < float(power_fraction) <= 1.0, "in (0, 1]"),
        ("future_reserve", future_reserve, 0.0 <= float(future_reserve) < 1.0, "in [0, 1)"),
    )
    for name, value, ok, allowed in checks:
        if not ok:
            raise ValueError(f"field {name!r} must lie {allowed}, got {value!r}")
    for name, value in (("horizon_steps", horizon_steps), ("iterations", iterations)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"field {name!r} must be a positive integer, got {value!r}")


def coupled_plan(
    env_params,
    *,
    power_fraction: float = COUPLED_POWER_FRACTION,
    horizon_steps: int = COUPLED_HORIZON_STEPS,
    future_reserve: float = COUPLED_FUTURE_RESERVE,
    iterations: int = COUPLED_ITERATIONS,
    charge_sensitive_premium_eur_kwh: float = CHARGE_SENSITIVE_PREMIUM_EUR_KWH,
    delay_cost_eur_kwh: float = DELAY_COST_EUR_KWH,
):
    """The parked cars' joint plan and the congestion prices, as a function of a core state.

    Args:
        env_params: concrete `chargax_marl.core.types.EnvParams`.
        power_fraction: the share of a car's top power counted on after the current step.
        horizon_steps: the steps planned (at most the day's; cut to it).
        future_reserve: the share of every node's limit kept for future cars after the
            current step.
        iterations: PDHG iterations (`solve_coupled_lp`; rounded down to a multiple of
            `COUPLED_RESTART_EVERY`, at least one restart's).
        charge_sensitive_premium_eur_kwh: a charge-sensitive car's margin falls by this per
            step of delay.
        delay_cost_eur_kwh: every car's margin falls by this per step of delay.

    Returns:
        ``plan(core) -> CoupledPlan`` for one (unbatched) core state.

    Raises:
        ValueError: a setting out of its range (the message names it).
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(env_params, "chargax_marl.teachers.congestion.coupled_plan")
    _check_settings(power_fraction, horizon_steps, future_reserve, iterations)
    st = env_params.station
    width = min(int(horizon_steps), int(env_params.num_steps))
    restart_every = min(COUPLED_RESTART_EVERY, int(iterations))
    num_steps = int(env_params.num_steps)
    step_h, step_min = float(env_params.step_hours), float(env_params.step_minutes)
    prices = np.asarray(step_buy_prices(env_params), np.float32)
    # pad past the day's end; those steps have no capacity
    prices = jnp.asarray(np.pad(prices, ((0, 0), (0, width)), mode="edge"))
    is_port = np.asarray(st.leaf_kind) != KIND_BATTERY
    depth_of = np.asarray(st.node_depth)
    at_depth = np.asarray(st.node_of_leaf_at_depth)
    eff_at = np.asarray(st.leaf_efficiency_at_depth, np.float64)
    nf = np.zeros((st.num_nodes, st.num_leaves), np.float32)
    for h in range(st.num_nodes):
        below = (at_depth[depth_of[h]] == h) & is_port
        nf[h, below] = 1.0 / eff_at[depth_of[h], below]
    node_factor = jnp.asarray(nf)
    eta = jnp.asarray(st.leaf_path_efficiency, jnp.float32)
    peak_factor = jnp.where(jnp.asarray(is_port), 1.0 / eta, 0.0)
    node_kwh = jnp.asarray(st.node_max_kw, jnp.float32) * step_h
    reserve = jnp.where(jnp.arange(width) == 0, 1.0, 1.0 - float(future_reserve))
    node_cap = node_kwh[:, None] * reserve[None, :]
    is_port = jnp.asarray(is_port)
    leaf_max_kw = jnp.asarray(st.leaf_max_kw, jnp.float32)
    customer = jnp.asarray(env_params.customer_price_eur_kwh, jnp.float32)
    peak_eur_kwh = jnp.asarray(env_params.peak_demand_eur_kw, jnp.float32) / step_h
    premium = float(charge_sensitive_premium_eur_kwh)
    delay_cost = float(delay_cost_eur_kwh)
    cols = jnp.arange(width)

    def plan(core):
        t = core.timestep
        steps = t + cols
        planned = core.occupied & is_port
        need = jnp.where(planned, jnp.maximum(core.energy_remaining_kwh, 0.0), 0.0)
        stay = jnp.where(core.charge_sensitive, width, steps_of(core.time_remaining_min, step_min))
        in_stay = (cols[None, :] < stay[:, None]) & (steps[None, :] < num_steps)
        top_kw = jnp.minimum(leaf_max_kw, core.max_rate_kw)
        now_kw = jnp.minimum(
            leaf_max_kw, physics.rate_curve_kw(core.soc, core.max_rate_kw, core.tau)
        )
        per_step = jnp.where(cols[None, :] == 0, now_kw[:, None], power_fraction * top_kw[:, None])
        cap = jnp.where(in_stay & planned[:, None], per_step * step_h, 0.0)
        buy = jax.lax.dynamic_slice(prices[core.day], (t,), (width,))
        per_step_cost = delay_cost + jnp.where(core.charge_sensitive, premium, 0.0)
        delay = per_step_cost[:, None] * cols[None, :]
        margin = customer - buy[None, :] / eta[:, None] - delay
        peak_cap = core.totals.peak_grid_kw * step_h
        x, lam, lam_peak = solve_coupled_lp(
            margin,
            cap,
            need,
            node_factor,
            node_cap,
            peak_factor,
            peak_cap,
            peak_eur_kwh,
            iterations=int(iterations),
            restart_every=restart_every,
        )
        path = node_factor.T @ lam + peak_factor[:, None] * lam_peak[None, :]
        return CoupledPlan(
            energy_kwh=x,
            node_prices_eur_kwh=lam,
            peak_prices_eur_kwh=lam_peak,
            path_prices_eur_kwh=path,
            margin_eur_kwh=margin,
            cap_kwh=cap,
            need_kwh=need,
            steps=steps.astype(jnp.int32),
        )

    return plan


# --------------------------------------------------------------------------- the plan as a rule


def fill_planned_power(priority, want_kw, able_kw, headroom_kw, station, num_levels: int):
    """Serve the leaves in ``priority`` order (lower first), each the lowest level that gives its
    wanted power, within what it can take and the headroom left on every node of its path; a grant a
    node cuts is rounded down to a level.

    Args:
        priority: ``(L,)`` the order of service; ``inf``: served nothing.
        want_kw: ``(L,)`` the power each leaf asks for (kW).
        able_kw: ``(L,)`` the most each leaf can take now (its car's curve and room, kW).
        headroom_kw: ``(H,)`` grid-side kW each node may still pass.
        station: the compiled station.
        num_levels: levels per direction.

    Returns:
        ``(levels (L,) int32 in [0, num_levels], headroom_kw (H,))``: the levels and the
        headroom they leave.
    """
    leaf_max_kw = station.leaf_max_kw

    def grant(leaf, free):
        want = jnp.where(jnp.isfinite(priority[leaf]), jnp.minimum(want_kw[leaf], able_kw[leaf]), 0)
        level = jnp.ceil(want / leaf_max_kw[leaf] * num_levels - 1e-6)
        drawn = jnp.minimum(level / num_levels * leaf_max_kw[leaf], able_kw[leaf])
        cut = drawn > free
        level = jnp.where(
            cut, jnp.floor(jnp.maximum(free, 0.0) / leaf_max_kw[leaf] * num_levels + 1e-6), level
        )
        drawn = jnp.minimum(level / num_levels * leaf_max_kw[leaf], able_kw[leaf])
        return jnp.clip(level, 0, num_levels).astype(jnp.int32), drawn

    return serve_in_order(priority, jnp.asarray(headroom_kw, jnp.float32), station, grant)


def coupled_plan_action(
    env_params,
    battery: str = "dp",
    top_up: bool = False,
    **plan_kwargs,
):
    """The coupled plan played as a rule.

    Each car asks for the power its plan takes this step (`coupled_plan`); the cars are
    served earliest planned departure first, each at the level nearest that power within what
    every node on its path has left (a node-cut grant rounded down), so no node is asked for
    more than its limit. With ``top_up`` the headroom left is then given, in the same order, to
    the cars that still want energy at a positive margin now. The batteries follow the
    battery-only programme (``battery="dp"``, on a station with a battery): a discharge adds
    its grid-side power to the headroom of the nodes above it before the cars are served; a
    charge takes only the headroom the cars leave. Otherwise they idle.

    Args:
        env_params: concrete `chargax_marl.core.types.EnvParams`.
        battery: ``"dp"`` or ``"idle"``.
        top_up: give the headroom the plan leaves to the cars that still want energy.
        **plan_kwargs: settings of `coupled_plan`.

    Returns:
        ``act(state, key, params) -> levels`` (the `chargax_marl.policies` signature):
        ``(L,)`` int32 levels in ``[-num_levels, num_levels]``.

    Raises:
        ValueError: ``battery`` not ``"dp"`` or ``"idle"``, or a plan setting out of range.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(env_params, "chargax_marl.teachers.congestion.coupled_plan_action")
    if battery not in ("dp", "idle"):
        raise ValueError(f"field 'battery' must be 'dp' or 'idle', got {battery!r}")
    plan_of = coupled_plan(env_params, **plan_kwargs)
    st = env_params.station
    is_battery_np = np.asarray(st.leaf_kind) == KIND_BATTERY
    use_dp = battery == "dp" and bool(is_battery_np.any())
    dp = dp_battery_action(env_params) if use_dp else None
    is_battery = jnp.asarray(is_battery_np)
    step_h = float(env_params.step_hours)

    def act(state, key, params):
        del key
        levels_n = params.num_levels
        plan = plan_of(state)
        able = able_kw(state, params)
        want = plan.energy_kwh[:, 0] / step_h
        bat = jnp.zeros((), jnp.int32) if dp is None else dp(state)[0]
        bat_levels = jnp.where(is_battery, bat * levels_n, 0).astype(jnp.int32)
        # a discharging battery's grid-side flow frees headroom above it
        bat_kw = physics.requested_current(bat_levels, state, params) * st.leaf_voltage_v / 1000.0
        bat_out = jnp.minimum(bat_kw, 0.0)
        flows = physics.grid_side_kw(bat_out, st)
        taken = (
            jnp.zeros_like(st.node_max_kw)
            .at[jnp.maximum(st.node_of_leaf_at_depth, 0)]
            .add(jnp.where(st.node_of_leaf_at_depth >= 0, flows, 0.0))
        )
        headroom = st.node_max_kw - taken
        served = state.occupied & ~is_battery & (want > 0)
        priority = jnp.where(served, state.time_remaining_min, jnp.inf)
        levels, headroom = fill_planned_power(priority, want, able, headroom, st, levels_n)
        if top_up:
            positive = plan.margin_eur_kwh[:, 0] > 0
            more = state.occupied & ~is_battery & positive
            drawn = jnp.minimum(levels / levels_n * st.leaf_max_kw, able)
            extra, headroom = fill_planned_power(
                jnp.where(more, state.time_remaining_min, jnp.inf),
                st.leaf_max_kw,
                jnp.maximum(able - drawn, 0.0),
                headroom,
                st,
                levels_n,
            )
            levels = jnp.minimum(levels + extra, levels_n)
        # a charging battery takes what the cars leave
        free = jnp.min(
            jnp.where(
                st.node_of_leaf_at_depth >= 0,
                headroom[jnp.maximum(st.node_of_leaf_at_depth, 0)] * st.leaf_efficiency_at_depth,
                jnp.inf,
            ),
            axis=0,
        )
        charge_levels = jnp.floor(jnp.maximum(free, 0.0) / st.leaf_max_kw * levels_n + 1e-6)
        bat_final = jnp.where(bat_levels > 0, jnp.minimum(bat_levels, charge_levels), bat_levels)
        return jnp.where(is_battery, bat_final, levels).astype(jnp.int32)

    return act


# --------------------------------------------------------------------------- advice and shaping


COUPLED_ADVICE_WIDTH = 2
"""Columns of `coupled_advice` per leaf."""


def coupled_advice(env_params, **plan_kwargs):
    """Each port's coupled plan now: the observation feature of
    `chargax_marl.wrappers.CoupledPlanAdviceObservation`.

    Args:
        env_params: concrete `chargax_marl.core.types.EnvParams`.
        **plan_kwargs: settings of `coupled_plan`.

    Returns:
        ``advice(core) -> (L, 2)`` float32 for one (unbatched) core state: column 0 the share
        of the port's top power its car's plan takes now (in [0, 1]); column 1 the congestion
        price on its path now (EUR per kWh into the car, node and peak, in [0, c] with ``c``
        the customer price). 0 for empty ports and batteries.

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(env_params, "chargax_marl.teachers.congestion.coupled_advice")
    plan_of = coupled_plan(env_params, **plan_kwargs)
    st = env_params.station
    leaf_kwh = jnp.asarray(st.leaf_max_kw, jnp.float32) * float(env_params.step_hours)
    is_port = jnp.asarray(np.asarray(st.leaf_kind) != KIND_BATTERY)
    customer = jnp.asarray(env_params.customer_price_eur_kwh, jnp.float32)

    def advice(core):
        plan = plan_of(core)
        share = jnp.clip(plan.energy_kwh[:, 0] / leaf_kwh, 0.0, 1.0)
        price = jnp.clip(plan.path_prices_eur_kwh[:, 0], 0.0, customer)
        live = core.occupied & is_port
        return jnp.where(live[:, None], jnp.stack([share, price], axis=1), 0.0)

    return advice


def knapsack_value(adjusted_eur_kwh, cap_kwh, need_kwh) -> jnp.ndarray:
    """Each car's best value alone at fixed prices: its steps by adjusted margin, best first,
    each filled to its cap while the margin is positive, until its demand is met.

    Args:
        adjusted_eur_kwh: ``(L, W)`` margins less the congestion prices.
        cap_kwh: ``(L, W)`` the most per step (0: not available).
        need_kwh: ``(L,)`` the demand.

    Returns:
        ``(L,)`` values (EUR).
    """
    order = jnp.argsort(-adjusted_eur_kwh, axis=1)
    a = jnp.take_along_axis(adjusted_eur_kwh, order, axis=1)
    u = jnp.take_along_axis(cap_kwh, order, axis=1)
    u = jnp.where(a > 0, u, 0.0)
    before = jnp.cumsum(u, axis=1) - u
    take = jnp.clip(jnp.maximum(need_kwh, 0.0)[:, None] - before, 0.0, u)
    return jnp.sum(a * take, axis=1)


def coupled_potential(env_params, **plan_kwargs):
    """Each car's value at the coupled plan's prices, as a potential per car, with the
    congestion price of what it takes now.

    A car's value is its best plan alone on its margins less the congestion prices on its path
    (`knapsack_value`; by LP duality the station's plan value splits into these and the
    capacity's worth). Its term over a step is its value after the step (one step less, its
    demand less what it took) minus before, both at the prices of the state before the step,
    minus those prices times what it took now. With the prices of the LP's optimum these
    terms keep its optimal plans optimal; as the prices move from step to step, a day's terms
    add up to minus the first values only approximately.

    Args:
        env_params: concrete `chargax_marl.core.types.EnvParams`.
        **plan_kwargs: settings of `coupled_plan`.

    Returns:
        ``potential(env_state) -> shift``, where ``shift(leaf_energy_kwh)`` is each leaf's
        term (EUR, ``(..., L)``; 0 for batteries and empty ports) for the (possibly wrapped
        and batched) ``env_state`` taken before the step.

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(env_params, "chargax_marl.teachers.congestion.coupled_potential")
    plan_of = coupled_plan(env_params, **plan_kwargs)
    is_port = jnp.asarray(np.asarray(env_params.station.leaf_kind) != KIND_BATTERY)

    def one(core, leaf_energy_kwh):
        plan = plan_of(core)
        adjusted = plan.margin_eur_kwh - plan.path_prices_eur_kwh
        before = knapsack_value(adjusted, plan.cap_kwh, plan.need_kwh)
        later = plan.cap_kwh.at[:, 0].set(0.0)
        taken = jnp.maximum(leaf_energy_kwh, 0.0)
        after = knapsack_value(adjusted, later, plan.need_kwh - taken)
        term = after - before - plan.path_prices_eur_kwh[:, 0] * taken
        return jnp.where(core.occupied & is_port, term, 0.0)

    def potential(env_state):
        core = core_state(env_state)
        return lambda leaf_energy_kwh: batched(one, core)(core, leaf_energy_kwh)

    return potential
