"""Network tariff terms on top of the day-ahead price: a time-of-use surcharge and a peak-demand
charge. One validator per field, used by `chargax_marl.core.params.make_params`.

- **Time of use** (``tou_fee_eur_kwh``): EUR/kWh added to the buy price in each local hour,
  an array of 24 values or a preset name from `TOU_PRESETS`. The optimal-control LP and
  the MPC read the same buy price (`chargax_marl.core.reward.grid_prices`).
- **Peak demand** (``peak_demand_eur_kw``): EUR per kW of the day's highest grid draw (the
  station's net draw at the grid connection, averaged over a step), charged once per day.
  ``peak_demand_booking`` chooses when the money is booked: ``"end_of_day"`` (the whole
  charge at the last step, as an operator's bill) or ``"incremental"`` (each step books the
  rise of the running peak; the daily total is the same, the timing is what a learner can
  attribute to the step that raised the peak).

The presets are illustrative scenario settings, not any operator's published tariff: their
sizes are of the order of European network charges (a few cents per kWh of peak-hour
surcharge, a few EUR per kW and month of capacity charge, i.e. about 0.1-0.2 EUR per kW and
day), chosen so that coordinating the ports pays.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from chargax_marl.core import checks

HOURS_PER_DAY = 24


def _hours(surcharge_eur_kwh: float, first_hour: int, last_hour: int) -> tuple[float, ...]:
    """A 24-hour surcharge of ``surcharge_eur_kwh`` in hours ``first_hour..last_hour - 1``."""
    return tuple(
        surcharge_eur_kwh if first_hour <= h < last_hour else 0.0 for h in range(HOURS_PER_DAY)
    )


TOU_PRESETS: dict[str, tuple[float, ...]] = {
    "flat": _hours(0.0, 0, 0),
    # a peak-hour surcharge on the evening peak of the distribution grid, 17:00-21:00
    "evening-peak": _hours(0.12, 17, 21),
    # a day/night split: 07:00-23:00 dearer than the night
    "day-night": _hours(0.05, 7, 23),
}
"""Named time-of-use surcharges, EUR/kWh per local hour (illustrative, see the module docstring)."""

PEAK_BOOKINGS = ("end_of_day", "incremental")

DEFAULT_PEAK_DEMAND_EUR_KW = 0.15
"""The peak-demand charge of the named ``-peak`` scenarios, EUR per kW of the day's peak
(about 4.5 EUR per kW and month; illustrative, see the module docstring)."""


def tou_fee(value: Any) -> np.ndarray:
    """Validated time-of-use surcharge ``(24,)`` float32 in EUR/kWh: None (no surcharge), a
    preset name of `TOU_PRESETS`, or 24 finite numbers within +-``checks.MAX_PRICE_EUR_KWH``.

    Args:
        value: ``None``, a preset's name, or 24 surcharges (EUR/kWh), one per local hour
            from 00:00.

    Returns:
        ``(24,)`` float32 EUR/kWh (zeros for ``None``).

    Raises:
        ValueError: an unknown preset name; a value that is not 24 numbers; or a surcharge
            that is not finite, beyond +-``checks.MAX_PRICE_EUR_KWH`` or not representable
            in float32.
    """
    if value is None:
        return np.zeros(HOURS_PER_DAY, np.float32)
    if isinstance(value, str):
        if value not in TOU_PRESETS:
            raise ValueError(
                f"field 'tou_fee_eur_kwh' must be one of {sorted(TOU_PRESETS)} or 24 hourly "
                f"surcharges in EUR/kWh, got {value!r}"
            )
        return np.asarray(TOU_PRESETS[value], np.float32)
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"field 'tou_fee_eur_kwh' must be 24 hourly surcharges in EUR/kWh, got {value!r}"
        ) from None
    if arr.shape != (HOURS_PER_DAY,):
        raise ValueError(
            f"field 'tou_fee_eur_kwh' must have shape ({HOURS_PER_DAY},) (one surcharge per local hour), "
            f"got shape {arr.shape}"
        )
    for h, v in enumerate(arr):
        checks.number(
            f"tou_fee_eur_kwh[{h}]",
            float(v),
            low=-checks.MAX_PRICE_EUR_KWH,
            high=checks.MAX_PRICE_EUR_KWH,
            unit="EUR/kWh",
        )
    return arr.astype(np.float32)


def peak_demand(rate_eur_kw: Any, booking: Any) -> tuple[float, bool]:
    """Validated ``(rate in EUR per kW of the day's peak, incremental booking?)``.

    Args:
        rate_eur_kw: the peak-demand charge, EUR per kW of the day's peak, in
            ``[0, 24 * checks.MAX_PRICE_EUR_KWH]``.
        booking: ``"end_of_day"`` or ``"incremental"`` (`PEAK_BOOKINGS`).

    Returns:
        ``(rate, incremental)``: the rate as a float and whether ``booking`` is
        ``"incremental"``.

    Raises:
        ValueError: the rate is not a finite number in range, or ``booking`` is not one of
            `PEAK_BOOKINGS`.
    """
    rate = checks.number(
        "peak_demand_eur_kw",
        rate_eur_kw,
        low=0.0,
        high=checks.MAX_PRICE_EUR_KWH * 24.0,
        unit="EUR/kW",
    )
    if booking not in PEAK_BOOKINGS:
        raise ValueError(
            f"field 'peak_demand_booking' must be one of {PEAK_BOOKINGS}, got {booking!r}"
        )
    return rate, booking == "incremental"
