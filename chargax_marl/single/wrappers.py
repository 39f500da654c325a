"""Wrappers of the single-agent env: episode logging and a flat ``Discrete`` view (JAX),
and a Gymnasium adapter (numpy)."""

from __future__ import annotations

from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from gymnax.environments import spaces as gx_spaces

from chargax_marl import bounds, lifecycle, rendering
from chargax_marl.core import actions, clock, observation, simulator
from chargax_marl.core.params import validate_params
from chargax_marl.core.types import EnvParams, EnvState, EpisodeTotals
from chargax_marl.single.env import Chargax, action_levels


@struct.dataclass
class LogState:
    """The state of the single-agent `LogWrapper`: the wrapped env's state and the episode
    statistics, each a scalar.

    Attributes:
        env_state: the wrapped env's state.
        episode_return: the return so far in the running episode (float32).
        episode_length: the steps so far in the running episode (int32).
        returned_episode_return: the return of the last finished episode (float32).
        returned_episode_length: the length of the last finished episode (int32).
        returned_totals: the last finished episode's `EpisodeTotals`.
    """

    env_state: EnvState
    episode_return: jnp.ndarray
    episode_length: jnp.ndarray
    returned_episode_return: jnp.ndarray
    returned_episode_length: jnp.ndarray
    returned_totals: EpisodeTotals


class LogWrapper:
    """Track episode returns, lengths and the episode totals across auto-resets.

    ``info`` gains ``returned_episode_returns``, ``returned_episode_lengths``,
    ``returned_episode`` (True on the step that ended an episode) and
    ``returned_episode_<total>`` for every field of `EpisodeTotals` (profit,
    energies, cars served and rejected, ...), each holding the last finished episode's value.

    Args:
        env: the single-agent env to wrap (a `Chargax` or a wrapper of one); every other
            attribute is forwarded to it.
    """

    def __init__(self, env: Chargax):
        self._env = env

    def __getattr__(self, name: str):
        return getattr(self._env, name)

    def reset(self, key: jax.Array, params: EnvParams | None = None):
        """The wrapped env's ``reset``, with the episode statistics at zero.

        Args:
            key: the reset's key.
            params: the environment parameters; None: the wrapped env's defaults.

        Returns:
            ``(obs, state)``: the wrapped env's observation and a `LogState`.
        """
        obs, env_state = self._env.reset(key, params)
        zero = jnp.zeros((), jnp.float32)
        state = LogState(
            env_state,
            zero,
            jnp.zeros((), jnp.int32),
            zero,
            jnp.zeros((), jnp.int32),
            EpisodeTotals.zeros(),
        )
        return obs, state

    def step(self, key: jax.Array, state: LogState, action, params: EnvParams | None = None):
        """The wrapped env's auto-resetting ``step``, with the episode logging.

        Args:
            key: the step's key.
            state: the `LogState`.
            action: an action of the wrapped env's space.
            params: the environment parameters; None: the wrapped env's defaults.

        Returns:
            ``(obs, state, reward, terminated, truncated, info)``: the wrapped env's values,
            the `LogState` after the step, and ``info`` with the logged entries (the class
            docstring).
        """
        obs, env_state, reward, terminated, truncated, info = self._env.step(
            key, state.env_state, action, params
        )
        done = jnp.logical_or(terminated, truncated)
        ep_return = state.episode_return + reward
        ep_length = state.episode_length + 1
        finished = EpisodeTotals(
            **{k: info[f"episode_{k}"] for k in EpisodeTotals.__dataclass_fields__}
        )
        totals = jax.tree.map(
            lambda new, old: jnp.where(done, new, old), finished, state.returned_totals
        )
        new_state = LogState(
            env_state=env_state,
            episode_return=ep_return * (1 - done),
            episode_length=ep_length * (1 - done),
            returned_episode_return=jnp.where(done, ep_return, state.returned_episode_return),
            returned_episode_length=jnp.where(done, ep_length, state.returned_episode_length),
            returned_totals=totals,
        )
        info = dict(info)
        info["returned_episode_returns"] = new_state.returned_episode_return
        info["returned_episode_lengths"] = new_state.returned_episode_length
        info["returned_episode"] = done
        info.update(
            {
                f"returned_episode_{k}": getattr(totals, k)
                for k in EpisodeTotals.__dataclass_fields__
            }
        )
        return obs, new_state, reward, terminated, truncated, info


