"""Rule-based policies, written in the core's per-leaf levels so both views can use them.

A policy is ``policy(state, key, params) -> levels`` with one signed level per leaf (ports,
then batteries) in ``[-L, L]`` (absolute action mode). Rule-based policies read the
simulator state, not the observation. To use one with a view:

- single agent: `for_single` gives ``fn(state, key) -> action`` for
  `chargax_marl.single.Chargax`;
- multi agent: `for_marl` gives ``fn(state, key) -> {agent: action}`` for
  `chargax_marl.marl.ChargaxMARL`.

All policies are jittable and vmappable.

The teachers' rules (``battery_programme``, ``plan_programme``, ``grid_programme``,
``coupled_plan``, `chargax_marl.teachers.rules`) read tables built for one station and price
table, so they are built for given params: ``get_policy("battery_programme", params)``.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from chargax_marl.core import physics
from chargax_marl.core.reward import episode_buy_prices, hour_of_step
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.core.types import EnvParams, EnvState
from chargax_marl.teachers.fill import able_kw, serve_in_order
from chargax_marl.teachers.rules import RULE_BUILDERS

Policy = Callable[[EnvState, jax.Array, EnvParams], jnp.ndarray]


def _is_battery(params: EnvParams) -> jnp.ndarray:
    return params.station.leaf_kind == KIND_BATTERY


def always_max(state: EnvState, key: jax.Array, params: EnvParams) -> jnp.ndarray:
    """The paper's baseline: every port at its highest level, batteries idle.

    The car's rate curve and the node limits then cut the current to what is possible,
    so every car charges as fast as the station allows.

    Args:
        state: the simulator state (one day, unbatched).
        key: unused (the policy is deterministic).
        params: the environment parameters.

    Returns:
        ``(num_leaves,)`` int32 levels in ``[-L, L]``.
    """
    del state, key
    return jnp.where(_is_battery(params), 0, params.num_levels).astype(jnp.int32)


def _day_and_hour(state: EnvState, params: EnvParams) -> tuple[jnp.ndarray, jnp.ndarray]:
    """``(day, hour)``: the day whose 24 hours from the start hour the step is in (the
    episode's day for one-day episodes; ``state.day`` plus the episode's day index,
    `chargax_marl.core.clock.episode_day_index`, for several) and the hour in it (0..23)."""
    hour = hour_of_step(state.timestep, params)
    if params.episode_days == 1:
        return state.day, hour
    return state.day + hour // 24, jnp.mod(hour, 24)


def _day_buy_prices(state: EnvState, params: EnvParams) -> tuple[jnp.ndarray, jnp.ndarray]:
    """``(day (24,), now ())``: the hourly buy prices of the 24 hours of the episode's current
    day (day-ahead, grid fee, time-of-use surcharge; EUR/kWh;
    `chargax_marl.core.reward.episode_buy_prices`) and the current hour's."""
    day, hour = _day_and_hour(state, params)
    day_prices = episode_buy_prices(day, params)
    return day_prices, day_prices[hour]


def _cheap_or_dear_hour(state: EnvState, params: EnvParams, quantile: float):
    """Whether the current hour's buy price (day-ahead plus the time-of-use surcharge) is in the
    cheapest / dearest ``quantile`` of the 24 hours of the episode's current day."""
    day, hour = _day_and_hour(state, params)
    day_prices = episode_buy_prices(day, params, grid_fee=False)
    now = day_prices[hour]
    return now <= jnp.quantile(day_prices, quantile), now >= jnp.quantile(
        day_prices, 1.0 - quantile
    )


def _battery_arbitrage_levels(state: EnvState, params: EnvParams, quantile: float) -> jnp.ndarray:
    """Per-leaf battery levels of the price rule that pays for losses and wear: charge fully in
    an hour of the cheapest ``quantile`` when a kWh bought now and sold back at the mean price
    of the dearest ``quantile`` earns more than its losses and its wear in and out
    (``eta p_dear - p_now / eta > 2 w``, ``eta`` each battery's path efficiency, ``w`` its
    wear per kWh of throughput); discharge fully in an hour of the dearest ``quantile`` when
    ``eta p_now - p_cheap / eta > 2 w`` against the mean price of the cheapest hours; idle
    otherwise (a flat day, a narrow spread)."""
    day_prices, now = _day_buy_prices(state, params)
    lo, hi = jnp.quantile(day_prices, quantile), jnp.quantile(day_prices, 1.0 - quantile)
    cheap_mean = jnp.sum(jnp.where(day_prices <= lo, day_prices, 0.0)) / jnp.sum(day_prices <= lo)
    dear_mean = jnp.sum(jnp.where(day_prices >= hi, day_prices, 0.0)) / jnp.sum(day_prices >= hi)
    st = params.station
    eta = st.leaf_path_efficiency
    wear = jnp.concatenate([jnp.zeros((st.num_ports,)), params.battery_wear_eur_kwh])
    charge = (now <= lo) & (eta * dear_mean - now / eta > 2.0 * wear)
    discharge = (now >= hi) & (eta * now - cheap_mean / eta > 2.0 * wear)
    return jnp.where(charge, params.num_levels, jnp.where(discharge, -params.num_levels, 0))


