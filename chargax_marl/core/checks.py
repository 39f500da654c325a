"""One checker for every value a user hands the library (scalars, solver time limits, output
paths), and the bounds it enforces.

The simulator runs in float32 (and draws arrivals as int32), but users pass Python floats
(float64). A value can be finite in float64 and still overflow to inf, or underflow to 0,
once cast, and products of two legal magnitudes can overflow too. So every number is checked
*after* the cast and against a documented range that keeps the step's arithmetic finite:
`number` for scalars, `array` for arrays. Errors are ``ValueError`` and name the
field, the value and what is allowed.

The bounds (units in the names) are generous for real stations and data, and small enough
that no product in the step leaves float32.
"""

from __future__ import annotations

import argparse
import functools
import inspect
import math
import numbers
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

# Physical magnitudes of the station tree.
MIN_VOLTAGE_V = 1.0
MAX_VOLTAGE_V = 1e5
MIN_CURRENT_A = 1e-3
MAX_CURRENT_A = 1e5
MIN_POWER_KW = 1e-3
MAX_POWER_KW = 1e7
MIN_CAPACITY_KWH = 1e-3
MAX_CAPACITY_KWH = 1e7
MIN_EFFICIENCY = 1e-3
# Exogenous data and economics.
MAX_PRICE_EUR_KWH = (
    1e3  # |day-ahead price|, customer price, grid fee, battery terminal price (1e6 EUR/MWh)
)
MAX_FACTOR = 1e3  # feed-in factor, weekend volume factor, hourly scale factors
MAX_FIXED_COST_EUR = 1e6  # per step
MAX_BATTERY_COST_EUR_KWH = 1e5  # installed cost of a station battery per kWh of capacity
MIN_CYCLE_LIFE = 1.0  # full equivalent cycles
MAX_CYCLE_LIFE = 1e7
MIN_CALENDAR_LIFE_YEARS = 1e-2
MAX_CALENDAR_LIFE_YEARS = 1e3
MAX_WEIGHT = 1e6  # |alpha_c| and beta
MAX_TOLERANCE_KWH = 1e3
MAX_CARS_PER_DAY = 1e6  # keeps the int32 Poisson draw of arrivals per step far from saturating
MAX_STAY_MIN = 1e6
MAX_DEMAND_KWH = 1e6
MAX_GRID_DEMAND_KWH = 1e7  # per step
MAX_STEPS_PER_DAY = 86_400  # 1-second steps
MAX_NUM_LEVELS = 10_000  # discrete levels per direction; action indices stay far inside int32

_F32 = np.finfo(np.float32)


def _range_text(
    low: float | None, high: float | None, low_open: bool, high_open: bool, unit: str
) -> str:
    u = f" {unit}" if unit else ""
    if low is not None and high is not None:
        return f"in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}{u}"
    if low is not None:
        return f"{'>' if low_open else '>='} {low:g}{u}"
    if high is not None:
        return f"{'<' if high_open else '<='} {high:g}{u}"
    return "finite"


