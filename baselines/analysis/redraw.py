"""Score a trained run on more cars: every held-out day with several car draws.

    python -m baselines.analysis.redraw results/ippo_shopping_grid25_high_4e6 --draws 16 --out-dir DIR

``baselines.train`` scores every policy on the 100 held-out days with one key (``PRNGKey(0)``,
unless ``EVAL_DRAWS`` says more), so every policy meets the same cars. On a station that
turns cars away the day-to-day spread of a paired difference is large (a battery step can
change which car gets a freed port), so with one car draw a seed's mean difference to a rule
can have a standard error larger than the differences in question. More draws per day
average that spread out.

This tool replays the run's trained seeds and the rules (always-max, the battery rule and,
on a station with a battery, the teachers' rules and the node-aware programme,
`baselines.eval.rules.BATTERY_RULES`) on the same held-out days with ``draws``
keys, ``PRNGKey(0) ... PRNGKey(draws - 1)`` (`baselines.eval.protocol.draw_keys`): the first
are the run's own evaluation draws (one unless it trained with ``EVAL_DRAWS``; the tool
refuses a run whose replayed evaluation differs from its ``results.json``: it was trained on
another model), and every policy meets the same cars in every draw. A seed's paired
difference is averaged over the draws of each day first and its standard error taken over
the days, so the days, not the draws, are the independent units (the draws of one day share
its prices), as ``baselines.train`` with ``EVAL_DRAWS`` does. ``beats`` is the trainers' rule:
the mean above two standard errors.

With ``--bound on`` (default) the LP hindsight bound is solved for every draw as well, and a
seed's headroom fraction is its mean gain over always-max over all days and draws divided
by the bound's, both over the days and draws on which the bound was solved. Several runs of one scenario in one call share the rules' and the bound's
draws.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from baselines import runs
from baselines.config import build_env_params
from baselines.eval import heldout, protocol, references, stats
from baselines.eval.rules import BATTERY_RULES, evaluate_rules
from baselines.eval.stats import over_seeds
from baselines.runs import load_run
from chargax_marl.core import checks
from chargax_marl.evaluation import policy_bound
from chargax_marl.teachers.rules import has_battery
from chargax_marl.trace import params_fingerprint

RULES = ("always_max", "battery_rule")


_REFERENCES: dict = {}


def reference_profits(
    eval_params, days, draws: int, bound: bool, mpc_draws: int = 0, references_dir=None
) -> dict:
    """``{name: (draws, days) daily profits}`` of the rules (and ``lp_bound``, the LP hindsight
    bound over always-max's occupancy, with ``bound``) under keys ``PRNGKey(0 .. draws - 1)``,
    and ``mpc`` (``(mpc_draws, days)``: the MPC of ``make optimal`` on the first ``mpc_draws``
    draws; draw 0 from ``references_dir`` when ``make optimal`` stored these params and days there);
    computed once per params, days and draws in a process, so several runs of one scenario
    share them.

    Args:
        eval_params: the evaluation env parameters.
        days: the held-out day indices.
        draws: car draws per day (a positive integer).
        bound: also solve the LP hindsight bound of every draw (``lp_bound``).
        mpc_draws: run the MPC on the first ``mpc_draws`` draws (0: no ``mpc``).
        references_dir: a directory ``make optimal`` wrote, read for the MPC of draw 0 when
            ``mpc_draws`` > 0; ``None`` runs it.

    Returns:
        ``{name: daily profits}`` as float64 arrays in EUR/day: ``(draws, days)`` per rule of
        `RULES` (and, on a station with a battery, `baselines.eval.rules.BATTERY_RULES`) and
        for ``lp_bound``, ``(mpc_draws, days)`` for ``mpc``. The same dict is returned again
        for the same arguments in a process.
    """

    cache_key = (
        params_fingerprint(eval_params),
        tuple(int(d) for d in days),
        int(draws),
        bool(bound),
        int(mpc_draws),
    )
    if cache_key not in _REFERENCES:
        names = RULES + BATTERY_RULES * has_battery(eval_params)
        out = {n: [] for n in names + ("lp_bound",) * bool(bound) + ("mpc",) * bool(mpc_draws)}
        stored = (
            references.cached(eval_params, days, references_dir)
            if mpc_draws and references_dir
            else None
        )
        for k, key in enumerate(protocol.draw_keys(draws)):
            for name, r in evaluate_rules(eval_params, days, names, key=key).items():
                out[name].append(r["daily_profit"])
            if bound:
                out["lp_bound"].append(
                    np.asarray(policy_bound(eval_params, days, key)["daily_profit"], np.float64)
                )
            if k < mpc_draws:
                # draw 0's stored MPC only when it ran on every one of the days
                stored_mpc = references.stored_mpc(stored, days) if k == 0 else None
                out["mpc"].append(
                    stored_mpc
                    if stored_mpc is not None
                    else np.asarray(
                        references.evaluate_mpc(eval_params, days, key)["daily_profit"], np.float64
                    )
                )
        _REFERENCES[cache_key] = {n: np.stack(v) for n, v in out.items()}
    return _REFERENCES[cache_key]


def headroom_fractions(learned: np.ndarray, refs: dict, mpc_draws: int = 0) -> dict:
    """The headroom (LP bound minus always-max) and each policy's fraction of it, over the
    draws and days on which the bound was solved (a failed solve is NaN and leaves its draw
    and day out of every mean, the policies' gains included).

    Args:
        learned: ``(seeds, draws, days)`` the learned seeds' daily profits (EUR/day).
        refs: `reference_profits`' ``{name: (draws, days)}``, with ``always_max`` and
            ``lp_bound`` (and ``mpc``, ``(mpc_draws, days)``, with ``mpc_draws``).
        mpc_draws: the draws the MPC ran on (the first ones); 0 for none.

    Returns:
        ``{"headroom_eur", "headroom_eur_per_draw", "bound_failed_days", "headroom_fraction":
        {"per_seed", "references", "over_seeds"[, "mpc_on_its_draws"]}}``; EUR/day, and
        fractions of the headroom.
    """
    am = refs["always_max"]
    solved = np.isfinite(refs["lp_bound"])

    def mean_solved(x, rows=None) -> float:
        mask = solved if rows is None else solved[:rows]
        return float(np.asarray(x)[mask].mean())

    gap = refs["lp_bound"] - am
    headroom = mean_solved(gap)
    out = {
        "headroom_eur": headroom,
        "headroom_eur_per_draw": [float(g[s].mean()) for g, s in zip(gap, solved, strict=True)],
        "bound_failed_days": int((~solved).sum()),
        "headroom_fraction": {
            "per_seed": [mean_solved(seed - am) / headroom for seed in learned],
            "references": {
                n: mean_solved(v - am) / headroom for n, v in refs.items() if n != "mpc"
            },
        },
    }
    if mpc_draws:  # the MPC's fraction on its own draws, against the bound on the same draws
        n = int(mpc_draws)
        own = mean_solved(gap[:n], n)
        out["headroom_fraction"]["mpc_on_its_draws"] = {
            "mpc": mean_solved(refs["mpc"] - am[:n], n) / own,
            "per_seed": [mean_solved(seed[:n] - am[:n], n) / own for seed in learned],
        }
    out["headroom_fraction"]["over_seeds"] = over_seeds(out["headroom_fraction"]["per_seed"])
    return out


def redraw(
    run_dir: str | Path,
    draws: int = 8,
    bound: bool = True,
    mpc_draws: int = 0,
    check_tolerance_eur: float = 1e-2,
    references_dir=None,
) -> dict:
    """Replay a run on ``draws`` car draws per held-out day; see the module docstring. With
    ``bound``, also the LP hindsight bound of every draw and each seed's fraction of the
    headroom (bound - always-max) over all draws; with ``mpc_draws``, the MPC on the first
    ``mpc_draws`` draws and each seed's paired difference to it on those draws
    (``vs["mpc"]``).

    Args:
        run_dir: an output directory of ``baselines.train`` (``results.json``,
            ``params.msgpack``).
        draws: car draws per held-out day, a positive integer at least the run's
            ``EVAL_DRAWS``.
        bound: also solve the LP hindsight bound of every draw and report headroom fractions.
        mpc_draws: run the MPC on the first ``mpc_draws`` draws, an integer in
            ``[0, draws]``.
        check_tolerance_eur: the largest difference (EUR/day, per seed) allowed between the
            replayed evaluation on the run's own draws and its ``results.json``.
        references_dir: a directory ``make optimal`` wrote (`reference_profits`), or ``None``.

    Returns:
        ``{"run", "algo", "scenario", "num_days", "draws", "seeds", "keys",
        "replay_check_max_abs_eur", "references_mean_profit_eur",
        "references_vs_always_max", "per_draw_vs_always_max", "mpc_draws", "vs"}``; with
        ``bound`` also `headroom_fractions`' ``headroom_eur``, ``headroom_eur_per_draw``,
        ``bound_failed_days`` and ``headroom_fraction``. ``vs`` holds, per reference but the bound, each seed's
        `baselines.eval.stats.day_clustered` difference (and on draw 0 alone,
        ``draw0_per_seed``), their `baselines.eval.stats.over_seeds`, and the counts of
        seeds above it and beating it. Profits and differences in EUR/day.

    Raises:
        ValueError: ``draws`` not a positive integer, ``mpc_draws`` not an integer in
            ``[0, draws]``, ``draws`` fewer than the run's ``EVAL_DRAWS``, or the replayed
            evaluation differing from ``results.json`` by more than ``check_tolerance_eur``
            (the run was made on another model).
    """

    if isinstance(draws, bool) or not isinstance(draws, (int, np.integer)) or int(draws) < 1:
        raise ValueError(f"draws must be a positive integer, got {draws!r}")
    keys = protocol.draw_keys(draws)
    if (
        isinstance(mpc_draws, bool)
        or not isinstance(mpc_draws, (int, np.integer))
        or not 0 <= mpc_draws <= draws
    ):
        raise ValueError(f"mpc_draws must be an integer in [0, draws={draws}], got {mpc_draws!r}")
    results, train, all_params = load_run(run_dir)
    _, eval_params, _, days = build_env_params(train.config)
    days = np.asarray(days)
    score = heldout.compiled_evaluation(train.make_act(eval_params), eval_params)
    run_draws = int(train.config.get("EVAL_DRAWS", 1))
    if draws < run_draws:
        raise ValueError(
            f"{run_dir} was evaluated on {run_draws} car draws per day; redraw it with draws >= {run_draws}, "
            f"got {draws}"
        )
    learned = np.stack(
        [np.asarray(score(all_params, days, k).profit_eur, np.float64) for k in keys], axis=1
    )  # (seeds, draws, days)
    stored = np.asarray([s["mean_profit_eur"] for s in results["per_seed"]], np.float64)
    worst = float(np.max(np.abs(learned[:, :run_draws].mean(axis=(1, 2)) - stored)))
    if worst > check_tolerance_eur:
        raise ValueError(
            f"{run_dir}: its {run_draws} evaluation draw(s) replayed on this code differ from results.json "
            f"by up to {worst:.3f} EUR/day per seed: the run was made on another model; re-run it instead"
        )
    refs = reference_profits(eval_params, days, draws, bound, int(mpc_draws), references_dir)
    am = refs["always_max"]
    scenario = results.get("scenario")
    out = {
        "run": str(run_dir),
        "algo": results["algo"],
        "scenario": scenario.get("name") if isinstance(scenario, dict) else scenario,
        "num_days": int(days.size),
        "draws": int(draws),
        "seeds": int(learned.shape[0]),
        "keys": f"PRNGKey(0) ... PRNGKey({int(draws) - 1})",
        "replay_check_max_abs_eur": worst,
        "references_mean_profit_eur": {n: float(v.mean()) for n, v in refs.items()},
        "references_vs_always_max": {
            n: stats.day_clustered(v - am[: len(v)]) for n, v in refs.items() if n != "always_max"
        },
        "per_draw_vs_always_max": {
            "learned_per_seed": [
                [float(x) for x in (learned[i] - am).mean(axis=1)] for i in range(learned.shape[0])
            ],
            **{
                n: [float(x) for x in (v - am[: len(v)]).mean(axis=1)]
                for n, v in refs.items()
                if n != "always_max"
            },
        },
        "mpc_draws": int(mpc_draws),
        "vs": {},
    }
    if bound:
        out.update(headroom_fractions(learned, refs, mpc_draws))
    for name in (n for n in refs if n != "lp_bound"):
        n = len(refs[name])  # the MPC's draws are the first mpc_draws
        per_seed = [
            stats.day_clustered(learned[i, :n] - refs[name]) for i in range(learned.shape[0])
        ]
        first_draw = [
            stats.day_clustered(learned[i, :1] - refs[name][:1]) for i in range(learned.shape[0])
        ]
        out["vs"][name] = {
            "per_seed": per_seed,
            "over_seeds": over_seeds([d["mean"] for d in per_seed]),
            "seeds_above": int(sum(d["mean"] > 0 for d in per_seed)),
            "seeds_beating": int(sum(d["beats"] for d in per_seed)),
            "draw0_per_seed": first_draw,
        }
    return out


def format_redraw(out: dict) -> str:
    """The plain-text report of a `redraw` result.

    Args:
        out: a `redraw` result.

    Returns:
        A header line; per reference its difference to always-max (and headroom fraction,
        with the bound); the learned seeds' headroom fractions (with the bound); and per
        reference of ``vs`` the seeds' differences over seeds and per seed, in EUR/day.
    """
    lines = [
        f"{out['algo']} run {out['run']} ({out['scenario']}): {out['num_days']} held-out days x "
        f"{out['draws']} car draws, {out['seeds']} seeds; EUR/day, per seed mean ± s.e. over days "
        f"(draw 0 alone in brackets)"
    ]
    for name, r in out["references_vs_always_max"].items():
        frac = out.get("headroom_fraction", {}).get("references", {}).get(name)
        lines.append(
            f"  {name:<21} vs always-max {r['mean']:+7.2f} ± {r['stderr']:.2f}"
            + ("" if frac is None else f", headroom {frac:.3f}")
        )
    if "headroom_fraction" in out:
        h = out["headroom_fraction"]
        lines.append(
            f"  learned headroom fraction {h['over_seeds']['mean']:.3f} ± {h['over_seeds']['stderr']:.3f} "
            f"over seeds ({', '.join(f'{x:.3f}' for x in h['per_seed'])}) of {out['headroom_eur']:.2f} EUR/day"
        )
        if "mpc_on_its_draws" in h:
            m = h["mpc_on_its_draws"]
            lines.append(
                f"  on the MPC's {out['mpc_draws']} draws: MPC headroom {m['mpc']:.3f}, learned "
                f"{', '.join(f'{x:.3f}' for x in m['per_seed'])}"
            )
    for name, v in out["vs"].items():
        o = v["over_seeds"]
        seeds = ", ".join(
            f"{d['mean']:+.2f} ± {d['stderr']:.2f} [{d0['stderr']:.2f}]"
            for d, d0 in zip(v["per_seed"], v["draw0_per_seed"])
        )
        lines.append(
            f"  vs {name:<18} {o['mean']:+7.2f} ± {o['stderr']:.2f} over seeds; "
            f"{v['seeds_above']} above, {v['seeds_beating']} by 2 s.e.: {seeds}"
        )
    return "\n".join(lines)


def main(argv=None) -> dict:
    """The command line: `redraw` every ``RUN_DIR``, print each report and, with
    ``--out-dir``, write each result to ``<out-dir>/<run name>.json``.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        ``{run_dir: redraw result}``.
    """
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "run_dirs",
        nargs="+",
        metavar="RUN_DIR",
        help="output directories of python -m baselines.train (results.json, params.msgpack)",
    )
    p.add_argument(
        "--draws", type=int, default=8, help="car draws (evaluation keys) per held-out day"
    )
    p.add_argument(
        "--bound",
        choices=("on", "off"),
        default="on",
        help="the LP hindsight bound of every draw and the headroom fractions (one LP per day "
        "and draw)",
    )
    p.add_argument(
        "--mpc-draws",
        type=int,
        default=0,
        help="run the MPC of make optimal on the first N draws too (an LP per step, the slowest "
        "part; draw 0 comes from --references when stored there)",
    )
    p.add_argument(
        "--references", default=None, help="a directory `make optimal` wrote (e.g. results/optimal)"
    )
    p.add_argument(
        "--out-dir",
        default=None,
        type=checks.output_option("dir"),
        help="write RUN_NAME.json for every run here",
    )
    a = p.parse_args(argv)
    outs = {}
    for run_dir in a.run_dirs:
        out = outs[run_dir] = redraw(
            run_dir,
            a.draws,
            bound=a.bound == "on",
            mpc_draws=a.mpc_draws,
            references_dir=a.references,
        )
        print(format_redraw(out), flush=True)
        if a.out_dir:
            runs.write_json(out, Path(a.out_dir) / f"{Path(run_dir).name}.json")
    return outs


if __name__ == "__main__":
    main()
