"""Observation feature wrappers: the teachers' views appended as columns
(`chargax_marl.teachers`).

JaxMARL view: every agent's observation gains the same number of columns, and
``observation_space(agent)``, ``observation_spaces`` and ``obs_size`` grow with them, so
JaxMARL's own IPPO sizes its network from them unmodified; other keys (MAPPO's
``world_state``) pass through. Gymnax view: the flat observation gains the columns, and
``observation_space(params)`` grows with it.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from chargax_marl.core import observation
from chargax_marl.teachers.car_plan import PLAN_POWER_FRACTION, plan_advice
from chargax_marl.teachers.congestion import COUPLED_ADVICE_WIDTH, coupled_advice
from chargax_marl.teachers.prices import relative_price_columns, relative_prices
from chargax_marl.teachers.shaping import core_state
from chargax_marl.wrappers.base import TeacherWrapper, base_env


class ObservationFeatures(TeacherWrapper):
    """Appends ``width`` columns to each observation; subclasses define `features`.

    An info's ``final_observation`` (the gymnax view's, or `chargax_marl.marl.FinalObservationWrapper`'s)
    keeps the observation's size: columns read from the observation alone
    (``reads_state = False``) are appended to it too; columns read from the state cannot be
    (the state before an auto-reset is not returned), so the gymnax view's entry is left out
    of the info and the JaxMARL view's wrapper is refused.

    Args:
        env: either view, possibly wrapped.
        width: columns appended per agent (JaxMARL) or to the flat observation (gymnax).
        low: the appended columns' lower bound, for the observation space.
        high: the appended columns' upper bound, for the observation space.

    Raises:
        TypeError: columns read from the state over a `chargax_marl.marl.FinalObservationWrapper`.
    """

    reads_state = True
    """Whether `features` reads the state (not only the observation): such columns cannot be
    appended to an info's ``final_observation``, whose state a step does not return."""

    def __init__(self, env, width: int, low: float, high: float):
        super().__init__(env)
        if self.reads_state and self.is_marl and getattr(env, "adds_final_observation", False):
            raise TypeError(
                f"{type(self).__name__}: its columns are read from the state, and the "
                "infos' final_observation (FinalObservationWrapper below) is of a state the "
                "step does not return, so its rows could not carry them: leave out "
                "FinalObservationWrapper, or this wrapper"
            )
        self.width = int(width)
        self._low = np.full(self.width, low, np.float32)
        self._high = np.full(self.width, high, np.float32)
        if self.is_marl:
            self.obs_size = env.obs_size + self.width
            self.observation_spaces = {a: self._grown(env.observation_space(a)) for a in env.agents}

    def _grown(self, space):
        low, high = (
            np.concatenate([np.broadcast_to(np.asarray(b, np.float32), space.shape), x])
            for b, x in ((space.low, self._low), (space.high, self._high))
        )
        return type(space)(low, high, (space.shape[0] + self.width,), space.dtype)

    def features(self, obs, state):
        """The appended columns: ``(agents, width)`` from the dict ``obs`` (JaxMARL) or
        ``(width,)`` from the flat ``obs`` (gymnax), for the (wrapped) core ``state``.

        Args:
            obs: the wrapped env's observation: a dict keyed by agent (JaxMARL) or the flat
                vector (gymnax).
            state: the state the observation is of (a core or wrapper state).

        Raises:
            NotImplementedError: always here; a subclass defines the columns.
        """
        raise NotImplementedError

    def _append(self, obs, state):
        extra = self.features(obs, state)
        if not self.is_marl:
            return jnp.concatenate([obs, extra], axis=-1)
        grown = {a: jnp.concatenate([obs[a], extra[i]]) for i, a in enumerate(self._env.agents)}
        return {**obs, **grown}

    def observation_space(self, agent_or_params=None):
        """JaxMARL: the grown ``Box`` of ``agent``; gymnax: the grown ``Box`` for ``params``.

        Args:
            agent_or_params: an agent name (JaxMARL view), or the environment parameters
                (gymnax view; None: the env's defaults).

        Returns:
            The wrapped env's ``Box`` with ``width`` columns appended, bounded by the class's
            ``low`` and ``high``.
        """
        if self.is_marl:
            return self.observation_spaces[agent_or_params]
        return self._grown(self._env.observation_space(agent_or_params))

    def reset(self, key, *args):
        """The wrapped env's ``reset`` with the columns appended to the observation(s).

        Args:
            key: the reset's key.
            *args: passed on to the wrapped ``reset`` (gymnax's ``params``).

        Returns:
            ``(obs, state)``: the grown observation(s) and the wrapped env's state.
        """
        obs, state = self._env.reset(key, *args)
        return self._append(obs, state), state

    def step(self, key, state, action, *args):
        """The wrapped env's ``step`` with the columns appended to the observation(s).

        Args:
            key: the step's key.
            state: the wrapped env's state.
            action: the action (gymnax) or action dict (JaxMARL) of the wrapped env.
            *args: passed on to the wrapped ``step``: gymnax's ``params`` or JaxMARL's
                ``reset_state``.

        Returns:
            The wrapped step's tuple with the returned state's columns appended to its
            observation(s) (after an auto-reset, the new day's).
        """
        obs, state, *rest = self._env.step(key, state, action, *args)
        return (self._append(obs, state), state, *self._final(rest))

    def _final(self, rest: list) -> list:
        """A step's values after the state, its info's ``final_observation`` grown as the
        observation is (columns from the observation), or left out of the info (columns from
        the state: the state before the auto-reset is not returned)."""
        info = rest[-1] if rest else None
        if not isinstance(info, dict) or "final_observation" not in info:
            return list(rest)
        final = info["final_observation"]
        info = dict(info)
        if self.reads_state:
            del info["final_observation"]
        elif self.is_marl:
            info["final_observation"] = jnp.concatenate(
                [final, self.matrix_features(final, None)], axis=-1
            )
        else:
            info["final_observation"] = jnp.concatenate(
                [final, self.features(final, None)], axis=-1
            )
        return [*rest[:-1], info]

    def step_arrays(self, key, state, indices, reset_state=None):
        """The JaxMARL view's ``step_arrays`` with the columns appended to every agent's row
        (the values of `step`, stacked).
        Arguments and returns as `chargax_marl.marl.ChargaxMARL.step_arrays`, with this
        wrapper's state.

        Args:
            key: the step's key.
            state: the wrapped env's state.
            indices: ``(num_agents,)`` action indices in agent order.
            reset_state: the fresh day's state at the end of a day (None: a random one).

        Returns:
            ``(obs, state, rewards, done, info)`` of the wrapped ``step_arrays``, ``obs``
            grown to ``(num_agents, obs_size + width)``.
        """
        obs, state, *rest = self._env.step_arrays(key, state, indices, reset_state)
        grown = jnp.concatenate([obs, self.matrix_features(obs, state)], axis=-1)
        return (grown, state, *self._final(rest))

    def matrix_features(self, obs, state):
        """`features` of the observation matrix ``obs (agents, obs_size)`` (JaxMARL view);
        subclasses that read ``obs`` may compute it on the matrix at once.

        Args:
            obs: ``(num_agents, obs_size)`` the wrapped env's observation matrix.
            state: the state the observations are of (a core or wrapper state).

        Returns:
            ``(num_agents, width)`` the appended columns.
        """
        return self.features(dict(zip(self._env.agents, obs)), state)

    def get_obs(self, state, *args, **kwargs):
        """The wrapped env's observation of ``state`` with the columns appended.

        Args:
            state: the state to observe (a core or wrapper state, as the wrapped env takes).
            *args: passed on to the wrapped ``get_obs`` (gymnax's ``params``).
            **kwargs: passed on to the wrapped ``get_obs``.

        Returns:
            The grown observation(s): a dict keyed by agent (JaxMARL) or the flat vector
            (gymnax).
        """
        return self._append(self._env.get_obs(state, *args, **kwargs), state)


