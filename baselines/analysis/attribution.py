"""Which agents carry a trained policy's gap to the battery rule: swap the ports' and the
batteries' decisions between the trained policy and the rules.

    python -m baselines.analysis.attribution outputs/train_ippo          # a run directory of baselines.train

On the run's held-out days and cars (the evaluation key 0), every seed of the run is scored as

* ``learned``: the trained policy (greedy), as ``baselines.train`` scores it;
* ``learned_ports_rule_battery``: the trained ports, the battery from the battery price rule;
* ``always_max_ports_learned_battery``: ports at full power, the trained battery;

each as the paired difference to always-max (mean ± standard error over days, then over
seeds). Where the second row is near the battery rule and the third near the first, the
ports have learned always-max and the battery is what falls short; the reverse points at
the ports. ``--out`` writes the JSON.
"""

from __future__ import annotations

import argparse
import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from baselines import runs
from baselines.config import build_env_params
from baselines.eval import stats
from baselines.eval.rules import evaluate_rules
from baselines.eval.stats import over_seeds
from chargax_marl import policies
from chargax_marl.core import checks
from chargax_marl.evaluation import run_policies_days, stateless

MIXES = ("learned", "learned_ports_rule_battery", "always_max_ports_learned_battery")


def mixed_policies(act, params) -> dict:
    """The `MIXES` as ``policy(state, key) -> levels`` from a trained ``act``.

    Args:
        act: the trained policy, ``act(state, key) -> levels``.
        params: the env parameters (the battery rule's prices, which leaves are batteries).

    Returns:
        ``{mix: policy(state, key) -> levels}`` for every name of `MIXES`.

    Raises:
        ValueError: ``act`` carries a memory (`chargax_marl.evaluation.stateless`).
    """
    act = stateless(act, "the attribution's policy mixes")
    is_battery = policies._is_battery(params)
    return {
        "learned": act,
        "learned_ports_rule_battery": lambda s, k: jnp.where(
            is_battery, policies.battery_rule(s, k, params), act(s, k)
        ),
        "always_max_ports_learned_battery": lambda s, k: jnp.where(
            is_battery, act(s, k), policies.always_max(s, k, params)
        ),
    }


def _ignore_params(act, state, key, params):
    """``act(state, key)`` as a rule's ``policy(state, key, params)``."""
    return act(state, key)


def attribute(run_dir: str | Path) -> dict:
    """Score every seed of a run under each mix; see the module docstring.

    Args:
        run_dir: an output directory of ``baselines.train`` (``results.json``,
            ``params.msgpack``).

    Returns:
        ``{"run", "algo", "num_days", "seeds", "battery_rule_vs_always_max", "mixes"}``:
        the battery rule's paired difference to always-max
        (`baselines.eval.stats.paired_difference`), and per mix ``{"per_seed": [{"mean",
        "stderr"}], "over_seeds"}`` (`baselines.eval.stats.over_seeds` of the seeds' means),
        differences to always-max in EUR/day.
    """

    results, train, all_params = runs.load_run(run_dir)
    _, eval_params, _, days = build_env_params(train.config)
    days = np.asarray(days)
    key = jax.random.PRNGKey(
        0
    )  # the evaluation key of baselines.train: the same cars for every policy
    rules = evaluate_rules(eval_params, days, ("always_max", "battery_rule"), key=key)
    am = rules["always_max"]["daily_profit"]
    make_act = train.make_act(eval_params)

    @jax.jit
    def score(seed_params, d, k):
        """Every mix in one program (the simulator compiled once), the seed's parameters an
        argument (not a constant): compiled once, run per seed."""
        mixes = mixed_policies(make_act(seed_params), eval_params)
        as_rules = [functools.partial(_ignore_params, mixes[name]) for name in MIXES]
        return run_policies_days(as_rules, eval_params, d, k)

    per_seed = {m: [] for m in MIXES}
    for i in range(int(results["seeds"])):
        seed_params = jax.tree.map(lambda x: x[i], all_params)
        profit = np.asarray(score(seed_params, days, key).profit_eur, np.float64)
        for j, name in enumerate(MIXES):
            per_seed[name].append(stats.paired_difference(profit[j], am))
    out = {
        "run": str(run_dir),
        "algo": results["algo"],
        "num_days": int(days.size),
        "seeds": int(results["seeds"]),
        "battery_rule_vs_always_max": stats.paired_difference(
            rules["battery_rule"]["daily_profit"], am
        ),
        "mixes": {},
    }
    for name, diffs in per_seed.items():
        out["mixes"][name] = {
            "per_seed": [{"mean": d["mean"], "stderr": d["stderr"]} for d in diffs],
            "over_seeds": over_seeds([d["mean"] for d in diffs]),
        }
    return out


def format_attribution(out: dict) -> str:
    """The plain-text report of an `attribute` result.

    Args:
        out: an `attribute` result.

    Returns:
        A header line, the battery rule's paired difference to always-max (over days), and
        one line per mix: its mean ± standard error over seeds and every seed's mean, in
        EUR/day.
    """
    rule = out["battery_rule_vs_always_max"]
    lines = [
        f"{out['algo']} run {out['run']}: paired difference to always-max, EUR/day, {out['num_days']} held-out "
        f"days, {out['seeds']} seeds (mean ± s.e. over seeds; per seed)",
        f"  {'battery rule':34s} {rule['mean']:+7.2f} ± {rule['stderr']:.2f} (over days)",
    ]
    for name, m in out["mixes"].items():
        o = m["over_seeds"]
        seeds = " ".join(f"{s['mean']:+.2f}" for s in m["per_seed"])
        lines.append(f"  {name:34s} {o['mean']:+7.2f} ± {o['stderr']:.2f}   [{seeds}]")
    return "\n".join(lines)


def main(argv=None) -> dict:
    """The command line: `attribute` a run directory, print the report and, with ``--out``,
    write the result as JSON (`baselines.runs.write_json`).

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        The `attribute` result.
    """
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "run_dir",
        help="an output directory of python -m baselines.train (results.json, params.msgpack)",
    )
    p.add_argument(
        "--out", default=None, type=checks.output_option("file"), help="write the JSON here"
    )
    a = p.parse_args(argv)
    out = attribute(a.run_dir)
    print(format_attribution(out))
    if a.out:
        runs.write_json(out, a.out)
    return out


if __name__ == "__main__":
    main()
