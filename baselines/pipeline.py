"""One training run end to end: train the seeds in chunks, evaluate each chunk on the validation
days (training days, `baselines.config.validation_env`) against the references played on them,
score the finished run once on the held-out days, and write the run directory."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np
from tqdm import tqdm  # plain text bars: no widget (nor warning) in Jupyter kernels

from baselines import runs
from baselines.algos import distributed, ppo_core, registry, runner
from baselines.algos.trainer import Trainer
from baselines.config import (
    build_env_params,
    name_session_model,
    resolve,
    stored_config,
    validation_env,
    validation_source,
)
from baselines.eval import heldout, references, stats
from chargax_marl.core import checks
from chargax_marl.evaluation import format_table, summarize_profit
from chargax_marl.machine import code_version


@dataclass(frozen=True)
class RunOutput:
    """What `run` returns.

    Attributes:
        results: the run's record, as written to ``results.json``.
        params: the trained parameters of every seed (leading axis: seed).
        trainer: the `baselines.algos.trainer.Trainer` that trained them.
    """

    results: dict
    params: Any
    trainer: Trainer


def chunked_updates(config: dict, chunks: int) -> tuple[int, int]:
    """``(chunks, updates)`` that `run` trains ``config`` with: the updates its
    ``TOTAL_TIMESTEPS`` holds, rounded down to equal chunks (one compiled program).

    Args:
        config: a resolved config (``TOTAL_TIMESTEPS``, ``NUM_ENVS``, ``NUM_STEPS``).
        chunks: the chunks asked for.

    Returns:
        ``(chunks, updates)``: the chunks, between 1 and the config's updates, and the
        updates the run trains, a multiple of them.

    Raises:
        ValueError: ``TOTAL_TIMESTEPS`` less than one rollout
            (`baselines.algos.ppo_core.num_updates`).
    """
    n_upd = ppo_core.num_updates(config)
    chunks = max(1, min(chunks, n_upd))
    return chunks, (n_upd // chunks) * chunks


def run(
    algo: str,
    config: dict,
    seeds: int = 1,
    seed: int = 0,
    out: str | Path | None = None,
    chunks: int = 10,
    evaluate_every_chunk: bool = True,
    baselines: dict | None = None,
    eval_params=None,
    eval_days=None,
    env_params=None,
    title: str | None = None,
    quiet: bool = False,
    optimal: str = "off",
    references_dir=None,
    resume: bool = False,
    overwrite: bool = False,
) -> RunOutput:
    """Train ``seeds`` seeds of ``algo`` and evaluate them; returns the results dict (and
    writes the outputs when ``out`` is given). ``eval_params`` / ``eval_days`` /
    ``env_params`` override the held-out evaluation's and the training's parameters (e.g.
    another price year). ``optimal`` adds the LP bound (and the MPC) to the held-out
    references, see `baselines.eval.heldout.baseline_results`; ``baselines`` gives them
    precomputed.

    While it trains, the run evaluates the greedy policy after every chunk on the config's
    validation days and draws (`baselines.config.validation_env`: training days, in the
    env of their price data) against always-max and the rules on the same days (``eval_curve``,
    ``first_beats_*``, the ``validation`` block); ``evaluate_every_chunk=False`` skips these.
    The held-out days are played once, after training: the references and the final
    parameters (the ``evaluation`` table, ``per_seed``, ``over_seeds``, ``vs_*``,
    ``headroom``).

    With ``out``, the whole training state (parameters, optimiser states, env states, keys,
    the curves and the validation evaluations so far) is written to ``out/checkpoint.msgpack``
    (`baselines.runs.save_checkpoint`, atomically) at the end of every chunk, on a single
    process. ``resume=True`` continues from that checkpoint: the run ends with the parameters
    and results it would have had without the interruption (the timings aside).

    ``out`` holds one run: the main process claims it before training
    (`baselines.runs.claim_run_dir`) and holds its lock until the run ends. A directory that
    holds another run's files is refused unless ``resume`` continues that run or
    ``overwrite`` deletes its files first; one another live process is writing is refused.

    Args:
        algo: the algorithm, one of `baselines.algos.registry.ALGOS`.
        config: the trainer's config (resolved here with `baselines.config.resolve`).
        seeds: the seeds trained together.
        seed: the seed of ``jax.random.PRNGKey`` split into the seeds' keys.
        out: the run directory to write (``results.json``, ``params.msgpack``,
            ``curve.png``, ``checkpoint.msgpack``); None: write nothing.
        chunks: the jitted chunks the training is split into (`chunked_updates`).
        evaluate_every_chunk: evaluate the greedy policy on the validation days after each
            chunk.
        baselines: the held-out references, as `baselines.eval.heldout.baseline_results`
            returns them; None: computed here.
        eval_params: the held-out evaluation's env parameters; None: the config's scenario
            on every day.
        eval_days: the held-out days; None: the config's.
        env_params: the training env's parameters; None: the config's, on its training days.
        title: the curve's title; None: `baselines.runs.curve_title` (the algorithm, the task
            or the scenario and traffic, the seeds).
        quiet: print nothing but the progress bar.
        optimal: ``"off"``, ``"bound"`` or ``"mpc"``: which optimal-control references the
            held-out evaluation adds (`baselines.eval.heldout.baseline_results`).
        references_dir: a directory ``make optimal`` wrote, whose stored bound and MPC are
            reused where they match; None: none.
        resume: continue from ``out``'s checkpoint.
        overwrite: delete the files of an earlier run in ``out`` first.

    Returns:
        The `RunOutput`: the results (what ``results.json`` holds), the final parameters of
        every seed and the trainer.

    Raises:
        ValueError: ``seeds`` or ``chunks`` not an integer >= 1, ``seed`` not one in
            ``[0, 2**31 - 1]``, ``out`` not a usable directory
            (`chargax_marl.core.checks.output_path`), ``references_dir`` not a directory,
            all before anything is built;
            ``resume`` without ``out``, without a readable checkpoint there, with one
            of another run (algorithm, config, seeds, chunks or references), or on several
            processes; or both ``resume`` and ``overwrite``.
        baselines.runs.RunDirError: ``out`` holds another run (without ``resume`` or
            ``overwrite``), or another live process is writing it.
    """
    seeds = int(checks.number("seeds (SEEDS)", seeds, low=1, integer=True))
    seed = int(checks.number("seed (SEED)", seed, low=0, high=2**31 - 1, integer=True))
    chunks = int(checks.number("chunks (CHUNKS)", chunks, low=1, integer=True))
    if out is not None:
        out = checks.output_path("out (OUT)", out, "dir")
    if references_dir is not None and not Path(references_dir).is_dir():
        raise ValueError(
            f"field 'references_dir' (REFERENCES_DIR) must be a directory of stored references "
            f"(make optimal's results/optimal), got {str(references_dir)!r}: no such directory"
        )
    kwargs = dict(
        algo=algo,
        config=config,
        seeds=seeds,
        seed=seed,
        out=out,
        chunks=chunks,
        evaluate_every_chunk=evaluate_every_chunk,
        baselines=baselines,
        eval_params=eval_params,
        eval_days=eval_days,
        env_params=env_params,
        title=title,
        quiet=quiet,
        optimal=optimal,
        references_dir=references_dir,
        resume=resume,
    )
    if out is None or not distributed.is_main():  # only process 0 writes
        return _run(**kwargs)
    record = _record(algo, config, seeds, seed, chunks, optimal, references_dir)
    with runs.claim_run_dir(out, overwrite=overwrite, resume=resume, run=record):
        return _run(**kwargs)


def _record(algo: str, config: dict, seeds: int, seed: int, chunks: int, optimal, references_dir):
    """The settings that make a run (what its checkpoint stores and a resumption must match),
    as JSON values: the config resolved, its env-steps rounded down to equal chunks."""
    config = name_session_model(resolve(config))
    chunks, n_upd = chunked_updates(config, chunks)
    config["TOTAL_TIMESTEPS"] = n_upd * config["NUM_ENVS"] * config["NUM_STEPS"]
    return runs.to_jsonable(
        {
            "algo": algo,
            "config": config,
            "seeds": seeds,
            "seed": seed,
            "chunks": chunks,
            "optimal": optimal,
            "references_dir": None if references_dir is None else str(references_dir),
        }
    )


def _run(
    algo: str,
    config: dict,
    seeds: int,
    seed: int,
    out: str | Path | None,
    chunks: int,
    evaluate_every_chunk: bool,
    baselines: dict | None,
    eval_params,
    eval_days,
    env_params,
    title: str | None,
    quiet: bool,
    optimal: str,
    references_dir,
    resume: bool,
) -> RunOutput:
    """`run` once ``out`` is claimed (see there)."""
    main_process = distributed.is_main()  # only process 0 writes and prints the evaluation
    quiet = quiet or not main_process
    out = out if main_process else None
    multi = jax.process_count() > 1
    host = distributed.to_host if multi else (lambda tree: tree)  # params readable on this process
    config = name_session_model(resolve(config))
    steps_per_update = config["NUM_ENVS"] * config["NUM_STEPS"]
    chunks, n_upd = chunked_updates(config, chunks)
    config["TOTAL_TIMESTEPS"] = n_upd * steps_per_update
    built = build_env_params(config)
    train_params, full_params, train_days, held_out = built
    val_params, val_days, val_draws = validation_env(config, built)
    env_params = train_params if env_params is None else env_params
    eval_params = full_params if eval_params is None else eval_params
    eval_days = held_out if eval_days is None else eval_days
    t_start = time.time()
    train = registry.make_train(algo, config, env_params)
    draws = int(config["EVAL_DRAWS"])
    held_out_desc = f"{np.size(eval_days)} held-out days x {draws} car draws"
    val_desc = f"{np.size(val_days)} validation days x {val_draws} car draws"

    def say(message: str) -> None:  # what the run is doing, between the progress bar's updates
        if not quiet:
            tqdm.write(message)

    evals = []
    val_refs = None  # the references on the validation days (when the chunks are evaluated)
    # The greedy policy is played a validation's number of days at a time, so the held-out
    # evaluation, in the same env, runs the validation's compiled program.
    chunk_days = None
    final_act = None
    if evaluate_every_chunk:
        say(f"scoring the references on {val_desc}: always-max and the rules")
        val_refs = heldout.baseline_results(val_params, val_days, optimal="off", draws=val_draws)
        val_act = train.make_act(val_params)
        if val_params is eval_params:
            chunk_days, final_act = int(np.size(val_days)), val_act

    def on_chunk(i, rs, m, steps, seconds):
        if not evaluate_every_chunk:
            return
        say(f"  evaluating chunk {i + 1}/{chunks}'s greedy policy on {val_desc}")
        ev = heldout.evaluate_batched(
            val_act,
            host(rs.params),
            val_params,
            val_days,
            reference_profit=val_refs["always_max"].get("daily_profit"),
            draws=val_draws,
            chunk_days=chunk_days,
        )
        diffs = _paired_differences(ev, val_refs)
        evals.append(
            {
                "timesteps": int(steps),
                "train_seconds": seconds,
                "per_seed_profit": ev["per_seed_profit"],
                "mean_profit": float(np.mean(ev["per_seed_profit"])),
                **diffs,
            }
        )
        if not quiet:
            am = val_refs["always_max"]["metrics"]["daily_profit_eur"]["mean"]
            tqdm.write(
                f"  validation greedy daily profit: {np.mean(ev['per_seed_profit']):.1f} EUR "
                f"(per seed {np.round(ev['per_seed_profit'], 1).tolist()}; always-max {am:.1f}"
                f"{_describe(diffs)})"
            )

    keys = jax.random.split(jax.random.PRNGKey(seed), seeds)
    if multi:  # inputs of a program over every process's devices must be global arrays
        keys = distributed.replicate(keys)
    record = _record(algo, config, seeds, seed, chunks, optimal, references_dir)
    checkpoint = None if out is None or multi else Path(out) / runs.CHECKPOINT
    metric_chunks: list = []
    start = None
    if resume:
        next_chunk, state, metric_chunks, seconds, done = _resume_from(
            checkpoint, record, train, keys, out, multi
        )
        evals.extend(done)
        start = (next_chunk, state, metric_chunks, seconds)

    def on_chunk_and_save(i, rs, m, steps, seconds):
        on_chunk(i, rs, m, steps, seconds)
        metric_chunks.append(m)
        if checkpoint is not None:
            progress = {"metrics": metric_chunks, "evals": evals, "seconds": seconds}
            runs.save_checkpoint(checkpoint, record, i + 1, rs, progress)

    rs, metrics, train_seconds = runner.run_in_chunks(
        train, keys, chunks, on_chunk_and_save, desc=algo, resume=start
    )
    params = host(rs.params)
    # The held-out days are played once, by the finished run: its references and its policy.
    if baselines is None:
        say(
            f"scoring the references on {held_out_desc}: always-max and the rules"
            + ("" if optimal == "off" else ", the LP hindsight bound")
            + (", the MPC" if optimal == "mpc" else "")
        )
        baselines = heldout.baseline_results(
            eval_params, eval_days, optimal, draws, references_dir, task=config["TASK"] or None
        )
    am = baselines["always_max"]["metrics"]["daily_profit_eur"]["mean"]
    teachers = [
        name for name in heldout.REFERENCES[2:] if name in baselines
    ]  # the teachers' rules (a station with a battery)
    say(f"evaluating the trained greedy policy on {held_out_desc}")
    final = heldout.evaluate_batched(
        final_act or train.make_act(eval_params),
        params,
        eval_params,
        eval_days,
        reference_profit=baselines["always_max"].get("daily_profit"),
        draws=draws,
        chunk_days=chunk_days,
    )
    final_diffs = _paired_differences(final, baselines)
    if not quiet:
        tqdm.write(
            f"  held-out greedy daily profit: {np.mean(final['per_seed_profit']):.1f} EUR "
            f"(per seed {np.round(final['per_seed_profit'], 1).tolist()}; always-max {am:.1f}"
            f"{_describe(final_diffs)})"
        )
    wall = time.time() - t_start
    first_beat = {
        f"first_beats_{name}": next(
            (e for e in evals if e.get(f"vs_{name}") is not None and stats.beats(e[f"vs_{name}"])),
            None,
        )
        for name in ("always_max", "battery_rule", *teachers)
    }
    heldout.add_headroom({"final": final}, baselines)
    table = {**baselines, algo: final}
    if not quiet:
        print(format_table(table))
    timesteps = (np.arange(n_upd) + 1) * steps_per_update
    per_seed = heldout.per_seed_results(final, evals, baselines, seed)
    summary = {
        f"vs_{k}": stats.over_seeds([p[f"vs_{k}"]["mean"] for p in per_seed])
        for k in heldout.REFERENCES
        if all(p.get(f"vs_{k}") is not None for p in per_seed)
    }
    if all(p["headroom_fraction"] is not None for p in per_seed):
        summary["headroom_fraction"] = stats.over_seeds([p["headroom_fraction"] for p in per_seed])
    results = {
        "algo": algo,
        "scenario": {
            "name": config["SCENARIO"],
            "traffic": config["TRAFFIC"],
            "env_kwargs": config["ENV_KWARGS"],
            "held_out_days": int(np.size(eval_days)),
            "car_draws_per_day": draws,
        },
        "per_seed": per_seed,
        "over_seeds": summary,
        "config": config,
        "seeds": seeds,
        "seed": seed,
        "devices": [str(d) for d in jax.devices()],
        "code": code_version(),
        "num_processes": jax.process_count(),
        "timesteps": int(config["TOTAL_TIMESTEPS"]),
        "wall_seconds": wall,
        "train_seconds_incl_compile": train_seconds,
        "evaluation": {
            "policy": "greedy (argmax per head)",
            "key": (
                "PRNGKey(0) for every policy and seed (common random numbers)"
                if draws == 1
                else f"PRNGKey(0) ... PRNGKey({draws - 1}) for every policy and seed (common random "
                f"numbers), each day's totals the mean over the {draws} car draws"
            ),
            "draws": draws,
            "num_days": int(np.size(eval_days)),
            "days": [int(d) for d in np.asarray(eval_days)],
            "table": table,
        },
        "vs_always_max": final_diffs["vs_always_max"],
        "vs_battery_rule": final_diffs["vs_battery_rule"],
        **{f"vs_{name}": final_diffs[f"vs_{name}"] for name in teachers},
        "headroom": final.get("headroom"),
        **first_beat,
        "validation": {
            "source": validation_source(config),
            "num_days": int(np.size(val_days)),
            "draws": val_draws,
            "days": [int(d) for d in np.asarray(val_days)],
            "evaluated": "every chunk" if evaluate_every_chunk else "never",
            "references": val_refs,
        },
        "eval_curve": evals,
        "curve": {
            "timesteps": timesteps,
            **{
                k: np.asarray(metrics[k])
                for k in (
                    "episode_profit_eur",
                    "episode_return",
                    "entropy",
                    "value_loss",
                    "actor_loss",
                )
            },
        },
    }
    if not quiet:
        for p_ in per_seed:
            rule, hf = p_["vs_battery_rule"], p_["headroom_fraction"]
            print(
                f"seed {p_['seed_index']}: vs always-max {p_['vs_always_max']['mean']:+.2f} ± "
                f"{p_['vs_always_max']['stderr']:.2f}"
                + (f", vs battery rule {rule['mean']:+.2f} ± {rule['stderr']:.2f}" if rule else "")
                + "".join(
                    f", vs {name.replace('_', ' ')} {p_[f'vs_{name}']['mean']:+.2f} ± "
                    f"{p_[f'vs_{name}']['stderr']:.2f}"
                    for name in teachers
                )
                + (f", headroom {hf:.2f}" if hf is not None else "")
                + f"; first beats the battery rule: {p_['first_beats_battery_rule']}"
            )
        for k, v in summary.items():
            print(
                f"over seeds, {k}: {v['mean']:+.3f} ± {v['stderr']:.3f} (min {v['min']:+.3f}, max {v['max']:+.3f})"
            )
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        runs.save_params(params, out / "params.msgpack")
        say(f"drawing {out / 'curve.png'}")
        runs.plot_curve(
            out / "curve.png",
            algo,
            timesteps,
            metrics["episode_profit_eur"],
            table,
            evals,
            title or runs.curve_title(algo, config, seeds, draws),
            validation=val_refs,
        )
        runs.write_json(results, out / "results.json")
        if not quiet:
            print(f"wrote {out / 'curve.png'}, {out / 'results.json'}, {out / 'params.msgpack'}")
    return RunOutput(results=results, params=params, trainer=train)


def _paired_differences(ev: dict, refs: dict) -> dict:
    """An evaluation's paired differences to the references played on the same days and
    draws: ``vs_always_max``, ``vs_battery_rule`` (None without it) and ``vs_<teacher rule>``
    for each teachers' rule the references hold."""
    rule = refs.get("battery_rule", {}).get("daily_profit")
    return {
        "vs_always_max": ev.get("paired_diff"),
        "vs_battery_rule": (
            None if rule is None else stats.paired_difference(ev["daily_profit"], rule)
        ),
        **{
            f"vs_{name}": stats.paired_difference(ev["daily_profit"], refs[name]["daily_profit"])
            for name in heldout.REFERENCES[2:]
            if name in refs
        },
    }


