"""The simulator's counter-hash random numbers (chargax_marl.core.rng): distribution,
independence, key handling, the Poisson inversion, and that XLA computes them once."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from chargax_marl.core import rng


def test_uniforms_are_uniform_and_in_range():
    u = np.asarray(rng.uniform(rng.key_seed(jax.random.PRNGKey(3)), rng.ARRIVALS, (200_000,)))
    assert u.dtype == np.float32 and u.min() >= 0.0 and u.max() < 1.0
    assert stats.kstest(u, "uniform").pvalue > 1e-3
    # serial correlation between consecutive counters
    assert abs(np.corrcoef(u[:-1], u[1:])[0, 1]) < 0.01


def test_adjacent_keys_and_streams_are_uncorrelated():
    # raw keys that differ in one bit (PRNGKey(i) vs PRNGKey(i + 1)) must give unrelated draws
    draws = jax.vmap(
        lambda i: rng.uniform(rng.key_seed(jax.random.PRNGKey(i)), rng.ARRIVALS, (4,))
    )(jnp.arange(50_000))
    d = np.asarray(draws)
    assert abs(np.corrcoef(d[:-1, 0], d[1:, 0])[0, 1]) < 0.02
    assert abs(np.corrcoef(d[:, 0], d[:, 1])[0, 1]) < 0.02
    other = jax.vmap(lambda i: rng.uniform(rng.key_seed(jax.random.PRNGKey(i)), rng.RESET, (1,)))(
        jnp.arange(50_000)
    )
    assert abs(np.corrcoef(d[:, 0], np.asarray(other)[:, 0])[0, 1]) < 0.02
    assert stats.kstest(d[:, 0], "uniform").pvalue > 1e-3


@pytest.mark.parametrize("impl", ["threefry2x32", "rbg", "unsafe_rbg"])
def test_every_key_kind_is_accepted(impl):
    typed = jax.random.key(5, impl=impl)
    seed = rng.key_seed(typed)
    assert seed.shape == (2,) and seed.dtype == jnp.uint32
    assert not np.array_equal(
        np.asarray(seed), np.asarray(rng.key_seed(jax.random.key(6, impl=impl)))
    )
    # a raw threefry key and its typed twin give the same draws
    if impl == "threefry2x32":
        np.testing.assert_array_equal(
            np.asarray(seed), np.asarray(rng.key_seed(jax.random.PRNGKey(5)))
        )


@pytest.mark.parametrize("rate", [0.05, 0.9, 2.34, 6.5, 15.0])
def test_poisson_inversion_matches_the_pmf(rate):
    u = rng.uniform(rng.key_seed(jax.random.PRNGKey(11)), rng.ARRIVALS, (100_000,))
    counts = np.asarray(rng.poisson(u, rate))
    assert counts.dtype == np.int32 and counts.min() >= 0
    kmax = int(stats.poisson.ppf(1 - 1e-4, rate))
    observed = np.bincount(np.minimum(counts, kmax), minlength=kmax + 1)
    expected = stats.poisson.pmf(np.arange(kmax + 1), rate)
    expected[-1] += stats.poisson.sf(kmax, rate)
    expected *= counts.size
    keep = expected > 5  # chi-square validity
    chi2 = ((observed[keep] - expected[keep]) ** 2 / expected[keep]).sum()
    assert stats.chi2.sf(chi2, keep.sum() - 1) > 1e-3


def test_poisson_is_the_exact_inverse_cdf():
    rate = 2.0
    for k in range(8):
        lo, hi = stats.poisson.cdf(k - 1, rate) if k else 0.0, stats.poisson.cdf(k, rate)
        mid = np.float32((lo + hi) / 2)
        assert int(rng.poisson(jnp.float32(mid), rate)) == k


def test_poisson_large_rate_uses_the_normal_approximation():
    u = rng.uniform(rng.key_seed(jax.random.PRNGKey(2)), rng.ARRIVALS, (100_000,))
    counts = np.asarray(rng.poisson(u, 60.0))
    assert abs(counts.mean() - 60.0) < 0.2 and abs(counts.var() / 60.0 - 1.0) < 0.05


def test_materialize_is_bit_exact():
    x = jnp.asarray([0.0, 1e-30, 0.3, 1.0 - 2**-24, 7.0], jnp.float32)
    np.testing.assert_array_equal(np.asarray(rng.materialize(x)), np.asarray(x))
    i = jnp.asarray([0, 1, 5, 40], jnp.int32)
    np.testing.assert_array_equal(np.asarray(rng.materialize(i)), np.asarray(i))


def test_the_draws_are_computed_once_in_the_compiled_step():
    """XLA must not re-fuse the hash into its consumers: in the compiled (vmapped) env step
    the hash constant appears a few times, not once per consumer fusion (28 times without
    `rng.materialize`, and a step 5-10x slower on a batch)."""
    from chargax_marl.single import make

    env, params = make("shopping")
    _, state = env.reset(jax.random.PRNGKey(0), params)
    action = jnp.zeros((params.station.num_leaves,), jnp.int32)
    step = jax.vmap(lambda k, s: env.step(k, s, action, params)[:3], in_axes=(0, None))
    text = (
        jax.jit(step).lower(jax.random.split(jax.random.PRNGKey(0), 8), state).compile().as_text()
    )
    uses = text.count(str(int(rng._M1)))
    assert 1 <= uses <= 6, (
        f"fmix32's constant appears {uses} times: the hash is duplicated across fusions"
    )
