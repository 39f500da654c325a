"""Gymnasium ids for the single-agent env.

``import chargax_marl`` registers (Gymnasium 1.x has no plugin discovery, so the import is
what makes the ids known; ``gymnasium.make("chargax_marl:chargax_marl/Chargax-v0")`` imports
it for you):

- ``chargax_marl/Chargax-v0``: the paper's default (shopping users, medium traffic);
- ``chargax_marl/Chargax-<scenario>-v0`` for every name of
  `chargax_marl.single.SCENARIOS` (``Chargax-workplace-high-v0``, ...).

Each makes a `chargax_marl.single.GymnasiumEnv`; keyword arguments of
``gymnasium.make`` (``render_mode``, any `chargax_marl.core.make_params` override)
reach it. The package also declares this function under the ``gymnasium.envs`` entry-point
group for Gymnasium versions that load plugins.
"""

from __future__ import annotations

import gymnasium

from chargax_marl.core.scenarios import SCENARIOS

ENTRY_POINT = "chargax_marl.single.wrappers:GymnasiumEnv"
NAMESPACE = "chargax_marl"


def env_ids() -> dict[str, dict]:
    """Every id this package registers, with the keyword arguments it passes.

    Returns:
        ``{env id: keyword arguments}``: ``{}`` for ``chargax_marl/Chargax-v0`` and a copy of
        `chargax_marl.core.scenarios.SCENARIOS`' entry for each scenario's id.
    """
    ids = {f"{NAMESPACE}/Chargax-v0": {}}
    for name, kwargs in SCENARIOS.items():
        ids[f"{NAMESPACE}/Chargax-{name}-v0"] = dict(kwargs)
    return ids


def register_envs() -> None:
    """Register the ids of `env_ids` (again: a no-op)."""
    for env_id, kwargs in env_ids().items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=ENTRY_POINT, kwargs=kwargs)
