r"""Paper Fig. 4a: PPO in the shopping scenario at low / medium / high traffic vs always-max.

    python -m baselines.experiments.traffic_sweep            # CPU default (2e6 steps, 4 seeds)
    python -m baselines.experiments.traffic_sweep --full     # the paper's budget (1e7 steps, 20 seeds)
    python -m baselines.experiments.traffic_sweep --appendix # also the appendix: every profile and fleet

Writes ``outputs/traffic_sweep.{png,json}``: per traffic level the training
episode profit (mean ± std over seeds), the greedy held-out daily profit, its paired
difference to always-max, to always-max + battery rule and to the teachers' rules
(``battery_programme``, ``plan_programme``: the shaping teachers played as rules), the
fraction of the hindsight headroom it captures, and always-max / battery rule / the teachers'
rules / price-threshold / the LP hindsight bound on the same 100 held-out days and cars.

``--appendix`` repeats the sweep for the four bundled user profiles (shopping, residential,
workplace, highway; EU fleet) and for the US and World fleets (shopping) and also writes
``outputs/traffic_sweep_appendix.{png,json}`` (the ``--out`` prefix with ``_appendix``);
``--profiles`` / ``--fleets`` pick conditions by hand (every profile with the first fleet,
then the first profile with every other fleet). Shopping with the EU fleet is the main figure
whenever it is among them.

``--traffic`` picks traffic levels. ``--reuse medium=DIR/results.json`` (or
``highway/EU/high=...`` for another condition) takes a cell from a run ``baselines.train``
already made with the same settings, seeds and budget (checked; a mismatch is an error)
instead of training it again, so a paper-scale sweep can be built a cell at a time, e.g.::

    python -m baselines.train --algo ppo --scenario highway --traffic high --seeds 20 --timesteps 1e7 \
        --chunks 4 --gamma 0.95 --relative-prices on --env-kwargs '{"num_levels": 1}' \
        --battery-shaping dp --split-credit on --out runs/highway_EU_high

The result file names the reused files and adds their wall time (``reused``,
``wall_seconds_with_reused``).
"""

from __future__ import annotations

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from baselines import runs
from baselines.experiments._common import (
    Record,
    config_of,
    output,
    parser,
    profit_curve,
    reused_run,
    with_env_kwargs,
)
from baselines.pipeline import run
from chargax_marl.core import checks

TRAFFIC = ("low", "medium", "high")
PROFILES = ("shopping", "residential", "workplace", "highway")
FLEETS = ("EU", "US", "World")


def conditions(profiles=("shopping",), fleets=("EU",)) -> list[tuple[str, str]]:
    """``(profile, fleet)`` pairs: every profile with the first fleet, then the first profile
    with each other fleet (the appendix varies one at a time).

    Args:
        profiles: user profile names, the first one paired with every other fleet.
        fleets: fleet names, the first one paired with every profile.

    Returns:
        The ``(profile, fleet)`` pairs, without repeats, in that order.
    """
    out = [(p, fleets[0]) for p in profiles] + [(profiles[0], f) for f in fleets[1:]]
    return list(dict.fromkeys(out))


def condition_config(base: dict, profile: str, fleet: str, traffic: str) -> dict:
    """The training config of one cell: ``base`` on ``profile``'s scenario at ``traffic``
    with ``fleet``.

    Args:
        base: the training config.
        profile: the scenario (``SCENARIO``), one of `PROFILES`.
        fleet: the fleet name, added to ``ENV_KWARGS``.
        traffic: the traffic level (``TRAFFIC``), one of `TRAFFIC`.

    Returns:
        A new config; ``base`` is not changed.
    """
    return {**with_env_kwargs(base, fleet=fleet), "SCENARIO": profile, "TRAFFIC": traffic}


