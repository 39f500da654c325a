"""`chargax_marl.core.checks`: an array is read as `number` reads one value."""

import jax.numpy as jnp
import numpy as np
import pytest

from chargax_marl.core import checks


@pytest.mark.parametrize(
    "value",
    [["1.5", "2"], [True, False], np.array([1.0 + 2.0j]), np.array(["0.3"]), [0.5, "x"]],
    ids=["numeric strings", "bools", "complex", "string array", "mixed"],
)
def test_array_refuses_what_number_refuses(value):
    with pytest.raises(ValueError, match=r"field 'rate' must be an array of real numbers"):
        checks.array("rate", value, low=0.0)
    with pytest.raises(ValueError, match="field 'rate'"):
        checks.number("rate", np.asarray(value).ravel()[0], low=0.0)


@pytest.mark.parametrize(
    "value",
    [
        [0.5, 2],
        np.arange(3, dtype=np.int32),
        jnp.ones((2, 2), jnp.float32),
        3.0,
        np.array([1, 2.5], dtype=object),
    ],
    ids=["list", "int array", "jax array", "scalar", "object numbers"],
)
def test_array_reads_real_numbers_as_float64(value):
    out = checks.array("rate", value, low=0.0)
    assert out.dtype == np.float64
    np.testing.assert_array_equal(out, np.asarray(value, dtype=np.float64))


def test_array_names_the_first_bad_entry():
    with pytest.raises(ValueError, match=r"field 'rate' .* got -1.0 at index \(1, 0\)"):
        checks.array("rate", [[0.0, 1.0], [-1.0, 2.0]], low=0.0)
