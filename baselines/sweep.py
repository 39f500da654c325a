"""Sweep hyper-parameters × seeds: every setting of a grid trained and scored on validation days.

    python -m baselines.sweep --config ippo LR=3e-4,1e-3 ENT_COEF=0.003,0.01,0.03 SEEDS=4
    python -m baselines.sweep --config ppo LR=1e-4,3e-4 HIDDEN=64,128 OUT=outputs/sweep_ppo

A ``KEY=v1,v2,...`` argument sweeps the key over those values; the grid is every combination
of the swept keys, each trained over ``SEEDS`` seeds (the same seeds for every setting).
``KEY=value`` sets a key for every setting, as in ``python -m baselines.train``; a value
that is itself a table or a list (``ENV_KWARGS={num_levels=2}``) is one value.

The scalar hyper-parameters (`baselines.algos.ppo_core.HYPER_KEYS`: learning rate, clip
norm, γ, λ, the clips, the entropy and value coefficients, the reward scale and the shaping
weight) are values of the training program: all settings that differ only in them train in
one compiled program. Every other key sets the program's shapes or structure (envs, steps,
minibatches, widths, the learning aids, the scenario), and each distinct combination of those
is its own compile. Every setting trains exactly the program ``python -m baselines.train``
runs for it alone (the same chunks, seeds and keys): with ``--settings-per-batch 1`` (the
default) its parameters and scores are bit for bit the same on the same machine; with ``n >
1`` settings are vmapped ``n`` at a time (for a GPU's width; the numbers then agree to float32
rounding).

Every setting is scored after each of ``CHUNKS`` chunks on the validation days (training days,
`baselines.config.validation_env`), never on the held-out days, against always-max and, unless
``OPTIMAL=off``, the LP hindsight bound on the same days (``headroom``: the fraction of the
bound's gain over always-max captured). The ranking is by mean validation profit over seeds.

Outputs: ``OUT.json`` (every setting's config, per-seed validation profits, paired
differences to always-max, headroom, the validation curve with env-steps and seconds (its
``train_seconds``: since the group's start, compiles included, evaluations left out), the
compile groups and their wall times), ``OUT.md`` (the ranked table) and ``OUT.params.msgpack``
(every setting's final parameters, leading axis seed). ``OUT`` defaults to
``outputs/sweep_<algo>``; the files of an earlier sweep are refused unless ``--overwrite``.
Score a chosen setting on the held-out days once, by training it with ``python -m
baselines.train`` and scoring the run with ``python -m baselines.score``.
"""

from __future__ import annotations

import argparse
import functools
import itertools
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

from baselines import pipeline, runs
from baselines.algos import ppo_core, registry, runner
from baselines.config import (
    DEFAULT_CONFIG,
    RUN_SCHEMA,
    SCHEMA,
    ConfigError,
    Field,
    build_env_params,
    canonical,
    check_value,
    load,
    parse_override,
    validation_env,
)
from baselines.eval import heldout, stats
from chargax_marl.core import checks
from chargax_marl.evaluation import headroom_captured
from chargax_marl.machine import code_version

SUFFIXES = (".json", ".md", ".params.msgpack")
"""The files a sweep writes after its ``OUT`` prefix."""

_PER_BATCH = Field(1, (int,), low=1, doc="settings vmapped together")
"""The field of ``--settings-per-batch``, checked as a config key is."""


