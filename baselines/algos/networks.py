"""Actor and critic MLPs, the always-max prior, and masked categorical distributions."""

from __future__ import annotations

from collections.abc import Callable

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax.linen.initializers import constant, variance_scaling

NEG_INF = -1e9


def _act(name: str) -> Callable:
    return {"tanh": nn.tanh, "relu": nn.relu}[name]


def _init(gain: float):
    """Gaussian init with the variance of an orthogonal init of this gain (``gain**2 / fan_in``).

    Not ``orthogonal``: its batched QR (under ``jax.vmap`` over seeds) runs LAPACK on XLA's
    CPU thread pool, which deadlocked on this 2-core machine under load (jaxlib 0.10).
    """
    return variance_scaling(gain**2, "fan_in", "normal")


class MLP(nn.Module):
    """``NUM_LAYERS`` hidden layers then a linear head (PureJaxRL's gains: sqrt(2) hidden,
    0.01 policy head, 1 value head).

    Every layer's weights are drawn from a normal distribution of variance
    ``gain**2 / fan_in``, its biases 0.

    Attributes:
        out: the head's outputs (logits or values).
        hidden: the width of each hidden layer.
        layers: the number of hidden layers.
        activation: the hidden layers' activation, ``"tanh"`` or ``"relu"``.
        head_scale: the head's gain (0.01 for a policy head, 1 for a value head).
        parent: the parent module (flax's; None for a top-level module).
        name: the module's name (flax's; None: assigned by its parent).
    """

    out: int
    hidden: int = 256
    layers: int = 2
    activation: str = "tanh"
    head_scale: float = 0.01

    @nn.compact
    def __call__(self, x):
        for _ in range(self.layers):
            x = _act(self.activation)(
                nn.Dense(self.hidden, kernel_init=_init(np.sqrt(2)), bias_init=constant(0.0))(x)
            )
        return nn.Dense(self.out, kernel_init=_init(self.head_scale), bias_init=constant(0.0))(x)


def actor_critic(config: dict, num_logits: int, num_values: int = 1):
    """The actor and critic `MLP`s of a trainer's config.

    Args:
        config: the trainer's config (``HIDDEN``, ``NUM_LAYERS``, ``ACTIVATION``).
        num_logits: the actor's outputs.
        num_values: the critic's outputs.

    Returns:
        ``(actor, critic)``: the actor with a head of gain 0.01, the critic with one of
        gain 1, both of the config's width, depth and activation.

    Raises:
        KeyError: the config lacks one of the three keys.
    """
    kw = dict(
        hidden=int(config["HIDDEN"]),
        layers=int(config["NUM_LAYERS"]),
        activation=config["ACTIVATION"],
    )
    return MLP(num_logits, head_scale=0.01, **kw), MLP(num_values, head_scale=1.0, **kw)


def always_max_prior(config: dict) -> tuple[float, float]:
    """The validated ``(ALWAYS_MAX_PRIOR, BATTERY_IDLE_PRIOR)``: fixed offsets ``>= 0`` added to
    the logit of the action that the always-max baseline takes, full power at every port and
    idle at every battery. With both ``> 0`` the untrained greedy policy *is* always-max and
    the sampled policy explores around it (an offset of 6 leaves about 5 % of a 21-action
    head's mass on the other 20 actions, 2 about 73 %); training moves away from the
    baseline wherever that pays, since the network's logits can outweigh the offsets. A
    weaker battery offset keeps the battery exploring. ``0`` is the plain policy.

    Args:
        config: the trainer's config (``ALWAYS_MAX_PRIOR``, ``BATTERY_IDLE_PRIOR``; each
            default 0).

    Returns:
        ``(always_max_prior, battery_idle_prior)`` as floats.

    Raises:
        ValueError: an offset that is negative or not finite.
    """
    out = []
    for name in ("ALWAYS_MAX_PRIOR", "BATTERY_IDLE_PRIOR"):
        b = float(config.get(name, 0.0))
        if not np.isfinite(b) or b < 0:
            raise ValueError(f"{name}={b} must be a finite number >= 0 (0 disables the offset)")
        out.append(b)
    return tuple(out)


def residual_prior(config: dict) -> tuple[float, float]:
    """The validated ``(RESIDUAL_PRIOR, RESIDUAL_BATTERY_PRIOR)``: how sharply the untrained
    policy of a ``RESIDUAL`` actor centres on the base rule's action (`residual_offsets`), at
    the ports and at the batteries.

    Args:
        config: the trainer's config (``RESIDUAL_PRIOR``, default 2;
            ``RESIDUAL_BATTERY_PRIOR``, default None: ``RESIDUAL_PRIOR``).

    Returns:
        ``(port_strength, battery_strength)`` as floats.

    Raises:
        ValueError: a strength that is not finite or not positive.
    """
    port = config.get("RESIDUAL_PRIOR", 2.0)
    battery = config.get("RESIDUAL_BATTERY_PRIOR")
    out = []
    for name, b in (
        ("RESIDUAL_PRIOR", port),
        ("RESIDUAL_BATTERY_PRIOR", port if battery is None else battery),
    ):
        b = float(b)
        if not np.isfinite(b) or b <= 0:
            raise ValueError(f"{name}={b} must be a finite number > 0")
        out.append(b)
    return tuple(out)


