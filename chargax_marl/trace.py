"""Exogenous day traces: everything about a day that no policy can change, to replay it exactly.

A day of the simulator is driven by two things: the policy's actions and the exogenous
inputs (the day's prices, the batteries' initial SoC and, per step, the cars that ask to
park). The cars of a step are drawn from the step's key without looking at the station
(`chargax_marl.core.traffic.draw_arrivals`), so for a given day and key they are the
same whatever the policy does; only which of them find a free port depends on it.

`make_traces` records those inputs as a `DayTrace` per day, with the same key
derivation as `chargax_marl.evaluation.run_days`; `replay` runs a policy on a
trace and gives, bit for bit, the day that ``run_days`` gives with the same key. The optimal
baselines (`chargax_marl.optimal`) read their cars and prices from traces.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from chargax_marl.core import clock, rng, simulator, traffic
from chargax_marl.core import reward as reward_lib
from chargax_marl.core.types import EnvParams, EnvState

Act = Callable[[EnvState, jax.Array], jnp.ndarray]


def day_keys(day_key: jax.Array, num_steps: int):
    """The keys of one evaluated day.

    Args:
        day_key: the day's key.
        num_steps: the steps of the day.

    Returns:
        ``(act_keys, step_keys, battery_key)``: ``act_keys[t]`` goes to the policy and
        ``step_keys[t]`` to the simulator's step ``t`` (it draws the step's cars), one key
        per step each; ``battery_key`` draws the batteries' initial SoC, apart from the
        cars so that they stay the same whatever the battery setting.
    """
    pairs = jax.vmap(jax.random.split)(jax.random.split(day_key, num_steps))
    return pairs[:, 0], pairs[:, 1], jax.random.fold_in(day_key, 1)


def station_fingerprint(params: EnvParams) -> str:
    """A short hash of the station's layout and limits (host side): traces made for one
    station are refused by another.

    Args:
        params: concrete environment parameters.

    Returns:
        16 hex digits.
    """
    st = params.station
    h = hashlib.sha1()
    for a in (
        st.leaf_kind,
        st.leaf_voltage_v,
        st.leaf_max_current_a,
        st.leaf_max_discharge_current_a,
        st.node_max_kw,
        st.node_of_leaf_at_depth,
        st.leaf_efficiency_at_depth,
        st.battery_capacity_kwh,
    ):
        h.update(np.asarray(a).tobytes())
    return h.hexdigest()[:16]


def params_fingerprint(params: EnvParams) -> str:
    """A short hash of every array and setting of ``params`` (host side) and of the random
    stream's version (`chargax_marl.core.rng.STREAM_VERSION`), to tell whether stored
    results were computed for the same scenario and cars.

    Args:
        params: concrete environment parameters.

    Returns:
        16 hex digits.

    Raises:
        RuntimeError: the params' tree has a layout the fingerprint does not know (a guard
            for changes of `EnvParams`).
    """
    h = hashlib.sha1()
    h.update(f"stream {rng.STREAM_VERSION}".encode())
    leaves, treedef = jax.tree_util.tree_flatten(params)
    structure = _treedef_text(treedef, params)
    dropped = _neutral_later_fields(params)
    collapse_tables = bool(dropped)
    if not params.fixed_departures:
        # the session model v3's fields, read only with fixed departures
        dropped += ("dc_share", "dc_margin_min")
    if float(np.asarray(params.stay_demand_corr)) == 0.0:
        # the copula came after the session model v2's first results: at 0 it changes nothing
        dropped += ("stay_demand_corr",)
    if dropped:
        # Fields added to EnvParams after results were first stored, at values that change
        # nothing, are left out (and tables that are the same for every arrival hour count
        # as one row), so params of an unchanged model keep the fingerprint of their stored
        # results.
        leaves = []
        for f in dataclasses.fields(params):
            if not f.metadata.get("pytree_node", True) or f.name in dropped:
                continue
            value = getattr(params, f.name)
            if collapse_tables and f.name in _HOURLY_TABLES and _same_rows(value):
                value = np.asarray(value)[0]
            leaves.extend(jax.tree_util.tree_leaves(value))
        start = structure.index("]), ") + len("]), ")  # after the station's node
        removed = "*, " * len(dropped)
        if structure[start : start + len(removed)] != removed:  # pragma: no cover - layout guard
            raise RuntimeError("params_fingerprint: unexpected EnvParams tree layout")
        structure = structure[:start] + structure[start + len(removed) :]
    h.update(structure.encode())
    for a in leaves:
        h.update(np.asarray(a).tobytes())
    return h.hexdigest()[:16]


_HOURLY_TABLES = ("stay_quantiles_min", "demand_quantiles_kwh")


def _same_rows(table) -> bool:
    arr = np.asarray(table)
    return arr.ndim == 2 and bool((arr == arr[:1]).all())


def is_paper_session_model(params: EnvParams) -> bool:
    """Whether ``params`` run the Chargax paper's session mechanics: every field of the
    session model v2 at the value that reproduces them (`make_params(session_model="paper")`
    gives such params; so does a v2 profile whose session fields are all neutral).

    Args:
        params: the environment parameters.

    Returns:
        True on the paper's mechanics.
    """
    return bool(_neutral_later_fields(params))


def _neutral_later_fields(params: EnvParams) -> tuple[str, ...]:
    """The `EnvParams` fields added with the session model v2 when every one of them is at
    the value that reproduces the earlier model (no holidays, weekday factors and requests of
    one, no day-to-day volume draw, the DC users' type that of the AC users, tables the same
    for every arrival hour); otherwise none."""
    neutral = (
        not np.asarray(params.holiday).any()
        and (np.asarray(params.weekday_volume_factors) == 1.0).all()
        and float(np.asarray(params.daily_volume_cv)) == 0.0
        and (np.asarray(params.request_ratio_quantiles) == 1.0).all()
        and float(np.asarray(params.dc_charge_sensitive_prob))
        == float(np.asarray(params.charge_sensitive_prob))
        and not bool(np.asarray(params.random_port_choice))
        and all(_same_rows(getattr(params, f)) for f in _HOURLY_TABLES)
    )
    if not neutral:
        return ()
    return (
        "holiday",
        "weekday_volume_factors",
        "daily_volume_cv",
        "request_ratio_quantiles",
        "dc_charge_sensitive_prob",
        "random_port_choice",
    )


def _treedef_text(treedef, params: EnvParams) -> str:
    """The text of ``params``' tree structure (its static settings included) that
    `params_fingerprint` hashes. ``episode_start_hour``, ``fixed_departures`` and
    ``episode_days`` came after the stored fingerprints: trailing ones at a start hour of 0,
    no fixed departures and one-day episodes are left out of the text, so that the fingerprints of the params before them, the references'
    among them, stay what they were."""
    text = str(treedef)
    fields = [f for f in dataclasses.fields(params) if not f.metadata.get("pytree_node", True)]
    static = tuple(getattr(params, f.name) for f in fields)
    kept = len(static)
    while kept and _LATER_STATIC.get(fields[kept - 1].name, _NONE) == static[kept - 1]:
        kept -= 1  # a later static field at the value that changes nothing
    if kept < len(static):
        text = text.replace(f"EnvParams[{static!r}]", f"EnvParams[{static[:kept]!r}]", 1)
    return text


_NONE = object()
_LATER_STATIC = {"episode_start_hour": 0, "fixed_departures": False, "episode_days": 1}
"""The static `EnvParams` fields added after the first stored fingerprints (at the end of the
class, in this order), at the value that computes what the params did before them."""


@struct.dataclass
class DayTrace:
    """The exogenous inputs of one day (or, with a leading axis, of several days).

    Attributes:
        day: ``()`` int32, the day's index into the price data (the day the episode
            starts on).
        arrivals: one `chargax_marl.core.traffic.Arrivals` per step (fields with a leading
            ``(num_steps,)`` axis): arrival step = index, and per slot the car model,
            capacity, r-bar for AC and DC ports, tau, arrival SoC, target SoC, planned stay
            and user type.
        battery_soc0: ``(B,)`` the initial SoC of each station battery.
        price_buy_eur_kwh: ``(num_steps,)`` what the station pays per kWh of net draw
            (EUR/kWh).
        price_sell_grid_eur_kwh: ``(num_steps,)`` what it earns per kWh of net feed-in
            (EUR/kWh).
        battery_value_eur_kwh: ``()`` the price of the batteries' net energy change at the
            day's end (EUR/kWh).
        step_minutes: the step length (minutes) of the params the trace was made for.
        num_steps: the steps of the day.
        station: `station_fingerprint` of the params' station.
        episode_start_hour: the hour the episode starts at (`chargax_marl.core.clock`) in
            the params the trace was made for.
    """

    day: jnp.ndarray
    arrivals: traffic.Arrivals
    battery_soc0: jnp.ndarray
    price_buy_eur_kwh: jnp.ndarray
    price_sell_grid_eur_kwh: jnp.ndarray
    battery_value_eur_kwh: jnp.ndarray
    step_minutes: float = struct.field(pytree_node=False, default=5.0)
    num_steps: int = struct.field(pytree_node=False, default=288)
    station: str = struct.field(pytree_node=False, default="")
    episode_start_hour: int = struct.field(pytree_node=False, default=0)


def _make_trace(params: EnvParams, day, day_key) -> DayTrace:
    _, step_keys, battery_key = day_keys(day_key, params.num_steps)
    day = jnp.asarray(day, jnp.int32)
    steps = jnp.arange(params.num_steps, dtype=jnp.int32)
    volume = traffic.day_volume(day, params, battery_key)
    arrivals = jax.vmap(
        lambda k, t: traffic.draw_arrivals(k, t, clock.is_workday(day, t, params), params, volume)
    )(step_keys, steps)
    buy, sell = jax.vmap(lambda t: reward_lib.grid_prices(day, t, params))(steps)
    nb = params.station.num_batteries
    return DayTrace(
        day=day,
        arrivals=arrivals,
        battery_soc0=simulator.battery_initial_soc(params, battery_key)
        if nb
        else jnp.zeros((0,), jnp.float32),
        price_buy_eur_kwh=buy,
        price_sell_grid_eur_kwh=sell,
        battery_value_eur_kwh=reward_lib.battery_terminal_value_eur(jnp.float32(1.0), day, params),
        step_minutes=params.step_minutes,
        num_steps=params.num_steps,
        episode_start_hour=params.episode_start_hour,
    )


_traces_of_days = jax.jit(jax.vmap(_make_trace, in_axes=(None, 0, 0)))
"""`_make_trace` for each day, compiled once per station shape and number of days, with the
params an argument: a call with other prices, traffic or fees reuses it instead of tracing
anew."""


def make_traces(
    params: EnvParams, days, key: jax.Array | None = None, *, day_keys: jax.Array | None = None
) -> DayTrace:
    """The traces of ``days`` (a leading axis over days) for the cars that
    `chargax_marl.evaluation.run_days` draws with the same ``key`` (default
    ``PRNGKey(0)``, the evaluation default).

    Args:
        params: the environment parameters.
        days: day indices of the price data.
        key: the evaluation key; day ``i`` gets ``split(key, len(days))[i]``.
        day_keys: ``(len(days), 2)`` keys, one per day, in place of ``key``'s split (the
            cars `chargax_marl.evaluation.run_days_keyed` draws with them).

    Returns:
        A `DayTrace` with a leading axis over days.

    Raises:
        ValueError: with ``episode_start_hour > 0``, a day of ``days`` is the data's last
            (`chargax_marl.core.clock.check_days`).
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.trace.make_traces")
    if params.episode_start_hour and not isinstance(days, jax.core.Tracer):
        clock.check_days(
            days, params.num_days, params.episode_start_hour, episode_days=params.episode_days
        )
    days = jnp.atleast_1d(jnp.asarray(days, jnp.int32))
    if day_keys is None:
        key = jax.random.PRNGKey(0) if key is None else key
        day_keys = jax.random.split(key, days.shape[0])
    fingerprint = station_fingerprint(params)
    return _traces_of_days(params, days, day_keys).replace(station=fingerprint)


