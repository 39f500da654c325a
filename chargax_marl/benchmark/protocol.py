"""Play a policy on a task's held-out days and car draws, whatever kind of policy it is.

Kinds of policy (``kind=``):

- ``"core"``: ``policy(state, key, params) -> levels``, the core's signed level per leaf
  (`chargax_marl.policies`); jitted (a named rule of `chargax_marl.policies.POLICIES` by one
  kept program per station shape with the params its argument,
  `chargax_marl.evaluation.play_policy_days`);
- ``"single"``: ``act(obs, key) -> action`` in the single-agent view's spaces
  (`chargax_marl.single.Chargax`); jitted;
- ``"marl"``: ``act(obs_dict, key) -> action_dict`` in the multi-agent view's spaces
  (`chargax_marl.marl.ChargaxMARL`); jitted;
- ``"gymnasium"``: ``act(obs) -> action`` with numpy arrays, the spaces of
  `chargax_marl.single.GymnasiumEnv` (an SB3 model's ``predict``); host loop;
- ``"pettingzoo"``: ``act(obs_dict) -> action_dict`` with numpy arrays and integers, the
  spaces of `chargax_marl.marl.ChargaxParallelEnv`; host loop.

Every kind meets the same cars: draw ``r`` of day ``days[i]`` steps the simulator with the keys
of ``day_keys[i, r]`` (`chargax_marl.trace.day_keys`), as
`chargax_marl.evaluation.run_days_keyed` does. The host kinds call the policy once per
day, draw and step (all days and draws advance together, one jitted step per time step).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from chargax_marl.core import clock, observation, physics, simulator
from chargax_marl.core.types import EnvParams, EpisodeTotals
from chargax_marl.evaluation import (
    PolicyOutputCounts,
    check_policy_outputs,
    play_days,
    play_policy_days,
)
from chargax_marl.marl.env import ChargaxMARL
from chargax_marl.policies import is_named_rule
from chargax_marl.single.env import Chargax, action_levels
from chargax_marl.trace import day_keys as split_day_key

JIT_KINDS = ("core", "single", "marl")
HOST_KINDS = ("gymnasium", "pettingzoo")
KINDS = JIT_KINDS + HOST_KINDS
"""Every kind of policy `play` accepts."""


def _check_kind(kind: str) -> None:
    if kind not in KINDS:
        raise ValueError(f"field 'kind' must be one of {list(KINDS)}, got {kind!r}")


def _single_space(params: EnvParams) -> tuple[tuple[int, ...], bool, np.ndarray | None]:
    """``(shape, integer, nvec)`` of the single-agent action space."""
    space = Chargax(params=params).action_space(params)
    if params.action_mode == "continuous":
        return tuple(space.shape), False, None
    return tuple(space.shape), True, np.asarray(space.nvec)


def _single_bounds(params: EnvParams) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` per leaf of the single-agent action space: ``[0, nvec - 1]`` indices,
    or ``[-1, 1]`` fractions in the continuous mode (the Box)."""
    shape, integer, nvec = _single_space(params)
    if not integer:
        return np.full(shape, -1.0, np.float32), np.full(shape, 1.0, np.float32)
    return np.zeros(shape, np.int32), (nvec - 1).astype(np.int32)


def _outside_level(params: EnvParams):
    """A level outside every leaf's range (`chargax_marl.evaluation.level_range`): what a view's
    action outside its space is played as, so that the play counts it."""
    if params.action_mode == "continuous":
        return jnp.float32(2.0)
    return jnp.int32(params.num_levels + 1)


def _check_single_action(out: Any, params: EnvParams, where: str, space=None) -> None:
    """Raise a ``ValueError`` for an action whose shape or dtype does not fit the single-agent
    space (``space``: `_single_space`, computed once by a caller that checks often)."""
    shape, integer, _ = space or _single_space(params)
    got_shape = tuple(np.shape(out))
    dtype = np.dtype(out.dtype) if hasattr(out, "dtype") else np.asarray(out).dtype
    if got_shape != shape:
        raise ValueError(
            f"{where}: the policy's action has shape {got_shape}; the task's action space "
            f"({params.action_mode}, one entry per port and battery) needs shape {shape}"
        )
    ok = np.issubdtype(dtype, np.integer) if integer else np.issubdtype(dtype, np.floating)
    if not ok:
        need = "integers (level indices)" if integer else "floats (current fractions)"
        raise ValueError(
            f"{where}: the policy's action has dtype {dtype}; the task's action space "
            f"({params.action_mode}) takes {need}"
        )


