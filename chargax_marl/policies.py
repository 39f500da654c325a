"""Rule-based policies, written in the core's per-leaf levels so both views can use them.

A policy is ``policy(state, key, params) -> levels`` with one signed level per leaf (ports,
then batteries) in ``[-L, L]``. Convert to a view's action with
``Chargax.levels_to_action`` (single agent) or the multi-agent view's equivalent.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from chargax_marl.core import physics
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.core.types import EnvParams, EnvState


def always_max(state: EnvState, key: jax.Array, params: EnvParams) -> jnp.ndarray:
    """The paper's baseline: every port at its highest level, batteries idle.

    The car's rate curve and the node limits then cut the current to what is possible,
    so every car charges as fast as the station allows.
    """
    del state, key
    is_battery = params.station.leaf_kind == KIND_BATTERY
    return jnp.where(is_battery, 0, params.num_levels).astype(jnp.int32)


def random_policy(state: EnvState, key: jax.Array, params: EnvParams) -> jnp.ndarray:
    """Uniform random level per leaf within the leaf's valid range."""
    del state
    low = physics.leaf_min_level(params.station, params.num_levels, params.v2g)
    return jax.random.randint(key, low.shape, low, params.num_levels + 1).astype(jnp.int32)


POLICIES = {"always_max": always_max, "random": random_policy}
