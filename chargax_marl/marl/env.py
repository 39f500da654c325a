"""Multi-agent view of the station: one agent per charging port and per station battery (JaxMARL 0.2 API).

The transition is `chargax_marl.core.simulator.step` (with
`chargax_marl.core.simulator.step_auto_reset`), the very functions the single-agent view
calls; this file only maps the agents' actions to the core's per-leaf levels and builds the
per-agent observations. `step_arrays` is the one array transition; the JaxMARL dict API
(`ChargaxMARL.step`, ``step_env``) is a view of it, and
`ChargaxMARL.validate_actions` is the one check of an action dict. The pure functions at
module level take ``params`` explicitly (so jitted callers may pass them as traced arguments
and share compiled code); `ChargaxMARL` binds them to ``self.params`` as JaxMARL
environments do.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jaxmarl.environments import spaces
from jaxmarl.environments.multi_agent_env import MultiAgentEnv

from chargax_marl import bounds
from chargax_marl.core import actions as core_actions
from chargax_marl.core import clock, observation, physics, simulator
from chargax_marl.core.params import make_params, validate_params
from chargax_marl.core.rng import materialize
from chargax_marl.core.scenarios import scenario_kwargs
from chargax_marl.core.station import KIND_AC, KIND_BATTERY, KIND_DC
from chargax_marl.core.types import EnvParams, EnvState
from chargax_marl.lifecycle import check_day

NUM_KINDS = 3  # one-hot order: AC, DC, battery (the values of KIND_AC, KIND_DC, KIND_BATTERY)
assert (KIND_AC, KIND_DC, KIND_BATTERY) == (0, 1, 2)


# --------------------------------------------------------------------------- pure functions


def agent_names(params: EnvParams) -> list[str]:
    """``port_0 .. port_{P-1}`` then ``battery_0 ..``, in leaf order.

    Args:
        params: the environment parameters.

    Returns:
        The ``N = num_ports + num_batteries`` agent names.
    """
    st = params.station
    return [f"port_{i}" for i in range(st.num_ports)] + [
        f"battery_{j}" for j in range(st.num_batteries)
    ]


def action_offset(params: EnvParams) -> int:
    """Index of idle (level 0) in the shared ``Discrete`` action space: ``L`` or 0.

    ``Discrete(2L+1)`` (index ``k`` is level ``k - L``) when any leaf may discharge or in
    ``delta`` mode, else ``Discrete(L+1)`` (index ``k`` is level ``k``). Needs concrete params.

    Args:
        params: the environment parameters (concrete).

    Returns:
        ``L = params.num_levels`` in ``delta`` mode or when any leaf may discharge, else 0.
    """
    if params.action_mode == "delta":
        return params.num_levels
    min_level = np.asarray(physics.leaf_min_level(params.station, params.num_levels, params.v2g))
    return params.num_levels if bool(np.any(min_level < 0)) else 0


def min_levels(params: EnvParams) -> jnp.ndarray:
    """Lowest valid level per agent: ``-L`` where the leaf may discharge (all leaves in delta mode), else 0.

    Args:
        params: the environment parameters.

    Returns:
        ``(N,)`` int32 levels, in agent order.
    """
    if params.action_mode == "delta":
        return jnp.full((params.station.num_leaves,), -params.num_levels, jnp.int32)
    return physics.leaf_min_level(params.station, params.num_levels, params.v2g)


def actions_to_levels(indices: jnp.ndarray, params: EnvParams, offset: int) -> jnp.ndarray:
    """Map per-agent action indices ``(N,)`` to the core's signed levels ``(N,)``.

    Indices outside ``[0, n)`` are clipped into it (in their own dtype, before any int32
    cast; host integers beyond int32 are clipped on the host first,
    `chargax_marl.core.actions.host_array`); NaN and +-inf are idle; a masked (invalid)
    action falls back to idle, level 0.

    Args:
        indices: ``(N,)`` action indices in agent order (integers or floats; floats are
            truncated toward zero).
        params: the environment parameters.
        offset: `action_offset` of ``params``, the index of idle.

    Returns:
        ``(N,)`` int32 signed levels, ``index - offset`` where valid, else 0.
    """
    n = params.num_levels + 1 + offset
    idx = core_actions.to_int32(core_actions.host_array(indices), 0, n - 1, offset)
    levels = idx - offset
    return jnp.where(levels < min_levels(params), 0, levels).astype(jnp.int32)


def levels_to_indices(levels: jnp.ndarray, params: EnvParams, offset: int) -> jnp.ndarray:
    """Inverse of `actions_to_levels` for valid levels (e.g. from `chargax_marl.policies`).

    Args:
        levels: ``(N,)`` signed levels in agent order (cast to int32; not checked).
        params: the environment parameters (unused: the offset carries what is needed).
        offset: `action_offset` of ``params``, the index of idle.

    Returns:
        ``(N,)`` int32 action indices ``level + offset``.
    """
    return jnp.asarray(levels).astype(jnp.int32) + offset


@functools.partial(jax.jit, static_argnums=1)
def avail_actions(params: EnvParams, offset: int) -> jnp.ndarray:
    """Bool ``(N, n)``: ``True`` where index ``k`` gives a level the agent's leaf can take.

    Compiled as one program per station shape (a new env builds its mask with it).

    Args:
        params: the environment parameters.
        offset: `action_offset` of ``params`` (static: ``n = num_levels + 1 + offset``).

    Returns:
        ``(N, n)`` bool mask, rows in agent order: index ``k`` is available where level
        ``k - offset`` is at least the agent's `min_levels`.
    """
    n = params.num_levels + 1 + offset
    levels = jnp.arange(n, dtype=jnp.int32)[None, :] - offset
    return levels >= min_levels(params)[:, None]


def ancestor_table(params: EnvParams) -> jnp.ndarray:
    """``(N, D)`` node index of each leaf's ancestors from the deepest to the root, ``-1`` padded.

    Args:
        params: the environment parameters; ``D`` is the station tree's depth.

    Returns:
        ``(N, D)`` int node indices; row ``i`` lists leaf ``i``'s ancestors starting with its
        parent and ending with the root (node 0, the grid connection), then ``-1``.
    """
    st = params.station
    anc = st.node_of_leaf_at_depth.T  # (N, D), ancestors by depth, root first, -1 where none
    count = jnp.sum(anc >= 0, axis=1)
    src = count[:, None] - 1 - jnp.arange(st.depth)[None, :]
    picked = jnp.take_along_axis(anc, jnp.maximum(src, 0), axis=1)
    return jnp.where(src >= 0, picked, -1)


@struct.dataclass
class ObsLayout:
    """Station-dependent constants of the agent observations (see `obs_layout`).

    Attributes:
        kind_onehot: ``(N, 3)`` float32 one-hot of each agent's leaf kind (AC, DC, battery).
        ancestors: ``(N, D)`` int32 node table of `ancestor_table`.
        agent_id: the agent-index columns: ``(N, N)`` one-hot, or ``(N, 1)``
            ``index / (N - 1)``.
    """

    kind_onehot: jnp.ndarray  # (N, 3) AC, DC, battery
    ancestors: jnp.ndarray  # (N, D) int32, `ancestor_table`
    agent_id: jnp.ndarray  # (N, N) one-hot, or (N, 1) index / (N - 1)


AGENT_ID_ENCODINGS = ("onehot", "scalar")


def obs_layout(params: EnvParams, agent_id: str = "onehot") -> ObsLayout:
    """Precompute the observation constants of a station (numpy arrays when ``params`` are
    concrete, so that jitted code bakes them in; traced arrays otherwise).

    ``agent_id`` picks the agent-index feature: ``"onehot"`` (N columns; the observation then
    grows with the number of agents, so a step costs O(N^2)) or ``"scalar"`` (one column,
    ``index / (N - 1)``; O(N) per step, for large stations).

    Args:
        params: the environment parameters.
        agent_id: ``"onehot"`` or ``"scalar"`` (`AGENT_ID_ENCODINGS`).

    Returns:
        The station's `ObsLayout`.

    Raises:
        ValueError: ``agent_id`` is not one of `AGENT_ID_ENCODINGS`.
    """
    if agent_id not in AGENT_ID_ENCODINGS:
        raise ValueError(f"field 'agent_id' must be one of {AGENT_ID_ENCODINGS}, got {agent_id!r}")
    # called with traced params, the program is inlined into the caller's
    layout = _layout_program(params, agent_id)
    if not any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(layout)):
        layout = jax.tree.map(np.asarray, layout)
    return layout


@functools.partial(jax.jit, static_argnums=1)
def _layout_program(params: EnvParams, agent_id: str) -> ObsLayout:
    """The arrays of `obs_layout`, one program per station shape and ``agent_id``."""
    st = params.station
    n = st.num_leaves
    ids = (
        jnp.eye(n, dtype=jnp.float32)
        if agent_id == "onehot"
        else (jnp.arange(n, dtype=jnp.float32) / max(n - 1, 1))[:, None]
    )
    return ObsLayout(
        kind_onehot=jax.nn.one_hot(st.leaf_kind, NUM_KINDS, dtype=jnp.float32),
        ancestors=ancestor_table(params).astype(jnp.int32),
        agent_id=ids,
    )


def ancestor_loads(
    state: EnvState, params: EnvParams, layout: ObsLayout | None = None
) -> jnp.ndarray:
    """``(N, D)`` load fraction of each agent's ancestor nodes, deepest first, zero-padded.

    The load of node ``H`` is its grid-side net flow
    `chargax_marl.core.physics.node_flows_kw` (each leaf's ``V * I`` divided by the
    efficiencies up to and including ``H`` when charging, multiplied when discharging, from
    the currents in ``state``) over its ``max_kw``: the same flow the hard rescale limits, so
    a load of 1 means the node binds. Linear in the number of ports.

    Args:
        state: the env state, whose ``current_a`` gives the flows.
        params: the environment parameters.
        layout: `obs_layout` of ``params`` (built when None).

    Returns:
        ``(N, D)`` load fractions, rows in agent order, 0 where an agent has fewer than ``D``
        ancestors.
    """
    layout = obs_layout(params) if layout is None else layout
    st = params.station
    # current_a stored once (rng.materialize): the node sums' transposes otherwise recompute
    # the step's whole current chain, once per tree level.
    load = (
        physics.node_flows_kw(materialize(state.current_a) * st.leaf_voltage_v / 1000.0, st)
        / st.node_max_kw
    )
    anc = layout.ancestors
    return jnp.where(anc >= 0, load[jnp.maximum(anc, 0)], 0.0)


def _observation_parts(state: EnvState, params: EnvParams, layout: ObsLayout):
    """The column blocks of `agent_observations`: per-agent blocks ``(N, w)`` and the
    shared context ``(C,)``."""
    leaf = observation.leaf_features(state, params).astype(jnp.float32)
    loads = ancestor_loads(state, params, layout).astype(jnp.float32)
    return (
        leaf,
        layout.kind_onehot,
        loads,
        observation.context_features(state, params),
        layout.agent_id,
    )


def agent_observations(
    state: EnvState, params: EnvParams, layout: ObsLayout | None = None
) -> jnp.ndarray:
    """Every agent's observation as one float32 matrix ``(N, obs_size)``, rows in agent order.

    Columns: the 8 leaf features of `observation.leaf_features`; kind one-hot (AC, DC,
    battery); load fraction ``|grid-side net flow| / max_kw`` of each ancestor node from the deepest to
    the root, zero-padded to the tree depth; the shared context; the agent index one-hot.
    ``layout`` (from `obs_layout`) saves recomputing the station constants.

    Args:
        state: the env state.
        params: the environment parameters.
        layout: `obs_layout` of ``params`` (built when None, with the one-hot agent index).

    Returns:
        ``(N, obs_size)`` float32; the agent-index columns are those of ``layout``.
    """
    layout = obs_layout(params) if layout is None else layout
    leaf, kind, loads, ctx, agent_id = _observation_parts(state, params, layout)
    n = params.station.num_leaves
    return jnp.concatenate(
        [leaf, kind, loads, jnp.broadcast_to(ctx, (n, ctx.shape[0])), agent_id], axis=1
    )


def agent_observation_rows(
    state: EnvState, params: EnvParams, layout: ObsLayout | None = None
) -> list:
    """The rows of `agent_observations` as a list of ``(obs_size,)`` arrays, each built
    on its own (the same values bit for bit). The dict API hands out one array per agent:
    slicing the matrix made XLA write the ``(N, obs_size)`` matrix and then copy every row
    out of it; built per agent, each row is written once (or fused into its reader).

    Args:
        state: the env state.
        params: the environment parameters.
        layout: `obs_layout` of ``params`` (built when None).

    Returns:
        ``N`` float32 arrays of shape ``(obs_size,)``, in agent order.
    """
    layout = obs_layout(params) if layout is None else layout
    leaf, kind, loads, ctx, agent_id = _observation_parts(state, params, layout)
    return [
        jnp.concatenate([leaf[i], kind[i], loads[i], ctx, agent_id[i]])
        for i in range(leaf.shape[0])
    ]


STEP_INFO_KEYS = simulator.STEP_INFO_KEYS
INFO_KEYS = simulator.INFO_KEYS
"""Every scalar info key (`chargax_marl.core.simulator.info_dict`), in order."""

AGENT_INFO_KEYS = ("agent_energy_kwh", "agent_reward_share")
"""The per-agent info entries this view adds to the single-agent view's keys."""


