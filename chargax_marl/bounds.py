"""Finite bounds of the observations, derived from the parameters (numpy, host side).

Every bound follows from how `chargax_marl.core.observation` builds the feature and
what the parameters allow, so the observations stay inside them on any trajectory:

- occupied, SoC, charge-sensitive flag, workday flag, day index: ``[0, 1]``;
  time remaining is clipped to ``[-1, 1]``; current over the leaf's signed rating,
  sin and cos of the time of day: ``[-1, 1]``.
- energy remaining and capacity: ``[0, C / 100]`` with ``C`` the largest car capacity of
  the fleet (ports) or the battery's own capacity (batteries).
- rate now over the leaf's max power: ``[0, r / P]`` with ``r`` the fleet's largest rate
  for the port's kind (AC or DC) and ``P`` the port's max power; 1 for batteries.
- prices and the day's price quantiles over `observation.PRICE_SCALE_EUR_KWH`: the min
  and max of the price data plus the min and max of the time-of-use surcharge; customer
  price: its value; MOER: the min and max of the MOER data; hour left until the price
  changes: ``[0, 1]``.
- grid connection load: ``[-F, F]`` and the day's peak over the connection's limit
  ``[0, F]``, with ``F`` every leaf's full power over its path efficiency, over the limit.
- Multi-agent only: kind one-hot and agent id in ``[0, 1]``; each ancestor node's load in
  ``[0, F / max_kw]`` with ``F`` the node's grid-side flow with every leaf below it at its
  full (dis)charge power (losses divide a charging leaf's power by at most the path's
  efficiencies, so no mix of charging and discharging leaves can exceed it).

A small margin (``1e-5`` relative, at least ``1e-5``) absorbs float32 rounding.
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from chargax_marl.core import observation, physics
from chargax_marl.core.station import KIND_AC, KIND_BATTERY
from chargax_marl.core.types import EnvParams

_PORT_FEATURES = observation.PORT_FEATURES


def _eager(fn):
    # Concrete values even when called while tracing (e.g. observation_space() inside jit).
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with jax.ensure_compile_time_eval():
            return fn(*args, **kwargs)

    return wrapper


# Station arrays the bounds read, each compiled as one program per station shape (run op by op,
# every operation of a new shape would compile a program of its own).
_leaf_max_kw = jax.jit(lambda station: station.leaf_max_kw)
_node_flows_kw = jax.jit(physics.node_flows_kw)


def _margin(low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    low = np.asarray(low, np.float64)
    high = np.asarray(high, np.float64)
    low = low - 1e-5 * np.maximum(1.0, np.abs(low))
    high = high + 1e-5 * np.maximum(1.0, np.abs(high))
    return low.astype(np.float32), high.astype(np.float32)


@_eager
def leaf_feature_bounds(params: EnvParams) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` of `observation.leaf_features`, each ``(L, 8)`` (no margin).

    Args:
        params: the environment parameters.

    Returns:
        ``(low, high)``, float64 ``(L, len(observation.PORT_FEATURES))``, one row per leaf
        (ports, then batteries), columns in the order of ``PORT_FEATURES``.
    """
    st = params.station
    kinds = np.asarray(st.leaf_kind)
    is_bat = kinds == KIND_BATTERY
    n = kinds.shape[0]
    leaf_max_kw = np.asarray(_leaf_max_kw(st), np.float64)
    fleet_cap = float(np.max(np.asarray(params.fleet_capacity_kwh)))
    bat_cap = np.zeros(n)
    bat_cap[is_bat] = np.asarray(st.battery_capacity_kwh, np.float64)
    cap = np.where(is_bat, bat_cap, fleet_cap) / observation.ENERGY_SCALE_KWH
    car_rate = np.where(
        kinds == KIND_AC,
        float(np.max(np.asarray(params.fleet_ac_kw))),
        float(np.max(np.asarray(params.fleet_dc_kw))),
    )
    rate = np.where(is_bat, 1.0, car_rate / np.maximum(leaf_max_kw, 1e-12))
    low = np.zeros((n, len(_PORT_FEATURES)))
    high = np.ones((n, len(_PORT_FEATURES)))
    col = _PORT_FEATURES.index
    high[:, col("energy_remaining")] = cap
    low[:, col("time_remaining")] = -1.0
    high[:, col("rate_now")] = np.maximum(rate, 0.0)
    high[:, col("capacity")] = cap
    low[:, col("current")] = -1.0
    return low, high


def _full_power_loads(params: EnvParams) -> np.ndarray:
    """``(H,)`` each node's grid-side flow over its limit with every leaf below it at its full
    (dis)charge current and no rescale (the soft constraint mode lets it flow), with a 1e-4
    margin: the largest load any mix of charging and discharging leaves can put on it."""
    st = params.station
    volts = np.asarray(st.leaf_voltage_v, np.float64)
    amps = np.maximum(
        np.asarray(st.leaf_max_current_a, np.float64),
        np.asarray(st.leaf_max_discharge_current_a, np.float64),
    )
    flows = np.asarray(
        _node_flows_kw(np.asarray(volts * amps / 1000.0, np.float32), st), np.float64
    )
    return flows * (1.0 + 1e-4) / np.maximum(np.asarray(st.node_max_kw, np.float64), 1e-12)


