"""Evaluate a policy over whole days, vmapped, and report mean +- std of the day's results.

A policy here is ``act(state, key) -> levels`` (the core's per-leaf levels). Rule-based
policies become one with ``lambda s, k: policy(s, k, params)``; a trained network becomes one
by reading the observation from the state (see ``baselines/``).
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from chargax_marl.core import checks, clock, physics, simulator
from chargax_marl.core.types import EnvParams, EnvState, EpisodeTotals
from chargax_marl.optimal import bound_days, pooled_bound_days
from chargax_marl.policies import get_policy, is_named_rule
from chargax_marl.trace import day_keys, is_paper_session_model

Act = Callable[[EnvState, jax.Array], jnp.ndarray]


@dataclass(frozen=True)
class MemoryAct:
    """A policy that carries a memory from step to step within a day, for the days that
    `run_days` plays: a controller that sees the station late, or whose commands can be
    lost (`chargax_marl.marl.communication.communicating_act`), remembers what it saw
    and what the ports applied.

    Attributes:
        init: ``init(state) -> memory`` at the day's first state.
        step: ``step(state, key, memory) -> (levels, memory)``; ``levels`` as an `Act`
            returns them.
    """

    init: Callable[[EnvState], Any]
    step: Callable[[EnvState, jax.Array, Any], tuple[jnp.ndarray, Any]]


def stateless(act: Act | MemoryAct, what: str) -> Act:
    """``act`` itself when it needs no memory.

    Args:
        act: a policy.
        what: the caller's name, for the error message.

    Returns:
        ``act``, an `Act`.

    Raises:
        ValueError: ``act`` is a `MemoryAct`, which ``what`` cannot play.
    """
    if isinstance(act, MemoryAct):
        raise ValueError(
            f"{what} plays a policy step by step without memory, and this one carries a memory "
            "(a policy trained with an observation delay or action loss: OBS_DELAY_STEPS, "
            "ACTION_LOSS_PROB); score it with run_days"
        )
    return act


def with_memory(act: Act | MemoryAct) -> MemoryAct:
    """A policy as a `MemoryAct`.

    Args:
        act: an `Act` or a `MemoryAct`.

    Returns:
        ``act`` itself if it is a `MemoryAct`; an `Act` wrapped with an empty memory.
    """
    if isinstance(act, MemoryAct):
        return act
    return MemoryAct(init=lambda state: (), step=lambda state, key, memory: (act(state, key), ()))


METRICS = {
    "daily_profit_eur": "profit_eur",
    "daily_reward": "reward",
    "energy_delivered_kwh": "energy_delivered_kwh",
    "missing_kwh_at_departure": "missing_kwh",
    "overtime_min": "overtime_min",
    "cars_rejected": "cars_rejected",
    "cars_served": "cars_served",
    "constraint_excess_kw": "constraint_excess_kw",
    "requested_excess_kw": "requested_excess_kw",
    "battery_terminal_value_eur": "battery_terminal_value_eur",
    "peak_grid_kw": "peak_grid_kw",
    "peak_demand_charge_eur": "peak_demand_charge_eur",
    "battery_wear_eur": "battery_wear_eur",
}
"""Reported metric -> field of `chargax_marl.core.types.EpisodeTotals`."""

SERVICE_METRICS = (
    "mean_satisfaction",
    "min_satisfaction",
    "jain_index",
    "rejected_share",
    "satisfaction_gap",
)
"""How fairly a day serves its drivers (`service_metrics`), reported beside
`METRICS`."""


def service_metrics(totals) -> dict[str, np.ndarray]:
    """The day's service and fairness metrics from its episode totals.

    A departing car's satisfaction ``s`` is the energy delivered over the energy it requested,
    1 when it reached its target (`chargax_marl.core.traffic.satisfaction`); over the
    ``n`` cars that left during the day:

    - ``mean_satisfaction``: ``sum(s) / n``;
    - ``min_satisfaction``: ``min(s)``;
    - ``jain_index``: Jain's fairness index ``sum(s)^2 / (n * sum(s^2))``, in ``[1/n, 1]``,
      1 when every car is served alike;
    - ``rejected_share``: cars turned away for want of a free port over the cars that came;
    - ``satisfaction_gap``: the mean satisfaction of the time-sensitive drivers (who leave at
      their planned time) minus that of the charge-sensitive ones (who stay until charged).

    A day on which no car left has mean, minimum and Jain 1 (no car was served less than
    another) and a NaN gap, as has a day on which one user type had no departure; a day
    with no car at all has a rejected share of 0. Cars still parked at the day's end are not
    counted.

    Args:
        totals: `chargax_marl.core.types.EpisodeTotals` with any leading axes.

    Returns:
        ``{name: float64 array}`` for each of `SERVICE_METRICS`, shaped as the totals.
    """

    def f(name):
        return np.asarray(getattr(totals, name), np.float64)

    n, total, squares = f("cars_served"), f("satisfaction_sum"), f("satisfaction_sq_sum")
    n0, total0 = f("cars_served_time_sensitive"), f("satisfaction_sum_time_sensitive")
    n1, total1 = n - n0, total - total0
    offered = f("cars_arrived") + f("cars_rejected")
    with np.errstate(divide="ignore", invalid="ignore"):
        return {
            "mean_satisfaction": np.where(n > 0, total / n, 1.0),
            "min_satisfaction": 1.0 - f("satisfaction_shortfall_max"),
            "jain_index": np.where(squares > 0, total**2 / (n * squares), 1.0),
            "rejected_share": np.where(offered > 0, f("cars_rejected") / offered, 0.0),
            "satisfaction_gap": np.where(
                (n0 > 0) & (n1 > 0), total0 / n0 - total1 / np.where(n1 > 0, n1, 1.0), np.nan
            ),
        }


def split_days(num_days: int, num_eval: int = 100, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Split day indices into training days and held-out evaluation days, reproducibly.

    Args:
        num_days: the days of the price data; indices ``0 .. num_days - 1`` are split. With
            episodes that start after midnight pass ``clock.num_episode_starts(params)`` (all days
            but the last, `chargax_marl.core.clock`).
        num_eval: how many days to hold out, in ``[1, num_days - 1]``.
        seed: the seed of the random permutation.

    Returns:
        ``(train_days, eval_days)``: sorted int32 arrays of ``num_days - num_eval`` and
        ``num_eval`` day indices.

    Raises:
        ValueError: ``num_days`` not an integer >= 2, ``num_eval`` not an integer in
            ``[1, num_days - 1]``, or ``seed`` not an integer >= 0.
    """
    num_days = int(checks.number("num_days", num_days, low=2, integer=True))
    checks.number("seed", seed, low=0, integer=True)
    if isinstance(num_eval, bool) or not isinstance(num_eval, (int, np.integer)):
        raise ValueError(
            f"field 'num_eval' must be an integer in [1, {num_days - 1}], got {num_eval!r}"
        )
    if not 0 < num_eval < num_days:
        raise ValueError(f"field 'num_eval' must lie in [1, {num_days - 1}], got {num_eval!r}")
    perm = np.random.default_rng(int(seed)).permutation(num_days)
    return np.sort(perm[num_eval:]).astype(np.int32), np.sort(perm[:num_eval]).astype(np.int32)