def _check_marl_actions(out: Any, env: ChargaxMARL, where: str) -> None:
    if not isinstance(out, dict) or set(out) != set(env.agents):
        got = sorted(out) if isinstance(out, dict) else type(out).__name__
        raise ValueError(
            f"{where}: the policy must return one action per agent {env.agents}, got {got}"
        )
    for agent, a in out.items():
        dtype = np.dtype(a.dtype) if hasattr(a, "dtype") else np.asarray(a).dtype
        if np.shape(a) != () or not np.issubdtype(dtype, np.integer):
            raise ValueError(
                f"{where}: agent {agent!r}'s action must be one integer of "
                f"Discrete({env.num_actions}), got shape {np.shape(a)} dtype {dtype}"
            )


def as_core(policy: Callable, kind: str, params: EnvParams) -> Callable:
    """A jittable policy of kind ``"core"``, ``"single"`` or ``"marl"`` as
    ``act(state, key) -> levels``, its action checked against the task's action space.

    Args:
        policy: the policy.
        kind: one of `JIT_KINDS`.
        params: the task's env parameters.

    Returns:
        ``act(state, key) -> levels``.

    Raises:
        ValueError: an unknown kind, or an action of the wrong shape or dtype.
    """
    _check_kind(kind)
    if kind not in JIT_KINDS:
        raise ValueError(f"as_core: kind {kind!r} is played on the host, not jitted")
    state0 = simulator.empty_state(0, params)
    key0 = jax.random.PRNGKey(0)
    if kind == "core":

        def act(state, key):
            return policy(state, key, params)

        out = jax.eval_shape(act, state0, key0)
        n = params.station.num_leaves
        if tuple(out.shape) != (n,):
            raise ValueError(
                f"core policy: levels of shape {tuple(out.shape)}; the station has {n} leaves"
            )
        return act
    outside_level = _outside_level(params)
    if kind == "single":
        low, high = _single_bounds(params)
        can_discharge = physics.leaf_min_level(params.station, 1, params.v2g) < 0

        def act(state, key):
            action = policy(observation.flat_obs(state, params), key)
            levels = action_levels(action, params)
            raw = jnp.reshape(jnp.asarray(action), levels.shape)
            # an index or fraction outside the space becomes a level outside the core's range,
            # so the play counts it (the core clips it as the view would have)
            outside = (raw < low) | (raw > high)
            if params.action_mode != "continuous":  # integer indices (checked below)
                return jnp.where(outside, outside_level, levels)
            # a fraction the leaf cannot take (discharge where it may not) plays as 0, as the
            # core plays it; a non-finite fraction stays non-finite, so the play counts it (the
            # core plays it as idle all the same)
            levels = jnp.where(can_discharge, levels, jnp.maximum(levels, 0.0))
            finite = jnp.isfinite(raw.astype(jnp.float32))
            return jnp.where(finite, jnp.where(outside, outside_level, levels), jnp.nan)

        out = jax.eval_shape(lambda s, k: policy(observation.flat_obs(s, params), k), state0, key0)
        _check_single_action(out, params, "single-agent policy")
        return act
    env = ChargaxMARL(params=params)

    def act(state, key):
        actions = policy(env.get_obs(state), key)
        raw = jnp.stack([jnp.reshape(jnp.asarray(actions[a]), ()) for a in env.agents])
        outside = (raw < 0) | (raw >= env.num_actions)  # counted as in the single kind
        return jnp.where(outside, outside_level, env.actions_to_levels(actions))

    out = jax.eval_shape(lambda s, k: policy(env.get_obs(s), k), state0, key0)
    _check_marl_actions(out, env, "multi-agent policy")
    return act


def flatten_schedule(days, day_keys) -> tuple[np.ndarray, jax.Array, int, int]:
    """``(days repeated per draw, keys (n * draws, 2), n, draws)``: one entry per played day.

    Args:
        days: ``(n,)`` day indices (any shape, flattened).
        day_keys: ``(n, draws, 2)`` keys, ``day_keys[i, r]`` the keys of draw ``r`` of
            ``days[i]``.

    Returns:
        ``(flat_days, flat_keys, n, draws)``: ``flat_days`` the ``(n * draws,)`` int32 day
        indices (each day repeated once per draw), ``flat_keys`` the ``(n * draws, 2)`` keys in
        the same order, and the two counts.

    Raises:
        ValueError: ``day_keys`` is not three-dimensional or its first axis is not the number
            of days.
    """
    days = np.asarray(days, np.int32).reshape(-1)
    keys = jnp.asarray(day_keys)
    if keys.ndim != 3 or keys.shape[0] != days.size:
        raise ValueError(
            f"day_keys must have shape (days={days.size}, draws, 2), got {tuple(keys.shape)}"
        )
    n, r = int(keys.shape[0]), int(keys.shape[1])
    return np.repeat(days, r), keys.reshape(n * r, keys.shape[-1]), n, r


def unflatten_totals(totals: EpisodeTotals, n: int, r: int) -> EpisodeTotals:
    """Per-day totals (scalars per day) over the flat schedule, with any leading axes before
    it (seeds), as ``(..., n, draws)``.

    Args:
        totals: `EpisodeTotals` whose leaves have the flat schedule (``n * draws``) as their
            last axis (`flatten_schedule`'s order).
        n: the number of days.
        r: the number of draws per day.

    Returns:
        The same totals as numpy leaves of shape ``(..., n, r)``.
    """
    return jax.tree.map(lambda x: np.asarray(x).reshape(np.shape(x)[:-1] + (n, r)), totals)


