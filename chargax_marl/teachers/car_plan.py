"""The value of each parked car's remaining demand under the day's prices, and the plan as advice.

A port earns ``c - p_t / eta`` per kWh it charges into a car at step ``t``: the customer
price ``c`` minus the step's buy price ``p_t`` (day-ahead + grid fee + time-of-use, as the env
prices it) over the port's path efficiency ``eta``. A time-sensitive car that still wants
``need`` kWh and stays ``k`` more whole steps (cut at the day's end) takes ``q`` kWh per
step in the plan (`PLAN_POWER_FRACTION` of the lower of the port's and the car's top
power, times the step). Ignoring the other cars, the best plan for it charges in the
cheapest steps of its stay first while the margin is positive::

    V = sum_j max(c - p_(j) / eta, 0) * clip(need - q * (j - 1), 0, q)

over the stay's steps sorted by price, ``p_(1) <= p_(2) <= ...``.

As a potential per car (`car_potential`, `chargax_marl.wrappers.CarPlanShaping`)
a port's shaping term is ``V`` after the step (the same car, ``need`` less what it took, one
step less; 0 once it has left) minus ``V`` before it. A car that arrives during the step
enters the potential from the next step on, so over a car's stay the terms add up to ``-V``
at its first step, which no action changes, and a step's own profit plus its term is what
the step lost against the plan: charging in one of the plan's steps scores about 0,
charging at a dearer step than the plan's dearest scores the price difference, idling in a
plan step scores the price difference to the step that must replace it.

Charge-sensitive cars (they leave when charged) have no potential: a port that delays one
keeps the cars behind it out (a rule that timed them like the others lost against
always-max; see the docs' design decisions).

It is a learning signal only; the evaluation scores the env's profit.

The plan advice (`plan_advice`, `chargax_marl.wrappers.PlanAdviceObservation`)
shows each port whether its car's plan charges now: whether a step is in a car's plan turns
on the rank of its price among all the steps of the stay, which a port reading hourly prices
a few hours ahead learns badly. The advice reads the day's whole price list within the stay
and the car's top power, which the observation holds only in part. `plan_action`
plays the plan as a rule.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from chargax_marl.core import clock
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.teachers.shaping import core_state
from chargax_marl.teachers.storage_value import dp_battery_action, step_buy_prices

PLAN_POWER_FRACTION = 0.5
"""The plan counts on this fraction of a car's top power per step (the lower of the port's and
the car's): the taper near full, a port sharing its EVSE and the station's limits cut what a
car takes, and a plan that counts on more tells a port it can wait when it cannot. For the
fractions compared as rules see ``python -m baselines.analysis.plan_rule`` and the docs' design
decisions."""


def price_order(params) -> tuple[np.ndarray, np.ndarray]:
    """Every day's steps sorted by buy price (cheapest first, ties by time).

    Args:
        params: concrete `chargax_marl.core.types.EnvParams`.

    Returns:
        ``(steps, prices)``, each ``(days, T)``: the step indices (int32) in price order and
        their buy prices (float32, EUR/kWh).
    """
    prices = step_buy_prices(params)
    order = np.argsort(prices, axis=1, kind="stable").astype(np.int32)
    return order, np.take_along_axis(prices, order, axis=1).astype(np.float32)


def plan_energy(sorted_steps, t, steps_left, need_kwh, step_kwh) -> jnp.ndarray:
    """The kWh each car's plan charges at each step: ``step_kwh`` at the stay's cheapest steps
    until ``need_kwh`` is met.

    Args:
        sorted_steps: ``(T,)`` one day's row of the steps of `price_order`.
        t: the current step.
        steps_left: ``(L,)`` the steps each car still charges (its stay is steps ``t`` to
            ``t + steps_left - 1``).
        need_kwh: ``(L,)`` each car's remaining demand (kWh).
        step_kwh: ``(L,)`` what the plan charges per step (kWh).

    Returns:
        ``(L, T)`` kWh, column ``j`` for step ``sorted_steps[j]``.
    """
    steps_left, need_kwh, step_kwh = (
        jnp.asarray(x, jnp.float32)[:, None] for x in (steps_left, need_kwh, step_kwh)
    )
    in_stay = (sorted_steps[None, :] >= t) & (sorted_steps[None, :] < t + steps_left)
    rank = prefix_count(in_stay) - 1.0  # 0 for the stay's cheapest step
    return jnp.where(in_stay, jnp.clip(need_kwh - step_kwh * rank, 0.0, step_kwh), 0.0)


PREFIX_BLOCK = 16
"""The block length of `prefix_count`'s two-level sum."""


