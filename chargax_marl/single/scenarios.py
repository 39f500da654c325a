"""Named scenarios: the four user profiles (paper Table 2) crossed with the traffic levels.

``make("shopping")`` is the paper default (medium traffic); ``make("workplace-high")``,
``make("highway-low")`` etc. pick a profile and traffic level. Keyword overrides go to
:func:`chargax_marl.core.params.make_params`.
"""

from __future__ import annotations

from typing import Any

from chargax_marl.core import datasets
from chargax_marl.core.types import EnvParams
from chargax_marl.single.env import Chargax

SCENARIOS: dict[str, dict[str, Any]] = {}
for _profile in datasets.USER_PROFILES:
    SCENARIOS[_profile] = {"user_profile": _profile, "traffic": "medium"}
    for _traffic in datasets.TRAFFIC_LEVELS:
        SCENARIOS[f"{_profile}-{_traffic}"] = {"user_profile": _profile, "traffic": _traffic}


def make(name: str = "shopping", **overrides: Any) -> tuple[Chargax, EnvParams]:
    """Return ``(env, params)`` for a named scenario, with keyword overrides applied."""
    if name not in SCENARIOS:
        raise KeyError(f"unknown scenario {name!r}; allowed: {sorted(SCENARIOS)}")
    env = Chargax(**{**SCENARIOS[name], **overrides})
    return env, env.default_params
