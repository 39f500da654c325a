"""PettingZoo ``ParallelEnv`` adapter of :class:`ChargaxMARL`: numpy in and out, jitted JAX underneath.

``parallel_env(**kwargs)`` takes the keyword arguments of :func:`chargax_marl.core.make_params`
(or ``params=``) plus ``render_mode``. One episode is one day; at its end every agent is
truncated and ``agents`` becomes empty (no auto-reset): call ``reset()`` to start a new day.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from pettingzoo.utils.env import ParallelEnv

from chargax_marl.core import simulator
from chargax_marl.core.station import KIND_NAMES
from chargax_marl.core.types import EnvParams
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
def _step(key: jax.Array, state, indices: jax.Array, params: EnvParams, layout: marl_env.ObsLayout, offset: int):
    key, sub = jax.random.split(key)
    obs, state, reward, done, info = marl_env.step_arrays(sub, state, indices, params, offset, layout)
    # One float vector for the host (one transfer instead of one per info key):
    # [reward, done, info scalars in INFO_KEYS order, energy per agent, reward share per agent]
    packed = jnp.concatenate([jnp.stack([reward.astype(jnp.float32), done.astype(jnp.float32)]
                                        + [info[k] for k in marl_env.INFO_KEYS]),
                              info["agent_energy_kwh"], info["agent_reward_share"]])
    return key, state, obs, packed


_world_state = jax.jit(marl_env.world_state)


class ChargaxParallelEnv(ParallelEnv):
    """The station as a PettingZoo ``ParallelEnv`` (see :class:`ChargaxMARL` for the model).

    - Observations: ``float32`` vectors in ``Box(-inf, inf, (obs_size,))``, the same layout as
      :class:`ChargaxMARL`. Actions: ``Discrete(n)`` per agent; ``infos[agent]["action_mask"]``
      (``np.int8``) marks the valid ones; a masked action falls back to idle.
    - ``step`` raises ``ValueError`` naming the agent and the allowed range for a missing or
      unknown agent, an index outside the space or a non-integer action, and
      ``RuntimeError`` when called before ``reset`` or after the day ended.
    - Rewards are the shared station reward (EUR), or the per-agent mix of
      ``local_reward_weight`` (see :class:`ChargaxMARL`); ``terminations`` are always ``False``;
      ``truncations`` turn ``True`` for every agent at the end of the day. ``infos[agent]``
      also holds the step's report as floats (profit, penalties, energies, prices, car
      counts, episode totals), ``energy_kwh``, the agent's own energy this step, and
      ``reward_share``, its share of the reward.
    - Seeding: ``reset(seed=s)`` starts a JAX key from ``s``, so the same seed and actions
      give the same trajectory. ``reset()`` without a seed continues the key sequence; the
      first key is ``PRNGKey(0)`` (as the single-agent Gymnasium wrapper).
      ``reset(options={"day": d})`` starts on day ``d`` of the price data.
    - ``state()`` is the single-agent observation (``state_space``). ``render()`` returns a
      text table (``render_mode="ansi"``) or an ``HxWx3`` uint8 plot of the day so far
      (``"rgb_array"``).
    """

    metadata = {"name": "chargax_v0", "render_modes": ["ansi", "rgb_array"], "is_parallelizable": True}

    def __init__(self, params: EnvParams | None = None, render_mode: str | None = None, **make_params_kwargs: Any):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.env = ChargaxMARL(params=params, **make_params_kwargs)
        self.params = self.env.params
        self._layout = jax.tree.map(jnp.asarray, self.env._layout)  # on the device once, not per call
        self.render_mode = render_mode
        self.possible_agents = list(self.env.agents)
        self.agents: list[str] = []
        n_obs, n_act = self.env.obs_size, self.env.num_actions
        self.observation_spaces = {
            a: gymnasium.spaces.Box(-np.inf, np.inf, (n_obs,), np.float32) for a in self.possible_agents
        }
        self.action_spaces = {a: gymnasium.spaces.Discrete(n_act) for a in self.possible_agents}
        self.state_space = gymnasium.spaces.Box(-np.inf, np.inf, (self.env.state_size,), np.float32)
        avail = jax.device_get(self.env.get_avail_actions(simulator.empty_state(0, self.params)))
        self._masks = {}
        for a in self.possible_agents:
            m = np.asarray(avail[a], dtype=np.int8)
            m.setflags(write=False)
            self._masks[a] = m
        self._key = jax.random.PRNGKey(0)
        self._state = None
        self._host_state = None
        self._history: list[tuple[float, float, float]] = []  # (hour, buy price, station kW)

    # ------------------------------------------------------------------ spaces
    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> gymnasium.spaces.Discrete:
        return self.action_spaces[agent]

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._key = jax.random.PRNGKey(int(seed))
        if options and "day" in options:
            day = int(options["day"])
            if not 0 <= day < self.params.num_days:
                raise ValueError(f"options['day'] must be in [0, {self.params.num_days - 1}], got {day}")
            self._state, obs = _reset_day(jnp.asarray(day, jnp.int32), self.params, self._layout)
        else:
            self._key, self._state, obs = _reset_random(self._key, self.params, self._layout)
        self._host_state = None
        self._history = []
        self.agents = list(self.possible_agents)
        obs = np.array(obs, dtype=np.float32)
        return ({a: obs[i] for i, a in enumerate(self.agents)},
                {a: {"action_mask": self._masks[a]} for a in self.agents})

    def step(self, actions: dict):
        if self._state is None:
            raise RuntimeError("ChargaxParallelEnv.step() called before reset(); call reset() to start a day")
        if not self.agents:
            raise RuntimeError("ChargaxParallelEnv.step() called after the episode ended (the day is over and "
                               "every agent is truncated); call reset() to start a new day")
        indices = self.env.check_actions(actions)
        self._key, self._state, obs, packed = _step(self._key, self._state, indices, self.params, self._layout,
                                                    self.env.action_offset)
        obs, packed = jax.device_get((obs, packed))
        self._host_state = None
        obs = np.array(obs, dtype=np.float32)
        values = packed.tolist()
        reward, done = values[0], bool(values[1])
        k = len(marl_env.INFO_KEYS)
        shared = dict(zip(marl_env.INFO_KEYS, values[2:2 + k]))
        n = len(self.possible_agents)
        energy = values[2 + k:2 + k + n]
        shares = values[2 + k + n:]
        per_agent = marl_env.agent_rewards(reward, np.asarray(shares), self.env.local_reward_weight)
        self._history.append((self._hours_now(), shared["price_buy_eur_kwh"],
                              shared["grid_net_kwh"] / self.params.step_hours))
        agents = self.agents
        observations = {a: obs[i] for i, a in enumerate(agents)}
        rewards = {a: float(per_agent[i]) for i, a in enumerate(agents)}
        terminations = {a: False for a in agents}
        truncations = {a: done for a in agents}
        infos = {a: {**shared, "energy_kwh": energy[i], "reward_share": shares[i], "action_mask": self._masks[a]}
                 for i, a in enumerate(agents)}
        if done:
            self.agents = []
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

    def _price_now(self) -> float:
        s = self._host()
        hour = min(int(int(s.timestep) * self.params.step_minutes // 60), 23)
        day = int(s.day) % self.params.num_days
        return float(np.asarray(self.params.prices_eur_kwh)[day, hour])

    def render(self):
        if self.render_mode is None:
            gymnasium.logger.warn("ChargaxParallelEnv.render() called without a render_mode; "
                                  "pass render_mode='ansi' or 'rgb_array' to parallel_env()")
            return None
        if self._state is None:
            raise RuntimeError("ChargaxParallelEnv.render() called before reset()")
        if self.render_mode == "ansi":
            return self._render_ansi()
        return self._render_rgb()

    def _render_ansi(self) -> str:
        s = self._host()
        st = self.params.station
        kinds = np.asarray(st.leaf_kind)
        volts = np.asarray(st.leaf_voltage_v)
        minutes = int(s.timestep) * self.params.step_minutes
        lines = [
            f"day {int(s.day)}  step {int(s.timestep)}/{self.params.num_steps}  "
            f"time {int(minutes // 60):02d}:{int(minutes % 60):02d}  "
            f"price {self._price_now():.4f} EUR/kWh  profit so far {float(s.totals.profit_eur):.2f} EUR",
            f"{'agent':<12}{'kind':<9}{'occupied':>9}{'SoC':>7}{'current A':>11}{'power kW':>10}",
        ]
        for i, a in enumerate(self.possible_agents):
            occ = bool(s.occupied[i])
            soc = f"{float(s.soc[i]):.2f}" if occ else "-"
            cur = float(s.current_a[i]) + 0.0  # no "-0.0"
            lines.append(f"{a:<12}{KIND_NAMES[int(kinds[i])]:<9}{('yes' if occ else 'no'):>9}{soc:>7}"
                         f"{cur:>11.1f}{cur * float(volts[i]) / 1000.0:>10.1f}")
        return "\n".join(lines)

    def _render_rgb(self) -> np.ndarray:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6.4, 4.0), dpi=80)
        canvas = FigureCanvasAgg(fig)
        ax_price, ax_power = fig.subplots(2, 1, sharex=True)
        if self._history:
            h = np.asarray(self._history)
            ax_price.step(h[:, 0], h[:, 1], where="post", color="tab:orange")
            ax_power.step(h[:, 0], h[:, 2], where="post", color="tab:blue")
        ax_price.set_ylabel("price EUR/kWh")
        ax_power.set_ylabel("station kW")
        ax_power.set_xlabel("hour of the day")
        ax_power.set_xlim(0, 24)
        s = self._host()
        ax_price.set_title(f"day {int(s.day)}, step {int(s.timestep)}/{self.params.num_steps}")
        fig.tight_layout()
        canvas.draw()
        return np.array(canvas.buffer_rgba(), dtype=np.uint8)[..., :3].copy()

    def close(self) -> None:
        self._state = None
        self._host_state = None
        self._history = []
        self.agents = []


def parallel_env(**kwargs: Any) -> ChargaxParallelEnv:
    """Build a :class:`ChargaxParallelEnv` (``render_mode=``, ``params=`` or ``make_params`` keywords)."""
    return ChargaxParallelEnv(**kwargs)


__all__ = ["ChargaxParallelEnv", "parallel_env"]
