"""Paper Fig. 4b-c: the satisfaction weights alpha vs missing kWh at departure and overtime.

    python -m baselines.experiments.alpha_ablation           # CPU default (2e6 steps, 4 seeds)
    python -m baselines.experiments.alpha_ablation --full    # the paper's budget (1e7 steps, 5 seeds)

For ``satisfaction_time`` (EUR per kWh still missing when a time-sensitive car leaves) and
``satisfaction_charge`` (EUR per minute a charge-sensitive car overstays) a PPO agent is
trained per alpha (reward = profit - alpha * term; all other alpha 0) and evaluated greedily
on the 100 held-out days. Writes ``outputs/alpha_ablation.{png,json}``: missing kWh
(resp. overtime) and profit vs alpha, mean ± std over seeds x days, the per-seed means, and
each alpha's paired difference to alpha 0 (mean ± standard error over seeds, the same days
and cars), beside always-max, always-max + battery rule and the LP hindsight bound (of the
profit).
"""

from __future__ import annotations

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from baselines import runs
from baselines.config import build_env_params, resolve
from baselines.eval.heldout import baseline_results
from baselines.eval.stats import paired_over_seeds
from baselines.experiments._common import (
    Record,
    config_of,
    output,
    parser,
    with_env_kwargs,
)
from baselines.pipeline import run

SMALL = {"satisfaction_time": (0.0, 0.5, 2.0), "satisfaction_charge": (0.0, 0.05, 0.5)}
FULL = {
    "satisfaction_time": (0.0, 0.1, 0.5, 1.0, 2.0, 5.0),
    "satisfaction_charge": (0.0, 0.01, 0.05, 0.1, 0.5, 1.0),
}
METRIC = {"satisfaction_time": "missing_kwh_at_departure", "satisfaction_charge": "overtime_min"}


def main(argv=None, out="outputs/alpha_ablation"):
    """The command line: train one agent per alpha of each term (`SMALL`, or `FULL` with
    ``--full``; alpha 0 trained once and shared by the terms), evaluate each on the held-out
    days, and write ``<out>.json`` and ``<out>.png`` (`plot`).

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.
        out: the path prefix of the result files.

    Returns:
        ``{term: {alpha: row}}``, each row with ``alpha``, ``metrics``, ``per_seed_profit``,
        ``per_seed`` (per-seed means of `TERMS`), ``vs_always_max``, ``wall_seconds``,
        ``timesteps`` and ``vs_alpha0`` (`baselines.eval.stats.paired_over_seeds` per term
        of `TERMS`).
    """
    args = parser(__doc__, full_seeds=5).parse_args(argv)
    with output(out, args.overwrite) as prefix:
        base, seeds = config_of(args)
        record = Record(args, seeds, base, paper_seeds=5, figure="Fig. 4b-c")
        grid = FULL if args.full else SMALL
        _, full_params, _, eval_days = build_env_params(resolve(base))
        baselines = baseline_results(full_params, eval_days, args.optimal)
        results = {term: {} for term in grid}
        zero = None
        for term, alphas in grid.items():
            for alpha in alphas:
                if alpha == 0.0 and zero is not None:
                    results[term][alpha] = zero
                    continue
                cfg = with_env_kwargs(base, alpha={term: alpha})
                # evaluation reports the raw terms (profit, missing kWh, overtime) on the held-out days
                res = run(
                    args.algo,
                    cfg,
                    seeds=seeds,
                    chunks=2,
                    evaluate_every_chunk=False,
                    baselines=baselines,
                    quiet=True,
                ).results
                ev = res["evaluation"]["table"][args.algo]
                row = {
                    "alpha": alpha,
                    "metrics": ev["metrics"],
                    "per_seed_profit": ev["per_seed_profit"],
                    "per_seed": {k: ev["per_seed_metrics"][k] for k in TERMS},
                    "vs_always_max": res["vs_always_max"],
                    "wall_seconds": res["wall_seconds"],
                    "timesteps": res["timesteps"],
                }
                results[term][alpha] = row
                if alpha == 0.0:
                    zero = row
                m = row["metrics"]
                print(
                    f"{term} alpha={alpha:g}: {METRIC[term]} {m[METRIC[term]]['mean']:.2f} ± {m[METRIC[term]]['std']:.2f}, "
                    f"profit {m['daily_profit_eur']['mean']:.1f} ({res['wall_seconds']:.0f} s)",
                    flush=True,
                )
        for term, rows in results.items():
            for row in rows.values():
                row["vs_alpha0"] = {
                    k: paired_over_seeds(row["per_seed"][k], zero["per_seed"][k])
                    for k in row["per_seed"]
                }
        meta = record.as_dict()
        runs.write_json(
            {
                **meta,
                "baselines": baselines,
                "results": {t: list(r.values()) for t, r in results.items()},
            },
            prefix + ".json",
        )
        plot(results, baselines, prefix + ".png")
        print(f"wrote {prefix}.png, {prefix}.json")
        print(Record.summary(meta))
        return results


TERMS = ("daily_profit_eur", "missing_kwh_at_departure", "overtime_min")


def _se(per_seed) -> float:
    x = np.asarray(per_seed, np.float64)
    return float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else 0.0


def plot(results, baselines, path):
    """Missing kWh, overtime and profit per alpha: means over seeds x days, error bars the
    standard error over seeds of the per-seed means.

    Args:
        results: `main`'s ``{term: {alpha: row}}``.
        baselines: `baselines.eval.heldout.baseline_results` of the held-out days
            (``always_max``; ``battery_rule`` and ``lp_bound`` drawn where present).
        path: the PNG file to write.
    """
    matplotlib.use("Agg")

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    labels = {
        "missing_kwh_at_departure": "kWh missing at departure",
        "overtime_min": "overtime (min per day)",
    }
    for ax, term in zip(axes[:2], results):
        rows = list(results[term].values())
        x = np.arange(len(rows))
        key = METRIC[term]
        ax.bar(
            x,
            [r["metrics"][key]["mean"] for r in rows],
            yerr=[_se(r["per_seed"][key]) for r in rows],
            capsize=3,
        )
        am = baselines["always_max"]["metrics"][key]["mean"]
        ax.axhline(am, ls="--", color="C3", label=f"always-max {am:.1f}")
        ax.set_xticks(x, [f"{r['alpha']:g}" for r in rows])
        ax.set_xlabel(f"alpha ({term})")
        ax.set_ylabel(labels[key])
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3, axis="y")
    ax = axes[2]
    for i, term in enumerate(results):
        rows = list(results[term].values())
        ax.errorbar(
            np.arange(len(rows)) + 0.1 * i,
            [r["metrics"]["daily_profit_eur"]["mean"] for r in rows],
            yerr=[_se(r["per_seed"]["daily_profit_eur"]) for r in rows],
            marker="o",
            capsize=3,
            label=term,
        )
    for i, name in enumerate(("always_max", "battery_rule", "lp_bound")):
        if name in baselines:
            v = baselines[name]["metrics"]["daily_profit_eur"]["mean"]
            ax.axhline(v, ls=("--", "-.", "-")[i], color=f"C{i + 3}", label=f"{name} {v:.0f}")
    ax.set_xlabel("alpha index (values on the left panels)")
    ax.set_ylabel("daily profit (EUR)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
