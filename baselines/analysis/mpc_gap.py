"""``python -m baselines.analysis.mpc_gap``: where the MPC stays below a task's exact bound.

On the first held-out days of a task (draw 0, the cars of the task's key schedule) it plays
always-max, the coupled plan and the MPC at several deadline margins, solves the occupancy
bound, and reports per policy the profit and the energy put into cars (for the bound, the
energy of its LP plan), each per day. On a version-3 task the bound is exact, so the energy
the MPC leaves undelivered against the bound's plan is headroom a policy can reach; a larger
deadline margin (each car planned to be done that many steps before it leaves) shows how much
of it comes from charging deferred into hours that cars arriving later, unseen by the MPC,
then compete for.

    python -m baselines.analysis.mpc_gap --task Chargax-shopping-grid10-high-v3 --days 6 \\
        --margins 1,4 --out results/optimal/mpc_gap_grid10_v3.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from chargax_marl import trace as trace_lib
from chargax_marl.benchmark import get_task
from chargax_marl.core import checks
from chargax_marl.evaluation import run_days_keyed
from chargax_marl.optimal import bound as bound_lib
from chargax_marl.optimal.mpc import MPC
from chargax_marl.policies import always_max, get_policy


def bound_energy(params, traces, keys) -> tuple[list[float], list[float]]:
    """The occupancy bound of each day and the energy its LP plan puts into the cars.

    Args:
        params: the environment parameters.
        traces: the days' traces (`chargax_marl.trace.make_traces`).
        keys: ``(days, 2)`` the days' keys.

    Returns:
        ``(energy_kwh, profit_eur)``: per day, the net energy into the cars of the bound's plan
        (kWh) and the bound (EUR).
    """
    energy, profit = [], []
    for i in range(len(keys)):
        day = trace_lib.day_of(traces, i)
        occ = bound_lib.occupancy(params, day, keys[i])
        solved = bound_lib.hindsight_bound(params, day, occ)
        cars = occ.sessions
        soc_end = solved.solution.soc_end[: len(cars.leaf)]
        energy.append(float(np.sum((soc_end - cars.soc0) * cars.capacity_kwh)))
        profit.append(float(solved.profit_eur))
    return energy, profit


def measure(task_id: str, num_days: int, margins: tuple[int, ...]) -> dict:
    """Profit and energy into cars per day of the bound, always-max, the coupled plan and the
    MPC at each deadline margin, on the task's first ``num_days`` held-out days, draw 0.

    Args:
        task_id: a task id.
        num_days: how many of the task's held-out days, from the first.
        margins: the MPC's ``deadline_margin_steps`` to play (1 is its default).

    Returns:
        ``{"task", "days", "policies": {name: {"energy_kwh": [...], "profit_eur": [...]}}}``.
    """
    task = get_task(task_id)
    params = task.make_params()
    days = task.eval_days()[:num_days]
    keys = task.day_keys()[:num_days, 0]
    traces = trace_lib.make_traces(params, days, day_keys=keys)
    energy, profit = bound_energy(params, traces, keys)
    out = {"lp_bound": {"energy_kwh": energy, "profit_eur": profit}}
    coupled = get_policy("coupled_plan", params)
    players = {
        "always_max": lambda s, k: always_max(s, k, params),
        "coupled_plan": lambda s, k: coupled(s, k, params),
    }
    for margin in margins:
        mpc = MPC(params, deadline_margin_steps=margin)
        players[f"mpc_margin{margin}"] = (lambda m: lambda s, k: m(s, k, params))(mpc)
    for name, act in players.items():
        totals = run_days_keyed(act, params, days, keys)
        out[name] = {
            "energy_kwh": np.asarray(totals.energy_delivered_kwh, np.float64).tolist(),
            "profit_eur": np.asarray(totals.profit_eur, np.float64).tolist(),
        }
    return {"task": task.id, "days": [int(d) for d in days], "draw": 0, "policies": out}


def table(result: dict) -> str:
    """The means per day over the measured days, over always-max.

    Args:
        result: a `measure` result.

    Returns:
        A Markdown table: per policy, the energy into cars and the profit, both over
        always-max's (kWh/day, EUR/day).
    """
    pol = result["policies"]
    base_e = np.mean(pol["always_max"]["energy_kwh"])
    base_p = np.mean(pol["always_max"]["profit_eur"])
    lines = ["| policy | energy into cars over always-max, kWh/day | EUR/day over always-max |"]
    lines.append("|---|---|---|")
    for name, v in pol.items():
        lines.append(
            f"| {name} | {np.mean(v['energy_kwh']) - base_e:+.1f} "
            f"| {np.mean(v['profit_eur']) - base_p:+.2f} |"
        )
    return "\n".join(lines)


def main(argv=None) -> dict:
    """The command line: measure, print the table, write the result.

    Args:
        argv: the arguments (None: ``sys.argv[1:]``); ``--help`` lists them.

    Returns:
        The `measure` result.
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="Chargax-shopping-grid10-high-v3", help="a task id")
    parser.add_argument("--days", type=int, default=6, help="held-out days, from the first")
    parser.add_argument("--margins", default="1,4", help="the MPC's deadline margins (steps)")
    parser.add_argument(
        "--out",
        default=None,
        type=checks.output_option("file"),
        help="write the result (JSON) here",
    )
    args = parser.parse_args(argv)
    if args.days < 1:
        parser.error(f"--days must be at least 1, got {args.days}")
    try:
        margins = tuple(int(m) for m in args.margins.split(","))
    except ValueError:
        parser.error(f"--margins must be integers separated by commas, got {args.margins!r}")
    result = measure(args.task, args.days, margins)
    print(table(result))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
