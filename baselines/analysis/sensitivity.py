"""How much one five-minute change moves a day's profit: the noise floor of a scenario.

Every policy meets the same cars on the same held-out days, so the paired difference of two
policies has no sampling noise from the traffic. It still has noise from the policies
themselves: at high traffic every port that frees is taken by the next car that arrives, and
which car that is (one wanting 5 kWh or 80) turns on the step at which a charge-sensitive car
finished. A policy change anywhere in the day can therefore reorder the admissions after it.

This module measures that directly. Always-max is compared, day by day, with always-max plus
one small change at one step: the battery charging at full power for one step, or one port
idling for one step. Where nothing cascades, the difference is a few cents; where admissions
reorder, a day moves by tens of euros. The spread over days sets how large a policy's gain
must be before 100 held-out days can resolve it (the docs' design decisions).

Run: ``python -m baselines.analysis.sensitivity``; writes ``outputs/sensitivity.json``
(`OUT`, or ``--out``; copy it to ``results/`` to commit) and prints the Markdown table.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from chargax_marl.core import checks
from chargax_marl.core.params import make_params
from chargax_marl.core.scenarios import scenario_kwargs
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.evaluation import run_days, split_days

SCENARIO_NAMES = (
    "shopping",
    "shopping-grid25-medium",
    "shopping-grid50-high",
    "shopping-grid25-high",
    "shopping-peak-high",
)
PERTURBATIONS = ("battery_charges", "port_idles")
OUT = Path("outputs/sensitivity.json")  # copy to results/ to commit


def perturbed_always_max(params, perturbation: str, step: int):
    """``act(state, key) -> levels``: always-max for the ports with the batteries idle, except at
    step ``step`` of the day, where the batteries charge at full power (``"battery_charges"``)
    or the first port idles (``"port_idles"``). A step outside the day changes nothing.

    Args:
        params: the env parameters.
        perturbation: one of `PERTURBATIONS`.
        step: the step of the day (from midnight) that is changed.

    Returns:
        ``act(state, key) -> levels``, int32 levels per leaf.

    Raises:
        ValueError: ``perturbation`` is not one of `PERTURBATIONS`.
    """
    if perturbation not in PERTURBATIONS:
        raise ValueError(f"perturbation must be one of {PERTURBATIONS}, got {perturbation!r}")
    is_battery = jnp.asarray(np.asarray(params.station.leaf_kind) == KIND_BATTERY)
    first_port = jnp.arange(is_battery.size) == int(np.argmin(np.asarray(is_battery)))
    changed = is_battery if perturbation == "battery_charges" else first_port
    changed_level = params.num_levels if perturbation == "battery_charges" else 0

    def act(state, key):
        del key
        levels = jnp.where(is_battery, 0, params.num_levels)
        return jnp.where(changed & (state.timestep == step), changed_level, levels).astype(
            jnp.int32
        )

    return act


def daily_totals(act, params, days, key):
    """The day totals of ``act`` on ``days``, jitted (`chargax_marl.evaluation.run_days`).

    Args:
        act: ``act(state, key) -> levels``.
        params: the env parameters.
        days: the day indices.
        key: the key the cars are drawn from.

    Returns:
        The days' `EpisodeTotals`, leaves with a leading axis over ``days``.
    """
    return jax.jit(lambda d, k: run_days(act, params, d, k))(np.asarray(days), key)


def sensitivity(params, days, key=None, step: int | None = None) -> dict:
    """Per perturbation (`PERTURBATIONS`, at ``step``, default 10:00): the day-by-day
    profit difference to the unperturbed policy (``perturbed_always_max`` at a step outside the
    day) and the days on which the served cars differ. ``key`` defaults to ``PRNGKey(0)``.

    Args:
        params: the env parameters.
        days: the day indices.
        key: the key the cars are drawn from; ``None``: ``PRNGKey(0)``.
        step: the changed step of the day; ``None``: the step at 10:00.

    Returns:
        ``{"step", "clock", <perturbation>: {...}}``: ``clock`` the step's time in decimal
        hours, and per perturbation ``daily_difference_eur`` (the per-day list), ``mean``,
        ``std``, ``max_abs`` (EUR/day), ``days_over_1_eur`` (days moved by more than 1 EUR)
        and ``days_served_cars_differ`` (days whose count of served cars differs).
    """
    key = jax.random.PRNGKey(0) if key is None else key
    step = int(round(10 * 60 / float(params.step_minutes))) if step is None else int(step)
    base = daily_totals(perturbed_always_max(params, "battery_charges", -1), params, days, key)
    out = {"step": step, "clock": f"{step * float(params.step_minutes) / 60:05.2f} h"}
    for name in PERTURBATIONS:
        tot = daily_totals(perturbed_always_max(params, name, step), params, days, key)
        d = np.asarray(tot.profit_eur, np.float64) - np.asarray(base.profit_eur, np.float64)
        served = np.asarray(tot.cars_served) != np.asarray(base.cars_served)
        out[name] = {
            "daily_difference_eur": d.tolist(),
            "mean": float(d.mean()),
            "std": float(d.std(ddof=1)),
            "max_abs": float(np.abs(d).max()),
            "days_over_1_eur": int(np.sum(np.abs(d) > 1.0)),
            "days_served_cars_differ": int(served.sum()),
        }
    return out


def main(argv=None) -> dict:
    """The command line: `sensitivity` of every ``--scenarios`` at ``--hour`` on the 100
    held-out days (key 0), the Markdown rows printed and, unless ``--out`` is empty, the
    result written as JSON.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        ``{"days", "key", "hour", "scenarios"}``, per scenario the `sensitivity` result and
        its ``wall_s`` (seconds).
    """
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenarios", nargs="+", default=list(SCENARIO_NAMES))
    p.add_argument(
        "--hour", type=float, default=10.0, help="the hour of the day of the changed step"
    )
    p.add_argument("--out", default=str(OUT), help="the JSON to write (empty: none)")
    a = p.parse_args(argv)
    if a.out:  # checked before the scenarios run
        try:
            checks.output_path("--out", a.out, "file")
        except ValueError as e:
            p.error(str(e))
    _, days = split_days(365, 100, seed=0)
    out = {"days": [int(d) for d in days], "key": 0, "hour": a.hour, "scenarios": {}}
    print(
        "| scenario | change at the step | mean EUR/day | std over days | days moved > 1 EUR | largest move EUR "
        "| days the served-car count differs |"
    )
    print("|---|---|---|---|---|---|---|")
    for name in a.scenarios:
        t0 = time.perf_counter()
        params = make_params(**scenario_kwargs(name))
        row = sensitivity(params, days, step=int(round(a.hour * 60 / float(params.step_minutes))))
        row["wall_s"] = time.perf_counter() - t0
        out["scenarios"][name] = row
        for pert, label in (
            ("battery_charges", "battery charges"),
            ("port_idles", "one port idles"),
        ):
            r = row[pert]
            print(
                f"| `{name}` | {label} | {r['mean']:+.2f} | {r['std']:.2f} | {r['days_over_1_eur']} | "
                f"{r['max_abs']:.1f} | {r['days_served_cars_differ']} |",
                flush=True,
            )
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
