"""What every ``make_train`` returns: the training function and the pieces its callers use."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, eq=False)
class Trainer:
    """A built trainer, PureJaxRL-shaped: ``trainer(key)`` trains one seed end to end.

    Attributes:
        init: ``init(key, hyper=None) -> runner_state``: networks, optimiser and envs of one
            seed; ``hyper`` the values of `baselines.algos.ppo_core.HYPER_KEYS` it trains
            with (float32 scalars; default the config's), kept in the runner state.
        run_updates: ``run_updates(runner_state, n) -> (runner_state, metrics)``: ``n``
            PPO updates (a ``jax.lax.scan``); metrics have a leading update axis.
        num_updates: the updates ``config["TOTAL_TIMESTEPS"]`` holds.
        config: the resolved config (`baselines.config.SCHEMA`).
        policy: the networks (``init``, ``logits``, ``value``).
        env: the unwrapped env view the trainer steps.
        env_params: the training env parameters.
        make_act: ``make_act(eval_params)(params) -> act(state, key) -> levels``: the greedy
            policy of trained parameters as a rule `chargax_marl.evaluation.run_days`
            plays (a `chargax_marl.evaluation.MemoryAct` when the multi-agent trainers
            see the station through an observation delay or action loss).
    """

    init: Callable
    run_updates: Callable
    num_updates: int
    config: dict
    policy: Any
    env: Any
    env_params: Any
    make_act: Callable

    def __call__(self, key):
        """Train one seed from ``key``; ``{"runner_state", "metrics"}``."""
        rs, metrics = self.run_updates(self.init(key), self.num_updates)
        return {"runner_state": rs, "metrics": metrics}


class IdentityCache:
    """Values built once per object, keyed by the object's identity.

    For objects that cannot be hashed (an ``EnvParams`` pytree of arrays). Each entry keeps
    its object alive, so the object's ``id`` cannot be reused by another while the entry
    exists, and a hit is confirmed with ``is``.
    """

    def __init__(self):
        self._entries: dict[int, tuple[Any, Any]] = {}

    def get(self, obj, build: Callable[[], Any]):
        """The value cached for ``obj``, or ``build()`` cached for it.

        Args:
            obj: the key object (compared by identity).
            build: makes the value on a miss.

        Returns:
            The cached value.
        """
        entry = self._entries.get(id(obj))
        if entry is None or entry[0] is not obj:
            entry = (obj, build())
            self._entries[id(obj)] = entry
        return entry[1]
