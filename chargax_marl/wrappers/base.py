"""What the teacher wrappers share: attribute forwarding and the view they wrap."""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from chargax_marl.core.station import KIND_BATTERY


def base_env(env):
    """The innermost env under a stack of wrappers (each holding the next one as ``_env``).

    Args:
        env: an env or a wrapper of one.

    Returns:
        The first object down the ``_env`` chain that has no ``_env``.
    """
    while hasattr(env, "_env"):
        env = env._env
    return env


class TeacherWrapper:
    """Forwards every attribute it does not define to the wrapped env, as the project's and
    JaxMARL's wrappers do, and knows which view it wraps.

    Args:
        env: a `chargax_marl.single.Chargax` (gymnax view) or a
            `chargax_marl.marl.ChargaxMARL` (JaxMARL view), possibly wrapped.

    Attributes:
        is_marl: whether ``env`` is the JaxMARL view (it has ``agents``).
        env_params: the params the teachers' tables are built for (the env's own; a gymnax
            ``step``/``reset`` must be given params with the same days and prices).
    """

    def __init__(self, env):
        self._env = env
        self.is_marl = hasattr(env, "agents")
        self.env_params = env.params if self.is_marl else env.default_params
        self.is_battery = np.asarray(self.env_params.station.leaf_kind) == KIND_BATTERY

    def __getattr__(self, name: str) -> Any:
        if name == "_env":  # not set yet (e.g. while unpickling): avoid infinite recursion
            raise AttributeError(name)
        return getattr(self._env, name)

    def step_arrays(self, key, state, indices, reset_state=None):
        """The JaxMARL view's array step (`chargax_marl.marl.ChargaxMARL.step_arrays`)
        through this wrapper. Each wrapper that changes the step defines its own; this one
        refuses, so that an array step never passes a wrapper by unchanged.

        Args:
            key: the step's key.
            state: this wrapper's state.
            indices: ``(num_agents,)`` action indices in agent order.
            reset_state: the fresh day's state at the end of a day (None: a random one).

        Raises:
            NotImplementedError: the wrapper has no array step.
        """
        raise NotImplementedError(f"{type(self).__name__} has no array step (step_arrays)")

    def add_to_rewards(self, rewards: dict, terms) -> dict:
        """``rewards[agent] + terms[i]`` for the agents in order (``terms (agents,)``).

        Args:
            rewards: the step's rewards keyed by agent.
            terms: ``(num_agents,)`` the terms to add, in agent order.

        Returns:
            The rewards keyed by agent, each with its term added.
        """
        return {a: rewards[a] + terms[i] for i, a in enumerate(self._env.agents)}


def agent_axis(values) -> jnp.ndarray:
    """``values (agents,)`` as a column ``(agents, 1)``, to append one feature per agent.

    Args:
        values: ``(num_agents,)`` one value per agent.

    Returns:
        ``(num_agents, 1)`` float32.
    """
    return jnp.asarray(values, jnp.float32)[:, None]
