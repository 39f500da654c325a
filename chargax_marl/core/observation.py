"""Observation features, shared by the single-agent view and the multi-agent views.

Every feature is scaled to roughly [-1, 1] or [0, 1]: currents by the leaf's rating, rates by
the leaf's max power, energies by ``ENERGY_SCALE_KWH``, minutes by a day, prices by
``PRICE_SCALE_EUR_KWH``.
"""

from __future__ import annotations

import jax.numpy as jnp

from chargax_marl.core import clock, physics
from chargax_marl.core.reward import day_ahead_price, day_price_quantiles, moer_now, tou_fee
from chargax_marl.core.types import EnvParams, EnvState

ENERGY_SCALE_KWH = 100.0
MINUTES_PER_DAY = 1440.0
PRICE_SCALE_EUR_KWH = 0.25
MOER_SCALE_KG_KWH = 1.0

PORT_FEATURES = (
    "occupied",
    "soc",
    "energy_remaining",
    "time_remaining",
    "rate_now",
    "capacity",
    "charge_sensitive",
    "current",
)
BATTERY_FEATURES = ("soc", "current")
PRICE_QUANTILES = (0.0, 0.2, 0.5, 0.8, 1.0)
"""Quantiles of the day's 24 hourly buy-side prices in the context (min, 20 %, median, 80 %, max)."""
EXTRA_CONTEXT = 1 + len(PRICE_QUANTILES) + 1 + 1
"""Context features after the day index: hour left, price quantiles, grid load, peak so far."""


def leaf_features(state: EnvState, params: EnvParams) -> jnp.ndarray:
    """Per-leaf features ``(L, len(PORT_FEATURES))`` in the order of `PORT_FEATURES`.

    Per leaf: occupied (0 / 1), SoC, energy the user still wants over `ENERGY_SCALE_KWH`,
    minutes to the planned departure over a day (clipped to [-1, 1]), the rate curve's limit
    at the SoC over the leaf's max power (0 when empty), capacity over `ENERGY_SCALE_KWH`,
    charge-sensitive (0 / 1), and the current over the leaf's max current (its max
    discharge current when discharging), so in [-1, 1].

    Args:
        state: the current state.
        params: the env parameters.

    Returns:
        ``(num_leaves, len(PORT_FEATURES))`` float32, ports then batteries.
    """
    st = params.station
    rate_kw = physics.rate_curve_kw(state.soc, state.max_rate_kw, state.tau)
    signed_max = jnp.where(
        state.current_a >= 0,
        st.leaf_max_current_a,
        jnp.maximum(st.leaf_max_discharge_current_a, 1e-6),
    )
    # Stacked feature-major, then transposed. Stacked on the last axis, XLA fused every
    # feature's producers (the whole state update of the step) into an interleaving
    # concatenate that it evaluates element by element without SIMD, a large share of a
    # single-agent env step at thousands of envs (docs/performance.md, "Where the time goes").
    features = [
        state.occupied.astype(jnp.float32),
        state.soc,
        state.energy_remaining_kwh / ENERGY_SCALE_KWH,
        jnp.clip(state.time_remaining_min / MINUTES_PER_DAY, -1.0, 1.0),
        jnp.where(state.occupied, rate_kw / st.leaf_max_kw, 0.0),
        state.capacity_kwh / ENERGY_SCALE_KWH,
        state.charge_sensitive.astype(jnp.float32),
        state.current_a / signed_max,
    ]
    return jnp.stack(features, axis=0).T


def root_load(state: EnvState, params: EnvParams) -> jnp.ndarray:
    """The station's net draw at the grid connection from the currents in ``state`` (each
    leaf's ``V * I`` over its path efficiency when charging, times it when feeding in) as a
    fraction of the connection's limit: 1 = the grid connection binds, negative = feed-in.

    Args:
        state: the current state.
        params: the env parameters.

    Returns:
        ``()`` the net draw (kW) over the root node's limit ``node_max_kw[0]`` (kW).
    """
    st = params.station
    return (
        jnp.sum(physics.path_grid_side(state.current_a * st.leaf_voltage_v / 1000.0, st))
        / st.node_max_kw[0]
    )


