"""A fairness term in the reward: a weight on the day's Jain index or minimum satisfaction.

The term of a step is ``weight * (F(after) - F(before))`` with ``F`` the metric of the day's
departed cars so far (`chargax_marl.evaluation.service_metrics`; 1 before any car
leaves), so over a day the terms add up to ``weight * (F_day - 1)``: a penalty of ``weight``
EUR per unit the day falls short of perfect fairness, booked as the cars leave. The profit,
the infos' totals and the evaluation are unchanged: it steers learning only.
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from chargax_marl.core.types import EpisodeTotals
from chargax_marl.teachers.shaping import core_state
from chargax_marl.wrappers.base import TeacherWrapper

FAIRNESS_METRICS = ("jain_index", "min_satisfaction")
"""The metrics the term can weigh (`chargax_marl.evaluation.SERVICE_METRICS` names)."""


def fairness_metric(totals: EpisodeTotals, metric: str) -> jnp.ndarray:
    """The day's ``metric`` so far from its running totals (traceable; the values of
    `chargax_marl.evaluation.service_metrics`).

    Args:
        totals: the day's running `EpisodeTotals` (any leading axes).
        metric: one of `FAIRNESS_METRICS`.

    Returns:
        The metric of the cars departed so far, shaped as the totals' fields; 1 before any car
        has left.

    Raises:
        ValueError: an unknown metric.
    """
    if metric == "jain_index":
        total, squares = totals.satisfaction_sum, totals.satisfaction_sq_sum
        safe = jnp.where(squares > 0, squares, 1.0)
        return jnp.where(
            squares > 0, total * total / (jnp.maximum(totals.cars_served, 1.0) * safe), 1.0
        )
    if metric == "min_satisfaction":
        return 1.0 - totals.satisfaction_shortfall_max
    raise ValueError(f"field 'metric' must be one of {FAIRNESS_METRICS}, got {metric!r}")


class FairnessReward(TeacherWrapper):
    """Adds ``weight_eur * (F(after) - F(before))`` to each step's reward, ``F`` the day's
    Jain index or minimum satisfaction of the departed cars so far.

    Over a day the terms add up to ``weight_eur * (F_day - 1)``. Gymnax view: the station's
    reward gains the term; JaxMARL view: every agent gains it (a shared objective).
    ``info["fairness_reward_eur"]`` holds the term. ``weight_eur=0`` is the wrapped env bit for
    bit.

    Args:
        env: either view, possibly wrapped.
        weight_eur: EUR per unit of the metric (``>= 0``).
        metric: ``"jain_index"`` or ``"min_satisfaction"``.

    Raises:
        ValueError: a negative or non-finite weight, or an unknown metric.
    """

    def __init__(self, env, weight_eur: float = 0.0, metric: str = "jain_index"):
        super().__init__(env)
        if (
            isinstance(weight_eur, bool)
            or not isinstance(weight_eur, (int, float))
            or not math.isfinite(weight_eur)
            or weight_eur < 0
        ):
            raise ValueError(f"field 'weight_eur' must be a finite number >= 0, got {weight_eur!r}")
        if metric not in FAIRNESS_METRICS:
            raise ValueError(f"field 'metric' must be one of {FAIRNESS_METRICS}, got {metric!r}")
        self.weight_eur, self.metric = float(weight_eur), metric

    def _term(self, state, info) -> jnp.ndarray:
        """The step's term from the state before it and the step's infos."""
        before = fairness_metric(core_state(state).totals, self.metric)
        # the stepped day's totals (the returned state may be a fresh day's after an auto-reset)
        after = fairness_metric(
            EpisodeTotals(
                **{
                    k: jnp.reshape(info[f"episode_{k}"], (-1,))[0]
                    for k in EpisodeTotals.__dataclass_fields__
                }
            ),
            self.metric,
        )
        return self.weight_eur * (after - before)

    def step(self, key, state, action, *args):
        """The wrapped ``step`` (gymnax: ``params``; JaxMARL: ``reset_state`` in ``args``) with
        the fairness term added to the reward(s).

        Args:
            key: the step's key.
            state: the wrapped env's state.
            action: the action (gymnax) or action dict (JaxMARL) of the wrapped env.
            *args: passed on to the wrapped ``step``: gymnax's ``params`` or JaxMARL's
                ``reset_state``.

        Returns:
            The wrapped step's tuple, gymnax's ``(obs, state, reward, terminated, truncated,
            info)`` or JaxMARL's ``(obs, state, rewards, dones, infos)``, with the term added
            to the reward (every agent's) and stored as ``fairness_reward_eur`` in the info
            (``(num_agents,)`` in the JaxMARL view).
        """
        out = self._env.step(key, state, action, *args)
        term = self._term(state, out[-1])
        if self.is_marl:
            obs, state, rewards, dones, infos = out
            n = len(self._env.agents)
            infos = {**infos, "fairness_reward_eur": jnp.broadcast_to(term, (n,))}
            return (
                obs,
                state,
                self.add_to_rewards(rewards, jnp.broadcast_to(term, (n,))),
                dones,
                infos,
            )
        obs, state, reward, terminated, truncated, info = out
        return (
            obs,
            state,
            reward + term,
            terminated,
            truncated,
            {**info, "fairness_reward_eur": term},
        )

    def step_arrays(self, key, state, indices, reset_state=None):
        """The JaxMARL view's ``step_arrays`` with the term added to every agent's reward
        (the values of `step`, stacked; ``info["fairness_reward_eur"]`` a scalar).
        Arguments and returns as `chargax_marl.marl.ChargaxMARL.step_arrays`, with this
        wrapper's state.

        Args:
            key: the step's key.
            state: the wrapped env's state.
            indices: ``(num_agents,)`` action indices in agent order.
            reset_state: the fresh day's state at the end of a day (None: a random one).

        Returns:
            ``(obs, state, rewards, done, info)`` of the wrapped ``step_arrays``, the term
            added to ``rewards`` and stored as ``info["fairness_reward_eur"]``.
        """
        obs, next_state, rewards, done, info = self._env.step_arrays(
            key, state, indices, reset_state
        )
        term = self._term(state, info)
        return obs, next_state, rewards + term, done, {**info, "fairness_reward_eur": term}
