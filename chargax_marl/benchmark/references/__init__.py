"""The references of every task: always-max (score 0), the LP hindsight bound (score 1) and
the strongest rules, per held-out day and car draw, shipped with the package.

Each task's file ``<task id>.json`` in this package's folder holds the per-day-and-draw profits of every
reference with the fingerprint of the parameters and the package version they were computed
on. `load_references` refuses a file whose fingerprint differs from the current code's
parameters for the task. Rebuild with::

    python -m chargax_marl.benchmark.references                 # every task
    python -m chargax_marl.benchmark.references --task Chargax-shopping-v1
    python -m chargax_marl.benchmark.references --task Chargax-shopping-v1 --mpc   # add the MPC
    python -m chargax_marl.benchmark.references --task Chargax-shopping-v1 --refill-bound

A task of one's own, read from a task file (`chargax_marl.benchmark.tasks.load_task`), has its
references built by the same code, into the task file's folder unless ``--out`` says otherwise::

    python -m chargax_marl.benchmark.references --task-file my_task.toml

``--refill-bound`` solves the stored LP bound's failed days again (`refill_bound`) and keeps
every other number as stored.

The MPC references (`MPC_REFERENCES`) solve an LP per step and are added on request to
a stored file of the same parameters; each one's days are shared among ``--processes``
processes (default: one per core).
"""

from __future__ import annotations

import functools
import importlib.metadata
import json
import multiprocessing
import pickle
import re
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import jax
import numpy as np

from chargax_marl.benchmark import protocol
from chargax_marl.benchmark.tasks import TASKS, Task, get_task
from chargax_marl.core import checks
from chargax_marl.evaluation import METRICS, service_metrics
from chargax_marl.optimal import bound_days
from chargax_marl.optimal.model import FIRST_ATTEMPTS
from chargax_marl.optimal.mpc import MPC
from chargax_marl.optimal.pooled import pooled_bound_days
from chargax_marl.policies import get_policy
from chargax_marl.trace import params_fingerprint

REFERENCES_DIR = Path(__file__).parent
"""Where the shipped references live."""

ZERO = "always_max"
"""The reference that scores 0."""

BOUND = "lp_bound"
"""The reference that scores 1: the task's LP bound (`chargax_marl.benchmark.tasks.Task.bound`):
the hindsight bound over always-max's occupancy on the version-1 tasks, the port-pooled bound
over every policy from version 2 on."""

RULES = (
    "always_max",
    "random",
    "battery_rule",
    "edf",
    "battery_programme",
    "plan_programme",
    "grid_programme",
    "coupled_plan",
)
"""The rules computed for every task (`chargax_marl.policies.get_policy` names)."""

MPC_REFERENCES = {"mpc": None, "mpc_levels1": 1}
"""The MPC references by name, with the ``num_levels`` they act in: the task's own action
space (``None``) and the learned agents' (one level: each port off or at full power)."""

SECONDARY = (
    "energy_delivered_kwh",
    "missing_kwh_at_departure",
    "cars_rejected",
    "overtime_min",
    "peak_grid_kw",
    "battery_wear_eur",
)
"""Metrics reported next to a score (`chargax_marl.evaluation.METRICS` names)."""


class ReferenceMismatchError(ValueError):
    """Stored references that do not belong to the task on this code."""


BOUND_CHUNK_DAYS = 5
"""Days per process in a chunk of a port-pooled bound kept in a ``bound_dir``."""


def package_version() -> str:
    """The installed chargax_marl version (``"unknown"`` when not installed).

    Returns:
        The version string from the package metadata, or ``"unknown"``.
    """
    try:
        return importlib.metadata.version("chargax_marl")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def secondary_metrics(totals) -> dict[str, float]:
    """The mean over days and draws of each of `SECONDARY`, of the service metrics
    (`chargax_marl.evaluation.service_metrics`) and of the profit.

    Args:
        totals: `chargax_marl.core.types.EpisodeTotals` with any leading axes.

    Returns:
        ``{metric: mean}``, plus ``daily_profit_eur`` and the service metrics (``None`` for a
        gap no day has).
    """
    out = {"daily_profit_eur": float(np.mean(np.asarray(totals.profit_eur, np.float64)))}
    for name in SECONDARY:
        out[name] = float(np.mean(np.asarray(getattr(totals, METRICS[name]), np.float64)))
    for name, x in service_metrics(totals).items():  # the gap over the days that have one
        out[name] = float(np.nanmean(x)) if np.isfinite(x).any() else None
    return out


