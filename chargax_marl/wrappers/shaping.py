"""Potential-based reward shaping wrappers: the battery's stored energy and each parked car's
plan valued as they move (`chargax_marl.teachers`).

Each adds ``Phi(s') - Phi(s)`` (EUR) to a step's reward, with the potential read from the state
*before* the step (the env auto-resets at the day's end, so the state it returns may be a new
day's). The evaluation still scores the env's profit: infos and episode totals are unchanged.
"""

from __future__ import annotations

import jax.numpy as jnp

from chargax_marl.teachers.car_plan import car_potential
from chargax_marl.teachers.congestion import coupled_potential
from chargax_marl.teachers.shaping import (
    agent_potential_shaping,
    battery_potential,
    battery_shaping,
    mix_own_terms,
)
from chargax_marl.wrappers.base import TeacherWrapper


class BatteryShaping(TeacherWrapper):
    """The battery's stored energy valued by a potential as it moves, instead of all at once at
    the day's last step (the env's terminal booking).

    A step's term is ``Phi_{t+1}(E_{t+1}) - Phi_t(E_t) - terminal booking`` (EUR; the booking,
    ``info["battery_terminal_value_eur"]``, is non-zero at the day's last step only), so a day's
    undiscounted shaped return differs from the env's by a constant of its first state.
    Gymnax view: the station's reward gains the term. JaxMARL view: each agent gains its part,
    mixed like the env's rewards with its ``local_reward_weight`` ``w``: ``(1 - w)`` times the
    station's term for every agent, plus ``w`` times an even share of it for each battery agent
    (`chargax_marl.teachers.shaping.agent_potential_shaping`). ``info["battery_shaping_eur"]``
    holds the term(s) added (scalar; ``(agents,)`` in the JaxMARL view).

    Args:
        env: either view, possibly wrapped (the potential unwraps ``.env_state``).
        potential: ``"dp"`` (the battery-only programme's value of the energy level),
            ``"storage_value"`` (the LP's value per kWh) or ``"day_mean"`` (the env's terminal
            price; a day's return unchanged).

    Raises:
        ValueError: an unknown potential, or a programme/LP potential on a station without a
            battery.
    """

    def __init__(self, env, potential: str = "dp"):
        super().__init__(env)
        self._potential = battery_potential(self.env_params, potential)

    def step(self, key, state, action, *args):
        """The wrapped ``step`` (gymnax: ``params``; JaxMARL: ``reset_state`` in ``args``) with the
        shaping term added to the reward(s).

        Args:
            key: the step's key.
            state: the wrapped env's state.
            action: the action (gymnax) or action dict (JaxMARL) of the wrapped env.
            *args: passed on to the wrapped ``step``: gymnax's ``params`` or JaxMARL's
                ``reset_state``.

        Returns:
            The wrapped step's tuple, gymnax's ``(obs, state, reward, terminated, truncated,
            info)`` or JaxMARL's ``(obs, state, rewards, dones, infos)``, with the term(s)
            added to the reward(s) and stored as ``battery_shaping_eur`` in the info.
        """
        shift = self._potential(state)  # before the (auto-resetting) step
        out = self._env.step(key, state, action, *args)
        if self.is_marl:
            obs, state, rewards, dones, infos = out
            terms = agent_potential_shaping(shift, infos, self.is_battery, self.local_reward_weight)
            infos = {**infos, "battery_shaping_eur": terms}
            return obs, state, self.add_to_rewards(rewards, terms), dones, infos
        obs, state, reward, terminated, truncated, info = out
        term = battery_shaping(shift(info["battery_net_kwh"]), info["battery_terminal_value_eur"])
        info = {**info, "battery_shaping_eur": term}
        return obs, state, reward + term, terminated, truncated, info

    def step_arrays(self, key, state, indices, reset_state=None):
        """The JaxMARL view's ``step_arrays`` with each agent's shaping term added (the values
        of `step`, stacked).

        Arguments and returns as `chargax_marl.marl.ChargaxMARL.step_arrays`, with this
        wrapper's state.

        Args:
            key: the step's key.
            state: the wrapped env's state.
            indices: ``(num_agents,)`` action indices in agent order.
            reset_state: the fresh day's state at the end of a day (None: a random one).

        Returns:
            ``(obs, state, rewards, done, info)`` of the wrapped ``step_arrays``, the
            ``(num_agents,)`` terms added to ``rewards`` and stored as
            ``info["battery_shaping_eur"]``.
        """

        def terms(shift, info):
            n = info["agent_energy_kwh"].shape[-1]
            per_agent = {
                "agent_energy_kwh": info["agent_energy_kwh"],
                "battery_terminal_value_eur": jnp.broadcast_to(
                    info["battery_terminal_value_eur"], (n,)
                ),
            }
            return agent_potential_shaping(
                shift, per_agent, self.is_battery, self.local_reward_weight
            )

        return _shaped_arrays(self, key, state, indices, reset_state, terms, "battery_shaping_eur")