def _describe(diffs: dict) -> str:
    """``diffs`` (`_paired_differences`) for a progress line."""
    return "".join(
        f"; vs {k[3:].replace('_', ' ')} {d['mean']:+.2f} ± {d['stderr']:.2f}"
        for k, d in diffs.items()
        if d is not None
    )


def _resume_from(checkpoint, record: dict, train: Trainer, keys, out, multi: bool):
    """``(next_chunk, runner_state, metric_chunks, seconds, evals)`` of the checkpoint a
    resumed `run` continues from (see there for the errors)."""
    if multi:
        raise ValueError("resume: a run on several processes cannot be resumed (no checkpoint)")
    if checkpoint is None:
        raise ValueError("resume: give the run directory (out) whose checkpoint to continue")
    if not checkpoint.exists():
        raise ValueError(
            f"resume: {checkpoint} does not exist (the run never finished a chunk in {out})"
        )
    template = jax.eval_shape(jax.vmap(train.init), keys)
    state = runs.load_checkpoint(checkpoint, template)
    stored = state["run"]
    if stored != record:
        changed = sorted(k for k in set(stored) | set(record) if stored.get(k) != record.get(k))
        raise ValueError(
            f"resume: {checkpoint} is a checkpoint of another run (differs in {changed}); "
            "resume with the settings it was started with (`python -m baselines.train --resume "
            f"{out}` reads them from the checkpoint)"
        )
    progress = state["progress"]
    return (
        state["next_chunk"],
        state["runner_state"],
        progress["metrics"],
        float(progress["seconds"]),
        progress["evals"],
    )


