"""Public holidays of the days of a price dataset (the `holidays` package).

A holiday's arrivals follow the weekend row of the arrival rate. The simulator reads the
result as a ``(days,)`` bool array (`chargax_marl.core.types.EnvParams.holiday`).
"""

from __future__ import annotations

import datetime as dt

import holidays as holidays_lib
import numpy as np

HOLIDAY_COUNTRIES: tuple[str, ...] = ("NL", "DE", "FR", "BE", "AT", "US")
"""Country codes accepted for ``make_params(holidays=...)``."""


def holiday_days(country: str, first_date: str | dt.date, num_days: int) -> np.ndarray:
    """Which of ``num_days`` consecutive days from ``first_date`` are public holidays.

    Args:
        country: an ISO 3166 code in `HOLIDAY_COUNTRIES`.
        first_date: the date of day 0 (ISO string or date).
        num_days: the number of days (>= 1).

    Returns:
        ``(num_days,)`` bool.

    Raises:
        ValueError: an unknown country or a malformed date; the message names the field.
    """
    if country not in HOLIDAY_COUNTRIES:
        raise ValueError(
            f"field 'holidays': unknown country {country!r}; valid codes are "
            f"{list(HOLIDAY_COUNTRIES)}, 'auto' or None"
        )
    if isinstance(first_date, str):
        try:
            first_date = dt.date.fromisoformat(first_date)
        except ValueError:
            raise ValueError(
                f"field 'holidays': the prices' first date must be an ISO date, got {first_date!r}"
            ) from None
    dates = [first_date + dt.timedelta(days=d) for d in range(num_days)]
    calendar = holidays_lib.country_holidays(
        country, years=range(dates[0].year, dates[-1].year + 1)
    )
    return np.array([d in calendar for d in dates], dtype=bool)
