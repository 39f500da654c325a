"""PettingZoo ``ParallelEnv`` adapter of `ChargaxMARL`: numpy in and out, jitted JAX underneath.

``parallel_env(**kwargs)`` takes the keyword arguments of `chargax_marl.core.make_params`
(or ``params=``) plus ``render_mode``, ``max_cycles``, ``action_mask_in_obs``,
``local_reward_weight`` and ``agent_id``. One episode is one day (or ``max_cycles`` steps);
at its end every agent is truncated and ``agents`` becomes empty (no auto-reset): call
``reset()`` to start a new day. ``env(**kwargs)`` is the same environment through
PettingZoo's AEC API (``parallel_to_aec``), so this module works with PettingZoo's tests
and tutorials (``max_cycles_test(pettingzoo_env)``, ``render_test(pettingzoo_env.env)``).
"""

from __future__ import annotations

from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from pettingzoo.utils.conversions import parallel_to_aec
from pettingzoo.utils.env import ParallelEnv

from chargax_marl import bounds, lifecycle, rendering
from chargax_marl.core import clock, simulator
from chargax_marl.core.types import EnvParams
from chargax_marl.marl import communication
from chargax_marl.marl import env as marl_env
from chargax_marl.marl.env import ChargaxMARL


# Module-level jitted functions with ``params`` as a traced argument: every instance with
# the same station layout and static settings shares one compilation.
@jax.jit
def _reset_random(key: jax.Array, params: EnvParams, layout: marl_env.ObsLayout):
    key, sub = jax.random.split(key)
    state = simulator.reset(sub, params)
    return key, state, marl_env.agent_observations(state, params, layout)


@jax.jit
def _reset_day(day: jax.Array, params: EnvParams, layout: marl_env.ObsLayout):
    state = simulator.empty_state(day, params)
    return state, marl_env.agent_observations(state, params, layout)


@jax.jit(static_argnames=("offset",))
def _step(
    key: jax.Array,
    state,
    indices: jax.Array,
    params: EnvParams,
    layout: marl_env.ObsLayout,
    offset: int,
):
    key, sub = jax.random.split(key)
    obs, state, _, done, info = marl_env.step_arrays(sub, state, indices, params, offset, layout)
    # One float vector for the host (one transfer instead of one per info key): [station
    # reward, done, info scalars in INFO_KEYS order, energy per agent, reward share per agent].
    # The per-agent rewards are mixed on the host (ChargaxParallelEnv.step).
    packed = jnp.concatenate(
        [
            jnp.stack(
                [info["reward"], done.astype(jnp.float32)] + [info[k] for k in marl_env.INFO_KEYS]
            ),
            info["agent_energy_kwh"],
            info["agent_reward_share"],
        ]
    )
    return key, state, obs, packed


_world_state = jax.jit(marl_env.world_state)
_lose_actions = jax.jit(
    communication.lose_actions, static_argnames=("idle_index", "loss_prob", "lost_action")
)
_delay = jax.jit(communication.delay)


