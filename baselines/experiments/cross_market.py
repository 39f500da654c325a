"""Cross-market price shift, beside the price-year shift of paper Fig. 5: train on one
market-year, evaluate on another.

    python -m baselines.experiments.cross_market                  # CPU default (2e6 steps, 4 seeds)
    python -m baselines.experiments.cross_market --full           # the paper's budget (1e7 steps, 5 seeds)
    python -m baselines.experiments.cross_market --no-reference   # skip the in-market agents

Sources -> targets: NL-2023 -> NL-2023, DE-2023, FR-2023 (same year, other markets) and
NL-2021 -> NL-2021, NL-2022, DE-2022, FR-2022 (into the 2022 price crisis, three markets).
Every target is also trained on itself (the in-market reference), so each cross-market score
comes with its transfer gap: the paired difference, on the same held-out days and cars
(common random numbers), between the source-trained agent and the target-trained one.

Writes ``outputs/cross_market.{png,json}``: greedy held-out daily profit (mean ± std
over seeds x days) per source x target, the in-market reference, always-max and
price-threshold per target, the paired differences to always-max and to the reference, and
the run's wall time.
"""

from __future__ import annotations

import time

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from baselines import runs
from baselines.eval import heldout, stats
from baselines.experiments._common import (
    Record,
    config_of,
    eval_setup,
    output,
    parser,
    profit_curve,
    train_on,
)

EXPERIMENTS = {
    "NL-2023": ("NL-2023", "DE-2023", "FR-2023"),
    "NL-2021": ("NL-2021", "NL-2022", "DE-2022", "FR-2022"),
}


def main(argv=None, out="outputs/cross_market", *, experiments=None, overrides=None):
    """``experiments`` ({source: targets}) and ``overrides`` (merged into the training config)
    are for tests; the command line runs `EXPERIMENTS`.

    Trains an agent per source (and, unless ``--no-reference``, per other target: the
    in-market references), evaluates each on its targets' held-out days, and writes
    ``<out>.json`` and ``<out>.png`` (`plot`).

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.
        out: the path prefix of the result files.
        experiments: ``{source market: target markets}``; ``None``: `EXPERIMENTS`.
        overrides: entries merged into the training config; ``None``: none.

    Returns:
        ``{trained market: {target: evaluation}}``, each evaluation a
        `baselines.eval.heldout.evaluate_batched` result with ``paired_diff`` to the target's
        always-max; an in-market reference is evaluated on its own market only.
    """
    p = parser(__doc__, full_seeds=5)
    p.add_argument(
        "--no-reference", action="store_true", help="do not train the in-market reference agents"
    )
    args = p.parse_args(argv)
    with output(out, args.overwrite) as prefix:
        base, seeds = config_of(args)
        base = {**base, **(overrides or {})}
        experiments = EXPERIMENTS if experiments is None else experiments
        t0 = time.time()
        record = Record(args, seeds, base, paper_seeds=5, figure="cross-market (beside Fig. 5)")
        markets = list(
            dict.fromkeys([m for src, targets in experiments.items() for m in (src, *targets)])
        )
        evals = {m: eval_setup(base, m, args.optimal) for m in markets}
        baselines = {m: e[2] for m, e in evals.items()}
        trained = list(experiments) + (
            [] if args.no_reference else [m for m in markets if m not in experiments]
        )
        matrix, trained_runs = {}, {}
        for src in trained:
            agent = train_on(args.algo, base, src, seeds, baselines[src])
            act, res = agent.trainer.make_act, agent.results
            matrix[src] = {}
            for tgt in experiments.get(src, (src,)):
                full, days, _ = evals[tgt]
                ev = heldout.evaluate_batched(
                    act(full),
                    agent.params,
                    full,
                    days,
                    reference_profit=baselines[tgt]["always_max"]["daily_profit"],
                )
                matrix[src][tgt] = ev
                m, d = ev["metrics"]["daily_profit_eur"], ev["paired_diff"]
                print(
                    f"train {src} -> eval {tgt}: {m['mean']:.1f} ± {m['std']:.1f} EUR/day "
                    f"(vs always-max {d['mean']:+.1f} ± {d['stderr']:.1f})",
                    flush=True,
                )
            trained_runs[src] = {
                "wall_seconds": res["wall_seconds"],
                "timesteps": res["timesteps"],
                "curve": profit_curve(res["curve"]),
            }
        gaps = transfer_gaps(matrix, experiments)
        wall = time.time() - t0
        plot(matrix, baselines, experiments, args.algo, prefix + ".png")
        meta = record.as_dict()
        runs.write_json(
            {
                **meta,
                "timesteps": trained_runs[trained[0]]["timesteps"],
                "experiments": {s: list(t) for s, t in experiments.items()},
                "evaluation": "greedy, held-out days of each target, PRNGKey(0) for every policy (common random numbers)",
                "wall_seconds_total": wall,
                "matrix": matrix,
                "transfer_gap_vs_in_market": gaps,
                "baselines": baselines,
                "runs": trained_runs,
            },
            prefix + ".json",
        )
        print(summary(matrix, baselines, gaps, experiments))
        print(f"wrote {prefix}.png, {prefix}.json ({wall:.0f} s wall)")
        return matrix