class PlanAdviceObservation(ObservationFeatures):
    """Each port's plan advice (`chargax_marl.teachers.car_plan.plan_advice`): 1.0 where its
    car's cheapest plan under the day's prices charges now (every charge-sensitive car), else
    0.0 (idle, empty ports, batteries), read from the returned state (after an auto-reset, the
    new day's). JaxMARL view: one column per agent, its own leaf's advice. Gymnax view: one
    column per leaf ``(L,)``, ports then batteries.

    Args:
        env: either view, possibly wrapped.
        power_fraction: the fraction of a car's top power the plan counts on per step.
    """

    def __init__(self, env, power_fraction: float = PLAN_POWER_FRACTION):
        params = env.params if hasattr(env, "agents") else env.default_params
        super().__init__(env, 1 if hasattr(env, "agents") else params.station.num_leaves, 0.0, 1.0)
        self._advice = plan_advice(self.env_params, power_fraction)

    def features(self, obs, state):
        """The plan advice of the state's ports.

        Args:
            obs: the wrapped env's observation (unused).
            state: the state to advise on (a core or wrapper state).

        Returns:
            ``(num_agents, 1)`` (JaxMARL) or ``(num_leaves,)`` (gymnax) float advice, 1.0 where
            the car's plan charges now.
        """
        advice = self._advice(core_state(state))
        return advice[:, None] if self.is_marl else advice


