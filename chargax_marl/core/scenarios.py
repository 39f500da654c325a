"""Named scenarios: keyword sets of `chargax_marl.core.params.make_params`, shared by the
single-agent ``make(name)`` and the multi-agent ``ChargaxMARL(scenario=name)``.

- ``<profile>`` and ``<profile>-<traffic>``: the four user profiles of paper Table 2
  (``shopping``, ``workplace``, ``residential``, ``highway``) at low / medium / high traffic
  (50 / 100 / 250 cars per day); ``shopping`` is the paper's default.
- Scenarios where the agents must coordinate (the default station's grid connection never
  binds under always-max, so there the ports barely interact):

  - ``shopping-grid10-<traffic>``, ``shopping-grid25-<traffic>``, ``shopping-grid50-<traffic>``:
    the grid connection at 10 / 25 / 50 % of the sum of its children's limits
    (``grid_fraction``), so the ports and the battery share a scarce connection. Under
    always-max the default station's draw peaks at about 300-330 kW of its 884.5 kW, so 25 %
    (221 kW) binds in only 3-4 % of the steps and 50 % almost never; 10 % (88 kW) binds in
    a third of them (table in docs/scenarios.md);
  - ``shopping-peak`` / ``shopping-peak-high``: the full connection, with a time-of-use
    surcharge on the evening peak (``tou_fee_eur_kwh="evening-peak"``, +0.12 EUR/kWh
    17:00-21:00) and a peak-demand charge of 0.15 EUR per kW of the day's highest net grid
    draw, booked at the end of the day (`chargax_marl.core.tariffs`);
  - ``shopping-grid50-peak-high``: both at once.
- ``residential-overnight`` and ``residential-overnight-<traffic>``: the residential profile
  with episodes from noon to noon (``episode_start_hour=12``, `chargax_marl.core.clock`), so
  that the evening arrivals charge overnight within one episode instead of being cut at
  midnight. Any scenario takes ``episode_start_hour`` as an override
  (``make("shopping", episode_start_hour=6)``).

How often each node binds under always-max in each scenario is tabled in docs/scenarios.md
(``python -m chargax_marl.binding``).
"""

from __future__ import annotations

from typing import Any

from chargax_marl.core import datasets, tariffs

SCENARIOS: dict[str, dict[str, Any]] = {}
"""Every named scenario: name -> its ``make_params`` keywords (filled in below)."""
for _profile in datasets.USER_PROFILES:
    SCENARIOS[_profile] = {"user_profile": _profile, "traffic": "medium"}
    for _traffic in datasets.TRAFFIC_LEVELS:
        SCENARIOS[f"{_profile}-{_traffic}"] = {"user_profile": _profile, "traffic": _traffic}

_PEAK = {
    "tou_fee_eur_kwh": "evening-peak",
    "peak_demand_eur_kw": tariffs.DEFAULT_PEAK_DEMAND_EUR_KW,
}
for _fraction in (10, 25, 50):
    for _traffic in datasets.TRAFFIC_LEVELS:
        SCENARIOS[f"shopping-grid{_fraction}-{_traffic}"] = {
            "user_profile": "shopping",
            "traffic": _traffic,
            "grid_fraction": _fraction / 100.0,
        }
SCENARIOS["shopping-peak"] = {"user_profile": "shopping", "traffic": "medium", **_PEAK}
SCENARIOS["shopping-peak-high"] = {"user_profile": "shopping", "traffic": "high", **_PEAK}
SCENARIOS["shopping-grid50-peak-high"] = {
    "user_profile": "shopping",
    "traffic": "high",
    "grid_fraction": 0.5,
    **_PEAK,
}

OVERNIGHT_START_HOUR = 12
"""The episode start hour of the ``residential-overnight`` scenarios (noon to noon)."""
SCENARIOS["residential-overnight"] = {
    "user_profile": "residential",
    "traffic": "medium",
    "episode_start_hour": OVERNIGHT_START_HOUR,
}
for _traffic in datasets.TRAFFIC_LEVELS:
    SCENARIOS[f"residential-overnight-{_traffic}"] = {
        "user_profile": "residential",
        "traffic": _traffic,
        "episode_start_hour": OVERNIGHT_START_HOUR,
    }

COORDINATION_SCENARIOS = tuple(n for n in SCENARIOS if "grid" in n or "peak" in n)
"""The scenarios built to make the agents coordinate (grid-constrained and/or peak-priced)."""


def scenario_kwargs(name: str, **overrides: Any) -> dict[str, Any]:
    """The ``make_params`` keywords of scenario ``name`` with ``overrides`` applied on top.

    Args:
        name: a scenario of `SCENARIOS`.
        **overrides: ``make_params`` keywords that replace or add to the scenario's (not
            checked here; ``make_params`` checks them).

    Returns:
        A new dict of keywords.

    Raises:
        KeyError: ``name`` is not a string naming a scenario of `SCENARIOS`.
    """
    if not isinstance(name, str) or name not in SCENARIOS:
        raise KeyError(f"unknown scenario {name!r}; allowed: {sorted(SCENARIOS)}")
    return {**SCENARIOS[name], **overrides}
