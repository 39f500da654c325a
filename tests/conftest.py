"""Shared fixtures: small stations and their parameters, built once per session."""

from __future__ import annotations

import os

import pytest
from hypothesis import settings

from chargax_marl.core import make_params
from tests.helpers import mixed_station, three_level_station  # noqa: F401

# CI runs the property tests on a fixed example sequence, so a red CI is reproducible;
# locally they explore new examples on every run.
settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


@pytest.fixture(scope="session")
def small_params():
    """A 6-port, 3-level station with a battery, busy traffic so cars come and go."""
    return make_params(station=three_level_station(), traffic=150.0)


@pytest.fixture(scope="session")
def default_params():
    return make_params()