def step_arrays(
    key: jax.Array,
    state: EnvState,
    indices: jnp.ndarray,
    params: EnvParams,
    offset: int,
    layout: ObsLayout | None = None,
    *,
    local_reward_weight: float = 0.0,
    auto_reset: bool = False,
    reset_state: EnvState | None = None,
):
    """The multi-agent transition on arrays; ``ChargaxMARL.step`` / ``step_env`` are views of it.

    Args:
        key: the step's key.
        state: the state to step.
        indices: ``(N,)`` action indices in agent order (clipped into ``[0, n)``, NaN idle,
            masked levels idle: `actions_to_levels`).
        params: the environment parameters.
        offset: `action_offset` of ``params``.
        layout: `obs_layout` of ``params`` (built when ``None``).
        local_reward_weight: ``w`` of `agent_rewards` (concrete).
        auto_reset: start a fresh day where the step ends one
            (`chargax_marl.core.simulator.step_auto_reset`).
        reset_state: with ``auto_reset``, the fresh day's state (``None``: a random one).

    Returns:
        ``(obs (N, obs_size), next_state, rewards (N,), done (), info)``; ``obs`` is that of
        ``next_state``. ``info`` holds `chargax_marl.core.simulator.info_dict` (scalars
        and ``leaf_energy_kwh``), ``agent_energy_kwh`` ``(N,)`` (the same energies, named for
        agents) and ``agent_reward_share`` ``(N,)``, each agent's share of the reward
        (`chargax_marl.core.reward.leaf_reward_shares`; the shares sum to the reward);
        with ``auto_reset`` also ``terminated`` and ``truncated`` (the observations before an
        auto-reset: `chargax_marl.marl.FinalObservationWrapper`).
    """
    next_state, rewards, done, info = _transition(
        key, state, indices, params, offset, layout, local_reward_weight, auto_reset, reset_state
    )
    return agent_observations(next_state, params, layout), next_state, rewards, done, info