class CoupledPlanAdviceObservation(ObservationFeatures):
    """Each port's coupled plan now (`chargax_marl.teachers.congestion.coupled_advice`): the
    share of its top power its car's joint plan takes now, in [0, 1], and the congestion price
    on its path now (EUR/kWh, in [0, customer price]), read from the returned state (after an
    auto-reset, the new day's); 0 for empty ports and batteries. JaxMARL view: two columns per
    agent, its own leaf's. Gymnax view: ``2 L`` columns, the shares of every leaf (ports then
    batteries), then their prices.

    Args:
        env: either view, possibly wrapped.
        **plan_kwargs: settings of `chargax_marl.teachers.congestion.coupled_plan`.
    """

    def __init__(self, env, **plan_kwargs):
        marl = hasattr(env, "agents")
        params = env.params if marl else env.default_params
        leaves = params.station.num_leaves
        width = COUPLED_ADVICE_WIDTH * (1 if marl else leaves)
        high = max(1.0, float(params.customer_price_eur_kwh))
        super().__init__(env, width, 0.0, high)
        self._advice = coupled_advice(self.env_params, **plan_kwargs)

    def features(self, obs, state):
        """The coupled plan's power share and congestion price of the state's ports.

        Args:
            obs: the wrapped env's observation (unused).
            state: the state to advise on (a core or wrapper state).

        Returns:
            ``(num_agents, 2)`` (JaxMARL: share, price) or ``(2 * num_leaves,)`` (gymnax: every
            leaf's share, then every leaf's price).
        """
        advice = self._advice(core_state(state))
        return advice if self.is_marl else advice.T.reshape(-1)


class RelativePriceObservation(ObservationFeatures):
    """Each observed buy price's place in its day's range, ``(p - median) / (q80 - q20)``
    (`chargax_marl.teachers.prices.relative_prices`; ``H + 1`` columns, now and the next
    ``H = price_horizon_hours`` hours, clipped to [-5, 5]), computed from the env's own
    observation columns. JaxMARL view: every agent's row; gymnax view: the flat observation.

    Args:
        env: either view, possibly wrapped (other appended columns come after the env's own,
            so the price columns stay where the env puts them).
    """

    reads_state = False

    def __init__(self, env):
        params = env.params if hasattr(env, "agents") else env.default_params
        super().__init__(env, int(params.price_horizon_hours) + 1, -5.0, 5.0)
        inner = base_env(env)
        end = (
            inner.obs_size - int(np.shape(inner._layout.agent_id)[1])
            if self.is_marl
            else observation.obs_size(params)
        )
        self.columns = relative_price_columns(params, end - observation.context_size(params))

    def features(self, obs, state):
        """The relative prices read from the observation's price columns.

        Args:
            obs: the wrapped env's observation: a dict keyed by agent (JaxMARL) or the flat
                vector (gymnax).
            state: unused (the prices are read from ``obs``).

        Returns:
            ``(num_agents, H + 1)`` (JaxMARL) or ``(H + 1,)`` (gymnax), each in ``[-5, 5]``.
        """
        if not self.is_marl:
            return relative_prices(obs, *self.columns)
        return jnp.stack([relative_prices(obs[a], *self.columns) for a in self._env.agents])

    def matrix_features(self, obs, state):
        """`features` on the matrix ``obs (agents, obs_size)`` at once, without a slice per
        agent.

        Args:
            obs: ``(num_agents, obs_size)`` the wrapped env's observation matrix.
            state: unused (the prices are read from ``obs``).

        Returns:
            ``(num_agents, H + 1)`` relative prices, each in ``[-5, 5]``.
        """
        return relative_prices(obs, *self.columns)