def transfer_gaps(matrix: dict, experiments: dict) -> dict:
    """{source: {target: paired difference (source-trained - target-trained) per seed x day}}
    for every cross target whose in-market agent was trained.

    Args:
        matrix: `main`'s ``{trained market: {target: evaluation}}``.
        experiments: ``{source market: target markets}``.

    Returns:
        ``{source: {target: difference}}``: `baselines.eval.stats.paired_difference` of the
        source-trained agent's ``(seeds, days)`` daily profits against the target-trained
        agent's per-day mean over its seeds, in EUR/day.
    """
    gaps = {}
    for src, targets in experiments.items():
        for tgt in targets:
            if tgt != src and tgt in matrix and tgt in matrix[tgt]:
                ref = np.asarray(matrix[tgt][tgt]["daily_profit"]).mean(axis=0)
                gaps.setdefault(src, {})[tgt] = stats.paired_difference(
                    matrix[src][tgt]["daily_profit"], ref
                )
    return gaps


def summary(matrix: dict, baselines: dict, gaps: dict, experiments: dict) -> str:
    """The plain-text summary: one line per source and target.

    Args:
        matrix: `main`'s ``{trained market: {target: evaluation}}``.
        baselines: ``{market: baseline results}`` with ``always_max`` and
            ``price_threshold``.
        gaps: `transfer_gaps`.
        experiments: ``{source market: target markets}``.

    Returns:
        A header line, then per source and target the mean held-out daily profits (EUR/day)
        of the source-trained agent, the in-market agent (``-`` when not trained),
        always-max and price-threshold, and the transfer gap when there is one.
    """
    lines = [
        "source -> target: source-trained | in-market | always-max | price-threshold EUR/day; gap to in-market"
    ]
    for src, targets in experiments.items():
        for tgt in targets:

            def mean(r):
                return r["metrics"]["daily_profit_eur"]["mean"]

            ref = (
                f"{mean(matrix[tgt][tgt]):7.1f}"
                if tgt in matrix and tgt in matrix[tgt]
                else "      -"
            )
            gap = gaps.get(src, {}).get(tgt)
            lines.append(
                f"  {src} -> {tgt}: {mean(matrix[src][tgt]):7.1f} | {ref} | {mean(baselines[tgt]['always_max']):7.1f}"
                f" | {mean(baselines[tgt]['price_threshold']):7.1f}"
                + (f"; {gap['mean']:+.1f} ± {gap['stderr']:.1f}" if gap else "")
            )
    return "\n".join(lines)


def plot(matrix, baselines, experiments, algo, path):
    """One panel per source: per target, the held-out daily profit of the source-trained and
    the target-trained agents (mean ± std over seeds × days), always-max and price-threshold,
    written as a PNG.

    Args:
        matrix: `main`'s ``{trained market: {target: evaluation}}``.
        baselines: ``{market: baseline results}`` with ``always_max`` and
            ``price_threshold``.
        experiments: ``{source market: target markets}``.
        algo: the algorithm's name, for the legend.
        path: the PNG file to write.
    """
    matplotlib.use("Agg")

    fig, axes = plt.subplots(
        1, len(experiments), figsize=(5.5 * len(experiments), 4), squeeze=False
    )
    w = 0.2
    for ax, (src, targets) in zip(axes[0], experiments.items()):
        x = np.arange(len(targets))

        def prof(r):
            return r["metrics"]["daily_profit_eur"]

        cross = [prof(matrix[src][t]) for t in targets]
        ax.bar(
            x - 1.5 * w,
            [c["mean"] for c in cross],
            w,
            yerr=[c["std"] for c in cross],
            capsize=2,
            label=f"{algo} trained on {src}",
        )
        ref = [prof(matrix[t][t]) if t in matrix and t in matrix[t] else None for t in targets]
        ax.bar(
            x - 0.5 * w,
            [r["mean"] if r else np.nan for r in ref],
            w,
            yerr=[r["std"] if r else 0.0 for r in ref],
            capsize=2,
            label=f"{algo} trained on the target",
        )
        ax.bar(
            x + 0.5 * w,
            [prof(baselines[t]["always_max"])["mean"] for t in targets],
            w,
            color="grey",
            label="always-max",
        )
        ax.bar(
            x + 1.5 * w,
            [prof(baselines[t]["price_threshold"])["mean"] for t in targets],
            w,
            color="silver",
            label="price-threshold",
        )
        ax.set_xticks(x, [f"eval {t}" for t in targets], fontsize=8)
        ax.set_title(f"trained on {src}", fontsize=10)
        ax.set_ylabel("held-out daily profit (EUR)")
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