CAR_DEFAULTS = {
    "capacity_kwh": 60.0,
    "ac_kw": 11.0,
    "dc_kw": 50.0,
    "ac_discharge_kw": 0.0,
    "dc_discharge_kw": 0.0,
    "tau": 0.8,
    "arrival_soc": 0.2,
    "target_soc": 0.8,
    "stay_min": 60.0,
    "charge_sensitive": False,
    "request_ratio": 1.0,
    "wants_dc": False,
    "margin_min": 0.0,
}
"""Defaults of `trace_from_cars` for fields a car leaves out."""


def trace_from_cars(
    params: EnvParams, cars: list[dict], day: int = 0, battery_soc0=None
) -> DayTrace:
    """A hand-made day, for tests and worked examples.

    Args:
        params: the environment parameters.
        cars: one dict per car with ``arrival_step`` (the step at whose end the car arrives;
            it charges from the next step) and any fields of `CAR_DEFAULTS` (the others take
            its defaults); cars of one step fill its slots in list order (at most one per
            port).
        day: the day of the price data whose prices the trace takes.
        battery_soc0: the batteries' initial SoC, ``(B,)`` or a scalar; None: the middle of
            the params' range.

    Returns:
        The one-day `DayTrace`.

    Raises:
        ValueError: a car with an unknown field or an ``arrival_step`` outside the day, or
            more cars in one step than the station has ports.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.trace.trace_from_cars")
    st = params.station
    n, slots = params.num_steps, st.num_ports
    fields = {f: np.zeros((n, slots), np.float32) for f in CAR_DEFAULTS}
    requested = np.zeros(n, np.int32)
    for i, car in enumerate(cars):
        unknown = set(car) - set(CAR_DEFAULTS) - {"arrival_step"}
        if unknown:
            raise ValueError(
                f"car {i}: unknown field(s) {sorted(unknown)}; allowed: arrival_step, {sorted(CAR_DEFAULTS)}"
            )
        t = int(car.get("arrival_step", -1))
        if not 0 <= t < n:
            raise ValueError(
                f"car {i}: field 'arrival_step' must lie in [0, {n - 1}], got {car.get('arrival_step')!r}"
            )
        k = requested[t]
        if k >= slots:
            raise ValueError(
                f"car {i}: more than {slots} cars (the number of ports) arrive in step {t}"
            )
        for f, default in CAR_DEFAULTS.items():
            fields[f][t, k] = car.get(f, default)
        requested[t] += 1
    arrivals = traffic.Arrivals(
        requested=jnp.asarray(requested),
        model=jnp.full((n, slots), -1, jnp.int32),
        **{
            f: jnp.asarray(v, bool if f in ("charge_sensitive", "wants_dc") else jnp.float32)
            for f, v in fields.items()
        },
        charge_sensitive_dc=jnp.asarray(fields["charge_sensitive"], bool),
        port_draw=jnp.zeros((n,), jnp.float32),
    )
    day_arr = jnp.asarray(day, jnp.int32)
    steps = jnp.arange(n, dtype=jnp.int32)
    buy, sell = jax.vmap(lambda t: reward_lib.grid_prices(day_arr, t, params))(steps)
    soc0 = (
        simulator.battery_initial_soc(params)
        if battery_soc0 is None
        else jnp.asarray(battery_soc0, jnp.float32)
    )
    return DayTrace(
        day=day_arr,
        arrivals=arrivals,
        battery_soc0=jnp.atleast_1d(soc0)[: st.num_batteries],
        price_buy_eur_kwh=buy,
        price_sell_grid_eur_kwh=sell,
        battery_value_eur_kwh=reward_lib.battery_terminal_value_eur(
            jnp.float32(1.0), day_arr, params
        ),
        step_minutes=params.step_minutes,
        num_steps=n,
        station=station_fingerprint(params),
        episode_start_hour=params.episode_start_hour,
    )


def day_of(traces: DayTrace, i: int) -> DayTrace:
    """The ``i``-th day of a batch of traces.

    Args:
        traces: traces with a leading axis over days (`make_traces`).
        i: the index along that axis.

    Returns:
        The one-day `DayTrace`.
    """
    return jax.tree_util.tree_map(lambda a: a[i], traces)


def check_trace(trace: DayTrace, params: EnvParams) -> None:
    """Check that ``trace`` was made for ``params``.

    Args:
        trace: a trace (one day or a batch).
        params: the environment parameters (with traced params only the static fields are
            checked).

    Raises:
        ValueError: the trace was made for another station, step length, day length or
            episode start hour.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.trace.check_trace")
    if trace.step_minutes != params.step_minutes:
        raise ValueError(
            f"trace field 'step_minutes' is {trace.step_minutes!r} but params have "
            f"step_minutes={params.step_minutes!r}: make the trace with the same params"
        )
    if trace.num_steps != params.num_steps:
        raise ValueError(
            f"trace field 'num_steps' is {trace.num_steps!r} but params have "
            f"num_steps={params.num_steps!r}: make the trace with the same params"
        )
    if trace.episode_start_hour != params.episode_start_hour:
        raise ValueError(
            f"trace field 'episode_start_hour' is {trace.episode_start_hour!r} but params have "
            f"episode_start_hour={params.episode_start_hour!r}: make the trace with the same "
            "params"
        )
    if isinstance(params.station.leaf_voltage_v, jax.core.Tracer):
        return  # params traced: only the static fields above can be checked
    fingerprint = station_fingerprint(params)
    if trace.station != fingerprint:
        raise ValueError(
            f"trace field 'station' is {trace.station!r} but the params' station is {fingerprint!r}: "
            "the trace was made for another station (ports, limits or efficiencies differ)"
        )
    slots = np.shape(trace.arrivals.model)[-1]
    if slots != params.station.num_ports:
        raise ValueError(
            f"trace has {slots} arrival slots per step but the station has "
            f"{params.station.num_ports} ports"
        )