def _transition(
    key,
    state,
    indices,
    params,
    offset,
    layout,
    local_reward_weight,
    auto_reset,
    reset_state,
    final_obs=False,
):
    """`step_arrays` without the observation: ``(next_state, rewards, done, info)``; with
    ``final_obs`` the info also holds ``final_observation``, the observation matrix of the
    stepped state (`chargax_marl.marl.FinalObservationWrapper`)."""
    levels = actions_to_levels(indices, params, offset)
    if auto_reset:
        next_state, stepped, core_info, done = simulator.step_auto_reset(
            key, state, levels, params, reset_state
        )
    else:
        stepped, core_info = simulator.step(key, state, levels, params)
        next_state, done = stepped, simulator.is_done(stepped, params)
    info = simulator.info_dict(core_info, stepped, params)
    info["agent_energy_kwh"] = info["leaf_energy_kwh"]
    info["agent_reward_share"] = core_info.leaf_reward.astype(jnp.float32)
    if auto_reset:
        info.update(terminated=jnp.asarray(False), truncated=done)
    if final_obs:
        info["final_observation"] = agent_observations(stepped, params, layout)
    rewards = agent_rewards(core_info.reward, info["agent_reward_share"], local_reward_weight)
    return next_state, rewards, done, info


def agent_rewards(reward, shares, local_reward_weight: float):
    """Per-agent rewards ``(N,)``: ``(1 - w) * reward + w * shares`` with ``w`` the
    (concrete) ``local_reward_weight``; exactly the shared ``reward`` for every agent when
    ``w == 0``. Works on JAX and NumPy values.

    Args:
        reward: the station's scalar reward of the step.
        shares: ``(N,)`` each agent's share of the reward (they sum to ``reward``).
        local_reward_weight: ``w`` in ``[0, 1]``, a concrete number.

    Returns:
        ``(N,)`` per-agent rewards, shaped as ``shares``.
    """
    w = float(local_reward_weight)
    if w == 0.0:  # the shared reward, without a dependence on the shares (XLA then skips them)
        xp = np if isinstance(shares, np.ndarray) else jnp
        return xp.broadcast_to(reward, xp.shape(shares))
    return (1.0 - w) * reward + w * shares


