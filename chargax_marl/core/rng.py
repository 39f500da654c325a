"""The simulator's random numbers: counter-based hashing of the caller's key.

Every random quantity of a transition (the arrival count, five attributes per arrival slot,
the day and battery SoC of an automatic reset) comes from one key. Drawing them with
``jax.random`` costs one Threefry-2x32 evaluation (20 rounds) per pair of 32-bit words plus a
``split`` per consumer, and ``jax.random.poisson`` runs both of its algorithms under ``vmap``;
on a CPU this was about half of a step (``benchmarks/profile_step.py``). Here the key's own
words are hashed once into a 64-bit seed, and each draw ``i`` of stream ``s`` is a hash of
``(seed, s, i)``: a handful of integer multiplies and shifts per number, whatever the key
implementation (threefry, rbg, unsafe_rbg; typed or raw ``uint32`` keys).

The hash is two rounds of the MurmurHash3 32-bit finaliser (``fmix32``, full avalanche: each
input bit flips each output bit with probability ~1/2) keyed by both seed words, i.e. a
SplitMix-style counter generator. Its statistical quality suffices for a simulator's
exogenous draws (tested in ``tests/test_rng.py``: moments, serial and cross-key
correlation, a chi-square test of the Poisson counts); it is not a cryptographic generator
and is not meant for anything that needs one. Uniforms have 24 random bits (float32
resolution).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

_GOLDEN = np.uint32(0x9E3779B9)
_M1 = np.uint32(0x85EBCA6B)
_M2 = np.uint32(0xC2B2AE35)
_STREAM = np.uint32(0x632BE5AB)

STREAM_VERSION = 3
"""The version of the random stream: bumped whenever the same key draws other cars, days or
SoCs (1: per-port draws of 0.1, 2: per-slot Threefry draws of 0.2, 3: this counter hash). It
is part of `chargax_marl.trace.params_fingerprint`, so results stored for one stream
are not read back as if they were another's."""

# Stream ids: one per consumer, so that draws of different purposes never share a counter.
ARRIVALS = 1
RESET = 2
VOLUME = 3
PORT_KIND = 4  # the session model v3's port kind and DC margin per car
DAY_VOLUME = 5  # a multi-day episode's volume draw of each new calendar day, at midnight


def fmix32(x: jnp.ndarray) -> jnp.ndarray:
    """MurmurHash3's 32-bit finaliser (a bijection of uint32 with full avalanche).

    Args:
        x: uint32 words, any shape.

    Returns:
        The hashed uint32 words, shaped as ``x``.
    """
    x = x ^ (x >> 16)
    x = x * _M1
    x = x ^ (x >> 13)
    x = x * _M2
    return x ^ (x >> 16)


def key_seed(key: jax.Array) -> jnp.ndarray:
    """The 64-bit seed ``(2,) uint32`` of one key: all of its words hashed together.

    Accepts typed keys (``jax.random.key``, any implementation) and raw ``uint32`` key arrays
    (``jax.random.PRNGKey``). Keys that differ in any bit give unrelated seeds.

    Args:
        key: one key, typed or raw (its words are flattened; the number of words is
            static).

    Returns:
        ``(2,)`` uint32, the seed words.
    """
    words = jax.random.key_data(key) if _is_typed(key) else jnp.asarray(key)
    words = jnp.reshape(words, (-1,)).astype(jnp.uint32)
    a = np.uint32(0x243F6A88)
    b = np.uint32(0x85A308D3)
    for i in range(words.shape[0]):  # static: 2 words for threefry, 4 for rbg
        a = fmix32(a ^ words[i])
        b = fmix32((b + words[i]) * _GOLDEN ^ a)
    return jnp.stack([a, b])


def _is_typed(key) -> bool:
    return hasattr(key, "dtype") and jnp.issubdtype(key.dtype, jax.dtypes.prng_key)


