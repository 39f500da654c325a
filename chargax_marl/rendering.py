"""Rendering shared by the Gymnasium and PettingZoo wrappers (host side, numpy).

Modes: ``"ansi"`` returns a text table of the station now, ``"human"`` prints that table and
returns None, ``"rgb_array"`` returns an ``HxWx3`` uint8 plot of the day so far (price and
station power). Times are clock times (`chargax_marl.core.clock`): an episode that starts at
noon is drawn from 12:00 to 12:00 the next day.
"""

from __future__ import annotations

import gymnasium
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, MultipleLocator

from chargax_marl.core import clock
from chargax_marl.core.station import KIND_NAMES
from chargax_marl.core.types import EnvParams

RENDER_MODES = ["ansi", "human", "rgb_array"]


def check_render_mode(render_mode: str | None, where: str) -> None:
    """Refuse a render mode that is not one of `RENDER_MODES` (None is allowed).

    Args:
        render_mode: the env's ``render_mode``.
        where: the caller's name, which starts the error message.

    Raises:
        ValueError: ``render_mode`` is neither None nor one of `RENDER_MODES`.
    """
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ValueError(
            f"{where}: render_mode must be one of {RENDER_MODES} or None, got {render_mode!r}"
        )


def price_now(state, params: EnvParams) -> float:
    """The day-ahead price (EUR/kWh) of the state's hour at its clock time (the next day's
    prices past midnight); ``state`` on the host.

    Args:
        state: the env state (`chargax_marl.core.types.EnvState`); its ``day`` and
            ``timestep`` are read.
        params: the environment parameters.

    Returns:
        The day-ahead price in EUR/kWh, without the time-of-use surcharge.
    """
    hour = int(clock.episode_hour(int(state.timestep), params))
    flat = np.asarray(params.prices_eur_kwh).reshape(-1)
    return float(flat[((int(state.day) % params.num_days) * 24 + hour) % flat.size])


def clock_time(state, params: EnvParams) -> str:
    """The state's clock time ``HH:MM``, with ``(+1 day)`` past the episode's first
    midnight when the episode starts after midnight (one that starts at midnight ends at
    ``24:00``); ``state`` on the host.

    Args:
        state: the env state; its ``timestep`` is read.
        params: the environment parameters.

    Returns:
        ``"HH:MM"``, followed by ``" (+1 day)"`` on the next day.
    """
    minutes = int(clock.steps_since_midnight(int(state.timestep), params)) * params.step_minutes
    next_day = ""
    if params.episode_start_hour and minutes >= 1440:
        next_day, minutes = " (+1 day)", minutes - 1440
    return f"{int(minutes // 60):02d}:{int(minutes % 60):02d}{next_day}"


def clock_axis(ax, params: EnvParams) -> None:
    """Label an axis of hours since midnight of the episode's first day as clock times
    (``HH:00``, wrapping past 24) when the episode starts after midnight; a start hour of 0
    keeps the plain hours of the day.

    Args:
        ax: the matplotlib axes whose x axis is labelled (in place).
        params: the environment parameters; ``episode_start_hour`` is read.
    """
    if not params.episode_start_hour:
        return
    ax.xaxis.set_major_locator(MultipleLocator(3))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{int(round(x)) % 24:02d}:00"))
    ax.set_xlabel("clock time (past 24:00: the next day)")


