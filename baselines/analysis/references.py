"""How far is each policy from the best? The LP bound, the MPC and the rules on the held-out days.

``python -m baselines.analysis.references`` (``make optimal``) evaluates, on the 100 held-out days
(``split_days(365, 100, seed=0)``, evaluation key 0, the same cars for every policy) of

- ``default``: the shopping scenario, medium traffic, the default station;
- ``grid25_high`` / ``grid10_high``: the same station with its grid connection at 25 % /
  10 % of the sum of its children (221 / 88 kW instead of 884.5), high traffic (the named
  scenarios ``shopping-grid25-high`` / ``shopping-grid10-high``);
- ``peak``: the default station with the evening time-of-use surcharge and the peak-demand
  charge (``shopping-peak``);

the rule-based policies (always-max, always-max + the battery price rule that pays for wear
and the one blind to it, EDF, LLF, price-threshold, the teachers' battery, plan and grid
programmes), the MPC (`chargax_marl.optimal.mpc`, 4 h horizon, re-solved every
step) and the LP hindsight bound over always-max's occupancy
(`chargax_marl.optimal.bound`), and the same bound without the battery (the difference,
``battery_worth``, is what the battery is worth at best). For each it reports EUR/day, the paired difference to
always-max (mean ± standard error over days) and the fraction of the headroom captured,
``(policy - always-max) / (bound - always-max)``, with solve times. Writes
``results/optimal/<scenario>.json`` (with the per-day profits, which
`baselines.train` reuses for the same params) and ``<scenario>.png``, and prints the
table.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from baselines.config import build_env_params, resolve
from baselines.eval import references, stats
from baselines.eval.rules import check_replay, evaluate_rules
from baselines.runs import write_json
from chargax_marl import trace as trace_lib
from chargax_marl.core import checks
from chargax_marl.evaluation import (
    headroom_captured,
    hindsight_bound,
)
from chargax_marl.optimal import milp
from chargax_marl.trace import params_fingerprint

RESULTS_DIR = Path("results/optimal")  # relative to the working directory: the repository root
RULES = (
    "always_max",
    "battery_rule",
    "battery_rule_naive",
    "edf",
    "llf",
    "price_threshold",
    "battery_programme",
    "plan_programme",
    "grid_programme",
)
DEFAULT_ROOT_KW = (
    884.5  # sum of the default station's root children: 750 (DC) + 34.5 (AC) + 100 (battery)
)

_PAPER = {"session_model": "paper"}
# make optimal's references are of the paper's session model, where the bound over
# always-max's occupancy holds (results/optimal; the v2 tasks' bound is the benchmark's)
SCENARIOS = {
    "default": {"SCENARIO": "shopping", "TRAFFIC": "medium", "ENV_KWARGS": _PAPER},
    "grid25_high": {"SCENARIO": "shopping-grid25-high", "ENV_KWARGS": _PAPER},
    "grid10_high": {"SCENARIO": "shopping-grid10-high", "ENV_KWARGS": _PAPER},
    "peak": {"SCENARIO": "shopping-peak", "ENV_KWARGS": _PAPER},
    # make train's action space (full power, idle or full discharge per leaf): the MPC rounds
    # its plan to these levels, so this is the MPC line of make train's learning curves.
    "default_full_power": {
        "SCENARIO": "shopping",
        "TRAFFIC": "medium",
        "ENV_KWARGS": {"num_levels": 1, **_PAPER},
    },
    "grid25_high_full_power": {
        "SCENARIO": "shopping-grid25-high",
        "ENV_KWARGS": {"num_levels": 1, **_PAPER},
    },
    "peak_full_power": {
        "SCENARIO": "shopping-peak",
        "ENV_KWARGS": {"num_levels": 1, "peak_demand_booking": "incremental", **_PAPER},
    },
}


def scenario_params(name: str):
    """``(eval_params, held_out_days)`` of a named scenario of this runner.

    Args:
        name: a key of `SCENARIOS`.

    Returns:
        The scenario's evaluation env parameters (every day of the year) and its held-out
        day indices.
    """
    config = resolve(SCENARIOS[name])
    _, full, _, days = build_env_params(config)
    return full, days


def run_scenario(
    name: str,
    mpc_kwargs: dict | None = None,
    num_days: int | None = None,
    mpc_days: int | None = None,
) -> dict:
    """The rules, the MPC and the LP bounds of scenario ``name`` on its held-out days (the
    first ``num_days``; the MPC on the first ``mpc_days`` of them, all by default, its
    paired differences and headroom on those days).

    Args:
        name: a key of `SCENARIOS`.
        mpc_kwargs: keyword arguments of `chargax_marl.optimal.mpc.MPC`; ``None``: none.
        num_days: play the first ``num_days`` held-out days; ``None``: all of them.
        mpc_days: run the MPC on the first ``mpc_days`` of those; ``None``: all of them.

    Returns:
        ``{"scenario", "config", "days", "params_fingerprint", "key", "root_kw", "policies",
        "battery_worth", "rules_wall_s"}``: ``policies`` holds every rule of `RULES`,
        ``mpc``, ``lp_bound`` and ``lp_bound_no_battery``, each with its ``daily_profit``
        (a list, EUR/day; NaN on a failed solve), ``mean_eur`` (failed days left out),
        ``vs_always_max`` and ``headroom`` on its days, and where they apply ``metrics``,
        ``timing`` (seconds), ``settings``, ``status`` and ``failed_days``;
        ``battery_worth`` is the paired difference of the bound with and without the
        battery (EUR/day).
    """
    params, days = scenario_params(name)
    days = days if num_days is None else days[:num_days]
    out = {
        "scenario": name,
        "config": SCENARIOS[name],
        "days": [int(d) for d in days],
        "params_fingerprint": params_fingerprint(params),
        "key": "PRNGKey(0)",
        "root_kw": float(params.station.node_max_kw[0]),
        "policies": {},
    }
    t0 = time.perf_counter()
    rules = evaluate_rules(params, days, RULES)
    rules_s = time.perf_counter() - t0
    am = rules["always_max"]["daily_profit"]
    t0 = time.perf_counter()
    bound = hindsight_bound(params, days)
    bound_wall = time.perf_counter() - t0
    no_battery = hindsight_bound(params, days, with_battery=False)
    mpc_n = len(days) if mpc_days is None else min(int(mpc_days), len(days))
    mpc = references.evaluate_mpc(params, days[:mpc_n], **(mpc_kwargs or {}))
    entries = {
        k: {"daily_profit": v["daily_profit"], "metrics": v["metrics"]} for k, v in rules.items()
    }
    entries["mpc"] = {
        "daily_profit": mpc["daily_profit"],
        "metrics": mpc["metrics"],
        "timing": {
            k: mpc[k] for k in ("wall_s", "solves", "failures", "solve_s_total", "ms_per_step")
        },
        "settings": mpc["settings"],
        "num_days": mpc_n,
    }
    if mpc["failed_days"]:
        entries["mpc"]["failed_days"] = mpc["failed_days"]
    entries["lp_bound"] = {
        "daily_profit": bound["daily_profit"],
        "timing": {
            "wall_s": bound_wall,
            "solve_s_mean": float(np.nanmean(bound["solve_s"])),
            "solve_s_max": float(np.nanmax(bound["solve_s"])),
        },
        "status": sorted(set(bound["status"])),
    }
    if bound["failed_days"]:
        entries["lp_bound"]["failed_days"] = bound["failed_days"]
    # the same LP without the battery: the bound minus this is what the battery is worth
    entries["lp_bound_no_battery"] = {
        "daily_profit": no_battery["daily_profit"],
        "status": sorted(set(no_battery["status"])),
    }
    if no_battery["failed_days"]:
        entries["lp_bound_no_battery"]["failed_days"] = no_battery["failed_days"]
    for key, e in entries.items():
        p = np.asarray(e["daily_profit"])
        n = p.shape[0]  # the MPC may run on the first days only: compare on those
        e["mean_eur"] = float(np.mean(p[np.isfinite(p)]))  # failed solves (NaN) left out
        e["vs_always_max"] = stats.paired_difference(p, am[:n])
        e["headroom"] = headroom_captured(p, am[:n], bound["daily_profit"][:n])
        e["daily_profit"] = [float(x) for x in p]
    out["policies"] = entries
    out["battery_worth"] = stats.paired_difference(
        bound["daily_profit"], no_battery["daily_profit"]
    )
    out["rules_wall_s"] = rules_s
    return out


def refresh_rules(name: str, out_dir: Path = RESULTS_DIR) -> dict:
    """Re-evaluate the rule-based policies of a stored scenario result on the current code and
    put them in place of the stored rules, keeping its LP bound and MPC (minutes to hours to
    recompute). Refuses (``ValueError``) a file made for other params or days, or whose
    always-max no longer replays to the stored profits (another model: re-run the scenario).

    Writes ``<out_dir>/<name>.json`` (the updated result) and ``<out_dir>/<name>.png``
    (`plot`).

    Args:
        name: a key of `SCENARIOS`.
        out_dir: the directory holding ``<name>.json``.

    Returns:
        The updated result, every rule of `RULES` with ``daily_profit``, ``metrics``,
        ``mean_eur``, ``vs_always_max`` and ``headroom`` (against the stored bound), and
        ``rules_wall_s``.

    Raises:
        ValueError: the file was made for other params or days than the scenario builds, or
            its always-max does not replay (`baselines.eval.rules.check_replay`).
    """
    path = Path(out_dir) / f"{name}.json"
    stored = json.loads(path.read_text())
    params, days = scenario_params(name)
    days = np.asarray(days)[: len(stored["days"])]
    if stored["params_fingerprint"] != params_fingerprint(params) or stored["days"] != [
        int(d) for d in days
    ]:
        raise ValueError(
            f"{path}: made for other params or days than scenario {name!r} builds now; re-run it"
        )
    t0 = time.perf_counter()
    rules = evaluate_rules(params, days, RULES)
    rules_s = time.perf_counter() - t0
    check_replay(rules, stored["policies"], ("always_max",), str(path))
    am = rules["always_max"]["daily_profit"]
    bound = np.asarray(stored["policies"]["lp_bound"]["daily_profit"], np.float64)
    for key, v in rules.items():
        p = v["daily_profit"]
        stored["policies"][key] = {
            "daily_profit": [float(x) for x in p],
            "metrics": v["metrics"],
            "mean_eur": float(np.mean(p)),
            "vs_always_max": stats.paired_difference(p, am),
            "headroom": headroom_captured(p, am, bound),
        }
    stored["rules_wall_s"] = rules_s
    write_json(stored, path)
    plot(stored, Path(out_dir) / f"{name}.png")
    return stored


MILP_SCENARIO = {
    "SCENARIO": "shopping",
    "TRAFFIC": "high",
    "ENV_KWARGS": {"station_kwargs": {"num_dc": 2, "num_ac": 2}},
}
"""Where the MILP runs: a 4-port station (2 DC, 2 AC, the battery), high traffic."""


def run_milp(num_days: int = 10, num_steps: int = 36) -> dict:
    """MILP (admissions free) against the LP over always-max's occupancy and always-max itself,
    on the first ``num_steps`` of the first ``num_days`` held-out days of `MILP_SCENARIO`.

    Args:
        num_days: the number of held-out days, the first ones (at least 2, for the standard
            error).
        num_steps: the window, steps from midnight.

    Returns:
        ``{"scenario", "num_steps", "days", "rows", "mean", "milp_minus_lp"}``: one row per
        day (window profits in EUR of the MILP, the LP and always-max, the number of cars
        and binaries, solve times in seconds), the means of the rows' numbers, and the
        MILP's profit minus the LP's (``mean``, ``stderr``, ``max``, EUR).
    """

    config = resolve(MILP_SCENARIO)
    _, params, _, days = build_env_params(config)
    days = days[:num_days]
    key = jax.random.PRNGKey(0)
    traces = trace_lib.make_traces(params, days, key)
    keys = jax.random.split(key, len(days))
    rows = []
    for i, day in enumerate(days):
        r = milp.compare(params, trace_lib.day_of(traces, i), keys[i], num_steps)
        rows.append(
            {
                "day": int(day),
                "milp_eur": r.milp_eur,
                "lp_eur": r.lp_eur,
                "always_max_eur": r.reference_eur,
                "cars": r.num_candidates,
                "binaries": r.num_binaries,
                "milp_solve_s": r.milp_solve_s,
                "lp_solve_s": r.lp_solve_s,
            }
        )
    arr = {k: np.array([row[k] for row in rows]) for k in rows[0]}
    gap = arr["milp_eur"] - arr["lp_eur"]
    return {
        "scenario": MILP_SCENARIO,
        "num_steps": num_steps,
        "days": [int(d) for d in days],
        "rows": rows,
        "mean": {k: float(np.mean(v)) for k, v in arr.items() if k != "day"},
        "milp_minus_lp": {
            "mean": float(gap.mean()),
            "stderr": float(gap.std(ddof=1) / np.sqrt(gap.size)),
            "max": float(gap.max()),
        },
    }


def format_milp(r: dict) -> str:
    """The one-paragraph report of a `run_milp` result.

    Args:
        r: a `run_milp` result.

    Returns:
        The mean window profits (EUR) of always-max, the LP bound and the MILP, the MILP's
        gap over the LP, the mean numbers of cars and binaries and the mean solve times.
    """
    m, g = r["mean"], r["milp_minus_lp"]
    return (
        f"MILP vs LP, 4-port station, high traffic, first {r['num_steps']} steps of {len(r['days'])} held-out days "
        f"(window profit, EUR): always-max {m['always_max_eur']:.2f}, LP bound (always-max occupancy) "
        f"{m['lp_eur']:.2f}, MILP (admissions free) {m['milp_eur']:.2f}; MILP - LP {g['mean']:+.2f} ± "
        f"{g['stderr']:.2f} (max {g['max']:.2f}); {m['cars']:.1f} cars and {m['binaries']:.0f} binaries per "
        f"window; solve {m['milp_solve_s']:.1f} s MILP, {m['lp_solve_s']:.3f} s LP"
    )


def format_optimal(result: dict) -> str:
    """The plain-text table of a `run_scenario` (or `refresh_rules`) result.

    Args:
        result: a `run_scenario` or `refresh_rules` result.

    Returns:
        A header line, and one line per policy: mean EUR/day, the paired difference to
        always-max, the headroom fraction and, for the MPC and the bound, the solve time;
        then the battery's worth when the result has it.
    """
    lines = [
        f"{result['scenario']}: {len(result['days'])} held-out days, key 0, same cars for all; "
        f"grid connection {result['root_kw']:.1f} kW",
        f"{'policy':<22}{'EUR/day':>10}{'vs always-max':>18}{'headroom':>10}{'time':>22}",
    ]
    for name, e in result["policies"].items():
        d = e["vs_always_max"]
        t = e.get("timing")
        if name == "mpc":
            timing = f"{t['ms_per_step']:.1f} ms/step"
        elif name == "lp_bound":
            timing = f"{t['solve_s_mean']:.2f} s/day LP"
        else:
            timing = ""
        lines.append(
            f"{name:<22}{e['mean_eur']:>10.1f}{d['mean']:>+11.2f} ± {d['stderr']:<5.2f}"
            f"{e['headroom']['fraction']:>10.2f}{timing:>22}"
        )
    if "battery_worth" in result:
        w = result["battery_worth"]
        lines.append(
            f"battery worth (bound - bound without it): {w['mean']:+.2f} ± {w['stderr']:.2f}"
        )
    return "\n".join(lines)


def plot(result: dict, path: Path) -> Path:
    """Bar chart of every policy's paired difference to always-max (EUR/day, ± standard
    error), written as a PNG (its parent directory created).

    Args:
        result: a `run_scenario` or `refresh_rules` result.
        path: the PNG file to write.

    Returns:
        ``path``.
    """
    matplotlib.use("Agg")

    names = list(result["policies"])
    diffs = [result["policies"][n]["vs_always_max"]["mean"] for n in names]
    errs = [result["policies"][n]["vs_always_max"]["stderr"] for n in names]
    fig, ax = plt.subplots(figsize=(7, 3.8))
    colors = ["C7" if n == "lp_bound" else "C2" if n == "mpc" else "C0" for n in names]
    ax.bar(names, diffs, yerr=errs, capsize=3, color=colors)
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_ylabel("EUR/day vs always-max (paired)")
    ax.set_title(
        f"{result['scenario']}: {len(result['days'])} held-out days; grid {result['root_kw']:.0f} kW"
    )
    ax.grid(axis="y", alpha=0.3)
    plt.setp(ax.get_xticklabels(), rotation=20)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv=None) -> dict:
    """The command line (``make optimal``): with ``--rules-only``, `refresh_rules` of every
    ``--scenarios``; otherwise `run_milp` (unless ``--milp-days 0``, written to
    ``<out>/milp_small.json``) and `run_scenario` of every scenario, each printed and written
    to ``<out>/<scenario>.json`` and ``<out>/<scenario>.png``.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        ``{scenario: result}``, and ``milp`` when the MILP ran.
    """
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=list(SCENARIOS))
    p.add_argument("--horizon-hours", type=float, default=4.0)
    p.add_argument("--resolve-every", type=int, default=1)
    p.add_argument(
        "--num-days", type=int, default=None, help="only the first N held-out days (a quick look)"
    )
    p.add_argument(
        "--mpc-days",
        type=int,
        default=None,
        help="the MPC on the first N held-out days only (its figures on those days)",
    )
    p.add_argument("--out", default=str(RESULTS_DIR), type=checks.output_option("dir"))
    p.add_argument(
        "--milp-days",
        type=int,
        default=10,
        help="held-out days of the MILP comparison (0: skip it)",
    )
    p.add_argument(
        "--milp-steps",
        type=int,
        default=36,
        help="window of the MILP comparison, steps from midnight",
    )
    p.add_argument(
        "--rules-only",
        action="store_true",
        help="re-evaluate only the rules of the stored results of --scenarios (refresh_rules)",
    )
    args = p.parse_args(argv)
    results = {}
    if args.rules_only:
        for name in args.scenarios:
            r = refresh_rules(name, Path(args.out))
            print(format_optimal(r))
            results[name] = r
        return results
    if args.milp_days > 0:
        r = run_milp(args.milp_days, args.milp_steps)
        print(format_milp(r))
        write_json(r, Path(args.out) / "milp_small.json")
        results["milp"] = r
    for name in args.scenarios:
        t0 = time.perf_counter()
        r = run_scenario(
            name,
            {"horizon_hours": args.horizon_hours, "resolve_every": args.resolve_every},
            args.num_days,
            args.mpc_days,
        )
        r["wall_s"] = time.perf_counter() - t0
        print(format_optimal(r))
        print(f"({r['wall_s']:.0f} s)")
        out = Path(args.out)
        write_json(r, out / f"{name}.json")
        plot(r, out / f"{name}.png")
        results[name] = r
    return results


if __name__ == "__main__":
    main()