def validation_days(train_days, num: int = 20, seed: int = 1) -> np.ndarray:
    """Draw validation days from training days, reproducibly.

    A training run evaluates its policy on these days while it trains (to follow and select
    it), so the held-out days it is scored on play no part in that; they are training days,
    never held-out ones.

    Args:
        train_days: the training day indices to draw from (e.g. ``split_days(...)[0]``).
        num: how many days to draw, in ``[1, len(train_days)]``.
        seed: the seed of the draw (``numpy.random.default_rng(seed)``).

    Returns:
        ``(num,)`` sorted int32 day indices, a subset of ``train_days``.

    Raises:
        ValueError: ``num`` outside ``[1, len(train_days)]``, or ``seed`` not an integer >= 0.
    """
    checks.number("seed", seed, low=0, integer=True)
    train_days = np.unique(np.asarray(train_days, np.int64).reshape(-1))
    if isinstance(num, bool) or int(num) != num or not 1 <= num <= train_days.size:
        raise ValueError(
            f"field 'num_validation_days' must lie in [1, {train_days.size}] (the training "
            f"days), got {num!r}"
        )
    chosen = np.random.default_rng(int(seed)).choice(train_days, size=int(num), replace=False)
    return np.sort(chosen).astype(np.int32)


@struct.dataclass
class PolicyOutputCounts:
    """How often a played policy returned levels the env had to reinterpret, per played day.

    Attributes:
        nonfinite_steps: ``(n,)`` int32, the steps whose levels held NaN or +-inf (the env
            plays such an entry as idle).
        fractional_steps: ``(n,)`` int32, the steps whose finite levels were not integers in a
            discrete action mode (the env truncates a level toward zero: 3.7 plays as 3, -1.5
            as -1); always 0 in the continuous mode, whose fractions are floats.
        outside_steps: ``(n,)`` int32, the steps with an entry outside its leaf's range
            (`level_range`: a level above ``L`` or below the leaf's lowest, a fraction above
            1 or below the leaf's lowest), which the env clips into the range.
    """

    nonfinite_steps: jnp.ndarray
    fractional_steps: jnp.ndarray
    outside_steps: jnp.ndarray


