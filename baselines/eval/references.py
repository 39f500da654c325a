"""The MPC on held-out days, references stored by ``python -m baselines.analysis.references``
read back from a directory the caller names, and a task's shipped LP bound read back where a
run's held-out evaluation is the task's."""

from __future__ import annotations

import json
import time
from pathlib import Path

import jax
import numpy as np

from chargax_marl.benchmark.references import ReferenceMismatchError, load_references
from chargax_marl.benchmark.tasks import get_task
from chargax_marl.evaluation import bound_kind, run_days, summarize
from chargax_marl.optimal.mpc import MPC
from chargax_marl.trace import params_fingerprint


def evaluate_mpc(params, days, key=None, **mpc_kwargs) -> dict:
    """The MPC on ``days`` with the evaluation's cars; per-day profits, metrics and timing.

    A day on which any of the MPC's solves failed or hit its time limit is not scored: its
    ``daily_profit`` is NaN, it is left out of ``metrics`` (``days_failed``) and listed in
    ``failed_days`` with the steps and solver statuses of its failed solves
    (`chargax_marl.optimal.mpc.MPC.failed_solves`).

    Args:
        params: the env parameters.
        days: the day indices to play.
        key: the evaluation key; ``None`` is ``PRNGKey(0)``.
        **mpc_kwargs: keyword arguments of `chargax_marl.optimal.mpc.MPC`.

    Returns:
        ``{"daily_profit", "metrics", "failed_days", "wall_s", "solves", "failures",
        "warm_retries", "solve_s_total", "ms_per_step", "settings"}``.
    """
    key = jax.random.PRNGKey(0) if key is None else key
    mpc = MPC(params, **mpc_kwargs)
    t0 = time.perf_counter()
    totals = jax.jit(lambda d, k: run_days(lambda s, kk: mpc(s, kk, params), params, d, k))(
        np.asarray(days), key
    )
    wall = time.perf_counter() - t0
    steps = int(np.size(days)) * params.num_steps
    day_list = [int(d) for d in np.asarray(days).reshape(-1)]
    failed = np.array([d in mpc.failed_solves for d in day_list], bool)
    return {
        "daily_profit": np.where(failed, np.nan, np.asarray(totals.profit_eur, np.float64)),
        "metrics": summarize(totals, failed=failed),
        "failed_days": [
            {
                "day": d,
                "steps": [t for t, _ in mpc.failed_solves[d]],
                "status": [s for _, s in mpc.failed_solves[d]],
            }
            for d in sorted(set(day_list) & set(mpc.failed_solves))
        ],
        "wall_s": wall,
        "solves": mpc.solves,
        "failures": mpc.failures,
        "warm_retries": mpc.warm_retries,
        "solve_s_total": mpc.solve_s,
        "ms_per_step": 1000.0 * wall / steps,
        "settings": {
            "horizon_steps": mpc.horizon_steps,
            "resolve_every": mpc.resolve_every,
            "urgency_eur_kwh_h": mpc.urgency_eur_kwh_h,
            "deadline_margin_steps": mpc.deadline_margin_steps,
        },
    }


def cached(params, days, directory: str | Path) -> dict | None:
    """The references stored in ``directory`` for exactly these params and days.

    Args:
        params: the evaluation's env parameters.
        days: the held-out days.
        directory: a directory of ``<scenario>.json`` files written by
            ``python -m baselines.analysis.references``.

    Returns:
        The stored result (per-day profits of the bound, the MPC and the rules), or ``None``
        when no file matches the params' fingerprint and the days.
    """
    fingerprint = params_fingerprint(params)
    for path in sorted(Path(directory).glob("*.json")):
        data = json.loads(path.read_text())
        if data.get("params_fingerprint") == fingerprint and data.get("days") == [
            int(d) for d in days
        ]:
            return data
    return None


def stored_mpc(stored: dict | None, days) -> np.ndarray | None:
    """The MPC's per-day profits of a stored result when it ran on every one of ``days``
    (``make optimal --mpc-days N`` stores it for the first N only); else ``None``.

    Args:
        stored: a stored result (`cached`), or ``None``.
        days: the held-out days.

    Returns:
        The MPC's ``(days,)`` float64 daily profits in EUR/day, or ``None`` when there is no
        stored result, it has no MPC, or its MPC covers a different number of days.
    """
    if stored is None or "mpc" not in stored["policies"]:
        return None
    daily = np.asarray(stored["policies"]["mpc"]["daily_profit"], np.float64)
    return daily if daily.shape[0] == len(days) else None


def shipped_bound(task, params, days, draws: int = 1) -> np.ndarray | None:
    """A task's shipped LP bound on a run's held-out days, where it is the bound the run
    would solve (`chargax_marl.evaluation.policy_bound` under ``params``, keys
    ``PRNGKey(0) ... PRNGKey(draws - 1)``).

    That holds when ``days`` are the task's held-out days, ``draws`` at most the task's
    (draw ``r`` of the task's key schedule is the run's key ``r``), the stored bound is of
    the kind ``params`` call for (`chargax_marl.evaluation.bound_kind`) and solved on every
    one of those days and draws, and ``params`` are the task's scored parameters up to the
    policy's action levels (``num_levels``), which the LP, over continuous currents, does not
    read. The task's references must load (`load_references`: this code's parameters).

    Args:
        task: a task id, task file or `chargax_marl.benchmark.Task`.
        params: the run's held-out env parameters.
        days: the run's held-out days.
        draws: the run's car draws per held-out day.

    Returns:
        The ``(days,)`` float64 bound in EUR/day, each day's the mean over draws ``0 ..
        draws - 1``; ``None`` where any condition above fails (the run solves it then).
    """
    task = get_task(task)
    scored = task.make_params()
    if draws > task.draws or [int(d) for d in np.asarray(days)] != [
        int(d) for d in task.eval_days()
    ]:
        return None
    if bound_kind(params) != task.bound:
        return None
    levels = params.replace(num_levels=scored.num_levels)
    if params_fingerprint(levels) != params_fingerprint(scored):
        return None
    try:
        refs = load_references(task)
    except ReferenceMismatchError:
        return None
    bound = refs["policies"].get("lp_bound")
    if bound is None:
        return None
    daily = np.asarray(bound["daily_profit"], np.float64)[:, :draws]
    if np.isnan(daily).any():
        return None
    return daily.mean(axis=1)