def number(
    field: str,
    value: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    unit: str = "",
    owner: str = "",
    integer: bool = False,
) -> float:
    """``value`` as a float that is finite, in range and representable in float32.

    ``owner`` prefixes the message (e.g. ``"Port 'p'"``). Bools and strings are rejected.

    Args:
        field: the name the error message gives the value.
        value: the value: a Python or numpy real number, or a 0-d numpy or jax array of a real
            dtype.
        low: the lowest allowed value; ``None`` for no lower bound.
        high: the highest allowed value; ``None`` for no upper bound.
        low_open: ``low`` itself is not allowed.
        high_open: ``high`` itself is not allowed.
        unit: the unit the message writes after the bounds (e.g. ``"kW"``).
        owner: a prefix naming what the value belongs to; empty for none.
        integer: the value must be an integer (`numbers.Integral`, or a 0-d array of an
            integer dtype); a float like ``2.0`` is rejected.

    Returns:
        The value as a Python float (also when ``integer``).

    Raises:
        ValueError: ``value`` is a bool, not a real number (an integer when ``integer``),
            not finite, outside the range, or overflows or underflows (a nonzero value
            becoming 0 or subnormal) in float32.
    """
    who = f"{owner}: " if owner else ""
    allowed = _range_text(low, high, low_open, high_open, unit)
    kind = "an integer" if integer else "a finite number"
    ok_type = isinstance(value, numbers.Integral if integer else numbers.Real)
    if (
        not ok_type
        and not isinstance(value, (str, bytes))
        and hasattr(value, "dtype")
        and hasattr(value, "ndim")
    ):
        # 0-d numpy or jax arrays
        ok_type = (
            value.ndim == 0
            and np.issubdtype(value.dtype, np.integer if integer else np.number)
            and not np.issubdtype(value.dtype, np.complexfloating)
        )
    if isinstance(value, (bool, np.bool_)) or not ok_type:
        raise ValueError(f"{who}field '{field}' must be {kind} {allowed}, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(f"{who}field '{field}' must be {kind} {allowed}, got {value!r}")
    bad = (low is not None and (x <= low if low_open else x < low)) or (
        high is not None and (x >= high if high_open else x > high)
    )
    if bad:
        raise ValueError(f"{who}field '{field}' must be {kind} {allowed}, got {value!r}")
    x32 = float(np.float32(x))
    if not math.isfinite(x32) or (x != 0.0 and abs(x32) < _F32.tiny):
        raise ValueError(
            f"{who}field '{field}' must be {kind} {allowed} that float32 can represent "
            f"(it underflows to 0 or overflows), got {value!r}"
        )
    return x


def array(
    field: str,
    value: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    unit: str = "",
) -> np.ndarray:
    """``value`` as a float64 array whose entries are finite and in range (checked as `number`).

    The message names the first offending entry and its index.

    Args:
        field: the name the error message gives the array.
        value: anything `numpy.asarray` turns into a float64 array, any shape.
        low: the lowest allowed entry; ``None`` for no lower bound.
        high: the highest allowed entry; ``None`` for no upper bound.
        low_open: ``low`` itself is not allowed.
        high_open: ``high`` itself is not allowed.
        unit: the unit the message writes after the bounds (e.g. ``"EUR/kWh"``).

    Returns:
        ``value`` as a float64 numpy array of its own shape.

    Raises:
        ValueError: ``value`` cannot be read as an array of real numbers (strings, bools
            and complex numbers are refused, as `number` refuses them), or an entry is not
            finite, is outside the range, or overflows or underflows in float32.
    """
    try:
        raw = np.asarray(value)
        if raw.dtype.kind not in "iuf":
            # object arrays (numbers of mixed types) pass when each entry would pass `number`
            if raw.dtype.kind != "O" or any(
                isinstance(v, (bool, np.bool_, str, bytes)) or not isinstance(v, numbers.Real)
                for v in raw.ravel()
            ):
                raise TypeError(f"entries of dtype {raw.dtype}")
        arr = raw.astype(np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"field '{field}' must be an array of real numbers, got {type(value).__name__} ({exc})"
        ) from None
    allowed = _range_text(low, high, low_open, high_open, unit)
    bad = ~np.isfinite(arr)
    if low is not None:
        bad |= (arr <= low) if low_open else (arr < low)
    if high is not None:
        bad |= (arr >= high) if high_open else (arr > high)
    with np.errstate(over="ignore", under="ignore"):
        a32 = arr.astype(np.float32)
    bad |= ~np.isfinite(a32) | ((arr != 0) & (np.abs(a32) < _F32.tiny))
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        where = idx[0] if len(idx) == 1 else idx
        raise ValueError(
            f"field '{field}' must hold finite numbers {allowed}, got {float(arr[idx])!r} at index {where}"
        )
    return arr


def keywords(owner: str, given: dict, allowed: tuple | list) -> None:
    """Raise ``TypeError`` naming unknown keyword arguments and the allowed names.

    Args:
        owner: the name of the function or class the message names.
        given: the keyword arguments given (only the keys are read).
        allowed: the allowed keyword names.

    Raises:
        TypeError: ``given`` has a key not in ``allowed``.
    """
    unknown = sorted(set(given) - set(allowed))
    if unknown:
        raise TypeError(
            f"{owner}: unknown keyword argument(s) {unknown}; allowed: {sorted(allowed)}"
        )


def known_keywords(fn):
    """Decorate ``fn`` so that an unknown keyword raises ``TypeError`` listing the allowed ones.

    (Python's own error names the bad keyword but not the ones that exist.) The allowed
    names are ``fn``'s positional-or-keyword and keyword-only parameters.

    Args:
        fn: the function to wrap.

    Returns:
        ``fn`` itself when it takes ``**kwargs``; otherwise a wrapper (`functools.wraps`)
        that checks the keyword arguments with `keywords` and then calls ``fn``.
    """

    sig = inspect.signature(fn)
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in sig.parameters.values()):
        return fn
    allowed = tuple(
        n
        for n, p in sig.parameters.items()
        if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    )

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        keywords(fn.__name__, kwargs, allowed)
        return fn(*args, **kwargs)

    return wrapper


