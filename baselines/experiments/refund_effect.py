"""The V2G refund and a learned agent: PPO trained with and without refunding discharged car energy.

    python -m baselines.experiments.refund_effect                 # CPU default (2e6 steps, 4 seeds)
    python -m baselines.experiments.refund_effect --fleets EU     # one fleet

The original Chargax never refunds energy discharged from a customer's car, so taking energy
back from a car before it leaves earns money there (``make_params(refund_discharged_energy=False)``
reproduces that accounting; ``python -m baselines.experiments.refund`` shows what it is worth to fixed
rules). Here PPO is trained under each accounting on the default scenario (the ``tuned``
settings, see ``_common.TUNED``), for the bundled EU fleet (11 % of the cars may discharge) and
for the EU fleet with every model allowed to discharge (``baselines.experiments.refund.all_v2g``). Each
agent is then evaluated greedily under **both** accountings on the same 100 held-out days and
cars. The refund changes the books, not the trajectory, so for one agent ``off - on`` is exactly
what its car discharging earned from not refunding the owners.

Writes ``outputs/refund_effect.{png,json}``: per fleet, trained-on x evaluated-on,
the daily profit and its paired difference to always-max under the same accounting (mean ±
standard error over seeds, the same days and cars), and always-max, always-max + battery
rule, ``discharge_departing`` and the LP hindsight bound under each accounting.
"""

from __future__ import annotations

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from baselines import runs
from baselines.config import build_env_params, resolve
from baselines.eval import heldout
from baselines.eval.rules import add_paired_differences, evaluate_rules
from baselines.eval.stats import paired_over_seeds
from baselines.experiments._common import (
    Record,
    config_of,
    output,
    parser,
    with_env_kwargs,
)
from baselines.experiments.refund import RULES, all_v2g
from baselines.pipeline import run
from chargax_marl.evaluation import hindsight_bound, summarize_profit

FLEETS = ("EU", "EU-all-v2g")
ACCOUNTS = {True: "refund", False: "no_refund"}


def fleet_of(name: str):
    """The ``fleet`` argument of ``make_params`` for a fleet name of `FLEETS`.

    Args:
        name: ``"EU-all-v2g"`` or a bundled fleet's name.

    Returns:
        `baselines.experiments.refund.all_v2g` of the EU fleet for ``"EU-all-v2g"``, else
        ``name`` itself.
    """
    return all_v2g("EU") if name == "EU-all-v2g" else name


def main(argv=None, out="outputs/refund_effect"):
    """The command line: per fleet of ``--fleets``, train an agent with and without the
    refund, evaluate each under both accountings, and write ``<out>.json`` and
    ``<out>.png`` (`plot`).

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.
        out: the path prefix of the result files.

    Returns:
        ``{fleet: {"references", "agents"}}``: ``references`` per accounting
        (``"refund"``, ``"no_refund"``) the `references` entries; ``agents`` per training
        accounting (``trained_refund``, ``trained_no_refund``) ``wall_seconds``,
        ``timesteps``, a `baselines.eval.heldout.evaluate_batched` result per evaluation
        accounting, and ``off_minus_on`` (`baselines.eval.stats.paired_over_seeds`).
    """
    p = parser(__doc__, full_seeds=5)
    p.add_argument("--fleets", nargs="+", choices=FLEETS, default=list(FLEETS))
    args = p.parse_args(argv)
    with output(out, args.overwrite) as prefix:
        base, seeds = config_of(args)
        record = Record(
            args, seeds, base, paper_seeds=None, figure="refund effect (the original's accounting)"
        )
        results = {}
        for fleet in args.fleets:
            setups = {}
            for refund in (True, False):
                cfg = with_env_kwargs(base, fleet=fleet_of(fleet), refund_discharged_energy=refund)
                _, full, _, days = build_env_params(resolve(cfg))
                setups[refund] = (cfg, full, days, references(full, days, args.optimal))
            results[fleet] = {
                "references": {ACCOUNTS[r]: s[3] for r, s in setups.items()},
                "agents": {},
            }
            for train_refund, (cfg, *_rest) in setups.items():
                trained = run(
                    args.algo,
                    cfg,
                    seeds=seeds,
                    chunks=2,
                    evaluate_every_chunk=False,
                    baselines=setups[train_refund][3],
                    quiet=True,
                )
                res = trained.results
                row = {"wall_seconds": res["wall_seconds"], "timesteps": res["timesteps"]}
                for eval_refund, (_, full, days, refs) in setups.items():
                    ev = heldout.evaluate_batched(
                        trained.trainer.make_act(full),
                        trained.params,
                        full,
                        days,
                        reference_profit=refs["always_max"]["daily_profit"],
                    )
                    row[ACCOUNTS[eval_refund]] = ev
                row["off_minus_on"] = paired_over_seeds(
                    row["no_refund"]["daily_profit"], row["refund"]["daily_profit"]
                )
                results[fleet]["agents"][f"trained_{ACCOUNTS[train_refund]}"] = row
                print(
                    f"{fleet}, trained with {ACCOUNTS[train_refund]}: "
                    + "; ".join(
                        f"evaluated with {ACCOUNTS[e]} {row[ACCOUNTS[e]]['metrics']['daily_profit_eur']['mean']:.1f} EUR/day "
                        f"(vs always-max {row[ACCOUNTS[e]]['paired_diff']['mean']:+.2f} ± "
                        f"{row[ACCOUNTS[e]]['paired_diff']['stderr']:.2f})"
                        for e in (True, False)
                    )
                    + f"; off - on {row['off_minus_on']['mean']:+.2f} ({res['wall_seconds']:.0f} s)",
                    flush=True,
                )
        meta = record.as_dict()
        runs.write_json(
            {
                **meta,
                "fleets": {
                    f: "bundled EU fleet"
                    if f == "EU"
                    else "EU fleet, every model may discharge at its charging limit"
                    for f in args.fleets
                },
                "results": results,
            },
            prefix + ".json",
        )
        plot(results, args.algo, prefix + ".png")
        print(f"wrote {prefix}.png, {prefix}.json")
        print(Record.summary(meta))
        return results


