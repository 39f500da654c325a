"""Every row of the DESIGN.md section 6 table builds a scenario that runs a day.

One dimension at a time is varied from the default scenario (multiple_types,
NL-2023, EU fleet, medium traffic, shopping); each case runs one day with the
always-max baseline. Price, profile and fleet arrays are traced, so a single
jitted function serves every case with the same array shapes (the jit cache is
keyed on shapes and the static fields), which keeps the number of compilations
to a handful.
"""

from __future__ import annotations

import functools

import jax
import numpy as np
import pytest

from chargax_marl.core import datasets as ds
from chargax_marl.core.params import make_params
from chargax_marl.policies import always_max
from chargax_marl.rollout import rollout_days

KEY = jax.random.PRNGKey(0)


@functools.cache
def _runner():
    return jax.jit(lambda params, keys: rollout_days(always_max, params, keys))


def _run_day(params, seed: int = 0):
    totals, day, ret = _runner()(params, jax.random.split(jax.random.PRNGKey(seed), 1))
    return (
        jax.tree_util.tree_map(lambda x: np.asarray(x)[0], totals),
        int(np.asarray(day)[0]),
        float(np.asarray(ret)[0]),
    )


def _check(totals, ret, *, expect_cars=True):
    for name, value in (
        vars(totals).items() if hasattr(totals, "__dict__") else totals._asdict().items()
    ):
        assert np.isfinite(value).all(), name
    assert np.isfinite(ret)
    if expect_cars:
        assert float(totals.cars_served) + float(totals.cars_rejected) > 0
        assert float(totals.energy_delivered_kwh) > 0


CASES = (
    [("prices", p) for p in ds.PRICE_DATASETS]
    + [("station", s) for s in ("single_type", "multiple_types", "multiple_splitters")]
    + [("fleet", f) for f in ds.FLEETS]
    + [("traffic", t) for t in ("low", "medium", "high")]
    + [("user_profile", u) for u in ds.ALL_USER_PROFILES]
)


@pytest.mark.parametrize("field, value", CASES, ids=[f"{f}={v}" for f, v in CASES])
def test_design_table_row_runs_a_day(field, value):
    params = make_params(**{field: value})
    totals, day, ret = _run_day(params)
    _check(totals, ret)
    assert 0 <= day < params.prices_eur_kwh.shape[0]


def test_traffic_levels_order():
    served = {}
    for level in ("low", "high"):
        totals, _, _ = _run_day(make_params(traffic=level), seed=1)
        served[level] = float(totals.cars_served) + float(totals.cars_rejected)
    assert served["high"] > served["low"]


def test_custom_number_traffic_and_moer_grid_names():
    params = make_params(
        traffic=30.0,
        moer_kg_per_kwh="CAISO-SCE-2020",
        grid_demand_kwh="synthetic-residential",
        alpha={"sustainability": 1.0, "grid_demand": 0.01},
    )
    assert params.observe_moer
    totals, _, ret = _run_day(params)
    _check(totals, ret)
