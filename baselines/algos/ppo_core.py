"""The PPO pieces every trainer shares: GAE, the clipped loss, epochs over shuffled
minibatches, the optimiser with an annealed learning rate, and episode metrics.

The scalar hyper-parameters of `HYPER_KEYS` are *values* of the training program, not
constants compiled into it: every trainer keeps them in its runner state (`hyper_values`), so
that one compiled program trains many settings of them at once (``jax.vmap`` over the runner
states, `baselines.sweep`) and a setting trained alone runs the same program.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

HYPER_KEYS = (
    "LR",
    "MAX_GRAD_NORM",
    "GAMMA",
    "GAE_LAMBDA",
    "CLIP_EPS",
    "VF_CLIP",
    "ENT_COEF",
    "VF_COEF",
    "REWARD_SCALE",
    "SHAPING_WEIGHT",
)
"""The config keys a trainer reads as values of its runner state (float32 scalars); every other
key sets the program's shapes or structure and is compiled in."""


def hyper_values(config: dict) -> dict[str, jax.Array]:
    """The `HYPER_KEYS` of a resolved config as float32 scalars (a runner state's ``hyper``).

    Args:
        config: a resolved config (`baselines.config.resolve`).

    Returns:
        ``{key: float32 array of shape ()}`` for every key of `HYPER_KEYS`.
    """
    return {k: jnp.asarray(np.float32(config[k])) for k in HYPER_KEYS}


def gae(rewards, values, dones, last_value, gamma: float, lam: float):
    """Generalised advantage estimation over a rollout ``(T, ...)``; ``dones[t]`` ends the
    episode after step ``t`` (the day ends: the next value is not bootstrapped).

    Args:
        rewards: ``(T, ...)`` rewards.
        values: ``(T, ...)`` the critic's values of the steps' observations.
        dones: ``(T, ...)`` 1 where the episode ends after the step, else 0.
        last_value: ``(...)`` the critic's value after the rollout's last step.
        gamma: the discount factor.
        lam: the GAE lambda.

    Returns:
        ``(advantages, targets)``, each ``(T, ...)``: the GAE advantages and the value
        targets ``advantages + values``.
    """

    def body(carry, x):
        next_adv, next_value = carry
        r, v, d = x
        delta = r + gamma * next_value * (1.0 - d) - v
        adv = delta + gamma * lam * (1.0 - d) * next_adv
        return (adv, v), adv

    _, adv = jax.lax.scan(
        body, (jnp.zeros_like(last_value), last_value), (rewards, values, dones), reverse=True
    )
    return adv, adv + values


def ppo_loss(
    new_logp, old_logp, advantages, values, old_values, targets, ent, hyper, ent_coef=None
):
    """Clipped surrogate + clipped value loss - entropy bonus.

    Args:
        new_logp: log-probabilities of the taken actions under the new policy, ``(rows,)``
            (or ``(rows, parts)``).
        old_logp: the same under the rollout's policy.
        advantages: GAE advantages, shaped as the values; normalised over the minibatch.
        values: the critic's new values.
        old_values: the critic's values in the rollout.
        targets: the value targets, shaped as the values.
        ent: the policy's entropy per row.
        hyper: ``CLIP_EPS``, ``VF_CLIP``, ``ENT_COEF`` and ``VF_COEF`` (a runner state's
            ``hyper``, or a config).
        ent_coef: the entropy coefficient of each row (default ``hyper["ENT_COEF"]`` for all).

    Returns:
        ``(total, parts)``: the loss and its actor, value, entropy and approximate-KL parts.
    """
    adv = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    ratio = jnp.exp(new_logp - old_logp)
    eps = hyper["CLIP_EPS"]
    actor_loss = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - eps, 1 + eps) * adv).mean()
    v_clip = old_values + jnp.clip(values - old_values, -hyper["VF_CLIP"], hyper["VF_CLIP"])
    value_loss = 0.5 * jnp.maximum((values - targets) ** 2, (v_clip - targets) ** 2).mean()
    bonus = (hyper["ENT_COEF"] if ent_coef is None else ent_coef) * ent
    ent = ent.mean()
    total = actor_loss + hyper["VF_COEF"] * value_loss - bonus.mean()
    approx_kl = ((ratio - 1) - (new_logp - old_logp)).mean()
    return total, {
        "actor_loss": actor_loss,
        "value_loss": value_loss,
        "entropy": ent,
        "approx_kl": approx_kl,
    }


