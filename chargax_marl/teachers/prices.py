"""Relative prices: each observed price's place in its day's range, an observation feature.

``(p - median) / (q80 - q20)`` of every observed buy price (now and the next hours), from the
day's 20 / 50 / 80 % price quantiles the observation's shared context already holds: the
comparison a battery's charge or discharge decision turns on, which the raw prices (a few
hundredths apart within a day, while the day's level moves by tenths) leave a network to
learn. `chargax_marl.wrappers.RelativePriceObservation` appends them to an env's
observations.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from chargax_marl.core import observation
from chargax_marl.core.observation import PRICE_SCALE_EUR_KWH


def relative_price_columns(params, context_start: int):
    """Where an observation holds the observed prices and the day's price quantiles.

    The single-agent observation ends with the shared context
    (`chargax_marl.core.observation.context_features`); a
    `chargax_marl.marl.ChargaxMARL` agent's has the agent index after it.

    Args:
        params: concrete `chargax_marl.core.types.EnvParams`.
        context_start: the column where the observation's shared context starts.

    Returns:
        ``(price_cols, q20_col, q50_col, q80_col)``: the columns ``(H + 1,)`` of the observed
        buy prices (now and the next ``H = price_horizon_hours`` hours) and those of the
        day's 20 / 50 / 80 % price quantiles.
    """
    prices = context_start + np.arange(int(params.price_horizon_hours) + 1)
    q0 = context_start + observation.context_index(params, "price_quantiles")
    qi = {q: q0 + observation.PRICE_QUANTILES.index(q) for q in (0.2, 0.5, 0.8)}
    return prices, qi[0.2], qi[0.5], qi[0.8]


def relative_prices(obs, prices, q20, q50, q80) -> jnp.ndarray:
    """Each observed price's place in its day's range, ``(p - median) / (q80 - q20)``.

    Args:
        obs: ``(..., obs_size)`` observations.
        prices: the observed buy prices' columns, from `relative_price_columns`.
        q20: the column of the day's 20 % price quantile (from the same).
        q50: the column of the day's 50 % price quantile (from the same).
        q80: the column of the day's 80 % price quantile (from the same).

    Returns:
        ``(..., H + 1)`` float32, the spread floored at 0.01 EUR/kWh and the result clipped
        to [-5, 5].
    """
    spread = jnp.maximum(obs[..., q80] - obs[..., q20], 0.01 / PRICE_SCALE_EUR_KWH)[..., None]
    return jnp.clip((obs[..., prices] - obs[..., q50][..., None]) / spread, -5.0, 5.0)


def with_relative_prices(obs, columns) -> jnp.ndarray:
    """``obs`` with `relative_prices` appended.

    Args:
        obs: ``(..., obs_size)`` observations.
        columns: from `relative_price_columns`, or ``None``.

    Returns:
        ``(..., obs_size + H + 1)``, or ``obs`` itself when ``columns`` is ``None``.
    """
    if columns is None:
        return obs
    return jnp.concatenate([obs, relative_prices(obs, *columns)], axis=-1)
