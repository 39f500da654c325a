"""Paper Fig. 4a: PPO in the shopping scenario at low / medium / high traffic vs always-max.

    python -m baselines.experiments.traffic_sweep            # small CPU default
    python -m baselines.experiments.traffic_sweep --full     # paper scale (1e7 steps, 20 seeds)

Writes ``baselines/results/traffic_sweep.{png,json}``: per traffic level the training
episode profit (mean ± std over seeds), the greedy held-out daily profit and the
always-max / price-threshold baselines on the same 100 held-out days.
"""

from __future__ import annotations

import numpy as np

from baselines import common
from baselines.experiments._common import config_of, parser
from baselines.train import run

TRAFFIC = ("low", "medium", "high")


def main(argv=None, out="baselines/results/traffic_sweep"):
    args = parser(__doc__, 3e5, 2, 20).parse_args(argv)
    base, seeds = config_of(args)
    results = {}
    for traffic in TRAFFIC:
        cfg = {**base, "SCENARIO": "shopping", "TRAFFIC": traffic}
        res = run(args.algo, cfg, seeds=seeds, chunks=4, evaluate_every_chunk=False, quiet=True)
        results[traffic] = {k: v for k, v in res.items() if not k.startswith("_")}
        t = res["evaluation"]["table"]
        print(f"{traffic:>6}: {args.algo} {t[args.algo]['metrics']['daily_profit_eur']['mean']:.1f} | always-max "
              f"{t['always_max']['metrics']['daily_profit_eur']['mean']:.1f} | price-threshold "
              f"{t['price_threshold']['metrics']['daily_profit_eur']['mean']:.1f} EUR/day "
              f"({res['wall_seconds']:.0f} s)", flush=True)
    plot(results, args.algo, out + ".png")
    common.write_json({"algo": args.algo, "full": args.full, "seeds": seeds, "results": results}, out + ".json")
    print(f"wrote {out}.png, {out}.json")
    return results


def plot(results, algo, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(4.2 * len(results), 3.6))
    for ax, (traffic, res) in zip(np.atleast_1d(axes), results.items()):
        t = np.asarray(res["curve"]["timesteps"])
        m, s = common.seed_mean_std(res["curve"]["episode_profit_eur"])
        ax.plot(t, m, label=f"{algo} (training, sampled)")
        ax.fill_between(t, m - s, m + s, alpha=0.25)
        table = res["evaluation"]["table"]
        ev = table[algo]["metrics"]["daily_profit_eur"]
        ax.errorbar([t[-1]], [ev["mean"]], yerr=[np.std(table[algo]["per_seed_profit"])], fmt="o",
                    label=f"{algo} held-out greedy {ev['mean']:.0f}")
        for i, name in enumerate(("always_max", "battery_rule", "price_threshold")):
            v = table[name]["metrics"]["daily_profit_eur"]["mean"]
            ax.axhline(v, ls=("--", "-.", ":")[i], color=f"C{i + 3}", label=f"{name} {v:.0f}")
        ax.set_title(f"shopping, {traffic} traffic")
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    np.atleast_1d(axes)[0].set_ylabel("daily profit (EUR)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
