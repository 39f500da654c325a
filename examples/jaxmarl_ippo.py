"""IPPO on `chargax_marl.marl.ChargaxMARL` in the shape of JaxMARL's ``ippo_ff_mpe.py``,
with the teachers of `chargax_marl.wrappers` and nothing from the project's ``baselines/``.

Run ``python examples/jaxmarl_ippo.py`` (``--seeds 2 --timesteps 6e5`` by default; ``--out
FILE`` writes the result as JSON). It builds the default scenario (shopping users, medium
traffic) with full-power actions (``num_levels=1``), trains on the training days only (the
100 held-out days of ``split_days(365, 100, seed=0)`` are kept out), with the battery's stored
energy and each parked car's plan as potential-based reward shaping and the plan advice and
relative prices as observation columns. It then plays the greedy policy of every seed on the
held-out days with evaluation key 0 (the same cars for every policy) beside always-max, the
battery rule and the battery-only programme, and prints the paired difference (mean ± standard
error over days) to the battery rule and to always-max.

Training is one compiled program (``jax.jit(jax.vmap(train))``) with no progress output; on a
small shared CPU it takes long, so lower ``--timesteps`` or ``--seeds`` for a quick look. The
committed run, its command and wall time: ``results/examples/jaxmarl_ippo.json``.

The pieces, as in JaxMARL: ``make_train(config)`` returns ``train(rng)``, which ``jax.vmap``
runs for several seeds; one actor-critic MLP shared by the ports (the agent index and kind
one-hot in each observation tell them apart) and one for the batteries; ``batchify`` /
``unbatchify`` between the env's dicts and the ``(agents * envs, ...)`` rows; logits masked by
``get_avail_actions``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import NamedTuple

import distrax
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax.linen.initializers import constant, variance_scaling
from flax.training.train_state import TrainState

from chargax_marl.core.observation import PORT_FEATURES
from chargax_marl.core.params import make_params
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.evaluation import run_days, split_days
from chargax_marl.marl import ChargaxMARL, LogWrapper
from chargax_marl.policies import get_policy
from chargax_marl.wrappers import (
    BatteryShaping,
    CarPlanShaping,
    PlanAdviceObservation,
    RelativePriceObservation,
)

CONFIG = {
    "LR": 2.5e-4,
    "NUM_ENVS": 12,
    "NUM_STEPS": 300,
    "TOTAL_TIMESTEPS": 6e5,
    "UPDATE_EPOCHS": 4,
    "NUM_MINIBATCHES": 4,
    "GAMMA": 0.9,
    "GAE_LAMBDA": 0.95,
    "CLIP_EPS": 0.2,
    "VF_CLIP": 10.0,
    "ENT_COEF": 0.01,
    "BATTERY_ENT_COEF": 0.05,  # the battery agents' entropy bonus: keep them exploring longer
    "VF_COEF": 0.25,
    "MAX_GRAD_NORM": 100.0,
    "HIDDEN": 256,
    "ACTIVATION": "tanh",
    "ANNEAL_LR": True,
    "LOCAL_REWARD_WEIGHT": 1.0,  # each agent learns from its own share of the station's reward
    "ENV_KWARGS": {"num_levels": 1},  # full-power actions: discharge / idle / charge
    "NUM_EVAL_DAYS": 100,
    "SPLIT_SEED": 0,
}

BATTERY_COL = len(PORT_FEATURES) + KIND_BATTERY  # the battery column of the kind one-hot


def _init(gain: float):
    # the variance of an orthogonal init of this gain; orthogonal's batched QR under vmap over
    # seeds can stall XLA's CPU thread pool on small machines
    return variance_scaling(gain**2, "fan_in", "normal")


class ActorCritic(nn.Module):
    action_dim: int
    hidden: int = 256
    activation: str = "tanh"

    @nn.compact
    def __call__(self, x):
        act = nn.relu if self.activation == "relu" else nn.tanh
        a = act(nn.Dense(self.hidden, kernel_init=_init(np.sqrt(2)), bias_init=constant(0.0))(x))
        a = act(nn.Dense(self.hidden, kernel_init=_init(np.sqrt(2)), bias_init=constant(0.0))(a))
        logits = nn.Dense(self.action_dim, kernel_init=_init(0.01), bias_init=constant(0.0))(a)
        c = act(nn.Dense(self.hidden, kernel_init=_init(np.sqrt(2)), bias_init=constant(0.0))(x))
        c = act(nn.Dense(self.hidden, kernel_init=_init(np.sqrt(2)), bias_init=constant(0.0))(c))
        value = nn.Dense(1, kernel_init=_init(1.0), bias_init=constant(0.0))(c)
        return logits, jnp.squeeze(value, axis=-1)


class Transition(NamedTuple):
    done: jnp.ndarray
    action: jnp.ndarray
    value: jnp.ndarray
    reward: jnp.ndarray
    log_prob: jnp.ndarray
    obs: jnp.ndarray
    avail: jnp.ndarray
    info: dict


def batchify(x: dict, agent_list, num_actors):
    return jnp.stack([x[a] for a in agent_list]).reshape((num_actors, -1))


def unbatchify(x: jnp.ndarray, agent_list, num_envs):
    x = x.reshape((len(agent_list), num_envs) + x.shape[1:])
    return {a: x[i] for i, a in enumerate(agent_list)}


def env_params(config):
    """``(train_params, eval_params, eval_days)``: training resets draw the training days only."""
    full = make_params(**config["ENV_KWARGS"])
    train_days, eval_days = split_days(
        int(full.num_days), config["NUM_EVAL_DAYS"], seed=config["SPLIT_SEED"]
    )
    return make_params(**config["ENV_KWARGS"], reset_days=train_days), full, eval_days


def wrap(env):
    """The teachers: shaping of the battery and the cars' plans, plan advice and relative prices."""
    shaped = CarPlanShaping(BatteryShaping(env, "dp"))
    return RelativePriceObservation(PlanAdviceObservation(shaped))


