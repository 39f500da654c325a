"""Relative prices, a network input: each observed price's place in its day's range."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from chargax_marl.core import observation
from chargax_marl.core.observation import PRICE_SCALE_EUR_KWH


def relative_price_columns(params, context_start: int):
    """``(price_cols, q20_col, q50_col, q80_col)``: where an observation whose shared context
    (:func:`chargax_marl.core.observation.context_features`) starts at column ``context_start``
    holds the observed buy prices (now and the next hours) and the day's 20 / 50 / 80 % price
    quantiles. The single-agent observation ends with the context; a
    :class:`chargax_marl.marl.ChargaxMARL` agent's has the agent index after it."""
    prices = context_start + np.arange(int(params.price_horizon_hours) + 1)
    q0 = context_start + observation.context_index(params, "price_quantiles")
    qi = {q: q0 + observation.PRICE_QUANTILES.index(q) for q in (0.2, 0.5, 0.8)}
    return prices, qi[0.2], qi[0.5], qi[0.8]


def with_relative_prices(obs, columns) -> jnp.ndarray:
    """The network input: ``obs`` with :func:`relative_prices` appended, or ``obs`` itself when
    ``columns`` (from :func:`relative_price_columns`) is ``None`` (``RELATIVE_PRICES`` off)."""
    if columns is None:
        return obs
    return jnp.concatenate([obs, relative_prices(obs, *columns)], axis=-1)


def relative_prices(obs, prices, q20, q50, q80) -> jnp.ndarray:
    """Each observed price's place in its day's range, ``(p - median) / (q80 - q20)`` (the spread
    floored at 0.01 EUR/kWh), clipped to [-5, 5]: the comparison a battery's charge or discharge
    decision turns on, which the raw prices (a few hundredths apart within a day, while the
    day's level moves by tenths) leave the network to learn."""
    spread = jnp.maximum(obs[..., q80] - obs[..., q20], 0.01 / PRICE_SCALE_EUR_KWH)[..., None]
    return jnp.clip((obs[..., prices] - obs[..., q50][..., None]) / spread, -5.0, 5.0)