def compute_references(
    task: str | Task,
    *,
    rules=RULES,
    bound: bool = True,
    day_index=None,
    time_limit_s: float | None = 60.0,
    reuse_dir: str | Path | None = None,
    log=print,
    processes: int = 1,
    bound_dir: str | Path | None = None,
    bound_chunk_days: int = BOUND_CHUNK_DAYS,
) -> dict:
    """Compute a task's references.

    Args:
        task: a task id, task file (`chargax_marl.benchmark.tasks.get_task`) or `Task`.
        rules: rule names to play (`chargax_marl.policies.get_policy`).
        bound: whether to solve the LP bound (one LP per day and draw).
        day_index: positions in the task's held-out days to compute (default: all); the keys
            stay those of the full schedule, so a subset equals the same rows of the whole.
        time_limit_s: the LP's time limit per day.
        reuse_dir: a directory of ``make optimal`` results (``results/optimal``): where one
            was computed for the same parameters and days with key 0, its LP bound is draw 0's.
        log: called with a line of progress (``None``: silent).
        processes: how many processes solve the port-pooled bound (each a contiguous share
            of the days, every draw; one core each). Its days are independent LPs, so the
            result is the one process's; the occupancy bound starts each day from the day
            before's basis and takes 1.
        bound_dir: where a port-pooled bound keeps its solved days: the days are solved in
            chunks of ``bound_chunk_days`` days per process, each chunk written to this
            directory when solved and read back, not solved again, by a later call for the
            same task and parameters (a stopped build resumes where it stopped).
        bound_chunk_days: with ``bound_dir``, the days of a chunk per process.

    Returns:
        The references as stored (``policies``: ``{name: {"daily_profit", "metrics"}}`` with
        ``daily_profit`` a ``(days, draws)`` list; ``lp_bound`` also has ``status``, per day
        and draw, `bound_status`'s).

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        ValueError: ``processes`` is not an integer >= 1, or is above 1 for a task whose
            bound is not the port-pooled one, or for a `Task` that does not pickle;
            ``bound_dir`` for a task whose bound is not the port-pooled one, or a chunk file
            there of other parameters or days; ``bound_chunk_days`` is not an integer >= 1.
    """
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
    task = get_task(task)
    if bound and bound_dir is not None:
        if task.bound != "pooled":
            raise ValueError(
                f"field 'bound_dir' needs a port-pooled bound; task {task.id!r} has the "
                f"{task.bound} bound, which starts each day from the day before's basis"
            )
        if (
            isinstance(bound_chunk_days, bool)
            or not isinstance(bound_chunk_days, (int, np.integer))
            or bound_chunk_days < 1
        ):
            raise ValueError(
                f"field 'bound_chunk_days' must be an integer >= 1, got {bound_chunk_days!r}"
            )
    shares = _process_shares(
        task, processes, len(task.eval_days()) if day_index is None else np.size(day_index)
    )
    if bound and shares > 1 and task.bound != "pooled":
        raise ValueError(
            f"field 'processes' must be 1 for task {task.id!r}: its {task.bound} bound starts "
            "each day from the day before's basis"
        )
    log = log or (lambda _line: None)
    params = task.make_params()
    days = task.eval_days()
    keys = task.day_keys()
    if day_index is not None:
        days, keys = days[np.asarray(day_index)], keys[np.asarray(day_index)]
    out = {
        "task": task.id,
        "params_fingerprint": params_fingerprint(params),
        "package_version": package_version(),
        "days": [int(d) for d in days],
        "draws": task.draws,
        "policies": {},
        "wall_s": {},
    }
    for name in rules:
        t0 = time.perf_counter()
        totals = protocol.play(get_policy(name, params), params, days, keys)
        out["policies"][name] = {
            "daily_profit": np.asarray(totals.profit_eur, np.float64).tolist(),
            "metrics": secondary_metrics(totals),
        }
        out["wall_s"][name] = round(time.perf_counter() - t0, 2)
        log(f"{task.id} {name}: {out['policies'][name]['metrics']['daily_profit_eur']:.2f} EUR/day")
    if bound:
        t0 = time.perf_counter()
        profit = np.full(keys.shape[:2], np.nan)
        status = np.full(keys.shape[:2], "", dtype=object)
        stored = None if day_index is not None else _stored_bound(params, days, reuse_dir)
        positions = np.arange(len(task.eval_days()))
        positions = positions if day_index is None else positions[np.asarray(day_index)]
        if bound_dir is not None:
            profit, status = _bound_in_chunks(
                task, positions, shares, bound_chunk_days, Path(bound_dir), time_limit_s, log
            )
            log(f"{task.id} {BOUND}: {len(positions)} days in {time.perf_counter() - t0:.0f} s")
        elif shares > 1:
            parts = _in_processes(
                _pooled_part, task, np.array_split(positions, shares), time_limit_s
            )
            profit = np.concatenate([p[0] for p in parts])
            status = np.concatenate([p[1] for p in parts])
            log(f"{task.id} {BOUND}: {shares} processes in {time.perf_counter() - t0:.0f} s")
        for r in range(task.draws if shares == 1 and bound_dir is None else 0):
            if r == 0 and stored is not None and task.bound == "occupancy":
                profit[:, 0], status[:, 0] = stored, "optimal (make optimal)"
                log(f"{task.id} {BOUND}: draw 1 from {reuse_dir}")
                continue
            profit[:, r], status[:, r] = _bound_draw(
                task.bound, params, days, keys[:, r], time_limit_s
            )
            log(f"{task.id} {BOUND}: draw {r + 1}/{task.draws} in {time.perf_counter() - t0:.0f} s")
        out["policies"][BOUND] = {
            "daily_profit": [[None if np.isnan(x) else float(x) for x in row] for row in profit],
            "status": status.tolist(),
            "kind": task.bound,
        }
        out["wall_s"][BOUND] = round(time.perf_counter() - t0, 2)
    return out