def parse_grid(overrides) -> tuple[list[str], dict[str, list]]:
    """Split ``KEY=value`` arguments into fixed overrides and swept keys.

    Every swept value is read as `baselines.config.parse_override` reads a value and checked
    by the key's field (`baselines.config.check_value`) here, before anything trains; values
    are compared as the schema parsed them (``64`` and ``64.0`` are one value).

    Args:
        overrides: ``"KEY=value"`` or ``"KEY=v1,v2,..."`` strings. A value that starts with
            ``{``, ``[`` or a quote is one value, commas and all.

    Returns:
        ``(fixed, grid)``: the ``"KEY=value"`` strings of single values, and the swept keys
        with their checked values, in the order given. A key given again replaces its
        earlier value(s).

    Raises:
        ConfigError: an argument without ``=``, a swept run key (``SEEDS``, ``OUT``, ...:
            one sweep has one of each), a swept key the schema does not know, an empty value
            in a grid (``KEY=a,`` or ``KEY=a,,b``), a value the key does not allow, or a
            value given twice (after parsing).
    """
    fixed, grid, seen = [], {}, set()
    for text in overrides:
        key, sep, raw = text.partition("=")
        key = key.strip().upper()
        if not sep or not key:
            raise ConfigError(f"argument {text!r}: expected KEY=value or KEY=v1,v2,...")
        if key in seen:  # a later argument sets the key again, as in baselines.train
            fixed = [f for f in fixed if f.partition("=")[0] != key]
            grid.pop(key, None)
        seen.add(key)
        raw = raw.strip()
        parts = [raw] if raw[:1] in ("{", "[", '"', "'") else raw.split(",")
        if len(parts) == 1:
            fixed.append(f"{key}={raw}")
            continue
        if key in RUN_SCHEMA:
            raise ConfigError(
                f"config key {key}={raw!r}: a run key takes one value per sweep; sweep the "
                f"trainer keys only (not {sorted(RUN_SCHEMA)})"
            )
        if key not in SCHEMA:
            raise ConfigError(f"unknown config key {key!r} in {text!r}; allowed: {sorted(SCHEMA)}")
        values, texts = [], []
        for i, part in enumerate(parts):
            if not part.strip():
                raise ConfigError(
                    f"config key {key}={raw!r}: value {i + 1} of {len(parts)} is empty (a "
                    f"trailing or doubled comma?); a grid lists its values, e.g. {key}=a,b"
                )
            value = check_value(key, parse_override(f"{key}={part.strip()}")[1], SCHEMA[key])
            text_value = canonical(key, value)
            if text_value in texts:
                raise ConfigError(
                    f"config key {key}={raw!r}: the value {part.strip()!r} is the same setting "
                    f"as {parts[texts.index(text_value)].strip()!r}; give each value once"
                )
            values.append(value)
            texts.append(text_value)
        grid[key] = values
    return fixed, grid


def settings_of(grid: dict[str, list]) -> list[dict]:
    """Every combination of the swept values, the first key varying slowest.

    Args:
        grid: swept keys and their values (`parse_grid`).

    Returns:
        One ``{key: value}`` per setting (one empty setting when nothing is swept).
    """
    keys = list(grid)
    return [dict(zip(keys, combo)) for combo in itertools.product(*(grid[k] for k in keys))]


def _override(key: str, value) -> str:
    """``KEY=value`` of a parsed value, read back by `baselines.config.parse_override`."""
    if isinstance(value, str):
        return f"{key}={json.dumps(value)}"
    if isinstance(value, dict):
        inner = ", ".join(f"{k} = {json.dumps(v)}" for k, v in value.items())
        return f"{key}={{{inner}}}"
    if isinstance(value, bool):
        return f"{key}={'true' if value else 'false'}"
    return f"{key}={value!r}"


def _structure(config: dict) -> str:
    """The keys that set a training program's shapes and structure, as one string: settings
    with equal structure train in one compiled program."""
    return json.dumps(
        {k: v for k, v in config.items() if k not in ppo_core.HYPER_KEYS}, sort_keys=True
    )


def compile_groups(configs: list[dict], chunks: int) -> dict[str, list[int]]:
    """The settings that train in one compiled program.

    Each config's ``TOTAL_TIMESTEPS`` is first rounded down to equal chunks, as
    `baselines.pipeline.run` rounds it (in place).

    Args:
        configs: the settings' resolved configs.
        chunks: the run's ``CHUNKS``.

    Returns:
        ``{structure: [setting index, ...]}``: settings whose keys other than
        `baselines.algos.ppo_core.HYPER_KEYS` are equal share one program.
    """
    groups: dict[str, list[int]] = {}
    for i, config in enumerate(configs):
        _, n_upd = pipeline.chunked_updates(config, chunks)
        config["TOTAL_TIMESTEPS"] = n_upd * config["NUM_ENVS"] * config["NUM_STEPS"]
        groups.setdefault(_structure(config), []).append(i)
    return groups