class CarPlanShaping(TeacherWrapper):
    """Each parked car's plan value as a potential per port
    (`chargax_marl.teachers.car_plan.car_potential`).

    A port's term is its car's plan value after the step minus before it (EUR; 0 for empty
    ports, batteries and charge-sensitive cars; a car that arrives during the step enters the
    potential from the next step on). Gymnax view: the station's reward gains the ports' sum.
    JaxMARL view: each agent gains ``(1 - w) * sum + w * own`` with the env's
    ``local_reward_weight`` ``w`` (`chargax_marl.teachers.shaping.mix_own_terms`).
    ``info["car_plan_shaping_eur"]`` holds the term(s) added.

    Args:
        env: either view, possibly wrapped.
    """

    def __init__(self, env):
        super().__init__(env)
        self._potential = car_potential(self.env_params)

    def step(self, key, state, action, *args):
        """The wrapped ``step`` with the ports' plan shaping added to the reward(s).

        Args:
            key: the step's key.
            state: the wrapped env's state.
            action: the action (gymnax) or action dict (JaxMARL) of the wrapped env.
            *args: passed on to the wrapped ``step``: gymnax's ``params`` or JaxMARL's
                ``reset_state``.

        Returns:
            The wrapped step's tuple, gymnax's ``(obs, state, reward, terminated, truncated,
            info)`` or JaxMARL's ``(obs, state, rewards, dones, infos)``, with the term(s)
            added to the reward(s) and stored as ``car_plan_shaping_eur`` in the info.
        """
        shift = self._potential(state)  # before the (auto-resetting) step
        out = self._env.step(key, state, action, *args)
        if self.is_marl:
            obs, state, rewards, dones, infos = out
            terms = mix_own_terms(shift(infos["agent_energy_kwh"]), self.local_reward_weight)
            infos = {**infos, "car_plan_shaping_eur": terms}
            return obs, state, self.add_to_rewards(rewards, terms), dones, infos
        obs, state, reward, terminated, truncated, info = out
        term = jnp.sum(shift(info["leaf_energy_kwh"]), axis=-1)
        info = {**info, "car_plan_shaping_eur": term}
        return obs, state, reward + term, terminated, truncated, info

    def step_arrays(self, key, state, indices, reset_state=None):
        """The JaxMARL view's ``step_arrays`` with each agent's plan shaping added (the values
        of `step`, stacked).

        Arguments and returns as `chargax_marl.marl.ChargaxMARL.step_arrays`, with this
        wrapper's state.

        Args:
            key: the step's key.
            state: the wrapped env's state.
            indices: ``(num_agents,)`` action indices in agent order.
            reset_state: the fresh day's state at the end of a day (None: a random one).

        Returns:
            ``(obs, state, rewards, done, info)`` of the wrapped ``step_arrays``, the
            ``(num_agents,)`` terms added to ``rewards`` and stored as
            ``info["car_plan_shaping_eur"]``.
        """

        def terms(shift, info):
            return mix_own_terms(shift(info["agent_energy_kwh"]), self.local_reward_weight)

        return _shaped_arrays(self, key, state, indices, reset_state, terms, "car_plan_shaping_eur")


class CoupledPlanShaping(CarPlanShaping):
    """Each parked car valued at the coupled plan's congestion prices, as a term per port
    (`chargax_marl.teachers.congestion.coupled_potential`).

    A port's term is its car's value after the step minus before it, both at the congestion
    prices (node limits and peak charge) of the state before the step, minus those prices
    times what the car took now (EUR; 0 for empty ports and batteries). Gymnax view: the
    station's reward gains the ports' sum. JaxMARL view: each agent gains ``(1 - w) * sum + w *
    own`` with the env's ``local_reward_weight`` ``w``, so at ``w = 1`` the agents' terms add
    up to the station's. ``info["car_plan_shaping_eur"]`` holds the term(s) added.

    Args:
        env: either view, possibly wrapped.
        **plan_kwargs: settings of `chargax_marl.teachers.congestion.coupled_plan`.
    """

    def __init__(self, env, **plan_kwargs):
        TeacherWrapper.__init__(self, env)
        self._potential = coupled_potential(self.env_params, **plan_kwargs)


def _shaped_arrays(wrapper, key, state, indices, reset_state, terms_of, info_key: str):
    """A potential-shaping wrapper's array step: the potential of ``state`` (before the
    auto-resetting step), the wrapped ``step_arrays``, and ``terms_of(shift, info)`` added to
    the agents' rewards and stored as ``info[info_key]``."""
    shift = wrapper._potential(state)
    obs, state, rewards, done, info = wrapper._env.step_arrays(key, state, indices, reset_state)
    terms = terms_of(shift, info)
    return obs, state, rewards + terms, done, {**info, info_key: terms}