def _process_shares(task: Task, processes, num_days: int) -> int:
    """How many processes share ``num_days`` days of ``task`` (at most one per day).

    Raises:
        ValueError: ``processes`` is not an integer >= 1.
    """
    if isinstance(processes, bool) or not isinstance(processes, (int, np.integer)) or processes < 1:
        raise ValueError(f"field 'processes' must be an integer >= 1, got {processes!r}")
    return max(1, min(int(processes), int(num_days)))


def _in_processes(part, task: Task, shares: list, *args) -> list:
    """``part(task, share, *args)`` for each share of days, each in its own spawned process
    (a registered task is sent by its id).

    Raises:
        ValueError: ``task`` is not registered and does not pickle.
    """
    which = task.id if TASKS.get(task.id) is task else task
    try:
        pickle.dumps(which)
    except Exception as exc:
        raise ValueError(
            f"field 'processes' must be 1 for task {task.id!r}: it is not registered and does "
            f"not pickle ({type(exc).__name__}: {exc}), so other processes cannot receive it"
        ) from exc
    # spawned, not forked: the parent's JAX runtime and threads do not survive a fork
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(len(shares), mp_context=context) as pool:
        return list(
            pool.map(part, [which] * len(shares), shares, *([a] * len(shares) for a in args))
        )


