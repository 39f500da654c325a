"""``python -m baselines.analysis.shaving``: a simple control for a learned gain over the
coupled plan, the coupled plan with a peak-shaving battery.

The rule plays the coupled plan (`chargax_marl.teachers.rules.coupled_plan_rule`) and
overrides the batteries' level with full discharge whenever the ports' requested draw at the
grid connection (what the plan's port levels ask for, before the node limits cut it) is above
``threshold_frac`` of the connection's limit. It reads the station's state as every rule
does, the same demand the learners' station columns summarise. The threshold is chosen on
the task's validation days (drawn from its training days, one car draw, key 1), then the
chosen rule is scored once on the held-out days and, given score files, set against each
learner paired per day and draw.

    python -m baselines.analysis.shaving --task Chargax-shopping-peak-v3 \\
        --thresholds 0.05,0.1,0.15,0.2,0.25,0.3,0.4 \\
        --against results/scores/ippo_distill_station_Chargax-shopping-peak-v3.json \\
        --out results/controls/shaving_Chargax-shopping-peak-v3.json
"""

from __future__ import annotations

import argparse
import json

import jax
import jax.numpy as jnp
import numpy as np

from baselines.runs import write_json
from chargax_marl.benchmark import get_task
from chargax_marl.benchmark.scoring import score
from chargax_marl.core import checks, physics
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.evaluation import run_policy_days
from chargax_marl.teachers.rules import coupled_plan_rule

VALIDATION_KEY = 1
"""The key of the validation days' car draw."""


def shaving_rule(params, threshold_frac: float):
    """The coupled plan whose batteries discharge at full power while the ports' requested
    draw at the grid connection is above ``threshold_frac`` of its limit.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams`.
        threshold_frac: the threshold as a fraction of the grid connection's limit (the root
            node's ``node_max_kw``), at least 0.

    Returns:
        ``policy(state, key, params) -> levels`` (int32 ``(L,)``).

    Raises:
        ValueError: ``threshold_frac`` is negative or not finite.
    """
    if not np.isfinite(threshold_frac) or threshold_frac < 0:
        raise ValueError(f"threshold_frac: expected a finite fraction >= 0, got {threshold_frac!r}")
    plan = coupled_plan_rule(params)
    st = params.station
    is_battery = jnp.asarray(np.asarray(st.leaf_kind) == KIND_BATTERY)
    threshold_kw = float(threshold_frac) * st.node_max_kw[0]

    def act(state, key, p):
        levels = plan(state, key, p)
        ports = jnp.where(is_battery, 0, levels)
        port_kw = physics.requested_current(ports, state, p) * st.leaf_voltage_v / 1000.0
        draw_kw = physics.node_flows_kw(port_kw, st)[0]
        battery = jnp.where(draw_kw > threshold_kw, -p.num_levels, levels)
        return jnp.where(is_battery, battery, levels).astype(jnp.int32)

    return act


def _paired(a: np.ndarray, b: np.ndarray) -> dict:
    """Mean and standard error over days of ``a - b``, each ``(days,)`` EUR."""
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    return {"mean": float(d.mean()), "stderr": float(d.std(ddof=1) / np.sqrt(d.size))}


def _per_day(daily_profit) -> np.ndarray:
    """``(days,)`` the mean over seeds and draws of ``(..., days, draws)`` profits."""
    arr = np.asarray(daily_profit, np.float64)
    return arr.reshape(-1, *arr.shape[-2:]).mean(axis=(0, 2))


def choose(task, thresholds) -> tuple[float, list[dict]]:
    """Play the rule at every threshold and the coupled plan on the task's validation days.

    Args:
        task: a `chargax_marl.benchmark.tasks.Task`.
        thresholds: fractions of the connection's limit.

    Returns:
        ``(best, rows)``: the threshold with the highest mean profit and, per threshold,
        ``{"threshold_frac", "profit_eur", "vs_coupled_plan", "peak_grid_kw"}`` (paired over
        the validation days, EUR/day).
    """
    params = task.validation_params()
    days = task.validation_days()
    key = jax.random.PRNGKey(VALIDATION_KEY)
    base = np.asarray(run_policy_days(coupled_plan_rule(params), params, days, key).profit_eur)
    rows = []
    for frac in thresholds:
        totals = run_policy_days(shaving_rule(params, frac), params, days, key)
        profit = np.asarray(totals.profit_eur)
        rows.append(
            {
                "threshold_frac": float(frac),
                "profit_eur": float(profit.mean()),
                "vs_coupled_plan": _paired(profit, base),
                "peak_grid_kw": float(np.asarray(totals.peak_grid_kw).mean()),
            }
        )
    best = max(rows, key=lambda r: r["profit_eur"])["threshold_frac"]
    return best, rows


def main(argv=None) -> dict:
    """The command line (see the module docstring).

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        ``{"task", "validation", "threshold_frac", "held_out", "against"}``: the validation
        rows, the chosen threshold, the held-out score and paired differences with the
        references (`chargax_marl.benchmark.scoring.score`), and per ``--against`` file the
        learner less the rule (EUR/day, paired over the held-out days).

    Raises:
        ValueError: a ``--against`` score file was scored on another task.
    """
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", required=True, help="a benchmark task id or task file")
    p.add_argument(
        "--thresholds",
        default="0.05,0.1,0.15,0.2,0.25,0.3,0.4",
        help="comma-separated fractions of the connection's limit to choose from",
    )
    p.add_argument("--against", nargs="*", default=[], metavar="SCORE_FILE")
    p.add_argument("--out", default=None, type=checks.output_option("file"))
    a = p.parse_args(argv)
    task = get_task(a.task)
    thresholds = [float(x) for x in a.thresholds.split(",")]
    best, rows = choose(task, thresholds)
    for r in rows:
        d = r["vs_coupled_plan"]
        print(
            f"validation, threshold {r['threshold_frac']:.2f}: {d['mean']:+.2f} ± "
            f"{d['stderr']:.2f} EUR/day over the coupled plan, peak {r['peak_grid_kw']:.0f} kW"
        )
    held = score(shaving_rule(task.scored_params(), best), task)
    rule_days = _per_day(held["daily_profit"])
    print(
        f"held-out, threshold {best:.2f}: score {held['score']:.3f} ± {held['score_stderr']:.3f}, "
        f"{held['vs']['coupled_plan']['mean']:+.2f} ± {held['vs']['coupled_plan']['stderr']:.2f}"
        " EUR/day over the coupled plan"
    )
    against = {}
    for path in a.against:
        with open(path) as f:
            learner = json.load(f)
        if learner["task"] != task.id:
            raise ValueError(f"--against {path}: scored on {learner['task']}, not {task.id}")
        diff = _paired(_per_day(learner["daily_profit"]), rule_days)
        against[path] = {"name": learner.get("name"), "learner_minus_rule": diff}
        print(f"{learner.get('name')}: {diff['mean']:+.2f} ± {diff['stderr']:.2f} over the rule")
    out = {
        "task": task.id,
        "validation": {
            "days": task.validation_days().tolist(),
            "key": VALIDATION_KEY,
            "rows": rows,
        },
        "threshold_frac": best,
        "held_out": {
            k: held[k]
            for k in ("score", "score_stderr", "vs", "over_always_max_eur", "eur_per_day")
        },
        "against": against,
    }
    if a.out:
        write_json(out, a.out)
    return out


if __name__ == "__main__":
    main()
