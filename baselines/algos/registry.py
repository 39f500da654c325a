"""The trainers by name: ``make_train(algo, config, env_params)``."""

from __future__ import annotations

from baselines.algos import ippo, mappo, ppo
from baselines.algos.trainer import Trainer

ALGOS = ("ppo", "ippo", "mappo")

_MAKERS = {"ppo": ppo.make_train, "ippo": ippo.make_train, "mappo": mappo.make_train}


def make_train(algo: str, config: dict | None = None, env_params=None) -> Trainer:
    """Build the trainer of ``algo`` for ``config``.

    Args:
        algo: ``"ppo"``, ``"ippo"`` or ``"mappo"``.
        config: trainer keys (`baselines.config.SCHEMA`; the rest at their defaults).
        env_params: training env parameters (default: the config's training days).

    Returns:
        The built `baselines.algos.trainer.Trainer`.

    Raises:
        ValueError: an unknown ``algo``.
    """
    if algo not in _MAKERS:
        raise ValueError(f"algo {algo!r} is not one of {ALGOS}")
    return _MAKERS[algo](config, env_params)