def _bound_in_chunks(
    task: Task, positions, shares: int, chunk_days: int, directory: Path, time_limit_s, log
) -> tuple[np.ndarray, np.ndarray]:
    """The port-pooled bound of the held-out days at ``positions``, chunk by chunk: a chunk
    (``chunk_days`` days per process) is read from ``directory`` where an earlier call
    solved it, else solved (in ``shares`` processes) and written there at once.

    Returns:
        ``(profit, status)``, each ``(days, draws)``.

    Raises:
        ValueError: a chunk file of other parameters, days or draws.
    """
    directory.mkdir(parents=True, exist_ok=True)
    fingerprint = params_fingerprint(task.make_params())
    all_days = task.eval_days()
    profit, status = [], []
    step = chunk_days * shares
    for start in range(0, len(positions), step):
        chunk = np.asarray(positions[start : start + step])
        days = [int(d) for d in all_days[chunk]]
        path = directory / f"{task.id}.bound.{int(chunk[0]):03d}-{int(chunk[-1]):03d}.json"
        if path.exists():
            stored = json.loads(path.read_text())
            if (stored["params_fingerprint"], stored["days"], stored["draws"]) != (
                fingerprint,
                days,
                task.draws,
            ):
                raise ValueError(
                    f"field 'bound_dir': {path} holds another bound (its parameters, days or "
                    "draws differ from the task's); remove it or choose another directory"
                )
            part = (
                np.array(stored["daily_profit"], np.float64),
                np.array(stored["status"], dtype=object),
            )
        else:
            if shares > 1:
                parts = _in_processes(
                    _pooled_part, task, np.array_split(chunk, shares), time_limit_s
                )
                part = (
                    np.concatenate([p[0] for p in parts]),
                    np.concatenate([p[1] for p in parts]),
                )
            else:
                part = _pooled_part(task, chunk, time_limit_s)
            record = {
                "task": task.id,
                "params_fingerprint": fingerprint,
                "days": days,
                "draws": task.draws,
                "daily_profit": [
                    [None if np.isnan(x) else float(x) for x in row] for row in part[0]
                ],
                "status": part[1].tolist(),
            }
            tmp = path.with_suffix(".tmp")
            tmp.write_text(json.dumps(record))
            tmp.replace(path)  # a chunk file is whole or absent
            log(f"{task.id} {BOUND}: days {int(chunk[0])}-{int(chunk[-1])} written to {path}")
        profit.append(np.asarray(part[0], np.float64))
        status.append(np.asarray(part[1], dtype=object))
    return np.concatenate(profit), np.concatenate(status)


def _pooled_part(task: str | Task, day_index: np.ndarray, time_limit_s) -> tuple:
    """The port-pooled bound of some of a task's held-out days (positions ``day_index``),
    every draw: ``(profit, status)``, each ``(days, draws)``. Module-level, so that
    `compute_references` can run it in another process."""
    task = get_task(task)
    params = task.make_params()
    days, keys = task.eval_days()[day_index], task.day_keys()[day_index]
    out = [_bound_draw("pooled", params, days, keys[:, r], time_limit_s) for r in range(task.draws)]
    return np.stack([o[0] for o in out], axis=1), np.stack([o[1] for o in out], axis=1)


def bound_status(b) -> str:
    """The status a reference file stores for a day's bound: the solver's, and in brackets
    the retry's settings where a retry solved it (e.g. ``"optimal (primal simplex)"``).

    Args:
        b: the day's `chargax_marl.optimal.Bound`.

    Returns:
        The status to store.
    """
    return b.status if not b.solved or b.attempt in FIRST_ATTEMPTS else f"{b.status} ({b.attempt})"


def _bound_draw(kind, params, days, day_keys, time_limit_s) -> tuple[np.ndarray, np.ndarray]:
    """The LP bound of kind ``kind`` (`chargax_marl.benchmark.tasks.BOUNDS`) of one draw on
    every one of ``days`` (keys ``day_keys``, one per day): the profits (NaN where the solve
    failed) and the statuses (`bound_status`). The occupancy bound warm-starts each day from
    the day before (`bound_days`)."""
    if kind == "pooled":
        bounds = pooled_bound_days(params, days, day_keys, time_limit_s=time_limit_s)
    else:
        bounds = bound_days(
            params,
            days,
            day_keys=day_keys,
            reference=get_policy(ZERO, params),
            time_limit_s=time_limit_s,
        )
    return (
        np.array([b.profit_eur for b in bounds], np.float64),
        np.array([bound_status(b) for b in bounds], dtype=object),
    )