def level_range(params: EnvParams) -> tuple[jnp.ndarray, jnp.ndarray]:
    """The range of each leaf's entry of the core's action, as the env plays it unclipped.

    Args:
        params: the environment parameters (action mode, levels, V2G, station).

    Returns:
        ``(low, high)``, each ``(num_leaves,)`` float32: levels ``[min_level, L]`` in the
        ``absolute`` mode (``min_level`` is ``-L`` where the leaf may discharge, else 0,
        `chargax_marl.core.physics.leaf_min_level`), changes ``[-L, L]`` in the ``delta``
        mode, fractions ``[-1, 1]`` (``[0, 1]`` where the leaf may not discharge) in the
        ``continuous`` mode.
    """
    st = params.station
    n = st.num_leaves
    if params.action_mode == "delta":
        low = jnp.full(n, -params.num_levels, jnp.float32)
        return low, -low
    top = 1 if params.action_mode == "continuous" else params.num_levels
    low = physics.leaf_min_level(st, top, params.v2g).astype(jnp.float32)
    return low, jnp.full(n, top, jnp.float32)


def _output_flags(levels: jnp.ndarray, params: EnvParams) -> jnp.ndarray:
    """``(3,)`` int32 flags of one step's policy output: a non-finite entry; a finite
    non-integer entry in a discrete action mode; a finite entry outside its leaf's range
    (`level_range`)."""
    x = jnp.asarray(levels)
    low, high = level_range(params)
    if not jnp.issubdtype(x.dtype, jnp.floating):  # float32 holds every level exactly
        xf = jnp.reshape(x, low.shape).astype(jnp.float32)
        outside = jnp.any((xf < low) | (xf > high))
        return jnp.stack([jnp.asarray(False), jnp.asarray(False), outside]).astype(jnp.int32)
    finite = jnp.isfinite(x)
    nonfinite = ~jnp.all(finite)
    x = jnp.reshape(jnp.where(finite, x, 0.0), low.shape)  # non-finite: counted above
    outside = jnp.any((x < low.astype(x.dtype)) | (x > high.astype(x.dtype)))
    if params.action_mode == "continuous":
        fractional = jnp.asarray(False)
    else:
        fractional = jnp.any(x != jnp.trunc(x))
    return jnp.stack([nonfinite, fractional, outside]).astype(jnp.int32)


def check_policy_outputs(counts: PolicyOutputCounts, days, what: str = "the policy") -> None:
    """Refuse the results of a play in which the policy returned levels the env reinterprets:
    non-finite, non-integer or outside the action space.

    A NaN level is played as idle, a level of 3.7 as 3 and a level above the top as the top
    level, so the day's profit is that of another policy than the one returned: no result
    of it is given. Nothing is checked when ``counts`` are traced (a play inside a caller's
    ``jit``: check its counts after it).

    Args:
        counts: the play's `PolicyOutputCounts`, one entry per played day (and draw).
        days: ``(n,)`` the day index of each entry.
        what: the policy's name, for the message.

    Raises:
        ValueError: a step with a non-finite level, with a non-integer level in a discrete
            action mode, or with an entry outside the action space; the message gives the
            number of steps and the days.
    """
    if isinstance(counts.nonfinite_steps, jax.core.Tracer):
        return
    days = np.asarray(days).reshape(-1)
    problems = []
    for name, meaning, fix in (
        (
            "nonfinite_steps",
            "non-finite levels (NaN or +-inf, played as idle)",
            "make it return finite levels",
        ),
        (
            "fractional_steps",
            "non-integer levels (truncated toward zero: 3.7 plays as 3)",
            "return integer levels (round them, or cast to int32, in the policy)",
        ),
        (
            "outside_steps",
            "actions outside the action space (a level above the top level or below the "
            "leaf's bottom one, an index outside Discrete(n) or MultiDiscrete, a fraction "
            "outside the Box; clipped into it)",
            "return actions of the action space",
        ),
    ):
        steps = np.asarray(getattr(counts, name)).reshape(-1)
        if steps.sum() > 0:
            bad_days = sorted({int(d) for d in days[steps > 0]})
            shown = bad_days[:10] + (["..."] if len(bad_days) > 10 else [])
            problems.append(
                f"{meaning} on {int(steps.sum())} steps, in {int((steps > 0).sum())} of the "
                f"{steps.size} days played (a day counted once per car draw; day indices "
                f"{shown}): {fix}"
            )
    if problems:
        raise ValueError(
            f"{what} returned " + "; and ".join(problems) + ". No result is given: the env "
            "played other levels than the policy returned."
        )


