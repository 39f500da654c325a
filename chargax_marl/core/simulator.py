"""The transition of the shared station simulator: reset and step as pure functions.

``step(key, state, levels, params)`` runs the four stages of paper Appendix A.2 in order
(apply actions, charge, departures, arrivals), prices the step and updates the episode
totals. `step_auto_reset` adds the start of a fresh day at the end of one, and
`info_dict` flattens the step's report. Both the single-agent and the multi-agent view
call exactly these functions.

Everything here is traceable and takes arrays only: turning host input (numpy, Python
numbers, strings) into arrays is the views' job, at their entry points
(`chargax_marl.core.actions`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from chargax_marl.core import clock, physics, rng, traffic
from chargax_marl.core import reward as reward_lib
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.core.types import PENALTY_TERMS, EnvParams, EnvState, EpisodeTotals, StepInfo


def is_workday(day: jnp.ndarray, params: EnvParams) -> jnp.ndarray:
    """Whether the first step of the episode that starts on ``day`` is on a workday: Monday to
    Friday, counting from the weekday of the data's first day, and not a public holiday. A later
    step's day type is `chargax_marl.core.clock.is_workday`'s (the episode may run past
    midnight).

    Args:
        day: the episode's day (``state.day``, int).
        params: the environment parameters.

    Returns:
        bool, shaped as ``day``.
    """
    return clock.is_workday(day, 0, params)


def battery_initial_soc(params: EnvParams, key: jax.Array | None = None) -> jnp.ndarray:
    """Initial SoC of each station battery ``(B,)``: uniform in ``[battery_soc0_low,
    battery_soc0_high]`` drawn from ``key``; without a key, the middle of the range (the
    fixed value when the range is a single point, as by default).

    Args:
        params: the environment parameters.
        key: the reset key (the draws 1.. of its reset stream, `chargax_marl.core.rng`),
            or ``None``.

    Returns:
        ``(B,)`` SoC in ``[battery_soc0_low, battery_soc0_high]``.
    """
    lo, hi = params.battery_soc0_low, params.battery_soc0_high
    if key is None:
        return 0.5 * (lo + hi)
    return lo + (hi - lo) * rng.uniform(rng.key_seed(key), rng.RESET, (1 + lo.shape[0],))[1:]


@jax.jit
def empty_state(day: jnp.ndarray, params: EnvParams, key: jax.Array | None = None) -> EnvState:
    """A station with no cars at step 0 of the episode that starts on ``day`` (at
    ``params.episode_start_hour``); batteries at their initial SoC.

    Args:
        day: the day's index into the price data (``()`` int).
        params: the environment parameters.
        key: draws the batteries' initial SoC when its range is not a point
            (`battery_initial_soc`) and the day's arrival volume (`traffic.day_volume`);
            None: the middle of the range and the weekday's volume factor.

    Returns:
        The empty `EnvState` at step 0 of ``day``, its totals at zero.
    """
    st = params.station
    num_leaves = st.leaf_kind.shape[0]
    zeros = jnp.zeros((num_leaves,), jnp.float32)
    is_bat = st.leaf_kind == KIND_BATTERY
    nb = st.num_batteries

    def bat(values, default=0.0):
        # Place per-battery values in the battery slots (the last nb leaves).
        padded = jnp.concatenate(
            [jnp.full((num_leaves - nb,), default, jnp.float32), values.astype(jnp.float32)]
        )
        return jnp.where(is_bat, padded, 0.0)

    day = jnp.asarray(day, jnp.int32)
    return EnvState(
        current_a=zeros,
        occupied=is_bat,
        soc=bat(battery_initial_soc(params, key)),
        energy_remaining_kwh=zeros,
        time_remaining_min=zeros,
        slack_min=zeros,
        capacity_kwh=bat(st.battery_capacity_kwh),
        max_rate_kw=jnp.where(is_bat, st.leaf_max_kw, 0.0),
        max_discharge_rate_kw=jnp.where(is_bat, st.leaf_max_kw, 0.0),
        target_soc=jnp.where(is_bat, 1.0, 0.0).astype(jnp.float32),
        tau=bat(st.battery_tau),
        charge_sensitive=jnp.zeros((num_leaves,), bool),
        arrival_soc=zeros,
        request_extra_kwh=zeros,
        day=day,
        timestep=jnp.zeros((), jnp.int32),
        is_workday=is_workday(day, params),
        day_volume=traffic.day_volume(day, params, key),
        totals=EpisodeTotals.zeros(),
    )


@jax.jit
def reset(key: jax.Array, params: EnvParams) -> EnvState:
    """Start an empty station on a uniformly random day of ``params.reset_days`` (exploring
    starts; all days of the price data unless training days were set).

    Args:
        key: draws the day and the batteries' initial SoC.
        params: the environment parameters.

    Returns:
        The `EnvState` at step 0 of the drawn day (`empty_state`).
    """
    # The day and the batteries' SoC are draws 0 and 1.. of the key's reset stream (`rng`).
    n = params.reset_days.shape[0]
    u = rng.uniform(rng.key_seed(key), rng.RESET, (1,))[0]
    day = params.reset_days[jnp.minimum((u * n).astype(jnp.int32), n - 1)]
    return empty_state(day, params, key)


@jax.jit
def step(key: jax.Array, state: EnvState, action: jnp.ndarray, params: EnvParams):
    """One 5-minute (``params.step_minutes``) transition.

    The new state keeps the dtypes of ``state`` (float32, int32, bool) and the report is
    float32, also under ``JAX_ENABLE_X64=1``.

    Args:
        key: draws the step's cars (`traffic.draw_arrivals`), independently of the state;
            `step_with_arrivals` takes them as given (to replay a recorded day).
        state: the state to step.
        action: an array (jax or numpy, possibly traced) with one entry per leaf (ports,
            then batteries), shape ``(num_leaves,)``: a signed level in ``[-L, L]`` for the
            discrete modes or a fraction in ``[-1, 1]`` for ``continuous``. Values outside
            the leaf's range are clipped and NaN or +-inf entries are idle. Host values that
            do not fit int32 / float32 (a numpy ``int64`` beyond ``2**31``) are the caller's
            to clip first (`chargax_marl.core.actions.host_array`, which the views' ``step``
            entry points apply).
        params: the environment parameters.

    Returns:
        ``(new_state, info)``: the state after the step and its `StepInfo`.

    Raises:
        ValueError: ``action`` does not have exactly one entry per leaf.
    """
    workday = clock.is_workday(state.day, state.timestep, params)
    new_state, info = step_with_arrivals(
        state,
        action,
        traffic.draw_arrivals(key, state.timestep, workday, params, state.day_volume),
        params,
    )
    if params.episode_days > 1:
        # each calendar day of a multi-day episode brings its own volume, drawn at midnight
        volume = traffic.next_day_volume(key, state.day, state.timestep, state.day_volume, params)
        new_state = new_state.replace(day_volume=volume.astype(new_state.day_volume.dtype))
    return new_state, info


@jax.jit
def step_with_arrivals(
    state: EnvState, action: jnp.ndarray, arrivals: traffic.Arrivals, params: EnvParams
):
    """`step` with the step's arriving cars given (`traffic.Arrivals`); the rest
    of the transition is deterministic. Returns ``(new_state, StepInfo)``.

    Args:
        state: the state to step.
        action: one entry per leaf (any shape of ``num_leaves`` entries; reshaped to
            ``(num_leaves,)``), as for `step`.
        arrivals: the cars that ask to park in this step.
        params: the environment parameters.

    Returns:
        ``(new_state, info)``: the state after the step (the dtypes of ``state``) and its
        float32 `StepInfo`.

    Raises:
        ValueError: ``action`` does not have exactly one entry per leaf (a static shape check).
    """
    num_leaves = params.station.num_leaves
    if jnp.size(action) != num_leaves:
        raise ValueError(
            f"field 'action' must have one entry per leaf (ports, then batteries): "
            f"shape ({num_leaves},), got shape {jnp.shape(action)}"
        )
    action = jnp.reshape(action, (num_leaves,))
    current, excess_kw, requested_kw = physics.apply_actions(action, state, params)
    charged_state, leaf_energy = physics.charge(current, state, params)
    flows = physics.energy_flows(leaf_energy, params.station)
    departed_state, dep = traffic.depart(charged_state, params)
    arrived_state, arr = traffic.place_arrivals(departed_state, arrivals, params)

    p_buy, p_sell_grid = reward_lib.grid_prices(state.day, state.timestep, params)
    last = state.timestep + 1 >= clock.episode_steps(params)
    battery_day_kwh = state.totals.battery_net_kwh + flows["battery_net_kwh"]
    # priced at the mean buy price of the episode's last day (its 24 hours from the start hour)
    value_day = state.day if params.episode_days == 1 else state.day + params.episode_days - 1
    terminal = jnp.where(
        last, reward_lib.battery_terminal_value_eur(battery_day_kwh, value_day, params), 0.0
    )
    peak_kw, peak_charge = reward_lib.peak_demand_charge(
        flows["grid_net_kwh"], state.totals.peak_grid_kw, last, params
    )
    leaf_wear, wear = reward_lib.battery_wear_eur(leaf_energy, params)
    profit = (
        reward_lib.profit_eur(flows, p_buy, p_sell_grid, params) + terminal - peak_charge - wear
    )
    moer = reward_lib.moer_now(state.day, state.timestep, params)
    demand = reward_lib.grid_demand_now(state.timestep, params)
    terms = reward_lib.penalty_terms(flows, dep, arr, excess_kw, moer, demand)
    r = reward_lib.reward(profit, terms, params)

    t = state.totals
    grid = flows["grid_net_kwh"]
    totals = EpisodeTotals(
        reward=t.reward + r,
        profit_eur=t.profit_eur + profit,
        energy_charged_kwh=t.energy_charged_kwh + flows["charged_kwh"],
        energy_discharged_kwh=t.energy_discharged_kwh + flows["discharged_kwh"],
        energy_delivered_kwh=t.energy_delivered_kwh + flows["delivered_kwh"],
        battery_net_kwh=t.battery_net_kwh + flows["battery_net_kwh"],
        grid_import_kwh=t.grid_import_kwh + jnp.maximum(grid, 0.0),
        grid_export_kwh=t.grid_export_kwh + jnp.maximum(-grid, 0.0),
        losses_kwh=t.losses_kwh + flows["losses_kwh"],
        cars_arrived=t.cars_arrived + arr["arrived"],
        cars_served=t.cars_served + dep["departed"],
        cars_rejected=t.cars_rejected + arr["rejected"],
        missing_kwh=t.missing_kwh + dep["missing_kwh"],
        overtime_min=t.overtime_min + dep["overtime_min"],
        constraint_excess_kw=t.constraint_excess_kw + excess_kw,
        requested_excess_kw=t.requested_excess_kw + requested_kw,
        battery_terminal_value_eur=t.battery_terminal_value_eur + terminal,
        peak_grid_kw=peak_kw,
        peak_demand_charge_eur=t.peak_demand_charge_eur + peak_charge,
        battery_wear_eur=t.battery_wear_eur + wear,
        satisfaction_sum=t.satisfaction_sum + dep["satisfaction_sum"],
        satisfaction_sq_sum=t.satisfaction_sq_sum + dep["satisfaction_sq_sum"],
        satisfaction_shortfall_max=jnp.maximum(
            t.satisfaction_shortfall_max, 1.0 - dep["satisfaction_min"]
        ),
        cars_served_time_sensitive=t.cars_served_time_sensitive + dep["departed_time_sensitive"],
        satisfaction_sum_time_sensitive=t.satisfaction_sum_time_sensitive
        + dep["satisfaction_sum_time_sensitive"],
    )
    new_state = arrived_state.replace(
        timestep=state.timestep + 1,
        is_workday=clock.is_workday(state.day, state.timestep + 1, params),
        totals=totals,
    )
    info = StepInfo(
        reward=r,
        profit_eur=profit,
        penalties=terms,
        energy_charged_kwh=flows["charged_kwh"],
        energy_discharged_kwh=flows["discharged_kwh"],
        energy_delivered_kwh=flows["delivered_kwh"],
        battery_net_kwh=flows["battery_net_kwh"],
        grid_net_kwh=grid,
        losses_kwh=flows["losses_kwh"],
        price_buy_eur_kwh=p_buy,
        price_sell_grid_eur_kwh=p_sell_grid,
        cars_arrived=arr["arrived"],
        cars_departed=dep["departed"],
        cars_rejected=arr["rejected"],
        missing_kwh=dep["missing_kwh"],
        overtime_min=dep["overtime_min"],
        constraint_excess_kw=excess_kw,
        requested_excess_kw=requested_kw,
        battery_terminal_value_eur=terminal,
        peak_demand_charge_eur=peak_charge,
        battery_wear_eur=wear,
        satisfaction_sum=dep["satisfaction_sum"],
        satisfaction_min=dep["satisfaction_min"],
        leaf_energy_kwh=leaf_energy,
        leaf_arrived=arr["leaf_arrived"],
        leaf_reward=reward_lib.leaf_reward_shares(
            flows, dep, terms, moer, terminal, p_buy, p_sell_grid, r, params, peak_charge, leaf_wear
        ),
    )
    return keep_dtypes(new_state, state), as_float32(info)


def keep_dtypes(new, like):
    """``new`` with every leaf cast to the dtype of the matching leaf of ``like``: the state's
    dtypes stay fixed whatever the x64 flag (random draws are float64 / int64 under x64).

    Args:
        new: a pytree.
        like: a pytree of the same structure, whose leaves give the dtypes.

    Returns:
        ``new`` with its leaves as arrays of ``like``'s dtypes.
    """
    return jax.tree.map(lambda x, y: jnp.asarray(x).astype(jnp.asarray(y).dtype), new, like)


def as_float32(tree):
    """Floating leaves of ``tree`` as float32 (no-op without x64).

    Args:
        tree: a pytree.

    Returns:
        ``tree`` with every leaf an array: floating leaves float32, the others unchanged
        in dtype.
    """

    def cast(x):
        x = jnp.asarray(x)
        return x.astype(jnp.float32) if jnp.issubdtype(x.dtype, jnp.floating) else x

    return jax.tree.map(cast, tree)


def is_done(state: EnvState, params: EnvParams) -> jnp.ndarray:
    """The episode is over (truncation; the station never terminates).

    Args:
        state: the station state.
        params: the environment parameters.

    Returns:
        A ``()`` bool: ``state.timestep >= num_steps * episode_days``
        (`chargax_marl.core.clock.episode_steps`).
    """
    return state.timestep >= clock.episode_steps(params)


def step_auto_reset(
    key: jax.Array,
    state: EnvState,
    action: jnp.ndarray,
    params: EnvParams,
    reset_state: EnvState | None = None,
):
    """`step`, then a fresh day where the step ended one: the auto-reset of both views.

    As gymnax's ``Environment.step``: step, reset, and select the reset state where done
    (``lax.select`` per leaf). The key is not split: the step's cars and the reset's day come
    from separate streams of the same key (`chargax_marl.core.rng`).

    Args:
        key: the step's key (also the reset's).
        state: the state to step.
        action: per-leaf levels or fractions, as for `step`.
        params: the environment parameters.
        reset_state: the state to start from at the end of the day; ``None`` draws one with
            `reset`.

    Returns:
        ``(next_state, stepped_state, info, done)``: the state to continue from (the reset
        one where ``done``), the state the step reached, the step's `StepInfo`, and
        whether the step ended the day.
    """
    stepped, info = step(key, state, action, params)
    done = is_done(stepped, params)
    fresh = reset(key, params) if reset_state is None else reset_state
    next_state = jax.tree.map(lambda x, y: jax.lax.select(done, x, y), fresh, stepped)
    return next_state, stepped, info, done


STEP_INFO_KEYS = (
    "reward",
    "profit_eur",
    "energy_charged_kwh",
    "energy_discharged_kwh",
    "energy_delivered_kwh",
    "battery_net_kwh",
    "grid_net_kwh",
    "losses_kwh",
    "price_buy_eur_kwh",
    "price_sell_grid_eur_kwh",
    "cars_arrived",
    "cars_departed",
    "cars_rejected",
    "missing_kwh",
    "overtime_min",
    "constraint_excess_kw",
    "requested_excess_kw",
    "battery_terminal_value_eur",
    "peak_demand_charge_eur",
    "battery_wear_eur",
    "satisfaction_sum",
    "satisfaction_min",
)
"""Scalar fields of `StepInfo` reported in the infos under their own names."""

INFO_KEYS = (
    STEP_INFO_KEYS
    + ("battery_reward_eur",)
    + tuple(f"penalty_{k}" for k in PENALTY_TERMS)
    + tuple(f"episode_{k}" for k in EpisodeTotals.__dataclass_fields__)
)
"""Every scalar key of `info_dict`, in order: the step's report, ``battery_reward_eur``,
``penalty_<term>``, ``episode_<total>``."""

AUTO_RESET_INFO_KEYS = ("terminated", "truncated")
"""The keys both views' auto-resetting ``step`` adds to `info_dict` (gymnax's names). The
single-agent view's also adds ``final_observation``, as gymnax's own base class does; the
multi-agent view's does not, as JaxMARL's does not (its baselines need every info leaf to be
one value per agent)."""


def info_dict(info: StepInfo, state: EnvState, params: EnvParams) -> dict:
    """The step's report as the views' info dict: float32 scalars keyed as `INFO_KEYS`
    and ``leaf_energy_kwh`` ``(L,)``.

    Args:
        info: the report of `step`.
        state: the stepped state, whose running totals become ``episode_<total>``.
        params: the environment parameters.

    Returns:
        A dict with `INFO_KEYS` (``battery_reward_eur`` is the batteries' leaves' share
        of the reward, `chargax_marl.core.reward.leaf_reward_shares`; with the ports'
        it sums to the reward) and ``leaf_energy_kwh``, the energy into each car and battery
        this step (terminal side, negative when discharging).
    """
    is_battery = params.station.leaf_kind == KIND_BATTERY
    out = {k: getattr(info, k) for k in STEP_INFO_KEYS}
    out["battery_reward_eur"] = jnp.sum(jnp.where(is_battery, info.leaf_reward, 0.0))
    out.update({f"penalty_{k}": info.penalties[k] for k in PENALTY_TERMS})
    out.update(
        {f"episode_{k}": getattr(state.totals, k) for k in EpisodeTotals.__dataclass_fields__}
    )
    out = {k: jnp.asarray(out[k], jnp.float32) for k in INFO_KEYS}
    out["leaf_energy_kwh"] = info.leaf_energy_kwh.astype(jnp.float32)
    return out