def main(argv=None, out="outputs/traffic_sweep"):
    """The command line: train (or reuse) every cell of the chosen conditions and traffic
    levels, and write ``<out>.json`` and ``<out>.png`` (`plot`) when shopping/EU is among
    the conditions, and ``<out>_appendix.json`` and ``<out>_appendix.png`` (`plot_grid`)
    when there are several conditions.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.
        out: the default of ``--out``, the path prefix of the result files.

    Returns:
        ``{"profile/fleet": {traffic: result}}``: each cell's ``baselines.train`` result
        (its keys starting with ``_`` left out) with its training ``curve`` cut to the
        timesteps and the episode profit.
    """
    p = parser(__doc__, full_seeds=20)
    p.add_argument(
        "--appendix",
        action="store_true",
        help="every bundled profile (EU fleet) and fleet (shopping)",
    )
    p.add_argument("--profiles", nargs="+", choices=PROFILES, default=None)
    p.add_argument("--fleets", nargs="+", choices=FLEETS, default=None)
    p.add_argument(
        "--traffic", nargs="+", choices=TRAFFIC, default=list(TRAFFIC), help="traffic levels"
    )
    p.add_argument(
        "--reuse",
        nargs="+",
        default=[],
        metavar="[PROFILE/FLEET/]TRAFFIC=RESULTS_JSON",
        help="cells already trained by baselines.train with these settings (default condition shopping/EU)",
    )
    p.add_argument(
        "--out",
        default=out,
        type=checks.output_option("prefix"),
        help="path prefix of the result files (.json, .png, _appendix.*)",
    )
    args = p.parse_args(argv)
    base, seeds = config_of(args)
    profiles = args.profiles or (PROFILES if args.appendix else ("shopping",))
    fleets = args.fleets or (FLEETS if args.appendix else ("EU",))
    cells = conditions(tuple(profiles), tuple(fleets))
    reuse = parse_reuse(p, args.reuse, cells, args.traffic)
    with output(
        args.out, args.overwrite, (".json", ".png", "_appendix.json", "_appendix.png")
    ) as prefix:
        record = Record(
            args,
            seeds,
            base,
            paper_seeds=20,
            figure="Fig. 4a" + (" and appendix" if len(cells) > 1 else ""),
        )
        sweeps = {
            f"{profile}/{fleet}": _sweep(args, base, seeds, profile, fleet, reuse)
            for profile, fleet in cells
        }
        meta = record.as_dict()
        if reuse:
            meta["reused"] = {
                key: {
                    "path": path,
                    "wall_seconds": sweeps[key.rsplit("/", 1)[0]][key.rsplit("/", 1)[1]][
                        "wall_seconds"
                    ],
                }
                for key, path in reuse.items()
            }
            meta["wall_seconds_with_reused"] = meta["wall_seconds"] + sum(
                r["wall_seconds"] for r in meta["reused"].values()
            )
        if "shopping/EU" in sweeps:  # the main figure: {traffic: result}
            runs.write_json({**meta, "results": sweeps["shopping/EU"]}, prefix + ".json")
            plot(sweeps["shopping/EU"], args.algo, prefix + ".png")
            print(f"wrote {prefix}.png, {prefix}.json")
        if len(cells) > 1:
            runs.write_json(
                {**meta, "conditions": [list(c) for c in cells], "results": sweeps},
                prefix + "_appendix.json",
            )
            plot_grid(sweeps, args.algo, prefix + "_appendix.png")
            print(f"wrote {prefix}_appendix.png, {prefix}_appendix.json")
        print(Record.summary(meta))
        return sweeps


CHUNKS = 4  # a cell trains in 4 chunks (its env-steps rounded to them), evaluated once at the end


def parse_reuse(
    p, items: list[str], cells: list[tuple[str, str]], traffic: list[str]
) -> dict[str, str]:
    """``{"profile/fleet/traffic": results.json path}`` of ``--reuse [PROFILE/FLEET/]TRAFFIC=PATH``
    items; a bare traffic level means shopping/EU. A cell that this sweep does not train is an
    error (through ``p``).

    Args:
        p: the argument parser, whose ``error`` reports a bad item.
        items: the ``--reuse`` items.
        cells: the sweep's ``(profile, fleet)`` conditions.
        traffic: the sweep's traffic levels.

    Returns:
        ``{"profile/fleet/traffic": path}`` per item.

    Raises:
        SystemExit: an item without ``=`` or a path, or naming a cell the sweep does not
            train (``p.error`` exits with status 2).
    """
    valid = [f"{profile}/{fleet}/{t}" for profile, fleet in cells for t in traffic]
    reuse = {}
    for item in items:
        cell, sep, path = item.partition("=")
        key = f"shopping/EU/{cell}" if "/" not in cell else cell
        if not sep or not path or key not in valid:
            p.error(
                f"--reuse {item!r}: expected [PROFILE/FLEET/]TRAFFIC=RESULTS_JSON with a cell of this sweep "
                f"({', '.join(valid)})"
            )
        reuse[key] = path
    return reuse


def _sweep(args, base, seeds, profile, fleet, reuse: dict) -> dict:
    results = {}
    for traffic in args.traffic:
        cfg = condition_config(base, profile, fleet, traffic)
        stored = reuse.get(f"{profile}/{fleet}/{traffic}")
        if stored:
            res = reused_run(stored, args.algo, cfg, seeds, CHUNKS)
        else:
            res = run(
                args.algo,
                cfg,
                seeds=seeds,
                chunks=CHUNKS,
                evaluate_every_chunk=False,
                quiet=True,
                optimal=args.optimal,
            ).results
        results[traffic] = {
            **{k: v for k, v in res.items() if not k.startswith("_")},
            "curve": profit_curve(res["curve"]),
        }
        how = f"reused {stored}, " if stored else ""
        print(
            f"{profile}/{fleet} {traffic:>6}: {line(res, args.algo)} ({how}{res['wall_seconds']:.0f} s)",
            flush=True,
        )
    return results