def sweep(
    name: str | Path = DEFAULT_CONFIG,
    overrides=(),
    settings_per_batch: int = 1,
    overwrite: bool = False,
    write: bool = True,
    quiet: bool = False,
    stop_at_headroom: float | None = None,
) -> dict:
    """Train and score every setting of a grid (see the module's docstring).

    Args:
        name: a bundled config's name or a TOML path (`baselines.config.load`).
        overrides: ``KEY=value`` and ``KEY=v1,v2,...`` strings (`parse_grid`).
        settings_per_batch: settings vmapped together within a compile group (1: each setting's
            numbers bit for bit those of its run alone); it must divide each group's settings.
        overwrite: replace the files of an earlier sweep at ``OUT``.
        write: write ``OUT.json``, ``OUT.md`` and ``OUT.params.msgpack``.
        quiet: print nothing but the progress bars.
        stop_at_headroom: stop a compile group's training after the first chunk at which
            every setting's mean headroom over seeds reaches this fraction (a time-to-score
            measurement; None: train the config's env-steps).

    Returns:
        The results (what ``OUT.json`` holds), with ``params``: each setting's final
        parameters (leading axis seed), in the order of ``results``.

    Raises:
        ConfigError: an unknown config, key or value (of any setting; `parse_grid`), a swept
            run key, ``settings_per_batch`` below 1 or not dividing every compile group's
            settings, or ``OUT`` an unusable prefix (`chargax_marl.core.checks.output_path`),
            all before anything trains.
        ValueError: ``stop_at_headroom`` not a finite number.
        baselines.runs.RunDirError: ``OUT``'s files exist (without ``overwrite``) or another
            live process writes them.
    """
    settings_per_batch = check_value(
        "settings_per_batch", settings_per_batch, _PER_BATCH, "--settings-per-batch:"
    )
    if stop_at_headroom is not None:
        stop_at_headroom = checks.number("stop_at_headroom", stop_at_headroom)
    fixed, grid = parse_grid(overrides)
    grid_settings = settings_of(grid)
    configs, run = [], None
    for setting in grid_settings:
        config, run_s = load(name, fixed + [_override(k, v) for k, v in setting.items()])
        run = run or run_s
        configs.append(config)
    algo = run["ALGO"]
    out = run["OUT"] if any(o.startswith("OUT=") for o in fixed) else f"outputs/sweep_{algo}"
    if write:
        try:
            out = checks.output_path("OUT", out, "prefix")
        except ValueError as e:
            raise ConfigError(str(e)) from None
    groups = compile_groups(configs, run["CHUNKS"])
    for g, members in enumerate(groups.values()):
        if len(members) % settings_per_batch:
            raise ConfigError(
                f"settings_per_batch={settings_per_batch} (--settings-per-batch) does not "
                f"divide compile group {g}'s {len(members)} settings: expected a divisor of "
                f"every group's size {[len(m) for m in groups.values()]}"
            )
    # every group's envs and trainer built before anything trains: a setting the env or the
    # trainer refuses is refused at once, not after the groups before it have trained
    prepared = []
    for members in groups.values():
        built = build_env_params(configs[members[0]])
        prepared.append(
            (
                validation_env(configs[members[0]], built),
                registry.make_train(algo, configs[members[0]], built[0]),
            )
        )
    train_and_score = functools.partial(
        _sweep, name, fixed, grid, grid_settings, configs, run, settings_per_batch, quiet
    )
    if not write:
        return train_and_score(groups, prepared, stop_at_headroom)
    with runs.claim_outputs(out, SUFFIXES, overwrite=overwrite):
        results = train_and_score(groups, prepared, stop_at_headroom)
        params = results.pop("params")
        runs.write_json(results, out + ".json")
        Path(out + ".md").write_text(ranked_table(results) + "\n")
        runs.save_params({str(i): p for i, p in enumerate(params)}, out + ".params.msgpack")
        results["params"] = params
        if not quiet:
            print(f"wrote {out}.json, {out}.md, {out}.params.msgpack")
    return results