def refill_bound(
    task: str | Task,
    directory: str | Path | None = None,
    *,
    time_limit_s: float | None = 60.0,
    log=print,
) -> Path:
    """Solve a task's stored LP bound again where it failed, and write the file back.

    Each draw with a failed day is solved again whole, with `compute_references`' code,
    so that every day starts from the basis a full rebuild gives it: a refilled day is the
    full rebuild's. Only the failed days change; every other number stays as stored (the
    log gives the largest difference of the days solved again to the stored ones).

    Args:
        task: a task id or `Task`.
        directory: where the files live (default: `default_references_dir`).
        time_limit_s: the LP's time limit per day and attempt.
        log: called with a line of progress (``None``: silent).

    Returns:
        The path of the task's file (left as it is when no day failed).

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        ReferenceMismatchError: no stored file for the task, one of other parameters, or
            one without an LP bound.
    """
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
    task = get_task(task)
    directory = reference_path(task, directory).parent  # written back where it was read
    log = log or (lambda _line: None)
    refs = load_references(task, directory)  # checks the file belongs to the task on this code
    stored = json.loads(reference_path(task, directory).read_text())
    if BOUND not in stored["policies"]:
        raise ReferenceMismatchError(
            f"{reference_path(task, directory)} holds no LP bound ({BOUND!r}; it holds "
            f"{sorted(stored['policies'])}): there is nothing to refill. Build the bound whole "
            f"(python -m chargax_marl.benchmark.references --task {task.id}, without --no-bound)"
        )
    profit = refs["policies"][BOUND]["daily_profit"]
    params, days, keys = task.make_params(), np.asarray(refs["days"]), task.day_keys()
    entry = stored["policies"][BOUND]
    draws = np.nonzero(np.isnan(profit).any(axis=0))[0]
    if draws.size == 0:
        log(f"{task.id} {BOUND}: no failed day")
        return reference_path(task, directory)
    for r in draws:
        t0 = time.perf_counter()
        new_profit, new_status = _bound_draw(task.bound, params, days, keys[:, r], time_limit_s)
        failed = np.isnan(profit[:, r])
        for i in np.nonzero(failed)[0]:
            x = new_profit[i]
            entry["daily_profit"][i][r] = None if np.isnan(x) else float(x)
            entry["status"][i][r] = new_status[i]
            log(f"{task.id} {BOUND}: day {int(days[i])} draw {r + 1}: {new_status[i]}")
        kept = ~failed & ~np.isnan(new_profit)
        moved = np.max(np.abs(new_profit[kept] - profit[kept, r]), initial=0.0)
        log(
            f"{task.id} {BOUND}: draw {r + 1} solved again in {time.perf_counter() - t0:.0f} s; "
            f"the other days within {moved:.2g} EUR of the stored ones"
        )
    _read.cache_clear()
    return save_references(stored, directory)


def _mpc_params(task: Task, num_levels: int | None):
    """The params an MPC reference acts in: the task's own (``None``) or ``num_levels``'."""
    return task.make_params() if num_levels is None else task.policy_params(num_levels)


def _mpc_part(task: str | Task, day_index: np.ndarray, num_levels: int | None) -> tuple:
    """The MPC on some of a task's held-out days (positions ``day_index``), every draw: its
    totals (numpy leaves, ``(days, draws)``), the days with a failed solve, the number of
    solves and the solves a retry solved by its settings (`MPC.retried_solves`).
    Module-level, so that `compute_mpc` can run it in another process."""
    task = get_task(task)
    params = _mpc_params(task, num_levels)
    controller = MPC(params)
    totals = protocol.play(
        controller, params, task.eval_days()[day_index], task.day_keys()[day_index]
    )
    return (
        totals,
        sorted(int(d) for d in controller.failed_solves),
        int(controller.solves),
        dict(controller.retried_solves),
    )