class ChargaxParallelEnv(ParallelEnv):
    """The station as a PettingZoo ``ParallelEnv`` (see `ChargaxMARL` for the model).

    - Observations: ``float32`` vectors in ``Box(low, high, (obs_size,))`` with finite bounds
      (`chargax_marl.bounds`), the same layout as `ChargaxMARL`. Actions:
      ``Discrete(n)`` per agent; ``infos[agent]["action_mask"]`` (a writable ``np.int8``
      copy) marks the valid ones; a masked action falls back to idle. With
      ``action_mask_in_obs=True`` each observation is instead
      ``{"observation": Box, "action_mask": MultiBinary(n)}`` (PettingZoo's classic-env
      convention, read by Tianshou, AgileRL and RLlib).
    - ``step`` raises ``ValueError`` naming the agent and the allowed range for a missing or
      unknown agent, an index outside the space or a non-integer action, and
      ``RuntimeError`` when called before ``reset`` or after the day ended.
    - Rewards are the shared station reward (EUR), or the per-agent mix of
      ``local_reward_weight`` (see `ChargaxMARL`); ``terminations`` are always ``False``;
      ``truncations`` turn ``True`` for every agent at the end of the day, or after
      ``max_cycles`` steps when given (a shorter episode, for tests and tutorials). ``infos[agent]``
      also holds the step's report as floats (profit, penalties, energies, prices, car
      counts, episode totals), ``energy_kwh``, the agent's own energy this step, and
      ``reward_share``, its share of the reward.
    - Seeding: ``reset(seed=s)`` starts a JAX key from any non-negative integer ``s``
      (`chargax_marl.lifecycle.key_from_seed`), so the same seed and actions give the
      same trajectory. ``reset()`` without a seed continues the key sequence; the first key
      is ``PRNGKey(0)`` (as the single-agent Gymnasium wrapper).
      ``reset(options={"day": d})`` starts on day ``d`` in ``[0, num_days)`` of the price
      data; a bad day or option key raises ``ValueError`` naming it.
    - ``state()`` is the single-agent observation (``state_space``). ``render()`` returns a
      text table (``render_mode="ansi"``), prints it (``"human"``) or returns an ``HxWx3``
      uint8 plot of the day so far (``"rgb_array"``).
    - Imperfect communication (`chargax_marl.marl.communication`, the same functions as
      its JaxMARL wrappers): ``observation_delay_steps=k`` shows each agent the shared context
      and its nodes' loads of ``k`` steps before (its own port stays current);
      ``action_loss_prob=p`` loses each agent's action with probability ``p``, the port then
      applying its previous action (``lost_action="previous"``) or idling (``"idle"``);
      ``infos[agent]["action_lost"]`` says whether it was. Both off by default.
    - In a process forked after JAX started, construction and every call raise
      `chargax_marl.lifecycle.ForkedProcessError` (use the ``spawn`` start method).

    Args:
        params: ready parameters; None: built from ``make_params_kwargs``.
        render_mode: ``"ansi"``, ``"human"``, ``"rgb_array"`` or None.
        max_cycles: truncate every agent after this many steps (a positive integer); None:
            at the end of the day.
        action_mask_in_obs: observations as ``{"observation", "action_mask"}`` dicts.
        observation_delay_steps: ``k >= 0``, the steps by which the shared context and the
            nodes' loads are seen late (0: none).
        action_loss_prob: ``p`` in ``[0, 1]``, the probability that an agent's action is
            lost (0: none).
        lost_action: what a port applies when its action is lost: ``"previous"`` or
            ``"idle"``.
        **make_params_kwargs: keyword arguments of `ChargaxMARL` (``scenario``,
            ``agent_id``, ``local_reward_weight``) and of
            `chargax_marl.core.params.make_params`.

    Raises:
        ValueError: an unknown ``render_mode``, ``max_cycles`` not a positive integer, a
            delay, loss probability or ``lost_action`` out of range, or an invalid
            `ChargaxMARL` argument.
        KeyError: an unknown scenario, architecture, dataset or traffic level name.
        TypeError: a keyword neither `ChargaxMARL` nor `make_params` takes.
        chargax_marl.lifecycle.ForkedProcessError: the process was forked after JAX started.
    """

    metadata = {
        "name": "chargax_v0",
        "render_modes": rendering.RENDER_MODES,
        "is_parallelizable": True,
        "render_fps": 4,
    }

    def __init__(
        self,
        params: EnvParams | None = None,
        render_mode: str | None = None,
        *,
        max_cycles: int | None = None,
        action_mask_in_obs: bool = False,
        observation_delay_steps: int = 0,
        action_loss_prob: float = 0.0,
        lost_action: str = "previous",
        **make_params_kwargs: Any,
    ):
        lifecycle.check_not_forked("ChargaxParallelEnv")
        rendering.check_render_mode(render_mode, "ChargaxParallelEnv")
        if max_cycles is not None and (
            isinstance(max_cycles, bool)
            or not isinstance(max_cycles, (int, np.integer))
            or max_cycles < 1
        ):
            raise ValueError(
                f"ChargaxParallelEnv: max_cycles must be a positive integer or None, got {max_cycles!r}"
            )
        self.max_cycles = None if max_cycles is None else int(max_cycles)
        self.action_mask_in_obs = bool(action_mask_in_obs)
        self.observation_delay_steps = communication.check_delay_steps(observation_delay_steps)
        self.action_loss_prob, self.lost_action = communication.check_loss(
            action_loss_prob, lost_action
        )
        self.env = ChargaxMARL(params=params, **make_params_kwargs)
        self._delayed_columns = communication.delayed_columns(self.env)
        self._idle = np.full(self.env.num_agents, self.env.action_offset, np.int32)
        self._delayed = None  # the delayed observations (communication.delay)
        self._applied = self._idle  # the indices the ports applied last step
        self.params = self.env.params
        self._layout = jax.tree.map(
            jnp.asarray, self.env._layout
        )  # on the device once, not per call
        self.render_mode = render_mode
        self.possible_agents = list(self.env.agents)
        self.agents: list[str] = []
        n_obs, n_act = self.env.obs_size, self.env.num_actions
        jax_space = self.env.observation_spaces[self.possible_agents[0]]
        low, high = np.asarray(jax_space.low, np.float32), np.asarray(jax_space.high, np.float32)
        box = gymnasium.spaces.Box(low, high, (n_obs,), np.float32)
        if self.action_mask_in_obs:
            self.observation_spaces = {
                a: gymnasium.spaces.Dict(
                    {"observation": box, "action_mask": gymnasium.spaces.MultiBinary(n_act)}
                )
                for a in self.possible_agents
            }
        else:
            self.observation_spaces = {a: box for a in self.possible_agents}
        self.action_spaces = {a: gymnasium.spaces.Discrete(n_act) for a in self.possible_agents}
        s_low, s_high = bounds.flat_obs_bounds(self.params)
        self.state_space = gymnasium.spaces.Box(s_low, s_high, s_low.shape, np.float32)
        avail = jax.device_get(self.env.get_avail_actions(simulator.empty_state(0, self.params)))
        self._masks = {}
        for a in self.possible_agents:
            self._masks[a] = np.asarray(avail[a], dtype=np.int8)
        self._key = jax.random.PRNGKey(0)
        self._state = None
        self._host_state = None
        self._history: list[tuple[float, float, float]] = []  # (hour, buy price, station kW)
        self._steps = 0

    # ------------------------------------------------------------------ spaces
    def observation_space(self, agent: str) -> gymnasium.spaces.Box | gymnasium.spaces.Dict:
        """An agent's observation space (PettingZoo's API).

        Args:
            agent: an agent name of ``possible_agents``.

        Returns:
            ``Box(low, high, (obs_size,), float32)``; with ``action_mask_in_obs`` a
            ``Dict`` of that box (``"observation"``) and ``MultiBinary(n)``
            (``"action_mask"``).
        """
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> gymnasium.spaces.Discrete:
        """An agent's action space (PettingZoo's API).

        Args:
            agent: an agent name of ``possible_agents``.

        Returns:
            ``Discrete(n)``, the same for every agent (`ChargaxMARL`'s actions).
        """
        return self.action_spaces[agent]

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None, options: dict | None = None):
        """Start a day with an empty station; every agent of ``possible_agents`` is live.

        Args:
            seed: a non-negative integer that starts the env's key
                (`chargax_marl.lifecycle.key_from_seed`); None continues the key sequence.
            options: ``{"day": d}`` starts on day ``d`` of the price data (an episode's start
                day, `chargax_marl.core.clock.num_episode_starts`); without it a random day is
                drawn. Other keys are ignored.

        Returns:
            ``(observations, infos)``: the observation keyed by agent (see the class
            docstring for its form), and ``{agent: {"action_mask": (n,) int8}}``.

        Raises:
            ValueError: a bad seed (`chargax_marl.lifecycle.key_from_seed`) or ``options``
                (`chargax_marl.lifecycle.reset_day`).
            chargax_marl.lifecycle.ForkedProcessError: the process was forked after JAX
                started.
        """
        lifecycle.check_not_forked("ChargaxParallelEnv.reset")
        key = None if seed is None else lifecycle.key_from_seed(seed, "ChargaxParallelEnv.reset")
        day = lifecycle.reset_day(
            options, clock.num_episode_starts(self.params), "ChargaxParallelEnv.reset"
        )
        if key is not None:
            self._key = key
        if day is not None:
            self._state, obs = _reset_day(jnp.asarray(day, jnp.int32), self.params, self._layout)
        else:
            self._key, self._state, obs = _reset_random(self._key, self.params, self._layout)
        self._host_state = None
        self._history = []
        self._steps = 0
        self._delayed = communication.start_history(obs, self.observation_delay_steps)
        self._applied = self._idle
        self.agents = list(self.possible_agents)
        obs = np.array(obs, dtype=np.float32)
        return (
            {a: self._observation(a, obs[i]) for i, a in enumerate(self.agents)},
            {a: {"action_mask": self._masks[a].copy()} for a in self.agents},
        )

    def _observation(self, agent: str, row: np.ndarray):
        if self.action_mask_in_obs:
            return {"observation": row, "action_mask": self._masks[agent].copy()}
        return row

    def step(self, actions: dict):
        """Step the station once with every live agent's action (PettingZoo's API).

        Args:
            actions: ``{agent: index}``, one integer in ``[0, n)`` per live agent
                (`ChargaxMARL.check_actions`); a masked index plays as idle.

        Returns:
            ``(observations, rewards, terminations, truncations, infos)`` keyed by agent: the
            observations of the stepped state (delayed columns as set), the rewards (floats,
            EUR; the station reward or its per-agent mix), ``terminations`` always False,
            ``truncations`` True for every agent at the day's end or after ``max_cycles``
            steps, and the infos (the step's report as floats, ``energy_kwh``,
            ``reward_share``, ``action_lost``, ``action_mask``). After a truncation
            ``agents`` is empty.

        Raises:
            RuntimeError: called before `reset`, or after the episode ended.
            ValueError: a bad action dict (`ChargaxMARL.validate_actions`, strict).
            chargax_marl.lifecycle.ForkedProcessError: the process was forked after JAX
                started.
        """
        lifecycle.check_not_forked("ChargaxParallelEnv.step")
        if self._state is None:
            raise RuntimeError(
                "ChargaxParallelEnv.step() called before reset(); call reset() to start a day"
            )
        if not self.agents:
            raise RuntimeError(
                "ChargaxParallelEnv.step() called after the episode ended (the day is over and "
                "every agent is truncated); call reset() to start a new day"
            )
        indices = self.env.check_actions(actions)
        lost = np.zeros(len(indices), bool)
        if self.action_loss_prob > 0.0:
            indices, lost = jax.device_get(
                _lose_actions(
                    self._key,
                    indices,
                    self._applied,
                    idle_index=int(self.env.action_offset),
                    loss_prob=self.action_loss_prob,
                    lost_action=self.lost_action,
                )
            )
            self._applied = np.asarray(indices, np.int32)
        self._key, self._state, obs, packed = _step(
            self._key, self._state, indices, self.params, self._layout, self.env.action_offset
        )
        if self.observation_delay_steps:
            obs, self._delayed = _delay(obs, self._delayed, self._delayed_columns, False)
        obs, packed = jax.device_get((obs, packed))
        self._host_state = None
        obs = np.array(obs, dtype=np.float32)
        values = packed.tolist()
        reward, done = values[0], bool(values[1])
        self._steps += 1
        if self.max_cycles is not None and self._steps >= self.max_cycles:
            done = True
        k = len(marl_env.INFO_KEYS)
        shared = dict(zip(marl_env.INFO_KEYS, values[2 : 2 + k]))
        n = len(self.possible_agents)
        energy = values[2 + k : 2 + k + n]
        shares = values[2 + k + n :]
        per_agent = marl_env.agent_rewards(reward, np.asarray(shares), self.env.local_reward_weight)
        self._history.append(
            (
                self._hours_now(),
                shared["price_buy_eur_kwh"],
                shared["grid_net_kwh"] / self.params.step_hours,
            )
        )
        agents = self.agents
        observations = {a: self._observation(a, obs[i]) for i, a in enumerate(agents)}
        rewards = {a: float(per_agent[i]) for i, a in enumerate(agents)}
        terminations = {a: False for a in agents}
        truncations = {a: done for a in agents}
        infos = {
            a: {
                **shared,
                "energy_kwh": energy[i],
                "reward_share": shares[i],
                "action_lost": bool(lost[i]),
                "action_mask": self._masks[a].copy(),
            }
            for i, a in enumerate(agents)
        }
        if done:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return observations, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """The global state: the single-agent observation of the current station state."""
        if self._state is None:
            raise RuntimeError("ChargaxParallelEnv.state() called before reset()")
        return np.array(_world_state(self._state, self.params), dtype=np.float32)

    # ------------------------------------------------------------------ rendering
    def _host(self):
        if self._host_state is None:
            self._host_state = jax.device_get(self._state)
        return self._host_state

    def _hours_now(self) -> float:
        return len(self._history) * self.params.step_minutes / 60.0

    def render(self):
        state = None if self._state is None else self._host()
        return rendering.render(
            self.render_mode,
            state,
            self.params,
            self.possible_agents,
            self._history,
            "ChargaxParallelEnv",
        )

    def close(self) -> None:
        self._state = None
        self._host_state = None
        self._history = []
        self.agents = []


