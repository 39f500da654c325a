"""Shared fixtures: small stations and their parameters, built once per session."""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import settings

from chargax_marl.core import Battery, Port, Splitter, make_params

# CI runs the property tests on a fixed example sequence, so a red CI is reproducible;
# locally they explore new examples on every run.
settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")



def three_level_station(ac_discharge_current_a: float = 16.0) -> Splitter:
    """grid -> {dc splitter -> 2 EVSE groups of 2 DC ports, ac splitter -> 2 AC ports, battery}."""
    dc = [Port(f"dc{i}", "DC", 500.0, 200.0, 200.0, 0.95) for i in range(4)]
    ac = [Port(f"ac{i}", "AC", 400.0, 32.0, ac_discharge_current_a, 0.97) for i in range(2)]
    evse = [Splitter("evse0", 150.0, tuple(dc[:2]), 0.99), Splitter("evse1", 150.0, tuple(dc[2:]), 0.99)]
    return Splitter(
        "grid",
        220.0,
        (
            Splitter("dc_split", 200.0, tuple(evse), 0.98),
            Splitter("ac_split", 20.0, tuple(ac), 0.99),
            Battery("bat", capacity_kwh=100.0, max_kw=50.0, efficiency=0.95, tau=0.8, initial_soc=0.5),
        ),
    )


@pytest.fixture(scope="session")
def small_params():
    """A 6-port, 3-level station with a battery, busy traffic so cars come and go."""
    return make_params(station=three_level_station(), traffic=150.0)


@pytest.fixture(scope="session")
def default_params():
    return make_params()


def rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(seed)


def mixed_station() -> Splitter:
    """The three-level station with AC ports that cannot discharge (no V2G): masks matter."""
    return three_level_station(ac_discharge_current_a=0.0)
