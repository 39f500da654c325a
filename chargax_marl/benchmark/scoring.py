"""Scores: the fraction of a task's hindsight headroom a policy captures.

For a task with held-out days ``d`` and draws ``r``, a policy's per-day profit ``p_d`` is its
mean over the draws, and::

    score = mean_d(p_d - a_d) / mean_d(b_d - a_d)

with ``a`` always-max's and ``b`` the LP hindsight bound's per-day profits on the same cars
(shipped, `chargax_marl.benchmark.references`): 0 is always-max, 1 the bound, negative
worse than always-max. Its standard error is over days (the days are the independent units;
the draws of one day share its prices). Days where the bound's solve failed are left out.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from chargax_marl.benchmark import protocol
from chargax_marl.benchmark.references import BOUND, ZERO, load_references, secondary_metrics
from chargax_marl.benchmark.tasks import Task, get_task


def _per_day(task: Task, daily_profit) -> np.ndarray:
    """``daily_profit`` ``(..., days, draws)`` (or ``(..., days)`` for a one-draw task) as the
    per-day means over draws ``(..., days)``, its shape checked against the task."""
    p = np.asarray(daily_profit, np.float64)
    days, draws = task.num_eval_days, task.draws
    if p.ndim >= 2 and p.shape[-2:] == (days, draws):
        return p.mean(axis=-1)
    if draws == 1 and p.ndim >= 1 and p.shape[-1] == days:
        return p
    raise ValueError(
        f"daily_profit of shape {p.shape} does not fit task {task.id!r}: it needs trailing axes "
        f"(days={days}, draws={draws}), one profit per held-out day and car draw "
        "(Task.eval_days(), Task.day_keys())"
    )


def _mean_stderr(x: np.ndarray) -> dict:
    x = np.asarray(x, np.float64)
    se = float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else float("nan")
    return {"mean": float(x.mean()), "stderr": se}


def _refs_per_day(task: Task, directory=None) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray]:
    refs = load_references(task, directory)
    zero = refs["policies"][ZERO]["daily_profit"].mean(axis=1)
    bound = refs["policies"][BOUND]["daily_profit"]
    keep = np.isfinite(bound).all(axis=1)
    return refs, zero, bound.mean(axis=1), keep


def get_normalized_score(task_id: str | Task, daily_profit, references_dir=None) -> np.ndarray:
    """The score of per-day profits on a task (D4RL's ``get_normalized_score`` for this
    benchmark): the fraction of the hindsight headroom captured.

    Args:
        task_id: a task id (`chargax_marl.benchmark.TASKS`), a task file's path
            (`chargax_marl.benchmark.tasks.load_task`) or `Task`.
        daily_profit: EUR per held-out day and draw, ``(..., days, draws)`` (leading axes,
            e.g. seeds, are kept), in the order of ``Task.eval_days()`` and the draws of
            ``Task.day_keys()``; ``(..., days)`` also for a one-draw task.
        references_dir: where the references live (default: the shipped ones; for a task
            read from a task file, the file's folder).

    Returns:
        The score, a float64 array of the leading shape (a 0-d array for one policy).

    Raises:
        KeyError: an unknown task.
        ValueError: a profit array whose shape does not fit the task's days and draws, or
            references that do not belong to the task on this code.
    """
    task = get_task(task_id)
    per_day = _per_day(task, daily_profit)
    _, zero, bound, keep = _refs_per_day(task, references_dir)
    headroom = float((bound - zero)[keep].mean())
    return (per_day[..., keep] - zero[keep]).mean(axis=-1) / headroom


def compare(task_id: str | Task, daily_profit, references_dir=None) -> dict:
    """A policy's per-day profits set against a task's references.

    Args:
        task_id: a task id, a task file's path or `Task`.
        daily_profit: ``(days, draws)`` or ``(seeds, days, draws)`` EUR (see
            `get_normalized_score`).
        references_dir: where the references live (default: the shipped ones; for a task
            read from a task file, the file's folder).

    Returns:
        ``score`` and ``score_stderr`` (over days, of the per-day mean over seeds and draws),
        ``per_seed_score`` (with seeds), ``over_always_max_eur`` and ``vs`` (``{reference:
        {"mean", "stderr"}}``, EUR/day, paired over days), ``profit_ratio_to_always_max``
        (the reference-free ratio of mean profits), ``eur_per_day``, ``days_scored``.
    """
    task = get_task(task_id)
    per_day = np.atleast_2d(_per_day(task, daily_profit))
    refs, zero, bound, keep = _refs_per_day(task, references_dir)
    headroom = float((bound - zero)[keep].mean())
    # days a policy has no profit for (an MPC reference's failed solves) are left out
    keep = keep & np.isfinite(per_day).all(axis=0)
    mine = per_day[:, keep].mean(axis=0)
    captured = _mean_stderr(mine - zero[keep])
    zero_mean = float(zero[keep].mean())
    vs = {}
    for name, entry in refs["policies"].items():
        other = entry["daily_profit"].mean(axis=1)[keep]
        both = np.isfinite(other)  # a reference's failed days drop out of its comparison
        vs[name] = _mean_stderr(mine[both] - other[both])
    return {
        "task": task.id,
        "score": captured["mean"] / headroom,
        "score_stderr": captured["stderr"] / headroom,
        "per_seed_score": [float(x) for x in (per_day[:, keep] - zero[keep]).mean(1) / headroom],
        "eur_per_day": float(mine.mean()),
        "over_always_max_eur": captured,
        "headroom_eur": headroom,
        "profit_ratio_to_always_max": float(mine.mean() / zero_mean) if zero_mean else np.nan,
        "vs": vs,
        "days_scored": int(keep.sum()),
        "draws": task.draws,
    }


def score(
    policy: Callable,
    task_id: str | Task,
    *,
    kind: str = "core",
    num_levels: int | None = None,
    references_dir=None,
) -> dict:
    """Play a policy on a task's held-out days and draws and score it.

    Args:
        policy: a policy of ``kind`` (`chargax_marl.benchmark.protocol`): ``"core"``
            ``policy(state, key, params) -> levels``; ``"single"`` ``act(obs, key) ->
            action``; ``"marl"`` ``act(obs_dict, key) -> action_dict``; ``"gymnasium"``
            ``act(obs) -> action`` and ``"pettingzoo"`` ``act(obs_dict) -> action_dict`` on
            numpy (host loops, slower).
        task_id: a task id, a task file's path or `Task`.
        kind: the policy's kind.
        num_levels: levels per direction of the policy's action space, where it was trained
            with fewer than the task's (``ENV_KWARGS = { num_levels = 1 }``: discharge,
            idle, charge at full power); default the task's (`Task.policy_params`).
        references_dir: where the references live (default: the shipped ones; for a task
            read from a task file, the file's folder).

    Returns:
        `compare`'s result, plus ``daily_profit`` (``(days, draws)`` array),
        ``metrics`` (the secondary metrics, means over days and draws: energy delivered, kWh
        missing at departure, cars rejected, overtime, peak grid draw, battery wear) and
        ``wall_s``.

    Raises:
        KeyError: an unknown task.
        ValueError: an unknown kind, an action that does not fit the task's action space, or
            references that do not belong to the task on this code.
    """
    task = get_task(task_id)
    load_references(task, references_dir)  # refuse stale references before playing
    params = task.policy_params(num_levels)
    t0 = time.perf_counter()
    totals = protocol.play(policy, params, task.eval_days(), task.day_keys(), kind=kind)
    wall_s = time.perf_counter() - t0
    daily = np.asarray(totals.profit_eur, np.float64)
    return {
        **compare(task, daily, references_dir),
        "daily_profit": daily,
        "metrics": secondary_metrics(totals),
        "kind": kind,
        "wall_s": wall_s,
    }