def _sweep(
    name,
    fixed,
    grid,
    grid_settings,
    configs,
    run,
    settings_per_batch,
    quiet,
    groups,
    prepared,
    stop_at_headroom,
) -> dict:
    """`sweep` once its outputs are claimed (``groups``: `compile_groups`; ``prepared``: each
    group's validation env and trainer)."""
    t_start = time.time()
    algo, seeds, seed, chunks = run["ALGO"], run["SEEDS"], run["SEED"], run["CHUNKS"]
    optimal = "off" if run["OPTIMAL"] == "off" else "bound"
    keys = jax.random.split(jax.random.PRNGKey(seed), seeds)
    entries: list[dict | None] = [None] * len(configs)
    params: list = [None] * len(configs)
    group_records, references_cache = [], {}
    for g, members in enumerate(groups.values()):
        config = configs[members[0]]
        t_group = time.time()
        (val_params, val_days, val_draws), train = prepared[g]
        refs_key = json.dumps(
            [config[k] for k in ("SCENARIO", "TASK", "TRAFFIC", "ENV_KWARGS")]
            + [np.asarray(val_days).tolist(), val_draws],
            sort_keys=True,
        )
        if refs_key not in references_cache:
            if not quiet:
                print(
                    f"scoring always-max{'' if optimal == 'off' else ' and the LP bound'} on "
                    f"{np.size(val_days)} validation days x {val_draws} car draws"
                )
            references_cache[refs_key] = heldout.baseline_results(
                val_params, val_days, optimal=optimal, draws=val_draws
            )
        refs = references_cache[refs_key]
        am_daily = np.asarray(refs["always_max"]["daily_profit"], np.float64)
        bound_daily = refs.get("lp_bound", {}).get("daily_profit")
        make_act = train.make_act(val_params)
        hyper = {
            k: np.asarray([configs[i][k] for i in members], np.float32) for k in ppo_core.HYPER_KEYS
        }
        curves: list[list[dict]] = [[] for _ in members]
        eval_seconds = [0.0]  # the evaluations' time so far, left out of train_seconds

        def score(flat_params):
            ev = heldout.evaluate_batched(
                make_act, flat_params, val_params, val_days, draws=val_draws
            )
            return np.asarray(ev["daily_profit"], np.float64)  # (settings * seeds, days)

        def on_chunk(i, rs, m, steps, seconds, curves=curves, score=score, spent=eval_seconds):
            t_eval = time.time()
            flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), rs.params)
            daily = score(jax.device_get(flat)).reshape(len(curves), seeds, -1)
            train_seconds = seconds - spent[0]
            spent[0] += time.time() - t_eval
            for j, curve in enumerate(curves):
                curve.append(
                    {
                        "timesteps": int(steps),
                        "train_seconds": train_seconds,
                        "wall_seconds": seconds + time.time() - t_eval,
                        "per_seed_profit": daily[j].mean(axis=1).tolist(),
                        "mean_profit": float(daily[j].mean()),
                        "headroom": _headroom(daily[j], am_daily, bound_daily),
                    }
                )
            if stop_at_headroom is None:
                return False
            reached = [c[-1]["headroom"] for c in curves]
            return all(h is not None and h["mean"] >= stop_at_headroom for h in reached)

        rs, metrics, seconds = runner.run_settings_in_chunks(
            train,
            keys,
            hyper,
            pipeline.chunked_updates(config, chunks)[0],
            on_chunk,
            desc=f"{algo} group {g + 1}/{len(groups)}",
            settings_per_batch=settings_per_batch,
        )
        final_params = jax.device_get(rs.params)
        for j, i in enumerate(members):
            curve = curves[j]
            per_seed = np.asarray(curve[-1]["per_seed_profit"])
            diffs = per_seed - am_daily.mean()
            params[i] = jax.tree.map(lambda x, j=j: x[j], final_params)
            entries[i] = {
                "index": i,
                "setting": grid_settings[i],
                "group": g,
                "config": configs[i],
                "per_seed_profit": per_seed.tolist(),
                "mean_profit": float(per_seed.mean()),
                "vs_always_max": stats.over_seeds(diffs),
                "headroom": curve[-1]["headroom"],
                "eval_curve": curve,
                "train_curve": {
                    "timesteps": (
                        (np.arange(metrics["episode_profit_eur"].shape[2]) + 1)
                        * config["NUM_ENVS"]
                        * config["NUM_STEPS"]
                    ).tolist(),
                    "episode_profit_eur": metrics["episode_profit_eur"][j].tolist(),
                },
            }
        group_records.append(
            {
                "settings": members,
                "structure": {k: v for k, v in json.loads(_structure(config)).items()},
                "train_seconds": seconds,
                "wall_seconds": time.time() - t_group,
            }
        )
    ranking = sorted(range(len(entries)), key=lambda i: -entries[i]["mean_profit"])
    _, first_days, first_draws = validation_env(configs[0])
    results = {
        "algo": algo,
        "config": str(name),
        "fixed": fixed,
        "grid": grid,
        "seeds": seeds,
        "seed": seed,
        "chunks": chunks,
        "settings_per_batch": settings_per_batch,
        "validation": {
            "days": [int(d) for d in np.asarray(first_days)],
            "draws": int(first_draws),
            "references": {
                k: float(np.mean(v["daily_profit"]))
                for k, v in next(iter(references_cache.values())).items()
                if isinstance(v, dict) and "daily_profit" in v
            },
        },
        "results": entries,
        "ranking": ranking,
        "groups": group_records,
        "devices": [str(d) for d in jax.devices()],
        "code": code_version(),
        "wall_seconds": time.time() - t_start,
        "params": params,
    }
    if not quiet:
        print(ranked_table(results))
    return results