def line(res: dict, algo: str) -> str:
    """One cell's held-out profits and paired differences, for the log.

    Args:
        res: the cell's ``baselines.train`` result.
        algo: the algorithm's name (its entry in the evaluation table).

    Returns:
        The mean held-out daily profits of the agent, always-max, the battery rule, the
        battery programme, price-threshold and the LP bound (those in the table), the
        agent's paired differences that the result holds (mean ± standard error, EUR/day),
        and its headroom fraction over seeds where recorded.
    """
    t = res["evaluation"]["table"]
    out = " | ".join(
        f"{name} {t[name]['metrics']['daily_profit_eur']['mean']:.1f}"
        for name in (
            algo,
            "always_max",
            "battery_rule",
            "battery_programme",
            "price_threshold",
            "lp_bound",
        )
        if name in t
    )
    for key in ("vs_always_max", "vs_battery_rule", "vs_battery_programme", "vs_plan_programme"):
        if res.get(key):
            out += f" | {algo} {key} {res[key]['mean']:+.2f} ± {res[key]['stderr']:.2f}"
    hf = res.get("over_seeds", {}).get("headroom_fraction")
    return out + (f" | headroom {hf['mean']:+.3f} ± {hf['stderr']:.3f}" if hf else "")


def plot_grid(results: dict, algo: str, path):
    """One panel per condition (``profile/fleet``): held-out daily profit minus always-max's
    on the same days and cars, per traffic level, of the learned agent (mean ± std over seeds),
    the battery rule and the LP bound.

    The teachers' rules are drawn too where every traffic level of the condition holds them;
    written as a PNG.

    Args:
        results: `main`'s ``{"profile/fleet": {traffic: result}}``.
        algo: the algorithm's name (its entry in the evaluation tables).
        path: the PNG file to write.
    """
    matplotlib.use("Agg")

    fig, axes = plt.subplots(1, len(results), figsize=(3.6 * len(results), 3.4), squeeze=False)
    for ax, (cond, sweep) in zip(axes[0], results.items()):
        x = np.arange(len(sweep))
        am = [
            sweep[t]["evaluation"]["table"]["always_max"]["metrics"]["daily_profit_eur"]["mean"]
            for t in sweep
        ]
        for i, name in enumerate(
            (algo, "battery_rule", "lp_bound", "battery_programme", "plan_programme")
        ):
            if any(name not in sweep[t]["evaluation"]["table"] for t in sweep):
                continue
            table = [sweep[t]["evaluation"]["table"][name] for t in sweep]
            m = [e["metrics"]["daily_profit_eur"]["mean"] - a for e, a in zip(table, am)]
            s = [np.std(e["per_seed_profit"]) if "per_seed_profit" in e else 0.0 for e in table]
            ax.errorbar(
                x,
                m,
                yerr=s,
                fmt="o-" if i == 0 else "s--",
                label=name,
                color=f"C{i if i < 3 else i + 1}",
                capsize=3,
            )
        ax.axhline(0.0, color="C3", ls=":", label="always_max")
        ax.set_xticks(x, list(sweep))
        ax.set_title(cond)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("held-out EUR/day − always-max")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot(results, algo, path):
    """One panel per traffic level: the agent's sampled training episode profit (mean ± std
    over seeds) against environment steps, its greedy held-out daily profit (error bar the
    std over seeds of the per-seed means) at the last step, and a line per reference in the
    evaluation table; written as a PNG.

    Args:
        results: ``{traffic: result}`` of one condition (shopping/EU in `main`).
        algo: the algorithm's name (its entry in the evaluation table).
        path: the PNG file to write.
    """
    matplotlib.use("Agg")

    fig, axes = plt.subplots(1, len(results), figsize=(4.2 * len(results), 3.6))
    for ax, (traffic, res) in zip(np.atleast_1d(axes), results.items()):
        t = np.asarray(res["curve"]["timesteps"])
        m, s = runs.seed_mean_std(res["curve"]["episode_profit_eur"])
        ax.plot(t, m, label=f"{algo} (training, sampled)")
        ax.fill_between(t, m - s, m + s, alpha=0.25)
        table = res["evaluation"]["table"]
        ev = table[algo]["metrics"]["daily_profit_eur"]
        ax.errorbar(
            [t[-1]],
            [ev["mean"]],
            yerr=[np.std(table[algo]["per_seed_profit"])],
            fmt="o",
            label=f"{algo} held-out greedy {ev['mean']:.0f}",
        )
        for i, name in enumerate(
            (
                "always_max",
                "battery_rule",
                "price_threshold",
                "lp_bound",
                "battery_programme",
                "plan_programme",
            )
        ):
            if name in table:
                v = table[name]["metrics"]["daily_profit_eur"]["mean"]
                ax.axhline(
                    v,
                    ls=("--", "-.", ":", "-", (0, (5, 1, 1, 1)), (0, (3, 1, 1, 1, 1, 1)))[i],
                    color=f"C{i + 3}",
                    label=f"{name} {v:.0f}",
                )
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