def residual_offsets(rule_index: jnp.ndarray, num_actions: int, strength) -> jnp.ndarray:
    """Logit offsets ``-strength * |j - rule_index|`` over the actions ``j``: the base rule's
    action gets the largest, and the further an action's level is from it, the smaller its
    offset. Added to an actor's logits (its head starts near 0), the untrained greedy policy
    is the rule and the sampled one explores the neighbouring levels most.

    Args:
        rule_index: ``(...)`` the rule's action indices (floats or ints).
        num_actions: the actions ``K``.
        strength: logit per level of distance (`residual_prior`), a float or ``(...)``
            per row.

    Returns:
        ``(..., K)`` float32 offsets.
    """
    j = jnp.arange(num_actions, dtype=jnp.float32)
    strength = jnp.asarray(strength, jnp.float32)[..., None]
    return -strength * jnp.abs(j - jnp.asarray(rule_index, jnp.float32)[..., None])


def masked_logits(logits: jnp.ndarray, mask) -> jnp.ndarray:
    """``logits`` with every action that ``mask`` rules out set to `NEG_INF`.

    Args:
        logits: ``(..., K)`` logits.
        mask: bool, broadcastable to ``logits``; True where the action is allowed.

    Returns:
        ``(..., K)`` the masked logits.
    """
    return jnp.where(mask, logits, NEG_INF)


def log_prob(logits: jnp.ndarray, action: jnp.ndarray) -> jnp.ndarray:
    """Log-probability of integer ``action`` under (masked) ``logits (..., K)``.

    Args:
        logits: ``(..., K)`` logits.
        action: ``(...)`` action indices in ``[0, K)``.

    Returns:
        ``(...)`` the log-probability of each action under ``softmax(logits)``.
    """
    logp = jax.nn.log_softmax(logits, axis=-1)
    return jnp.take_along_axis(logp, action[..., None].astype(jnp.int32), axis=-1)[..., 0]


# t = u * total is shrunk by this relative margin so that rounding can never push it to the
# total, where the inversion would fall through to the masked (zero-probability) tail.
_INVERSION_MARGIN = np.float32(1.0 - 2.0**-22)


def categorical_from_uniform(u: jnp.ndarray, logits: jnp.ndarray):
    """One draw per head from ``softmax(logits (..., K))`` by inverting its CDF at ``u (...)``
    in ``[0, 1)``.

    The chosen index is the first ``j`` with ``cdf[j] > u * cdf[K-1]``, so an index of zero
    probability (a masked action, ``NEG_INF`` logit) is never chosen, whatever ``u``; the
    margin keeps ``u * cdf[K-1]`` below ``cdf[K-1]``, so some ``j < K`` always qualifies.

    Args:
        u: ``(...)`` uniforms in ``[0, 1)``, one per head.
        logits: ``(..., K)`` logits.

    Returns:
        ``(action, logp)``: ``(...)`` int32 actions and their ``(...)`` log-probabilities.
    """
    logp_all = jax.nn.log_softmax(logits, axis=-1)
    cdf = jnp.cumsum(jnp.exp(logp_all), axis=-1)
    t = (u * _INVERSION_MARGIN)[..., None] * cdf[..., -1:]
    action = jnp.sum(cdf <= t, axis=-1, dtype=jnp.int32)
    return action, jnp.take_along_axis(logp_all, action[..., None], axis=-1)[..., 0]


def sample_categorical(key: jax.Array, logits: jnp.ndarray):
    """``(action, log-probability)`` of one draw per head of ``logits (..., K)``.

    Same distribution as ``jax.random.categorical`` (which adds Gumbel noise to every logit,
    ``K`` uniforms per head), from one uniform per head by inversion
    (`categorical_from_uniform`): on a CPU the Gumbel draw was most of a small PPO rollout
    step (``docs/performance.md``, training speed).

    Args:
        key: a PRNG key.
        logits: ``(..., K)`` logits.

    Returns:
        ``(action, logp)``: ``(...)`` int32 actions and their ``(...)`` log-probabilities.
    """
    return categorical_from_uniform(jax.random.uniform(key, logits.shape[:-1]), logits)


def entropy(logits: jnp.ndarray) -> jnp.ndarray:
    """The entropy of ``softmax(logits)`` per head (nats); actions of probability 0 add 0.

    Args:
        logits: ``(..., K)`` logits.

    Returns:
        ``(...)`` the entropies.
    """
    logp = jax.nn.log_softmax(logits, axis=-1)
    p = jnp.exp(logp)
    return -jnp.sum(jnp.where(p > 0, p * logp, 0.0), axis=-1)