def compute_mpc(
    task: str | Task, num_levels: int | None = None, *, day_index=None, processes: int = 1
) -> dict:
    """The MPC (`chargax_marl.optimal.mpc.MPC`, default settings) on a task's held-out
    days and car draws.

    The MPC starts each solve from the basis of the same env's previous one (the env: a day
    and a car draw), so an env's decisions do not depend on the envs beside it: split over
    processes by day, the reference is the one a single process computes, number for
    number.

    Args:
        task: a task id or `Task` (a `Task` that is not registered must pickle for
            ``processes > 1``).
        num_levels: the action space it acts in (``None``: the task's own; see
            `Task.policy_params`).
        day_index: positions in the task's held-out days to play (default: all).
        processes: how many processes play the days (each takes a contiguous share of
            them, every draw of a day in the same process); one core each.

    Returns:
        The reference as stored: ``daily_profit`` (a ``(days, draws)`` list, ``None`` on a day
        where a solve failed: a day with a failed solve is not the MPC's result), ``metrics``
        (over every day played), ``failed_days``, ``solves``, ``retried_solves`` (the solves
        that a retry with other settings solved, by those settings) and ``num_levels``.

    Raises:
        ValueError: ``processes`` is not a whole number >= 1, or is above 1 for a `Task` that
            does not pickle.
    """
    task = get_task(task)
    positions = np.arange(len(task.eval_days())) if day_index is None else np.asarray(day_index)
    positions = positions.reshape(-1)
    shares = np.array_split(positions, _process_shares(task, processes, positions.size))
    if len(shares) == 1:
        parts = [_mpc_part(task, shares[0], num_levels)]
    else:
        parts = _in_processes(_mpc_part, task, shares, num_levels)
    totals = jax.tree.map(lambda *xs: np.concatenate(xs), *[p[0] for p in parts])
    failed = sorted(set().union(*(p[1] for p in parts)))
    profit = np.asarray(totals.profit_eur, np.float64)
    profit[np.isin(task.eval_days()[positions], failed)] = np.nan
    return {
        "daily_profit": [[None if np.isnan(x) else float(x) for x in row] for row in profit],
        "metrics": secondary_metrics(totals),
        "failed_days": failed,
        "solves": sum(p[2] for p in parts),
        "retried_solves": {
            name: sum(p[3].get(name, 0) for p in parts)
            for name in sorted(set().union(*(p[3] for p in parts)))
        },
        "num_levels": int(_mpc_params(task, num_levels).num_levels),
    }


def add_mpc(
    task: str | Task,
    directory: str | Path | None = None,
    log=print,
    names=None,
    processes: int = 1,
) -> Path:
    """Add `MPC_REFERENCES` (or those of them named in ``names``) to a task's stored
    references and write them back; the others stay as stored.

    Args:
        task: a task id or `Task`.
        directory: where the files live (default: `default_references_dir`).
        log: called with a line of progress (``None``: silent).
        names: the `MPC_REFERENCES` to compute (default: all).
        processes: how many processes play each reference's days (`compute_mpc`).

    Returns:
        The path written.

    Raises:
        ReferenceMismatchError: no stored file for the task, or one of other parameters.
        ValueError: a name that is not one of `MPC_REFERENCES`.
    """
    names = list(MPC_REFERENCES) if names is None else list(names)
    unknown = [n for n in names if n not in MPC_REFERENCES]
    if unknown:
        raise ValueError(f"field 'names' must name {list(MPC_REFERENCES)}, got {unknown}")
    task = get_task(task)
    directory = reference_path(task, directory).parent  # written back where it was read
    log = log or (lambda _line: None)
    load_references(task, directory)  # checks the file belongs to the task on this code
    refs = json.loads(reference_path(task, directory).read_text())
    for name in names:
        t0 = time.perf_counter()
        refs["policies"][name] = compute_mpc(task, MPC_REFERENCES[name], processes=processes)
        refs["wall_s"][name] = round(time.perf_counter() - t0, 2)
        mean = refs["policies"][name]["metrics"]["daily_profit_eur"]
        log(f"{task.id} {name}: {mean:.2f} EUR/day in {refs['wall_s'][name]:.0f} s")
    _read.cache_clear()
    return save_references(refs, directory)