def play_days(
    act: Act | MemoryAct, params: EnvParams, days, keys: jax.Array
) -> tuple[EpisodeTotals, PolicyOutputCounts]:
    """`run_days_keyed`'s play, traceable, with the counts of reinterpreted policy outputs.

    Args:
        act: ``act(state, key) -> levels``, or a `MemoryAct`.
        params: the environment parameters.
        days: ``(n,)`` day indices of the price data.
        keys: ``(n, 2)`` keys, one per day.

    Returns:
        ``(totals, counts)``: the final `EpisodeTotals` and the `PolicyOutputCounts`, each
        with a leading axis ``(n,)``. Pass ``counts`` to `check_policy_outputs`.
    """
    return _play_days(act, params, jnp.asarray(days, jnp.int32), keys)


def _start_days(days, params: EnvParams) -> jnp.ndarray:
    """``days`` as int32, checked to be days an episode can start on when episodes start after
    midnight (`clock.check_days`: the last day of the data has no next day's prices)."""
    if params.episode_start_hour and not isinstance(days, jax.core.Tracer):
        clock.check_days(
            days, params.num_days, params.episode_start_hour, episode_days=params.episode_days
        )
    return jnp.asarray(days, jnp.int32)


def run_days(act: Act | MemoryAct, params: EnvParams, days, key: jax.Array):
    """Run ``act`` for one whole day per entry of ``days`` (vmapped).

    Args:
        act: ``act(state, key) -> levels``, or a `MemoryAct` (its memory starts afresh
            each day).
        params: the environment parameters.
        days: ``(n,)`` day indices of the price data.
        key: day ``i`` draws its cars from ``split(key, n)[i]`` (`run_days_keyed`).

    Returns:
        The final `chargax_marl.core.types.EpisodeTotals` with a leading axis ``(n,)``.

    Raises:
        ValueError: the policy returned non-finite or non-integer levels
            (`check_policy_outputs`), or, with ``episode_start_hour > 0``, a day of ``days``
            is the data's last (`chargax_marl.core.clock.check_days`).
    """
    days = jnp.asarray(days, jnp.int32)
    return run_days_keyed(act, params, days, jax.random.split(key, days.shape[0]))


def run_days_keyed(act: Act | MemoryAct, params: EnvParams, days, keys: jax.Array):
    """`run_days` with one key per day: the cars of day ``days[i]`` are drawn from
    ``day_keys[i]`` alone, so a day's result does not depend on which other days run beside it.

    Args:
        act: ``act(state, key) -> levels``, or a `MemoryAct` (its memory starts afresh
            each day).
        params: the environment parameters.
        days: ``(n,)`` day indices of the price data.
        keys: ``(n, 2)`` keys, one per day.

    Returns:
        The final `EpisodeTotals` with a leading axis ``(n,)``.

    Raises:
        ValueError: the policy returned non-finite or non-integer levels
            (`check_policy_outputs`; inside a caller's ``jit`` use `play_days` and check its
            counts), or, with ``episode_start_hour > 0``, a day of ``days`` is the data's last
            (`chargax_marl.core.clock.check_days`).
    """
    days = _start_days(days, params)
    # compiled as one program: run eagerly, the vmapped scan is traced, batched and compiled
    # piecewise, which costs more than the whole program (inside a caller's jit it is inlined)
    totals, counts = jax.jit(lambda d, k: _play_days(act, params, d, k))(days, keys)
    check_policy_outputs(counts, days)
    return totals


def run_policy_days(policy: Callable, params: EnvParams, days, key: jax.Array):
    """`run_days` of a rule-based policy, with the params an argument of the program.

    The params are not constants baked into the compiled program, so one program plays the
    policy under any prices, traffic, fees or settings of the same shapes. The program of a
    named rule of `chargax_marl.policies.POLICIES` is kept: it is compiled once per process
    and station shape (and found in JAX's persistent compilation cache, when one is set, by
    every later process). Any other policy (a teacher's rule built for its params, a
    caller's function) is compiled for this call and released with it, so policies built
    anew for every call do not pile up compiled programs.

    Args:
        policy: ``policy(state, key, params) -> levels`` (`chargax_marl.policies.get_policy`).
        params: the environment parameters, also passed to the policy.
        days: ``(n,)`` day indices of the price data.
        key: day ``i`` draws its cars from ``split(key, n)[i]``, as in `run_days`.

    Returns:
        The final `EpisodeTotals` with a leading axis ``(n,)``, as `run_days` returns for
        ``lambda s, k: policy(s, k, params)``.

    Raises:
        ValueError: the policy returned non-finite or non-integer levels
            (`check_policy_outputs`), or, with ``episode_start_hour > 0``, a day of ``days``
            is the data's last (`chargax_marl.core.clock.check_days`).
    """
    days = _start_days(days, params)
    keys = jax.random.split(key, days.shape[0])
    totals, counts = play_policy_days(policy, params, days, keys)
    check_policy_outputs(counts, days)
    return totals