class FlatDiscrete:
    """A ``Discrete`` view of the single-agent env for code that expects one (PureJaxRL's
    ``ppo.py``, gymnax's wrappers, DQN heads).

    Action ``a`` in ``Discrete(n_port * n_battery)`` sets one shared level for every port,
    ``port_levels[a // n_battery]``, and one shared level for every station battery,
    ``battery_levels[a % n_battery]``. ``port_levels`` runs from the lowest level any port
    can take (``-L`` with V2G, else 0) to ``L``; a port that cannot discharge idles at a
    negative shared level. ``battery_levels`` is ``-L .. L`` (just ``[0]`` without a
    battery). With the defaults (``L = 10``, V2G) that is ``Discrete(441)``; index
    ``n_battery * (n_port - 1) + L`` is every port at full power with the battery idle.
    Actions outside ``[0, n)`` are clipped. Only ``action_mode="absolute"``.

    ``reset``, ``step``, ``observation_space`` and every other attribute are the wrapped
    env's; ``action_space()`` is ``gymnax.environments.spaces.Discrete(n)`` and
    ``num_actions`` is ``n``, as gymnax code expects::

        env = LogWrapper(FlatDiscrete(Chargax()))   # gymnax.wrappers.purerl.LogWrapper also works

    Args:
        env: the single-agent env to wrap, built with ``action_mode="absolute"``.

    Raises:
        ValueError: the env's ``action_mode`` is not ``"absolute"``.
    """

    def __init__(self, env: Chargax):
        self._env = env
        params = env.default_params
        if params.action_mode != "absolute":
            raise ValueError(
                f"FlatDiscrete: field 'action_mode' must be 'absolute', got {params.action_mode!r}"
            )
        st = params.station
        with jax.ensure_compile_time_eval():
            self._min_level = np.asarray(env.min_level(params), np.int32)
        L = params.num_levels
        p, b = st.num_ports, st.num_batteries
        low = int(self._min_level[:p].min()) if p else 0
        self.port_levels = np.arange(low, L + 1, dtype=np.int32)
        self.battery_levels = np.arange(-L, L + 1, dtype=np.int32) if b else np.zeros(1, np.int32)
        self._is_port = np.arange(st.num_leaves) < p
        self.n = int(self.port_levels.size * self.battery_levels.size)

    def __getattr__(self, name: str):
        if name == "_env":
            raise AttributeError(name)
        return getattr(self._env, name)

    @property
    def num_actions(self) -> int:
        return self.n

    def action_space(self, params: EnvParams | None = None) -> gx_spaces.Discrete:
        """The flat action space.

        Args:
            params: unused (gymnax's signature); the space is the construction's.

        Returns:
            ``gymnax.environments.spaces.Discrete(n)``.
        """
        return gx_spaces.Discrete(self.n)

    def action_index(self, port_level: int, battery_level: int = 0) -> int:
        """The flat action of a shared port level and battery level (host side).

        Args:
            port_level: a level of `port_levels`.
            battery_level: a level of `battery_levels` (0 without a battery).

        Returns:
            The index ``i * len(battery_levels) + j`` of the two levels' positions ``i`` and
            ``j``.

        Raises:
            ValueError: a level that is not in `port_levels` or `battery_levels`, naming the
                field, the value and the levels allowed.
        """
        i, j = (
            np.flatnonzero(levels == level)
            for levels, level in (
                (self.port_levels, port_level),
                (self.battery_levels, battery_level),
            )
        )
        for field, value, found, allowed in (
            ("port_level", port_level, i, self.port_levels),
            ("battery_level", battery_level, j, self.battery_levels),
        ):
            if not found.size:
                raise ValueError(f"{field} {value!r} is not one of {allowed.tolist()}")
        return int(i[0]) * self.battery_levels.size + int(j[0])

    def levels(self, action) -> jnp.ndarray:
        """The per-leaf levels ``(L,)`` of a flat action (works under jit).

        An index outside ``[0, n)`` is clipped into it in its own dtype (a host integer beyond
        int32 on the host first, `chargax_marl.core.actions.host_array`), so it never
        wraps; NaN and +-inf are the index of every leaf idle.

        Args:
            action: a flat action, a scalar (or an array of one element).

        Returns:
            ``(num_leaves,)`` int32 signed levels: the shared port level for the ports, the
            shared battery level for the batteries, each raised to the leaf's lowest level
            (a port that cannot discharge idles at a negative level).
        """
        idle = self.action_index(0, 0)
        a = actions.to_int32(jnp.reshape(actions.host_array(action), ()), 0, self.n - 1, idle)
        nb = self.battery_levels.size
        port = jnp.asarray(self.port_levels)[a // nb]
        bat = jnp.asarray(self.battery_levels)[a % nb]
        lv = jnp.where(jnp.asarray(self._is_port), port, bat)
        return jnp.maximum(lv, jnp.asarray(self._min_level))

    def to_env_action(self, action) -> jnp.ndarray:
        """The wrapped env's ``MultiDiscrete`` action of a flat action.

        Args:
            action: a flat action (`levels`).

        Returns:
            ``(num_leaves,)`` int32 indices of the wrapped env's action space.
        """
        return self.levels(action) - jnp.asarray(self._min_level)

    def reset(self, key: jax.Array, params: EnvParams | None = None):
        """The wrapped env's ``reset``, unchanged.

        Args:
            key: the reset's key.
            params: the environment parameters; None: the wrapped env's defaults.

        Returns:
            ``(obs, state)`` of the wrapped env.
        """
        return self._env.reset(key, params)

    def step(self, key: jax.Array, state, action, params: EnvParams | None = None):
        """The wrapped env's ``step`` with a flat action (`to_env_action`).

        Args:
            key: the step's key.
            state: the wrapped env's state.
            action: a flat action in ``Discrete(n)`` (clipped into range).
            params: the environment parameters; None: the wrapped env's defaults.

        Returns:
            ``(obs, state, reward, terminated, truncated, info)`` of the wrapped env's step.
        """
        return self._env.step(key, state, self.to_env_action(action), params)


# Module-level jitted functions with ``params`` as a traced argument: every GymnasiumEnv of
# a plain Chargax with the same station layout and static settings shares one compilation
# (and the wrapper holds no jitted attribute, so it pickles). They take arrays only:
# GymnasiumEnv.step checks the host action against the space first.


@jax.jit
def _shared_reset(key: jax.Array, params: EnvParams):
    key, sub = jax.random.split(key)
    state = simulator.reset(sub, params)
    return key, observation.flat_obs(state, params), state


@jax.jit
def _shared_reset_day(day: jax.Array, params: EnvParams):
    state = simulator.empty_state(day, params)
    return observation.flat_obs(state, params), state


@jax.jit
def _shared_step(key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams):
    key, sub = jax.random.split(key)
    new_state, info = simulator.step(sub, state, action_levels(action, params), params)
    return (
        key,
        observation.flat_obs(new_state, params),
        new_state,
        info.reward,
        simulator.is_done(new_state, params),
        simulator.info_dict(info, new_state, params),
    )


def compile_count() -> int:
    """How many times the shared reset and step were compiled in this process (for tests).

    Returns:
        The number of entries in the compilation caches of the shared random reset and step
        (the reset to a chosen day is not counted).
    """
    return int(_shared_reset._cache_size()) + int(_shared_step._cache_size())


class GymnasiumEnv(gymnasium.Env):
    """Gymnasium adapter: numpy in and out, jitted JAX underneath.

    - Observation: ``Box(low, high, (n,), float32)`` with finite bounds the observations
      respect (`chargax_marl.bounds`). Action: ``MultiDiscrete`` with one entry per port
      and battery (discrete modes) or ``Box(-1, 1)`` (continuous).
    - The episode is one day; it ends with ``truncated=True`` and does not auto-reset:
      ``step`` after that raises ``RuntimeError`` until ``reset``.
    - ``reset(seed=s)`` accepts any non-negative integer (``ValueError`` otherwise); the same
      seed gives the same day and cars (`chargax_marl.lifecycle.key_from_seed`;
      seeds below ``2**32`` use ``jax.random.PRNGKey(seed)``).
      ``reset(options={"day": d})`` starts on day ``d`` in ``[0, num_days)`` of the price data
      (all but the last when episodes start after midnight).
    - ``render_mode``: ``"ansi"`` (text table), ``"human"`` (prints it) or ``"rgb_array"``.
    - Instances of a plain `Chargax` share one compiled reset and step per station
      layout and static settings; the wrapper pickles.
    - In a process forked after JAX started, construction and every call raise
      `chargax_marl.lifecycle.ForkedProcessError` (use the ``spawn`` start method).

    Args:
        env: the single-agent env to adapt; None: a `Chargax` built from ``params`` or
            ``overrides``.
        params: the parameters to run with (checked by
            `chargax_marl.core.params.validate_params`); None: the env's ``default_params``.
        render_mode: ``"ansi"``, ``"human"``, ``"rgb_array"`` or None.
        **overrides: keyword arguments of `chargax_marl.core.params.make_params`, when
            ``env`` is None.

    Raises:
        ValueError: both ``env`` and ``overrides`` given, an unknown ``render_mode``, or
            invalid params.
        KeyError: an unknown architecture, dataset or traffic level name (`make_params`).
        TypeError: a keyword `make_params` does not take.
        chargax_marl.lifecycle.ForkedProcessError: the process was forked after JAX started.
    """

    metadata = {"render_modes": rendering.RENDER_MODES, "render_fps": 4}

    def __init__(
        self,
        env: Chargax | None = None,
        params: EnvParams | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ):
        lifecycle.check_not_forked("GymnasiumEnv")
        rendering.check_render_mode(render_mode, "GymnasiumEnv")
        if env is None:
            env = Chargax(params=params, **overrides)
        elif overrides:
            raise ValueError(
                f"GymnasiumEnv: pass either 'env' or keyword overrides, not both (got {sorted(overrides)})"
            )
        self.env = env
        self.params = validate_params(params) if params is not None else env.default_params
        self.render_mode = render_mode
        self._build()
        self._key = jax.random.PRNGKey(0)
        self._state = None
        self._done = False
        self._history: list[tuple[float, float, float]] = []

    def _build(self) -> None:
        space = self.env.action_space(self.params)
        if self.params.action_mode == "continuous":
            self.action_space = gymnasium.spaces.Box(-1.0, 1.0, space.shape, np.float32)
        else:
            self.action_space = gymnasium.spaces.MultiDiscrete(
                np.asarray(space.nvec, dtype=np.int64)
            )
        low, high = bounds.flat_obs_bounds(self.params)
        self.observation_space = gymnasium.spaces.Box(low, high, low.shape, np.float32)
        if type(self.env) is Chargax:
            self._reset_fn, self._step_fn = _shared_reset, _shared_step
        else:  # a subclass may change the dynamics: compile its own
            env = self.env

            def reset_fn(key, params):
                key, sub = jax.random.split(key)
                obs, state = env.reset_env(sub, params)
                return key, obs, state

            def step_fn(key, state, action, params):
                key, sub = jax.random.split(key)
                obs, state, reward, _, info = env.step_env(sub, state, action, params)
                return key, obs, state, reward, env.is_truncated(state, params), info

            self._reset_fn, self._step_fn = jax.jit(reset_fn), jax.jit(step_fn)

    # ------------------------------------------------------------------ pickling
    def __getstate__(self):
        d = dict(self.__dict__)
        d.pop("_reset_fn", None)
        d.pop("_step_fn", None)
        d["_key"] = np.asarray(d["_key"])
        d["_state"] = None if d["_state"] is None else jax.device_get(d["_state"])
        return d

    def __setstate__(self, d):
        lifecycle.check_not_forked("GymnasiumEnv")
        self.__dict__.update(d)
        self._build()

    # ------------------------------------------------------------------ episode
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start a day with an empty station (Gymnasium's API).

        Args:
            seed: a non-negative integer that starts the env's key
                (`chargax_marl.lifecycle.key_from_seed`); None continues the key sequence.
            options: ``{"day": d}`` starts on day ``d`` of the price data (an episode's start
                day, `chargax_marl.core.clock.num_episode_starts`); without it a random day is
                drawn. Other keys are ignored.

        Returns:
            ``(obs, info)``: the ``(n,)`` float32 observation and an empty dict.

        Raises:
            ValueError: a bad seed or ``options`` (`chargax_marl.lifecycle`).
            chargax_marl.lifecycle.ForkedProcessError: the process was forked after JAX
                started.
        """
        lifecycle.check_not_forked("GymnasiumEnv.reset")
        if seed is not None:
            key = lifecycle.key_from_seed(seed, "GymnasiumEnv.reset")
        day = lifecycle.reset_day(
            options, clock.num_episode_starts(self.params), "GymnasiumEnv.reset"
        )
        super().reset(seed=seed)
        if seed is not None:
            self._key = key
        if day is not None and type(self.env) is Chargax:
            obs, self._state = _shared_reset_day(jnp.asarray(day, jnp.int32), self.params)
        elif day is not None:  # a subclass may build its own observation
            obs, self._state = self.env.reset_to_day(day, self.params)
        else:
            self._key, obs, self._state = self._reset_fn(self._key, self.params)
        self._done = False
        self._history = []
        return np.array(obs, dtype=np.float32), {}

    def step(self, action):
        """Step the station once (Gymnasium's API; no auto-reset).

        Args:
            action: an element of ``action_space``: per-leaf level indices (discrete modes)
                or fractions in ``[-1, 1]`` (continuous mode), as numpy values.

        Returns:
            ``(obs, reward, terminated, truncated, info)``: the ``(n,)`` float32
            observation, the step's reward as a float, ``terminated`` always False,
            ``truncated`` True on the day's last step, and the step's report
            (`chargax_marl.core.simulator.info_dict`) with scalars as floats and
            ``leaf_energy_kwh`` as a float32 array.

        Raises:
            RuntimeError: called before `reset`, or after the day ended.
            ValueError: the action is not numeric or lies outside ``action_space``.
            chargax_marl.lifecycle.ForkedProcessError: the process was forked after JAX
                started.
        """
        lifecycle.check_not_forked("GymnasiumEnv.step")
        if self._state is None:
            raise RuntimeError(
                "GymnasiumEnv.step() called before reset(); call reset() to start a day"
            )
        action = self._check_action(action)
        if self._done:
            raise RuntimeError(
                "GymnasiumEnv.step() called after the episode ended (truncated=True at the end "
                "of the day); call reset() to start a new day"
            )
        self._key, obs, state, reward, done, info = self._step_fn(
            self._key, self._state, jnp.asarray(action), self.params
        )
        self._state = state
        obs, reward, done, info = jax.device_get((obs, reward, done, info))
        # scalars as floats; per-leaf entries (``leaf_energy_kwh``) as float32 arrays
        info = {
            k: float(v) if np.ndim(v) == 0 else np.asarray(v, np.float32) for k, v in info.items()
        }
        self._done = bool(done)
        self._history.append(
            (
                len(self._history) * self.params.step_minutes / 60.0,
                info["price_buy_eur_kwh"],
                info["grid_net_kwh"] / self.params.step_hours,
            )
        )
        if self.render_mode == "human":
            self.render()
        return np.array(obs, dtype=np.float32), float(reward), False, self._done, info

    def _check_action(self, action) -> np.ndarray:
        """``action`` as a numpy array of this env's action space.

        Raises:
            ValueError: the action is not an array of numbers (strings, objects, complex
                values) or lies outside the action space; the message names the action and
                the space.
        """
        try:
            arr = np.asarray(action)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"action {action!r} is not an array of numbers of the action space "
                f"{self.action_space} ({exc})"
            ) from None
        numeric = np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
        if not (numeric or np.issubdtype(arr.dtype, np.bool_)):
            raise ValueError(
                f"action {arr.tolist()!r} (dtype {arr.dtype}) is not in the action space "
                f"{self.action_space}: it must hold numbers"
            )
        with np.errstate(invalid="ignore", over="ignore"):
            cast = arr.astype(self.action_space.dtype)
        if not self.action_space.contains(cast):
            raise ValueError(
                f"action {arr.tolist()} is outside the action space {self.action_space}"
            )
        return arr

    def render(self):
        state = None if self._state is None else jax.device_get(self._state)
        st = self.params.station
        names = [f"port_{i}" for i in range(st.num_ports)] + [
            f"battery_{j}" for j in range(st.num_batteries)
        ]
        return rendering.render(
            self.render_mode, state, self.params, names, self._history, "GymnasiumEnv"
        )
