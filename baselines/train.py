"""Train PPO, IPPO or MAPPO on a scenario, evaluate on held-out days, write PNG + JSON + checkpoint.

    python -m baselines.train --algo ippo --scenario shopping --traffic medium \\
        --timesteps 1e6 --seeds 4 --out baselines/results/ippo_shopping

Several seeds train in one compiled program (``jax.vmap``); the env batch is sharded over
every device JAX sees: the local ones, or those of every process with ``--coordinator HOST:PORT
--num-processes N --process-id i`` (``jax.distributed``; only process 0 writes ``--out``).
Training runs in ``--chunks`` jitted pieces under a progress bar; after
each piece the current greedy policies are evaluated on the held-out days, so the JSON
records the budget (steps and minutes) at which the mean over seeds first beats always-max.
The baselines (always-max, the battery rule, price-threshold and, on a station with a
battery, the teachers' rules ``battery_programme`` and ``plan_programme``) are evaluated on
the same held-out days (``split_days(num_days, 100, seed=0)``; training resets use the other
days only) and cars; each seed's paired difference to each is in the JSON.

Outputs in ``--out``: ``curve.png`` (training episode profit, mean ± std over seeds, the
held-out evaluations as points, the baselines as horizontal lines), ``results.json``
(config, curves, evaluation table, wall time, timesteps) and ``params.msgpack`` (the final
parameters of every seed, ``flax.serialization``; leading axis = seed).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

if __name__ == "__main__":  # before the imports below: importing gymnax already runs JAX, after which
    from baselines import distributed  # jax.distributed.initialize() is refused

    distributed.initialize_from_argv()
from baselines import common, outputs  # noqa: E402
from chargax_marl.machine import code_version  # noqa: E402

ALGOS = ("ppo", "ippo", "mappo")


def get_module(algo: str):
    from baselines import ippo, mappo, ppo

    return {"ppo": ppo, "ippo": ippo, "mappo": mappo}[algo]


# Settings used for the measured CPU runs (differences from Table 3 are documented in README).
FAST = {"NUM_ENVS": 24, "NUM_STEPS": 150, "HIDDEN": 64, "LR": 1e-3, "ENT_COEF": 0.0, "REWARD_SCALE": 0.1,
        "BATTERY_SHAPING": True}


BASELINES = ("always_max", "battery_rule", "price_threshold")
"""The rule-based references every training run is scored against (``battery_rule`` is
always-max plus a battery that charges in the day's cheapest 20 % of hours and discharges in
the dearest 20 %); on a station with a battery also the teachers' rules,
``battery_programme`` (always-max plus the battery-only programme) and ``plan_programme``
(the ports' plans plus the programme), :data:`baselines.heuristics.TEACHER_RULES`."""

REFERENCES = ("always_max", "battery_rule", "battery_programme", "plan_programme")
"""The baselines each trained seed gets a paired difference to (``vs_<name>``), where present."""


OPTIMAL_CHOICES = ("off", "bound", "mpc")


def baseline_results(eval_params, eval_days, optimal: str = "off", draws: int = 1) -> dict:
    """The :data:`BASELINES` (and, on a station with a battery, the teachers' rules) on the
    held-out days, with the evaluation's default key (the same
    drawn cars that :func:`baselines.common.evaluate_batched` gives the agents). Each keeps its
    daily profits (``daily_profit``) for paired comparisons.

    ``optimal``: ``"bound"`` adds ``lp_bound`` (the LP hindsight bound over always-max's
    occupancy, :func:`chargax_marl.evaluation.hindsight_bound`) and, when ``make optimal``
    stored it for exactly these params and days, ``mpc``; ``"mpc"`` also runs the MPC when no
    stored result matches (about 10 min per 100 days on 2 cores); ``"off"`` adds neither.
    Every entry then gets ``headroom`` (:func:`chargax_marl.evaluation.headroom_captured`).
    With ``draws`` > 1 every rule and the bound are scored under the keys of
    :func:`baselines.common.draw_keys`, each day's profit the mean over the draws; the stored
    MPC (one draw) is then not used, and ``optimal="mpc"`` runs the MPC on every draw.
    """
    from baselines.heuristics import TEACHER_RULES, evaluate_rules, has_battery

    if optimal not in OPTIMAL_CHOICES:
        raise ValueError(f"field 'optimal' must be one of {OPTIMAL_CHOICES}, got {optimal!r}")
    out = evaluate_rules(eval_params, eval_days, BASELINES + TEACHER_RULES * has_battery(eval_params), draws=draws)
    for name in REFERENCES[1:]:
        if name in out:
            out[name]["vs_always_max"] = common.paired_difference(out[name]["daily_profit"],
                                                                  out["always_max"]["daily_profit"])
    for name in TEACHER_RULES:
        if name in out:
            out[name]["vs_battery_rule"] = common.paired_difference(out[name]["daily_profit"],
                                                                    out["battery_rule"]["daily_profit"])
    if optimal == "off":
        return out
    from baselines.optimal import cached, evaluate_mpc
    from chargax_marl.evaluation import hindsight_bound, summarize_profit

    stored = cached(eval_params, eval_days) if draws == 1 else None
    if stored is not None:
        bound_daily = np.asarray(stored["policies"]["lp_bound"]["daily_profit"])
        mpc_daily = np.asarray(stored["policies"]["mpc"]["daily_profit"])
        source = "baselines/results/optimal (same params and days)"
    else:
        keys = common.draw_keys(draws)
        bound_daily = common.mean_over_draws(lambda k: hindsight_bound(eval_params, eval_days, k)["daily_profit"], keys)
        mpc_daily = (common.mean_over_draws(lambda k: evaluate_mpc(eval_params, eval_days, k)["daily_profit"], keys)
                     if optimal == "mpc" else None)
        source = "computed" if draws == 1 else f"computed, mean over {draws} car draws per day"
    out["lp_bound"] = {"daily_profit": bound_daily, "metrics": summarize_profit(bound_daily), "source": source}
    if mpc_daily is not None:
        out["mpc"] = {"daily_profit": mpc_daily, "metrics": summarize_profit(mpc_daily), "source": source}
    add_headroom(out, out)
    return out


def add_headroom(entries: dict, baselines: dict) -> dict:
    """Add ``headroom`` (fraction of the hindsight headroom captured) to every entry that has
    ``daily_profit``, when ``baselines`` hold ``lp_bound`` and ``always_max``."""
    from chargax_marl.evaluation import headroom_captured

    if "lp_bound" not in baselines:
        return entries
    am, bound = baselines["always_max"]["daily_profit"], baselines["lp_bound"]["daily_profit"]
    for e in entries.values():
        if isinstance(e, dict) and "daily_profit" in e:
            e["headroom"] = headroom_captured(e["daily_profit"], am, bound)
    return entries


def beats(paired: dict) -> bool:
    """Significantly better than the reference: the paired mean difference over seeds × days
    exceeds two standard errors."""
    return paired["mean"] > 2.0 * paired["stderr"]


def seed_beats(paired: dict, i: int) -> bool:
    """Seed ``i`` is significantly better than the reference on the held-out days (its mean paired
    difference exceeds two standard errors over days)."""
    return paired["per_seed_mean"][i] > 2.0 * paired["per_seed_stderr"][i]


def over_seeds(values) -> dict:
    """Mean and standard error over seeds of per-seed numbers (``stderr`` is NaN for one seed)."""
    v = np.asarray(values, np.float64)
    return {"mean": float(v.mean()), "stderr": float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else float("nan"),
            "min": float(v.min()), "max": float(v.max()), "all_seeds_positive": bool(np.all(v > 0))}


def per_seed_results(final: dict, evals: list, baselines: dict, seed: int) -> list[dict]:
    """One entry per trained seed: its paired differences (mean and standard error over the
    held-out days) to always-max (``vs_always_max``), to always-max + battery rule
    (``vs_battery_rule``) and, where the baselines hold them, to the teachers' rules
    (``vs_battery_programme``, ``vs_plan_programme``), the fraction of the LP bound's headroom it captures
    (``headroom_fraction``, when the bound was computed), and the env steps and wall minutes
    (since the start of training, compile and evaluations included) of the first held-out
    evaluation at which this seed beats each reference by more than two standard errors
    (``None``: never)."""
    from chargax_marl.evaluation import headroom_captured

    profit = np.atleast_2d(np.asarray(final["daily_profit"], np.float64))
    am = np.asarray(baselines["always_max"]["daily_profit"], np.float64)
    bound = baselines.get("lp_bound", {}).get("daily_profit")
    vs = {name: common.paired_difference(profit, baselines[name]["daily_profit"])
          for name in REFERENCES if name in baselines}
    out = []
    for i in range(profit.shape[0]):
        def first(key):
            e = next((e for e in evals if e.get(key) is not None and seed_beats(e[key], i)), None)
            return None if e is None else {"timesteps": e["timesteps"], "wall_minutes": e["train_seconds"] / 60.0}

        entry = {"seed_index": i, "key": f"split(PRNGKey({seed}), seeds)[{i}]", "mean_profit_eur": float(profit[i].mean())}
        for name in (n for n in REFERENCES if n in vs or n == "battery_rule"):  # battery_rule: None when absent
            d = vs.get(name)
            entry[f"vs_{name}"] = None if d is None else {"mean": d["per_seed_mean"][i], "stderr": d["per_seed_stderr"][i]}
        entry["headroom_fraction"] = None if bound is None else headroom_captured(profit[i], am, bound)["fraction"]
        for name in REFERENCES:
            if f"vs_{name}" in entry:
                entry[f"first_beats_{name}"] = first(f"vs_{name}")
        out.append(entry)
    return out


def chunked_updates(config: dict, chunks: int) -> tuple[int, int]:
    """``(chunks, updates)`` that :func:`run` trains ``config`` with: the updates its
    ``TOTAL_TIMESTEPS`` holds, rounded down to equal chunks (one compiled program)."""
    n_upd = common.num_updates(config)
    chunks = max(1, min(chunks, n_upd))
    return chunks, (n_upd // chunks) * chunks


def run(algo: str, config: dict, seeds: int = 1, seed: int = 0, out: str | Path | None = None, chunks: int = 10,
        evaluate_every_chunk: bool = True, baselines: dict | None = None, eval_params=None, eval_days=None,
        env_params=None, title: str | None = None, quiet: bool = False, optimal: str = "off") -> dict:
    """Train ``seeds`` seeds of ``algo`` and evaluate them; returns the results dict (and
    writes the outputs when ``out`` is given). ``eval_params`` / ``env_params`` override the
    evaluation and training parameters (e.g. another price year). ``optimal`` adds the LP
    bound (and the MPC) to the baselines, see :func:`baseline_results`."""
    from chargax_marl.evaluation import format_table

    from baselines import distributed

    main_process = distributed.is_main()  # only process 0 writes and prints the evaluation
    quiet = quiet or not main_process
    out = out if main_process else None
    multi = jax.process_count() > 1
    host = distributed.to_host if multi else (lambda tree: tree)  # params readable on this process
    mod = get_module(algo)
    config = common.parse_config({}, config)
    steps_per_update = config["NUM_ENVS"] * config["NUM_STEPS"]
    chunks, n_upd = chunked_updates(config, chunks)
    config["TOTAL_TIMESTEPS"] = n_upd * steps_per_update
    train_params, full_params, train_days, held_out = common.build_env_params(config)
    env_params = train_params if env_params is None else env_params
    eval_params = full_params if eval_params is None else eval_params
    eval_days = held_out if eval_days is None else eval_days
    t_start = time.time()
    train = mod.make_train(config, env_params)
    make_act = train.make_act(eval_params)
    draws = int(config["EVAL_DRAWS"])
    if baselines is None:
        baselines = baseline_results(eval_params, eval_days, optimal, draws)
    am = baselines["always_max"]["metrics"]["daily_profit_eur"]["mean"]
    am_daily = baselines["always_max"].get("daily_profit")
    rule_daily = baselines.get("battery_rule", {}).get("daily_profit")
    teachers = [name for name in REFERENCES[2:] if name in baselines]  # the teachers' rules (a station with a battery)
    evals = []

    def vs_rule(ev):
        return None if rule_daily is None else common.paired_difference(ev["daily_profit"], rule_daily)

    def vs_programme(ev):
        return {f"vs_{name}": common.paired_difference(ev["daily_profit"], baselines[name]["daily_profit"])
                for name in teachers}

    def on_chunk(i, rs, m, steps, seconds):
        if not evaluate_every_chunk and i < chunks - 1:
            return
        ev = common.evaluate_batched(make_act, host(rs.params), eval_params, eval_days, reference_profit=am_daily,
                                     draws=draws)
        teacher_diffs = vs_programme(ev)
        evals.append({"timesteps": int(steps), "train_seconds": seconds, "per_seed_profit": ev["per_seed_profit"],
                      "mean_profit": float(np.mean(ev["per_seed_profit"])),
                      "vs_always_max": ev.get("paired_diff"), "vs_battery_rule": vs_rule(ev), **teacher_diffs})
        if not quiet:
            from tqdm.auto import tqdm

            diff, rule = ev.get("paired_diff"), vs_rule(ev)
            vs = f"; vs always-max {diff['mean']:+.2f} ± {diff['stderr']:.2f}" if diff else ""
            vs += f", vs battery rule {rule['mean']:+.2f} ± {rule['stderr']:.2f}" if rule else ""
            vs += "".join(f", vs {k[3:].replace('_', ' ')} {d['mean']:+.2f} ± {d['stderr']:.2f}"
                          for k, d in teacher_diffs.items())
            tqdm.write(f"  held-out greedy daily profit: {np.mean(ev['per_seed_profit']):.1f} EUR "
                       f"(per seed {np.round(ev['per_seed_profit'], 1).tolist()}; always-max {am:.1f}{vs})")

    keys = jax.random.split(jax.random.PRNGKey(seed), seeds)
    if multi:  # inputs of a program over every process's devices must be global arrays
        keys = distributed.replicate(keys)
    rs, metrics, train_seconds = common.run_in_chunks(train, keys, chunks, on_chunk, desc=algo)
    params = host(rs.params)
    final = common.evaluate_batched(make_act, params, eval_params, eval_days, reference_profit=am_daily, draws=draws)
    wall = time.time() - t_start
    first_beat = next((e for e in evals if e["vs_always_max"] is not None and beats(e["vs_always_max"])), None)
    first_beat_rule = next((e for e in evals if e["vs_battery_rule"] is not None and beats(e["vs_battery_rule"])), None)
    add_headroom({"final": final}, baselines)
    table = {**baselines, algo: final}
    if not quiet:
        print(format_table(table))
    timesteps = (np.arange(n_upd) + 1) * steps_per_update
    per_seed = per_seed_results(final, evals, baselines, seed)
    summary = {f"vs_{k}": over_seeds([p[f"vs_{k}"]["mean"] for p in per_seed]) for k in REFERENCES
               if all(p.get(f"vs_{k}") is not None for p in per_seed)}
    if all(p["headroom_fraction"] is not None for p in per_seed):
        summary["headroom_fraction"] = over_seeds([p["headroom_fraction"] for p in per_seed])
    results = {
        "algo": algo,
        "scenario": {"name": config["SCENARIO"], "traffic": config["TRAFFIC"], "env_kwargs": config["ENV_KWARGS"],
                     "held_out_days": int(np.size(eval_days)), "car_draws_per_day": draws},
        "per_seed": per_seed,
        "over_seeds": summary,
        "config": config,
        "seeds": seeds,
        "seed": seed,
        "devices": [str(d) for d in jax.devices()],
        "code": code_version(),
        "num_processes": jax.process_count(),
        "timesteps": int(config["TOTAL_TIMESTEPS"]),
        "wall_seconds": wall,
        "train_seconds_incl_compile": train_seconds,
        "evaluation": {"policy": "greedy (argmax per head)",
                       "key": ("PRNGKey(0) for every policy and seed (common random numbers)" if draws == 1 else
                               f"PRNGKey(0) ... PRNGKey({draws - 1}) for every policy and seed (common random "
                               f"numbers), each day's totals the mean over the {draws} car draws"),
                       "draws": draws, "num_days": int(np.size(eval_days)),
                       "days": [int(d) for d in np.asarray(eval_days)], "table": table},
        "vs_always_max": final.get("paired_diff"),
        "vs_battery_rule": vs_rule(final),
        **vs_programme(final),
        "headroom": final.get("headroom"),
        "first_beats_always_max": first_beat,
        "first_beats_battery_rule": first_beat_rule,
        **{f"first_beats_{name}": next((e for e in evals if beats(e[f"vs_{name}"])), None) for name in teachers},
        "eval_curve": evals,
        "curve": {"timesteps": timesteps,
                  **{k: np.asarray(metrics[k]) for k in ("episode_profit_eur", "episode_return", "entropy",
                                                           "value_loss", "actor_loss")}},
    }
    if not quiet:
        for p_ in per_seed:
            rule, hf = p_["vs_battery_rule"], p_["headroom_fraction"]
            print(f"seed {p_['seed_index']}: vs always-max {p_['vs_always_max']['mean']:+.2f} ± "
                  f"{p_['vs_always_max']['stderr']:.2f}" + (f", vs battery rule {rule['mean']:+.2f} ± "
                                                            f"{rule['stderr']:.2f}" if rule else "")
                  + "".join(f", vs {name.replace('_', ' ')} {p_[f'vs_{name}']['mean']:+.2f} ± "
                            f"{p_[f'vs_{name}']['stderr']:.2f}" for name in teachers)
                  + (f", headroom {hf:.2f}" if hf is not None else "")
                  + f"; first beats the battery rule: {p_['first_beats_battery_rule']}")
        for k, v in summary.items():
            print(f"over seeds, {k}: {v['mean']:+.3f} ± {v['stderr']:.3f} (min {v['min']:+.3f}, max {v['max']:+.3f})")
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        outputs.save_params(params, out / "params.msgpack")
        plot_curve(out / "curve.png", algo, timesteps, metrics["episode_profit_eur"], baselines, evals,
                   title or f"{algo.upper()} {config['SCENARIO']} / {config['TRAFFIC']}: {seeds} seeds"
                   + (f", held-out days x {draws} car draws" if draws > 1 else ""))
        outputs.write_json(results, out / "results.json")
        if not quiet:
            print(f"wrote {out / 'curve.png'}, {out / 'results.json'}, {out / 'params.msgpack'}")
    results["_params"], results["_train"] = params, train  # for callers (not written to JSON)
    return results


LINES = (("battery_rule", "always-max + battery rule"), ("battery_programme", "always-max + battery programme"),
         ("plan_programme", "plan + battery programme"), ("price_threshold", "price-threshold"),
         ("mpc", "MPC, 4 h horizon"), ("lp_bound", "LP hindsight bound"))
"""The reference policies drawn as horizontal lines on a learning curve (after always-max)."""


def plot_curve(path, algo: str, timesteps, episode_profit, baselines: dict, evals: list, title: str):
    """A run's learning curve: the sampled training-episode profit over seeds, the held-out
    greedy evaluations, and every reference of ``baselines`` present (:data:`LINES`) as a line."""
    am = baselines["always_max"]["metrics"]["daily_profit_eur"]["mean"]
    lines = {f"always-max (held-out) {am:.0f}": am}
    for key, label in LINES:
        if key in baselines:
            v = baselines[key]["metrics"]["daily_profit_eur"]["mean"]
            lines[f"{label} (held-out) {v:.0f}"] = v
    outputs.plot_learning_curve(
        path, timesteps, {f"{algo} training episodes (sampled)": np.asarray(episode_profit)}, lines, title,
        eval_points={f"{algo} held-out (greedy)": ([e["timesteps"] for e in evals],
                                                    np.asarray([e["per_seed_profit"] for e in evals]).T)}
        if evals else None)


def add_stored_mpc(run_dir) -> dict:
    """Add the MPC that ``make optimal`` (``python -m baselines.optimal``) stored for exactly a
    run's evaluation params and held-out days to the run's ``results.json`` (its evaluation
    table, with ``headroom`` and the run's paired difference to it, ``vs_mpc``) and redraw its
    ``curve.png`` with the MPC line, without retraining. Raises ``LookupError`` when no stored
    result matches (run ``python -m baselines.optimal --scenarios ...`` for these params first)."""
    from baselines.optimal import cached
    from chargax_marl.evaluation import summarize_profit

    run_dir = Path(run_dir)
    results = json.loads((run_dir / "results.json").read_text())
    config = common.parse_config({}, results["config"])
    _, eval_params, _, days = common.build_env_params(config)
    days = results["evaluation"]["days"] if results["evaluation"].get("days") else days
    if int(config["EVAL_DRAWS"]) != 1:
        raise LookupError(f"{run_dir}: evaluated on {config['EVAL_DRAWS']} car draws per day; the stored MPC "
                          "is one draw (PRNGKey(0)), so it does not pair with this run")
    stored = cached(eval_params, days)
    if stored is None or "mpc" not in stored["policies"]:
        raise LookupError(f"{run_dir}: no stored MPC for its params and {len(days)} held-out days in "
                          "baselines/results/optimal (run `python -m baselines.optimal` for this scenario)")
    table = results["evaluation"]["table"]
    mpc_daily = np.asarray(stored["policies"]["mpc"]["daily_profit"])
    table["mpc"] = {"daily_profit": mpc_daily.tolist(), "metrics": summarize_profit(mpc_daily),
                    "source": "baselines/results/optimal (same params and days)"}
    add_headroom({"mpc": table["mpc"]}, {k: {"daily_profit": np.asarray(v["daily_profit"])} for k, v in table.items()
                                          if isinstance(v, dict) and "daily_profit" in v})
    algo = results["algo"]
    results["vs_mpc"] = common.paired_difference(table[algo]["daily_profit"], mpc_daily)  # (seeds, days) - (days,)
    outputs.write_json(results, run_dir / "results.json")
    curve = results["curve"]
    title = f"{algo.upper()} {config['SCENARIO']} / {config['TRAFFIC']}: {results['seeds']} seeds"
    plot_curve(run_dir / "curve.png", algo, curve["timesteps"], curve["episode_profit_eur"], table,
               results["eval_curve"], title)
    return results


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--algo", choices=ALGOS, default="ippo")
    p.add_argument("--scenario", default="shopping")
    p.add_argument("--traffic", default=None, help="low / medium / high or cars per day (default: the scenario's)")
    p.add_argument("--prices", default=None, help="price data, e.g. NL-2022")
    p.add_argument("--timesteps", type=float, default=1e6, help="env steps per seed")
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--num-envs", type=int, default=None)
    p.add_argument("--num-steps", type=int, default=None)
    p.add_argument("--hidden", type=int, default=None)
    p.add_argument("--lr", type=float, default=None)
    p.add_argument("--ent-coef", type=float, default=None)
    p.add_argument("--gamma", type=float, default=None, help="discount per step (Table 3: 0.99)")
    p.add_argument("--gae-lambda", type=float, default=None, help="GAE lambda (Table 3: 0.95)")
    p.add_argument("--minibatches", type=int, default=None)
    p.add_argument("--epochs", type=int, default=None)
    p.add_argument("--always-max-prior", type=float, default=None,
                   help="logit offset >= 0 on each port's full-power action (the always-max rule); 0: none")
    p.add_argument("--battery-idle-prior", type=float, default=None,
                   help="logit offset >= 0 on each battery's idle action (the always-max rule); 0: none")
    p.add_argument("--local-reward-weight", type=float, default=None,
                   help="ippo/mappo: weight in [0, 1] of each agent's own share of the reward in its reward "
                        "(ChargaxMARL local_reward_weight); 0: the shared station reward")
    p.add_argument("--battery-shaping", choices=("on", "off", "day_mean", "storage_value", "dp"), default=None,
                   help="value the batteries' energy as it moves instead of at the day's last step: 'on' = "
                        "'day_mean' at the env's terminal price (same daily profit), 'storage_value' at the value "
                        "of a stored kWh from the day's battery-only LP, 'dp' at the value of the stored energy level from the "
                        "day's battery-only dynamic programme (both baselines/storage_value.py); see "
                        "baselines.shaping.battery_shaping. Default: on (off with --paper)")
    p.add_argument("--port-shaping", choices=("off", "plan"), default=None,
                   help="'plan': each port also sees the change of its parked car's best-plan value under the "
                        "day's prices (baselines/car_value.py, a potential per car; charge-sensitive cars have "
                        "none); default off")
    p.add_argument("--plan-obs", choices=("on", "off"), default=None,
                   help="ippo/mappo: each agent also observes its port's plan advice (1 = the car's best plan "
                        "under the day's prices charges now; baselines/car_value.plan_advice); default off")
    p.add_argument("--agent-adv-norm", choices=("on", "off"), default=None,
                   help="ippo/mappo: normalise the advantages per agent (over its rows of the rollout) instead of "
                        "only over the minibatch (default off)")
    p.add_argument("--relative-prices", choices=("on", "off"), default=None,
                   help="also feed the networks each observed price's place in the day's range, "
                        "(p - median) / (q80 - q20) (see common.relative_prices); default off")
    p.add_argument("--battery-gamma", type=float, default=None,
                   help="ippo/mappo: the battery agents' discount per step (default: --gamma)")
    p.add_argument("--split-credit", choices=("on", "off"), default=None,
                   help="ppo: the port heads learn from the ports' share of the reward, the battery heads from "
                        "the batteries' share (and the battery shaping), each with its own value (default off)")
    p.add_argument("--battery-ent-coef", type=float, default=None,
                   help="ippo/mappo: the battery agents' entropy coefficient (default: --ent-coef)")
    p.add_argument("--battery-net", choices=("on", "off"), default=None,
                   help="ippo/mappo: a separate actor (ippo: and critic) for the battery agents (default off)")
    p.add_argument("--paper", action="store_true", help="use Table 3 exactly (12 envs x 300 steps, 2x256, lr 2.5e-4, "
                                                        "entropy 0.01); default: the faster CPU settings FAST")
    p.add_argument("--env-kwargs", default="{}", help="JSON of extra make_params keywords")
    p.add_argument("--eval-days", type=int, default=None, help="held-out days (default 100)")
    p.add_argument("--eval-draws", type=int, default=None,
                   help="car draws per held-out day (default 1): every policy, rule and the bound scored under "
                        "PRNGKey(0 .. N-1), each day's profit the mean over the draws (baselines.common.draw_keys)")
    p.add_argument("--chunks", type=int, default=10, help="training pieces (progress + held-out evaluation)")
    p.add_argument("--out", default="baselines/results/run")
    p.add_argument("--optimal", choices=OPTIMAL_CHOICES, default="bound",
                   help="add the LP hindsight bound (bound, default), also the MPC (mpc), or neither (off)")
    p.add_argument("--replot", nargs="+", default=None, metavar="RUN_DIR",
                   help="train nothing: add the stored MPC for each run's params and days to its results.json "
                        "and redraw its curve.png (add_stored_mpc)")
    from baselines import distributed

    distributed.add_arguments(p)
    a = p.parse_args(argv)
    if a.replot:
        for run_dir in a.replot:
            r = add_stored_mpc(run_dir)
            mpc = r["evaluation"]["table"]["mpc"]["metrics"]["daily_profit_eur"]["mean"]
            print(f"{run_dir}: MPC {mpc:.2f} EUR/day added; {r['algo']} vs MPC {r['vs_mpc']['mean']:+.2f} ± "
                  f"{r['vs_mpc']['stderr']:.2f}")
        return {}
    # `python -m baselines.train` has initialised before its imports; a caller of main() must have
    # called distributed.initialize() before importing baselines.train (see baselines/distributed.py)
    distributed.initialize_from_argv(argv)
    config = {} if a.paper else dict(FAST)
    config.update({"SCENARIO": a.scenario, "TRAFFIC": a.traffic, "TOTAL_TIMESTEPS": int(a.timesteps),
                   "ENV_KWARGS": json.loads(a.env_kwargs)})
    if a.prices:
        config["ENV_KWARGS"]["prices"] = a.prices
    for flag, key in (("num_envs", "NUM_ENVS"), ("num_steps", "NUM_STEPS"), ("hidden", "HIDDEN"), ("lr", "LR"),
                      ("ent_coef", "ENT_COEF"), ("gamma", "GAMMA"),
                      ("gae_lambda", "GAE_LAMBDA"), ("minibatches", "NUM_MINIBATCHES"), ("epochs", "UPDATE_EPOCHS"),
                      ("always_max_prior", "ALWAYS_MAX_PRIOR"),
                      ("battery_idle_prior", "BATTERY_IDLE_PRIOR"),
                      ("local_reward_weight", "LOCAL_REWARD_WEIGHT"), ("eval_days", "NUM_EVAL_DAYS"),
                      ("eval_draws", "EVAL_DRAWS")):
        if getattr(a, flag) is not None:
            config[key] = getattr(a, flag)
    if a.battery_gamma is not None:
        config["BATTERY_GAMMA"] = a.battery_gamma
    if a.split_credit is not None:
        config["SPLIT_CREDIT"] = a.split_credit == "on"
    if a.battery_ent_coef is not None:
        config["BATTERY_ENT_COEF"] = a.battery_ent_coef
    for flag, key in (("relative_prices", "RELATIVE_PRICES"), ("battery_net", "BATTERY_NET"),
                      ("agent_adv_norm", "AGENT_ADV_NORM"), ("plan_obs", "PLAN_OBS")):
        if getattr(a, flag) is not None:
            config[key] = getattr(a, flag) == "on"
    if a.port_shaping is not None:
        config["PORT_SHAPING"] = a.port_shaping
    if a.battery_shaping is not None:
        config["BATTERY_SHAPING"] = {"on": True, "off": False}.get(a.battery_shaping, a.battery_shaping)
    if config["TRAFFIC"] is None:
        from chargax_marl.single.scenarios import SCENARIOS

        config["TRAFFIC"] = SCENARIOS[a.scenario]["traffic"]
    if jax.process_index() == 0:
        print(f"processes: {jax.process_count()}  devices: {jax.devices()}  "
              f"config: {json.dumps({k: v for k, v in config.items()}, default=str)}")
    res = run(a.algo, config, seeds=a.seeds, seed=a.seed, out=a.out, chunks=a.chunks, optimal=a.optimal)
    return {k: v for k, v in res.items() if not k.startswith("_")}


if __name__ == "__main__":
    main()
