"""Paper Fig. 5: distribution shift in prices. Train on NL 2021, 2022, 2023; evaluate each
agent on the held-out days of all three years.

    python -m baselines.experiments.price_shift              # CPU default (2e6 steps, 4 seeds)
    python -m baselines.experiments.price_shift --full       # the paper's budget (1e7 steps, 10 seeds)

Writes ``outputs/price_shift.{png,json}``: the train-year x eval-year matrix of
greedy held-out daily profit (mean ± std over seeds x days), each cell's paired difference
to always-max, to always-max + battery rule and to always-max + battery programme (the
battery shaping's teacher as a rule) on the eval year's held-out days and cars
(mean ± standard error), and the fraction of that year's hindsight headroom captured, beside
always-max, the battery rule and the LP hindsight bound per year. (The paper evaluates on
36,500 episodes per agent; here every agent meets each year's same 100 held-out days.)
"""

from __future__ import annotations

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from baselines import runs
from baselines.eval import heldout, stats
from baselines.eval.heldout import add_headroom
from baselines.experiments._common import (
    Record,
    config_of,
    eval_setup,
    output,
    parser,
    profit_curve,
    train_on,
)

YEARS = ("NL-2021", "NL-2022", "NL-2023")


def main(argv=None, out="outputs/price_shift"):
    """The command line: train on each year of `YEARS`, evaluate every agent on every year's
    held-out days, and write ``<out>.json`` and ``<out>.png`` (`plot`).

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.
        out: the path prefix of the result files.

    Returns:
        ``{train year: {eval year: evaluation}}``, each a
        `baselines.eval.heldout.evaluate_batched` result with ``paired_diff`` (to the eval
        year's always-max), ``vs_battery_rule``, ``vs_<teacher rule>`` where the year has
        them, and ``headroom`` when the year's baselines hold the LP bound.
    """
    args = parser(__doc__, full_seeds=10).parse_args(argv)
    with output(out, args.overwrite) as prefix:
        base, seeds = config_of(args)
        record = Record(args, seeds, base, paper_seeds=10, figure="Fig. 5")
        evals = {year: eval_setup(base, year, args.optimal) for year in YEARS}
        matrix, rows = {}, {}
        for train_year in YEARS:
            trained = train_on(args.algo, base, train_year, seeds, evals[train_year][2])
            train, res = trained.trainer, trained.results
            matrix[train_year] = {}
            for eval_year, (full, days, bl) in evals.items():
                ev = heldout.evaluate_batched(
                    train.make_act(full),
                    trained.params,
                    full,
                    days,
                    reference_profit=bl["always_max"]["daily_profit"],
                )
                ev["vs_battery_rule"] = stats.paired_difference(
                    ev["daily_profit"], bl["battery_rule"]["daily_profit"]
                )
                for name in (
                    n for n in ("battery_programme", "plan_programme") if n in bl
                ):  # the teachers' rules
                    ev[f"vs_{name}"] = stats.paired_difference(
                        ev["daily_profit"], bl[name]["daily_profit"]
                    )
                add_headroom({"agent": ev}, bl)
                matrix[train_year][eval_year] = ev
                d, r = ev["paired_diff"], ev["vs_battery_rule"]
                print(
                    f"train {train_year} -> eval {eval_year}: {ev['metrics']['daily_profit_eur']['mean']:.1f} EUR/day; "
                    f"vs always-max {d['mean']:+.2f} ± {d['stderr']:.2f}, vs battery rule {r['mean']:+.2f} ± "
                    f"{r['stderr']:.2f}",
                    flush=True,
                )
            rows[train_year] = {
                "wall_seconds": res["wall_seconds"],
                "timesteps": res["timesteps"],
                "curve": profit_curve(res["curve"]),
            }
        baselines = {y: e[2] for y, e in evals.items()}
        meta = record.as_dict()
        runs.write_json(
            {**meta, "matrix": matrix, "baselines": baselines, "runs": rows}, prefix + ".json"
        )
        plot(matrix, baselines, args.algo, prefix + ".png")
        print(f"wrote {prefix}.png, {prefix}.json")
        print(Record.summary(meta))
        return matrix


def plot(matrix, baselines, algo, path):
    """Grouped bars per eval year: each train year's agent (mean held-out daily profit, error
    bar the std over seeds of the per-seed means) beside the references every year has
    (always-max, the battery rule, the teachers' rules, the LP bound), written as a PNG.

    Args:
        matrix: `main`'s ``{train year: {eval year: evaluation}}``.
        baselines: ``{eval year: baseline results}``.
        algo: the algorithm's name, for the legend.
        path: the PNG file to write.
    """
    matplotlib.use("Agg")

    fig, ax = plt.subplots(figsize=(7.5, 4))
    x = np.arange(len(YEARS))
    refs = [
        (n, c)
        for n, c in (
            ("always_max", "grey"),
            ("battery_rule", "dimgrey"),
            ("battery_programme", "tan"),
            ("plan_programme", "peru"),
            ("lp_bound", "black"),
        )
        if all(n in baselines[ey] for ey in YEARS)
    ]
    w = 0.8 / (len(YEARS) + len(refs))
    for i, ty in enumerate(YEARS):
        ys = [matrix[ty][ey]["metrics"]["daily_profit_eur"] for ey in YEARS]
        ax.bar(
            x + (i - (len(YEARS) + len(refs) - 1) / 2) * w,
            [y["mean"] for y in ys],
            w,
            yerr=[np.std(matrix[ty][ey]["per_seed_profit"]) for ey in YEARS],
            capsize=2,
            label=f"{algo} trained on {ty}",
        )
    for j, (name, color) in enumerate(refs):
        v = [baselines[ey][name]["metrics"]["daily_profit_eur"]["mean"] for ey in YEARS]
        ax.bar(
            x + (len(YEARS) + j - (len(YEARS) + len(refs) - 1) / 2) * w,
            v,
            w,
            color=color,
            label=name,
        )
    ax.set_xticks(x, [f"eval {y}" for y in YEARS])
    ax.set_ylabel("held-out daily profit (EUR)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