def ansi_table(state, params: EnvParams, names: list[str]) -> str:
    """One line of context, then one row per leaf (``names`` in leaf order); ``state`` on the host.

    Args:
        state: the env state.
        params: the environment parameters.
        names: one name per leaf (ports, then batteries), in leaf order.

    Returns:
        The table as text: a line with the day, step, clock time, price (EUR/kWh) and profit so
        far (EUR), a header, and per leaf its name, kind, whether it is occupied, its SoC
        ("-" when free), current (A) and power (kW).
    """
    st = params.station
    kinds = np.asarray(st.leaf_kind)
    volts = np.asarray(st.leaf_voltage_v)
    lines = [
        f"day {int(state.day)}  step {int(state.timestep)}/{clock.episode_steps(params)}  "
        f"time {clock_time(state, params)}  "
        f"price {price_now(state, params):.4f} EUR/kWh  profit so far {float(state.totals.profit_eur):.2f} EUR",
        f"{'agent':<12}{'kind':<9}{'occupied':>9}{'SoC':>7}{'current A':>11}{'power kW':>10}",
    ]
    for i, a in enumerate(names):
        occ = bool(state.occupied[i])
        soc = f"{float(state.soc[i]):.2f}" if occ else "-"
        cur = float(state.current_a[i]) + 0.0  # no "-0.0"
        lines.append(
            f"{a:<12}{KIND_NAMES[int(kinds[i])]:<9}{('yes' if occ else 'no'):>9}{soc:>7}"
            f"{cur:>11.1f}{cur * float(volts[i]) / 1000.0:>10.1f}"
        )
    return "\n".join(lines)


def rgb_plot(history: list[tuple[float, float, float]], state, params: EnvParams) -> np.ndarray:
    """``HxWx3`` uint8 plot of ``history`` rows ``(hour, buy price, station kW)``, the hour
    counted from the episode's start and drawn at its clock time.

    Args:
        history: the rows of the day so far, one per step; empty draws empty axes.
        state: the env state, whose day and step make the title.
        params: the environment parameters.

    Returns:
        The RGB image, ``(320, 512, 3)`` uint8 (a 6.4 x 4.0 inch figure at 80 dpi): the price
        over the power, 24 hours from the episode's start.
    """

    fig = Figure(figsize=(6.4, 4.0), dpi=80)
    canvas = FigureCanvasAgg(fig)
    ax_price, ax_power = fig.subplots(2, 1, sharex=True)
    if history:
        h = np.asarray(history)
        hours = params.episode_start_hour + h[:, 0]
        ax_price.step(hours, h[:, 1], where="post", color="tab:orange")
        ax_power.step(hours, h[:, 2], where="post", color="tab:blue")
    ax_price.set_ylabel("price EUR/kWh")
    ax_power.set_ylabel("station kW")
    ax_power.set_xlabel("hour of the day")
    ax_power.set_xlim(params.episode_start_hour, params.episode_start_hour + 24)
    clock_axis(ax_power, params)
    ax_price.set_title(
        f"day {int(state.day)}, step {int(state.timestep)}/{clock.episode_steps(params)}"
    )
    fig.tight_layout()
    canvas.draw()
    return np.array(canvas.buffer_rgba(), dtype=np.uint8)[..., :3].copy()


def render(mode: str | None, state, params: EnvParams, names: list[str], history, where: str):
    """Dispatch on ``mode``; ``None`` warns (Gymnasium's convention) and returns None.

    Args:
        mode: one of `RENDER_MODES`, or None.
        state: the env state on the host; None before the first reset.
        params: the environment parameters.
        names: one name per leaf, in leaf order (`ansi_table`).
        history: the rows of the day so far (`rgb_plot`).
        where: the env's class name, for the messages.

    Returns:
        ``"rgb_array"``: the image of `rgb_plot`; ``"human"`` and None: None (``"human"``
        prints the table); any other mode: the text of `ansi_table`.

    Raises:
        RuntimeError: a mode is given and ``state`` is None (render before reset).
    """
    if mode is None:
        gymnasium.logger.warn(
            f"{where}.render() called without a render_mode; pass render_mode='ansi', "
            "'human' or 'rgb_array' when constructing the env"
        )
        return None
    if state is None:
        raise RuntimeError(f"{where}.render() called before reset()")
    if mode == "rgb_array":
        return rgb_plot(history, state, params)
    text = ansi_table(state, params, names)
    if mode == "human":
        print(text)
        return None
    return text
