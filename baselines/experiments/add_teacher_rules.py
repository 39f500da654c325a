"""Score committed training results against the teachers' rules, without retraining.

    python -m baselines.experiments.add_teacher_rules results/traffic_sweep.json ...

The trainers' shaping teachers, played as rules with no learning
(`baselines.eval.rules.TEACHER_RULES`):

- ``battery_programme``: always-max ports, the batteries on the battery-only programme (the
  teacher of ``BATTERY_SHAPING="dp"``, PPO's and the multi-agent settings');
- ``plan_programme``: the ports on their cars' plans, the batteries on the programme (also
  the teacher of ``PORT_SHAPING="plan"`` and ``PLAN_OBS``, the multi-agent settings').

`baselines.eval.heldout.baseline_results` evaluates both on every station with a battery, so
each new run records its paired differences to them (``vs_battery_programme``,
``vs_plan_programme``). Runs made before that lack them; this adds to every training result
in each file (a ``baselines.train`` result: ``config``, ``evaluation``, ``per_seed``) what a
new run would record:

- each rule in the evaluation table, with its paired differences to always-max and to the
  battery rule and its share of the LP bound's headroom;
- per seed and over seeds, ``vs_<rule>`` (the seed's mean paired difference and its standard
  error over the held-out days);
- the run's ``vs_<rule>`` over seeds × days.

A ``price_shift`` result (Fig. 5) gets the rules per evaluation year and each cell's
``vs_<rule>``.

The first-beats budgets are not added: the stored evaluations during training keep only each
seed's mean profit. Before touching a result it rebuilds the run's evaluation params and
held-out days from its ``config`` and replays always-max and the battery rule with the
evaluation key; a run whose stored days or profits differ from the replay (another model
version) is refused with a ``ValueError``, and the file is left as it was. The file is
rewritten in place.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from baselines import runs
from baselines.config import build_env_params, resolve
from baselines.eval import stats
from baselines.eval.heldout import add_headroom
from baselines.eval.rules import (
    TEACHER_RULES,
    check_replay,
    evaluate_rules,
)
from baselines.eval.stats import over_seeds
from baselines.experiments._common import TUNED, with_env_kwargs
from chargax_marl.teachers.rules import has_battery


def training_results(tree, path: str = "") -> list[tuple[str, dict]]:
    """``(where, result)`` of every ``baselines.train`` result nested in a result file.

    Args:
        tree: a result file's JSON value (or a part of it).
        path: the ``/``-joined keys that lead to ``tree`` (``""`` at the top).

    Returns:
        ``(where, result)`` for every dict with ``config``, ``evaluation`` and ``per_seed``
        (searched through nested dicts, not lists; not inside such a result), ``where`` its
        ``/``-joined keys (``"/"`` for the file itself); ``[]`` when there is none.
    """
    if isinstance(tree, dict):
        if {"config", "evaluation", "per_seed"} <= set(tree):
            return [(path or "/", tree)]
        return [hit for k, v in tree.items() for hit in training_results(v, f"{path}/{k}")]
    return []


def teacher_entries(params, days, stored: dict, where: str) -> dict:
    """``{rule: entry}`` of the teachers' rules on ``days`` (evaluation key 0), each with its
    paired differences to the stored always-max and battery rule and its headroom share, after
    checking that always-max and the battery rule replayed on this code give the stored
    ``stored[name]["daily_profit"]`` (else a ``ValueError``: the run was made on another model).

    Args:
        params: the run's evaluation env parameters.
        days: the run's held-out days, rebuilt from its config.
        stored: the stored evaluation table (``{name: entry}``) with ``always_max`` (and its
            ``days``) and ``battery_rule``, and ``lp_bound`` for the headroom.
        where: the result's name, for the error messages.

    Returns:
        ``{rule: entry}`` per rule of `baselines.eval.rules.TEACHER_RULES`: the
        `baselines.eval.rules.evaluate_rules` entry with ``vs_always_max``,
        ``vs_battery_rule`` and, when ``stored`` holds ``lp_bound``, ``headroom``.

    Raises:
        ValueError: ``days`` differ from the stored always-max's, or always-max or the
            battery rule replay differently (`baselines.eval.rules.check_replay`).
    """
    if [int(d) for d in np.asarray(days)] != [int(d) for d in stored["always_max"]["days"]]:
        raise ValueError(f"{where}: its config builds other held-out days than it was evaluated on")
    rules = evaluate_rules(params, days, ("always_max", "battery_rule") + TEACHER_RULES)
    check_replay(rules, stored, ("always_max", "battery_rule"), where)
    out = {}
    for name in TEACHER_RULES:
        e = rules[name]
        for ref in ("always_max", "battery_rule"):
            e[f"vs_{ref}"] = stats.paired_difference(e["daily_profit"], stored[ref]["daily_profit"])
        add_headroom({name: e}, stored)
        out[name] = e
    return out


def add_to_result(res: dict, where: str = "") -> bool:
    """Add the teachers' rules to one training result in place (see the module's doc).
    ``False`` when the run's station has no battery (nothing to add).

    Args:
        res: a ``baselines.train`` result (``config``, ``algo``, ``evaluation``,
            ``per_seed``); changed in place.
        where: the result's name, for the error messages.

    Returns:
        ``True`` when the rules were added, ``False`` when the station has no battery.

    Raises:
        ValueError: the stored run does not replay on this code (`teacher_entries`).
    """
    _, params, _, days = build_env_params(resolve(res["config"]))
    if not has_battery(params):
        return False
    table, algo = res["evaluation"]["table"], res["algo"]
    rules = teacher_entries(params, days, table, where)
    res["evaluation"]["table"] = {
        **{k: v for k, v in table.items() if k not in rules and k != algo},
        **rules,
        algo: table[algo],
    }
    learned = np.atleast_2d(np.asarray(table[algo]["daily_profit"], np.float64))
    summary = res.get("over_seeds", {})
    for name, rule in rules.items():
        vs, key = stats.paired_difference(learned, rule["daily_profit"]), f"vs_{name}"
        for i, seed in enumerate(res["per_seed"]):
            items = [(k, v) for k, v in seed.items() if k != key]
            at = next(j for j, (k, _) in enumerate(items) if k == "headroom_fraction")
            items.insert(
                at, (key, {"mean": vs["per_seed_mean"][i], "stderr": vs["per_seed_stderr"][i]})
            )
            res["per_seed"][i] = dict(items)
        summary = {
            **{k: v for k, v in summary.items() if k.startswith("vs_") and k != key},
            key: over_seeds([s[key]["mean"] for s in res["per_seed"]]),
            **{k: v for k, v in summary.items() if not k.startswith("vs_")},
        }
        res[key] = vs
    res["over_seeds"] = summary
    return True


def add_to_price_shift(d: dict, where: str = "") -> dict:
    """Add the teachers' rules to a ``price_shift`` result (``matrix`` train year x eval year,
    ``baselines`` per eval year) in place: per eval year the rules' entries, checked as in
    `teacher_entries`, and per cell ``vs_<rule>``. Returns ``{cell: {key: difference}}``.

    Args:
        d: a ``price_shift`` result file's JSON (``settings``, ``algo``, ``matrix``,
            ``baselines``); changed in place.
        where: the file's name, for the error messages.

    Returns:
        ``{"<train year> -> <eval year>": {"vs_<rule>": paired difference}}`` per cell, the
        differences over seeds × days in EUR/day (`baselines.eval.stats.paired_difference`).

    Raises:
        ValueError: the result's settings are not ``"tuned"``, or an eval year's always-max
            or battery rule does not replay (`teacher_entries`).
    """
    if d.get("settings") != "tuned":
        raise ValueError(
            f"{where}: settings {d.get('settings')!r}; only the tuned settings' params are rebuilt here"
        )
    for year, bl in d["baselines"].items():
        # the price-shift runner plays the paper's session model (`_common.config_of`)
        config = with_env_kwargs(TUNED[d["algo"]], session_model="paper", prices=year)
        _, params, _, days = build_env_params(resolve(config))
        bl.update(teacher_entries(params, days, bl, f"{where} {year}"))
    rows = {}
    for train_year, row in d["matrix"].items():
        for eval_year, ev in row.items():
            bl = d["baselines"][eval_year]
            for name in (n for n in bl if n.endswith("_programme")):
                ev[f"vs_{name}"] = stats.paired_difference(
                    ev["daily_profit"], bl[name]["daily_profit"]
                )
            rows[f"{train_year} -> {eval_year}"] = {
                k: v for k, v in ev.items() if k.endswith("_programme")
            }
    return rows


def _line(diffs: dict) -> str:
    return ", ".join(f"{k[3:]} {v['mean']:+.2f} ± {v['stderr']:.2f}" for k, v in diffs.items())


def main(argv=None) -> dict:
    """The command line: add the teachers' rules to every result file named, print a line per
    training result (or ``price_shift`` cell) and rewrite each file in place.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        ``{file: rows}``: for a ``price_shift`` file the `add_to_price_shift` rows, otherwise
        ``{where: the result's over-seeds vs_<reference>}`` per training result with a battery.

    Raises:
        ValueError: a file (not a ``price_shift`` one) holds no ``baselines.train`` result,
            or a result does not replay on this code; the files named before it are already
            rewritten.
    """
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "files", nargs="+", help="result files of baselines.train or of the experiment runners"
    )
    args = p.parse_args(argv)
    out = {}
    for f in args.files:
        d = json.loads(Path(f).read_text())
        if "matrix" in d and d.get("figure") == "Fig. 5":
            rows = add_to_price_shift(d, f)
            for cell, diffs in rows.items():
                print(f"{f} {cell}: {d['algo']} − {_line(diffs)} (over seeds × days)", flush=True)
        else:
            found = training_results(d)
            if not found:
                raise ValueError(f"{f}: no baselines.train result in it")
            rows = {}
            for where, res in found:  # all checked before the file is written
                if not add_to_result(res, f"{f}{where}"):
                    print(f"{f}{where}: no battery, nothing added")
                    continue
                rows[where] = {k: v for k, v in res["over_seeds"].items() if k.startswith("vs_")}
                print(
                    f"{f}{where}: {res['algo']} − {_line(rows[where])} (over {len(res['per_seed'])} seeds)",
                    flush=True,
                )
        runs.write_json(d, f)
        out[f] = rows
    return out


if __name__ == "__main__":
    main()