def battery_rule(
    state: EnvState, key: jax.Array, params: EnvParams, quantile: float = 0.2
) -> jnp.ndarray:
    """Always-max for the ports plus a price rule for the batteries that pays for losses and
    wear: charge fully in the cheapest ``quantile`` of the day's hours and discharge
    fully in the dearest ``quantile``, each only when the round trip against the mean price of
    the other side of the day beats the battery's losses plus its wear in and out; idle
    otherwise. The strong two-line heuristic a learned agent must beat.

    Args:
        state: the simulator state (one day, unbatched).
        key: unused (the policy is deterministic).
        params: the environment parameters.
        quantile: the fraction of the day's hours counted as cheap (and as dear);
            default 0.2.

    Returns:
        ``(num_leaves,)`` int32 levels in ``[-L, L]``.
    """
    del key
    battery = _battery_arbitrage_levels(state, params, quantile)
    return jnp.where(_is_battery(params), battery, params.num_levels).astype(jnp.int32)


def battery_rule_naive(
    state: EnvState, key: jax.Array, params: EnvParams, quantile: float = 0.2
) -> jnp.ndarray:
    """`battery_rule` blind to losses and wear: the batteries charge fully in the
    cheapest ``quantile`` of the day's hours and discharge fully in the dearest, whatever the
    spread (on a flat day they charge).

    Args:
        state: the simulator state (one day, unbatched).
        key: unused (the policy is deterministic).
        params: the environment parameters.
        quantile: the fraction of the day's hours counted as cheap (and as dear);
            default 0.2.

    Returns:
        ``(num_leaves,)`` int32 levels in ``[-L, L]``.
    """
    del key
    cheap, dear = _cheap_or_dear_hour(state, params, quantile)
    battery = jnp.where(cheap, params.num_levels, jnp.where(dear, -params.num_levels, 0))
    return jnp.where(_is_battery(params), battery, params.num_levels).astype(jnp.int32)


def discharge_departing(
    state: EnvState, key: jax.Array, params: EnvParams, steps_before: int = 2
) -> jnp.ndarray:
    """Always-max, except that a time-sensitive car whose planned departure is within the
    next ``steps_before`` steps discharges at full power (where its port and the car may
    discharge); batteries idle.

    It takes back, just before the car leaves, energy the customer has paid for. That earns
    money only when discharged energy is not refunded to the car owner
    (``make_params(refund_discharged_energy=False)``, the original Chargax accounting); with
    the refund (the default) each kWh taken back is repaid at the customer price and sold at
    the grid price, a loss. The simulator never takes a car below its arrival SoC.
    Charge-sensitive cars leave when charged, not at a planned time: they charge at full power.

    Args:
        state: the simulator state (one day, unbatched).
        key: unused (the policy is deterministic).
        params: the environment parameters.
        steps_before: how many steps before its planned departure a car starts discharging;
            default 2.

    Returns:
        ``(num_leaves,)`` int32 levels in ``[-L, L]``.
    """
    del key
    is_battery = _is_battery(params)
    can_discharge = (
        physics.leaf_min_level(params.station, params.num_levels, params.v2g) < 0
    ) & ~is_battery
    departing = (
        state.occupied
        & ~state.charge_sensitive
        & (state.max_discharge_rate_kw > 0)
        & (state.time_remaining_min <= steps_before * params.step_minutes)
    )
    ports = jnp.where(departing & can_discharge, -params.num_levels, params.num_levels)
    return jnp.where(is_battery, 0, ports).astype(jnp.int32)


def random_policy(state: EnvState, key: jax.Array, params: EnvParams) -> jnp.ndarray:
    """Uniform random level per leaf within the leaf's valid range.

    Args:
        state: unused.
        key: draws the levels.
        params: the environment parameters.

    Returns:
        ``(num_leaves,)`` int32 levels, each in ``[min_level, L]`` of its leaf.
    """
    del state
    low = physics.leaf_min_level(params.station, params.num_levels, params.v2g)
    return jax.random.randint(key, low.shape, low, params.num_levels + 1, jnp.int32)


def _levels_for_power(power_kw: jnp.ndarray, params: EnvParams, *, round_up: bool) -> jnp.ndarray:
    """The charging level whose current gives ``power_kw`` at each leaf (clipped to [0, L])."""
    return _level_of(
        power_kw / params.station.leaf_max_kw * params.num_levels, round_up, params.num_levels
    )