def play(
    policy: Callable, params: EnvParams, days, day_keys: jax.Array, kind: str = "core"
) -> EpisodeTotals:
    """Play ``policy`` for one whole day per held-out day and draw.

    Args:
        policy: a policy of ``kind`` (module docstring).
        params: the env parameters.
        days: ``(n,)`` day indices.
        day_keys: ``(n, draws, 2)`` keys (`chargax_marl.benchmark.Task.day_keys`).
        kind: one of `KINDS`.

    Returns:
        The days' final `EpisodeTotals`, numpy leaves with leading axes
        ``(n, draws)``.

    Raises:
        ValueError: an unknown kind, an action that does not fit the action space, or levels
            the env would have reinterpreted: non-finite or outside the action space on any
            step, or not integers in a
            discrete action mode (`chargax_marl.evaluation.check_policy_outputs`, counted
            inside the compiled play).
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.benchmark.protocol.play")
    _check_kind(kind)
    flat_days, flat_keys, n, r = flatten_schedule(days, day_keys)
    if kind in HOST_KINDS:
        totals, counts = _play_host(policy, kind, params, flat_days, flat_keys)
    elif kind == "core" and is_named_rule(policy):
        as_core(policy, kind, params)  # its levels' shape checked
        # one kept program per rule and station shape, the params its argument
        totals, counts = play_policy_days(policy, params, flat_days, flat_keys)
    else:
        act = as_core(policy, kind, params)
        totals, counts = jax.jit(lambda d, k: play_days(act, params, d, k))(flat_days, flat_keys)
    check_policy_outputs(jax.device_get(counts), flat_days, f"the {kind} policy")
    return unflatten_totals(jax.device_get(totals), n, r)


def _play_host(policy, kind, params, days, keys) -> tuple[EpisodeTotals, PolicyOutputCounts]:
    """The host loop: every day and draw one env, stepped together, the policy called per env;
    the totals and the counts of non-finite actions and of fractions outside the Box (only a
    continuous action can hold them: the discrete kinds' indices are checked to be integers of
    the space at each step, and refused at the first that is not)."""
    steps = int(params.num_steps)
    _, step_keys, battery_keys = jax.vmap(lambda k: split_day_key(k, steps))(keys)
    state = jax.jit(jax.vmap(lambda d, k: simulator.empty_state(d, params, k)))(
        jnp.asarray(days), battery_keys
    )
    if kind == "gymnasium":
        space = _single_space(params)

        def obs_fn(s):
            return observation.flat_obs(s, params)

        def to_levels(a):
            return action_levels(a, params)

        def check(a):
            return _host_single_action(a, params, space)

    else:
        env = ChargaxMARL(params=params)

        def obs_fn(s):
            return env.get_obs_matrix(s)

        def to_levels(a):
            return env.actions_to_levels(a)

        def check(a):
            return env.check_actions(a)

    observe = jax.jit(jax.vmap(obs_fn))
    advance = jax.jit(jax.vmap(lambda s, k, a: simulator.step(k, s, to_levels(a), params)[0]))
    agents = None if kind == "gymnasium" else env.agents
    nonfinite = np.zeros(len(days), np.int32)
    outside = np.zeros(len(days), np.int32)
    for t in range(steps):
        obs = np.asarray(observe(state))
        if agents is None:
            acts = [check(policy(o)) for o in obs]
        else:
            acts = [check(policy(dict(zip(agents, o)))) for o in obs]
        acts = np.stack(acts)
        flat = acts.reshape(len(days), -1)
        nonfinite += ~np.isfinite(flat).all(axis=1)
        if np.issubdtype(flat.dtype, np.floating):  # fractions; NaN is counted above
            with np.errstate(invalid="ignore"):
                outside += (np.isfinite(flat) & ((flat < -1.0) | (flat > 1.0))).any(axis=1)
        state = advance(state, step_keys[:, t], jnp.asarray(acts))
    counts = PolicyOutputCounts(nonfinite, np.zeros_like(nonfinite), outside)
    return jax.device_get(state.totals), counts


def _host_single_action(a, params, space) -> np.ndarray:
    arr = np.asarray(a)
    _check_single_action(arr, params, "Gymnasium policy", space)
    _, integer, nvec = space
    if not integer:  # a fraction outside the Box is counted by the loop (as NaN is)
        return arr.astype(np.float32)
    if np.any(arr < 0) or np.any(arr >= nvec):
        raise ValueError(
            f"Gymnasium policy: action {arr.tolist()} is outside MultiDiscrete({nvec.tolist()})"
        )
    return arr.astype(np.int32)