def resume_settings(out) -> dict:
    """The settings a run was started with, from the checkpoint in its directory ``out``.

    Args:
        out: A run directory of ``python -m baselines.train``.

    Returns:
        ``{"algo", "config", "seeds", "seed", "chunks", "optimal", "references_dir"}``, the
        keyword arguments of `run` (with ``out`` and ``resume=True``) that continue it.

    Raises:
        ValueError: no readable checkpoint in ``out``.
    """
    path = Path(out) / runs.CHECKPOINT
    if not path.exists():
        raise ValueError(f"--resume: {path} does not exist (no chunk of that run finished)")
    settings = runs.load_checkpoint(path)["run"]
    return {**settings, "config": stored_config(settings["config"])}


def add_stored_mpc(run_dir, references_dir) -> dict:
    """Add a stored MPC to a finished run, without retraining.

    Adds the MPC that ``python -m baselines.analysis.references`` (``make optimal``) stored
    for exactly the run's evaluation params and held-out days to its ``results.json`` (the
    evaluation table, with ``headroom`` and the run's paired difference to it, ``vs_mpc``)
    and redraws its ``curve.png`` with the MPC line.

    Args:
        run_dir: a run directory of ``python -m baselines.train``.
        references_dir: the directory ``make optimal`` wrote (e.g. ``results/optimal``).

    Returns:
        The updated results.

    The run directory is claimed for the rewrite (`baselines.runs.claim_run_dir`, accepting
    the run it holds), so a replot never mixes its files with those of a training that is
    writing the directory.

    Raises:
        LookupError: no stored MPC matches the run's params and days, or the run was scored
            on several car draws (the stored MPC is one draw).
        FileNotFoundError: ``run_dir`` holds no ``results.json``.
        baselines.runs.RunDirError: another live process is writing ``run_dir``.
    """
    run_dir = Path(run_dir)
    if not (run_dir / "results.json").is_file():
        raise FileNotFoundError(f"{run_dir}: no results.json (not a finished training run)")
    with runs.claim_run_dir(run_dir, resume=True):
        return _add_stored_mpc(run_dir, references_dir)


