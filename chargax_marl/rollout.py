"""Roll out a rule-based policy for whole days and print the day's results.

``python -m chargax_marl.rollout`` runs the always-max baseline for one day of the default
scenario (shopping, medium traffic, NL-2023 prices) and prints the profit, the energy
delivered and the cars served. ``--days K`` averages over K random days (vmapped).
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

from chargax_marl.core import simulator
from chargax_marl.core.types import EnvParams
from chargax_marl.evaluation import run_days
from chargax_marl.policies import POLICIES
from chargax_marl.single import make


def rollout_days(policy, params: EnvParams, keys: jax.Array):
    """Run ``policy(state, key, params)`` for one random day per key (vmapped).

    Returns ``(totals, days, returns)``: the final `EpisodeTotals` per day, the day
    indices drawn as ``reset`` draws them, and each day's summed reward.

    Args:
        policy: ``policy(state, key, params) -> levels``, e.g. a value of
            `chargax_marl.policies.POLICIES`.
        params: the environment parameters.
        keys: ``(n, 2)`` keys: key ``i`` draws day ``i`` (`chargax_marl.core.simulator.reset`);
            the days' cars are drawn from ``keys[0]`` (`chargax_marl.evaluation.run_days`).

    Returns:
        ``(totals, days, returns)`` as above, each with a leading axis ``(n,)``; ``returns``
        is ``totals.reward``.

    Raises:
        ValueError: the policy returned non-finite or non-integer levels
            (`chargax_marl.evaluation.check_policy_outputs`; not checked inside a caller's
            ``jit``).
    """
    days = jax.jit(jax.vmap(lambda k: simulator.reset(k, params).day))(keys)
    totals = run_days(lambda s, k: policy(s, k, params), params, days, keys[0])
    return totals, days, totals.reward


def main(argv=None) -> None:
    """The command line: roll out a policy and print the days' results (the module doc).

    Args:
        argv: the command-line arguments (``--policy``, ``--scenario``, ``--days``,
            ``--seed``); None: ``sys.argv``.

    Raises:
        SystemExit: ``--days`` below 1 or ``--seed`` outside ``[0, 2**31 - 1]`` (argparse's
            error, before anything runs).
    """
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--policy", default="always_max", choices=sorted(POLICIES))
    parser.add_argument(
        "--scenario", default="shopping", help="named scenario, e.g. shopping, workplace-high"
    )
    parser.add_argument("--days", type=int, default=1, help="number of random days to average over")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.days < 1:
        parser.error(f"--days must be an integer >= 1, got {args.days}")
    if not 0 <= args.seed <= 2**31 - 1:
        parser.error(f"--seed must be an integer in [0, 2**31 - 1], got {args.seed}")

    _, params = make(args.scenario)
    keys = jax.random.split(jax.random.PRNGKey(args.seed), args.days)
    start = time.perf_counter()
    totals, days, returns = rollout_days(POLICIES[args.policy], params, keys)
    jax.block_until_ready(returns)
    elapsed = time.perf_counter() - start

    profit = np.asarray(totals.profit_eur)
    delivered = np.asarray(totals.energy_delivered_kwh)
    served = np.asarray(totals.cars_served)
    rejected = np.asarray(totals.cars_rejected)
    print(
        f"policy={args.policy} scenario={args.scenario} days={args.days} seed={args.seed} "
        f"({elapsed:.1f} s incl. compile)"
    )
    if args.days == 1:
        print(f"day index        : {int(days[0])}")

    def fmt(x, unit):
        return f"{x.mean():10.2f} {unit}" + (f"  (std {x.std():.2f})" if x.size > 1 else "")

    print(f"daily profit     : {fmt(profit, 'EUR')}")
    print(f"energy delivered : {fmt(delivered, 'kWh')}")
    print(f"cars served      : {fmt(served, '')}")
    print(f"cars rejected    : {fmt(rejected, '')}")


if __name__ == "__main__":
    main()