@_eager
def context_bounds(params: EnvParams) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` of `observation.context_features` (no margin).

    Args:
        params: the environment parameters.

    Returns:
        ``(low, high)``, float64 vectors of the context's width, in the order of
        `observation.context_features` (MOER when ``params.observe_moer``, then the
        weekday's sine and cosine when ``params.episode_days > 1``).
    """
    tou = np.asarray(params.tou_fee_eur_kwh, np.float64)
    spot = np.asarray(params.prices_eur_kwh, np.float64)
    prices = (
        np.array([spot.min() + tou.min(), spot.max() + tou.max()]) / observation.PRICE_SCALE_EUR_KWH
    )
    h = params.price_horizon_hours + 1
    q = len(observation.PRICE_QUANTILES)
    customer = float(np.asarray(params.customer_price_eur_kwh)) / observation.PRICE_SCALE_EUR_KWH
    root = float(_full_power_loads(params)[0])  # node 0 is the grid connection
    low = [
        np.full(h, prices[0]),
        [customer],
        [-1.0, -1.0],
        [0.0],
        [0.0],
        [0.0],
        np.full(q, prices[0]),
        [-root],
        [0.0],
    ]
    high = [
        np.full(h, prices[1]),
        [customer],
        [1.0, 1.0],
        [1.0],
        [1.0],
        [1.0],
        np.full(q, prices[1]),
        [root],
        [root],
    ]
    if params.observe_moer:
        moer = np.asarray(params.moer_kg_per_kwh, np.float64) / observation.MOER_SCALE_KG_KWH
        low.append([moer.min()])
        high.append([moer.max()])
    if params.episode_days > 1:
        low.append([-1.0, -1.0])
        high.append([1.0, 1.0])
    return np.concatenate(low), np.concatenate(high)


@_eager
def flat_obs_bounds(params: EnvParams) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` float32 of the single-agent observation `observation.flat_obs`.

    Args:
        params: the environment parameters.

    Returns:
        ``(low, high)``, float32 ``(obs_size,)``: the ports' features, the batteries' SoC
        and current, then the context, widened by the margin.
    """
    low, high = leaf_feature_bounds(params)
    clow, chigh = context_bounds(params)
    p = params.station.num_ports
    keep = [_PORT_FEATURES.index("soc"), _PORT_FEATURES.index("current")]
    lo = np.concatenate([low[:p].reshape(-1), low[p:][:, keep].reshape(-1), clow])
    hi = np.concatenate([high[:p].reshape(-1), high[p:][:, keep].reshape(-1), chigh])
    return _margin(lo, hi)


@_eager
def ancestor_load_bounds(params: EnvParams, ancestors: np.ndarray) -> np.ndarray:
    """Upper bound ``(N, D)`` of each agent's ancestor loads (``ancestors``: the
    ``(N, D)`` node table of `chargax_marl.marl.env.ancestor_table`).

    Args:
        params: the environment parameters.
        ancestors: ``(N, D)`` int node indices, -1 where an agent has no ancestor at that
            depth.

    Returns:
        ``(N, D)`` float64: each ancestor's full-power load over its limit (with a 1e-4
        margin), 0 where ``ancestors`` is -1. The lower bound is 0.
    """
    load = _full_power_loads(params)
    anc = np.asarray(ancestors)
    return np.where(anc >= 0, load[np.maximum(anc, 0)], 0.0)


@_eager
def agent_obs_bounds(
    params: EnvParams, ancestors: np.ndarray, agent_id_width: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` float32 ``(obs_size,)`` shared by every agent of the multi-agent view
    (the elementwise min and max over the agents' rows).

    Args:
        params: the environment parameters.
        ancestors: ``(N, D)`` node table of `chargax_marl.marl.env.ancestor_table`.
        agent_id_width: the width of the agent-id part of the observation (0 without one).

    Returns:
        ``(low, high)``, float32 ``(obs_size,)`` in the order of the multi-agent row: leaf
        features, kind one-hot (3), ancestor loads (D), context, agent id; widened by the
        margin.
    """
    low, high = leaf_feature_bounds(params)
    n = low.shape[0]
    clow, chigh = context_bounds(params)
    anc_hi = ancestor_load_bounds(params, ancestors)
    lo = np.concatenate(
        [
            low,
            np.zeros((n, 3)),
            np.zeros_like(anc_hi),
            np.broadcast_to(clow, (n, clow.size)),
            np.zeros((n, agent_id_width)),
        ],
        axis=1,
    )
    hi = np.concatenate(
        [
            high,
            np.ones((n, 3)),
            anc_hi,
            np.broadcast_to(chigh, (n, chigh.size)),
            np.ones((n, agent_id_width)),
        ],
        axis=1,
    )
    return _margin(lo.min(axis=0), hi.max(axis=0))
