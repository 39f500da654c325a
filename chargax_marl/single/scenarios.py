"""Named scenarios of the single-agent view: ``make(name, **overrides)``.

The scenarios themselves (the four user profiles of paper Table 2 at three traffic levels,
and the coordination scenarios ``shopping-grid10-<traffic>``, ``shopping-grid25-<traffic>``, ``shopping-grid50-<traffic>``,
``shopping-peak``, ``shopping-peak-high``, ``shopping-grid50-peak-high``, and the
``residential-overnight`` scenarios whose episodes run from noon to noon) are defined in
`chargax_marl.core.scenarios`, shared with ``ChargaxMARL(scenario=...)``. Every scenario
takes ``make_params`` overrides, ``episode_start_hour`` among them (the hour episodes start
at, `chargax_marl.core.clock`).
"""

from __future__ import annotations

from typing import Any

from chargax_marl.core.scenarios import COORDINATION_SCENARIOS, SCENARIOS, scenario_kwargs
from chargax_marl.core.types import EnvParams
from chargax_marl.single.env import Chargax

__all__ = ["COORDINATION_SCENARIOS", "SCENARIOS", "make"]


def make(name: str = "shopping", **overrides: Any) -> tuple[Chargax, EnvParams]:
    """The env and params of a named scenario.

    Args:
        name: a scenario of `SCENARIOS` (the user profiles at each traffic level, the
            coordination scenarios and the overnight ones of `chargax_marl.core.scenarios`).
        **overrides: keyword arguments of `chargax_marl.core.params.make_params`, applied on
            top of the scenario's own (``episode_start_hour=12``: episodes from noon to
            noon).

    Returns:
        ``(env, params)``: a `Chargax` and its ``default_params``.

    Raises:
        KeyError: an unknown scenario name (or dataset name in ``overrides``).
        ValueError: an invalid override (the message names the field).
        TypeError: a keyword `make_params` does not take.
    """
    env = Chargax(**scenario_kwargs(name, **overrides))
    return env, env.default_params
