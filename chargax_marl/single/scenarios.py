"""Named scenarios of the single-agent view: ``make(name, **overrides)``.

The scenarios themselves (the four user profiles of paper Table 2 at three traffic levels,
and the coordination scenarios ``shopping-grid10-<traffic>``, ``shopping-grid25-<traffic>``, ``shopping-grid50-<traffic>``,
``shopping-peak``, ``shopping-peak-high``, ``shopping-grid50-peak-high``) are defined in
`chargax_marl.core.scenarios`, shared with ``ChargaxMARL(scenario=...)``.
"""

from __future__ import annotations

from typing import Any

from chargax_marl.core.scenarios import COORDINATION_SCENARIOS, SCENARIOS, scenario_kwargs
from chargax_marl.core.types import EnvParams
from chargax_marl.single.env import Chargax

__all__ = ["COORDINATION_SCENARIOS", "SCENARIOS", "make"]


def make(name: str = "shopping", **overrides: Any) -> tuple[Chargax, EnvParams]:
    """Return ``(env, params)`` for a named scenario (`SCENARIOS`), with keyword
    overrides of `chargax_marl.core.params.make_params` applied on top."""
    env = Chargax(**scenario_kwargs(name, **overrides))
    return env, env.default_params