def play_policy_days(
    policy: Callable, params: EnvParams, days, keys: jax.Array
) -> tuple[EpisodeTotals, PolicyOutputCounts]:
    """`play_days` of a rule-based policy, with the params an argument of the program (as in
    `run_policy_days`): the program of a named rule of `chargax_marl.policies.POLICIES` is
    compiled once per station shape and kept, so every task of that shape (other prices,
    traffic, fees) plays it without compiling again.

    Args:
        policy: ``policy(state, key, params) -> levels`` (`chargax_marl.policies.get_policy`).
        params: the environment parameters, also passed to the policy.
        days: ``(n,)`` day indices of the price data.
        keys: ``(n, 2)`` keys, one per day.

    Returns:
        ``(totals, counts)`` as `play_days` returns them for
        ``lambda s, k: policy(s, k, params)`` (to float32 rounding: the params are not
        constants of the program). Pass ``counts`` to `check_policy_outputs`.
    """
    days = jnp.asarray(days, jnp.int32)
    if is_named_rule(policy):
        return _policy_days(policy, params, days, keys)
    return jax.jit(functools.partial(_policy_program, policy))(params, days, keys)


def _policy_program(policy, params, days, keys):
    """The traced body of `run_policy_days`: ``(totals, counts)``."""
    return _play_days(lambda s, k: policy(s, k, params), params, days, keys)


_policy_days = jax.jit(_policy_program, static_argnums=0)
"""`_policy_program` compiled once per named rule and station shape."""


def run_policies_days(policies: Sequence[Callable], params: EnvParams, days, key: jax.Array):
    """`run_policy_days` of several rule-based policies, in one compiled program.

    The policies take turns in the program (``lax.map`` over them, a ``lax.switch`` picking
    the policy at each step), so the simulator is traced and compiled once for all of them
    rather than once per policy; each policy meets the cars of ``key``, as in
    `run_policy_days`. Its totals agree with `run_policy_days` to float32 rounding (the
    compiler fuses the step differently in the two programs). The program of named rules
    of `chargax_marl.policies.POLICIES` is kept, as in `run_policy_days`; one policy alone
    is played by `run_policy_days` itself.

    Args:
        policies: one or more ``policy(state, key, params) -> levels``
            (`chargax_marl.policies.get_policy`), returning integer levels (they are cast to
            int32 unchecked; `run_policy_days` checks a policy's levels).
        params: the environment parameters, also passed to the policies.
        days: ``(n,)`` day indices of the price data.
        key: day ``i`` draws its cars from ``split(key, n)[i]``, as in `run_days`.

    Returns:
        The final `EpisodeTotals` with leading axes ``(len(policies), n)``.

    Raises:
        ValueError: no policy, or, with ``episode_start_hour > 0``, a day of ``days`` is the
            data's last (`chargax_marl.core.clock.check_days`).
    """
    policies = tuple(policies)
    if not policies:
        raise ValueError("field 'policies' must name at least one policy, got none")
    if len(policies) == 1:
        return jax.tree.map(lambda x: x[None], run_policy_days(policies[0], params, days, key))
    days = _start_days(days, params)
    keys = jax.random.split(key, days.shape[0])
    if all(is_named_rule(p) for p in policies):
        return _policies_days(policies, params, days, keys)
    return jax.jit(functools.partial(_policies_program, policies))(params, days, keys)


def _policies_program(policies, params, days, keys):
    """The traced body of `run_policies_days`."""

    def levels(policy, state, key):  # every branch of the switch returns int32 levels
        return jnp.asarray(policy(state, key, params), jnp.int32)

    branches = [functools.partial(levels, policy) for policy in policies]

    def one_policy(index):
        def act(state, key):
            return jax.lax.switch(index, branches, state, key)

        return _play_days(act, params, days, keys)[0]

    return jax.lax.map(one_policy, jnp.arange(len(policies)))


_policies_days = jax.jit(_policies_program, static_argnums=0)
"""`_policies_program` compiled once per tuple of named rules and station shape."""


