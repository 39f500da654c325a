"""A picture of a policy's held-out day beside a reference, for an operator to look at.

`day_picture` plays one held-out day and draw of a task (the cars every policy meets on
it) and draws, over the hours of the day (clock times: an episode that starts at noon runs from
12:00 to 12:00 the next day): the buy price; the grid draw of both against the
connection's limit; each port's power under the policy as a heat map, with arrivals and
departures marked; the station battery's state of charge; and the cumulative profit of both,
with the LP hindsight bound's day total.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np
from matplotlib.figure import Figure

from chargax_marl.benchmark import protocol
from chargax_marl.benchmark.references import BOUND, load_references
from chargax_marl.benchmark.tasks import Task, get_task
from chargax_marl.policies import get_policy
from chargax_marl.rendering import clock_axis
from chargax_marl.trace import day_of, make_traces, replay


def play_day(act: Callable, params, day: int, key: jax.Array) -> dict:
    """One day of ``act(state, key) -> levels`` with the cars of ``key``, step by step.

    Args:
        act: a jittable ``act(state, key) -> levels`` (`chargax_marl.benchmark.protocol.as_core`).
        params: the env parameters.
        day: the day index.
        key: the ``(2,)`` key of the day and draw (one row of
            `chargax_marl.benchmark.Task.day_keys`).

    Returns:
        ``{"hours" (hours since midnight of the episode's first day, the step's clock time;
        24 and more on the next day), "price_eur_kwh", "grid_kw", "port_kw" (steps, ports), "arrived"
        (steps, ports), "departed" (steps, ports), "battery_soc" (steps, batteries),
        "profit_eur" (steps,), "total_profit_eur"}``; the total equals the day's profit in
        `chargax_marl.benchmark.score` for the same day and draw.
    """
    trace = day_of(make_traces(params, [day], day_keys=key[None]), 0)
    states, infos, final = jax.jit(lambda t, k: replay(act, params, t, k))(trace, key)
    states, infos, final = jax.device_get((states, infos, final))
    ports = int(params.station.num_ports)
    hours = float(params.step_hours)
    occupied = np.asarray(states.occupied)[:, :ports]
    after = np.concatenate([occupied[1:], np.zeros_like(occupied[:1])])
    arrived = np.asarray(infos.leaf_arrived)[:, :ports]
    return {
        "hours": params.episode_start_hour + np.arange(occupied.shape[0]) * hours,
        "price_eur_kwh": np.asarray(infos.price_buy_eur_kwh),
        "grid_kw": np.asarray(infos.grid_net_kwh) / hours,
        "port_kw": np.asarray(infos.leaf_energy_kwh)[:, :ports] / hours,
        "arrived": arrived,
        # a car leaves in step t when its port is empty after it, or holds the next car
        "departed": occupied & (~after | arrived),
        "battery_soc": np.asarray(states.soc)[:, ports:],
        "profit_eur": np.asarray(infos.profit_eur, np.float64),
        "total_profit_eur": float(final.totals.profit_eur),
    }


def day_picture(
    policy: Callable,
    task: str | Task,
    *,
    day_index: int = 0,
    draw: int = 0,
    kind: str = "core",
    num_levels: int | None = None,
    reference: str = "always_max",
    label: str = "policy",
    path: str | Path | None = None,
    references_dir: str | Path | None = None,
):
    """Draw a policy's held-out day of a task beside a reference rule.

    Args:
        policy: a jittable policy of ``kind`` (``"core"``, ``"single"`` or ``"marl"``).
        task: a task id or `Task`.
        day_index: position in the task's held-out days.
        draw: the car draw.
        kind: the policy's kind (`chargax_marl.benchmark.protocol`).
        num_levels: the policy's levels per direction (default: the task's).
        reference: a rule name (`chargax_marl.policies.get_policy`).
        label: the policy's name in the legend.
        path: where to save the figure (PNG), if given.
        references_dir: where the references live (default: the shipped ones; for a task
            read from a task file, the file's folder).

    Returns:
        ``(figure, {"policy": play_day(...), "reference": play_day(...), "bound_eur"})``.

    Raises:
        ValueError: ``day_index`` or ``draw`` outside the task, or a host kind of policy.
    """
    task = get_task(task)
    if not 0 <= day_index < task.num_eval_days or not 0 <= draw < task.draws:
        raise ValueError(
            f"day_index must lie in [0, {task.num_eval_days - 1}] and draw in "
            f"[0, {task.draws - 1}] for {task.id}, got {day_index!r} and {draw!r}"
        )
    params = task.policy_params(num_levels)
    base = task.make_params()
    day = int(task.eval_days()[day_index])
    key = task.day_keys()[day_index, draw]
    mine = play_day(protocol.as_core(policy, kind, params), params, day, key)
    ref_policy = get_policy(reference, base)
    ref = play_day(lambda s, k: ref_policy(s, k, base), base, day, key)
    bound = float(
        load_references(task, references_dir)["policies"][BOUND]["daily_profit"][day_index, draw]
    )

    fig = Figure(figsize=(10, 12), layout="constrained")
    # the heat map's colour bar in a column of its own, so that every panel keeps the width
    # of the shared hour axis
    grid = fig.add_gridspec(5, 2, width_ratios=(1, 0.015))
    axes = [fig.add_subplot(grid[0, 0])]
    axes += [fig.add_subplot(grid[i, 0], sharex=axes[0]) for i in range(1, 5)]
    for ax in axes[:-1]:
        ax.tick_params(labelbottom=False)
    h = mine["hours"]
    axes[0].step(h, mine["price_eur_kwh"], where="post", color="k")
    axes[0].set_ylabel("buy price\nEUR/kWh")
    axes[1].plot(h, mine["grid_kw"], label=label)
    axes[1].plot(h, ref["grid_kw"], label=reference, alpha=0.7)
    limit_kw = float(base.station.node_max_kw[0])
    axes[1].axhline(limit_kw, color="r", ls="--", lw=1, label="connection limit")
    axes[1].axhline(-limit_kw, color="r", ls="--", lw=1)
    axes[1].set_ylabel("grid draw, kW")
    axes[1].legend(loc="upper left", fontsize=8)
    ports = mine["port_kw"].shape[1]
    image = axes[2].imshow(
        mine["port_kw"].T,
        aspect="auto",
        origin="lower",
        cmap="coolwarm",
        extent=(h[0], h[-1] + (h[1] - h[0]), -0.5, ports - 0.5),
        vmin=-np.abs(mine["port_kw"]).max() - 1e-6,
        vmax=np.abs(mine["port_kw"]).max() + 1e-6,
    )
    for marks, style in ((mine["arrived"], "k^"), (mine["departed"], "kv")):
        t, p = np.nonzero(marks)
        axes[2].plot(h[t], p, style, ms=3)
    axes[2].set_ylabel(f"{label}:\nport (▲ arrives, ▼ leaves)")
    fig.colorbar(image, cax=fig.add_subplot(grid[2, 1]), label="kW")
    if mine["battery_soc"].shape[1]:
        axes[3].plot(h, mine["battery_soc"].mean(axis=1), label=label)
        axes[3].plot(h, ref["battery_soc"].mean(axis=1), label=reference, alpha=0.7)
        axes[3].legend(loc="upper left", fontsize=8)
    axes[3].set_ylabel("battery SoC")
    axes[4].plot(h, np.cumsum(mine["profit_eur"]), label=f"{label}: {mine['total_profit_eur']:.1f}")
    axes[4].plot(
        h, np.cumsum(ref["profit_eur"]), label=f"{reference}: {ref['total_profit_eur']:.1f}"
    )
    # the task's bound: over always-max's occupancy (v1; a policy that seats other cars can
    # pass it) or port-pooled (v2)
    axes[4].axhline(
        bound, color="g", ls=":", label=f"LP bound, {task.bound} (day total): {bound:.1f}"
    )
    axes[4].set_ylabel("cumulative\nprofit, EUR")
    axes[4].set_xlabel("hour of the day")
    clock_axis(axes[4], base)
    axes[4].legend(loc="upper left", fontsize=8)
    fig.suptitle(f"{task.id}, held-out day {day} (draw {draw}): {label} and {reference}")
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=90)
    return fig, {"policy": mine, "reference": ref, "bound_eur": bound}
