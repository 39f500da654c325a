"""The clock of an episode: where step ``t`` of an episode that starts on day ``d`` falls.

An episode is ``episode_steps = num_steps * episode_days`` steps (``episode_days`` days,
1 by default) long and starts at ``episode_start_hour`` (an `EnvParams` setting, 0 by
default) of its day ``d`` (``state.day``, the day the episode starts on, which indexes the
price data). Step ``t`` is at clock time ``episode_start_hour + t * step_minutes / 60`` hours
of day ``d``; hours of 24 and more fall on day ``d + 1``, of 48 and more on ``d + 2``, and so
on. With a start hour of 0 and one day an episode is the calendar day from 00:00 to 24:00;
with 12 it runs from noon to noon and a car that parks in the evening can stay the night.
With ``episode_days = N`` it spans N consecutive days and each calendar day brings its own
prices, day type and arrival volume.

Everything that reads the time of a step (the day-ahead price and the time-of-use surcharge,
the arrival rate and its day type, the stay and demand scaling by arrival hour, MOER, the
grid-demand signal, the observation's time features) goes through these functions.

Two kinds of index, both clamped to the episode's last step (a state after the last step,
``timestep == episode_steps``, reads the clock of the last step, as it always has):

- by step: `episode_slot` (steps since midnight of day ``d``), `slot_of_day` and
  `day_offset` / `calendar_day` (the per-step tables: arrival rate, MOER, grid demand);
- by hour: `hours_since_start` (0..24 N - 1, the hour of the episode), `episode_day_index`
  (0..N - 1, the episode's day: its 24 hours from the start hour), `episode_hour` (hours
  since midnight of day ``d``; the hourly price tables, flattened over days, are read at
  ``d * 24 + episode_hour``) and `clock_hour` (0..23, the local hour).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from chargax_marl.core.types import EnvParams

HOURS_PER_DAY = 24


def episode_steps(params: EnvParams) -> int:
    """The steps of an episode (a Python int): ``num_steps * episode_days``.

    Args:
        params: the environment parameters (``num_steps``, ``episode_days``).

    Returns:
        ``num_steps * episode_days``; ``num_steps`` (one day) by default.
    """
    return int(params.num_steps) * int(params.episode_days)


def require_one_day(params: EnvParams, where: str) -> None:
    """Refuse episodes of several days where only one-day episodes are supported yet.

    Args:
        params: the environment parameters (``episode_days``).
        where: the entry point that refuses, for the message.

    Raises:
        ValueError: ``params.episode_days`` is not 1; the message names the field, its value
            and the entry point.
    """
    n = int(getattr(params, "episode_days", 1))
    if n != 1:
        raise ValueError(
            f"{where}: field 'episode_days' is {n}, but only episode_days=1 (one-day "
            f"episodes) is supported here yet"
        )


def start_step(params: EnvParams) -> int:
    """The step of the day at which an episode starts (a Python int).

    Args:
        params: the environment parameters (``episode_start_hour``, ``step_minutes``).

    Returns:
        ``episode_start_hour * 60 / step_minutes``, a whole number (`make_params` checks).
    """
    return int(round(params.episode_start_hour * 60.0 / params.step_minutes))


def episode_slot(timestep, params: EnvParams) -> jnp.ndarray:
    """Steps since midnight of the episode's first day, ``start_step + t`` with ``t`` clamped
    to the episode (``[0, episode_steps - 1]``).

    Args:
        timestep: the step of the episode (int, any shape).
        params: the environment parameters.

    Returns:
        int32 steps in ``[start_step, start_step + episode_steps - 1]``, shaped as
        ``timestep``.
    """
    return start_step(params) + jnp.clip(jnp.asarray(timestep), 0, episode_steps(params) - 1)


def day_offset(timestep, params: EnvParams) -> jnp.ndarray:
    """0 while step ``timestep`` is on the episode's first calendar day, 1 after the first
    midnight, 2 after the second, and so on.

    Args:
        timestep: the step of the episode (int, any shape).
        params: the environment parameters.

    Returns:
        int32 in ``[0, episode_days]`` (at most ``episode_days - 1`` with a start hour of
        0), shaped as ``timestep``.
    """
    return episode_slot(timestep, params) // params.num_steps


def calendar_day(day, timestep, params: EnvParams) -> jnp.ndarray:
    """The calendar day step ``timestep`` of an episode that starts on ``day`` falls on.

    Args:
        day: the episode's day (``state.day``, int, any shape broadcasting with
            ``timestep``).
        timestep: the step of the episode.
        params: the environment parameters.

    Returns:
        ``day + day_offset`` (int32); not wrapped around the data (callers that index
        per-day tables wrap it themselves).
    """
    return day + day_offset(timestep, params)


def slot_of_day(timestep, params: EnvParams) -> jnp.ndarray:
    """The step of the calendar day that step ``timestep`` of the episode falls in, the
    column of the per-step day tables (arrival rate, MOER, grid demand).

    Args:
        timestep: the step of the episode (int, any shape).
        params: the environment parameters.

    Returns:
        int32 in ``[0, num_steps - 1]``, shaped as ``timestep``.
    """
    return jnp.mod(episode_slot(timestep, params), params.num_steps)


def hours_since_start(timestep, params: EnvParams) -> jnp.ndarray:
    """The hour of the episode step ``timestep`` is in: 0 for the first hour, ``24 *
    episode_days - 1`` for the last (an episode starts on a whole hour, so the hourly prices
    change on the same steps).

    Args:
        timestep: the step of the episode (int, any shape).
        params: the environment parameters.

    Returns:
        int32 in ``[0, 24 * episode_days - 1]`` (``[0, 23]`` for one day), shaped as
        ``timestep``.
    """
    hours = jnp.asarray(timestep) * params.step_minutes / 60.0
    return jnp.clip(hours.astype(jnp.int32), 0, HOURS_PER_DAY * int(params.episode_days) - 1)


def episode_day_index(timestep, params: EnvParams) -> jnp.ndarray:
    """The day of the episode step ``timestep`` is in: 0 for its first 24 hours (from the
    start hour), 1 for the next 24, up to ``episode_days - 1``. With a start hour of 0 it is
    the calendar day's offset, `day_offset`. The "day's" quantities of the observation and of
    the battery's terminal value (the price quantiles, the mean buy price of 24 hours) read
    the 24 hours of the episode's day ``day + episode_day_index``.

    Args:
        timestep: the step of the episode (int, any shape).
        params: the environment parameters.

    Returns:
        int32 in ``[0, episode_days - 1]``; 0 for one-day episodes.
    """
    return hours_since_start(timestep, params) // HOURS_PER_DAY


def episode_hour(timestep, params: EnvParams) -> jnp.ndarray:
    """Hours since midnight of the episode's first day: ``episode_start_hour +
    hours_since_start``, 24 and more after midnight. The hourly price data flattened over
    days, ``prices.reshape(-1)``, is read at ``day * 24 + episode_hour``.

    Args:
        timestep: the step of the episode (int, any shape).
        params: the environment parameters.

    Returns:
        int32 in ``[episode_start_hour, episode_start_hour + 24 * episode_days - 1]``.
    """
    return params.episode_start_hour + hours_since_start(timestep, params)


def clock_hour(timestep, params: EnvParams) -> jnp.ndarray:
    """The local hour of day (0..23) of step ``timestep`` of the episode.

    Args:
        timestep: the step of the episode (int, any shape).
        params: the environment parameters.

    Returns:
        int32 in ``[0, 23]``, shaped as ``timestep``.
    """
    return jnp.mod(episode_hour(timestep, params), HOURS_PER_DAY)


def steps_since_midnight(timestep, params: EnvParams) -> jnp.ndarray:
    """``start_step + timestep``, unclamped: the time of a step in steps since midnight of
    the episode's first day, for the observation's time-of-day features (periodic in a day).

    Args:
        timestep: the step of the episode (int, any shape).
        params: the environment parameters.

    Returns:
        int steps, shaped as ``timestep``.
    """
    return start_step(params) + timestep


def is_workday(day, timestep, params: EnvParams) -> jnp.ndarray:
    """Whether step ``timestep`` of the episode that starts on ``day`` falls on a workday
    (Monday to Friday of its calendar day, counting from ``first_weekday``, the weekday of
    the data's day 0, and not a public holiday, ``params.holiday``).

    Args:
        day: the episode's day.
        timestep: the step of the episode.
        params: the environment parameters.

    Returns:
        A bool array shaped as the broadcast of ``day`` and ``timestep``.
    """
    calendar = calendar_day(day, timestep, params)
    return (weekday(calendar, params) < 5) & ~is_holiday(calendar, params)


def weekday(calendar, params: EnvParams) -> jnp.ndarray:
    """The weekday (0 = Monday) of calendar day ``calendar`` of the price data.

    Args:
        calendar: a day index of the price data (int, any shape).
        params: the environment parameters (``first_weekday``).

    Returns:
        int32 in ``[0, 6]``, shaped as ``calendar``.
    """
    return jnp.mod(params.first_weekday + calendar, 7)


def is_holiday(calendar, params: EnvParams) -> jnp.ndarray:
    """Whether calendar day ``calendar`` of the price data is a public holiday
    (``params.holiday``; wrapped around the data).

    Args:
        calendar: a day index of the price data (int, any shape).
        params: the environment parameters.

    Returns:
        bool, shaped as ``calendar``.
    """
    return params.holiday[jnp.mod(calendar, params.holiday.shape[0])]


def num_episode_starts(params: EnvParams) -> int:
    """How many days of the price data an episode can start on (a Python int): the days
    ``d`` whose episode's calendar days ``d .. d + episode_days - 1`` (and ``d +
    episode_days`` with a start hour above 0) all have prices (`num_start_days`).

    Args:
        params: the environment parameters.

    Returns:
        ``num_days - episode_days + 1``, one less with a start hour above 0 (may be 0 or
        less when the data is too short).
    """
    return num_start_days(params.num_days, params.episode_start_hour, params.episode_days)


def num_start_days(num_days: int, episode_start_hour: int, episode_days: int = 1) -> int:
    """`num_episode_starts` from the number of days of price data, the start hour and the
    days an episode spans.

    Args:
        num_days: the days of the price data.
        episode_start_hour: the hour episodes start at.
        episode_days: the calendar days an episode spans from its start hour (1: one day).

    Returns:
        ``num_days - (episode_days - 1)`` when ``episode_start_hour == 0``, one less
        otherwise: an episode that starts on day ``d`` needs the prices of days ``d`` to
        ``d + episode_days - 1``, and of ``d + episode_days`` when it starts after midnight.
    """
    extra = (int(episode_days) - 1) + (1 if int(episode_start_hour) else 0)
    return int(num_days) - extra


def check_days(
    days, num_days: int, episode_start_hour: int, field: str = "days", episode_days: int = 1
) -> np.ndarray:
    """Check that every day of ``days`` (host values) can start an episode.

    Args:
        days: day indices into the price data.
        num_days: the days of the price data.
        episode_start_hour: the hour episodes start at.
        field: the name of the argument, for the message.
        episode_days: the calendar days an episode spans from its start hour.

    Returns:
        ``days`` as an int64 numpy array.

    Raises:
        ValueError: a day outside ``[0, num_start_days - 1]``; the message says which last
            day of the data an episode from a later day would run past.
    """
    arr = np.asarray(days).astype(np.int64)
    last = num_start_days(num_days, episode_start_hour, episode_days) - 1
    if arr.size and (arr.min() < 0 or arr.max() > last):
        if int(episode_days) > 1:
            start = f" from {int(episode_start_hour)}:00" if episode_start_hour else ""
            why = (
                f": an episode of {int(episode_days)} days{start} needs the prices of "
                f"{num_days - 1 - last} day(s) after its first, and the data's last day is "
                f"{num_days - 1}"
            )
        elif episode_start_hour:
            why = (
                f": an episode that starts at {int(episode_start_hour)}:00 runs into the next "
                f"day, whose prices the last day of the data ({num_days - 1}) does not have"
            )
        else:
            why = " (days of the price data)"
        raise ValueError(
            f"field '{field}' must lie in [0, {last}]{why}, got values from {arr.min()} to "
            f"{arr.max()}"
        )
    return arr


def episode_price_hours(day, params: EnvParams) -> jnp.ndarray:
    """Indices of the episode's 24 hours into the hourly price data flattened over days, in
    the episode's order (``day * 24 + episode_start_hour + k``, wrapped around the data).

    Args:
        day: the episode's day (``()`` int).
        params: the environment parameters.

    Returns:
        ``(24,)`` int32 indices into ``params.prices_eur_kwh.reshape(-1)``.
    """
    flat = params.prices_eur_kwh.shape[0] * HOURS_PER_DAY
    k = jnp.arange(HOURS_PER_DAY, dtype=jnp.int32)
    return jnp.mod(day * HOURS_PER_DAY + params.episode_start_hour + k, flat)


def episode_day_ahead_prices(day, params: EnvParams) -> jnp.ndarray:
    """The day-ahead prices (EUR/kWh) of the episode's 24 hours, in the episode's order:
    the row ``prices_eur_kwh[day]`` with a start hour of 0, else the hours from the start
    hour of ``day`` to the one before it on the next day. For a later day ``k`` of an
    episode of several days pass ``day + k`` (`episode_day_index`).

    Args:
        day: the episode's day (``()`` int).
        params: the environment parameters.

    Returns:
        ``(24,)`` EUR/kWh, indexed by `hours_since_start`.
    """
    if params.episode_start_hour == 0:
        return params.prices_eur_kwh[day]
    return params.prices_eur_kwh.reshape(-1)[episode_price_hours(day, params)]


def episode_tou_fee(params: EnvParams) -> jnp.ndarray:
    """The time-of-use surcharge (EUR/kWh) of the episode's 24 hours, in the episode's order
    (``tou_fee_eur_kwh`` rolled to start at the start hour).

    Args:
        params: the environment parameters.

    Returns:
        ``(24,)`` EUR/kWh, indexed by `hours_since_start`.
    """
    if params.episode_start_hour == 0:
        return params.tou_fee_eur_kwh
    return jnp.roll(params.tou_fee_eur_kwh, -params.episode_start_hour)


def episode_price_window(prices_eur_kwh: np.ndarray, episode_start_hour: int) -> np.ndarray:
    """Host side: ``(D, 24)`` the hourly prices of the episode that starts on each day, in
    the episode's order (the last day's episode wraps to the data's first day).

    Args:
        prices_eur_kwh: ``(D, 24)`` hourly prices.
        episode_start_hour: the hour episodes start at.

    Returns:
        ``prices_eur_kwh`` itself with a start hour of 0, else the shifted windows.
    """
    prices = np.asarray(prices_eur_kwh)
    if not episode_start_hour:
        return prices
    flat = prices.reshape(-1)
    idx = np.arange(prices.shape[0])[:, None] * HOURS_PER_DAY + episode_start_hour
    return flat[np.mod(idx + np.arange(HOURS_PER_DAY)[None, :], flat.size)]
