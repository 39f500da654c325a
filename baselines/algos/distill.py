"""Distillation of the MPC into the multi-agent trainers' shared actor (DAgger).

The MPC (`chargax_marl.optimal.mpc.MPC`: a receding-horizon LP over the cars present and the
day's prices) is the strongest controller that acts on what the station knows now, but it
solves an LP at every step. Distillation buys its decisions at a network's cost per step:

1. **Collect.** ``DISTILL_ENVS`` envs play one day from a reset. At every step each agent's
   observation (the row the actor reads, advice and all) is stored with the MPC's level for
   its leaf in that state, the *label*. In round 0 the MPC acts; in round ``r`` each env
   follows the MPC with probability ``DISTILL_BETA ** r`` for the whole day and the actor's
   greedy action otherwise, so later rounds label the states the actor itself reaches
   (DAgger, Ross et al. 2011).
2. **Fit.** After each round the actor (and the batteries' actor under ``BATTERY_NET``) takes
   ``DISTILL_STEPS`` Adam steps of the cross-entropy between its masked logits and the labels,
   on minibatches of ``DISTILL_BATCH`` rows drawn from every round so far; a port without a
   car (whose action changes nothing) is left out of the loss.

``DISTILL_AGENTS = "battery"`` fits the batteries' actor alone: the ports keep theirs (with
``RESIDUAL``, the coupled plan) and play their own greedy actions in every round.

The labels are privileged information that shapes training only: the trained actor reads its
observation as before and the MPC is not part of the policy that is scored. The critic is not
touched; PPO's updates, if any follow, start from the distilled actor.

The whole distillation is one jitted function of the parameters and a key; the MPC runs on
the host through its ``pure_callback`` (one call per step for the batch of envs, and of seeds
under ``vmap``), so a round costs about ``DISTILL_ENVS * steps_per_day`` LP solves.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax

from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.optimal.mpc import MPC
from chargax_marl.teachers import shaping as teacher_shaping
from chargax_marl.teachers.fill import able_kw

MODES = ("off", "mpc")


def distill_mode(config: dict) -> str:
    """The validated ``DISTILL`` setting.

    Args:
        config: the trainer's config (``DISTILL``, default ``"off"``).

    Returns:
        ``"off"`` or ``"mpc"``.

    Raises:
        ValueError: a value that is not one of `MODES`.
    """
    mode = config.get("DISTILL", "off")
    if mode not in MODES:
        raise ValueError(f"DISTILL={mode!r} must be one of {MODES}")
    return mode


def make_distill(
    config: dict,
    policy,
    env,
    agents: list,
    agent_rows: Callable,
    avail_rows: np.ndarray,
    action_offset: int,
    env_params,
) -> Callable:
    """Build ``distill(params, key) -> (params, metrics)`` (see the module docstring).

    Args:
        config: the resolved config (``DISTILL_ROUNDS``, ``DISTILL_ENVS``, ``DISTILL_BETA``,
            ``DISTILL_STEPS``, ``DISTILL_BATCH``, ``DISTILL_LR``, ``DISTILL_HORIZON_H``).
        policy: the trainer's `baselines.algos.ippo.SharedPolicy`.
        env: the wrapped training env (``reset``, ``step_arrays``), as the trainer steps it.
        agents: the env's agent names, in the order of its observation matrix.
        agent_rows: ``agent_rows(obs (envs, agents, obs), env_state) -> (agents * envs,
            obs')``: the actor's rows, agent-major, with the advice the policy reads.
        avail_rows: ``(agents, K)`` bool, the actions each agent may take.
        action_offset: the index of level 0 (idle) in an agent's actions.
        env_params: the training env's parameters (the MPC plans on them).

    Returns:
        ``distill(params, key) -> (params, metrics)`` with the actor's parameters fitted
        to the MPC's labels and ``metrics`` ``{"loss": (rounds,), "agreement": (rounds,)}``:
        each round's mean cross-entropy over its last fitting steps and, before the fit, the
        share of the round's deciding rows (a battery, or a port with a car) where the
        actor's greedy action was the MPC's.

    Raises:
        ValueError: a ``DISTILL_*`` value out of range, ``DISTILL_AGENTS="battery"`` on a
            station without a battery or without ``BATTERY_NET``, or ``PRIORITY_FILL`` on.
    """
    rounds = int(config["DISTILL_ROUNDS"])
    n_envs = int(config["DISTILL_ENVS"])
    beta = float(config["DISTILL_BETA"])
    fit_steps = int(config["DISTILL_STEPS"])
    batch = int(config["DISTILL_BATCH"])
    for name, value, least in (
        ("DISTILL_ROUNDS", rounds, 1),
        ("DISTILL_ENVS", n_envs, 1),
        ("DISTILL_STEPS", fit_steps, 1),
        ("DISTILL_BATCH", batch, 1),
    ):
        if value < least:
            raise ValueError(f"{name}={value} must be an integer >= {least}")
    if not 0.0 <= beta <= 1.0:
        raise ValueError(f"DISTILL_BETA={beta} must be in [0, 1]")
    mpc = MPC(env_params, horizon_hours=float(config["DISTILL_HORIZON_H"]))
    n_steps = int(env_params.num_steps)
    n_agents = int(avail_rows.shape[0])
    # the agents that learn from the labels (the last ones are the batteries)
    learners = np.arange(n_agents)
    if config["DISTILL_AGENTS"] == "battery":
        learners = learners[n_agents - int(env_params.station.num_batteries) :]
    if learners.size == 0:
        raise ValueError("DISTILL_AGENTS='battery' on a station without a battery")
    if learners.size < n_agents and not policy.battery_net:
        raise ValueError(
            "DISTILL_AGENTS='battery' fits the batteries' own actor: set BATTERY_NET=true "
            "(with one shared actor the ports' actor would move too)"
        )
    if config.get("PRIORITY_FILL", False):
        raise ValueError(
            "DISTILL fits the actor to the MPC's levels, which PRIORITY_FILL's actions do not "
            "encode: set PRIORITY_FILL=false or DISTILL='off'"
        )
    learner_rows = (learners[:, None] * n_envs + np.arange(n_envs)[None, :]).ravel()
    is_learner_row = np.isin(np.arange(n_agents * n_envs), learner_rows)
    n_rows = n_steps * learner_rows.size  # one round's rows
    avail = jnp.asarray(np.repeat(avail_rows, n_envs, axis=0))  # agent-major
    tx = optax.adam(float(config["DISTILL_LR"]))
    actor_keys = ["actor"] + (["battery_actor"] if policy.battery_net else [])

    top = int(env_params.num_levels)
    leaf_max_kw = jnp.asarray(env_params.station.leaf_max_kw)
    is_port = jnp.asarray(np.asarray(env_params.station.leaf_kind) != KIND_BATTERY)

    def labels_of(core):
        """The MPC's action index per actor row ``(agents * envs,)`` of the batched state.

        A port's charging level that already reaches what its car can take this step (its
        rate curve, its room to the target, `chargax_marl.teachers.fill.able_kw`) is labelled
        full power, the level that gives the same power: the MPC's plan there is the car's
        own limit, not a choice, and one label for it spares the actor learning each car's
        limit as a level."""
        levels = jax.vmap(lambda s: mpc(s, None, env_params))(core)  # (envs, agents)
        able = jax.vmap(lambda s: able_kw(s, env_params))(core)
        at_limit = levels.astype(jnp.float32) / top * leaf_max_kw >= able - 1e-4 * leaf_max_kw
        levels = jnp.where(is_port & (levels > 0) & at_limit, top, levels)
        return jnp.swapaxes(levels, 0, 1).reshape(-1).astype(jnp.int32) + action_offset

    def collect(params, key, follow_prob):
        k_reset, k_follow, k_steps = jax.random.split(key, 3)
        obs, env_state = jax.vmap(env.reset)(jax.random.split(k_reset, n_envs))
        obs = jnp.stack([obs[a] for a in agents], axis=1)
        follow = jax.random.uniform(k_follow, (n_envs,)) < follow_prob  # per env, the whole day
        follow_rows = jnp.tile(follow, n_agents) & is_learner_row

        def step(carry, k):
            obs, env_state = carry
            rows = agent_rows(obs, env_state)
            core = teacher_shaping.core_state(env_state)
            label = labels_of(core)
            # the rows where the agent's action matters: a battery, or a port with a car
            decides = jnp.swapaxes(core.occupied | ~is_port, 0, 1).reshape(-1)
            greedy = jnp.argmax(policy.logits(params, rows, avail, rows="agent_major"), axis=-1)
            action = jnp.where(follow_rows, label, greedy).astype(jnp.int32)
            actions = jnp.swapaxes(action.reshape(n_agents, n_envs), 0, 1)
            obs, env_state, _, _, _ = jax.vmap(env.step_arrays)(
                jax.random.split(k, n_envs), env_state, actions
            )
            kept = (rows[learner_rows], label[learner_rows], decides[learner_rows])
            return (obs, env_state), kept + (greedy[learner_rows] == label[learner_rows],)

        _, (rows, label, decides, agree) = jax.lax.scan(
            step, (obs, env_state), jax.random.split(k_steps, n_steps)
        )
        agreement = jnp.sum(agree & decides) / jnp.maximum(jnp.sum(decides), 1)
        return rows.reshape(n_rows, -1), label.reshape(n_rows), decides.reshape(n_rows), agreement

    def cross_entropy(actor, params, obs, label, weight, mask):
        logits = policy.logits({**params, **actor}, obs, mask)
        nll = -jnp.take_along_axis(jax.nn.log_softmax(logits, axis=-1), label[:, None], axis=-1)
        return jnp.sum(weight * nll[:, 0]) / jnp.maximum(jnp.sum(weight), 1.0)

    def distill(params, key):
        # the rows as stored: the observation with its advice, before the networks' features
        obs_dim = jax.eval_shape(collect, params, key, jnp.float32(1.0))[0].shape[1]
        buf_obs = jnp.zeros((rounds * n_rows, obs_dim), jnp.float32)
        buf_label = jnp.zeros((rounds * n_rows,), jnp.int32)
        buf_weight = jnp.zeros((rounds * n_rows,), jnp.float32)
        # each row's agent, for its mask: rows are (step, agent, env) within a round
        row_agent = jnp.tile(jnp.repeat(jnp.asarray(learners), n_envs), n_steps * rounds)
        actor = {k: params[k] for k in actor_keys}
        opt_state = tx.init(actor)

        def round_(carry, r):
            actor, opt_state, buf_obs, buf_label, buf_weight, key = carry
            key, k_collect, k_fit = jax.random.split(key, 3)
            obs, label, decides, agree = collect(
                {**params, **actor}, k_collect, jnp.float32(beta) ** r.astype(jnp.float32)
            )
            buf_obs = jax.lax.dynamic_update_slice(buf_obs, obs, (r * n_rows, 0))
            buf_label = jax.lax.dynamic_update_slice(buf_label, label, (r * n_rows,))
            buf_weight = jax.lax.dynamic_update_slice(
                buf_weight, decides.astype(jnp.float32), (r * n_rows,)
            )
            filled = (r + 1) * n_rows

            def fit(carry, k):
                actor, opt_state = carry
                idx = jax.random.randint(k, (batch,), 0, filled)
                mask = jnp.asarray(avail_rows)[row_agent[idx]]
                loss, grads = jax.value_and_grad(cross_entropy)(
                    actor, params, buf_obs[idx], buf_label[idx], buf_weight[idx], mask
                )
                updates, opt_state = tx.update(grads, opt_state, actor)
                return (optax.apply_updates(actor, updates), opt_state), loss

            (actor, opt_state), losses = jax.lax.scan(
                fit, (actor, opt_state), jax.random.split(k_fit, fit_steps)
            )
            tail = losses[-max(1, fit_steps // 10) :].mean()
            jax.debug.print(
                "distill round {r}: agreement {a:.3f}, loss {l:.3f}", r=r, a=agree, l=tail
            )
            return (actor, opt_state, buf_obs, buf_label, buf_weight, key), (tail, agree)

        (actor, *_), (loss, agree) = jax.lax.scan(
            round_,
            (actor, opt_state, buf_obs, buf_label, buf_weight, key),
            jnp.arange(rounds, dtype=jnp.int32),
        )
        return {**params, **actor}, {"loss": loss, "agreement": agree}

    return distill