def _level_of(frac, round_up, num_levels) -> jnp.ndarray:
    """``frac`` (levels, fractional) rounded up where ``round_up`` (a bool or bool array) else
    down, clipped to [0, ``num_levels``]."""
    return jnp.clip(
        jnp.where(round_up, jnp.ceil(frac - 1e-6), jnp.floor(frac + 1e-6)), 0, num_levels
    ).astype(jnp.int32)


def minimum_power_kw(state: EnvState, params: EnvParams) -> jnp.ndarray:
    """Per leaf, the constant power that delivers the remaining demand one step before the
    planned departure.

    Args:
        state: the simulator state (one day, unbatched).
        params: the environment parameters.

    Returns:
        ``(num_leaves,)`` power (kW), 0 for empty ports, batteries and cars already
        satisfied.
    """
    hours_left = (
        jnp.maximum(state.time_remaining_min - params.step_minutes, params.step_minutes) / 60.0
    )
    need = jnp.maximum(state.energy_remaining_kwh, 0.0) / hours_left
    return jnp.where(state.occupied & ~_is_battery(params), need, 0.0)


def price_threshold(
    state: EnvState, key: jax.Array, params: EnvParams, quantile: float = 0.3
) -> jnp.ndarray:
    """Charge fully while the buy price is in the cheapest ``quantile`` of the day's hours;
    otherwise charge each car at the lowest level that still meets its demand by its
    planned departure. Batteries follow `battery_rule`'s price rule at the same
    ``quantile`` (cycling only where the spread beats losses plus wear).

    Args:
        state: the simulator state (one day, unbatched).
        key: unused (the policy is deterministic).
        params: the environment parameters.
        quantile: the fraction of the day's hours counted as cheap (and as dear);
            default 0.3.

    Returns:
        ``(num_leaves,)`` int32 levels in ``[-L, L]``.
    """
    del key
    cheap, _ = _cheap_or_dear_hour(state, params, quantile)
    lazy = _levels_for_power(minimum_power_kw(state, params), params, round_up=True)
    ports = jnp.where(cheap, params.num_levels, lazy)
    battery = _battery_arbitrage_levels(state, params, quantile)
    return jnp.where(_is_battery(params), battery, ports).astype(jnp.int32)


def fill_in_priority_order(
    priority: jnp.ndarray,
    state: EnvState,
    params: EnvParams,
    headroom_kw: jnp.ndarray | None = None,
    want_kw: jnp.ndarray | None = None,
) -> jnp.ndarray:
    """Give cars power in order of ``priority`` (lower first), each as much as its rate,
    its port and the remaining headroom of every node on its path allow, as a level.

    A grant cut by a node is rounded down to a level, so the station never needs a rescale; a
    grant the car itself limits is rounded up (the car's curve and target clip the rest), so a
    car close to its target still finishes. Each car takes from its nodes' headroom what it
    will draw at its level, not its unrounded grant: with few levels (``num_levels`` 1) a
    node-bound car rounds to idle, and the power it does not draw stays for the cars after it.

    Args:
        priority: ``(num_leaves,)`` the order of service (lower first); ``inf`` for a leaf
            that gets nothing (an empty port, a battery, a car that is not to charge).
        state: the simulator state (one day, unbatched).
        params: the environment parameters.
        headroom_kw: ``(num_nodes,)`` grid-side kW each node may still pass before the cars
            are served (what other leaves already take is kept from them); None: every node's
            limit (``params.station.node_max_kw``).
        want_kw: ``(num_leaves,)`` kW each leaf would take with the headroom to spare; None:
            what its car can take (`chargax_marl.teachers.fill.able_kw`, 0 for batteries).

    Returns:
        ``(num_leaves,)`` int32 levels in ``[0, L]``, 0 where ``priority`` is ``inf``.
    """
    st = params.station
    want_kw = able_kw(state, params) if want_kw is None else want_kw
    want_kw = jnp.where(jnp.isfinite(priority), want_kw, 0.0)
    headroom = st.node_max_kw if headroom_kw is None else headroom_kw
    levels = params.num_levels

    def grant(leaf, free):
        want = want_kw[leaf]
        kw = jnp.clip(jnp.minimum(want, free), 0.0)
        node_bound = free < want
        level = _level_of(kw / st.leaf_max_kw[leaf] * levels, ~node_bound, levels)
        drawn = jnp.where(node_bound, level / levels * st.leaf_max_kw[leaf], kw)
        return level, drawn

    return serve_in_order(priority, headroom, st, grant)[0]


