"""The held-out protocol: every policy on the same days and cars (car draws per day), the rules'
and the optimal references beside it, and what each trained seed scores against them. A
training run plays the same protocol on its validation days while it trains (the rules only,
``optimal="off"``) and on the held-out days once, when it has finished."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from baselines.algos.trainer import IdentityCache
from baselines.config import RUN_SCHEMA
from baselines.eval import protocol, references, rules, stats
from chargax_marl.benchmark.tasks import get_task
from chargax_marl.evaluation import (
    METRICS,
    bound_kind,
    headroom_captured,
    policy_bound,
    run_days,
    run_days_keyed,
    summarize,
    summarize_profit,
)
from chargax_marl.teachers.rules import has_battery


def evaluate_batched(
    make_act,
    net_params,
    eval_params,
    days,
    key=None,
    reference_profit=None,
    draws: int = 1,
    chunk_days: int | None = None,
) -> dict:
    """Greedy held-out evaluation of every seed's parameters (leading axis) with
    `chargax_marl.evaluation.run_days`.

    Every seed runs with the *same* key as `chargax_marl.evaluation.evaluate` (default
    ``PRNGKey(0)``), so all policies meet the same drawn cars on the same days (common random
    numbers): differences between policies are then not masked by the day-to-day spread of
    traffic, which is far larger than most differences between policies. With ``draws`` > 1
    (and no ``key``) each day is played under the keys of `draw_keys` and every per-day total
    is the mean over the draws. Returns pooled mean ± std over seeds × days (``metrics``),
    each seed's mean daily profit (``per_seed_profit``) and mean of every metric over days
    (``per_seed_metrics``), and daily profits (``daily_profit``, seeds × days). With
    ``reference_profit`` (the daily profits of a baseline on the same days and key, e.g.
    always-max), also ``paired_diff``: per seed, the mean and standard error over days of
    (policy − reference) profit.

    With ``chunk_days``, the days are played ``chunk_days`` at a time through one program
    compiled for that many days (`compiled_keyed_evaluation`), each day on the key it has in
    the whole batch: the same cars, and a later call with the same ``make_act``,
    ``eval_params`` and ``chunk_days`` on any number of days compiles nothing (a training
    run's held-out days reuse the program of its validation days).

    Args:
        make_act: ``make_act(params) -> act(state, key) -> levels`` or a
            `chargax_marl.evaluation.MemoryAct` (a trainer's ``make_act(eval_params)``).
        net_params: every seed's network parameters, a pytree with a leading seed axis.
        eval_params: the evaluation env parameters.
        days: ``(days,)`` day indices to play.
        key: one evaluation key for every day; ``None`` plays the keys of `draw_keys`.
        reference_profit: ``(days,)`` daily profits in EUR/day of a reference on the same
            days and key, or ``None`` for no ``paired_diff``.
        draws: car draws per day (a positive integer); only with ``key=None``.
        chunk_days: the days per compiled call (a positive integer; the last chunk is padded
            with its last day, whose copies are dropped); None: every day in one call.

    Returns:
        ``{"num_days", "num_seeds", "metrics", "per_seed_profit", "daily_profit",
        "per_seed_metrics"}`` (``daily_profit`` a float64 ``(seeds, days)`` array in EUR/day,
        ``per_seed_profit`` a list of each seed's mean daily profit in EUR/day), plus
        ``paired_diff`` (`baselines.eval.stats.paired_difference`) with ``reference_profit``.

    Raises:
        ValueError: both a ``key`` and ``draws`` other than 1, ``draws`` not a positive
            integer (`baselines.eval.protocol.draw_keys`), or ``chunk_days`` not a positive
            integer.
    """
    if chunk_days is not None and (
        isinstance(chunk_days, bool)
        or not isinstance(chunk_days, (int, np.integer))
        or chunk_days < 1
    ):
        raise ValueError(f"field 'chunk_days' must be a positive integer, got {chunk_days!r}")
    if key is not None and draws != 1:
        raise ValueError(
            f"evaluate_batched: give either a key or draws > 1, not both (draws={draws!r})"
        )
    keys = [key] if key is not None else protocol.draw_keys(draws)
    days = jnp.asarray(days, jnp.int32)
    seeds = jax.tree.leaves(net_params)[0].shape[0]
    if chunk_days is None:
        fn = compiled_evaluation(make_act, eval_params)
        totals = protocol.mean_over_draws(lambda k: fn(net_params, days, k), keys)
    else:
        fn = compiled_keyed_evaluation(make_act, eval_params)
        totals = protocol.mean_over_draws(
            lambda k: _in_chunks(fn, net_params, days, k, int(chunk_days)), keys
        )
    flat = jax.tree.map(lambda x: np.asarray(x).reshape(-1), totals)
    profit = np.asarray(totals.profit_eur, np.float64)
    out = {
        "num_days": int(days.shape[0]),
        "num_seeds": int(seeds),
        "metrics": summarize(flat),
        "per_seed_profit": [float(x) for x in profit.mean(axis=1)],
        "daily_profit": profit,
        "per_seed_metrics": {
            name: [float(x) for x in np.asarray(getattr(totals, field), np.float64).mean(axis=1)]
            for name, field in METRICS.items()
        },
    }
    if reference_profit is not None:
        out["paired_diff"] = stats.paired_difference(profit, reference_profit)
    return out


def _seed_vmapped(cache: IdentityCache, play, make_act, eval_params):
    """``play(act, eval_params, days, keys)`` of every seed's act, jitted and vmapped over the
    seeds' parameters, kept in ``cache`` per ``make_act`` and ``eval_params``."""
    per_params = cache.get(make_act, IdentityCache)
    return per_params.get(
        eval_params,
        lambda: jax.jit(
            jax.vmap(
                lambda p, d, kk: play(make_act(p), eval_params, d, kk), in_axes=(0, None, None)
            )
        ),
    )


_COMPILED = IdentityCache()


def compiled_evaluation(make_act, eval_params):
    """The jitted evaluation of every seed's parameters on days, one per policy and params.

    Args:
        make_act: ``make_act(params) -> act(state, key) -> levels`` or a
            `chargax_marl.evaluation.MemoryAct` (a trainer's ``make_act(eval_params)``).
        eval_params: the evaluation env parameters.

    Returns:
        ``fn(net_params, days, key) -> totals`` with a leading seed axis on ``net_params`` and
        on every total, compiled once for this ``make_act`` and ``eval_params``.
    """
    return _seed_vmapped(_COMPILED, run_days, make_act, eval_params)


_COMPILED_KEYED = IdentityCache()


def compiled_keyed_evaluation(make_act, eval_params):
    """`compiled_evaluation` with one key per day (`chargax_marl.evaluation.run_days_keyed`).

    Args:
        make_act: ``make_act(params) -> act(state, key) -> levels`` or a
            `chargax_marl.evaluation.MemoryAct` (a trainer's ``make_act(eval_params)``).
        eval_params: the evaluation env parameters.

    Returns:
        ``fn(net_params, days, day_keys) -> totals`` (``day_keys`` ``(days, 2)``, day ``i``'s
        cars drawn from ``day_keys[i]``), with a leading seed axis on ``net_params`` and on
        every total, compiled once per number of days for this ``make_act`` and
        ``eval_params``.
    """
    return _seed_vmapped(_COMPILED_KEYED, run_days_keyed, make_act, eval_params)


def _in_chunks(fn, net_params, days, key, chunk_days: int):
    """``fn`` (`compiled_keyed_evaluation`) on ``days`` in calls of ``chunk_days`` days, day
    ``i`` on ``split(key, len(days))[i]`` as `run_days` plays it; totals ``(seeds, days)``."""
    n = int(days.shape[0])
    day_keys = jax.random.split(key, n)
    padded = -(-n // chunk_days) * chunk_days
    fill = padded - n
    days = jnp.concatenate([days, jnp.repeat(days[-1:], fill)])
    day_keys = jnp.concatenate([day_keys, jnp.repeat(day_keys[-1:], fill, axis=0)])
    parts = [
        jax.device_get(fn(net_params, days[i : i + chunk_days], day_keys[i : i + chunk_days]))
        for i in range(0, padded, chunk_days)
    ]
    return jax.tree.map(lambda *x: np.concatenate(x, axis=1)[:, :n], *parts)


BASELINES = ("always_max", "battery_rule", "price_threshold")
"""The rule-based references every training run is scored against (``battery_rule`` is
always-max plus a battery that charges in the day's cheapest 20 % of hours and discharges in
the dearest 20 %); on a station with a battery also the teachers' rules,
``battery_programme`` (always-max plus the battery-only programme) and ``plan_programme``
(the ports' plans plus the programme), `baselines.eval.rules.TEACHER_RULES`."""


REFERENCES = ("always_max", "battery_rule", "battery_programme", "plan_programme")
"""The baselines each trained seed gets a paired difference to (``vs_<name>``), where present."""


OPTIMAL_CHOICES = RUN_SCHEMA["OPTIMAL"].choices


def baseline_results(
    eval_params, eval_days, optimal: str = "off", draws: int = 1, references_dir=None, task=None
) -> dict:
    """The `BASELINES` (and, on a station with a battery, the teachers' rules) on
    ``eval_days`` (the held-out days, or a run's validation days), with the evaluation's
    default key (the same
    drawn cars that `evaluate_batched` gives the agents). Each keeps its
    daily profits (``daily_profit``) for paired comparisons.

    ``optimal``: ``"bound"`` adds ``lp_bound`` (the LP bound that holds under the params'
    session model, `chargax_marl.evaluation.policy_bound`: over always-max's occupancy on
    the paper's mechanics, the port-pooled bound otherwise; its ``kind`` says which) and,
    when ``references_dir``
    (a directory ``make optimal`` wrote) holds them for exactly these params and days, the
    stored bound and ``mpc``; ``"mpc"`` also runs the MPC when no
    stored result matches (an LP per step: the slowest part); ``"off"`` adds neither.
    Every entry then gets ``headroom`` (`chargax_marl.evaluation.headroom_captured`).
    With ``draws`` > 1 every rule and the bound are scored under the keys of
    `draw_keys`, each day's profit the mean over the draws; the stored
    MPC (one draw) is then not used, and ``optimal="mpc"`` runs the MPC on every draw.
    With ``task``, the task's shipped bound is read instead of solved where it is the same
    bound (`baselines.eval.references.shipped_bound`: the task's held-out days and draws, its
    parameters up to the action levels); its ``source`` names the task.

    Args:
        eval_params: the evaluation env parameters.
        eval_days: the day indices to play.
        optimal: one of `OPTIMAL_CHOICES`: ``"off"``, ``"bound"`` or ``"mpc"``.
        draws: car draws per day (a positive integer).
        references_dir: a directory of stored references (``make optimal``), or ``None`` to
            compute the bound (and the MPC) here.
        task: the benchmark task (id, file or `chargax_marl.benchmark.Task`) whose shipped
            bound to read where it matches; None: none.

    Returns:
        ``{name: entry}`` per rule (`baselines.eval.rules.evaluate_rules` entries;
        ``battery_rule`` and the teachers' rules with ``vs_always_max``, the teachers' rules
        also with ``vs_battery_rule``). Unless ``optimal="off"``, also ``lp_bound``
        (``daily_profit``, ``metrics``, ``source``, ``kind``) and, when stored or run,
        ``mpc`` (``daily_profit``, ``metrics``, ``source``), and every entry gets
        ``headroom``.

    Raises:
        ValueError: ``optimal`` not one of `OPTIMAL_CHOICES`, or ``draws`` not a positive
            integer (`baselines.eval.protocol.draw_keys`).
    """
    if optimal not in OPTIMAL_CHOICES:
        raise ValueError(f"field 'optimal' must be one of {OPTIMAL_CHOICES}, got {optimal!r}")
    names = BASELINES + rules.TEACHER_RULES * has_battery(eval_params)
    out = rules.evaluate_rules(eval_params, eval_days, names, draws=draws)
    for name in REFERENCES[1:]:
        if name in out:
            out[name]["vs_always_max"] = stats.paired_difference(
                out[name]["daily_profit"], out["always_max"]["daily_profit"]
            )
    for name in rules.TEACHER_RULES:
        if name in out:
            out[name]["vs_battery_rule"] = stats.paired_difference(
                out[name]["daily_profit"], out["battery_rule"]["daily_profit"]
            )
    if optimal == "off":
        return out
    stored = None
    if references_dir is not None and draws == 1:
        stored = references.cached(eval_params, eval_days, references_dir)
    shipped = None
    if stored is None and task is not None:
        shipped = references.shipped_bound(task, eval_params, eval_days, draws)
    if stored is not None:
        bound_daily = np.asarray(stored["policies"]["lp_bound"]["daily_profit"])
        mpc_daily = references.stored_mpc(stored, eval_days)
        source = f"{references_dir} (same params and days)"
    elif shipped is not None:
        bound_daily, mpc_daily = shipped, None
        source = f"the shipped references of {get_task(task).id} (same days and cars)"
        source += "" if draws == 1 else f", mean over {draws} car draws per day"
    else:
        keys = protocol.draw_keys(draws)
        bound_daily = protocol.mean_over_draws(
            lambda k: policy_bound(eval_params, eval_days, k)["daily_profit"], keys
        )
        mpc_daily = (
            protocol.mean_over_draws(
                lambda k: references.evaluate_mpc(eval_params, eval_days, k)["daily_profit"], keys
            )
            if optimal == "mpc"
            else None
        )
        source = "computed" if draws == 1 else f"computed, mean over {draws} car draws per day"
    mpc_source = source
    if optimal == "mpc" and mpc_daily is None:  # stored without an MPC of every one of the days
        mpc_daily = protocol.mean_over_draws(
            lambda k: references.evaluate_mpc(eval_params, eval_days, k)["daily_profit"],
            protocol.draw_keys(draws),
        )
        mpc_source = "computed"
    out["lp_bound"] = {
        "daily_profit": bound_daily,
        "metrics": summarize_profit(bound_daily),
        "source": source,
        "kind": bound_kind(eval_params),
    }
    if mpc_daily is not None:
        out["mpc"] = {
            "daily_profit": mpc_daily,
            "metrics": summarize_profit(mpc_daily),
            "source": mpc_source,
        }
    add_headroom(out, out)
    return out


def add_headroom(entries: dict, baselines: dict) -> dict:
    """Add ``headroom`` (fraction of the hindsight headroom captured) to every entry that has
    ``daily_profit``, when ``baselines`` hold ``lp_bound`` and ``always_max``.

    Args:
        entries: ``{name: entry}``; the dict entries with ``daily_profit`` are changed in place.
        baselines: ``{name: entry}`` that may hold ``lp_bound``; with it, also ``always_max``.

    Returns:
        ``entries``, the same dict (unchanged when ``baselines`` lack ``lp_bound``).
    """
    if "lp_bound" not in baselines:
        return entries
    am, bound = baselines["always_max"]["daily_profit"], baselines["lp_bound"]["daily_profit"]
    for e in entries.values():
        if isinstance(e, dict) and "daily_profit" in e:
            e["headroom"] = headroom_captured(e["daily_profit"], am, bound)
    return entries


def per_seed_results(final: dict, evals: list, baselines: dict, seed: int) -> list[dict]:
    """One entry per trained seed: its paired differences (mean and standard error over the
    held-out days) to always-max (``vs_always_max``), to always-max + battery rule
    (``vs_battery_rule``) and, where the baselines hold them, to the teachers' rules
    (``vs_battery_programme``, ``vs_plan_programme``), the fraction of the LP bound's headroom it captures
    (``headroom_fraction``, when the bound was computed), and the env steps and wall minutes
    (since the start of training, compile and evaluations included) of the first evaluation
    of ``evals`` (a run's validation evaluations) at which this seed beats each reference by
    more than two standard errors (``None``: never).

    Args:
        final: the held-out evaluation of every seed (`evaluate_batched`), its
            ``daily_profit`` ``(seeds, days)`` in EUR/day.
        evals: the run's validation evaluations, each a dict with ``timesteps``,
            ``train_seconds`` and the ``vs_<reference>`` paired differences it has.
        baselines: `baseline_results` on the same days (``always_max`` is required).
        seed: the run's seed, written into each entry's ``key``.

    Returns:
        One dict per seed: ``seed_index``, ``key``, ``mean_profit_eur``, ``vs_<reference>``
        (``{"mean", "stderr"}`` in EUR/day, or ``None``), ``headroom_fraction`` and
        ``first_beats_<reference>`` (``{"timesteps", "wall_minutes"}`` or ``None``).
    """
    profit = np.atleast_2d(np.asarray(final["daily_profit"], np.float64))
    am = np.asarray(baselines["always_max"]["daily_profit"], np.float64)
    bound = baselines.get("lp_bound", {}).get("daily_profit")
    vs = {
        name: stats.paired_difference(profit, baselines[name]["daily_profit"])
        for name in REFERENCES
        if name in baselines
    }
    out = []
    for i in range(profit.shape[0]):

        def first(key):
            e = next(
                (e for e in evals if e.get(key) is not None and stats.seed_beats(e[key], i)), None
            )
            return (
                None
                if e is None
                else {"timesteps": e["timesteps"], "wall_minutes": e["train_seconds"] / 60.0}
            )

        entry = {
            "seed_index": i,
            "key": f"split(PRNGKey({seed}), seeds)[{i}]",
            "mean_profit_eur": float(profit[i].mean()),
        }
        for name in (
            n for n in REFERENCES if n in vs or n == "battery_rule"
        ):  # battery_rule: None when absent
            d = vs.get(name)
            entry[f"vs_{name}"] = (
                None
                if d is None
                else {"mean": d["per_seed_mean"][i], "stderr": d["per_seed_stderr"][i]}
            )
        entry["headroom_fraction"] = (
            None if bound is None else headroom_captured(profit[i], am, bound)["fraction"]
        )
        for name in REFERENCES:
            if f"vs_{name}" in entry:
                entry[f"first_beats_{name}"] = first(f"vs_{name}")
        out.append(entry)
    return out
