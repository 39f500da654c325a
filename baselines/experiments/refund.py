"""What the V2G refund is worth: three rules with and without refunding discharged car energy.

The original Chargax implementation never refunds energy discharged from a customer's car,
so taking energy back from a car before it leaves earns money there. This simulator refunds
it by default (``make_params(refund_discharged_energy=True)``); ``False`` reproduces the
original's accounting. ``python -m baselines.experiments.refund`` evaluates always-max, always-max + the
battery price rule and "discharge departing cars" (`chargax_marl.policies.discharge_departing`)
under both, on a scenario's 100 held-out days (``split_days(365, 100, seed=0)``) with the
evaluation key 0, so every run meets the same cars; it prints each one's mean daily profit,
its paired difference to always-max and the paired difference refund off - refund on (mean ±
standard error over days). ``--all-v2g`` lets every car model of the fleet discharge at its
charging limit (in the bundled EU fleet only the VW ID.4 and the Nissan Leaf, 11 % of the cars,
may discharge, at DC ports, 10 and 7 kW). Each run takes seconds.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from baselines.eval.rules import evaluate_rules
from baselines.eval.stats import mean_stderr, paired_difference
from chargax_marl.core import datasets
from chargax_marl.core.params import make_params
from chargax_marl.core.scenarios import scenario_kwargs
from chargax_marl.evaluation import split_days

RULES = ("always_max", "battery_rule", "discharge_departing")


def all_v2g(fleet="EU") -> datasets.FleetData:
    """``fleet`` with every model allowed to discharge at its charging limit (AC and DC).

    Args:
        fleet: the name of a bundled fleet (`chargax_marl.core.datasets.load_fleet`).

    Returns:
        The fleet with ``max_ac_discharge_kw`` and ``max_dc_discharge_kw`` set to its
        ``max_ac_kw`` and ``max_dc_kw``.
    """
    f = datasets.load_fleet(fleet)
    return dataclasses.replace(f, max_ac_discharge_kw=f.max_ac_kw, max_dc_discharge_kw=f.max_dc_kw)


def daily_profits(
    scenario: str = "shopping", rules=RULES, num_eval: int = 100, key=None, **overrides
) -> dict:
    """``{(rule, refund): daily profit (days,)}`` on the held-out days, refund in (True, False);
    ``overrides`` go to ``make_params`` on top of the scenario.

    Args:
        scenario: a named scenario (`chargax_marl.core.scenarios.scenario_kwargs`).
        rules: rule names (`baselines.eval.rules.evaluate_rules`).
        num_eval: the number of held-out days (``split_days(num_days, num_eval, seed=0)``).
        key: the evaluation key; ``None``: ``PRNGKey(0)``.
        **overrides: ``make_params`` keyword arguments on top of the scenario's.

    Returns:
        ``{(rule, refund): daily profits}``, float64 ``(days,)`` arrays in EUR/day.
    """
    kwargs = scenario_kwargs(scenario, **overrides)
    base = make_params(**kwargs)
    _, days = split_days(int(base.num_days), num_eval, seed=0)
    out = {}
    for refund, prm in (
        (True, base),
        (False, make_params(**kwargs, refund_discharged_energy=False)),
    ):
        for name, r in evaluate_rules(prm, days, rules, key=key).items():
            out[(name, refund)] = r["daily_profit"]
    return out


def format_table(profits: dict, rules=RULES) -> str:
    """The plain-text table of `daily_profits`: one line per rule.

    Args:
        profits: `daily_profits`' result; it must hold always-max under both accountings.
        rules: the rules to list.

    Returns:
        A header line, and per rule its mean daily profit ± standard error and paired
        difference to always-max with the refund and without, and the paired difference
        without - with (EUR/day).
    """

    def mean_se(x):
        return "{:.2f} ± {:.2f}".format(*mean_stderr(x))

    def diff(a, b):
        d = paired_difference(a, b)
        return f"{d['mean']:+.2f} ± {d['stderr']:.2f}"

    lines = [
        f"{'rule':<22}{'refund on EUR/day':>20}{'vs always-max':>16}{'refund off EUR/day':>20}"
        f"{'vs always-max':>16}{'off - on':>16}"
    ]
    for name in rules:
        on, off = profits[(name, True)], profits[(name, False)]
        lines.append(
            f"{name:<22}{mean_se(on):>20}{diff(on, profits[('always_max', True)]):>16}{mean_se(off):>20}"
            f"{diff(off, profits[('always_max', False)]):>16}{diff(off, on):>16}"
        )
    return "\n".join(lines)


def main(argv=None) -> dict:
    """The command line: `daily_profits` of `RULES` on ``--scenario`` (with ``--all-v2g``, on
    the `all_v2g` EU fleet), the table printed.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        `daily_profits`' ``{(rule, refund): daily profits}``.
    """
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--scenario", default="shopping")
    p.add_argument(
        "--all-v2g", action="store_true", help="every car model of the fleet may discharge"
    )
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    profits = daily_profits(args.scenario, **({"fleet": all_v2g()} if args.all_v2g else {}))
    n = profits[(RULES[0], True)].size
    fleet = "EU fleet, every model may discharge" if args.all_v2g else "EU fleet"
    print(
        f"{args.scenario} ({fleet}): {n} held-out days (split_days(seed=0)), key 0, same cars for all; "
        f"daily profit mean ± standard error, paired differences ({time.perf_counter() - t0:.0f} s)"
    )
    print(format_table(profits))
    return profits


if __name__ == "__main__":
    main()