def _play_days(act: Act | MemoryAct, params: EnvParams, days, keys: jax.Array):
    """The traced body of `run_days_keyed`: ``act`` for one day per entry of ``days``;
    ``(totals, PolicyOutputCounts)``, counted in the program (no host call per step)."""
    clock.require_one_day(params, "chargax_marl.evaluation._play_days")
    policy = with_memory(act)

    def one_day(day, key):
        act_keys, step_keys, battery_key = day_keys(key, params.num_steps)

        def body(carry, keys):
            state, memory, flags = carry
            k_act, k_step = keys
            levels, memory = policy.step(state, k_act, memory)
            flags = flags + _output_flags(levels, params)
            state, _ = simulator.step(k_step, state, levels, params)
            return (state, memory, flags), None

        # the batteries' initial SoC (when drawn from a range) from a key of its own, so the
        # cars drawn from ``key`` stay the same whatever the battery setting
        start = simulator.empty_state(day, params, battery_key)
        carry = (start, policy.init(start), jnp.zeros(3, jnp.int32))
        (state, _, flags), _ = jax.lax.scan(body, carry, (act_keys, step_keys))
        return state.totals, PolicyOutputCounts(flags[0], flags[1], flags[2])

    return jax.vmap(one_day)(days, keys)


def _stats(x: np.ndarray, scored: np.ndarray) -> dict:
    """Mean, std, min and max of ``x[scored]`` (NaN when no day is scored); with days left
    out, also ``days_scored`` and ``days_failed``."""
    kept = x[scored]
    nan = float("nan")
    out = {
        "mean": float(kept.mean()) if kept.size else nan,
        "std": float(kept.std()) if kept.size else nan,
        "min": float(kept.min()) if kept.size else nan,
        "max": float(kept.max()) if kept.size else nan,
    }
    if not scored.all():
        out["days_scored"] = int(scored.sum())
        out["days_failed"] = int(scored.size - scored.sum())
    return out


def summarize(totals, failed=None) -> dict:
    """Mean, std, min and max over days of every metric in `METRICS`.

    Args:
        totals: `EpisodeTotals` with a leading axis over days (`run_days`).
        failed: optional bool ``(days,)``, ``True`` for days whose result does not count (a
            failed solve of a solver-based policy); they are left out of every statistic and
            counted in ``days_failed``.

    Returns:
        ``{metric: {"mean", "std", "min", "max"}}`` for `METRICS` and
        `SERVICE_METRICS` (plus ``days_scored`` and ``days_failed`` when days were left
        out; a NaN satisfaction gap counts as left out).
    """
    out = {}
    for name, field in METRICS.items():
        x = np.asarray(getattr(totals, field), dtype=np.float64)
        scored = np.ones(x.shape, bool) if failed is None else ~np.asarray(failed, bool)
        out[name] = _stats(x, scored)
    for name, x in service_metrics(totals).items():
        scored = np.ones(x.shape, bool) if failed is None else ~np.asarray(failed, bool)
        out[name] = _stats(x, scored & np.isfinite(x))  # the gap is NaN on one-type days
    return out


def summarize_profit(daily_profit) -> dict:
    """Statistics of per-day profits alone (for entries, such as the LP bound, that have no
    other metrics).

    Args:
        daily_profit: per-day profits (EUR). A NaN profit marks a day whose solve failed
            (`hindsight_bound`): it is left out of every statistic and counted in
            ``days_failed`` (with ``days_scored``), never averaged in.

    Returns:
        ``{"daily_profit_eur": {"mean", "std", "min", "max"}}`` (EUR), plus ``days_scored``
        and ``days_failed`` when days were left out.
    """
    x = np.asarray(daily_profit, np.float64)
    return {"daily_profit_eur": _stats(x, np.isfinite(x))}


def evaluate(act: Act, params: EnvParams, days, key: jax.Array | None = None) -> dict:
    """Evaluate ``act`` on the given day indices.

    Args:
        act: ``act(state, key) -> levels``, or a `MemoryAct`.
        params: the environment parameters.
        days: day indices of the price data.
        key: the key the cars are drawn from (`run_days`); None: ``PRNGKey(0)``, also used
            by the trainers' held-out evaluation. Policies evaluated with the same key and
            days meet the same drawn cars, so their day-by-day profits can be compared
            pairwise.

    Returns:
        ``{"num_days", "days", "metrics"}``: the number of days, their indices and the
        statistics of `summarize`.
    """
    key = jax.random.PRNGKey(0) if key is None else key
    return _evaluation(days, run_days(act, params, days, key))


def _evaluation(days, totals) -> dict:
    """`evaluate`'s result from the days' final totals."""
    return {
        "num_days": int(np.size(days)),
        "days": [int(d) for d in np.asarray(days)],
        "metrics": summarize(totals),
    }