def _headroom(daily, am_daily, bound_daily) -> dict | None:
    """Per seed and over seeds, the fraction of the bound's headroom ``daily (seeds, days)``
    captures on the validation days; None without the bound."""
    if bound_daily is None:
        return None
    per_seed = [headroom_captured(d, am_daily, bound_daily)["fraction"] for d in daily]
    return {"per_seed": per_seed, **stats.over_seeds(per_seed)}


def ranked_table(results: dict) -> str:
    """The settings ranked by mean validation profit, as a Markdown table.

    Args:
        results: what `sweep` returns (or ``OUT.json`` holds).

    Returns:
        One row per setting: its swept values, the validation profit (mean and standard
        deviation over seeds), the difference to always-max (mean ± standard error over
        seeds), the headroom captured (when the bound was computed) and its compile group.
    """
    keys = list(results["grid"])
    head = ["rank", *keys, "profit EUR/day", "sd over seeds", "vs always-max", "headroom", "group"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for rank, i in enumerate(results["ranking"], 1):
        e = results["results"][i]
        vs, hr = e["vs_always_max"], e["headroom"]
        seeds_profit = np.asarray(e["per_seed_profit"])
        row = [
            str(rank),
            *(json.dumps(e["setting"][k]) for k in keys),
            f"{e['mean_profit']:.2f}",
            f"{seeds_profit.std(ddof=1) if seeds_profit.size > 1 else float('nan'):.2f}",
            f"{vs['mean']:+.2f} ± {vs['stderr']:.2f}",
            "–" if hr is None else f"{hr['mean']:.2f} ± {hr['stderr']:.2f}",
            str(e["group"]),
        ]
        lines.append("| " + " | ".join(row) + " |")
    days = len(results["validation"]["days"])
    lines.append(
        f"\n{results['algo'].upper()} `{results['config']}` {' '.join(results['fixed'])}: "
        f"{len(results['results'])} settings x {results['seeds']} seeds (first key "
        f"{results['seed']}), scored on {days} validation days x "
        f"{results['validation']['draws']} car draws; {len(results['groups'])} compile "
        f"group(s), {results['wall_seconds']:.0f} s"
    )
    return "\n".join(lines)


def _positive_int(text: str) -> int:
    """``--settings-per-batch``'s value: an integer >= 1, or argparse's error naming it."""
    try:
        return check_value("settings_per_batch", int(text), _PER_BATCH, "--settings-per-batch:")
    except (ValueError, ConfigError):
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None


def parser() -> argparse.ArgumentParser:
    """The command line: ``--config``, ``KEY=value`` / ``KEY=v1,v2`` arguments,
    ``--settings-per-batch`` and ``--overwrite``.

    Returns:
        The argument parser (its description the module docstring).
    """
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--config", default=DEFAULT_CONFIG, help="a bundled config or a TOML path")
    p.add_argument("overrides", nargs="*", metavar="KEY=v1,v2", help="keys to set or sweep")
    p.add_argument(
        "--settings-per-batch",
        type=_positive_int,
        default=1,
        help="settings vmapped together (default 1: bit for bit the runs alone)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an earlier sweep's files")
    return p


def main(argv=None) -> dict:
    """Run the command line ``argv`` (default ``sys.argv[1:]``); the sweep's results.

    Args:
        argv: the arguments (None: ``sys.argv[1:]``); ``--help`` lists them.

    Returns:
        `sweep`'s results, written to ``OUT.json``, ``OUT.md`` and ``OUT.params.msgpack``.

    Raises:
        ConfigError: an unknown config, key or value, or a swept run key (`sweep`).
        baselines.runs.RunDirError: ``OUT``'s files exist (without ``--overwrite``) or
            another live process writes them.
    """
    a = parser().parse_intermixed_args(argv)
    return sweep(a.config, a.overrides, a.settings_per_batch, a.overwrite)


if __name__ == "__main__":
    try:
        main()
    except (ValueError, runs.RunDirError) as e:  # ConfigError and the env's refusals
        sys.exit(f"baselines.sweep: {e}")