def references(params, days, optimal: str) -> dict:
    """The refund rules (always-max, battery rule, discharge departing) and, unless ``optimal``
    is ``"off"``, the LP hindsight bound, on ``days`` with the evaluation key.

    Args:
        params: the env parameters (one accounting).
        days: the held-out days.
        optimal: ``"off"`` leaves the bound out; any other value adds it.

    Returns:
        ``{name: entry}`` per rule of `baselines.experiments.refund.RULES` (and
        ``lp_bound``: ``daily_profit``, ``metrics``), each with ``vs_always_max``.
    """
    out = evaluate_rules(params, days, RULES)
    if optimal != "off":
        bound = hindsight_bound(params, days)["daily_profit"]
        out["lp_bound"] = {"daily_profit": bound, "metrics": summarize_profit(bound)}
    return add_paired_differences(out, ("always_max",))


def plot(results: dict, algo: str, path):
    """Per fleet, the paired difference to always-max (same accounting) of the rules and of the
    agents trained with / without the refund, evaluated with / without it.

    Bars: the rules after always-max and the bound (± standard error over days), and each
    agent (mean over seeds of the per-seed differences ± standard error over seeds), on a
    symlog axis; written as a PNG.

    Args:
        results: `main`'s ``{fleet: {"references", "agents"}}``.
        algo: the algorithm's name, for the labels.
        path: the PNG file to write.
    """
    matplotlib.use("Agg")

    fig, axes = plt.subplots(1, len(results), figsize=(5.5 * len(results), 3.8), squeeze=False)
    for ax, (fleet, res) in zip(axes[0], results.items()):
        labels, on, off, on_err, off_err = [], [], [], [], []
        for name in RULES[1:] + ("lp_bound",):
            if name in res["references"]["refund"]:
                labels.append(name)
                for acc, vals, errs in (("refund", on, on_err), ("no_refund", off, off_err)):
                    d = res["references"][acc][name]["vs_always_max"]
                    vals.append(d["mean"])
                    errs.append(d["stderr"])
        for trained, row in res["agents"].items():
            labels.append(f"{algo} {trained.replace('_', ' ')}")
            for acc, vals, errs in (("refund", on, on_err), ("no_refund", off, off_err)):
                per_seed = np.asarray(row[acc]["paired_diff"]["per_seed_mean"])
                vals.append(float(per_seed.mean()))
                errs.append(
                    float(per_seed.std(ddof=1) / np.sqrt(per_seed.size))
                    if per_seed.size > 1
                    else 0.0
                )
        x = np.arange(len(labels))
        ax.bar(
            x - 0.2, on, 0.4, yerr=on_err, capsize=2, label="evaluated with the refund (default)"
        )
        ax.bar(
            x + 0.2, off, 0.4, yerr=off_err, capsize=2, label="evaluated without it (the original)"
        )
        ax.axhline(0, color="black", lw=0.8)
        ax.set_yscale("symlog", linthresh=10)  # the bound without the refund is two orders larger
        ax.set_xticks(x, labels, rotation=20, ha="right", fontsize=8)
        ax.set_ylabel("EUR/day vs always-max (symlog)")
        ax.set_title(f"shopping, {fleet} fleet")
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