def earliest_deadline_first(state: EnvState, key: jax.Array, params: EnvParams) -> jnp.ndarray:
    """Serve cars with the earliest planned departure first, each at the most power the node
    limits leave; levels cut by a node are rounded down so the station never needs a rescale.
    Batteries idle.

    Args:
        state: the simulator state (one day, unbatched).
        key: unused (the policy is deterministic).
        params: the environment parameters.

    Returns:
        ``(num_leaves,)`` int32 levels in ``[0, L]``.
    """
    del key
    priority = jnp.where(state.occupied & ~_is_battery(params), state.time_remaining_min, jnp.inf)
    return fill_in_priority_order(priority, state, params)


def least_laxity_first(state: EnvState, key: jax.Array, params: EnvParams) -> jnp.ndarray:
    """Serve cars with the least laxity first (minutes left minus minutes needed at full
    rate), each at the most power the node limits leave. Batteries idle.

    Args:
        state: the simulator state (one day, unbatched).
        key: unused (the policy is deterministic).
        params: the environment parameters.

    Returns:
        ``(num_leaves,)`` int32 levels in ``[0, L]``.
    """
    del key
    rate_kw = jnp.maximum(jnp.minimum(params.station.leaf_max_kw, state.max_rate_kw), 1e-3)
    needed_min = jnp.maximum(state.energy_remaining_kwh, 0.0) / rate_kw * 60.0
    laxity = state.time_remaining_min - needed_min
    priority = jnp.where(state.occupied & ~_is_battery(params), laxity, jnp.inf)
    return fill_in_priority_order(priority, state, params)


POLICIES: dict[str, Policy] = {
    "always_max": always_max,
    "battery_rule": battery_rule,
    "battery_rule_naive": battery_rule_naive,
    "random": random_policy,
    "price_threshold": price_threshold,
    "edf": earliest_deadline_first,
    "llf": least_laxity_first,
    "discharge_departing": discharge_departing,
}


def is_named_rule(policy) -> bool:
    """Whether ``policy`` is one of the functions of `POLICIES` (defined once, so a program
    compiled with it as a static argument can be kept and reused), not a rule built for given
    params or a caller's function.

    Args:
        policy: any policy ``(state, key, params) -> levels``.

    Returns:
        True for a function of `POLICIES` itself.
    """
    return any(policy is rule for rule in POLICIES.values())


TEACHER_RULES = tuple(RULE_BUILDERS)
"""The teachers' rules (`chargax_marl.teachers.rules`): `get_policy` builds them for
given params; each but ``coupled_plan`` needs a station with a battery."""


def get_policy(name: str, params: EnvParams | None = None) -> Policy:
    """The policy of a name.

    Args:
        name: a key of `POLICIES` or one of `TEACHER_RULES`.
        params: concrete params to build a teacher's rule for (ignored by the other rules).

    Returns:
        ``policy(state, key, params) -> levels``.

    Raises:
        KeyError: an unknown name.
        ValueError: a teacher's rule without ``params``, or for a station without a battery.
    """
    if name in RULE_BUILDERS:
        if params is None:
            raise ValueError(
                f"policy {name!r} is built for a station and its prices: "
                f"call get_policy({name!r}, params)"
            )
        return RULE_BUILDERS[name](params)
    if name not in POLICIES:
        allowed = sorted(POLICIES) + sorted(TEACHER_RULES)
        raise KeyError(f"unknown policy {name!r}; allowed: {allowed}")
    return POLICIES[name]


def for_single(policy: Policy | str, env, params: EnvParams | None = None):
    """A rule-based policy as a policy of the single-agent env.

    Args:
        policy: ``policy(state, key, params) -> levels`` or its name (`get_policy`).
        env: the single-agent env (`chargax_marl.single.Chargax`), whose
            ``levels_to_action`` maps the levels to its action space.
        params: the parameters the policy reads; None: ``env.default_params``.

    Returns:
        ``fn(state, key) -> action`` in the action space of ``env``.

    Raises:
        KeyError: an unknown policy name.
        ValueError: a teacher's rule for a station without a battery.
    """
    params = params if params is not None else env.default_params
    policy = get_policy(policy, params) if isinstance(policy, str) else policy
    return lambda state, key: env.levels_to_action(policy(state, key, params), params)


def for_marl(policy: Policy | str, env):
    """A rule-based policy as a policy of the multi-agent env.

    Args:
        policy: ``policy(state, key, params) -> levels`` or its name (`get_policy`).
        env: the multi-agent env (`chargax_marl.marl.ChargaxMARL`); the policy reads its
            ``params``.

    Returns:
        ``fn(state, key) -> {agent: action}`` for ``env``.

    Raises:
        KeyError: an unknown policy name.
        ValueError: a teacher's rule for a station without a battery.
    """
    policy = get_policy(policy, env.params) if isinstance(policy, str) else policy
    return lambda state, key: env.levels_to_actions(policy(state, key, env.params))
