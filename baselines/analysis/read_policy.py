"""Read a trained run's battery along the held-out days: what it does each hour, next to the
battery-only dynamic programme (`chargax_marl.teachers.storage_value.dp_values`) and the
battery rule.

    python -m baselines.analysis.read_policy outputs/train_ippo            # a run directory of baselines.train
    python -m baselines.analysis.read_policy outputs/train_ippo --days 20 --out reading.json

For every seed (greedy policy, the run's held-out days, evaluation key 0, so the cars of
``baselines.train``'s evaluation) it reports the share of steps the batteries discharge, idle
and charge; per hour of the day, the mean action (-1 discharge ... +1 charge) and the mean
state of charge; and how often the learned battery takes the programme's action where the
programme strictly prefers one (ties, such as discharging an empty battery, left out). The
ports are read as they are: the share of port steps at full power while a car is parked.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from baselines.config import build_env_params
from baselines.runs import load_run
from chargax_marl.core import checks, simulator
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.teachers.car_plan import plan_advice
from chargax_marl.teachers.storage_value import dp_battery_action


def read(run_dir: str | Path, num_days: int | None = None) -> dict:
    """Read every seed of a run on its held-out days; see the module docstring.

    Args:
        run_dir: an output directory of ``baselines.train`` (``results.json``,
            ``params.msgpack``).
        num_days: play the first ``num_days`` held-out days; ``None`` (or 0) plays them all.

    Returns:
        ``{"run", "algo", "num_days", "per_seed"}``, per seed ``battery_share`` (the shares
        of steps with the batteries' summed level below, at and above zero),
        ``hourly_action`` and ``hourly_soc`` (per hour of the day, the mean sign of the
        batteries' summed level and their capacity-weighted state of charge, 0 to 1),
        ``agrees_with_dp`` (``None`` when the programme never strictly prefers an action),
        ``ports_full_power_share`` and ``ports_follow_plan_share`` (shares of the steps of
        parked cars).
    """
    results, train, all_params = load_run(run_dir)
    _, params, _, days = build_env_params(train.config)
    days = np.asarray(days)[:num_days] if num_days else np.asarray(days)
    make_act = train.make_act(params)
    dp_act = dp_battery_action(params)
    advice = plan_advice(params)
    is_battery = np.asarray(params.station.leaf_kind) == KIND_BATTERY
    top = int(params.num_levels)
    steps_per_hour = int(round(60.0 / float(params.step_minutes)))

    def one_day(seed_params, day, key):
        act = make_act(seed_params)

        def body(carry, _):
            state, key = carry
            key, k_act, k_step = jax.random.split(key, 3)
            levels = act(state, k_act)
            bat = jnp.sign(jnp.sum(jnp.where(is_battery, levels, 0)))
            dp, strict = dp_act(state)
            soc = jnp.sum(jnp.where(is_battery, state.soc * state.capacity_kwh, 0.0)) / jnp.maximum(
                jnp.sum(jnp.where(is_battery, state.capacity_kwh, 0.0)), 1e-6
            )
            parked = state.occupied & ~jnp.asarray(is_battery)
            full = jnp.sum(parked & (levels == top)), jnp.sum(parked)
            follows = jnp.sum(parked & ((levels == top) == (advice(state) > 0.5)))
            new_state, _ = simulator.step(k_step, state, levels, params)
            return (new_state, key), (bat, dp, strict, soc, full[0], full[1], follows)

        state = simulator.empty_state(day, params, key)
        return jax.lax.scan(body, (state, key), None, int(params.num_steps))[1]

    run_days = jax.jit(jax.vmap(one_day, in_axes=(None, 0, None)))
    key = jax.random.PRNGKey(0)
    out = {"run": str(run_dir), "algo": results["algo"], "num_days": int(days.size), "per_seed": []}
    for i in range(int(results["seeds"])):
        seed_params = jax.tree.map(lambda x: x[i], all_params)
        bat, dp, strict, soc, full, parked, follows = (
            np.asarray(x) for x in run_days(seed_params, jnp.asarray(days), key)
        )
        hours = bat.shape[1] // steps_per_hour

        def by_hour(x):
            return (
                x[:, : hours * steps_per_hour]
                .reshape(x.shape[0], hours, steps_per_hour)
                .mean(axis=(0, 2))
            )

        out["per_seed"].append(
            {
                "battery_share": {
                    name: float((bat == v).mean())
                    for name, v in (("discharge", -1), ("idle", 0), ("charge", 1))
                },
                "hourly_action": [round(float(x), 3) for x in by_hour(bat.astype(np.float64))],
                "hourly_soc": [round(float(x), 3) for x in by_hour(soc)],
                "agrees_with_dp": float((bat == dp)[strict].mean()) if strict.any() else None,
                "ports_full_power_share": float(full.sum() / max(parked.sum(), 1)),
                "ports_follow_plan_share": float(follows.sum() / max(parked.sum(), 1)),
            }
        )
    return out


def format_reading(out: dict) -> str:
    """The plain-text report of a `read` result.

    Args:
        out: a `read` result.

    Returns:
        A header line, and per seed a line of its battery and port shares and two lines of
        its hourly action and hourly state of charge.
    """
    lines = [f"{out['algo']} run {out['run']}, {out['num_days']} held-out days"]
    for i, s in enumerate(out["per_seed"]):
        share = ", ".join(f"{k} {v:.2f}" for k, v in s["battery_share"].items())
        agrees = s["agrees_with_dp"]
        agrees = "- (it never has one)" if agrees is None else f"{agrees:.2f}"
        lines.append(
            f"seed {i}: battery {share}; agrees with the programme where it has a strict best "
            f"action {agrees}; ports at full power {s['ports_full_power_share']:.3f}, "
            f"as the plan advises (plan_advice) {s['ports_follow_plan_share']:.3f}"
        )
        lines.append("  hourly action " + " ".join(f"{a:+.2f}" for a in s["hourly_action"]))
        lines.append("  hourly SoC    " + " ".join(f"{a:.2f}" for a in s["hourly_soc"]))
    return "\n".join(lines)


def main(argv=None) -> dict:
    """The command line: `read` a run directory, print the report and, with ``--out``,
    write the result as JSON.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        The `read` result.
    """
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("run_dir")
    p.add_argument("--days", type=int, default=None, help="the first N held-out days (default all)")
    p.add_argument(
        "--out", default=None, type=checks.output_option("file"), help="write the JSON here"
    )
    a = p.parse_args(argv)
    out = read(a.run_dir, a.days)
    print(format_reading(out))
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