def prefix_count(mask) -> jnp.ndarray:
    """How many entries of each row of ``mask`` are set up to and including each column.

    ``jnp.cumsum(mask, axis=-1)`` as float32, computed in blocks of `PREFIX_BLOCK` columns:
    each block's running count is a product with a small triangular matrix of ones, and the
    counts of the blocks before it are added. Every count is a whole number far below 2**24,
    so the float32 sums are exact in any order: the same numbers as the cumulative sum,
    which XLA's CPU backend computes as a much slower associative scan.

    Args:
        mask: ``(..., T)`` booleans.

    Returns:
        ``(..., T)`` float32 counts.
    """
    x = jnp.asarray(mask, jnp.float32)
    width = x.shape[-1]
    blocks = -(-width // PREFIX_BLOCK)
    pad = [(0, 0)] * (x.ndim - 1) + [(0, blocks * PREFIX_BLOCK - width)]
    x = jnp.pad(x, pad).reshape(*x.shape[:-1], blocks, PREFIX_BLOCK)
    within = x @ jnp.asarray(np.triu(np.ones((PREFIX_BLOCK, PREFIX_BLOCK), np.float32)))
    before = within[..., -1] @ jnp.asarray(np.triu(np.ones((blocks, blocks), np.float32), 1))
    counts = within + before[..., None]
    return counts.reshape(*counts.shape[:-2], blocks * PREFIX_BLOCK)[..., :width]


def plan_value(
    sorted_steps, sorted_prices, t, steps_left, need_kwh, step_kwh, efficiency, customer_price
):
    """The plan value ``V`` of the module docstring for each car.

    Args:
        sorted_steps: ``(T,)`` one day's row of the steps of `price_order`.
        sorted_prices: ``(T,)`` their buy prices (EUR/kWh).
        t: the current step.
        steps_left: ``(L,)`` the steps each car still charges (``<= 0``: none).
        need_kwh: ``(L,)`` each car's remaining demand (kWh).
        step_kwh: ``(L,)`` what the plan charges per step (kWh).
        efficiency: ``(L,)`` each car's port's path efficiency.
        customer_price: what a delivered kWh sells for (EUR/kWh).

    Returns:
        ``(L,)`` values ``V`` (EUR).
    """
    energy = plan_energy(sorted_steps, t, steps_left, need_kwh, step_kwh)
    margin = jnp.maximum(
        customer_price - sorted_prices[None, :] / jnp.asarray(efficiency)[:, None], 0.0
    )
    return jnp.sum(margin * energy, axis=1)


def steps_of(minutes_left, step_minutes: float) -> jnp.ndarray:
    """The steps a time-sensitive car still charges: it leaves after the step that takes its
    minutes left to 0 or below, so ``ceil(minutes / step)`` (0 when none are left).

    Args:
        minutes_left: the cars' minutes of stay left (any shape).
        step_minutes: the length of a step (minutes).

    Returns:
        The steps left, as floats of ``minutes_left``'s shape (a tolerance of 1e-4 step
        keeps an exact multiple from rounding up).
    """
    return jnp.maximum(jnp.ceil(minutes_left / step_minutes - 1e-4), 0.0)


def batched(fn, core):
    """``fn(core, *per_env_args)`` of one core state, vmapped over the env batch of ``core``
    (none, one or more leading axes of its ``timestep``).

    Args:
        fn: a function of one (unbatched) core state and per-env arguments.
        core: a core state whose ``timestep`` has the batch's leading axes (a scalar for
            one env).

    Returns:
        ``fn`` wrapped in one `jax.vmap` per leading axis of ``core.timestep``.
    """
    for _ in range(jnp.ndim(core.timestep)):
        fn = jax.vmap(fn)
    return fn


def plan_constants(env_params):
    """What the plan reads from the params: every day's steps by price and their prices, the
    port mask, the path efficiencies, the leaves' top power, the step in minutes and hours and
    the customer price.

    Args:
        env_params: concrete `chargax_marl.core.types.EnvParams`.

    Returns:
        ``(order, sorted_prices, is_port, eff, leaf_max_kw, step_minutes, step_hours,
        customer)``: `price_order`'s ``(days, T)`` step indices and buy prices (EUR/kWh),
        ``(L,)`` bool port mask, ``(L,)`` path efficiencies, ``(L,)`` leaf top power (kW),
        the step in minutes and hours (floats) and the customer price (EUR/kWh).

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(env_params, "chargax_marl.teachers.car_plan.plan_constants")
    order_np, sorted_np = price_order(env_params)
    st = env_params.station
    return (
        jnp.asarray(order_np),
        jnp.asarray(sorted_np),
        jnp.asarray(np.asarray(st.leaf_kind) != KIND_BATTERY),
        jnp.asarray(st.leaf_path_efficiency, jnp.float32),
        jnp.asarray(st.leaf_max_kw, jnp.float32),
        float(env_params.step_minutes),
        float(env_params.step_hours),
        jnp.asarray(env_params.customer_price_eur_kwh, jnp.float32),
    )


def car_values(env_params):
    """The plan value ``V`` of each leaf's car, as a function of one core state.

    Args:
        env_params: concrete `chargax_marl.core.types.EnvParams`.

    Returns:
        ``values(core, timestep, minutes_left, need_kwh) -> V (L,)`` (EUR) for one
        (unbatched) core state: each leaf's car valued at step ``timestep`` with
        ``minutes_left`` of its stay and ``need_kwh`` still wanted (``(L,)`` each; 0 for
        batteries, empty ports and charge-sensitive cars).
        ``values(core, core.timestep, core.time_remaining_min, core.energy_remaining_kwh)``
        is the potential of ``core``.

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(env_params, "chargax_marl.teachers.car_plan.car_values")
    order, sorted_prices, is_port, eff, leaf_max_kw, step_min, step_h, customer = plan_constants(
        env_params
    )

    def values(core, timestep, minutes_left, need_kwh):
        planned = core.occupied & is_port & ~core.charge_sensitive
        q = PLAN_POWER_FRACTION * jnp.minimum(leaf_max_kw, core.max_rate_kw) * step_h
        need = jnp.where(planned, jnp.maximum(need_kwh, 0.0), 0.0)
        v = plan_value(
            order[core.day],
            sorted_prices[core.day],
            timestep,
            steps_of(minutes_left, step_min),
            need,
            q,
            eff,
            customer,
        )
        return jnp.where(planned, v, 0.0)

    return values


def car_potential(env_params):
    """Each leaf's change of the car plan value ``V`` over a step, as a potential per car.

    Args:
        env_params: concrete `chargax_marl.core.types.EnvParams`.

    Returns:
        ``potential(env_state) -> shift``, where ``shift(leaf_energy_kwh)`` is each leaf's
        change of ``V`` (EUR) over the step of the (possibly wrapped and batched)
        ``env_state``, taken *before* the step, when the leaves take ``leaf_energy_kwh``
        (shaped like the state's leaves, ``(..., L)``; 0 for batteries, empty ports and
        charge-sensitive cars). The value after the step is computed from the state before
        it, so the env's auto-reset does not hide it.

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(env_params, "chargax_marl.teachers.car_plan.car_potential")
    values = car_values(env_params)
    step_min = float(env_params.step_minutes)

    def one(core, leaf_energy_kwh):
        before = values(core, core.timestep, core.time_remaining_min, core.energy_remaining_kwh)
        after = values(
            core,
            core.timestep + 1,
            core.time_remaining_min - step_min,
            jnp.maximum(core.energy_remaining_kwh, 0.0) - leaf_energy_kwh,
        )
        return after - before

    def potential(env_state):
        core = core_state(env_state)
        return lambda leaf_energy_kwh: batched(one, core)(core, leaf_energy_kwh)

    return potential


# --------------------------------------------------------------------------- the plan as a rule


def plan_advice(env_params, power_fraction: float | None = PLAN_POWER_FRACTION):
    """Whether each port should charge its car now by the plan: the plan advice observation
    feature and the ports of `plan_action`.

    Args:
        env_params: concrete `chargax_marl.core.types.EnvParams`.
        power_fraction: the fraction of the car's top power (the lower of the port's and
            the car's) the plan counts on per step; None: every occupied port charges
            (always-max).

    Returns:
        ``advice(core) -> (L,)`` float32 for one (unbatched) core state: 1 where a port
        should charge its car now (a time-sensitive car whose plan, `plan_energy` at
        ``power_fraction`` of its top power, uses the current step at a positive margin;
        every charge-sensitive car), 0 for idle, empty ports and batteries.

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(env_params, "chargax_marl.teachers.car_plan.plan_advice")
    order, sorted_prices, is_port, eff, leaf_max_kw, step_min, step_h, customer = plan_constants(
        env_params
    )

    def advice(core):
        t = core.timestep
        steps, prices = order[core.day], sorted_prices[core.day]
        q = (power_fraction or 0.0) * jnp.minimum(leaf_max_kw, core.max_rate_kw) * step_h
        energy = plan_energy(
            steps,
            t,
            steps_of(core.time_remaining_min, step_min),
            jnp.maximum(core.energy_remaining_kwh, 0.0),
            q,
        )
        margin_ok = customer - prices[None, :] / eff[:, None] > 0
        now = jnp.any((energy > 0) & margin_ok & (steps[None, :] == t), axis=1)
        charge = now | core.charge_sensitive | (power_fraction is None)
        return (charge & core.occupied & is_port).astype(jnp.float32)

    return advice


def plan_action(
    env_params, battery: str = "dp", power_fraction: float | None = PLAN_POWER_FRACTION
):
    """The car plan played as a rule: a reference for what the port shaping's teacher earns,
    not a trained policy.

    Each port charges its car at full power where `plan_advice` says so and idles
    otherwise.

    Args:
        env_params: concrete `chargax_marl.core.types.EnvParams`.
        battery: ``"dp"``: the batteries follow the battery-only programme's best action
            (`chargax_marl.teachers.storage_value.dp_battery_action`); ``"idle"`` (or any
            other value): they idle.
        power_fraction: as for `plan_advice`; None: the ports charge at full power always
            (always-max).

    Returns:
        ``act(state, key, params) -> levels`` (the `chargax_marl.policies` signature):
        ``(L,)`` int32 levels.

    Raises:
        ValueError: ``battery="dp"`` on a station without a battery.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(env_params, "chargax_marl.teachers.car_plan.plan_action")
    is_battery = jnp.asarray(np.asarray(env_params.station.leaf_kind) == KIND_BATTERY)
    advice = plan_advice(env_params, power_fraction)
    dp = dp_battery_action(env_params) if battery == "dp" else None

    def act(state, key, params):
        del key
        ports = jnp.where(advice(state) > 0.5, params.num_levels, 0)
        bat = 0 if dp is None else dp(state)[0] * params.num_levels
        return jnp.where(is_battery, bat, ports).astype(jnp.int32)

    return act
