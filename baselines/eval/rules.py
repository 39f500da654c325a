"""Rule-based policies on the held-out days: daily profit and paired differences.

The rules are `chargax_marl.policies` (always-max, the battery rule, price-threshold,
EDF, LLF) and the teachers' rules of `chargax_marl.teachers.rules`; every rule is played
with the evaluation's keys, so every policy meets the same cars.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from baselines.eval import protocol, stats
from chargax_marl.evaluation import run_policies_days, summarize
from chargax_marl.policies import get_policy

POLICIES = ("always_max", "battery_rule", "price_threshold", "edf", "llf")


PROGRAMME = "battery_programme"
"""Always-max ports with the batteries on the battery-only programme: at each step the
best of discharge / idle / charge at full power for the stored energy, by backward induction
over the day's known buy prices (`chargax_marl.teachers.storage_value.dp_battery_action`). It is
the battery shaping's teacher (``BATTERY_SHAPING="dp"``) played as a rule, no learning, and
so the reference a learner trained with that shaping has to beat to show it learned more
than its teacher."""


PLAN_PROGRAMME = "plan_programme"
"""The ports on their cars' plans (`chargax_marl.teachers.car_plan.plan_action` at
`chargax_marl.teachers.car_plan.PLAN_POWER_FRACTION`: full power in the steps of each car's
cheapest plan, idle otherwise) with the batteries on the battery-only programme: both
teachers of the multi-agent settings (``PORT_SHAPING="plan"``, ``PLAN_OBS``,
``BATTERY_SHAPING="dp"``) played as a rule."""


TEACHER_RULES = (PROGRAMME, PLAN_PROGRAMME)
"""Rules built from the trainers' shaping teachers, per station and price table
(`chargax_marl.teachers.rules`, built by `chargax_marl.policies.get_policy` with
params); each needs a battery."""


GRID_PROGRAMME = "grid_programme"
"""``battery_programme`` that knows the node limits: always-max ports, the batteries on the
battery-only programme, except that they do not charge while the ports' full-power draw
alone (grid side) exceeds the limit of a node above a battery. There the programme's charge
would be rescaled with the ports', taking the scarce connection from the cars
(the docs' design decisions say what this one change is worth on ``shopping-grid25-high``).
Not a teacher of any trainer; ``baselines.analysis.redraw`` scores it beside the teachers' rules."""


BATTERY_RULES = TEACHER_RULES + (GRID_PROGRAMME,)
"""Every rule of this module that needs a battery."""


def rule_policy(name: str, params):
    """The ``policy(state, key, params)`` of a rule name: a `chargax_marl.policies` rule, or
    one of `BATTERY_RULES` (built for ``params``; a ``ValueError`` on a station without
    a battery).

    Args:
        name: a rule name of `chargax_marl.policies.get_policy`.
        params: the env parameters a battery rule is built for.

    Returns:
        ``policy(state, key, params) -> levels``.
    """
    return get_policy(name, params)


def check_replay(replayed: dict, stored: dict, names, where: str) -> None:
    """Refuse (``ValueError``) a stored result whose ``names`` (rule entries with
    ``daily_profit``) differ from ``replayed`` on this code by more than float32 noise: it was
    made on another model, and new entries computed beside it would not compare.

    Args:
        replayed: ``{name: entry}`` played on this code, each with ``daily_profit`` (EUR/day).
        stored: ``{name: entry}`` read from the stored result, each with ``daily_profit``.
        names: the entries to compare.
        where: the stored result's name, for the error message.

    Raises:
        ValueError: a ``daily_profit`` of ``names`` differs by more than ``rtol=1e-5`` and
            ``atol=1e-3`` EUR/day on some day.
    """
    for name in names:
        ref = np.asarray(stored[name]["daily_profit"], np.float64)
        if not np.allclose(replayed[name]["daily_profit"], ref, rtol=1e-5, atol=1e-3):
            worst = float(np.max(np.abs(replayed[name]["daily_profit"] - ref)))
            raise ValueError(
                f"{where}: {name} replayed on this code differs from the stored run by up to "
                f"{worst:.3f} EUR/day: the run was made on another model; re-run it instead"
            )


def evaluate_rules(params, days, policies=POLICIES, key=None, draws: int = 1) -> dict:
    """``{policy: {"num_days", "days", "metrics", "daily_profit"}}`` of each rule-based policy on
    ``days``, all with the same key (default ``PRNGKey(0)``, the trainers' evaluation key), so
    every policy meets the same cars and daily profits compare pairwise. ``policies`` may name
    `TEACHER_RULES`. With ``draws`` > 1 (and no ``key``), every day is played under the
    keys of `baselines.eval.protocol.draw_keys` and its totals are the means over the draws.
    The rules, and the draws, are played in one compiled program
    (`chargax_marl.evaluation.run_policies_days`).

    Args:
        params: the env parameters.
        days: the day indices to play.
        policies: rule names (`rule_policy`).
        key: one evaluation key for every day; ``None`` plays the keys of ``draw_keys``.
        draws: car draws per day (a positive integer); only with ``key=None``.

    Returns:
        ``{name: {"num_days", "days", "metrics", "daily_profit"}}`` per rule (``metrics`` of
        `chargax_marl.evaluation.summarize`, ``daily_profit`` a float64 ``(days,)`` array in
        EUR/day); ``{}`` for no ``policies``.

    Raises:
        ValueError: both a ``key`` and ``draws`` other than 1, or ``draws`` not a positive
            integer (`baselines.eval.protocol.draw_keys`).
    """
    if key is not None and draws != 1:
        raise ValueError(
            f"evaluate_rules: give either a key or draws > 1, not both (draws={draws!r})"
        )
    keys = [key] if key is not None else protocol.draw_keys(draws)
    names = tuple(policies)
    if not names:
        return {}
    rules = [rule_policy(name, params) for name in names]

    def play(k):  # every rule in one program (the simulator compiled once), on the same cars
        return run_policies_days(rules, params, days, k)

    if len(keys) == 1:
        every = protocol.mean_over_draws(play, keys)
    else:  # and every draw in one program (compiled once, not once per draw)
        every = protocol.mean_of_draws(jax.device_get(jax.jit(jax.vmap(play))(jnp.stack(keys))))
    out = {}
    for i, name in enumerate(names):
        totals = jax.tree.map(lambda x, i=i: x[i], every)
        out[name] = {
            "num_days": int(np.size(days)),
            "days": [int(d) for d in np.asarray(days)],
            "metrics": summarize(totals),
            "daily_profit": np.asarray(totals.profit_eur, np.float64),
        }
    return out


def add_paired_differences(results: dict, references=("always_max", "battery_rule")) -> dict:
    """Add ``vs_<reference>`` (paired mean ± standard error over days) to every entry.

    Args:
        results: ``{name: entry}`` with ``daily_profit`` (`evaluate_rules`); changed in place.
        references: the names of the entries to compare against; those absent from
            ``results`` are skipped.

    Returns:
        ``results``, every entry with a `baselines.eval.stats.paired_difference` per present
        reference (an entry that is a reference gets one to itself).
    """
    for r in results.values():
        for ref in references:
            if ref in results:
                r[f"vs_{ref}"] = stats.paired_difference(
                    r["daily_profit"], results[ref]["daily_profit"]
                )
    return results


def format_rules(results: dict) -> str:
    """A plain-text table of rule results: one line per policy.

    Args:
        results: ``{name: entry}`` of `evaluate_rules`, each with ``metrics``, optionally with
            ``vs_always_max`` and ``vs_battery_rule`` (`add_paired_differences`).

    Returns:
        The header and one line per policy: mean daily profit (EUR/day), the paired
        differences to always-max and to the battery rule (mean ± standard error, ``-`` when
        absent), mean energy delivered and missing at departure (kWh) and the battery's
        terminal value (EUR).
    """
    lines = [
        f"{'policy':<18}{'EUR/day':>10}{'vs always-max':>20}{'vs battery rule':>20}"
        f"{'delivered kWh':>15}{'missing kWh':>13}{'battery V EUR':>15}"
    ]
    for name, r in results.items():
        m = r["metrics"]

        def diff(ref):
            d = r.get(f"vs_{ref}")
            return f"{d['mean']:+.2f} ± {d['stderr']:.2f}" if d else "-"

        lines.append(
            f"{name:<18}{m['daily_profit_eur']['mean']:>10.1f}{diff('always_max'):>20}{diff('battery_rule'):>20}"
            f"{m['energy_delivered_kwh']['mean']:>15.0f}{m['missing_kwh_at_departure']['mean']:>13.1f}"
            f"{m['battery_terminal_value_eur']['mean']:>15.2f}"
        )
    return "\n".join(lines)