def shuffled_rows(key: jax.Array, steps: int, actors: int, agents: int = 1) -> jnp.ndarray:
    """A random order ``(steps * actors,)`` of the rows of a rollout flattened from ``(steps, actors)``.

    With ``agents == 1`` a uniform permutation of the rows. With ``agents > 1`` the actors are
    agent-major (``actor = agent * envs + env``, ``envs = actors / agents``) and the
    *env-steps* ``(step, env)`` are permuted instead, each followed by its ``agents`` rows in
    agent order: a minibatch then holds every agent of the env-steps it draws. Permuting the
    rows of a multi-agent rollout (81,600 for 17 agents x 16 envs x 300 steps, a sort) cost
    about a quarter of an IPPO epoch on a CPU; permuting its env-steps is ``agents`` times
    smaller.

    Args:
        key: a PRNG key.
        steps: the rollout's steps.
        actors: the rollout's actors (``agents * envs`` when ``agents > 1``).
        agents: the agents per env.

    Returns:
        ``(steps * actors,)`` row indices into the rollout flattened as
        ``step * actors + actor``, each row once.
    """
    if agents == 1:
        return jax.random.permutation(key, steps * actors)
    envs = actors // agents
    unit = jax.random.permutation(key, steps * envs)  # step * envs + env
    step, env = unit // envs, unit % envs
    rows = step[:, None] * actors + jnp.arange(agents)[None, :] * envs + env[:, None]
    return rows.reshape(-1)


def ppo_epochs(
    loss_fn, tx: Optimizer, params, rs, key, traj, adv, targets, config: dict, agents: int = 1
):
    """``UPDATE_EPOCHS`` passes over the rollout in ``NUM_MINIBATCHES`` shuffled minibatches.

    ``traj`` is the rollout (a NamedTuple with an ``info`` field, dropped here) with leading
    axes ``(steps, actors)``; ``loss_fn(params, (traj, adv, targets))`` returns
    ``(loss, parts)``; ``tx`` steps from the runner state ``rs``'s optimiser state, with the
    learning rate and clip norm of its ``hyper`` at its update index ``update``.
    ``agents > 1`` (IPPO, MAPPO: ``actors = agents * envs``, agent-major) shuffles
    env-steps, each with all of its agents' rows (`shuffled_rows`).

    Args:
        loss_fn: ``loss_fn(params, (traj, adv, targets)) -> (loss, parts)`` on a minibatch.
        tx: the `Optimizer`.
        params: the network parameters to train.
        rs: the runner state (its ``opt_state``, ``hyper`` and ``update``).
        key: a PRNG key for the shuffles.
        traj: the rollout, leaves with leading axes ``(steps, actors)``.
        adv: the advantages, leading axes ``(steps, actors)``.
        targets: the value targets, leading axes ``(steps, actors)``.
        config: the resolved config (``UPDATE_EPOCHS``, ``NUM_MINIBATCHES``).
        agents: the agents per env (1 for single-agent PPO).

    Returns:
        ``(params, opt_state, key, parts)``: the trained parameters, the optimiser state,
        the advanced key and ``loss_fn``'s ``parts`` stacked over epochs and minibatches
        (leading axes ``(UPDATE_EPOCHS, NUM_MINIBATCHES)``).
    """
    opt_state, hyper, update = rs.opt_state, rs.hyper, rs.update
    steps, actors = traj.reward.shape[:2]
    batch = steps * actors

    def epoch(carry, _):
        params, opt_state, key = carry
        key, k_perm = jax.random.split(key)
        data = (traj._replace(info={}), adv, targets)
        flat = jax.tree.map(lambda x: x.reshape((batch,) + x.shape[2:]), data)
        perm = shuffled_rows(k_perm, steps, actors, agents)
        mbs = jax.tree.map(
            lambda x: x[perm].reshape((config["NUM_MINIBATCHES"], -1) + x.shape[1:]), flat
        )

        def minibatch(carry, mb):
            params, opt_state = carry
            (_, parts), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, mb)
            params, opt_state = tx.step(grads, opt_state, params, hyper, update)
            return (params, opt_state), parts

        (params, opt_state), parts = jax.lax.scan(minibatch, (params, opt_state), mbs)
        return (params, opt_state, key), parts

    (params, opt_state, key), parts = jax.lax.scan(
        epoch, (params, opt_state, key), None, config["UPDATE_EPOCHS"]
    )
    return params, opt_state, key, parts