def _add_stored_mpc(run_dir: Path, references_dir) -> dict:
    """`add_stored_mpc` on a claimed run directory."""
    results = json.loads((run_dir / "results.json").read_text())
    config = resolve(stored_config(results["config"]))
    _, eval_params, _, days = build_env_params(config)
    days = results["evaluation"]["days"] if results["evaluation"].get("days") else days
    if int(config["EVAL_DRAWS"]) != 1:
        raise LookupError(
            f"{run_dir}: evaluated on {config['EVAL_DRAWS']} car draws per day; the stored MPC "
            "is one draw (PRNGKey(0)), so it does not pair with this run"
        )
    stored = references.cached(eval_params, days, references_dir)
    mpc_daily = references.stored_mpc(stored, days)
    if mpc_daily is None:
        raise LookupError(
            f"{run_dir}: no stored MPC for its params and {len(days)} held-out days in "
            f"{references_dir} (run `python -m baselines.analysis.references` for this scenario)"
        )
    table = results["evaluation"]["table"]
    table["mpc"] = {
        "daily_profit": mpc_daily.tolist(),
        "metrics": summarize_profit(mpc_daily),
        "source": f"{references_dir} (same params and days)",
    }
    heldout.add_headroom(
        {"mpc": table["mpc"]},
        {
            k: {"daily_profit": np.asarray(v["daily_profit"])}
            for k, v in table.items()
            if isinstance(v, dict) and "daily_profit" in v
        },
    )
    algo = results["algo"]
    results["vs_mpc"] = stats.paired_difference(
        table[algo]["daily_profit"], mpc_daily
    )  # (seeds, days) - (days,)
    runs.write_json(results, run_dir / "results.json")
    runs.plot_run(results, run_dir / "curve.png")
    return results