def bits(seed: jnp.ndarray, stream: int, shape: tuple[int, ...]) -> jnp.ndarray:
    """``shape`` uint32 words of ``stream`` from ``seed`` (see `key_seed`).

    Word ``i`` (in row-major order) hashes the counter ``i`` offset by the stream, keyed by
    both seed words; the same ``(seed, stream, i)`` always gives the same word.

    Args:
        seed: ``(2,)`` uint32, from `key_seed`.
        stream: the stream id (`ARRIVALS`, `RESET`, `VOLUME`, `PORT_KIND`).
        shape: the static shape of the result.

    Returns:
        uint32 words of shape ``shape``.
    """
    n = int(np.prod(shape, dtype=np.int64))
    counter = jnp.arange(n, dtype=jnp.uint32) + np.uint32((stream * int(_STREAM)) & 0xFFFFFFFF)
    x = fmix32(counter * _GOLDEN + seed[1])
    x = fmix32(x ^ seed[0])
    return jnp.reshape(x, shape)


def materialize(x: jnp.ndarray) -> jnp.ndarray:
    """``x`` unchanged (bit for bit), computed once.

    XLA fuses cheap elementwise producers (such as the hash) into *every* consumer, so a
    draw read by many per-leaf computations was recomputed in each of them (a 4-5x slower
    step). A division is an "expensive" op that XLA does not duplicate; dividing by a one it
    cannot fold (``1 + 0 * x``; ``0 * x`` is not simplified for floats) keeps the value exact
    and makes XLA compute it once and store it. (``jax.lax.optimization_barrier`` does not
    help: the CPU compiler removes it before fusion.)

    The value passes through float32, so it comes back unchanged for bools, finite float32
    and integers of magnitude up to ``2**24``: the values the simulator passes (+-inf
    becomes NaN, ``0 * inf`` being NaN).

    Args:
        x: a bool, integer or float array.

    Returns:
        ``x``'s values, its shape and dtype.
    """
    xf = x.astype(jnp.float32)
    out = xf / (1.0 + 0.0 * xf)
    return out.astype(x.dtype)


def uniform(seed: jnp.ndarray, stream: int, shape: tuple[int, ...]) -> jnp.ndarray:
    """Float32 uniforms in ``[0, 1)`` (24 random bits each), computed once (`materialize`).

    Args:
        seed: ``(2,)`` uint32, from `key_seed`.
        stream: the stream id (`ARRIVALS`, `RESET`, `VOLUME`, `PORT_KIND`).
        shape: the static shape of the result.

    Returns:
        float32 of shape ``shape``, multiples of ``2**-24`` in ``[0, 1)``.
    """
    return materialize((bits(seed, stream, shape) >> 8).astype(jnp.float32) * np.float32(2.0**-24))


POISSON_TERMS = 48
"""Terms of the inverse-CDF Poisson sum: exact (tail below 1e-8) up to a rate of 20 per step."""
POISSON_EXACT_MAX_RATE = 20.0


def poisson(u: jnp.ndarray, rate: jnp.ndarray) -> jnp.ndarray:
    """A Poisson(``rate``) count from one uniform ``u`` by inversion (int32).

    ``N = #{k : F(k) <= u}`` with the CDF summed term by term (``POISSON_TERMS`` terms,
    unrolled; no data-dependent loop, so ``vmap`` costs nothing extra). Exact for rates up to
    `POISSON_EXACT_MAX_RATE` (the truncated tail is below 1e-8); above it, the normal
    approximation ``round(rate + sqrt(rate) z)`` with ``z`` from the same uniform (the rates
    of the bundled scenarios are at most about 6.5 cars per step).

    Args:
        u: uniforms in ``[0, 1)``.
        rate: the expected counts (negative rates count as 0); broadcasts with ``u``.

    Returns:
        int32 counts (>= 0; at most `POISSON_TERMS` below the normal approximation's
        range), shaped as the broadcast of ``u`` and ``rate``.
    """
    rate = jnp.maximum(jnp.asarray(rate, jnp.float32), 0.0)
    term = jnp.exp(-jnp.minimum(rate, POISSON_EXACT_MAX_RATE))
    cdf = term
    count = jnp.zeros(jnp.shape(u), jnp.int32)
    for k in range(1, POISSON_TERMS + 1):
        count = count + (u >= cdf).astype(jnp.int32)
        term = term * rate / np.float32(k)
        cdf = cdf + term
    z = jax.scipy.special.ndtri(jnp.clip(u, 1e-7, 1.0 - 1e-7))
    normal = jnp.maximum(jnp.round(rate + jnp.sqrt(rate) * z), 0.0).astype(jnp.int32)
    return materialize(jnp.where(rate <= POISSON_EXACT_MAX_RATE, count, normal))