def _stored_bound(params, days, directory) -> np.ndarray | None:
    """Draw 0's LP bound from ``make optimal``'s results in ``directory``, if one of them was
    computed for these parameters and days (with key 0, the schedule's draw 0)."""
    if directory is None:
        return None
    fingerprint = params_fingerprint(params)
    for path in sorted(Path(directory).glob("*.json")):
        data = json.loads(path.read_text())
        if (
            data.get("params_fingerprint") == fingerprint
            and data.get("days") == [int(d) for d in days]
            and data.get("key", "PRNGKey(0)") in ("PRNGKey(0)", 0)
            and BOUND in data.get("policies", {})
        ):
            daily = np.asarray(data["policies"][BOUND]["daily_profit"], np.float64)
            if daily.shape == (len(days),) and np.isfinite(daily).all():
                return daily
    return None


def default_references_dir(task: str | Task) -> Path:
    """Where a task's references live unless a directory is given: the folder of the task
    file a task was read from (`Task.source`), else the shipped `REFERENCES_DIR`.

    Args:
        task: a task id or `Task`.

    Returns:
        The folder.
    """
    if isinstance(task, Task) and task.source is not None:
        return Path(task.source).parent
    return REFERENCES_DIR


def reference_path(task: str | Task, directory: str | Path | None = None) -> Path:
    """The file of a task's references (in ``directory``, default `default_references_dir`).

    Args:
        task: a task id or `Task` (an id is not checked against the registry).
        directory: the folder of the files; None: `default_references_dir` (the task file's
            folder for a task read from a file, else `REFERENCES_DIR`).

    Returns:
        ``<directory>/<task id>.json`` (the file need not exist).
    """
    task_id = task.id if isinstance(task, Task) else str(task)
    return Path(directory or default_references_dir(task)) / f"{task_id}.json"


def build_command(task: Task) -> str:
    """The command line that builds a task's references, for the messages that ask for it.

    Args:
        task: the task.

    Returns:
        ``python -m chargax_marl.benchmark.references`` with ``--task <id>`` for a registered
        task, ``--task-file <path>`` for one read from a file; for a task made in Python, the
        calls that build and save them.
    """
    if task.source is not None:
        return f"python -m chargax_marl.benchmark.references --task-file {task.source}"
    if TASKS.get(task.id) == task:
        return f"python -m chargax_marl.benchmark.references --task {task.id}"
    return "save_references(compute_references(task), DIRECTORY)"


def _dumps(refs: dict) -> str:
    """JSON with every innermost list on one line (one line per day of a reference)."""
    text = json.dumps(refs, indent=1, sort_keys=True)
    return re.sub(
        r"\[\s*([^\[\]{}]*?)\s*\]", lambda m: "[" + " ".join(m.group(1).split()) + "]", text
    )


def save_references(refs: dict, directory: str | Path | None = None) -> Path:
    """Write references as `compute_references` returns them, as ``<task id>.json``.

    Args:
        refs: the references of one task (`compute_references`).
        directory: the folder to write to (created if missing); None: the shipped
            `REFERENCES_DIR`.

    Returns:
        The path of the written file.
    """
    path = reference_path(refs["task"], directory)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(_dumps(refs) + "\n")
    tmp.replace(path)
    return path


@functools.cache
def _read(path: Path) -> dict:
    return json.loads(path.read_text())