def context_features(state: EnvState, params: EnvParams) -> jnp.ndarray:
    """Shared context, in order: the buy-side price (day-ahead plus
    the time-of-use surcharge) now and the next H hours, customer price, time of day (sin, cos)
    and the workday flag of the step's clock time and calendar day (`chargax_marl.core.clock`;
    ``state.is_workday``, which `chargax_marl.core.simulator.step` keeps current),
    the day of the data the episode started on, the fraction of the hour left until the price
    changes, the price quantiles of the episode's 24 hours (`PRICE_QUANTILES`), the grid
    connection's load
    (`root_load`), the episode's peak draw so far over the connection's limit, MOER now
    when ``params.observe_moer``, and with ``episode_days > 1`` the day of the week.

    With ``episode_days > 1`` the "day's" parts follow the episode as it runs: ``day`` is the
    calendar day of the step (wrapped around the data), ``price_quantiles`` are those of the
    24 hours of the episode's current day (`chargax_marl.core.clock.episode_day_index`: the
    calendar day with a start hour of 0), and a last part ``weekday`` holds the sine and
    cosine of ``2 pi weekday / 7`` of the step's calendar day (0 = Monday). With one day the
    context is exactly what it always was.

    Prices are divided by `PRICE_SCALE_EUR_KWH`, MOER by `MOER_SCALE_KG_KWH`; the day is
    divided by ``num_days - 1`` (at least 1). `context_parts` names the parts and their
    widths.

    Args:
        state: the current state.
        params: the env parameters.

    Returns:
        ``(context_size(params),)`` float32.
    """
    ahead = jnp.arange(params.price_horizon_hours + 1)  # one gather per table, not one per hour
    prices = day_ahead_price(state.day, state.timestep, params, ahead) + tou_fee(
        state.timestep, params, ahead
    )
    now = clock.steps_since_midnight(state.timestep, params)
    angle = 2.0 * jnp.pi * now / params.num_steps
    minute_of_hour = jnp.mod(now * params.step_minutes, 60.0)
    root_kw = params.station.node_max_kw[0]
    multi_day = params.episode_days > 1
    if multi_day:
        calendar = jnp.mod(clock.calendar_day(state.day, state.timestep, params), params.num_days)
        day_index = calendar
        price_day = state.day + clock.episode_day_index(state.timestep, params)
    else:
        day_index = price_day = state.day
    parts = [
        prices / PRICE_SCALE_EUR_KWH,
        jnp.atleast_1d(params.customer_price_eur_kwh / PRICE_SCALE_EUR_KWH),
        jnp.stack([jnp.sin(angle), jnp.cos(angle)]),
        jnp.atleast_1d(state.is_workday.astype(jnp.float32)),
        jnp.atleast_1d(day_index / jnp.maximum(params.num_days - 1, 1)),
        jnp.atleast_1d((60.0 - minute_of_hour) / 60.0),
        day_price_quantiles(price_day, params) / PRICE_SCALE_EUR_KWH,
        jnp.atleast_1d(root_load(state, params)),
        jnp.atleast_1d(state.totals.peak_grid_kw / root_kw),
    ]
    if params.observe_moer:
        parts.append(
            jnp.atleast_1d(moer_now(state.day, state.timestep, params) / MOER_SCALE_KG_KWH)
        )
    if multi_day:
        week_angle = 2.0 * jnp.pi * clock.weekday(calendar, params) / 7.0
        parts.append(jnp.stack([jnp.sin(week_angle), jnp.cos(week_angle)]))
    return jnp.concatenate(parts).astype(jnp.float32)


