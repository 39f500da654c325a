"""Single-agent PPO for `chargax_marl.single.Chargax`, in the PureJaxRL style.

``train = make_train(config)`` gives a jittable ``train(key)``; ``jax.jit(jax.vmap(train))(keys)``
trains several seeds in one compiled program. The whole loop (rollout with ``jax.lax.scan``,
GAE, clipped PPO epochs over shuffled minibatches) is JAX. Defaults are the paper's Table 3.

Policy: one categorical head per port/battery over its action indices (a factored
``MultiDiscrete``); the joint log-probability is the sum over heads, the entropy the sum of
the heads' entropies. Leaves with fewer valid indices (no V2G) have the rest masked.
Actor and critic are separate MLPs (``NUM_LAYERS`` x ``HIDDEN``, tanh; 2 x 256 by default).
``train.init(key)`` and ``train.run_updates(state, n)`` expose the same loop in pieces (the
CLI evaluates on held-out days between chunks).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from baselines.algos import aids, networks, ppo_core, runner
from baselines.algos.trainer import IdentityCache, Trainer
from baselines.config import build_env_params, resolve
from chargax_marl.core.observation import context_size, flat_obs
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.policies import always_max
from chargax_marl.single.env import Chargax
from chargax_marl.single.wrappers import LogWrapper
from chargax_marl.teachers import car_plan, prices
from chargax_marl.teachers import shaping as teacher_shaping


class Transition(NamedTuple):
    """One rollout step of every env.

    Attributes:
        obs: ``(envs, obs)`` the observations (with the plan advice when ``PLAN_OBS`` is
            on).
        action: ``(envs, leaves)`` the sampled action index of every head.
        log_prob: ``(envs,)`` the joint log-probability (summed over heads), or
            ``(envs, 2)`` the ports' and the batteries' parts with ``SPLIT_CREDIT``.
        value: ``(envs,)`` the critic's values, or ``(envs, 2)`` with ``SPLIT_CREDIT``.
        reward: the rewards, shaped and times ``REWARD_SCALE``, shaped as ``value``.
        done: ``(envs,)`` 1.0 where the episode ended (terminated or truncated).
        info: the `INFO_KEYS` of the step's infos.
    """

    obs: jnp.ndarray
    action: jnp.ndarray
    log_prob: jnp.ndarray  # joint (summed over heads)
    value: jnp.ndarray
    reward: jnp.ndarray
    done: jnp.ndarray
    info: dict


class RunnerState(NamedTuple):
    """The state the training loop carries from update to update (one seed).

    Attributes:
        params: the networks' parameters (`Policy.init`).
        opt_state: the optimiser's state (`baselines.algos.ppo_core.Optimizer`).
        env_state: the wrapped envs' states, leading axis the envs.
        obs: ``(envs, obs_dim)`` the current observations.
        key: the PRNG key.
        update: the index of the next update (int32 scalar).
        hyper: the values of `baselines.algos.ppo_core.HYPER_KEYS` (float32 scalars).
    """

    params: dict
    opt_state: object
    env_state: object
    obs: jnp.ndarray
    key: jnp.ndarray
    update: jnp.ndarray
    hyper: dict  # ppo_core.HYPER_KEYS as float32 scalars


INFO_KEYS = (
    "returned_episode",
    "returned_episode_returns",
    "returned_episode_profit_eur",
    "returned_episode_energy_delivered_kwh",
)


class Policy:
    """The factored categorical policy and the critic of a single-agent env.

    Args:
        config: the resolved config (``HIDDEN``, ``NUM_LAYERS``, ``ACTIVATION``,
            ``SPLIT_CREDIT``, ``ALWAYS_MAX_PRIOR``, ``BATTERY_IDLE_PRIOR``,
            ``RELATIVE_PRICES``, ``PLAN_OBS``).
        env: the single-agent env (its ``MultiDiscrete`` action space).
        env_params: the training env's parameters.

    Raises:
        ValueError: ``SPLIT_CREDIT`` on a station without a battery, a negative or
            non-finite prior offset, or an unknown ``PLAN_OBS``.
    """

    def __init__(self, config: dict, env: Chargax, env_params):
        nvec = np.asarray(env.action_space(env_params).nvec)
        self.num_leaves, self.k = len(nvec), int(nvec.max())
        self.mask = np.arange(self.k)[None, :] < nvec[:, None]
        self.obs_dim = env.observation_space(env_params).shape[0]
        # SPLIT_CREDIT: two parts of the reward, the ports' and the batteries' shares, each with
        # its own value; the port heads learn from the first advantage, the battery heads from
        # the second (one critic network with two outputs).
        self.is_battery = np.asarray(env_params.station.leaf_kind) == KIND_BATTERY
        self.split = bool(config["SPLIT_CREDIT"])
        if self.split and not self.is_battery.any():
            raise ValueError(
                "SPLIT_CREDIT=True needs a station with a battery; this station has none"
            )
        self.actor, self.critic = networks.actor_critic(
            config, self.num_leaves * self.k, 2 if self.split else 1
        )
        # ALWAYS_MAX_PRIOR / BATTERY_IDLE_PRIOR: fixed offsets on the index of the always-max
        # baseline's action of every head (ports: full power; batteries: idle).
        baseline = np.asarray(env.levels_to_action(always_max(None, None, env_params), env_params))
        port_b, battery_b = networks.always_max_prior(config)
        offset = np.zeros((self.num_leaves, self.k), np.float32)
        offset[np.arange(self.num_leaves), baseline] = np.where(self.is_battery, battery_b, port_b)
        self.offset = offset
        # RELATIVE_PRICES: each observed price's place in the day's range appended to the input
        # (chargax_marl.teachers.prices.relative_prices); the observation ends with the shared context.
        self.relative = None
        if config["RELATIVE_PRICES"]:
            self.relative = prices.relative_price_columns(
                env_params, self.obs_dim - context_size(env_params)
            )
        # PLAN_OBS: the observation also ends with every leaf's advice (aids.plan_features),
        # leaf-major, before the relative prices.
        self.plan_config = {"PLAN_OBS": config.get("PLAN_OBS", False)}
        features = aids.plan_features(self.plan_config, env_params)
        self.plan, plan_width = (None, 0) if features is None else features
        self.input_dim = (
            self.obs_dim
            + self.num_leaves * plan_width
            + (0 if self.relative is None else len(self.relative[0]))
        )

    def plan_for(self, env_params):
        """The `PLAN_OBS` advice read from ``env_params``' prices, for a policy played on
        parameters other than the training env's (a shift task's held-out year).

        Args:
            env_params: concrete `chargax_marl.core.types.EnvParams` of the env played.

        Returns:
            ``advice(core) -> (L, width)`` (`baselines.algos.aids.plan_features`), or None
            when ``PLAN_OBS`` is off.
        """
        if self.plan is None:
            return None
        return aids.plan_features(self.plan_config, env_params)[0]

    def with_plan(self, obs, core, plan=None):
        """``obs (..., obs_dim)`` with the plan advice of the (batched) core state ``core``
        appended when ``PLAN_OBS`` is on.

        Args:
            obs: ``(..., obs_dim)`` observations.
            core: the core state (`chargax_marl.core.types.EnvState`) with the same leading
                axes.
            plan: the advice to read (`plan_for`); None: the training env's.

        Returns:
            ``(..., obs_dim + leaves * width)``, every leaf's advice leaf-major, or ``obs``
            itself.
        """
        if self.plan is None:
            return obs
        plan = self.plan if plan is None else plan
        advice = car_plan.batched(plan, core)(core)  # (..., L, width)
        return jnp.concatenate([obs, advice.reshape(advice.shape[:-2] + (-1,))], axis=-1)

    def features(self, obs):
        """The networks' input: ``obs`` with the relative prices when ``RELATIVE_PRICES``
        is on.

        Args:
            obs: ``(..., obs)`` observations.

        Returns:
            ``(..., obs + H + 1)`` (`chargax_marl.teachers.prices.with_relative_prices`), or
            ``obs`` itself.
        """
        return prices.with_relative_prices(obs, self.relative)

    def init(self, key):
        """Fresh parameters of the networks.

        Args:
            key: a PRNG key.

        Returns:
            ``{"actor", "critic"}`` flax parameters.
        """
        ka, kc = jax.random.split(key)
        x = jnp.zeros((self.input_dim,), jnp.float32)
        return {"actor": self.actor.init(ka, x), "critic": self.critic.init(kc, x)}

    def logits(self, params, obs):
        """The masked logits of every head.

        Args:
            params: the networks' parameters (`init`).
            obs: ``(..., obs)`` observations, as `with_plan` returns them.

        Returns:
            ``(..., leaves, K)`` logits, with the prior offsets added and the indices a
            leaf does not have at `baselines.algos.networks.NEG_INF`.
        """
        raw = self.actor.apply(params["actor"], self.features(obs))
        return networks.masked_logits(
            raw.reshape(raw.shape[:-1] + (self.num_leaves, self.k)) + self.offset, self.mask
        )

    def value(self, params, obs):
        """``(...)``, or ``(..., 2)`` (ports, batteries) with ``SPLIT_CREDIT``.

        Args:
            params: the networks' parameters (`init`).
            obs: ``(..., obs)`` observations, as `with_plan` returns them.

        Returns:
            The critic's values, ``(...)`` or ``(..., 2)``.
        """
        v = self.critic.apply(params["critic"], self.features(obs))
        return v if self.split else v[..., 0]

    def credit_logp(self, head_logp):
        """The log-probability of the joint action ``(...)``, or with ``SPLIT_CREDIT`` that of
        the ports' and the batteries' parts ``(..., 2)``.

        Args:
            head_logp: ``(..., leaves)`` each head's log-probability.

        Returns:
            ``(...)`` their sum, or ``(..., 2)`` the sums over the ports' and the batteries'
            heads.
        """
        if not self.split:
            return head_logp.sum(-1)
        bat = jnp.asarray(self.is_battery)
        return jnp.stack(
            [jnp.where(bat, 0.0, head_logp).sum(-1), jnp.where(bat, head_logp, 0.0).sum(-1)], -1
        )


# The multi-agent trainers' settings single-agent PPO refuses: (key, its off value, why).
_MULTI_AGENT_ONLY = (
    ("PRIORITY_FILL", False, "it reads their agents' charging actions as priorities"),
    ("RESIDUAL", "off", "it centres each agent's actor on the rule's level"),
    ("STATION_OBS", False, "the single agent observes every port already"),
    ("DISTILL", "off", "it fits each agent's actor to the MPC's level for its leaf"),
)


def make_train(config: dict | None = None, env_params=None):
    """Build ``train(key)`` for a config (keys of `baselines.algos.PAPER_DEFAULTS`).

    ``env_params`` defaults to the config's scenario restricted to its training days.

    Args:
        config: the config (resolved with `baselines.config.resolve`; None: the defaults).
        env_params: the training env's parameters; None: the config's
            (`baselines.config.build_env_params`).

    Returns:
        The `baselines.algos.trainer.Trainer`.

    Raises:
        ValueError: a setting of the multi-agent trainers only (``LOCAL_REWARD_WEIGHT``,
            ``OBS_DELAY_STEPS``, ``ACTION_LOSS_PROB``, ``PRIORITY_FILL``),
            ``NUM_ENVS * NUM_STEPS`` not divisible by ``NUM_MINIBATCHES``, ``NUM_ENVS`` not
            divisible by the number of devices, ``TOTAL_TIMESTEPS`` less than one rollout,
            or a learning aid's setting refused (`baselines.algos.aids`).
    """
    config = resolve(
        {**{"RELATIVE_PRICES": False, "SPLIT_CREDIT": False, "PLAN_OBS": False}, **(config or {})}
    )
    if config["LOCAL_REWARD_WEIGHT"]:
        raise ValueError(
            f"LOCAL_REWARD_WEIGHT={config['LOCAL_REWARD_WEIGHT']} applies to the multi-agent "
            "trainers (ippo, mappo) only; single-agent PPO learns from the station reward (use 0)"
        )
    for key, off in (("OBS_DELAY_STEPS", 0), ("ACTION_LOSS_PROB", 0.0)):
        if config.get(key, off) != off:
            raise ValueError(
                f"{key}={config[key]} applies to the multi-agent trainers (ippo, mappo) only: "
                "single-agent PPO has one controller and nothing to communicate (use "
                f"{off})"
            )
    for key, off, why in _MULTI_AGENT_ONLY:
        value = config.get(key, off)
        if value != off:
            shown, off_shown = (
                ("true" if value is True else repr(value)),
                ("false" if off is False else repr(off)),
            )
            raise ValueError(
                f"{key}={shown} applies to the multi-agent trainers (ippo, mappo) only: {why} "
                f"(use {off_shown})"
            )
    if env_params is None:
        env_params = build_env_params(config)[0]
    base_env = Chargax(params=env_params)
    env = LogWrapper(aids.fairness(config, base_env))  # FAIRNESS_WEIGHT (off: the env itself)
    policy = Policy(config, base_env, env_params)
    n_envs, n_steps = config["NUM_ENVS"], config["NUM_STEPS"]
    total_updates = ppo_core.num_updates(config)
    batch = n_envs * n_steps
    if batch % config["NUM_MINIBATCHES"]:
        raise ValueError(
            f"NUM_ENVS*NUM_STEPS={batch} must be divisible by NUM_MINIBATCHES={config['NUM_MINIBATCHES']}"
        )
    mesh = runner.env_mesh(n_envs)
    tx = ppo_core.make_optimizer(config, total_updates)
    potential = aids.battery_potential(config, env_params)  # BATTERY_SHAPING
    car_potential = aids.car_potential(config, env_params)  # PORT_SHAPING
    v_reset = jax.vmap(env.reset, in_axes=(0, None))
    v_step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def init(key, hyper=None):
        k_net, k_env, key = jax.random.split(key, 3)
        params = policy.init(k_net)
        obs, env_state = v_reset(jax.random.split(k_env, n_envs), env_params)
        obs, env_state = runner.shard_envs((obs, env_state), mesh)
        hyper = ppo_core.hyper_values(config) if hyper is None else hyper
        return RunnerState(
            params, tx.init(params), env_state, obs, key, jnp.zeros((), jnp.int32), hyper
        )

    def env_step(hyper, carry, _):
        params, env_state, obs, key = carry
        key, k_act, k_step = jax.random.split(key, 3)
        obs = policy.with_plan(obs, teacher_shaping.core_state(env_state))
        logits = policy.logits(params, obs)
        action, head_logp = networks.sample_categorical(k_act, logits)  # (envs, leaves)
        logp = policy.credit_logp(head_logp)
        value = policy.value(params, obs)
        pot = (
            None if potential is None else potential(env_state)
        )  # before the (auto-resetting) step
        car_pot = None if car_potential is None else car_potential(env_state)
        next_obs, env_state, reward, term, trunc, info = v_step(
            jax.random.split(k_step, n_envs), env_state, action, env_params
        )
        battery_term = (
            0.0
            if pot is None
            else teacher_shaping.battery_shaping(
                pot(info["battery_net_kwh"]), info["battery_terminal_value_eur"]
            )
        )
        port_shaping = (
            0.0 if car_pot is None else jnp.sum(car_pot(info["leaf_energy_kwh"]), axis=-1)
        )
        battery_term = hyper["SHAPING_WEIGHT"] * battery_term
        port_shaping = hyper["SHAPING_WEIGHT"] * port_shaping
        if (
            policy.split
        ):  # (envs, 2): the ports' share and their shaping, the batteries' share and theirs
            reward = jnp.stack(
                [
                    reward - info["battery_reward_eur"] + port_shaping,
                    info["battery_reward_eur"] + battery_term,
                ],
                -1,
            )
        else:
            reward = reward + battery_term + port_shaping
        next_obs, env_state = runner.shard_envs((next_obs, env_state), mesh)
        done = jnp.logical_or(term, trunc)
        tr = Transition(
            obs,
            action,
            logp,
            value,
            reward * hyper["REWARD_SCALE"],
            done.astype(jnp.float32),
            {k: info[k] for k in INFO_KEYS},
        )
        return (params, env_state, next_obs, key), tr

    def loss_fn(hyper, params, mb):
        tr, adv, targets = mb
        logits = policy.logits(params, tr.obs)
        head_logp = networks.log_prob(logits, tr.action)  # (batch, heads)
        ent = networks.entropy(logits).sum(-1)
        values = policy.value(params, tr.obs)
        return ppo_core.ppo_loss(
            policy.credit_logp(head_logp), tr.log_prob, adv, values, tr.value, targets, ent, hyper
        )

    def update(rs: RunnerState, _):
        hyper = rs.hyper
        (params, env_state, obs, key), traj = jax.lax.scan(
            functools.partial(env_step, hyper),
            (rs.params, rs.env_state, rs.obs, rs.key),
            None,
            n_steps,
        )
        last_value = policy.value(
            params, policy.with_plan(obs, teacher_shaping.core_state(env_state))
        )
        done = traj.done[..., None] if policy.split else traj.done
        adv, targets = ppo_core.gae(
            traj.reward, traj.value, done, last_value, hyper["GAMMA"], hyper["GAE_LAMBDA"]
        )
        if policy.split:  # each part's advantages to mean 0 and std 1 over the rollout
            adv = (adv - adv.mean(axis=(0, 1))) / (adv.std(axis=(0, 1)) + 1e-8)

        params, opt_state, key, parts = ppo_core.ppo_epochs(
            functools.partial(loss_fn, hyper), tx, params, rs, key, traj, adv, targets, config
        )
        metrics = {k: v.mean() for k, v in parts.items()}
        metrics.update(ppo_core.episode_metrics(traj.info["returned_episode"], traj.info))
        return RunnerState(params, opt_state, env_state, obs, key, rs.update + 1, hyper), metrics

    def run_updates(rs: RunnerState, n: int):
        return jax.lax.scan(update, rs, None, n)

    return Trainer(
        init=init,
        run_updates=run_updates,
        num_updates=total_updates,
        config=config,
        policy=policy,
        env=base_env,
        env_params=env_params,
        make_act=make_act_builder(policy, base_env),
    )


def make_act_builder(policy: Policy, env: Chargax):
    """``make_act_for(eval_params)(params) -> act(state, key) -> levels``: the greedy (argmax
    per head) policy read from the simulator state, for `chargax_marl.evaluation`.

    Args:
        policy: the trained `Policy`.
        env: the single-agent env (its ``action_to_levels``).

    Returns:
        ``make_act_for(eval_params) -> make_act``, built once per ``eval_params`` object.
    """
    cache = IdentityCache()

    def build(eval_params):
        plan = policy.plan_for(eval_params)  # the advice under the prices played on

        def make_act(params):
            def act(state, key):
                del key
                obs = policy.with_plan(flat_obs(state, eval_params), state, plan)
                action = jnp.argmax(policy.logits(params, obs), axis=-1)
                return env.action_to_levels(action, eval_params)

            return act

        return make_act

    return lambda eval_params: cache.get(eval_params, lambda: build(eval_params))