def evaluate_policy(policy, params: EnvParams, days, key: jax.Array | None = None) -> dict:
    """`evaluate` for a rule-based policy.

    Args:
        policy: ``policy(state, key, params) -> levels`` or its name
            (`chargax_marl.policies.get_policy`).
        params: the environment parameters, also passed to the policy.
        days: day indices of the price data.
        key: as for `evaluate`.

    Returns:
        The result of `evaluate`.

    Raises:
        KeyError: an unknown policy name.
        ValueError: a teacher's rule for a station without a battery.
    """
    policy = get_policy(policy, params) if isinstance(policy, str) else policy
    key = jax.random.PRNGKey(0) if key is None else key
    return _evaluation(days, run_policy_days(policy, params, days, key))


def hindsight_bound(
    params: EnvParams,
    days,
    key: jax.Array | None = None,
    reference: str = "always_max",
    time_limit_s: float | None = 60.0,
    with_battery: bool = True,
) -> dict:
    """The LP hindsight bound (`chargax_marl.optimal.bound`) of each of ``days`` over
    ``reference``'s port occupancy, with the cars `evaluate` draws with ``key``.

    A day whose LP fails or hits ``time_limit_s`` has a NaN ``daily_profit`` and its solver
    status in ``status``, and is listed in ``failed_days``; the other days are solved as
    usual. `summarize_profit` and `headroom_captured` leave such days out.

    Args:
        params: the environment parameters.
        days: day indices of the price data.
        key: as for `evaluate`; None: ``PRNGKey(0)``.
        reference: the name of the policy whose occupancy is bounded
            (`chargax_marl.policies.get_policy`).
        time_limit_s: HiGHS's time limit per day (seconds); None: none.
        with_battery: False leaves the station's batteries out of the LP (the bound without
            them; the difference is what the batteries are worth at best).

    Returns:
        ``{"daily_profit", "reference_daily_profit", "solve_s", "status", "failed_days",
        "reference"}``: the bound's and the reference's profit per day (EUR), the solve
        time per day (seconds) and the solver status per day, the failed days
        (``{"day", "status"}`` each) and the reference's name.

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        KeyError: an unknown reference name.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.evaluation.hindsight_bound")
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)

    bounds = bound_days(
        params,
        days,
        key,
        get_policy(reference, params),
        time_limit_s=time_limit_s,
        with_battery=with_battery,
    )
    return {
        "daily_profit": np.array([b.profit_eur for b in bounds]),
        "reference_daily_profit": np.array([b.reference_profit_eur for b in bounds]),
        "solve_s": np.array([b.solve_s for b in bounds]),
        "status": [b.status for b in bounds],
        "failed_days": [
            {"day": int(d), "status": b.status}
            for d, b in zip(np.asarray(days).reshape(-1), bounds)
            if not b.solved
        ],
        "reference": reference,
    }


def bound_kind(params: EnvParams) -> str:
    """Which LP bound holds for every policy under the params' session model.

    Args:
        params: the environment parameters.

    Returns:
        ``"occupancy"`` (`hindsight_bound`, over always-max's port occupancy) where every
        policy has that occupancy: on the paper's mechanics (`trace.is_paper_session_model`)
        and under fixed departures (the session model v3, ``params.fixed_departures``);
        otherwise ``"pooled"`` (`chargax_marl.optimal.pooled`: a random free port, users who
        leave when charged), which holds whatever ports the cars get.
    """
    if is_paper_session_model(params) or bool(params.fixed_departures):
        return "occupancy"
    return "pooled"


def policy_bound(
    params: EnvParams, days, key: jax.Array | None = None, time_limit_s: float | None = 60.0
) -> dict:
    """The LP bound no policy beats under the params' session model (`bound_kind`), per day,
    with the cars `evaluate` draws with ``key``: the hindsight bound over always-max's
    occupancy (`hindsight_bound`) where no policy changes the ports and departures (the
    paper's mechanics, the session model v3), else the port-pooled bound
    (`chargax_marl.optimal.pooled`).

    Args:
        params: the environment parameters.
        days: day indices of the price data.
        key: as for `evaluate`; None: ``PRNGKey(0)``.
        time_limit_s: HiGHS's time limit per day (seconds); None: none.

    Returns:
        ``{"daily_profit", "status", "failed_days", "kind"}``: the bound per day (EUR, NaN
        where the solve failed), the solver status per day, the failed days (``{"day",
        "status"}`` each) and the bound's kind, ``"occupancy"`` or ``"pooled"``.

    Raises:
        ValueError: ``time_limit_s`` neither None nor a finite number of seconds > 0.
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.evaluation.policy_bound")
    time_limit_s = checks.time_limit("time_limit_s", time_limit_s)
    if bound_kind(params) == "occupancy":
        out = hindsight_bound(params, days, key, time_limit_s=time_limit_s)
        return {k: out[k] for k in ("daily_profit", "status", "failed_days")} | {
            "kind": "occupancy"
        }
    key = jax.random.PRNGKey(0) if key is None else key
    days = np.asarray(days).reshape(-1)
    bounds = pooled_bound_days(
        params, days, jax.random.split(key, days.size), time_limit_s=time_limit_s
    )
    return {
        "daily_profit": np.array([b.profit_eur for b in bounds]),
        "status": [b.status for b in bounds],
        "failed_days": [
            {"day": int(d), "status": b.status} for d, b in zip(days, bounds) if not b.solved
        ],
        "kind": "pooled",
    }


def headroom_captured(daily_profit, always_max_daily, bound_daily) -> dict:
    """The fraction of the hindsight headroom a policy captures on the same days and cars:
    ``mean(policy - always-max) / mean(bound - always-max)``. 1 means the bound, 0
    always-max; negative is worse than always-max.

    Days where any of the three is NaN (a failed solve of the bound or of a solver-based
    policy) are left out of both means, so that the pairs stay on the same days.

    Args:
        daily_profit: the policy's profit per day (EUR), ``(days,)`` or ``(seeds, days)``.
        always_max_daily: always-max's profit on the same days (EUR), ``(days,)``.
        bound_daily: the hindsight bound on the same days (EUR), ``(days,)``.

    Returns:
        ``{"fraction", "captured_eur", "captured_stderr", "headroom_eur",
        "headroom_stderr"}``: the fraction, both means (EUR/day) and their standard errors
        over days (and seeds); ``fraction`` is NaN when the mean headroom is not positive.
        ``days_excluded`` counts the days left out, present only when some are.
    """
    a = np.asarray(always_max_daily, np.float64)
    p = np.atleast_2d(np.asarray(daily_profit, np.float64))
    b = np.asarray(bound_daily, np.float64)
    keep = np.isfinite(a) & np.isfinite(b) & np.isfinite(p).all(axis=0)
    captured = p[:, keep] - a[None, keep]
    headroom = b[keep] - a[keep]

    def se(x):
        return float(np.std(x, ddof=1) / np.sqrt(x.size)) if x.size > 1 else float("nan")

    mean_headroom = float(headroom.mean()) if headroom.size else float("nan")
    out = {
        "fraction": float(captured.mean() / mean_headroom) if mean_headroom > 0 else float("nan"),
        "captured_eur": float(captured.mean()) if captured.size else float("nan"),
        "captured_stderr": se(captured),
        "headroom_eur": mean_headroom,
        "headroom_stderr": se(headroom),
    }
    if not keep.all():
        out["days_excluded"] = int(keep.size - keep.sum())
    return out


def write_json(results: dict, path: str | Path) -> Path:
    """Write results as indented JSON with sorted keys, creating the folder if needed.

    Args:
        results: JSON-serialisable results (e.g. of `evaluate`).
        path: the file to write.

    Returns:
        The path written, as a `Path`.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(results, indent=2, sort_keys=True) + "\n")
    return path


def format_table(results: dict[str, dict]) -> str:
    """A text table of evaluation results, one column per policy.

    Args:
        results: ``{policy name: evaluate(...) result}``; an entry may also carry
            ``headroom``, a result of `headroom_captured`.

    Returns:
        The table: mean +- std per metric of `METRICS` ("-" where an entry lacks the
        metric), plus the fraction of the hindsight headroom captured where entries carry
        ``headroom``.
    """
    names = list(results)
    metrics = list(METRICS)
    width = max(len(m) for m in metrics) + 2

    def cell(n, m):
        v = results[n]["metrics"].get(m)
        return f"{v['mean']:>14.2f} ± {v['std']:<7.2f}" if v else f"{'-':>14}   {'':<7}"

    lines = [" " * width + "".join(f"{n:>24}" for n in names)]
    for m in metrics:
        lines.append(f"{m:<{width}}" + "".join(cell(n, m) for n in names))
    if any("headroom" in results[n] for n in names):
        row = "".join(
            f"{results[n]['headroom']['fraction']:>14.2f}   {'':<7}"
            if "headroom" in results[n]
            else f"{'-':>14}   {'':<7}"
            for n in names
        )
        lines.append(f"{'headroom_captured':<{width}}{row}")
    return "\n".join(lines)