def parallel_env(**kwargs: Any) -> ChargaxParallelEnv:
    """Build a `ChargaxParallelEnv`.

    Args:
        **kwargs: keyword arguments of `ChargaxParallelEnv` (``params``, ``render_mode``,
            ``max_cycles``, ``action_mask_in_obs``, the communication settings), of
            `ChargaxMARL` (``scenario``, ``agent_id``, ``local_reward_weight``) and of
            `chargax_marl.core.params.make_params`.

    Returns:
        The PettingZoo ``ParallelEnv``.
    """
    return ChargaxParallelEnv(**kwargs)


def raw_env(**kwargs: Any):
    """The AEC view of `parallel_env` (PettingZoo's ``parallel_to_aec``).

    Args:
        **kwargs: the keyword arguments of `parallel_env`.

    Returns:
        The PettingZoo ``AECEnv``.
    """
    return parallel_to_aec(ChargaxParallelEnv(**kwargs))


def env(**kwargs: Any):
    """PettingZoo's AEC constructor: `raw_env`.

    Agents act one after another within a cycle; the station steps once all have acted.

    Args:
        **kwargs: the keyword arguments of `parallel_env`.

    Returns:
        The PettingZoo ``AECEnv``.
    """
    return raw_env(**kwargs)


__all__ = ["ChargaxParallelEnv", "env", "parallel_env", "raw_env"]
