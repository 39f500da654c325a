"""Paper Fig. 5: distribution shift in prices. Train on NL 2021, 2022, 2023; evaluate each
agent on the held-out days of all three years.

    python -m baselines.experiments.price_shift              # small CPU default
    python -m baselines.experiments.price_shift --full       # paper scale (1e7 steps, 5 seeds)

Writes ``baselines/results/price_shift.{png,json}``: the train-year x eval-year matrix of
greedy held-out daily profit (mean ± std over seeds x days) next to always-max per year.
"""

from __future__ import annotations

import numpy as np

from baselines import common
from baselines.experiments._common import config_of, eval_setup, parser, train_on

YEARS = ("NL-2021", "NL-2022", "NL-2023")


def main(argv=None, out="baselines/results/price_shift"):
    args = parser(__doc__, 3e5, 2, 5).parse_args(argv)
    base, seeds = config_of(args)
    evals = {year: eval_setup(base, year) for year in YEARS}
    matrix, rows = {}, {}
    for train_year in YEARS:
        res = train_on(args.algo, base, train_year, seeds, evals[train_year][2])
        train = res["_train"]
        matrix[train_year] = {}
        for eval_year, (full, days, _) in evals.items():
            ev = common.evaluate_batched(train.make_act(full), res["_params"], full, days)
            matrix[train_year][eval_year] = ev
            print(f"train {train_year} -> eval {eval_year}: {ev['metrics']['daily_profit_eur']['mean']:.1f} "
                  f"± {ev['metrics']['daily_profit_eur']['std']:.1f} EUR/day", flush=True)
        rows[train_year] = {"wall_seconds": res["wall_seconds"], "timesteps": res["timesteps"],
                            "curve": res["curve"]}
    baselines = {y: e[2] for y, e in evals.items()}
    plot(matrix, baselines, args.algo, out + ".png")
    common.write_json({"algo": args.algo, "full": args.full, "seeds": seeds, "matrix": matrix,
                       "baselines": baselines, "runs": rows}, out + ".json")
    print(f"wrote {out}.png, {out}.json")
    return matrix


def plot(matrix, baselines, algo, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4))
    x = np.arange(len(YEARS))
    w = 0.2
    for i, ty in enumerate(YEARS):
        ys = [matrix[ty][ey]["metrics"]["daily_profit_eur"] for ey in YEARS]
        ax.bar(x + (i - 1.5) * w, [y["mean"] for y in ys], w, yerr=[y["std"] for y in ys], capsize=2,
               label=f"{algo} trained on {ty}")
    am = [baselines[ey]["always_max"]["metrics"]["daily_profit_eur"]["mean"] for ey in YEARS]
    ax.bar(x + 1.5 * w, am, w, color="grey", label="always-max")
    ax.set_xticks(x, [f"eval {y}" for y in YEARS])
    ax.set_ylabel("held-out daily profit (EUR)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