def world_state(state: EnvState, params: EnvParams) -> jnp.ndarray:
    """The single-agent observation, MAPPO's world state.

    Args:
        state: the env state.
        params: the environment parameters.

    Returns:
        ``(state_size,)`` float32, `chargax_marl.core.observation.flat_obs` of the state.
    """
    return observation.flat_obs(state, params)


# --------------------------------------------------------------------------- the environment


class ChargaxMARL(MultiAgentEnv):
    """The EV charging station as a JaxMARL multi-agent environment.

    One agent per charging port (``port_0 .. port_{P-1}``, in port order) and per station
    battery (``battery_0 ..``); ``self.agents`` follows the core's leaf order. All agents step
    together through `chargax_marl.core.simulator.step`, the same function the
    single-agent env calls, and share the station reward (``rewards[a]`` is the same scalar
    for every agent). An episode is one day: ``dones[a]`` and ``dones["__all__"]`` turn true
    at its end (truncation); `step` then auto-resets (JaxMARL's base class).

    **Actions.** Every agent has the same ``Discrete(n)`` space. With ``n = 2L+1`` (any leaf
    may discharge: batteries always, ports with V2G) index ``k`` means level ``k - L``, so
    ``L`` is idle and ``2L`` full power; with ``n = L+1`` (no leaf can discharge) index ``k``
    means level ``k``. Level ``l`` targets ``l/L`` of the leaf's max (dis)charge current
    (``absolute`` mode) or changes the current by that much (``delta`` mode, always
    ``Discrete(2L+1)`` with every index valid). Discharging levels of a port without V2G are
    *masked*: `get_avail_actions` returns ``False`` for them (the mask depends only on
    the station, not on the state) and, if chosen anyway, such an action falls back to idle
    (level 0). An action may have shape ``()`` or ``(1,)``. Indices outside ``[0, n)`` are
    clipped into it (as the single-agent env clips), then the mask rule applies;
    `check_actions` refuses them instead (PettingZoo's strict check). A missing or
    unknown agent, a non-number or a wrong shape raises ``ValueError`` at every entry point
    (`validate_actions`). Action mode ``continuous`` is not supported here
    (``ValueError``): use the single-agent view.

    **Construction.** ``ChargaxMARL()`` is the paper default (``shopping``, medium traffic);
    ``ChargaxMARL(scenario="shopping-grid25-high")`` picks a named scenario, keyword
    arguments of `chargax_marl.core.params.make_params` override it, and ``params=`` passes
    ready parameters.

    **Observations.** Every agent gets a float32 vector of the same size
    (`obs_size`): its own leaf features (8, `observation.PORT_FEATURES`), its
    kind one-hot (AC, DC, battery), the load fraction ``|grid-side net flow| / max_kw`` of each
    ancestor node from the deepest to the root (zero-padded to the tree depth; the flow is
    `chargax_marl.core.physics.node_flows_kw` of the currents in the state), the shared
    context (prices, time of day, ...), and the agent index (so a shared policy can tell
    agents apart): a one-hot by default, or with ``agent_id="scalar"`` one column
    ``index / (N - 1)``, which keeps the step linear in the number of agents for large
    stations. `get_global_state` is the single-agent observation.

    **Infos.** The single-agent view's keys (`chargax_marl.core.simulator.info_dict`;
    `step` adds ``terminated`` and ``truncated``) plus `AGENT_INFO_KEYS`. Every leaf has
    shape ``(num_agents,)`` and nothing else, the contract of JaxMARL's baselines (they
    reshape every info leaf of a batch of envs to ``(num_envs * num_agents,)``), which
    every wrapper of this package keeps: the step's reward and profit, every penalty
    term as ``penalty_<name>``, energies, prices, car counts, the running episode totals as
    ``episode_<name>`` (scalars broadcast to every agent), ``leaf_energy_kwh`` and its alias
    ``agent_energy_kwh``, each agent's own energy this step, and ``agent_reward_share``, each
    agent's share of the reward (`chargax_marl.core.reward.leaf_reward_shares`: the
    money its own energy made minus the penalties it caused and an even part of the fixed
    cost; the shares sum to the reward). The observations of the last step of a day, which
    the auto-reset replaces, are not in the infos (JaxMARL's convention);
    `chargax_marl.marl.FinalObservationWrapper` adds them for a loop that needs them.

    **Rewards.** By default every agent gets the shared station reward ``r``. The optional
    per-agent shaping ``local_reward_weight=w`` in ``[0, 1]`` gives agent ``i`` the reward
    ``(1 - w) * r + w * share_i`` instead: ``w = 1`` rewards each agent with its own share
    only (a local, lower-variance learning signal for independent learners), and the
    rewards of all agents then still add up to ``r``. Infos and episode totals report the
    station's reward and profit whatever ``w`` is, so evaluations stay comparable.

    Args:
        params: ready parameters (checked by `chargax_marl.core.params.validate_params`,
            kept as ``self.params``); None: built from ``scenario`` and
            ``make_params_kwargs``.
        scenario: a named scenario of `chargax_marl.core.scenarios` (also the coordination
            scenarios with a constrained grid connection, a time-of-use surcharge and a
            peak-demand charge); None: the `make_params` defaults.
        agent_id: the agent-index feature of the observations: ``"onehot"`` or ``"scalar"``.
        local_reward_weight: ``w`` in ``[0, 1]`` of the per-agent reward shaping above (0:
            the shared station reward).
        **make_params_kwargs: keyword arguments of `chargax_marl.core.params.make_params`
            (its ``Args:`` list them all), on top of the scenario's.

    Raises:
        ValueError: ``local_reward_weight`` outside ``[0, 1]``, ``params`` together with a
            scenario or keyword arguments, an unknown ``agent_id``, ``action_mode
            "continuous"``, or invalid params.
        KeyError: an unknown scenario, architecture, dataset or traffic level name.
        TypeError: a keyword `make_params` does not take.
    """

    def __init__(
        self,
        params: EnvParams | None = None,
        *,
        scenario: str | None = None,
        agent_id: str = "onehot",
        local_reward_weight: float = 0.0,
        **make_params_kwargs: Any,
    ):
        w = float(local_reward_weight)
        if not 0.0 <= w <= 1.0:  # also rejects NaN
            raise ValueError(
                f"ChargaxMARL: field 'local_reward_weight' must be in [0, 1] "
                f"(0: the shared station reward), got {local_reward_weight!r}"
            )
        self.local_reward_weight = w
        if params is not None and (make_params_kwargs or scenario is not None):
            raise ValueError(
                "ChargaxMARL: pass either 'params' or a scenario / keyword arguments of make_params, "
                "not both"
            )
        if scenario is not None:
            make_params_kwargs = scenario_kwargs(scenario, **make_params_kwargs)
        params = (
            validate_params(params) if params is not None else make_params(**make_params_kwargs)
        )
        if params.action_mode == "continuous":
            raise ValueError(
                "ChargaxMARL: action_mode 'continuous' is not supported by the multi-agent view "
                "(every agent has one Discrete space); use action_mode 'absolute' or 'delta', "
                "or the single-agent env chargax_marl.single.Chargax for continuous actions"
            )
        st = params.station
        super().__init__(num_agents=st.num_leaves)
        self.params = params
        self.agents = agent_names(params)
        self.agent_index = {a: i for i, a in enumerate(self.agents)}
        self.action_offset = action_offset(params)
        self.num_actions = params.num_levels + 1 + self.action_offset
        self._avail_np = np.asarray(avail_actions(params, self.action_offset))
        self._layout = obs_layout(params, agent_id)
        obs_shape = jax.eval_shape(
            lambda s: agent_observations(s, params, self._layout), simulator.empty_state(0, params)
        ).shape
        self.obs_size = int(obs_shape[1])
        low, high = bounds.agent_obs_bounds(
            params, np.asarray(self._layout.ancestors), int(np.shape(self._layout.agent_id)[1])
        )
        obs_space = spaces.Box(
            low, high, (self.obs_size,), jnp.float32
        )  # finite: chargax_marl.bounds
        act_space = spaces.Discrete(self.num_actions)
        self.observation_spaces = {a: obs_space for a in self.agents}
        self.action_spaces = {a: act_space for a in self.agents}

    # ------------------------------------------------------------------ JaxMARL API
    @functools.partial(jax.jit, static_argnums=(0,))
    def reset(self, key: jax.Array):
        """Start an empty station on a random day. Returns ``(obs, state)``."""
        state = simulator.reset(key, self.params)
        return self.get_obs(state), state

    def reset_to_day(self, day: int | jax.Array):
        """Start an empty station on a chosen day of the price data (for fixed evaluation days;
        ``ValueError`` for a concrete day outside ``[0, num_days)``, or the data's last day
        when episodes start after midnight, `chargax_marl.core.clock.num_episode_starts`).

        Args:
            day: the day index, a Python int or a JAX scalar (a traced day is not checked).

        Returns:
            ``(obs, state)``: the observations keyed by agent (`get_obs`) and the state.

        Raises:
            ValueError: a concrete day that is not a day an episode can start on
                (`chargax_marl.lifecycle.check_day`).
        """
        if not isinstance(day, jax.core.Tracer):
            check_day(day, clock.num_episode_starts(self.params))
        state = simulator.empty_state(jnp.asarray(day, jnp.int32), self.params)
        return self.get_obs(state), state

    def step_env(self, key: jax.Array, state: EnvState, actions: Mapping[str, Any]):
        """One transition without auto-reset: ``(obs, state, rewards, dones, infos)``.

        Args:
            key: the step's key.
            state: the state to step.
            actions: ``{agent: index}``, one entry per agent (`validate_actions`).

        Returns:
            ``(obs, state, rewards, dones, infos)``: the stepped state's observations keyed by
            agent, the stepped state (not reset at the day's end), the rewards keyed by agent,
            ``dones`` keyed by agent and ``"__all__"`` (true at the day's end), and the infos
            (the class docstring's keys without ``terminated`` and ``truncated``), each
            ``(num_agents,)``.

        Raises:
            ValueError: a bad action dict (`validate_actions`).
        """
        return self._dict_step(key, state, self.stack_actions(actions), None, auto_reset=False)

    def step(
        self,
        key: jax.Array,
        state: EnvState,
        actions: Mapping[str, Any],
        reset_state: EnvState | None = None,
    ):
        """JaxMARL's auto-resetting step: ``(obs, state, rewards, dones, infos)``; at the end of
        the day the returned state and observations are those of a fresh day (``reset_state``
        when given, else a random one) while rewards, dones and infos are the last step's.

        The action dict is checked here, once, before it enters ``jit``
        (`validate_actions`: host integers are clipped into int32, so a large one clips
        instead of wrapping); the transition is `step_arrays`'s. Under a caller's own
        ``jax.jit`` of this method JAX converts the dict at the jit boundary, before this code
        runs: with ``JAX_ENABLE_X64`` off a numpy ``int64`` beyond int32 wraps there and a
        Python ``int`` beyond int32 raises JAX's ``OverflowError``; call ``step`` outside
        ``jit`` (it jits itself) or clip with `chargax_marl.core.actions.host_array`
        first.

        Args:
            key: the step's key.
            state: the state to step.
            actions: ``{agent: index}``, one entry per agent (`validate_actions`).
            reset_state: the fresh day's state at the end of a day (None: a random one).

        Returns:
            ``(obs, state, rewards, dones, infos)``: the observations keyed by agent, the next
            state, the rewards keyed by agent, ``dones`` keyed by agent and ``"__all__"``, and
            the infos (the class docstring's keys, ``terminated`` and ``truncated`` included),
            each of shape ``(num_agents,)``.

        Raises:
            ValueError: a bad action dict (`validate_actions`).
        """
        return self._step(key, state, tuple(self.validate_actions(actions)), reset_state)

    def step_arrays(
        self,
        key: jax.Array,
        state: EnvState,
        indices: jax.Array,
        reset_state: EnvState | None = None,
    ):
        """The auto-resetting step on arrays, for trainers that batch the agents themselves:
        the transition of `step` without the per-agent dicts.

        Args:
            key: the step's key.
            state: the state to step.
            indices: ``(num_agents,)`` action indices in `agents` order (clipped into
                range, NaN idle, as `step`'s dict values; not validated on the host).
            reset_state: the fresh day's state at the end of a day (``None``: a random one).

        Returns:
            ``(obs (num_agents, obs_size), state, rewards (num_agents,), done (), info)``, the
            same values as `step`'s dicts (``obs`` stacked as `get_obs_matrix`);
            ``info`` as `step_arrays`'s with ``auto_reset``.
        """
        next_state, rewards, done, info = self._transition(key, state, indices, reset_state, True)
        obs = agent_observations(next_state, self.params, self._layout)
        return obs, next_state, rewards, done, info

    def _transition(
        self, key, state, indices, reset_state, auto_reset: bool, final_observation: bool = False
    ):
        """This env's `_transition`: ``(next_state, rewards, done, info)``."""
        return _transition(
            key,
            state,
            indices,
            self.params,
            self.action_offset,
            self._layout,
            self.local_reward_weight,
            auto_reset,
            reset_state,
            final_observation,
        )

    @functools.partial(jax.jit, static_argnums=(0,))
    def _step(self, key: jax.Array, state: EnvState, parts: tuple, reset_state: EnvState | None):
        return self._dict_step(key, state, self._stack(parts), reset_state, auto_reset=True)

    def _dict_step(
        self,
        key: jax.Array,
        state: EnvState,
        indices: jax.Array,
        reset_state: EnvState | None,
        *,
        auto_reset: bool,
        final_observation: bool = False,
    ):
        """The dict view of `step_arrays`: observation rows built per agent (no matrix),
        scalar infos broadcast to ``(num_agents,)``."""
        next_state, rewards, done, info = self._transition(
            key, state, indices, reset_state, auto_reset, final_observation
        )
        dones = {a: done for a in self.agents}
        dones["__all__"] = done
        n = self.num_agents
        infos = {k: v if jnp.ndim(v) else jnp.broadcast_to(v, (n,)) for k, v in info.items()}
        return self.get_obs(next_state), next_state, dict(zip(self.agents, rewards)), dones, infos

    def get_obs(self, state: EnvState) -> dict:
        """Observations keyed by agent (see the class docstring for the layout).

        Args:
            state: the env state.

        Returns:
            ``{agent: (obs_size,) float32}`` (`agent_observation_rows`).
        """
        return dict(zip(self.agents, agent_observation_rows(state, self.params, self._layout)))

    def get_obs_matrix(self, state: EnvState) -> jnp.ndarray:
        """All observations as one ``(num_agents, obs_size)`` matrix, rows in agent order.

        Args:
            state: the env state.

        Returns:
            ``(num_agents, obs_size)`` float32 (`agent_observations`).
        """
        return agent_observations(state, self.params, self._layout)

    @functools.partial(jax.jit, static_argnums=(0,))
    def get_avail_actions(self, state: EnvState) -> dict:
        """Bool mask ``(n,)`` per agent: ``False`` for levels its leaf cannot take (station-dependent only)."""
        del state
        avail = jnp.asarray(self._avail_np)
        return {a: avail[i] for i, a in enumerate(self.agents)}

    def get_global_state(self, state: EnvState) -> jnp.ndarray:
        """MAPPO's world state: the single-agent observation ``(state_size,)``.

        Args:
            state: the env state.

        Returns:
            ``(state_size,)`` float32 (`world_state`).
        """
        return world_state(state, self.params)

    @property
    def state_size(self) -> int:
        return observation.obs_size(self.params)

    @property
    def agent_classes(self) -> dict:
        """Agents by kind: ``{"dc_ports": [...], "ac_ports": [...], "batteries": [...]}`` (lists may be empty)."""
        kinds = np.asarray(self.params.station.leaf_kind)
        return {
            "dc_ports": [a for a, k in zip(self.agents, kinds) if k == KIND_DC],
            "ac_ports": [a for a, k in zip(self.agents, kinds) if k == KIND_AC],
            "batteries": [a for a, k in zip(self.agents, kinds) if k == KIND_BATTERY],
        }

    @property
    def name(self) -> str:
        return "ChargaxMARL"

    # ------------------------------------------------------------------ actions
    def validate_actions(self, actions: Mapping[str, Any], strict: bool = False) -> list:
        """The one check of an action dict; returns the agents' actions in agent order.

        Every entry point goes through it: `stack_actions` (``step``, ``step_env``,
        ``actions_to_levels``) with ``strict=False`` and `check_actions` (PettingZoo)
        with ``strict=True``. Host values are converted by
        `chargax_marl.core.actions.host_array` (integers clipped into int32); traced
        values get the structural checks only.

        Args:
            actions: ``{agent: index}`` with one entry per agent.
            strict: also require integer indices in ``[0, n)`` (else values outside are
                clipped later and floats truncated, NaN idle).

        Returns:
            The actions, one array of shape ``()`` or ``(1,)`` per agent, in agent order.

        Raises:
            ValueError: ``actions`` is not a dict, an agent is missing or unknown, an action is
                not a number or has a shape other than ``()`` or ``(1,)``; with ``strict``, an
                action is not an integer in ``[0, n)``. The message names the agent, the value
                and what is allowed.
        """
        n = self.num_actions
        allowed = f"an integer in [0, {n - 1}] (Discrete({n}))"
        if not isinstance(actions, Mapping):
            raise ValueError(
                f"actions must be a dict {{agent: {allowed}}}, got {type(actions).__name__}"
            )
        missing = [a for a in self.agents if a not in actions]
        unknown = [a for a in actions if a not in self.agent_index]
        if missing or unknown:
            raise ValueError(
                f"actions must have one entry per agent: missing agent(s) {missing}, "
                f"unknown agent(s) {unknown}; agents are {self.agents}, "
                f"each taking {allowed}"
            )
        out = []
        for a in self.agents:
            value = actions[a]
            try:
                x = core_actions.host_array(value, None, f"actions[{a!r}]")
            except ValueError as exc:
                raise ValueError(
                    f"action of agent {a!r} must be {allowed}, got {value!r} ({exc})"
                ) from None
            if np.shape(x) not in ((), (1,)):
                raise ValueError(
                    f"action of agent {a!r} must be {allowed} with shape () or (1,), "
                    f"got shape {np.shape(x)}"
                )
            traced = isinstance(x, jax.core.Tracer)
            raw = x if traced else np.asarray(value)
            if strict and not np.issubdtype(raw.dtype, np.integer):
                raise ValueError(
                    f"action of agent {a!r} must be {allowed}, got {value!r} (dtype {raw.dtype})"
                )
            if strict and not traced and not 0 <= int(raw.reshape(())) < n:
                raise ValueError(
                    f"action of agent {a!r} must be {allowed}, got {int(raw.reshape(()))}"
                )
            out.append(x)
        return out

    def stack_actions(self, actions: Mapping[str, Any]) -> jnp.ndarray:
        """The action dict as an int32 vector ``(num_agents,)`` in agent order (works under jit).

        Indices outside ``[0, n)`` are clipped into it (in their own dtype), floats truncated,
        NaN and +-inf idle.

        Args:
            actions: ``{agent: index}``, one entry per agent.

        Returns:
            ``(num_agents,)`` int32 indices in ``[0, num_actions)``.

        Raises:
            ValueError: as `validate_actions` (``strict=False``).
        """
        return self._stack(self.validate_actions(actions))

    def _stack(self, parts) -> jnp.ndarray:
        """Validated per-agent actions as clipped int32 indices ``(num_agents,)`` (traceable)."""
        top = self.num_actions - 1
        offset = self.action_offset
        return jnp.stack(
            [core_actions.to_int32(jnp.asarray(x).reshape(()), 0, top, offset) for x in parts]
        )

    def check_actions(self, actions: Mapping[str, Any]) -> np.ndarray:
        """The action dict as a numpy int32 index vector, every index required valid (PettingZoo).

        Masked actions are accepted (they fall back to idle). Traced values (inside ``jit``)
        get the structural checks only and give 0.

        Args:
            actions: ``{agent: index}``, one entry per agent.

        Returns:
            ``(num_agents,)`` numpy int32 indices, in agent order.

        Raises:
            ValueError: as `validate_actions` (``strict=True``).
        """
        return np.array(
            [
                0 if isinstance(x, jax.core.Tracer) else int(np.reshape(x, ()))
                for x in self.validate_actions(actions, strict=True)
            ],
            np.int32,
        )

    def actions_to_levels(self, actions: Mapping[str, jax.Array] | jax.Array) -> jnp.ndarray:
        """The core's signed levels ``(num_agents,)`` for an action dict or index vector.

        Args:
            actions: ``{agent: index}`` (checked by `stack_actions`), or a ``(num_agents,)``
                index vector in agent order (checked by
                `chargax_marl.core.actions.host_array`).

        Returns:
            ``(num_agents,)`` int32 levels (module-level `actions_to_levels`: out-of-range
            indices clipped, masked ones idle).

        Raises:
            ValueError: a bad action dict (`validate_actions`), or a vector of the wrong
                size or dtype.
        """
        indices = (
            self.stack_actions(actions)
            if isinstance(actions, Mapping)
            else core_actions.host_array(actions, self.num_agents)
        )
        return actions_to_levels(indices, self.params, self.action_offset)

    def levels_to_actions(self, levels: jax.Array) -> dict:
        """Action dict for valid signed levels ``(num_agents,)`` (e.g. a rule-based policy of
        `chargax_marl.policies`).

        Args:
            levels: ``(num_agents,)`` signed levels in agent order.

        Returns:
            ``{agent: int32 index}`` (`levels_to_indices`).
        """
        idx = levels_to_indices(levels, self.params, self.action_offset)
        return {a: idx[i] for i, a in enumerate(self.agents)}