class Optimizer(NamedTuple):
    """Adam whose learning rate and clip norm are values (a runner state's ``hyper``).

    Attributes:
        init: ``init(params) -> opt_state``.
        step: ``step(grads, opt_state, params, hyper, update) -> (params, opt_state)``: one
            gradient step at the update index ``update``.
    """

    init: Callable
    step: Callable


def make_optimizer(config: dict, num_updates: int) -> Optimizer:
    """Adam with global-norm clipping (``MAX_GRAD_NORM``); the learning rate ``LR`` anneals
    linearly to 0 over the ``num_updates`` updates when ``ANNEAL_LR`` is on.

    Args:
        config: a resolved config (``ANNEAL_LR``; the values come from ``hyper`` at each step).
        num_updates: the updates of the whole training.

    Returns:
        The `Optimizer`.
    """
    adam = optax.scale_by_adam(eps=1e-5)
    anneal = bool(config["ANNEAL_LR"])

    def step(grads, opt_state, params, hyper, update):
        g_norm = jnp.sqrt(sum(jnp.sum(jnp.square(g)) for g in jax.tree.leaves(grads)))
        max_norm = hyper["MAX_GRAD_NORM"]
        grads = jax.tree.map(
            lambda g: jax.lax.select(g_norm < max_norm, g, (g / g_norm.astype(g.dtype)) * max_norm),
            grads,
        )
        direction, opt_state = adam.update(grads, opt_state, params)
        lr = hyper["LR"]
        if anneal:
            lr = lr * (1.0 - update / max(num_updates, 1))
        return jax.tree.map(lambda p, d: p - lr * d, params, direction), opt_state

    return Optimizer(adam.init, step)


def num_updates(config: dict) -> int:
    """The number of updates of a training run: whole rollouts in ``TOTAL_TIMESTEPS``.

    Args:
        config: the config (``TOTAL_TIMESTEPS``, ``NUM_ENVS``, ``NUM_STEPS``).

    Returns:
        ``TOTAL_TIMESTEPS // (NUM_ENVS * NUM_STEPS)``.

    Raises:
        ValueError: ``TOTAL_TIMESTEPS`` less than one rollout.
    """
    n = int(config["TOTAL_TIMESTEPS"]) // (int(config["NUM_ENVS"]) * int(config["NUM_STEPS"]))
    if n < 1:
        raise ValueError(
            f"TOTAL_TIMESTEPS={config['TOTAL_TIMESTEPS']} is less than one rollout "
            f"(NUM_ENVS*NUM_STEPS={config['NUM_ENVS'] * config['NUM_STEPS']})"
        )
    return n


def episode_metrics(done, info, prefix="returned_episode") -> dict:
    """Mean over the episodes that ended in a rollout of the episode return and totals.

    Args:
        done: where an episode ended (any shape, as the info's leaves).
        info: the rollout's infos, with ``<prefix>_returns``, ``<prefix>_profit_eur`` and
            ``<prefix>_energy_delivered_kwh`` (the log wrapper's episode totals).
        prefix: the prefix of those keys.

    Returns:
        ``{"episodes", "episode_return", "episode_profit_eur" (EUR),
        "episode_energy_delivered_kwh" (kWh)}``: the count of ended episodes and the means
        over them (NaN when none ended).
    """
    done = done.astype(jnp.float32)
    count = done.sum()

    def mean(x):
        return jnp.where(count > 0, (x * done).sum() / jnp.maximum(count, 1.0), jnp.nan)

    return {
        "episodes": count,
        "episode_return": mean(info[f"{prefix}_returns"]),
        "episode_profit_eur": mean(info[f"{prefix}_profit_eur"]),
        "episode_energy_delivered_kwh": mean(info[f"{prefix}_energy_delivered_kwh"]),
    }
