"""IPPO for `chargax_marl.marl.ChargaxMARL`, in the JaxMARL style (shared parameters).

One actor and one critic are shared by every agent (port or battery); the agent-index
feature in each observation lets them tell agents apart. The env is stepped through its array
path (``step_arrays``: observations ``(num_agents, obs_dim)`` per env, no per-agent dicts);
the rows are *batchified* into ``(num_agents * num_envs, obs_dim)`` (agent-major, as
JaxMARL's ``batchify``), actions are sampled from the logits masked by
``get_avail_actions`` (invalid logits set to -1e9) and handed back as ``(num_envs,
num_agents)`` indices. All agents receive the shared station reward, or with
``LOCAL_REWARD_WEIGHT`` ``w > 0`` the
mix ``(1 - w) * r + w * share_i`` with their own share of it (see
`chargax_marl.marl.ChargaxMARL`; evaluation always scores the station's profit).
Episodes are logged by `chargax_marl.marl.wrappers.LogWrapper`.
``jax.vmap(train)(keys)`` trains several seeds at once; the env batch is sharded over all
devices (`baselines.algos.shard_envs`).

`make_train` with ``centralised_critic=True`` is MAPPO (see `baselines.algos.mappo`):
the critic then reads the world state of
`chargax_marl.marl.wrappers.WorldStateWrapper` (``global_state``, once per env) instead
of the agent's observation.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from baselines.algos import aids, distill, networks, ppo_core, runner
from baselines.algos.trainer import IdentityCache, Trainer
from baselines.config import build_env_params, resolve
from chargax_marl.core.arrays import device_array
from chargax_marl.core.observation import PORT_FEATURES, context_size
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.marl import env as marl_env
from chargax_marl.marl.communication import communicating_act
from chargax_marl.marl.env import ChargaxMARL
from chargax_marl.marl.wrappers import LogWrapper, WorldStateWrapper
from chargax_marl.teachers import car_plan, prices
from chargax_marl.teachers import shaping as teacher_shaping
from chargax_marl.wrappers import PriorityFill, priority_class_levels, priority_fill_levels


class Transition(NamedTuple):
    """One rollout step of every actor (``actors = agents * envs`` rows, agent-major).

    Attributes:
        obs: ``(actors, obs_dim)`` the actors' observations (with the plan advice when
            ``PLAN_OBS`` is on).
        critic_in: the critic's input: IPPO, an int8 zero placeholder ``(actors,)`` (the
            critic reads ``obs``); MAPPO, the world states ``(envs, state_dim)`` in the
            rollout, and in the update each row's index into the rollout's table of world
            states (or its world state ``(actors, state_dim)`` when
            `DEDUP_CENTRAL_CRITIC` is off).
        avail: ``(actors, K)`` bool, the actions each actor may take.
        action: ``(actors,)`` the sampled action indices.
        log_prob: ``(actors,)`` their log-probabilities.
        value: ``(actors,)`` the critic's values.
        reward: ``(actors,)`` the rewards, shaped and times ``REWARD_SCALE``.
        done: ``(actors,)`` 1.0 where the env's episode ended with the step.
        info: the `INFO_KEYS` of the step's infos, leaves ``(envs, agents)``.
    """

    obs: jnp.ndarray  # (actors, obs_dim)
    # IPPO: a zero placeholder (actors,), the critic reads ``obs``. MAPPO: during the rollout the world state
    # (envs, state_dim), once per env; for the update the row's index into the rollout's
    # table of world states (`make_train`), or its world state (actors, state_dim)
    # when ``DEDUP_CENTRAL_CRITIC`` is off.
    critic_in: jnp.ndarray
    avail: jnp.ndarray
    action: jnp.ndarray
    log_prob: jnp.ndarray
    value: jnp.ndarray
    reward: jnp.ndarray
    done: jnp.ndarray
    info: dict


class RunnerState(NamedTuple):
    """The state the training loop carries from update to update (one seed).

    Attributes:
        params: the networks' parameters (`SharedPolicy.init`).
        opt_state: the optimiser's state (`baselines.algos.ppo_core.Optimizer`).
        env_state: the wrapped envs' states, leading axis the envs.
        obs: ``(envs, agents, obs_dim)`` the current observations.
        key: the PRNG key.
        update: the index of the next update (int32 scalar).
        hyper: the values of `baselines.algos.ppo_core.HYPER_KEYS` (float32 scalars).
    """

    params: dict
    opt_state: object
    env_state: object
    obs: jnp.ndarray  # (envs, agents, obs_dim)
    key: jnp.ndarray
    update: jnp.ndarray
    hyper: dict  # ppo_core.HYPER_KEYS as float32 scalars


INFO_KEYS = (
    "returned_episode",
    "returned_episode_returns",
    "returned_episode_profit_eur",
    "returned_episode_energy_delivered_kwh",
)

# MAPPO: every agent of an env sees the same world state, so the centralised critic runs once
# per (step, env) and its value is shared by the env's agents, in the rollout and in the
# update (the minibatch rows then gather their values from the rollout's table). Exactly the
# same function and gradients; only the order of floating-point sums differs. ``False``
# evaluates the critic once per agent row (the JaxMARL layout); kept for the equivalence test.
DEDUP_CENTRAL_CRITIC = True


def agent_major(x: jnp.ndarray) -> jnp.ndarray:
    """``(envs, agents, ...)`` -> ``(agents * envs, ...)``, agent-major rows (JaxMARL's
    ``batchify`` of a per-agent dict).

    Args:
        x: ``(envs, agents, ...)`` an array per env and agent.

    Returns:
        ``(agents * envs, ...)``, row ``agent * envs + env``.
    """
    x = jnp.swapaxes(x, 0, 1)
    return x.reshape((x.shape[0] * x.shape[1],) + x.shape[2:])


def env_major(x: jnp.ndarray, num_agents: int, num_envs: int) -> jnp.ndarray:
    """``(agents * envs, ...)`` agent-major rows -> ``(envs, agents, ...)``.

    Args:
        x: ``(agents * envs, ...)`` agent-major rows (`agent_major`).
        num_agents: the agents per env.
        num_envs: the envs.

    Returns:
        ``(envs, agents, ...)``, the inverse of `agent_major`.
    """
    return jnp.swapaxes(x.reshape((num_agents, num_envs) + x.shape[1:]), 0, 1)


class SharedPolicy:
    """The shared actor (masked ``Discrete``) and critic.

    Args:
        config: the resolved config (``HIDDEN``, ``NUM_LAYERS``, ``ACTIVATION``,
            ``ALWAYS_MAX_PRIOR``, ``BATTERY_IDLE_PRIOR``, ``BATTERY_NET``,
            ``RELATIVE_PRICES``, ``PLAN_OBS``).
        env: the multi-agent env whose action space the agents act in (a
            `chargax_marl.wrappers.PriorityFill` with ``PRIORITY_CLASSES``).
        centralised_critic: the critic reads the world state (MAPPO), not the agent's own
            observation (IPPO).

    Raises:
        ValueError: a negative or non-finite prior offset, or an unknown ``PLAN_OBS``.
    """

    def __init__(self, config: dict, env: ChargaxMARL, centralised_critic: bool):
        self.k = env.num_actions
        self.obs_dim = env.obs_size
        self.critic_dim = env.state_size if centralised_critic else env.obs_size
        self.actor, self.critic = networks.actor_critic(config, self.k)
        # ALWAYS_MAX_PRIOR / BATTERY_IDLE_PRIOR: fixed offsets on the always-max baseline's
        # action, chosen per agent by the kind one-hot of its observation (after the leaf
        # features): index k - 1 (full power) for ports, the idle index (level 0) for batteries.
        port_b, battery_b = networks.always_max_prior(config)
        port_row = np.zeros(self.k, np.float32)
        port_row[self.k - 1] = port_b
        battery_row = np.zeros(self.k, np.float32)
        battery_row[env.action_offset] = battery_b
        self.port_offset, self.battery_offset = port_row, battery_row
        self.battery_col = len(PORT_FEATURES) + KIND_BATTERY
        # BATTERY_NET: the battery agents get their own actor (and, with a critic on the agent's
        # own observation, their own critic) instead of the ports' network with a kind feature.
        # With one shared actor the battery's discharge index is the ports' (V2G) discharge,
        # which the 16 ports learn to avoid, and that carried over to the battery.
        self.battery_net = bool(config["BATTERY_NET"])
        self.battery_critic = self.battery_net and not centralised_critic
        self.num_agents = env.num_agents
        self.num_batteries = int(env.params.station.num_batteries)  # the last agents
        # RELATIVE_PRICES: each observed price (now and the next hours) also as its place in the
        # day's range, (p - median) / (q80 - q20), appended to the actor's and the critic's input.
        self.relative = None
        if config["RELATIVE_PRICES"]:  # the context sits just before the agent index
            id_width = int(np.shape(env._layout.agent_id)[1])
            self.relative = prices.relative_price_columns(
                env.params, env.obs_size - id_width - context_size(env.params)
            )
        # the critic reads the same features when it reads the agent's own observation (IPPO)
        self.critic_features = self.relative is not None and not centralised_critic
        # PLAN_OBS: each agent's observation ends with its leaf's advice (aids.plan_features:
        # its own plan's charge-now flag, or the coupled plan's share and congestion price;
        # always 0 for the batteries), before the relative prices.
        self.plan_config = {
            "PLAN_OBS": config.get("PLAN_OBS", False),
            "RESIDUAL": config.get("RESIDUAL", "off"),
        }
        features = aids.advice_features(self.plan_config, env.params)
        self.plan, plan_width = (None, 0) if features is None else features
        # STATION_OBS: the parked cars' demand on the whole station (aids.station_features),
        # the same columns for every agent, before the advice.
        self.station_params = env.params if config.get("STATION_OBS", False) else None
        if self.station_params is not None:
            plan_width += aids.STATION_WIDTH
        self.obs_dim += plan_width
        # RESIDUAL: the base rule's level is the last advice column; the actor's logits get
        # offsets centred on its action (networks.residual_offsets), so the untrained greedy
        # policy is the rule and training learns the corrections that pay.
        self.residual_col = None
        if aids.residual_mode(self.plan_config) != "off":
            if config.get("PRIORITY_FILL", False):
                raise ValueError(
                    "RESIDUAL centres the actor on the rule's level, which PRIORITY_FILL's "
                    "actions do not encode: set PRIORITY_FILL=false or RESIDUAL='off'"
                )
            self.residual_col = self.obs_dim - 1
            self.residual_strength = networks.residual_prior(config)
            self.num_levels = int(env.params.num_levels)
            self.idle_index = int(env.action_offset)
        if not centralised_critic:
            self.critic_dim += plan_width
        if self.relative is not None:
            self.obs_dim += len(self.relative[0])
            if self.critic_features:
                self.critic_dim += len(self.relative[0])

    def plan_for(self, env_params):
        """The `PLAN_OBS` advice read from ``env_params``' prices, for a policy played on
        parameters other than the training env's (a shift task's held-out year): the plan
        advises on the day the state is in, under the prices of the params it is played on.

        Args:
            env_params: concrete `chargax_marl.core.types.EnvParams` of the env played.

        Returns:
            ``advice(core) -> (L, width)``, as `baselines.algos.aids.plan_features` gives
            it, or None when ``PLAN_OBS`` is off.
        """
        if self.plan is None:
            return None
        return aids.advice_features(self.plan_config, env_params)[0]

    def with_plan(self, obs_matrix, core, plan=None):
        """``obs_matrix (..., agents, obs)`` with the ``STATION_OBS`` columns and the `PLAN_OBS`
        column of the (batched) core state ``core`` appended; unchanged when both are off.
        The station's columns are read with the training env's station (its ports' ratings).

        Args:
            obs_matrix: ``(..., agents, obs)`` the agents' observations.
            core: the core state (`chargax_marl.core.types.EnvState`) with the same leading
                axes.
            plan: the advice to read (`plan_for`); None: the training env's.

        Returns:
            ``(..., agents, obs + width)`` with the station's demand
            (`baselines.algos.aids.station_features`) and each agent's leaf advice
            (`baselines.algos.aids.plan_features`), or ``obs_matrix`` itself.
        """
        if self.station_params is not None:
            station = aids.station_features(core, self.station_params)[..., None, :]
            station = jnp.broadcast_to(station, obs_matrix.shape[:-1] + station.shape[-1:])
            obs_matrix = jnp.concatenate([obs_matrix, station], axis=-1)
        if self.plan is None:
            return obs_matrix
        plan = self.plan if plan is None else plan
        return jnp.concatenate([obs_matrix, car_plan.batched(plan, core)(core)], axis=-1)

    def features(self, obs):
        """The networks' input: ``obs`` with the relative prices when ``RELATIVE_PRICES``
        is on.

        Args:
            obs: ``(..., obs)`` actor rows.

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
            ``{"actor", "critic"}`` flax parameters, with ``"battery_actor"`` under
            ``BATTERY_NET`` and ``"battery_critic"`` when the batteries also get their own
            critic (``BATTERY_NET`` with a critic on the agent's own observation).
        """
        ka, kc, kba, kbc = jax.random.split(key, 4)
        params = {
            "actor": self.actor.init(ka, jnp.zeros((self.obs_dim,))),
            "critic": self.critic.init(kc, jnp.zeros((self.critic_dim,))),
        }
        if self.battery_net:
            params["battery_actor"] = self.actor.init(kba, jnp.zeros((self.obs_dim,)))
        if self.battery_critic:
            params["battery_critic"] = self.critic.init(kbc, jnp.zeros((self.critic_dim,)))
        return params

    def is_battery(self, obs):
        """The battery flag of the kind one-hot in each row's observation.

        Args:
            obs: ``(..., obs)`` actor rows.

        Returns:
            ``(..., 1)``: 1.0 for a battery agent's row, 0.0 for a port's.
        """
        return obs[..., self.battery_col : self.battery_col + 1]

    def _by_kind(self, port_net, battery_net, x, rows: str):
        """``port_net`` on the ports' rows of ``x`` and ``battery_net`` on the batteries' rows
        only, for rows laid out as ``rows``: ``"agent_major"`` (``agent * envs + env``, the
        rollout) or ``"env_step_major"`` (``env_step * agents + agent``, a minibatch of
        `baselines.algos.ppo_core.shuffled_rows`)."""
        n, ports = self.num_agents, self.num_agents - self.num_batteries
        axis = 0 if rows == "agent_major" else 1
        x3 = x.reshape(((n, -1) if axis == 0 else (-1, n)) + x.shape[1:])
        p, b = jnp.split(x3, [ports], axis=axis)
        out = jnp.concatenate([port_net(p), battery_net(b)], axis=axis)
        return out.reshape((x.shape[0],) + out.shape[2:])

    def _split(self, rows) -> bool:
        if rows not in (None, "agent_major", "env_step_major"):
            raise ValueError(f"rows must be None, 'agent_major' or 'env_step_major', got {rows!r}")
        return rows is not None and self.num_batteries > 0

    def logits(self, params, obs, avail, rows: str | None = None):
        """Masked logits of the actor rows ``obs (rows, obs)``. With ``BATTERY_NET`` the
        battery rows go through the battery's actor: with ``rows`` (the rows' layout, see
        `_by_kind`) each actor runs on its own rows only, else both run on every row and
        a ``where`` keeps each row's own.

        Args:
            params: the networks' parameters (`init`).
            obs: ``(rows, obs)`` actor rows (``(..., obs)`` when ``rows`` is None).
            avail: ``(rows, K)`` bool, or broadcastable to the logits; True where the action
                is allowed.
            rows: the rows' layout, ``"agent_major"`` or ``"env_step_major"``; None for any
                rows.

        Returns:
            ``(rows, K)`` logits, with the prior offsets added and the unavailable actions
            at `baselines.algos.networks.NEG_INF`.

        Raises:
            ValueError: an unknown ``rows`` (with ``BATTERY_NET``).
        """
        x = self.features(obs)
        if self.battery_net and self._split(rows):
            logits = self._by_kind(
                lambda v: self.actor.apply(params["actor"], v),
                lambda v: self.actor.apply(params["battery_actor"], v),
                x,
                rows,
            )
        else:
            logits = self.actor.apply(params["actor"], x)
            if self.battery_net:
                logits = jnp.where(
                    self.is_battery(obs) > 0.5, self.actor.apply(params["battery_actor"], x), logits
                )
        if self.port_offset.any() or self.battery_offset.any():
            is_battery = self.is_battery(obs)
            logits = (
                logits + (1.0 - is_battery) * self.port_offset + is_battery * self.battery_offset
            )
        if self.residual_col is not None:
            level = jnp.round(obs[..., self.residual_col] * self.num_levels)
            port_s, battery_s = self.residual_strength
            strength = jnp.where(self.is_battery(obs)[..., 0] > 0.5, battery_s, port_s)
            logits = logits + networks.residual_offsets(level + self.idle_index, self.k, strength)
        return networks.masked_logits(logits, avail)

    def value(self, params, critic_in, rows: str | None = None):
        """Values of the critic rows; ``rows`` as in `logits` (used with a battery
        critic, which reads the agent's own observation).

        Args:
            params: the networks' parameters (`init`).
            critic_in: ``(rows, critic_dim)`` the critic's input: the agents' observations
                (IPPO) or world states (MAPPO).
            rows: the rows' layout, as in `logits`.

        Returns:
            ``(rows,)`` the values.

        Raises:
            ValueError: an unknown ``rows`` (with a battery critic).
        """
        x = self.features(critic_in) if self.critic_features else critic_in
        if self.battery_critic and self._split(rows):
            return self._by_kind(
                lambda v: self.critic.apply(params["critic"], v)[..., 0],
                lambda v: self.critic.apply(params["battery_critic"], v)[..., 0],
                x,
                rows,
            )
        v = self.critic.apply(params["critic"], x)[..., 0]
        if self.battery_critic:  # critic_in is the agent's own observation
            v = jnp.where(
                self.is_battery(critic_in)[..., 0] > 0.5,
                self.critic.apply(params["battery_critic"], x)[..., 0],
                v,
            )
        return v


def make_train(config: dict | None = None, env_params=None, centralised_critic: bool = False):
    """Build ``train(key)`` (IPPO; MAPPO with ``centralised_critic=True``).

    ``config`` keys are those of `baselines.algos.PAPER_DEFAULTS` plus ``AGENT_ID``
    (``onehot``/``scalar``, the agent-index encoding). ``TOTAL_TIMESTEPS`` counts env steps
    (one step moves every agent).

    Args:
        config: the config (resolved with `baselines.config.resolve`; None: the defaults).
        env_params: the training env's parameters; None: the config's
            (`baselines.config.build_env_params`).
        centralised_critic: MAPPO's critic on the world state, in place of IPPO's on the
            agent's own observation.

    Returns:
        The `baselines.algos.trainer.Trainer`.

    Raises:
        ValueError: ``NUM_ENVS * NUM_STEPS`` not divisible by ``NUM_MINIBATCHES``,
            ``NUM_ENVS`` not divisible by the number of devices, ``BATTERY_GAMMA`` outside
            [0, 1], ``BATTERY_ENT_COEF`` negative or not finite, ``TOTAL_TIMESTEPS`` less
            than one rollout, or a learning aid's setting refused
            (`baselines.algos.aids`).
    """
    config = resolve(
        {
            **{
                "AGENT_ID": "onehot",
                "AGENT_ADV_NORM": False,
                "BATTERY_NET": False,
                "BATTERY_GAMMA": None,
                "BATTERY_ENT_COEF": None,
                "RELATIVE_PRICES": False,
                "PLAN_OBS": False,
                "RESIDUAL": "off",
                "RESIDUAL_PRIOR": 2.0,
                "RESIDUAL_BATTERY_PRIOR": None,
            },
            **(config or {}),
        }
    )
    if env_params is None:
        env_params = build_env_params(config)[0]
    base_env = ChargaxMARL(
        params=env_params,
        agent_id=config["AGENT_ID"],
        local_reward_weight=config["LOCAL_REWARD_WEIGHT"],
    )
    # PRIORITY_FILL, FAIRNESS_WEIGHT, OBS_DELAY_STEPS, ACTION_LOSS_PROB (each off: the env)
    filled_env = aids.priority_fill(config, base_env)
    env = aids.communication(config, aids.fairness(config, filled_env))
    env = LogWrapper(WorldStateWrapper(env) if centralised_critic else env)
    agents = base_env.agents
    # the agents' own action space: the view's, or PRIORITY_CLASSES' classes (the fill's)
    action_env = filled_env if config.get("PRIORITY_CLASSES", 0) else base_env
    policy = SharedPolicy(config, action_env, centralised_critic)
    n_envs, n_steps, n_agents = config["NUM_ENVS"], config["NUM_STEPS"], base_env.num_agents
    n_actors = n_agents * n_envs
    total_updates = ppo_core.num_updates(config)
    if (n_envs * n_steps) % config[
        "NUM_MINIBATCHES"
    ]:  # minibatches hold whole env-steps (ppo_core.shuffled_rows)
        raise ValueError(
            f"NUM_ENVS*NUM_STEPS={n_envs * n_steps} must be divisible by "
            f"NUM_MINIBATCHES={config['NUM_MINIBATCHES']}"
        )
    mesh = runner.env_mesh(n_envs)
    tx = ppo_core.make_optimizer(config, total_updates)

    # ``get_avail_actions`` depends only on the station: one constant (actors, K) mask, agent-major.
    avail_agents = action_env.get_avail_actions(None)
    avail_b = device_array(
        np.repeat(np.stack([np.asarray(avail_agents[a]) for a in agents]), n_envs, axis=0)
    )
    dedup = centralised_critic and DEDUP_CENTRAL_CRITIC
    # In the update the deduplicated critic runs on the whole rollout's world states
    # (n_steps * n_envs rows) for every minibatch: cheaper than one row per agent row while
    # a minibatch holds more rows than that, i.e. NUM_MINIBATCHES < num_agents.
    dedup_update = dedup and config["NUM_MINIBATCHES"] < n_agents

    def rollout_value(params, env_state, obs_b):
        """``(critic_in, value (actors,))`` of the step's observations ``obs_b`` (IPPO) or the
        world states of ``env_state`` (MAPPO)."""
        if not centralised_critic:
            return jnp.zeros((n_actors,), jnp.int8), policy.value(
                params, obs_b, rows="agent_major"
            )  # unused placeholder
        ws = jax.vmap(env.global_state)(env_state)  # (envs, state): one row per env
        if dedup:
            return ws, jnp.tile(policy.value(params, ws), n_agents)  # agent-major rows
        ws_b = jnp.tile(ws, (n_agents, 1))  # (agents * envs, state), agent-major
        return ws, policy.value(params, ws_b)

    # BATTERY_SHAPING (shaping.battery_potential, per agent as teacher_shaping.agent_potential_shaping).
    is_bat = np.asarray(env_params.station.leaf_kind) == KIND_BATTERY

    potential = aids.battery_potential(config, env_params)
    car_potential = aids.car_potential(
        config, env_params
    )  # PORT_SHAPING, each port its own car's term

    def per_agent_infos(info):
        """The array step's infos with each env's scalars as ``(envs, agents)``, as the dict
        view's."""
        return {
            k: jnp.broadcast_to(v[:, None], (n_envs, n_agents)) if v.ndim == 1 else v
            for k, v in info.items()
        }

    def battery_term(pot, info):
        """Per-actor ``(agents * envs,)`` shaping term of a step (info leaves ``(envs, agents)``)."""
        per_agent = teacher_shaping.agent_potential_shaping(
            pot, per_agent_infos(info), is_bat, config["LOCAL_REWARD_WEIGHT"]
        )
        return agent_major(per_agent)

    # BATTERY_GAMMA: the battery agents' own discount (None: GAMMA). A port's decisions pay off
    # within minutes; a battery's charge pays off hours later, when it is discharged.
    battery_gamma = (
        config["GAMMA"] if config["BATTERY_GAMMA"] is None else float(config["BATTERY_GAMMA"])
    )
    if not 0.0 <= battery_gamma <= 1.0:
        raise ValueError(f"BATTERY_GAMMA={battery_gamma} must be in [0, 1] (or None: GAMMA)")
    # BATTERY_ENT_COEF: the battery agents' own entropy bonus (None: ENT_COEF). Early on a
    # random battery discharges at the wrong hours and its discharge probability collapses
    # before it has learned when discharging pays; the ports want little entropy.
    if config["BATTERY_ENT_COEF"] is not None and not (
        np.isfinite(float(config["BATTERY_ENT_COEF"])) and float(config["BATTERY_ENT_COEF"]) >= 0
    ):
        raise ValueError(
            f"BATTERY_ENT_COEF={config['BATTERY_ENT_COEF']} must be a finite number >= 0 "
            "(or None: ENT_COEF)"
        )
    battery_rows = np.repeat(is_bat, n_envs)  # agent-major

    def row_gammas(hyper):
        """Each actor's discount ``(agents * envs,)``: ``BATTERY_GAMMA`` for the batteries'
        rows when it is set, ``GAMMA`` (a value of ``hyper``) otherwise."""
        if config["BATTERY_GAMMA"] is None:
            return jnp.broadcast_to(hyper["GAMMA"], battery_rows.shape)
        return jnp.where(battery_rows, jnp.float32(battery_gamma), hyper["GAMMA"])

    def per_agent_normalised(adv):
        """AGENT_ADV_NORM: each agent's advantages ``(steps, agents * envs)`` scaled to mean 0 and
        std 1 over its own rows of the rollout, before the minibatches mix the agents (whose
        global normalisation then leaves them about as they are). Without it the battery's
        advantages (cents per step) are scaled by the ports' spread (euros per step) and its
        head hardly moves against the entropy bonus and the ports' gradients."""
        a = adv.reshape((n_steps, n_agents, n_envs))
        mean = a.mean(axis=(0, 2), keepdims=True)
        std = a.std(axis=(0, 2), keepdims=True)
        return ((a - mean) / (std + 1e-8)).reshape(adv.shape)

    def init(key, hyper=None):
        k_net, k_env, key = jax.random.split(key, 3)
        params = policy.init(k_net)
        if distill_fn is not None:  # DISTILL: the actor starts from the MPC's decisions
            key, k_distill = jax.random.split(key)
            params, _ = distill_fn(params, k_distill)
        obs, env_state = jax.vmap(env.reset)(jax.random.split(k_env, n_envs))
        obs = jnp.stack([obs[a] for a in agents], axis=1)  # (envs, agents, obs)
        obs, env_state = runner.shard_envs((obs, env_state), mesh)
        hyper = ppo_core.hyper_values(config) if hyper is None else hyper
        return RunnerState(
            params, tx.init(params), env_state, obs, key, jnp.zeros((), jnp.int32), hyper
        )

    def agent_rows(obs, env_state):
        """The actors' observations ``(agents * envs, obs)`` (agent-major) of the per-env
        matrices ``obs (envs, agents, obs)``, with the plan advice of ``env_state`` when
        ``PLAN_OBS`` is on."""
        if policy.plan is not None or policy.station_params is not None:
            obs = policy.with_plan(obs, teacher_shaping.core_state(env_state))
        return agent_major(obs)

    distill_fn = None
    if distill.distill_mode(config) != "off":
        distill_fn = distill.make_distill(
            config,
            policy,
            env,
            agents,
            agent_rows,
            np.stack([np.asarray(avail_agents[a]) for a in agents]),
            action_env.action_offset,
            env_params,
        )

    def env_step(hyper, carry, _):
        params, env_state, obs, key = carry
        key, k_act, k_step = jax.random.split(key, 3)
        obs_b = agent_rows(obs, env_state)
        avail = avail_b
        logits = policy.logits(params, obs_b, avail, rows="agent_major")
        action, logp = networks.sample_categorical(k_act, logits)
        cin, value = rollout_value(params, env_state, obs_b)
        pot = (
            None if potential is None else potential(env_state)
        )  # before the (auto-resetting) step
        car_pot = None if car_potential is None else car_potential(env_state)
        next_obs, env_state, reward, done, info = jax.vmap(env.step_arrays)(
            jax.random.split(k_step, n_envs), env_state, env_major(action, n_agents, n_envs)
        )
        reward_b = agent_major(reward)
        if pot is not None:
            reward_b = reward_b + hyper["SHAPING_WEIGHT"] * battery_term(pot, info)
        if car_pot is not None:
            own = teacher_shaping.mix_own_terms(
                car_pot(info["agent_energy_kwh"]), config["LOCAL_REWARD_WEIGHT"]
            )
            reward_b = reward_b + hyper["SHAPING_WEIGHT"] * agent_major(own)
        next_obs, env_state = runner.shard_envs((next_obs, env_state), mesh)
        tr = Transition(
            obs_b,
            cin,
            avail,
            action,
            logp,
            value,
            reward_b * hyper["REWARD_SCALE"],
            jnp.tile(done, n_agents).astype(jnp.float32),
            {k: info[k] for k in INFO_KEYS},
        )  # each (envs, agents)
        return (params, env_state, next_obs, key), tr

    def make_loss(ws_table, hyper):
        def loss_fn(params, mb):
            tr, adv, targets = mb
            logits = policy.logits(params, tr.obs, tr.avail, rows="env_step_major")
            new_logp = networks.log_prob(logits, tr.action)
            if not centralised_critic:
                values = policy.value(params, tr.obs, rows="env_step_major")
            elif dedup_update:
                values = policy.value(params, ws_table)[tr.critic_in]
            else:
                values = policy.value(params, tr.critic_in)
            ent_coef = None
            if config["BATTERY_ENT_COEF"] is not None:  # the battery rows' own entropy coefficient
                ent_coef = jnp.where(
                    policy.is_battery(tr.obs)[..., 0] > 0.5,
                    float(config["BATTERY_ENT_COEF"]),
                    hyper["ENT_COEF"],
                )
            return ppo_core.ppo_loss(
                new_logp,
                tr.log_prob,
                adv,
                values,
                tr.value,
                targets,
                networks.entropy(logits),
                hyper,
                ent_coef,
            )

        return loss_fn

    def update(rs: RunnerState, _):
        hyper = rs.hyper
        (params, env_state, obs, key), traj = jax.lax.scan(
            functools.partial(env_step, hyper),
            (rs.params, rs.env_state, rs.obs, rs.key),
            None,
            n_steps,
        )
        last_value = rollout_value(params, env_state, agent_rows(obs, env_state))[1]
        ws_table = None
        if centralised_critic:
            ws_table = traj.critic_in.reshape((n_steps * n_envs, -1))  # (step, env) world states
            # row (t, agent * n_envs + e) reads world state t * n_envs + e
            idx = (
                jnp.arange(n_steps)[:, None] * n_envs + jnp.arange(n_actors)[None, :] % n_envs
            ).astype(jnp.int32)
            traj = traj._replace(critic_in=idx if dedup_update else ws_table[idx])
        loss_fn = make_loss(ws_table, hyper)
        adv, targets = ppo_core.gae(
            traj.reward, traj.value, traj.done, last_value, row_gammas(hyper), hyper["GAE_LAMBDA"]
        )
        if config["AGENT_ADV_NORM"]:
            adv = per_agent_normalised(adv)

        params, opt_state, key, parts = ppo_core.ppo_epochs(
            loss_fn, tx, params, rs, key, traj, adv, targets, config, agents=n_agents
        )
        metrics = {k: v.mean() for k, v in parts.items()}
        # Every agent logs the same episode: use agent 0's column.
        metrics.update(
            ppo_core.episode_metrics(
                traj.info["returned_episode"][..., 0], {k: v[..., 0] for k, v in traj.info.items()}
            )
        )
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
        make_act=make_act_builder(
            policy,
            config["AGENT_ID"],
            config.get("OBS_DELAY_STEPS", 0),
            config.get("ACTION_LOSS_PROB", 0.0),
            config.get("LOST_ACTION", "previous"),
            config.get("PRIORITY_FILL", False),
            config.get("PRIORITY_CLASSES", 0),
        ),
    )


def make_act_builder(
    policy: SharedPolicy,
    agent_id: str,
    delay_steps: int = 0,
    loss_prob: float = 0.0,
    lost_action: str = "previous",
    priority_fill: bool = False,
    priority_classes: int = 0,
):
    """``make_act_for(eval_params)(params) -> act``: every agent takes the argmax of its masked
    logits (greedy), read from the simulator state. With an observation delay or an action loss
    (the config's ``OBS_DELAY_STEPS``, ``ACTION_LOSS_PROB``, ``LOST_ACTION``) the policy is
    played under them (`chargax_marl.marl.communicating_act`), as it was trained; with
    ``priority_fill`` (``PRIORITY_FILL``) its levels are filled as the training env filled them
    (`chargax_marl.wrappers.priority_fill_levels`; with ``priority_classes``
    (``PRIORITY_CLASSES``) its indices are classes, `chargax_marl.wrappers.priority_class_levels`).

    Args:
        policy: the trained `SharedPolicy`.
        agent_id: the agent-index encoding (``AGENT_ID``).
        delay_steps: the observation delay (steps).
        loss_prob: the probability that an action is lost.
        lost_action: what a lost action becomes (``LOST_ACTION``).
        priority_fill: the levels are filled as priorities (``PRIORITY_FILL``).
        priority_classes: the number of charging classes (``PRIORITY_CLASSES``); 0 for none.

    Returns:
        ``make_act_for(eval_params) -> make_act``, built once per ``eval_params`` object,
        where ``make_act(params) -> act(state, key) -> levels`` (or a
        `chargax_marl.evaluation.MemoryAct` under a delay or a loss).
    """
    cache = IdentityCache()

    def build(eval_params):
        env = ChargaxMARL(params=eval_params, agent_id=agent_id)
        if priority_classes:
            env = PriorityFill(env, priority_classes)
        avail = jnp.asarray(env._avail_np)
        plan = policy.plan_for(eval_params)  # the advice under the prices played on

        def make_act(params):
            def choose(obs, state, key):
                del key
                obs = policy.with_plan(obs, state, plan)
                return jnp.argmax(policy.logits(params, obs, avail), axis=-1)

            if delay_steps or loss_prob:
                return communicating_act(env, choose, delay_steps, loss_prob, lost_action)

            def act(state, key):
                idx = choose(env.get_obs_matrix(state), state, key)
                if priority_classes:
                    return priority_class_levels(idx, state, eval_params, priority_classes)
                levels = marl_env.actions_to_levels(idx, eval_params, env.action_offset)
                if priority_fill:
                    return priority_fill_levels(levels, state, eval_params)
                return levels

            return act

        return make_act

    return lambda eval_params: cache.get(eval_params, lambda: build(eval_params))
