"""Build and validate `EnvParams` from named scenarios or custom data.

All validation happens here, at construction, with errors that name the field, the value
and what is allowed; the jitted step never sees a bad value. `make_params` builds
validated params; `validate_params` re-runs the same checks on params made otherwise
(``params.replace(...)``, hand-made `StationArrays`), and both views call it on the
params they are given; `validated_replace` is ``replace`` with the checks.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from chargax_marl.core import (
    calendar_days,
    checks,
    clock,
    data_io,
    datasets,
    fleets,
    prices,
    profiles,
    tariffs,
)
from chargax_marl.core.arrays import device_array
from chargax_marl.core.data_io import NUM_QUANTILES
from chargax_marl.core.observation import PRICE_QUANTILES
from chargax_marl.core.station import (
    KIND_AC,
    KIND_DC,
    Splitter,
    StationArrays,
    battery_calendar_eur_day,
    battery_wear_eur_kwh,
    build_station,
    check_station_arrays,
)
from chargax_marl.core.types import (
    ACTION_MODES,
    CONSTRAINT_MODES,
    PENALTY_TERMS,
    EnvParams,
    PenaltyWeights,
)

MINUTES_PER_DAY = 1440

GRID_FEE_EUR_KWH = 0.04
"""Default surcharge on the day-ahead price when buying: energy tax for EV-charging
installations plus supplier and network energy charges (sources in the data README)."""
FIXED_COST_EUR_PER_STEP = 0.35
"""Default fixed cost per 5-minute step (about 100 EUR/day): the capacity-based network and
connection charges of a ~900 kW grid connection, an estimate (see the data README)."""


def _finite(
    field: str,
    value: Any,
    *,
    minimum: float | None = None,
    strict: bool = False,
    maximum: float | None = None,
    unit: str = "",
) -> float:
    """A finite scalar in range and representable in float32 (`checks.number`)."""
    return checks.number(field, value, low=minimum, high=maximum, low_open=strict, unit=unit)


_SCALARS = {
    "customer_price_eur_kwh": dict(minimum=0.0, maximum=checks.MAX_PRICE_EUR_KWH, unit="EUR/kWh"),
    "grid_fee_eur_kwh": dict(minimum=0.0, maximum=checks.MAX_PRICE_EUR_KWH, unit="EUR/kWh"),
    "feed_in_factor": dict(minimum=0.0, maximum=checks.MAX_FACTOR),
    "fixed_cost_eur": dict(minimum=0.0, maximum=checks.MAX_FIXED_COST_EUR, unit="EUR per step"),
    "battery_value_eur_kwh": dict(minimum=0.0, maximum=checks.MAX_PRICE_EUR_KWH, unit="EUR/kWh"),
    "beta": dict(minimum=0.0, maximum=checks.MAX_WEIGHT),
    "charged_tolerance_kwh": dict(
        minimum=0.0, strict=True, maximum=checks.MAX_TOLERANCE_KWH, unit="kWh"
    ),
}
"""The range of every scalar float field of `EnvParams` (keyword arguments of
`_finite`), for `make_params` and `validate_params` alike."""


def _check_settings(
    action_mode: Any,
    constraint_mode: Any,
    num_levels: Any,
    price_horizon_hours: Any,
    step_minutes: Any,
) -> tuple[float, int]:
    """Check the static settings; return ``(step_minutes, num_steps)``."""
    if action_mode not in ACTION_MODES:
        raise ValueError(f"field 'action_mode' must be one of {ACTION_MODES}, got {action_mode!r}")
    if constraint_mode not in CONSTRAINT_MODES:
        raise ValueError(
            f"field 'constraint_mode' must be one of {CONSTRAINT_MODES}, got {constraint_mode!r}"
        )
    if (
        isinstance(num_levels, (bool, np.bool_))
        or not isinstance(num_levels, (int, np.integer))
        or not 1 <= num_levels <= checks.MAX_NUM_LEVELS
    ):
        raise ValueError(
            f"field 'num_levels' must be an integer in [1, {checks.MAX_NUM_LEVELS}], got {num_levels!r}"
        )
    if not isinstance(price_horizon_hours, (int, np.integer)) or not 0 <= price_horizon_hours <= 48:
        raise ValueError(
            f"field 'price_horizon_hours' must be an integer in [0, 48], got {price_horizon_hours!r}"
        )
    step_minutes = _finite(
        "step_minutes",
        step_minutes,
        minimum=MINUTES_PER_DAY / checks.MAX_STEPS_PER_DAY,
        maximum=MINUTES_PER_DAY,
        unit="min",
    )
    num_steps = MINUTES_PER_DAY / step_minutes
    if abs(num_steps - round(num_steps)) > 1e-9:
        raise ValueError(
            f"field 'step_minutes' must divide a day (1440 min) evenly, got {step_minutes!r}"
        )
    return step_minutes, int(round(num_steps))


def _check_start_hour(episode_start_hour: Any, step_minutes: float) -> int:
    """The hour episodes start at: an integer in ``[0, 23]`` on a step boundary."""
    h = episode_start_hour
    if (
        isinstance(h, (bool, np.bool_))
        or not isinstance(h, (int, np.integer))
        or not 0 <= h < clock.HOURS_PER_DAY
    ):
        raise ValueError(
            f"field 'episode_start_hour' must be an integer hour in [0, 23] (the local hour "
            f"an episode starts at; 0: midnight), got {h!r}"
        )
    steps = int(h) * 60.0 / step_minutes
    if abs(steps - round(steps)) > 1e-9:
        raise ValueError(
            f"field 'episode_start_hour' must fall on a step boundary: {int(h)} h is not a "
            f"whole number of {step_minutes:g}-minute steps; use an hour that is, or 0"
        )
    return int(h)


def _check_episode_days(episode_days: Any) -> int:
    """The days an episode spans: an integer >= 1 (not a bool)."""
    n = episode_days
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(
            f"field 'episode_days' must be an integer >= 1 (the consecutive days an episode "
            f"spans; 1: one day), got {n!r}"
        )
    return int(n)


def _check_reset_days(
    reset_days: Any, days_all: int, episode_start_hour: int = 0, episode_days: int = 1
) -> np.ndarray:
    """The days ``reset`` draws from as int32, each a day an episode can start on
    (`clock.check_days`: all days of the price data whose episode's days all have prices)."""
    days = np.asarray(reset_days)
    if days.ndim != 1 or days.size == 0 or not np.issubdtype(days.dtype, np.integer):
        raise ValueError(
            f"field 'reset_days' must be a non-empty 1-D array of day indices, got {reset_days!r}"
        )
    clock.check_days(days, days_all, episode_start_hour, "reset_days", episode_days)
    return days.astype(np.int32)


def _day_price_quantiles(
    prices_eur_kwh: np.ndarray, tou: np.ndarray, episode_start_hour: int = 0
) -> np.ndarray:
    """Quantiles (`PRICE_QUANTILES`) of the hourly buy price plus surcharge of the episode
    that starts on each day (its 24 hours from ``episode_start_hour``), float32."""
    window = clock.episode_price_window(prices_eur_kwh, episode_start_hour)
    return np.asarray(
        np.quantile(
            np.asarray(window, np.float64) + np.roll(tou, -episode_start_hour)[None, :],
            PRICE_QUANTILES,
            axis=1,
        ).T,
        np.float32,
    )


def _battery_wear(
    station: StationArrays,
    cost_eur_kwh: float | None,
    cycle_life: float | None,
    calendar_life_years: float | None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(wear_eur_kwh (B,), calendar_eur_day (B,))`` of the station's batteries, each from its
    own `Battery` fields where the override is None."""

    if cost_eur_kwh is not None:
        _finite(
            "battery_cost_eur_kwh",
            cost_eur_kwh,
            minimum=0.0,
            maximum=checks.MAX_BATTERY_COST_EUR_KWH,
            unit="EUR/kWh",
        )
    if cycle_life is not None:
        _finite(
            "battery_cycle_life",
            cycle_life,
            minimum=checks.MIN_CYCLE_LIFE,
            maximum=checks.MAX_CYCLE_LIFE,
            unit="cycles",
        )
    if calendar_life_years is not None and calendar_life_years != 0:
        _finite(
            "battery_calendar_life_years",
            calendar_life_years,
            minimum=checks.MIN_CALENDAR_LIFE_YEARS,
            maximum=checks.MAX_CALENDAR_LIFE_YEARS,
            unit="years (0: no calendar ageing)",
        )

    def field(own, value):
        return np.asarray(own, np.float64) if value is None else np.full(len(own), value)

    own = (station.battery_cost_eur_kwh, station.battery_cycle_life)
    cost = field(own[0], cost_eur_kwh)
    cycles = field(own[1], cycle_life)
    years = field(station.battery_calendar_life_years, calendar_life_years)
    capacity = np.asarray(station.battery_capacity_kwh, np.float64)
    wear = np.array([battery_wear_eur_kwh(c, n) for c, n in zip(cost, cycles)])
    calendar = np.array(
        [
            battery_calendar_eur_day(c, k, None if y == 0 else y)
            for c, k, y in zip(cost, capacity, years)
        ]
    )
    return wear.reshape(capacity.shape), calendar.reshape(capacity.shape)


def resample_day(weights_5min: np.ndarray, num_steps: int) -> np.ndarray:
    """Resample per-5-minute weights (..., 288) to ``num_steps`` steps, preserving each day's sum.

    The cumulative sum over the day is interpolated linearly at the new step edges, so a
    step that covers part of a source slot gets that part of its weight. Any number of
    source slots works (the last axis).

    Args:
        weights_5min: ``(..., S)`` weights per source slot, ``S`` slots a day (288 for 5
            minutes).
        num_steps: the steps per day to resample to.

    Returns:
        ``(..., num_steps)`` float64; the input (as float64) when ``S == num_steps``.
    """
    w = np.asarray(weights_5min, dtype=np.float64)
    if w.shape[-1] == num_steps:
        return w
    edges_src = np.linspace(0.0, 1.0, w.shape[-1] + 1)
    edges_dst = np.linspace(0.0, 1.0, num_steps + 1)
    cum = np.concatenate([np.zeros(w.shape[:-1] + (1,)), np.cumsum(w, axis=-1)], axis=-1)
    cum_dst = np.stack(
        [np.interp(edges_dst, edges_src, row) for row in cum.reshape(-1, cum.shape[-1])]
    )
    return np.diff(cum_dst, axis=-1).reshape(w.shape[:-1] + (num_steps,))


def _battery_initial_soc(value: Any, station: StationArrays) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` arrays ``(B,)`` of the batteries' initial SoC range."""
    own = np.asarray(station.battery_initial_soc, np.float32)
    if value is None:
        return own, own
    if isinstance(value, (tuple, list, np.ndarray)) and np.ndim(value) == 1:
        if len(value) != 2:
            raise ValueError(
                f"field 'battery_initial_soc' must be a SoC in [0, 1] or a (low, high) pair, got {value!r}"
            )
        lo = _finite("battery_initial_soc[0]", value[0])
        hi = _finite("battery_initial_soc[1]", value[1])
    else:
        lo = hi = _finite("battery_initial_soc", value)
    if not 0.0 <= lo <= hi <= 1.0:
        raise ValueError(
            f"field 'battery_initial_soc' must satisfy 0 <= low <= high <= 1, got {value!r}"
        )
    return np.full_like(own, lo), np.full_like(own, hi)


def penalty_weights(alpha: PenaltyWeights | dict | None) -> PenaltyWeights:
    """Validated weights: every term finite with ``|alpha_c| <= checks.MAX_WEIGHT``, whether
    given as a dict or a `PenaltyWeights`.

    Args:
        alpha: the weights: ``None`` (all 0), a `PenaltyWeights`, or a dict
            ``{term: weight}`` over names of `PENALTY_TERMS` (terms left out are 0).

    Returns:
        The weights as a `PenaltyWeights` of Python floats.

    Raises:
        KeyError: a dict names a term not in `PENALTY_TERMS`.
        ValueError: ``alpha`` is of another type, or a weight is not a finite number in
            ``[-MAX_WEIGHT, MAX_WEIGHT]`` (see `chargax_marl.core.checks.number`).
    """
    if alpha is None:
        return PenaltyWeights()
    if isinstance(alpha, PenaltyWeights):
        values = {k: getattr(alpha, k) for k in PENALTY_TERMS}
    elif isinstance(alpha, dict):
        unknown = set(alpha) - set(PENALTY_TERMS)
        if unknown:
            raise KeyError(
                f"unknown penalty term(s) {sorted(unknown)} in 'alpha'; allowed: {list(PENALTY_TERMS)}"
            )
        values = dict(alpha)
    else:
        raise ValueError(
            f"field 'alpha' must be a dict {{term: weight}} or a PenaltyWeights, got {type(alpha).__name__}"
        )
    return PenaltyWeights(
        **{
            k: checks.number(f"alpha.{k}", v, low=-checks.MAX_WEIGHT, high=checks.MAX_WEIGHT)
            for k, v in values.items()
        }
    )


PORT_CHOICES = ("auto", "first_free", "random")
"""Values of ``make_params(port_choice=...)``."""


def _holidays(country: str | None, price: prices.PriceData, session_model: str) -> np.ndarray:
    """``(days,)`` bool: the public holidays of ``country`` on the price data's days."""
    days = price.prices_eur_kwh.shape[0]
    if country == "auto":
        known = price.first_date is not None and price.country in calendar_days.HOLIDAY_COUNTRIES
        country = price.country if session_model != "paper" and known else None
    if country is None:
        return np.zeros(days, bool)
    if price.first_date is None:
        raise ValueError(
            f"field 'holidays' ({country!r}) needs the dates of the price data, which "
            f"{price.name!r} does not carry: use a bundled dataset or holidays=None"
        )
    return calendar_days.holiday_days(country, price.first_date, days)


@checks.known_keywords
def make_params(
    *,
    station: str | Splitter | StationArrays = "multiple_types",
    station_kwargs: dict | None = None,
    grid_fraction: float | None = None,
    prices: Any = "NL-2023",
    first_weekday: int | None = None,
    user_profile: Any = "shopping",
    traffic: str | float = "medium",
    fleet: Any = "EU",
    moer_kg_per_kwh: Any = None,
    grid_demand_kwh: Any = None,
    customer_price_eur_kwh: float = 0.75,
    refund_discharged_energy: bool = True,
    grid_fee_eur_kwh: float = GRID_FEE_EUR_KWH,
    tou_fee_eur_kwh: Any = None,
    peak_demand_eur_kw: float = 0.0,
    peak_demand_booking: str = "end_of_day",
    feed_in_factor: float = 1.0,
    fixed_cost_eur: float | None = None,
    battery_initial_soc: float | tuple | None = None,
    battery_terminal_price: str | float | None = "day_mean_buy",
    battery_cost_eur_kwh: float | None = None,
    battery_cycle_life: float | None = None,
    battery_calendar_life_years: float | None = None,
    alpha: PenaltyWeights | dict | None = None,
    beta: float = 0.0,
    charged_tolerance_kwh: float = 0.05,
    step_minutes: float = 5.0,
    num_levels: int = 10,
    action_mode: str = "absolute",
    v2g: bool = True,
    constraint_mode: str = "hard",
    price_horizon_hours: int = 6,
    observe_moer: bool | None = None,
    reset_days: Any = None,
    session_model: str = "v2",
    holidays: str | None = "auto",
    port_choice: str = "auto",
    episode_start_hour: int = 0,
    dc_share: float | None = None,
    dc_margin_min: tuple[float, float] | None = None,
    episode_days: int = 1,
) -> EnvParams:
    """Assemble the parameters of a station scenario (paper defaults throughout).

    Every argument is keyword-only and checked here; the result's fields are listed, with
    their shapes and units, in `EnvParams` (and the model they feed in ``docs/model.md``).

    Economics: the station sells at ``customer_price_eur_kwh``, buys at the day-ahead price
    plus ``grid_fee_eur_kwh`` (and the hour's ``tou_fee_eur_kwh``), feeds in at
    ``feed_in_factor`` times the day-ahead price and pays ``fixed_cost_eur`` per step; the
    network tariff terms (`chargax_marl.core.tariffs`) and the batteries' wear
    (`chargax_marl.core.reward.battery_wear_eur`) are part of the profit.

    Args:
        station: an architecture name (``single_type``, ``multiple_types``,
            ``multiple_splitters``) built with ``station_kwargs``, a custom `Splitter` tree,
            or compiled `StationArrays` (see `chargax_marl.core.station.build_station`).
        station_kwargs: keyword arguments of the named architecture's builder.
        grid_fraction: in (0, 1]: sets the grid connection (the root) to that fraction of the
            sum of its children's limits (0.25: a quarter of what the EVSEs and the battery
            could draw together); it replaces the builder's ``grid_kw``. None: the tree's own.
        prices: day-ahead prices: a bundled dataset name, custom data (an array of EUR/kWh
            ``(days, 24)`` or ``(24,)``, a `chargax_marl.core.prices.PriceData`) or a CSV
            path in EUR/MWh (see `chargax_marl.core.datasets`).
        first_weekday: the weekday of day 0 of the prices (0 = Monday); None: the dataset's
            own.
        user_profile: a bundled user-profile name or custom data (see
            `chargax_marl.core.datasets`).
        traffic: ``low``/``medium``/``high`` (50/100/250 cars per day) or a number of cars
            per day (workdays; weekends scaled by the profile's weekend volume factor).
        fleet: a bundled car-fleet name, custom data or a CSV path (see
            `chargax_marl.core.datasets`).
        moer_kg_per_kwh: the marginal emission rate in kg CO2/kWh: an array ``(days, steps)``
            or ``(steps,)`` at the step resolution, or a bundled dataset name
            (``datasets.MOER_DATASETS``, 5-minute data resampled to the step); None: zeros.
            When given, MOER is observed unless ``observe_moer=False``.
        grid_demand_kwh: the grid-demand signal of the grid-demand penalty: ``(steps,)`` kWh
            per step, a shape name (``datasets.GRID_DEMAND_SHAPES``) or a CSV path; None:
            zeros.
        customer_price_eur_kwh: the price car owners pay (EUR/kWh; the paper's 0.75).
        refund_discharged_energy: True (default) refunds car owners
            ``customer_price_eur_kwh`` for every kWh discharged from their car (V2G), so
            customers pay for the net energy delivered; False bills only the energy put into
            each car and refunds nothing, the original Chargax implementation's accounting,
            under which discharging a car before it leaves earns money (see
            `chargax_marl.core.reward.billed_car_kwh`).
        grid_fee_eur_kwh: added to the day-ahead price when buying (EUR/kWh).
        tou_fee_eur_kwh: a time-of-use surcharge per local hour on the buy price (EUR/kWh):
            24 values or a preset such as ``"evening-peak"``
            (`chargax_marl.core.tariffs.TOU_PRESETS`); None: none.
        peak_demand_eur_kw: EUR per kW of the day's highest net grid draw (0: no peak
            charge).
        peak_demand_booking: ``"end_of_day"`` books the peak charge at the day's last step,
            ``"incremental"`` as the running peak rises (same daily total).
        feed_in_factor: the feed-in price as a multiple of the day-ahead price.
        fixed_cost_eur: the fixed cost per step (EUR); None: 0.35 EUR per 5 minutes, about
            100 EUR/day, scaled with the step length.
        battery_initial_soc: the station batteries' SoC at reset: a fixed SoC, a
            ``(low, high)`` range drawn uniformly at every reset, or None (each `Battery`'s
            own ``initial_soc``).
        battery_terminal_price: values the batteries' energy change over the day at the last
            step: ``"day_mean_buy"`` (default: the day's mean day-ahead price plus the grid
            fee), a price in EUR/kWh, or None (no value, the paper's free battery energy).
        battery_cost_eur_kwh: every battery's installed cost per kWh of capacity (EUR/kWh);
            None: each `Battery`'s own; 0 makes cycling free. Each kWh into or out of the
            cells costs ``cost / (2 cycle_life)``.
        battery_cycle_life: every battery's full equivalent cycles to the end of life; None:
            each `Battery`'s own.
        battery_calendar_life_years: every battery's calendar life (years), which adds
            ``cost * capacity / (365 years)`` per day; None: each `Battery`'s own; 0 turns
            calendar ageing off.
        alpha: the penalty weights, a `PenaltyWeights` or a dict ``{term: weight}`` over
            `PENALTY_TERMS`; None: all 0.
        beta: weighs the undertime credit of the charge-sensitive satisfaction term, 0 by
            default (see `chargax_marl.core.traffic.depart`).
        charged_tolerance_kwh: a charge-sensitive car leaves when the energy it still wants
            is at most this (kWh, > 0).
        step_minutes: the step length (minutes); must divide a day evenly.
        num_levels: L, the discrete levels per direction (actions in ``[-L, L]``, or
            ``[0, L]`` for a leaf that cannot discharge).
        action_mode: ``"absolute"``, ``"delta"`` or ``"continuous"`` (``docs/model.md``).
        v2g: ports with a discharge current may discharge cars (V2G); False: only the
            batteries discharge.
        constraint_mode: ``"hard"`` rescales currents so every node limit holds,
            ``"soft"`` leaves them and reports the excess.
        price_horizon_hours: hours of upcoming prices in the observation (0 to 48).
        observe_moer: MOER now is part of the observation; None: whenever
            ``moer_kg_per_kwh`` is given.
        reset_days: restricts the days ``reset`` draws from (e.g. training days, holding out
            evaluation days; see `chargax_marl.evaluation.split_days`), indices into the
            price data; None: all days an episode can start on (with
            ``episode_start_hour > 0`` all but the last, which has no next day's prices).
        session_model: ``"v2"`` (default: stays and energies by arrival hour, requests,
            day-to-day volume, holidays), ``"v3"`` (v2's sessions with every departure fixed
            when the car arrives: each car wants a port kind, an AC user stays its drawn
            stay, a DC user the earliest finish of its charge plus a margin, nobody leaves
            when charged; `EnvParams.fixed_departures`) or ``"paper"`` (the Chargax paper's
            sessions): which bundled profiles a ``user_profile`` name refers to, and the
            default of ``holidays``.
        holidays: the public holidays of this country (``calendar_days.HOLIDAY_COUNTRIES``)
            get the arrivals of a weekend day; needs prices whose dates are known (a bundled
            dataset). ``"auto"``: under the v2 session model the price market's country
            where the prices' dates are known, else none; under ``"paper"`` none. None: no
            holidays.
        port_choice: where an arriving car parks: ``"first_free"`` (the first free port in
            port order, the paper's) or ``"random"`` (the step's first car at a uniformly random
            free port, the next ones at the free ports after it);
            ``"auto"``: ``"random"`` under the v2 session model, else ``"first_free"``.
        episode_start_hour: the local hour (an integer in ``[0, 23]``) an episode starts at:
            step ``t`` of an episode that starts on day ``d`` is at ``episode_start_hour + t *
            step_minutes / 60`` hours of day ``d``, hours of 24 and more on day ``d + 1``,
            whose prices, arrival rates and day type (workday or weekend) then apply
            (`chargax_marl.core.clock`). 0 (default): an episode is the calendar day; 12: noon
            to noon, so that overnight (home) charging fits in one episode. Must fall on a
            step boundary.

        dc_share: under the session model v3, the probability in [0, 1] that an arriving
            car wants a DC port; a car finds a free port of its kind or is turned away.
            None: the profile's share (`chargax_marl.core.data_io.DC_SHARE_BY_PROFILE`,
            ``DEFAULT_DC_SHARE`` for a custom profile), 0 on a station without DC ports and 1
            on one without AC ports.
        dc_margin_min: under the session model v3, the ``(low, high)`` range of the uniform
            margin a DC user stays beyond the earliest finish of its charge (minutes,
            rounded to whole steps); None: ``data_io.DC_MARGIN_MIN``.
        episode_days: the consecutive days an episode spans, an integer >= 1 (default 1: one
            day). An episode of N days is ``num_steps * N`` steps from ``episode_start_hour``
            of its start day; parked cars stay over midnight, each calendar day brings its own
            prices, arrivals, day type and volume, the batteries' terminal value and the
            peak-demand charge (the episode's peak) are booked at its last step, and with N >
            1 the observation also holds the day of the week (`docs/model.md`, "Multi-day
            episodes"). An episode needs the prices of all its days, so N - 1 fewer days can
            start one (`chargax_marl.core.clock.num_episode_starts`).

    Returns:
        The validated `EnvParams`.

    Raises:
        ValueError: any value outside what its field allows; the message names the field,
            the value and what is allowed.
        KeyError: an unknown architecture, dataset, traffic level or penalty term name.
        TypeError: an unknown keyword argument.
    """
    if not isinstance(refund_discharged_energy, (bool, np.bool_)):
        raise ValueError(
            f"field 'refund_discharged_energy' must be a bool (True: refund car owners for energy "
            f"discharged from their car; False: no refund), got {refund_discharged_energy!r}"
        )
    step_minutes, num_steps = _check_settings(
        action_mode, constraint_mode, num_levels, price_horizon_hours, step_minutes
    )
    start_hour = _check_start_hour(episode_start_hour, step_minutes)
    num_episode_days = _check_episode_days(episode_days)

    stations = build_station(station, grid_fraction=grid_fraction, **(station_kwargs or {}))
    tou = tariffs.tou_fee(tou_fee_eur_kwh)
    peak_rate, peak_incremental = tariffs.peak_demand(peak_demand_eur_kw, peak_demand_booking)
    price = datasets.load_prices(prices, first_weekday=first_weekday)
    profile = datasets.load_user_profile(user_profile, session_model=session_model)
    fleet_data = datasets.load_fleet(fleet)
    cars_per_day = datasets.traffic_cars_per_day(traffic)

    weekend_cars = cars_per_day * profile.weekend_volume_factor
    if weekend_cars > checks.MAX_CARS_PER_DAY:
        raise ValueError(
            f"field 'traffic' ({cars_per_day:g} cars per day) times the profile's weekend_volume_factor "
            f"({profile.weekend_volume_factor:g}) must be <= {checks.MAX_CARS_PER_DAY:g} cars per day, "
            f"got {weekend_cars:g}"
        )
    weights = resample_day(profile.arrival_weights, num_steps)
    rate = weights * cars_per_day
    rate[1] *= profile.weekend_volume_factor
    holiday = _holidays(holidays, price, session_model)
    if port_choice not in PORT_CHOICES:
        raise ValueError(
            f"field 'port_choice' must be one of {list(PORT_CHOICES)}, got {port_choice!r}"
        )
    if port_choice == "auto":
        port_choice = "first_free" if session_model == "paper" else "random"
    fixed_departures = session_model == "v3"
    dc_share, dc_margin = _port_kinds(
        dc_share, dc_margin_min, stations, profile.name, fixed_departures
    )

    # MOER: a bundled dataset name / MoerData (resampled to num_steps) or an array at the step resolution.
    if moer_kg_per_kwh is None:
        moer = np.zeros((1, num_steps), np.float32)
        observe_moer = bool(observe_moer)
    elif isinstance(moer_kg_per_kwh, (str, datasets.MoerData)) or hasattr(
        moer_kg_per_kwh, "__fspath__"
    ):
        moer_data = datasets.load_moer(moer_kg_per_kwh)
        moer = datasets.validate_moer(
            datasets.resample_moer(moer_data.moer_kg_per_kwh, num_steps), check_resolution=False
        )
        observe_moer = True if observe_moer is None else bool(observe_moer)
    else:
        moer = np.asarray(moer_kg_per_kwh, dtype=np.float64)
        moer = moer[None] if moer.ndim == 1 else moer
        if moer.ndim == 2 and moer.shape[1] != num_steps and moer.shape[1] > 0:
            raise ValueError(
                f"field 'moer_kg_per_kwh' has {moer.shape[1]} columns per day ({MINUTES_PER_DAY / moer.shape[1]:g}-minute "
                f"resolution) but the simulator runs {num_steps} steps per day ({step_minutes:g}-minute resolution); "
                f"pass shape (days, {num_steps}) or ({num_steps},), or resample with datasets.resample_moer"
            )
        if moer.ndim != 2 or moer.shape[1] != num_steps or moer.shape[0] == 0:
            raise ValueError(
                f"field 'moer_kg_per_kwh' must have shape (days, {num_steps}) or ({num_steps},), "
                f"got {np.shape(moer_kg_per_kwh)}"
            )
        moer = datasets.validate_moer(moer, check_resolution=False)
        observe_moer = True if observe_moer is None else bool(observe_moer)
    # grid demand: a bundled shape name (generated at num_steps), a CSV path, or an array (num_steps,).
    if grid_demand_kwh is None:
        demand = np.zeros(num_steps, np.float32)
    elif isinstance(grid_demand_kwh, str) or hasattr(grid_demand_kwh, "__fspath__"):
        demand = datasets.load_grid_demand(grid_demand_kwh, num_steps=num_steps)
    else:
        arr = np.asarray(grid_demand_kwh, dtype=np.float64)
        if arr.ndim == 1 and arr.shape[0] != num_steps and arr.shape[0] > 0:
            raise ValueError(
                f"field 'grid_demand_kwh' has {arr.shape[0]} steps per day ({MINUTES_PER_DAY / arr.shape[0]:g}-minute "
                f"resolution) but the simulator runs {num_steps} steps per day ({step_minutes:g}-minute resolution)"
            )
        demand = datasets.validate_grid_demand(grid_demand_kwh, num_steps)

    days_all = price.prices_eur_kwh.shape[0]
    if reset_days is None:
        starts = clock.num_start_days(days_all, start_hour, num_episode_days)
        reset_days = np.arange(max(starts, 0), dtype=np.int32)
        if reset_days.size == 0 and num_episode_days > 1:
            raise ValueError(
                f"field 'episode_days' ({num_episode_days}) with episode_start_hour "
                f"{start_hour} needs at least {days_all - starts + 1} days of prices, got "
                f"{days_all}"
            )
        if reset_days.size == 0:
            raise ValueError(
                f"field 'episode_start_hour' ({start_hour}) needs at least two days of prices "
                f"(an episode runs into the next day), got {days_all} day"
            )
    days = _check_reset_days(reset_days, days_all, start_hour, num_episode_days)

    def scalar(name, value):
        return device_array(_finite(name, value, **_SCALARS[name]), jnp.float32)

    if fixed_cost_eur is None:
        fixed_cost_eur = FIXED_COST_EUR_PER_STEP * step_minutes / 5.0
    soc0_low, soc0_high = _battery_initial_soc(battery_initial_soc, stations)
    wear_eur_kwh, calendar_eur_day = _battery_wear(
        stations, battery_cost_eur_kwh, battery_cycle_life, battery_calendar_life_years
    )
    if isinstance(battery_terminal_price, str):
        if battery_terminal_price != "day_mean_buy":
            raise ValueError(
                f"field 'battery_terminal_price' must be 'day_mean_buy', a price in EUR/kWh or None, "
                f"got {battery_terminal_price!r}"
            )
        value_day_mean, value_price = True, 0.0
    elif battery_terminal_price is None:
        value_day_mean, value_price = False, 0.0
    else:
        value_day_mean, value_price = (
            False,
            _finite(
                "battery_terminal_price",
                battery_terminal_price,
                **_SCALARS["battery_value_eur_kwh"],
            ),
        )

    return EnvParams(
        station=stations,
        prices_eur_kwh=device_array(price.prices_eur_kwh, jnp.float32),
        day_price_quantiles_eur_kwh=device_array(
            _day_price_quantiles(price.prices_eur_kwh, tou, start_hour)
        ),
        first_weekday=device_array(price.first_weekday, jnp.int32),
        arrival_rate=device_array(rate, jnp.float32),
        holiday=device_array(holiday),
        weekday_volume_factors=device_array(profile.weekday_factors, jnp.float32),
        daily_volume_cv=device_array(profile.daily_volume_cv, jnp.float32),
        stay_quantiles_min=device_array(profile.stay_table_min, jnp.float32),
        stay_scale_by_hour=device_array(profile.stay_scale_by_hour, jnp.float32),
        demand_quantiles_kwh=device_array(profile.demand_table_kwh, jnp.float32),
        demand_scale_by_hour=device_array(profile.demand_scale_by_hour, jnp.float32),
        stay_demand_corr=device_array(profile.stay_demand_corr, jnp.float32),
        request_ratio_quantiles=device_array(profile.request_ratios, jnp.float32),
        arrival_soc_range=device_array(profile.arrival_soc_range, jnp.float32),
        charge_sensitive_prob=device_array(profile.charge_sensitive_prob, jnp.float32),
        dc_charge_sensitive_prob=device_array(profile.dc_charge_sensitive, jnp.float32),
        random_port_choice=device_array(port_choice == "random"),
        dc_share=device_array(dc_share, jnp.float32),
        dc_margin_min=device_array(dc_margin, jnp.float32),
        fleet_share=device_array(fleet_data.share, jnp.float32),
        fleet_capacity_kwh=device_array(fleet_data.capacity_kwh, jnp.float32),
        fleet_ac_kw=device_array(fleet_data.max_ac_kw, jnp.float32),
        fleet_dc_kw=device_array(fleet_data.max_dc_kw, jnp.float32),
        fleet_tau=device_array(fleet_data.tau, jnp.float32),
        fleet_ac_discharge_kw=device_array(fleet_data.max_ac_discharge_kw, jnp.float32),
        fleet_dc_discharge_kw=device_array(fleet_data.max_dc_discharge_kw, jnp.float32),
        moer_kg_per_kwh=device_array(moer, jnp.float32),
        grid_demand_kwh=device_array(demand, jnp.float32),
        reset_days=device_array(days),
        battery_soc0_low=device_array(soc0_low, jnp.float32),
        battery_soc0_high=device_array(soc0_high, jnp.float32),
        battery_wear_eur_kwh=device_array(wear_eur_kwh, jnp.float32),
        battery_calendar_eur_step=device_array(
            calendar_eur_day * step_minutes / MINUTES_PER_DAY, jnp.float32
        ),
        customer_price_eur_kwh=scalar("customer_price_eur_kwh", customer_price_eur_kwh),
        refund_discharged_energy=device_array(bool(refund_discharged_energy)),
        grid_fee_eur_kwh=scalar("grid_fee_eur_kwh", grid_fee_eur_kwh),
        tou_fee_eur_kwh=device_array(tou, jnp.float32),
        peak_demand_eur_kw=device_array(peak_rate, jnp.float32),
        peak_demand_incremental=device_array(peak_incremental),
        feed_in_factor=scalar("feed_in_factor", feed_in_factor),
        fixed_cost_eur=scalar("fixed_cost_eur", fixed_cost_eur),
        alpha=penalty_weights(alpha),
        battery_value_day_mean=device_array(value_day_mean),
        battery_value_eur_kwh=device_array(value_price, jnp.float32),
        beta=scalar("beta", beta),
        charged_tolerance_kwh=scalar("charged_tolerance_kwh", charged_tolerance_kwh),
        step_minutes=step_minutes,
        num_steps=num_steps,
        num_levels=int(num_levels),
        action_mode=action_mode,
        v2g=bool(v2g),
        constraint_mode=constraint_mode,
        price_horizon_hours=int(price_horizon_hours),
        observe_moer=observe_moer,
        episode_start_hour=start_hour,
        fixed_departures=fixed_departures,
        episode_days=num_episode_days,
    )


def _port_kinds(
    dc_share, dc_margin_min, stations: StationArrays, profile: str, fixed: bool
) -> tuple[float, tuple[float, float]]:
    """The checked ``dc_share`` and ``dc_margin_min`` of `make_params` (see there)."""
    kinds = np.asarray(stations.leaf_kind)
    has_ac, has_dc = bool((kinds == KIND_AC).any()), bool((kinds == KIND_DC).any())
    if dc_share is None:
        share = data_io.DC_SHARE_BY_PROFILE.get(profile, data_io.DEFAULT_DC_SHARE)
        share = share if has_ac and has_dc else float(has_dc)
    else:
        share = _finite("dc_share", dc_share, minimum=0.0, maximum=1.0)
        if fixed and ((share > 0.0 and not has_dc) or (share < 1.0 and not has_ac)):
            missing, kind = ("DC", "0") if not has_dc else ("AC", "1")
            raise ValueError(
                f"field 'dc_share' is {share:g} but the station has no {missing} ports: a car "
                f"wanting one would always be turned away; use {kind} or None"
            )
    margin = data_io.DC_MARGIN_MIN if dc_margin_min is None else dc_margin_min
    arr = np.asarray(margin, dtype=np.float64) if np.ndim(margin) == 1 else None
    if arr is None or arr.shape != (2,) or not np.isfinite(arr).all():
        raise ValueError(
            f"field 'dc_margin_min' must be a (low, high) pair of finite minutes, got {margin!r}"
        )
    low, high = float(arr[0]), float(arr[1])
    if not 0.0 <= low <= high <= MINUTES_PER_DAY:
        raise ValueError(
            f"field 'dc_margin_min' must satisfy 0 <= low <= high <= {MINUTES_PER_DAY:g} "
            f"minutes, got ({low:g}, {high:g})"
        )
    return share, (low, high)


def _scalar(params: EnvParams, field: str, kind: str = "number") -> Any:
    """The 0-d field ``field`` of ``params`` as a Python value (``kind``: number or bool)."""
    x = np.asarray(getattr(params, field))
    if x.shape != ():
        raise ValueError(f"field '{field}' must be a scalar (shape ()), got shape {x.shape}")
    if kind == "bool" and x.dtype != np.bool_:
        raise ValueError(f"field '{field}' must be a bool, got {x.item()!r} of dtype {x.dtype}")
    if kind == "number" and not (
        np.issubdtype(x.dtype, np.floating) or np.issubdtype(x.dtype, np.integer)
    ):
        raise ValueError(f"field '{field}' must be a number, got {x.item()!r} of dtype {x.dtype}")
    return x.item()


def _shape(field: str, value: Any, shape: tuple, what: str) -> np.ndarray:
    arr = np.asarray(value)
    if arr.shape != shape:
        raise ValueError(f"field '{field}' must have shape {shape} ({what}), got {arr.shape}")
    return arr


def validate_params(params: EnvParams) -> EnvParams:
    """Re-run `make_params`'s checks on params made some other way.

    ``EnvParams.replace`` and hand-made `StationArrays` skip every check of
    `make_params`; this applies them to the finished object (the same bounds, from
    `chargax_marl.core.checks` and the data validators), so that a bad value is an error
    at construction and never a NaN later. Both views call it on the params they are given.
    Params with traced leaves (inside ``jit``) are returned unchecked.

    Args:
        params: the parameters to check.

    Returns:
        ``params`` unchanged.

    Raises:
        ValueError: a field outside its range or of the wrong shape or kind, or derived fields
            that no longer match what they derive from (the day price quantiles); the message
            names the field, the value and what is allowed.
    """
    if not isinstance(params, EnvParams):
        raise ValueError(f"params must be an EnvParams, got {type(params).__name__}")
    if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(params)):
        return params
    _, num_steps = _check_settings(
        params.action_mode,
        params.constraint_mode,
        params.num_levels,
        params.price_horizon_hours,
        params.step_minutes,
    )
    if params.num_steps != num_steps:
        raise ValueError(
            f"field 'num_steps' must be 1440 / step_minutes = {num_steps}, got {params.num_steps!r}"
        )
    start_hour = _check_start_hour(params.episode_start_hour, params.step_minutes)
    episode_days = _check_episode_days(params.episode_days)
    for field in ("v2g", "observe_moer"):
        if not isinstance(getattr(params, field), (bool, np.bool_)):
            raise ValueError(f"field '{field}' must be a bool, got {getattr(params, field)!r}")
    st = check_station_arrays(params.station)
    b = (st.num_batteries,)
    for field, bounds in _SCALARS.items():
        _finite(field, _scalar(params, field), **bounds)
    for field in (
        "refund_discharged_energy",
        "peak_demand_incremental",
        "battery_value_day_mean",
        "random_port_choice",
    ):
        _scalar(params, field, "bool")
    booking = "incremental" if _scalar(params, "peak_demand_incremental", "bool") else "end_of_day"
    tariffs.peak_demand(_scalar(params, "peak_demand_eur_kw"), booking)
    weekday = _scalar(params, "first_weekday")
    if not (isinstance(weekday, int) and 0 <= weekday <= 6):
        raise ValueError(f"field 'first_weekday' must be an integer in [0, 6], got {weekday!r}")
    for field in ("charge_sensitive_prob", "dc_charge_sensitive_prob"):
        _finite(field, _scalar(params, field), minimum=0.0, maximum=1.0)
    if not isinstance(params.fixed_departures, (bool, np.bool_)):
        raise ValueError(
            f"field 'fixed_departures' must be a bool, got {params.fixed_departures!r}"
        )
    _port_kinds(
        _scalar(params, "dc_share"),
        tuple(_shape("dc_margin_min", params.dc_margin_min, (2,), "(low, high) minutes")),
        st,
        "",
        params.fixed_departures,
    )
    profiles._validate_volume_cv(_scalar(params, "daily_volume_cv"))
    profiles._validate_corr(_scalar(params, "stay_demand_corr"))

    price = np.asarray(params.prices_eur_kwh)
    if price.ndim != 2:
        raise ValueError(
            f"field 'prices_eur_kwh' must have shape (days, 24), got shape {price.shape}"
        )
    prices._validate_prices(price, "prices_eur_kwh")
    tou = tariffs.tou_fee(np.asarray(params.tou_fee_eur_kwh, np.float64))
    quantiles = np.asarray(params.day_price_quantiles_eur_kwh)
    if quantiles.shape != (price.shape[0], len(PRICE_QUANTILES)) or not np.allclose(
        quantiles, _day_price_quantiles(price, tou, start_hour), rtol=1e-5, atol=1e-6
    ):
        raise ValueError(
            "field 'day_price_quantiles_eur_kwh' must be the quantiles of prices_eur_kwh plus "
            "tou_fee_eur_kwh of each day's episode (derived by make_params): build the params "
            "with make_params(prices=..., tou_fee_eur_kwh=..., episode_start_hour=...) instead "
            "of replacing any of them"
        )
    rate = _shape("arrival_rate", params.arrival_rate, (2, num_steps), "workday and weekend rows")
    checks.array("arrival_rate", rate, low=0.0, high=checks.MAX_CARS_PER_DAY, unit="cars per step")
    for field in ("stay_quantiles_min", "demand_quantiles_kwh"):
        table = _shape(field, getattr(params, field), (24, NUM_QUANTILES), "one per arrival hour")
        profiles._validate_quantiles(table, field, by_hour=True)
    profiles._validate_request_ratios(np.asarray(params.request_ratio_quantiles))
    profiles._validate_weekday_factors(np.asarray(params.weekday_volume_factors))
    _shape("holiday", params.holiday, (price.shape[0],), "one per day of the prices")
    profiles._validate_scale(np.asarray(params.stay_scale_by_hour), "stay_scale_by_hour")
    profiles._validate_scale(np.asarray(params.demand_scale_by_hour), "demand_scale_by_hour")
    soc_range = _shape("arrival_soc_range", params.arrival_soc_range, (2,), "low and high")
    profiles._validate_soc_range(tuple(float(x) for x in soc_range))
    share = np.asarray(params.fleet_share, np.float64)
    fleet = fleets._make_fleet(
        "params",
        [f"model {i}" for i in range(share.size)],
        share,
        params.fleet_capacity_kwh,
        params.fleet_ac_kw,
        params.fleet_dc_kw,
        params.fleet_tau,
        params.fleet_ac_discharge_kw,
        params.fleet_dc_discharge_kw,
    )
    if not np.allclose(share, fleet.share, rtol=0.0, atol=1e-5):
        raise ValueError(f"field 'fleet_share' must sum to 1, got a sum of {share.sum()!r}")
    moer = np.asarray(params.moer_kg_per_kwh)
    if moer.ndim != 2 or moer.shape[0] == 0 or moer.shape[1] != num_steps:
        raise ValueError(
            f"field 'moer_kg_per_kwh' must have shape (days, {num_steps}), got shape {moer.shape}"
        )
    datasets.validate_moer(moer, check_resolution=False)
    datasets.validate_grid_demand(np.asarray(params.grid_demand_kwh), num_steps)
    _check_reset_days(params.reset_days, price.shape[0], start_hour, episode_days)
    low = _shape("battery_soc0_low", params.battery_soc0_low, b, "one per battery")
    high = _shape("battery_soc0_high", params.battery_soc0_high, b, "one per battery")
    checks.array("battery_soc0_low", low, low=0.0, high=1.0)
    checks.array("battery_soc0_high", high, low=0.0, high=1.0)
    if (low > high).any():
        i = int(np.argmax(low > high))
        raise ValueError(
            f"fields 'battery_soc0_low' and 'battery_soc0_high' must satisfy low <= high, got "
            f"{float(low[i])!r} > {float(high[i])!r} for battery {i}"
        )
    for field in ("battery_wear_eur_kwh", "battery_calendar_eur_step"):
        checks.array(
            field, _shape(field, getattr(params, field), b, "one per battery"), low=0.0, unit="EUR"
        )
    penalty_weights(params.alpha)
    return params


def validated_replace(params: EnvParams, **changes: Any) -> EnvParams:
    """``params.replace(**changes)`` with the checks of `validate_params`.

    ``EnvParams.replace`` itself is unchecked (a frozen-dataclass copy); derive params
    through this function (or rebuild them with `make_params`) so that a bad value is an
    error here rather than a NaN in the step.

    Args:
        params: the parameters to derive from.
        **changes: new values of `EnvParams` fields.

    Returns:
        The derived, validated params.

    Raises:
        TypeError: an unknown field name (the message lists the allowed ones).
        ValueError: as `validate_params`.
    """
    checks.keywords("validated_replace", changes, tuple(EnvParams.__dataclass_fields__))
    return validate_params(params.replace(**changes))