def replay(act: Act, params: EnvParams, trace: DayTrace, day_key: jax.Array):
    """Run a policy for one day on ``trace``. Jittable.

    Args:
        act: the policy, ``act(state, key) -> levels`` (``(num_leaves,)`` levels).
        params: the environment parameters.
        trace: one day's trace (no leading axis).
        day_key: the day's key; the policy receives the same keys as in
            `chargax_marl.evaluation.run_days` with it, so the result equals that day of
            ``run_days`` bit for bit.

    Returns:
        ``(start_states, infos, final_state)``: the state at the start of every step and the
        step's `chargax_marl.core.types.StepInfo`, each with a leading ``(num_steps,)``
        axis, and the state after the last step.

    Raises:
        ValueError: the trace was not made for ``params`` (`check_trace`).
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.trace.replay")
    check_trace(trace, params)
    act_keys, _, _ = day_keys(day_key, params.num_steps)
    start = simulator.empty_state(trace.day, params)
    if params.station.num_batteries:
        start = start.replace(
            soc=start.soc.at[params.station.num_ports :].set(
                jnp.asarray(trace.battery_soc0, jnp.float32)
            )
        )

    def body(state, xs):
        k_act, arrivals = xs
        new_state, info = simulator.step_with_arrivals(state, act(state, k_act), arrivals, params)
        return new_state, (state, info)

    final, (states, infos) = jax.lax.scan(body, start, (act_keys, trace.arrivals))
    return states, infos, final


def replay_days(act: Act, params: EnvParams, traces: DayTrace, key: jax.Array | None = None):
    """`replay` over a batch of traces (vmapped). Jittable.

    Args:
        act: the policy, ``act(state, key) -> levels``.
        params: the environment parameters.
        traces: traces with a leading axis over days (`make_traces`).
        key: the evaluation key, split into one key per day as
            `chargax_marl.evaluation.run_days` splits it; None: ``PRNGKey(0)``.

    Returns:
        The final `chargax_marl.core.types.EpisodeTotals` (leading axis over days), equal to
        ``run_days(act, params, traces.day, key)``.

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.trace.replay_days")
    key = jax.random.PRNGKey(0) if key is None else key
    num_days = traces.day.shape[0]
    return jax.vmap(lambda t, k: replay(act, params, t, k)[2].totals)(
        traces, jax.random.split(key, num_days)
    )


__all__ = [
    "DayTrace",
    "check_trace",
    "day_keys",
    "day_of",
    "make_traces",
    "params_fingerprint",
    "replay",
    "replay_days",
    "trace_from_cars",
    "station_fingerprint",
]