def time_limit(field: str, value: Any) -> float | None:
    """A solver's time limit: ``None`` (no limit) or a positive finite number of seconds.

    ``-1``, ``0``, NaN and inf would reach HiGHS, which reads them as "no limit" (or stops
    at once); every solver entry point checks its limit here first.

    Args:
        field: the name the error message gives the value (e.g. ``"time_limit_s"``).
        value: the limit in seconds, or ``None``.

    Returns:
        ``None``, or the limit as a float (seconds).

    Raises:
        ValueError: ``value`` is not ``None`` and not a finite number > 0.
    """
    if value is None:
        return None
    return number(field, value, low=0.0, low_open=True, unit="s (None: no limit)")


OUTPUT_KINDS = ("file", "dir", "prefix")
"""What `output_path` checks a destination as."""


def output_path(field: str, value: Any, kind: str = "file") -> Any:
    """An output destination, checked before any work: a command refuses it at once instead
    of failing when it writes.

    Refused: an empty path (or only spaces), a path through an existing file (``a_file/x``),
    a file where a directory is meant or a directory where a file or a prefix's file is
    meant, a prefix without a name of its own (``outputs/``, ``.``), and a destination whose
    nearest existing folder this process may not write to. A prefix is returned as typed:
    its files are ``prefix + suffix`` (``sessions.v2`` writes ``sessions.v2.json``).

    Args:
        field: the option or key the message names (e.g. ``"--out"``, ``"OUT"``).
        value: the destination, a string or path.
        kind: ``"file"`` (one file, written whole), ``"dir"`` (a directory, created if
            missing) or ``"prefix"`` (a path prefix of several files ``prefix + suffix``).

    Returns:
        ``value`` as a `pathlib.Path` (``"file"``, ``"dir"``) or as the string typed
        (``"prefix"``).

    Raises:
        ValueError: an unknown ``kind``, or an unusable destination (the message names the
            field, the value and why).
    """
    if kind not in OUTPUT_KINDS:
        raise ValueError(f"field 'kind' must be one of {list(OUTPUT_KINDS)}, got {kind!r}")
    if isinstance(value, Path):
        text = str(value)
    elif isinstance(value, str):
        text = value
    else:
        raise ValueError(
            f"field '{field}' must be a path (a string), got {type(value).__name__} {value!r}"
        )

    def refuse(why: str) -> None:
        raise ValueError(f"field '{field}' must name a usable output {kind}, got {text!r}: {why}")

    if not text.strip():
        refuse("the path is empty")
    if "\x00" in text:
        refuse("the path holds a NUL character")
    path = Path(text)
    if kind == "prefix" and (text.endswith(("/", os.sep)) or path.name in ("", ".", "..")):
        refuse("a prefix needs a file name after its folder (e.g. outputs/sweep)")
    if kind == "file" and text.endswith(("/", os.sep)):
        refuse("a file's path cannot end in '/'")
    if path.exists():
        if kind == "dir" and not path.is_dir():
            refuse("it is an existing file, not a directory")
        if kind == "file" and path.is_dir():
            refuse("it is an existing directory, not a file")
        if kind == "dir" and not os.access(path, os.W_OK | os.X_OK):
            refuse("this process may not write to that directory")
        if kind == "file" and not os.access(path, os.W_OK):
            refuse("this process may not write to that file")
        if kind == "dir":
            return path
    folder = path if kind == "dir" else path.parent
    ancestor = folder
    while not ancestor.exists():
        if ancestor.is_symlink():
            refuse(f"{str(ancestor)!r} is a broken link")
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        refuse(f"{str(ancestor)!r} is a file, not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        refuse(f"this process may not write to the folder {str(ancestor)!r}")
    return text if kind == "prefix" else path


def output_option(kind: str = "file") -> Callable[[str], Any]:
    """An ``argparse`` ``type=`` for an output option: the path checked by `output_path` while
    the command line is parsed, before any work.

    Args:
        kind: ``"file"``, ``"dir"`` or ``"prefix"`` (`output_path`).

    Returns:
        ``parse(text)``: `output_path`'s value, or ``argparse.ArgumentTypeError`` with its
        message (argparse names the option and exits with status 2).

    Raises:
        ValueError: an unknown ``kind``.
    """
    if kind not in OUTPUT_KINDS:
        raise ValueError(f"field 'kind' must be one of {list(OUTPUT_KINDS)}, got {kind!r}")

    def parse(text: str) -> Any:
        try:
            return output_path("path", text, kind)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    return parse