def apply_policy(network, params, obs, avail):
    """Masked logits and values of rows ``obs (..., obs)``; battery rows read the battery net."""
    logits, value = network.apply(params["ports"], obs)
    b_logits, b_value = network.apply(params["battery"], obs)
    is_bat = obs[..., BATTERY_COL] > 0.5
    logits = jnp.where(is_bat[..., None], b_logits, logits)
    return jnp.where(avail, logits, -1e9), jnp.where(is_bat, b_value, value)


def make_train(config, train_params=None):
    config = {**CONFIG, **config}
    train_params = env_params(config)[0] if train_params is None else train_params
    env = ChargaxMARL(params=train_params, local_reward_weight=config["LOCAL_REWARD_WEIGHT"])
    env = LogWrapper(wrap(env))
    agents, num_agents, num_envs = env.agents, env.num_agents, config["NUM_ENVS"]
    num_actors = num_agents * num_envs
    num_updates = int(config["TOTAL_TIMESTEPS"]) // config["NUM_STEPS"] // num_envs
    masks = env.get_avail_actions(None)  # depends on the station only
    avail_b = batchify(
        {a: jnp.broadcast_to(m, (num_envs,) + m.shape) for a, m in masks.items()},
        agents,
        num_actors,
    )
    network = ActorCritic(env.action_space(agents[0]).n, config["HIDDEN"], config["ACTIVATION"])

    def linear_schedule(count):
        frac = 1.0 - (count // (config["NUM_MINIBATCHES"] * config["UPDATE_EPOCHS"])) / num_updates
        return config["LR"] * frac

    def train(rng):
        rng, k_ports, k_battery = jax.random.split(rng, 3)
        init_x = jnp.zeros(env.observation_space(agents[0]).shape)
        params = {
            "ports": network.init(k_ports, init_x),
            "battery": network.init(k_battery, init_x),
        }
        lr = linear_schedule if config["ANNEAL_LR"] else config["LR"]
        tx = optax.chain(
            optax.clip_by_global_norm(config["MAX_GRAD_NORM"]), optax.adam(lr, eps=1e-5)
        )
        train_state = TrainState.create(apply_fn=network.apply, params=params, tx=tx)
        rng, _rng = jax.random.split(rng)
        obsv, env_state = jax.vmap(env.reset)(jax.random.split(_rng, num_envs))

        def _update_step(runner_state, unused):
            def _env_step(runner_state, unused):
                train_state, env_state, last_obs, rng = runner_state
                obs_batch = batchify(last_obs, agents, num_actors)
                rng, _rng = jax.random.split(rng)
                logits, value = apply_policy(network, train_state.params, obs_batch, avail_b)
                pi = distrax.Categorical(logits=logits)
                action = pi.sample(seed=_rng)
                log_prob = pi.log_prob(action)
                env_act = unbatchify(action, agents, num_envs)
                rng, _rng = jax.random.split(rng)
                obsv, env_state, reward, done, info = jax.vmap(env.step)(
                    jax.random.split(_rng, num_envs), env_state, env_act
                )
                info = {
                    k: info[k][:, 0]  # every agent logs the same episode
                    for k in ("returned_episode", "returned_episode_profit_eur")
                }
                transition = Transition(
                    batchify(done, agents, num_actors).squeeze(-1),
                    action,
                    value,
                    batchify(reward, agents, num_actors).squeeze(-1),
                    log_prob,
                    obs_batch,
                    avail_b,
                    info,
                )
                return (train_state, env_state, obsv, rng), transition

            runner_state, traj_batch = jax.lax.scan(
                _env_step, runner_state, None, config["NUM_STEPS"]
            )
            train_state, env_state, last_obs, rng = runner_state
            last_obs_batch = batchify(last_obs, agents, num_actors)
            _, last_val = apply_policy(network, train_state.params, last_obs_batch, avail_b)

            def _calculate_gae(traj_batch, last_val):
                def _get_advantages(gae_and_next_value, transition):
                    gae, next_value = gae_and_next_value
                    done = transition.done.astype(jnp.float32)
                    delta = (
                        transition.reward
                        + config["GAMMA"] * next_value * (1 - done)
                        - transition.value
                    )
                    gae = delta + config["GAMMA"] * config["GAE_LAMBDA"] * (1 - done) * gae
                    return (gae, transition.value), gae

                _, advantages = jax.lax.scan(
                    _get_advantages, (jnp.zeros_like(last_val), last_val), traj_batch, reverse=True
                )
                return advantages, advantages + traj_batch.value

            advantages, targets = _calculate_gae(traj_batch, last_val)
            # each agent's advantages to mean 0 and std 1 over its own rows: a battery's
            # advantages (cents) would otherwise be scaled by the ports' spread (euros)
            per_agent = advantages.reshape((config["NUM_STEPS"], num_agents, num_envs))
            per_agent = (per_agent - per_agent.mean(axis=(0, 2), keepdims=True)) / (
                per_agent.std(axis=(0, 2), keepdims=True) + 1e-8
            )
            advantages = per_agent.reshape(advantages.shape)

            def _update_epoch(update_state, unused):
                def _update_minbatch(train_state, batch_info):
                    traj_batch, advantages, targets = batch_info

                    def _loss_fn(params, traj_batch, gae, targets):
                        logits, value = apply_policy(
                            network, params, traj_batch.obs, traj_batch.avail
                        )
                        pi = distrax.Categorical(logits=logits)
                        log_prob = pi.log_prob(traj_batch.action)
                        value_pred_clipped = traj_batch.value + (value - traj_batch.value).clip(
                            -config["VF_CLIP"], config["VF_CLIP"]
                        )
                        value_losses = jnp.square(value - targets)
                        value_losses_clipped = jnp.square(value_pred_clipped - targets)
                        value_loss = 0.5 * jnp.maximum(value_losses, value_losses_clipped).mean()
                        ratio = jnp.exp(log_prob - traj_batch.log_prob)
                        gae = (gae - gae.mean()) / (gae.std() + 1e-8)
                        eps = config["CLIP_EPS"]
                        clipped = jnp.clip(ratio, 1.0 - eps, 1.0 + eps)
                        loss_actor = -jnp.minimum(ratio * gae, clipped * gae).mean()
                        is_bat = traj_batch.obs[:, BATTERY_COL] > 0.5
                        ent_coef = jnp.where(is_bat, config["BATTERY_ENT_COEF"], config["ENT_COEF"])
                        entropy = pi.entropy()
                        total_loss = (
                            loss_actor
                            + config["VF_COEF"] * value_loss
                            - (ent_coef * entropy).mean()
                        )
                        return total_loss, (value_loss, loss_actor, entropy.mean())

                    grad_fn = jax.value_and_grad(_loss_fn, has_aux=True)
                    total_loss, grads = grad_fn(train_state.params, traj_batch, advantages, targets)
                    train_state = train_state.apply_gradients(grads=grads)
                    loss_info = {
                        "total_loss": total_loss[0],
                        "critic_loss": total_loss[1][0],
                        "actor_loss": total_loss[1][1],
                        "entropy": total_loss[1][2],
                    }
                    return train_state, loss_info

                train_state, traj_batch, advantages, targets, rng = update_state
                rng, _rng = jax.random.split(rng)
                batch_size = config["NUM_STEPS"] * num_actors
                # shuffle (step, env) pairs, each with all of its agents' rows (agent-major
                # actors): a permutation num_agents times smaller than one over the rows
                unit = jax.random.permutation(_rng, config["NUM_STEPS"] * num_envs)
                step, env_i = unit // num_envs, unit % num_envs
                permutation = (
                    step[:, None] * num_actors
                    + jnp.arange(num_agents)[None, :] * num_envs
                    + env_i[:, None]
                ).reshape(-1)
                batch = jax.tree.map(
                    lambda x: x.reshape((batch_size,) + x.shape[2:]),
                    (traj_batch._replace(info={}), advantages, targets),
                )
                minibatches = jax.tree.map(
                    lambda x: jnp.take(x, permutation, axis=0).reshape(
                        (config["NUM_MINIBATCHES"], -1) + x.shape[1:]
                    ),
                    batch,
                )
                train_state, loss_info = jax.lax.scan(_update_minbatch, train_state, minibatches)
                return (train_state, traj_batch, advantages, targets, rng), loss_info

            update_state = (train_state, traj_batch, advantages, targets, rng)
            update_state, loss_info = jax.lax.scan(
                _update_epoch, update_state, None, config["UPDATE_EPOCHS"]
            )
            train_state, rng = update_state[0], update_state[-1]
            ended = traj_batch.info["returned_episode"]
            metric = {k: v.mean() for k, v in loss_info.items()}
            profit = traj_batch.info["returned_episode_profit_eur"]
            metric["episode_profit_eur"] = jnp.where(
                ended.any(), (profit * ended).sum() / jnp.maximum(ended.sum(), 1), jnp.nan
            )
            return (train_state, env_state, last_obs, rng), metric

        rng, _rng = jax.random.split(rng)
        runner_state = (train_state, env_state, obsv, _rng)
        runner_state, metric = jax.lax.scan(_update_step, runner_state, None, num_updates)
        return {"runner_state": runner_state, "metrics": metric}

    train.env, train.network, train.num_updates = env, network, num_updates
    return train


def greedy_act(network, params, eval_params):
    """``act(state, key) -> levels`` for `chargax_marl.evaluation.run_days`: every agent takes
    the argmax of its masked logits, on the observations the training env's wrappers build."""
    env = wrap(ChargaxMARL(params=eval_params))
    avail = jnp.stack([m for m in env.get_avail_actions(None).values()])

    def act(state, key):
        obs = env.get_obs(state)
        logits, _ = apply_policy(network, params, jnp.stack([obs[a] for a in env.agents]), avail)
        return env.actions_to_levels(jnp.argmax(logits, axis=-1))

    return act


def paired(profit, reference) -> dict:
    """Mean and standard error over days of ``profit - reference`` (EUR/day); ``profit`` may
    have a leading seed axis (then pooled over seeds and days, and per seed)."""
    d = np.atleast_2d(profit) - np.asarray(reference)[None, :]
    return {
        "mean": float(d.mean()),
        "stderr": float(d.std(ddof=1) / np.sqrt(d.size)),
        "per_seed_mean": [float(x) for x in d.mean(axis=1)],
        "per_seed_stderr": [float(x) for x in d.std(axis=1, ddof=1) / np.sqrt(d.shape[1])],
    }


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--timesteps", type=float, default=CONFIG["TOTAL_TIMESTEPS"])
    p.add_argument("--out", default=None, help="write the result as JSON here")
    a = p.parse_args(argv)
    config = {**CONFIG, "TOTAL_TIMESTEPS": a.timesteps}
    train_params, eval_params, eval_days = env_params(config)
    t0 = time.time()
    train = make_train(config, train_params)
    rngs = jax.random.split(jax.random.PRNGKey(0), a.seeds)
    out = jax.block_until_ready(jax.jit(jax.vmap(train))(rngs))
    train_s = time.time() - t0
    key, days = jax.random.PRNGKey(0), jnp.asarray(eval_days)
    profit = {}

    def daily_profit(act):
        totals = jax.jit(lambda d, k: run_days(act, eval_params, d, k))(days, key)
        return np.asarray(totals.profit_eur, np.float64)

    for name in ("always_max", "battery_rule", "battery_programme"):
        policy = get_policy(name, eval_params)
        profit[name] = daily_profit(lambda s, k, policy=policy: policy(s, k, eval_params))
    seeds = []
    for i in range(a.seeds):
        params = jax.tree.map(lambda x, i=i: x[i], out["runner_state"][0].params)
        seeds.append(daily_profit(greedy_act(train.network, params, eval_params)))
    ippo = np.stack(seeds)
    args = sys.argv[1:] if argv is None else list(argv)
    steps = train.num_updates * config["NUM_STEPS"] * config["NUM_ENVS"]
    result = {
        "command": " ".join(["python", "examples/jaxmarl_ippo.py"] + args),
        "seeds": a.seeds,
        "timesteps_per_seed": steps,
        "train_wall_s": round(train_s, 1),
        "total_wall_s": round(time.time() - t0, 1),
        "eval": {
            "days": len(eval_days),
            "key": 0,
            "always_max_eur_day": float(profit["always_max"].mean()),
            "ippo_eur_day": float(ippo.mean()),
        },
        "vs_battery_rule": paired(ippo, profit["battery_rule"]),
        "vs_always_max": paired(ippo, profit["always_max"]),
        "battery_rule_vs_always_max": paired(profit["battery_rule"], profit["always_max"]),
        "battery_programme_vs_always_max": paired(
            profit["battery_programme"], profit["always_max"]
        ),
        "ippo_vs_battery_programme": paired(ippo, profit["battery_programme"]),
        "config": config,
    }
    print(
        f"IPPO, {a.seeds} seeds x {steps:.3g} steps, trained in {train_s:.0f} s; "
        f"{len(eval_days)} held-out days, key 0"
    )
    for name in (
        "vs_battery_rule",
        "vs_always_max",
        "battery_rule_vs_always_max",
        "battery_programme_vs_always_max",
        "ippo_vs_battery_programme",
    ):
        r = result[name]
        print(
            f"  {name:<32} {r['mean']:+7.2f} ± {r['stderr']:.2f} EUR/day (per seed "
            + ", ".join(f"{m:+.2f}" for m in r["per_seed_mean"])
            + ")"
        )
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
