"""What a training option costs or buys, on the same held-out days and cars: trained runs
against a reference run, seed against seed, and against always-max, in profit and in the
service metrics.

Each run is scored as it was trained (a run trained through an observation delay or action
loss plays under them: `chargax_marl.marl.communicating_act`) on its config's held-out
days, under ``--draws`` car draws per day (`baselines.eval.protocol.draw_keys`); a day's
figure is the mean over its draws of the day's metric. For every metric, the comparison gives
the mean of each side over seeds x days and the paired difference ``run - reference``
(seed ``i`` against seed ``i``, day against day) with two standard errors: over the seeds'
mean differences, and over the seeds x days differences.

    python -m baselines.experiments.service_effects --draws 1 \\
        --compare fairness outputs/d_fair outputs/d_base --out results/service_effects.json
    python -m baselines.experiments.service_effects --table results/service_effects.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from baselines import runs
from baselines.config import build_env_params
from baselines.eval import protocol
from baselines.eval.heldout import compiled_evaluation
from chargax_marl import policies
from chargax_marl.core import checks
from chargax_marl.evaluation import run_days, service_metrics

METRICS = ("daily_profit_eur", "jain_index", "min_satisfaction", "mean_satisfaction")
"""The metrics compared, each per day."""


def daily_metrics(totals) -> dict[str, np.ndarray]:
    """`METRICS` of episode totals with any leading axes (float64).

    Args:
        totals: `EpisodeTotals` with any leading axes (e.g. ``(seeds, days)``).

    Returns:
        ``{metric: array}`` per name of `METRICS`, each of the totals' leading shape: the
        profit in EUR/day and the service metrics of
        `chargax_marl.evaluation.service_metrics`.
    """
    out = {"daily_profit_eur": np.asarray(totals.profit_eur, np.float64)}
    service = service_metrics(totals)
    out.update({m: service[m] for m in METRICS if m != "daily_profit_eur"})
    return out


def _mean_over_keys(evaluate, keys) -> dict[str, np.ndarray]:
    per_key = [daily_metrics(jax.device_get(evaluate(k))) for k in keys]
    return {m: np.mean([d[m] for d in per_key], axis=0) for m in METRICS}


def score_run(run_dir, draws: int) -> dict:
    """Every seed of a run on its held-out days: ``{"days", "config", metric: (seeds, days)}``,
    plus always-max's ``(days,)`` on the same days and cars under ``"always_max"``.

    Args:
        run_dir: an output directory of ``baselines.train`` (``results.json``,
            ``params.msgpack``).
        draws: car draws per held-out day (`baselines.eval.protocol.draw_keys`); every
            metric is the mean over a day's draws.

    Returns:
        ``{metric: (seeds, days) array}`` per name of `METRICS`, ``"always_max"``
        (``{metric: (days,) array}``), ``"days"`` (the held-out day indices) and
        ``"config"`` (the run's stored config).

    Raises:
        ValueError: ``draws`` is not a positive integer
            (`baselines.eval.protocol.draw_keys`).
    """
    results, train, params = runs.load_run(run_dir)
    _, eval_params, _, days = build_env_params(train.config)
    days = jnp.asarray(days, jnp.int32)
    keys = protocol.draw_keys(draws)
    learned = compiled_evaluation(train.make_act(eval_params), eval_params)
    out = _mean_over_keys(lambda k: learned(params, days, k), keys)
    always = jax.jit(
        lambda d, k: run_days(
            lambda s, kk: policies.always_max(s, kk, eval_params), eval_params, d, k
        )
    )
    return {
        **out,
        "always_max": _mean_over_keys(lambda k: always(days, k), keys),
        "days": np.asarray(days).tolist(),
        "config": results["config"],
    }


def paired(a: np.ndarray, b: np.ndarray) -> dict:
    """``a - b`` with ``a`` ``(seeds, days)`` and ``b`` ``(seeds, days)`` or ``(days,)``: the
    mean, its standard error over the seeds' mean differences (NaN for one seed) and over
    the seeds x days differences, and each seed's mean difference.

    Args:
        a: ``(seeds, days)`` numbers of the run.
        b: ``(seeds, days)`` or ``(days,)`` numbers of the reference.

    Returns:
        ``{"mean", "stderr_seeds", "stderr_seed_days", "per_seed"}`` in the numbers' unit.
    """
    d = np.asarray(a, np.float64) - np.broadcast_to(np.asarray(b, np.float64), np.shape(a))
    per_seed = d.mean(axis=1)
    seeds = per_seed.size
    return {
        "mean": float(d.mean()),
        "stderr_seeds": float(per_seed.std(ddof=1) / np.sqrt(seeds)) if seeds > 1 else np.nan,
        "stderr_seed_days": float(d.std(ddof=1) / np.sqrt(d.size)),
        "per_seed": per_seed.tolist(),
    }


def compare(name: str, run: dict, reference: dict) -> dict:
    """One comparison's record: both runs' means and the paired differences per metric.

    Args:
        name: the comparison's label.
        run: `score_run` of the run.
        reference: `score_run` of the reference run.

    Returns:
        ``{"name", "seeds", metric: {...}}``, per name of `METRICS` the means over seeds ×
        days of the run, the reference and always-max (on the run's cars), and `paired`
        differences ``vs_reference`` and ``vs_always_max``.

    Raises:
        ValueError: the run and the reference were held out on different days.
    """
    if run["days"] != reference["days"]:
        raise ValueError(f"{name}: the run and its reference were held out on different days")
    out = {"name": name, "seeds": int(np.shape(run["daily_profit_eur"])[0])}
    for m in METRICS:
        out[m] = {
            "run": float(np.mean(run[m])),
            "reference": float(np.mean(reference[m])),
            "always_max": float(np.mean(run["always_max"][m])),
            "vs_reference": paired(run[m], reference[m]),
            "vs_always_max": paired(run[m], run["always_max"][m]),
        }
    return out


def table(record: dict) -> str:
    """A markdown table of a result file: one row per comparison and metric.

    Args:
        record: ``{"comparisons": [compare record]}``, a result file of `main`.

    Returns:
        The table: per comparison and metric the run's, the reference's and always-max's
        means and the differences to the reference and to always-max with their standard
        errors.
    """
    lines = [
        "| comparison | metric | run | reference | always-max | run - reference "
        "(± se seeds; ± se seeds x days) | run - always-max (± se seeds x days) |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in record["comparisons"]:
        for m in METRICS:
            r = c[m]
            v, a = r["vs_reference"], r["vs_always_max"]
            digits = 2 if m == "daily_profit_eur" else 4
            lines.append(
                f"| {c['name']} | {m} | {r['run']:.{digits}f} | {r['reference']:.{digits}f} "
                f"| {r['always_max']:.{digits}f} | {v['mean']:+.{digits}f} "
                f"(± {v['stderr_seeds']:.{digits}f}; ± {v['stderr_seed_days']:.{digits}f}) "
                f"| {a['mean']:+.{digits}f} (± {a['stderr_seed_days']:.{digits}f}) |"
            )
    return "\n".join(lines)


def main(argv=None) -> dict | None:
    """The command line: ``--table FILE`` prints a result file's table; otherwise every
    ``--compare NAME RUN REFERENCE`` is scored (each run directory once) and its table
    printed, and with ``--out`` the comparisons are written to that JSON file, replacing
    those of the same names and keeping the others.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        ``None`` with ``--table``; otherwise ``{"comparisons": [...]}``: the `compare`
        records with ``run``, ``reference`` and ``draws`` (with ``--out`` onto an existing
        file, also the comparisons kept from it).

    Raises:
        SystemExit: neither ``--compare`` nor ``--table`` is given (``argparse`` exits with
            status 2).
    """
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--compare",
        nargs=3,
        action="append",
        default=[],
        metavar=("NAME", "RUN", "REFERENCE"),
        help="a comparison: its label, the run's directory and the reference run's",
    )
    parser.add_argument("--draws", type=int, default=1, help="car draws per held-out day")
    parser.add_argument(
        "--out",
        default=None,
        type=checks.output_option("file"),
        help="add the comparisons to this JSON file",
    )
    parser.add_argument("--table", default=None, help="print the table of this result file")
    args = parser.parse_args(argv)
    if args.table:
        print(table(json.loads(Path(args.table).read_text())))
        return None
    if not args.compare:
        parser.error("give at least one --compare NAME RUN REFERENCE, or --table FILE")
    start = time.perf_counter()
    scored: dict[str, dict] = {}
    comparisons = []
    for name, run_dir, ref_dir in args.compare:
        for d in (run_dir, ref_dir):
            if d not in scored:
                print(f"scoring {d} ({args.draws} draws per day)", flush=True)
                scored[d] = score_run(d, args.draws)
        c = compare(name, scored[run_dir], scored[ref_dir])
        c.update({"run": run_dir, "reference": ref_dir, "draws": args.draws})
        comparisons.append(c)
    record = {"comparisons": comparisons}
    if args.out:
        path = Path(args.out)
        if path.exists():  # keep the other comparisons of the file
            kept = [
                c
                for c in json.loads(path.read_text())["comparisons"]
                if c["name"] not in {x["name"] for x in comparisons}
            ]
            record = {"comparisons": kept + comparisons}
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(record, indent=1))
    print(table({"comparisons": comparisons}))
    print(f"({time.perf_counter() - start:.0f} s)")
    return record


if __name__ == "__main__":
    main()
