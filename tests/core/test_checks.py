"""`chargax_marl.core.checks`: an array is read as `number` reads one value."""

import os

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


# --- output paths and solver time limits ----------------------------------------------------


def test_output_path_refuses_unusable_destinations(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for value, kind, why in (
        ("", "dir", "the path is empty"),
        ("  ", "prefix", "the path is empty"),
        (str(a_file / "sessions"), "prefix", "is a file, not a folder"),
        (str(a_file / "deeper" / "run"), "dir", "is a file, not a folder"),
        (str(a_file), "dir", "an existing file, not a directory"),
        (str(tmp_path), "file", "an existing directory, not a file"),
        (str(tmp_path) + "/", "prefix", "a prefix needs a file name"),
        (".", "prefix", "a prefix needs a file name"),
    ):
        with pytest.raises(
            ValueError, match=rf"field 'OUT' must name a usable output {kind}.*{why}"
        ):
            checks.output_path("OUT", value, kind)
    with pytest.raises(ValueError, match="field 'OUT' must be a path"):
        checks.output_path("OUT", 3, "file")
    with pytest.raises(ValueError, match="field 'kind'"):
        checks.output_path("OUT", "x", "folder")


def test_output_path_refuses_a_folder_it_may_not_write(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if os.access(locked, os.W_OK):  # running as root: every folder is writable
            pytest.skip("this process may write to any folder")
        with pytest.raises(ValueError, match="may not write to the folder"):
            checks.output_path("--out", str(locked / "x" / "sessions"), "prefix")
    finally:
        locked.chmod(0o700)


def test_output_path_keeps_a_prefix_as_typed(tmp_path):
    prefix = str(tmp_path / "new" / "sessions.v2")
    assert checks.output_path("--out", prefix, "prefix") == prefix
    assert checks.output_path("OUT", tmp_path / "run", "dir") == tmp_path / "run"
    assert checks.output_path("--out", str(tmp_path / "s.json"), "file") == tmp_path / "s.json"


@pytest.mark.parametrize("value", [-1, 0, float("nan"), float("inf"), "10", True])
def test_time_limit_refuses_what_is_not_a_positive_number_of_seconds(value):
    with pytest.raises(ValueError, match=r"field 'time_limit_s' must be a finite number > 0 s"):
        checks.time_limit("time_limit_s", value)
    assert checks.time_limit("time_limit_s", None) is None
    assert checks.time_limit("time_limit_s", 2) == 2.0