def obs_dict(state: EnvState, params: EnvParams) -> dict:
    """Named parts of the single-agent observation: ports, batteries and context.

    ``ports`` is `leaf_features` of the ports, ``(P, len(PORT_FEATURES))``; ``batteries``
    the ``soc`` and ``current`` features of the batteries, ``(B, 2)``
    (`BATTERY_FEATURES`); ``context`` is `context_features`.

    Args:
        state: the current state.
        params: the env parameters.

    Returns:
        ``{"ports": (P, 8), "batteries": (B, 2), "context": (context_size(params),)}``,
        float32 arrays.
    """
    feats = leaf_features(state, params)
    n = params.station.num_ports
    soc_i, cur_i = PORT_FEATURES.index("soc"), PORT_FEATURES.index("current")
    return {
        "ports": feats[:n],
        "batteries": feats[n:][:, jnp.array([soc_i, cur_i])],
        "context": context_features(state, params),
    }


def flat_obs(state: EnvState, params: EnvParams) -> jnp.ndarray:
    """The single-agent observation: ports, then batteries, then context, as one float32 vector.

    The parts of `obs_dict`, each flattened row by row (a port's features together).

    Args:
        state: the current state.
        params: the env parameters.

    Returns:
        ``(obs_size(params),)`` float32.
    """
    parts = obs_dict(state, params)
    return jnp.concatenate(
        [parts["ports"].reshape(-1), parts["batteries"].reshape(-1), parts["context"]]
    )


def context_parts(params: EnvParams) -> tuple[tuple[str, int], ...]:
    """``(name, width)`` of each part of `context_features`, in order.

    Args:
        params: the env parameters (``price_horizon_hours``, ``observe_moer`` and
            ``episode_days`` set widths).

    Returns:
        The parts ``prices`` (``price_horizon_hours + 1``), ``customer_price``,
        ``time_of_day`` (2), ``workday``, ``day``, ``hour_left``, ``price_quantiles``
        (``len(PRICE_QUANTILES)``), ``grid_load``, ``peak_so_far``, ``moer`` (1 when
        ``observe_moer``, else 0) and, only when ``episode_days > 1``, ``weekday`` (2: sine
        and cosine of the step's weekday); the others have width 1.
    """
    weekday = (("weekday", 2),) if params.episode_days > 1 else ()
    return (
        ("prices", int(params.price_horizon_hours) + 1),
        ("customer_price", 1),
        ("time_of_day", 2),
        ("workday", 1),
        ("day", 1),
        ("hour_left", 1),
        ("price_quantiles", len(PRICE_QUANTILES)),
        ("grid_load", 1),
        ("peak_so_far", 1),
        ("moer", int(bool(params.observe_moer))),
    ) + weekday


def context_size(params: EnvParams) -> int:
    """Length of `context_features`.

    Args:
        params: the env parameters.

    Returns:
        The sum of the widths of `context_parts`.
    """
    return sum(width for _, width in context_parts(params))


def context_index(params: EnvParams, name: str) -> int:
    """Where part ``name`` of `context_parts` starts inside the context.

    Args:
        params: the env parameters.
        name: a part's name (see `context_parts`).

    Returns:
        The index of the part's first entry in `context_features`. A part of width 0
        (``moer`` without ``observe_moer``) gets the index where it would start.

    Raises:
        ValueError: ``name`` is not a part of `context_parts`.
    """
    start = 0
    for part, width in context_parts(params):
        if part == name:
            return start
        start += width
    raise ValueError(f"no context part {name!r}; parts are {[p for p, _ in context_parts(params)]}")


def obs_size(params: EnvParams) -> int:
    """Length of the single-agent observation `flat_obs`.

    Args:
        params: the env parameters.

    Returns:
        ``num_ports * len(PORT_FEATURES) + num_batteries * len(BATTERY_FEATURES)`` plus
        `context_size`.
    """
    st = params.station
    context = context_size(params)
    return st.num_ports * len(PORT_FEATURES) + st.num_batteries * len(BATTERY_FEATURES) + context