def load_references(task: str | Task, directory: str | Path | None = None) -> dict:
    """A task's references, checked against this code.

    Args:
        task: a task id, task file (`chargax_marl.benchmark.tasks.get_task`) or `Task`.
        directory: where the files live (default: `default_references_dir`: the task file's
            folder for a task read from a file, else the shipped `REFERENCES_DIR`).

    Returns:
        The stored references, with every ``daily_profit`` a float64 ``(days, draws)`` array
        (NaN where the bound's solve failed).

    Raises:
        KeyError: an unknown task.
        ValueError: a task file `chargax_marl.benchmark.tasks.load_task` refuses.
        ReferenceMismatchError: no file for the task, or one computed for other parameters, days or
            draws than the task's on this code.
    """
    task = get_task(task)
    path = reference_path(task, directory)
    if not path.exists():
        raise ReferenceMismatchError(
            f"no references for task {task.id!r} in {path.parent}; build them with "
            f"{build_command(task)}"
        )
    data = _read(path.resolve())
    current = params_fingerprint(task.make_params())
    if data["params_fingerprint"] != current:
        raise ReferenceMismatchError(
            f"references of {task.id!r} were computed on parameters with fingerprint "
            f"{data['params_fingerprint']} (package {data.get('package_version')}), but the "
            f"task's parameters on this code have fingerprint {current}: the model changed; "
            f"rebuild them ({build_command(task)}) and raise the task's version"
        )
    kind = data["policies"].get(BOUND, {}).get("kind", "occupancy")
    if BOUND in data["policies"] and kind != task.bound:
        raise ReferenceMismatchError(
            f"references of {task.id!r} hold the {kind!r} bound, but the task is scored "
            f"against the {task.bound!r} bound; rebuild them"
        )
    days = [int(d) for d in task.eval_days()]
    if data["days"] != days or data["draws"] != task.draws:
        raise ReferenceMismatchError(
            f"references of {task.id!r} cover {len(data['days'])} days x {data['draws']} draws "
            f"that are not the task's {len(days)} held-out days x {task.draws} draws"
        )
    out = dict(data)
    out["policies"] = {
        name: {
            **entry,
            "daily_profit": np.array(
                [[np.nan if x is None else x for x in row] for row in entry["daily_profit"]],
                np.float64,
            ),
        }
        for name, entry in data["policies"].items()
    }
    return out


BOUND_RTOL = 1e-4
"""The relative part of the solver tolerance `bound_violations` allows above the bound."""
BOUND_ATOL_EUR = 1e-3
"""The absolute part (EUR per day)."""


def bound_violations(
    task: str | Task,
    daily_profits: dict[str, np.ndarray] | None = None,
    directory: str | Path | None = None,
) -> list[dict]:
    """Every day and draw on which a policy earns more than the task's bound, beyond solver
    tolerance: ``profit > bound + BOUND_RTOL * |bound| + BOUND_ATOL_EUR``.

    On a task whose bound is exact (version 3: the occupancy is every policy's) the list is
    empty for every policy; on the version-1 tasks, whose occupancy bound holds only for the
    policies with always-max's occupancy, it is not. Days whose bound's solve failed are
    skipped.

    Args:
        task: a task id or `Task`.
        daily_profits: further policies by name, each a ``(days, draws)`` array of its
            per-day profits on the task's held-out days and draws (EUR), or ``(seeds, days,
            draws)`` (a score file's ``daily_profit``); the stored references are always
            checked.
        directory: where the task's references live (default: the shipped ones).

    Returns:
        One dict per violation: ``policy``, ``seed`` (None for a stored reference or a 2-d
        array), ``day_index`` (into the task's held-out days), ``draw``, ``profit_eur``,
        ``bound_eur`` and ``excess_eur`` (above the tolerance).

    Raises:
        ReferenceMismatchError: as `load_references`.
        ValueError: a policy's profits not of the shape of the task's days and draws.
    """
    refs = load_references(task, directory)
    bound = refs["policies"][BOUND]["daily_profit"]
    limit = bound + BOUND_RTOL * np.abs(bound) + BOUND_ATOL_EUR
    policies = {k: v["daily_profit"] for k, v in refs["policies"].items() if k != BOUND}
    policies.update(daily_profits or {})
    out = []
    for name, profits in policies.items():
        arr = np.asarray(profits, np.float64)
        seeded = arr.ndim == 3
        if arr.shape[-2:] != bound.shape or arr.ndim not in (2, 3):
            raise ValueError(
                f"field 'daily_profits[{name!r}]' must have shape {bound.shape} or (seeds, "
                f"*{bound.shape}) (the task's days and draws), got {arr.shape}"
            )
        for seed, rows in enumerate(arr if seeded else arr[None]):
            with np.errstate(invalid="ignore"):
                over = rows - limit
            for day, draw in zip(*np.nonzero(np.nan_to_num(over, nan=-1.0) > 0.0), strict=True):
                out.append(
                    {
                        "policy": name,
                        "seed": seed if seeded else None,
                        "day_index": int(day),
                        "draw": int(draw),
                        "profit_eur": float(rows[day, draw]),
                        "bound_eur": float(bound[day, draw]),
                        "excess_eur": float(over[day, draw]),
                    }
                )
    return out
