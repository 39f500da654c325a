"""Markdown tables of the experiment runners' result files (``docs/REPRODUCTION.md`` quotes them).

    python -m baselines.experiments.report [--results results]

Every difference is paired (the same held-out days and cars) and reported as mean ± standard
error over seeds of the per-seed means; "seeds above" counts the seeds whose mean is above
the reference. The teachers' rules (``battery_programme``: always-max ports with the
battery-only programme; ``plan_programme``: the ports' plans with it) show "–" in files made
before they were baselines, until ``python -m baselines.experiments.add_teacher_rules FILE``
adds them. A runner's file that is
missing is skipped with a line saying so.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from baselines.eval.stats import over_seeds, paired_difference


def pm(d: dict | None, digits: int = 2) -> str:
    """``mean ± stderr`` of a difference, the mean signed.

    Args:
        d: a dict with ``mean`` and ``stderr``, or ``None``.
        digits: the decimals of both numbers.

    Returns:
        ``"+1.23 ± 0.45"``, or ``"–"`` for ``None``.
    """
    if d is None:
        return "–"
    return f"{d['mean']:+.{digits}f} ± {d['stderr']:.{digits}f}"


def seeds_stat(per_seed) -> dict:
    """`baselines.eval.stats.over_seeds` of per-seed numbers, with how many are above zero.

    Args:
        per_seed: one number per seed.

    Returns:
        `baselines.eval.stats.over_seeds`' dict with ``above`` (the count of numbers above
        zero) and ``n`` (the count of numbers).
    """
    v = np.asarray(per_seed, np.float64)
    return {**over_seeds(v), "above": int((v > 0).sum()), "n": int(v.size)}


def provenance(d: dict) -> str:
    """One line on how a runner's result file was made.

    Args:
        d: a runner's result file (`baselines.experiments._common.Record.as_dict` keys, and
            ``reused`` / ``wall_seconds_with_reused`` where cells were reused).

    Returns:
        The budget note (``cut_note``), the settings, the wall time in minutes (with the
        reused cells' when there are some) and the machine, where recorded.
    """
    m = d.get("machine") or {}
    wall = d.get("wall_seconds_with_reused", d.get("wall_seconds"))
    reused = d.get("reused") or {}
    return (
        f"{d.get('cut_note', '')}; settings `{d.get('settings', '?')}`; "
        + (f"{wall / 60:.0f} min wall" if wall else "wall time not recorded")
        + (
            " (with the reused "
            + ", ".join(f"{k} cell ({v['path']})" for k, v in reused.items())
            + ")"
            if reused
            else ""
        )
        + (f" on {m.get('cpu')} ×{m.get('cores')} ({m.get('backend')})" if m else "")
    )


def _profit(table: dict, name: str) -> str:
    return f"{table[name]['metrics']['daily_profit_eur']['mean']:.1f}" if name in table else "–"


TEACHERS = ("battery_programme", "plan_programme")
"""The teachers' rules (`baselines.eval.rules.TEACHER_RULES`)."""


def _vs_seeds(per_seed: list, name: str) -> str:
    """``mean ± s.e. (seeds above/seeds)`` of the per-seed differences to ``name``, or "–" when
    the file predates that reference."""
    if not per_seed or not all(p.get(f"vs_{name}") for p in per_seed):
        return "–"
    st = seeds_stat([p[f"vs_{name}"]["mean"] for p in per_seed])
    return f"{pm(st)} ({st['above']}/{st['n']})"


def _cell_row(label: str, res: dict, algo: str) -> str:
    t = res["evaluation"]["table"]
    per_seed = res.get("per_seed") or []
    hf = res.get("over_seeds", {}).get("headroom_fraction")
    return (
        f"| {label} | {_profit(t, algo)} | {_profit(t, 'always_max')} | {_profit(t, 'battery_rule')} | "
        f"{_profit(t, 'lp_bound')} | "
        + " | ".join(_vs_seeds(per_seed, n) for n in ("always_max", "battery_rule") + TEACHERS)
        + f" | {pm(hf, 3) if hf else '–'} | {res['wall_seconds'] / 60:.1f} |"
    )


CELL_HEADER = (
    "| {what} | {algo} EUR/day | always-max | battery rule | LP bound | {algo} − always-max (seeds above) | "
    "{algo} − battery rule | {algo} − battery programme | {algo} − plan programme | headroom fraction | "
    "wall min |\n|---|---|---|---|---|---|---|---|---|---|---|"
)


def teacher_rules(cells: list[tuple[str, dict]]) -> str:
    """The teachers' rules over always-max per cell (one line each), where the file holds them.

    Args:
        cells: ``(label, training result)`` pairs.

    Returns:
        A Markdown table (after a blank line and a caption) with one row per cell whose
        evaluation table holds both `TEACHERS`: each rule's paired difference to
        always-max over days (and headroom fraction, where stored); ``""`` when no cell
        holds them.
    """
    rows = []
    for label, res in cells:
        t = res["evaluation"]["table"]
        if all(n in t for n in TEACHERS):
            rows.append(
                f"| {label} | "
                + " | ".join(
                    f"{pm(t[n]['vs_always_max'])} ({t[n]['headroom']['fraction']:.3f})"
                    if "headroom" in t[n]
                    else pm(t[n]["vs_always_max"])
                    for n in TEACHERS
                )
                + " |"
            )
    if not rows:
        return ""
    return "\n".join(
        [
            "",
            "The teachers' rules (no learning) − always-max, mean ± s.e. over the held-out days "
            "(headroom fraction):",
            "",
            "| cell | battery programme (always-max ports) | plan programme (the ports' plans) |",
            "|---|---|---|",
            *rows,
        ]
    )


def traffic_sweep(d: dict) -> str:
    """The tables of a ``traffic_sweep`` result file (Fig. 4a).

    Args:
        d: the result file's JSON: ``algo`` and ``results`` ``{traffic: training result}``.

    Returns:
        The `provenance` line, one row per traffic level (`CELL_HEADER`'s columns) and the
        `teacher_rules` table.
    """
    algo = d["algo"]
    cells = list(d["results"].items())
    rows = [_cell_row(traffic, res, algo) for traffic, res in cells]
    return "\n".join(
        [
            provenance(d),
            "",
            CELL_HEADER.format(what="traffic", algo=algo.upper()),
            *rows,
            teacher_rules(cells),
        ]
    )


def appendix(d: dict) -> str:
    """The tables of a ``traffic_sweep`` appendix result file (every profile and fleet).

    Args:
        d: the result file's JSON: ``algo`` and ``results``
            ``{"profile/fleet": {traffic: training result}}``.

    Returns:
        The `provenance` line, one row per condition and traffic level (`CELL_HEADER`'s
        columns) and the `teacher_rules` table.
    """
    algo = d["algo"]
    cells = [
        (f"{cond} {traffic}", res)
        for cond, sweep in d["results"].items()
        for traffic, res in sweep.items()
    ]
    rows = [_cell_row(label, res, algo) for label, res in cells]
    return "\n".join(
        [
            provenance(d),
            "",
            CELL_HEADER.format(what="profile/fleet traffic", algo=algo.upper()),
            *rows,
            teacher_rules(cells),
        ]
    )


METRIC = {"satisfaction_time": "missing_kwh_at_departure", "satisfaction_charge": "overtime_min"}


def alpha_ablation(d: dict) -> str:
    """The table of an ``alpha_ablation`` result file (Fig. 4b-c).

    Args:
        d: the result file's JSON: ``baselines`` and ``results`` ``{term: [row per alpha]}``.

    Returns:
        The `provenance` line; per term and alpha its metric (kWh or min), the change to
        alpha 0 (with the count of seeds below it), the daily profit and its change to alpha
        0, and the wall minutes; then a line of always-max's figures (and the battery rule's
        and the bound's profit, where present).
    """
    am = d["baselines"]["always_max"]["metrics"]
    lines = [
        provenance(d),
        "",
        "| term | α | its metric (mean over seeds × days) | metric − α 0 (seeds below) | profit EUR/day | "
        "profit − α 0 | wall min |",
        "|---|---|---|---|---|---|---|",
    ]
    for term, rows in d["results"].items():
        key = METRIC[term]
        for r in rows:
            v = r.get("vs_alpha0", {})
            dm, dp = v.get(key), v.get("daily_profit_eur")
            change = "–"
            if dm and r["alpha"]:
                change = f"{pm(dm)} ({sum(x < 0 for x in dm['per_seed'])}/{len(dm['per_seed'])})"
            unit = "kWh" if "kwh" in key else "min"
            lines.append(
                f"| {term} | {r['alpha']:g} | {r['metrics'][key]['mean']:.1f} {unit} | {change} | "
                f"{r['metrics']['daily_profit_eur']['mean']:.1f} | {pm(dp) if r['alpha'] else '–'} | "
                f"{r['wall_seconds'] / 60:.1f} |"
            )
    lines.append("")
    lines.append(
        f"Always-max: {am['missing_kwh_at_departure']['mean']:.1f} kWh missing, "
        f"{am['overtime_min']['mean']:.1f} min overtime, {am['daily_profit_eur']['mean']:.1f} EUR/day"
        + "".join(
            f"; {n.replace('_', ' ')} {_profit(d['baselines'], n)} EUR/day"
            for n in ("battery_rule", "lp_bound")
            if n in d["baselines"]
        )
        + "."
    )
    return "\n".join(lines)


def price_shift(d: dict) -> str:
    """The tables of a ``price_shift`` result file (Fig. 5).

    Args:
        d: the result file's JSON: ``matrix`` ``{train year: {eval year: evaluation}}`` and
            ``baselines`` ``{eval year: baseline results}``.

    Returns:
        The `provenance` line; the train year × eval year table of held-out daily profits
        with the paired differences to always-max over seeds, a row per reference every
        year holds; and per teacher rule that every cell holds a table of the differences to
        it.
    """
    years = list(d["matrix"])
    lines = [
        provenance(d),
        "",
        "Held-out daily profit EUR (train year × eval year), then the paired difference to always-max of the eval "
        "year (mean ± s.e. over seeds, seeds above):",
        "",
        "| train \\ eval | " + " | ".join(years) + " |",
        "|---|" + "---|" * len(years),
    ]
    for ty, row in d["matrix"].items():
        cells = []
        for ey in years:
            ev = row[ey]
            s = seeds_stat(ev["paired_diff"]["per_seed_mean"])
            cells.append(
                f"{ev['metrics']['daily_profit_eur']['mean']:.1f} ({pm(s)}, {s['above']}/{s['n']})"
            )
        lines.append(f"| {ty} | " + " | ".join(cells) + " |")
    for name in ("always_max", "battery_rule", *TEACHERS, "lp_bound"):
        if all(name in d["baselines"][ey] for ey in years):
            lines.append(
                f"| {name.replace('_', ' ')} | "
                + " | ".join(_profit(d["baselines"][ey], name) for ey in years)
                + " |"
            )
    for name in TEACHERS:
        if not all(f"vs_{name}" in ev for row in d["matrix"].values() for ev in row.values()):
            continue
        lines += [
            "",
            f"The same agents − {name.replace('_', ' ')} of the eval year (mean ± s.e. over seeds, "
            "seeds above):",
            "",
            "| train \\ eval | " + " | ".join(years) + " |",
            "|---|" + "---|" * len(years),
        ]
        for ty, row in d["matrix"].items():
            cells = []
            for ey in years:
                st = seeds_stat(row[ey][f"vs_{name}"]["per_seed_mean"])
                cells.append(f"{pm(st)} ({st['above']}/{st['n']})")
            lines.append(f"| {ty} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def refund_effect(d: dict) -> str:
    """The tables of a ``refund_effect`` result file.

    Args:
        d: the result file's JSON: ``algo``, ``fleets`` and ``results``
            ``{fleet: {"references", "agents"}}``.

    Returns:
        The `provenance` line, and per fleet a table of every reference and agent: daily
        profit and difference to always-max with the refund and without, and the paired
        difference without - with.
    """
    lines = [provenance(d), ""]
    for fleet, res in d["results"].items():
        refs = res["references"]
        lines += [
            f"**{fleet}** ({d.get('fleets', {}).get(fleet, '')}): daily profit EUR and − always-max under the same "
            "accounting",
            "",
            "| policy | with the refund (default) | − always-max | without (the original's) | − always-max | "
            "without − with |",
            "|---|---|---|---|---|---|",
        ]
        for name in refs["refund"]:
            on, off = refs["refund"][name], refs["no_refund"][name]
            diff = paired_difference(off["daily_profit"], on["daily_profit"])
            lines.append(
                f"| {name.replace('_', ' ')} | {_profit(refs['refund'], name)} | {pm(on['vs_always_max'])} | "
                f"{_profit(refs['no_refund'], name)} | {pm(off['vs_always_max'])} | {pm(diff)} |"
            )
        for trained, row in res["agents"].items():
            on = seeds_stat(row["refund"]["paired_diff"]["per_seed_mean"])
            off = seeds_stat(row["no_refund"]["paired_diff"]["per_seed_mean"])
            lines.append(
                f"| {d['algo'].upper()} {trained.replace('_', ' ')} | "
                f"{row['refund']['metrics']['daily_profit_eur']['mean']:.1f} | {pm(on)} ({on['above']}/{on['n']}) | "
                f"{row['no_refund']['metrics']['daily_profit_eur']['mean']:.1f} | {pm(off)} ({off['above']}/{off['n']}) | "
                f"{pm(row['off_minus_on'])} |"
            )
        lines.append("")
    return "\n".join(lines)


REPORTS = {
    "traffic_sweep": traffic_sweep,
    "traffic_sweep_5e6_appendix": appendix,
    "traffic_sweep_5e6_fleets": appendix,
    "traffic_sweep_appendix": appendix,
    "alpha_ablation": alpha_ablation,
    "price_shift": price_shift,
    "refund_effect": refund_effect,
}
"""The result files (``<name>.json`` under ``--results``) and their tables: Fig. 4a at the paper's
scale, the appendix's profiles and fleets with the tuned settings (``traffic_sweep --timesteps
5e6 --profiles ... --out results/traffic_sweep_5e6``, then ``--fleets ...``, the
``_appendix`` file of that run kept as ``traffic_sweep_5e6_fleets``) and every condition with
the earlier settings, Fig. 4b-c, Fig. 5, the refund."""


def main(argv=None) -> str:
    """The command line: the tables of every file of `REPORTS` under ``--results``, printed.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        The Markdown text: a ``###`` section per file of `REPORTS`, saying so where the file
        is missing or was written by a runner that did not record its budget
        (no ``cut_note``).
    """
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--results", default="results")
    args = p.parse_args(argv)
    parts = []
    for name, fn in REPORTS.items():
        path = Path(args.results) / f"{name}.json"
        if not path.exists():
            parts.append(f"### {name}\n\n(no {path})")
            continue
        d = json.loads(path.read_text())
        if "cut_note" not in d:  # before the runners recorded their budget and machine
            parts.append(f"### {name}\n\n({path} was written by an older runner: re-run it)")
            continue
        parts.append(f"### {name}\n\n" + fn(d))
    text = "\n\n".join(parts)
    print(text)
    return text


if __name__ == "__main__":
    main()
