"""The held-out comparison of simulated and real charging sessions.

For each ACN site and each period of 2019-2020, the session model is refitted on the site's
other periods (`fit.fit_profile`), a station built like the site plays the simulated days
with always-max, and the simulated sessions are compared with the held-out period's real
ones by two-sample Kolmogorov-Smirnov distances. Each distance is set against ``d``, the
distance between the held-out period's real sessions and the site's other periods' real
sessions: no model should match a period better than the site's own other periods do.
The day-to-day volume is compared by the standard deviation of the workday session counts
(the simulated sessions are the cars that parked, not those a full station turned away, as
the real data counts them; the simulated station's traffic set to the period's own mean, a
level the user chooses), the requests by their medians.

The NL profiles are compared with the ElaadNL tables they come from: the realised stays at
the AC ports of a station with the profile, against the connection-time distribution.
"""

from __future__ import annotations

import jax
import numpy as np
from scipy.stats import ks_2samp

from chargax_marl.core.data_io import QUANTILE_PROBS
from chargax_marl.core.params import make_params
from chargax_marl.core.profiles import UserProfileData, load_user_profile
from chargax_marl.core.station import single_type
from chargax_marl.validation import fit, real
from chargax_marl.validation.simulated import SimulatedSessions, simulate_sessions

HELD_OUT_PERIODS = ("2019-05-01", "2019-09-01", "2020-02-01")
"""The periods held out in turn (the 2021 period is always a training period)."""
SITE_PORTS = {"caltech": 54, "jpl": 52}
"""AC ports of each ACN site (208 V, 32 A)."""
SITE_PRICES = "NL-2019"
"""The price data of the simulated site (its calendar: weekdays and, with US holidays,
the days the arrivals follow); prices do not enter always-max's sessions."""
THRESHOLDS = {"stay": 0.10, "arrival_hour": 0.11, "delivered": 0.07}
"""A statistic passes when its KS distance is at most max(threshold, d)."""
DAILY_SD_TOLERANCE = 0.25
REQUEST_MEDIAN_TOLERANCE = 0.10
REQUEST_KS_THRESHOLD = 0.10
"""The requests pass when their KS distance is at most max(this, d)."""
SERVED_FRACTION = 0.95
"""A session is served when it received at least this fraction of its request."""
SERVED_SHARE_TOLERANCE = 0.05
"""The share of served sessions passes within this many (absolute) of the real share."""


SESSION_MODEL = "v3"
"""The session model validated by default (`chargax_marl.core.data_io.SESSION_MODELS`)."""


def site_params(
    site: str, profile: UserProfileData, cars_per_workday: float, session_model: str = SESSION_MODEL
):
    """A station like an ACN site (AC ports, 208 V, 32 A, no V2G), US fleet and holidays.

    Args:
        site: ``"caltech"`` or ``"jpl"``.
        profile: the user profile.
        cars_per_workday: mean arrivals per workday.
        session_model: the session model (`make_params`'s ``session_model``).

    Returns:
        The `EnvParams`.
    """
    station = single_type(
        SITE_PORTS[site], kind="AC", voltage_v=208.0, max_current_a=32.0, v2g=False
    )
    return make_params(
        station=station,
        prices=SITE_PRICES,
        user_profile=profile,
        traffic=float(cars_per_workday),
        fleet="US",
        holidays="US",
        num_levels=1,
        session_model=session_model,
    )


def _ks(a: np.ndarray, b: np.ndarray) -> float:
    return float(ks_2samp(a, b).statistic)


def held_out(
    site: str, period: str, num_days: int = 364, seed: int = 0, session_model: str = SESSION_MODEL
) -> dict:
    """One site with one period held out: the model fitted on the other periods against the
    held-out period's real sessions.

    Args:
        site: ``"caltech"`` or ``"jpl"``.
        period: the held-out period (`real.PERIODS`).
        num_days: simulated days (from day 0 of `SITE_PRICES`).
        seed: the evaluation key's seed.
        session_model: the session model (`make_params`'s ``session_model``).

    Returns:
        A row: per statistic the KS distance, ``d`` and whether it passes (``requested``:
        the requests users entered against the model's); the daily-count standard
        deviations; the request medians; ``served``, the share of sessions that received at
        least `SERVED_FRACTION` of their request, real and simulated; the share of cut
        sessions.
    """
    sessions = real.load_sessions(site)
    others = tuple(p for p in real.PERIODS if p != period)
    train, test = sessions.select(others), sessions.select([period])
    profile = fit.fit_profile(train, real.SITES[site])
    _, counts, _, workday, _ = fit.day_types(test)
    params = site_params(site, profile, counts[workday].mean(), session_model)
    sim = simulate_sessions(params, np.arange(num_days), jax.random.PRNGKey(seed))
    real_of = {
        "stay": (test.stay_min, train.stay_min, sim.stay_min),
        "arrival_hour": (test.arrival_hour, train.arrival_hour, sim.arrival_hour),
        "delivered": (test.delivered_kwh, train.delivered_kwh, sim.delivered_kwh),
    }
    row = {"site": site, "held_out": period, "sessions": len(test), "simulated": len(sim.stay_min)}
    for name, (held, rest, simulated) in real_of.items():
        ks, d = _ks(held, simulated), _ks(held, rest)
        row[name] = {
            "ks": ks,
            "d": d,
            "real_median": float(np.median(held)),
            "sim_median": float(np.median(simulated)),
            "pass": ks <= max(THRESHOLDS[name], d),
        }
    real_sd = float(counts[workday].std(ddof=1))
    # sessions a day, as the real data counts them (not the cars a full station turned away)
    sim_sd = float(sim.day_sessions[sim.day_workday].std(ddof=1))
    row["daily_sd"] = {
        "real": real_sd,
        "sim": sim_sd,
        "real_mean": float(counts[workday].mean()),
        "sim_mean": float(sim.day_sessions[sim.day_workday].mean()),
        "pass": abs(sim_sd / real_sd - 1.0) <= DAILY_SD_TOLERANCE,
    }
    # the requests users entered (sessions without one left out) against the model's requests
    entered = test.entered_request
    held_req = test.requested_kwh[entered]
    rest_req = train.requested_kwh[train.entered_request]
    ks, d = _ks(held_req, sim.requested_kwh), _ks(held_req, rest_req)
    row["requested"] = {"ks": ks, "d": d, "pass": ks <= max(REQUEST_KS_THRESHOLD, d)}
    served_real = float(np.mean(test.delivered_kwh[entered] >= SERVED_FRACTION * held_req))
    served_sim = float(np.mean(sim.delivered_kwh >= SERVED_FRACTION * sim.requested_kwh))
    row["served"] = {
        "real": served_real,
        "sim": served_sim,
        "pass": abs(served_sim - served_real) <= SERVED_SHARE_TOLERANCE,
    }
    req_real, req_sim = float(np.median(test.requested_kwh)), float(np.median(sim.requested_kwh))
    row["request_median"] = {
        "real": req_real,
        "sim": req_sim,
        "pass": abs(req_sim / req_real - 1.0) <= REQUEST_MEDIAN_TOLERANCE,
    }
    row["cut_share"] = float(sim.cut.mean())
    return row


def elaad_stay_ks(sim: SimulatedSessions, stay_quantiles_min: np.ndarray) -> float:
    """One-sample KS distance between the realised AC stays and a quantile table.

    Args:
        sim: simulated sessions.
        stay_quantiles_min: ``(Q,)`` the reference stay quantiles (minutes).

    Returns:
        ``sup |F_sim - F_ref|`` over the simulated stays.
    """
    x = np.sort(sim.stay_min[sim.ac])
    return _sup_distance(x, np.interp(x, stay_quantiles_min, QUANTILE_PROBS, left=0.0, right=1.0))


def _sup_distance(x_sorted: np.ndarray, ref: np.ndarray) -> float:
    """One-sample KS distance of sorted values to a reference CDF evaluated at them."""
    n = x_sorted.size
    upper = np.arange(1, n + 1) / n - ref
    lower = ref - np.arange(0, n) / n
    return float(max(upper.max(), lower.max()))


def elaad_stay_ks_censored(sim: SimulatedSessions, stay_quantiles_min: np.ndarray) -> float:
    """`elaad_stay_ks` against the reference cut where each session's episode ends: the
    reference CDF at ``x`` is the mean over the AC sessions of the table's CDF at ``x``, or 1
    where ``x`` reaches the session's ``time_left_min``. It measures the sessions against the
    data with the episode's horizon taken out; the share of stays the horizon cuts is
    reported apart.

    Args:
        sim: simulated sessions.
        stay_quantiles_min: ``(Q,)`` the reference stay quantiles (minutes).

    Returns:
        ``sup |F_sim - F_ref|`` over the simulated stays.
    """
    x = np.sort(sim.stay_min[sim.ac])
    left = sim.time_left_min[sim.ac]
    base = np.interp(x, stay_quantiles_min, QUANTILE_PROBS, left=0.0, right=1.0)
    cut = np.searchsorted(np.sort(left), x + 1e-9, side="right") / left.size  # caps <= x
    return _sup_distance(x, base * (1.0 - cut) + cut)


def cut_share_by_start_hour(profile: UserProfileData, step_minutes: float = 5.0) -> np.ndarray:
    """Per episode start hour, the expected share of a profile's sessions whose drawn stay
    outlasts the one-day episode they arrive in (at a station where every car finds a port):
    each arrival step weighted by the profile's arrival shape, five workdays and two weekend
    days a week (the weekend's weighted by ``weekend_volume_factor``), each stay drawn from
    its arrival hour's table. It is a property of the profile, not of a policy or a station.

    Args:
        profile: a `UserProfileData` (stay tables per arrival hour, ``(24, Q)``, or pooled).
        step_minutes: the arrival steps' length (minutes).

    Returns:
        ``(24,)`` shares in [0, 1], indexed by the episode's start hour.
    """
    weights = np.asarray(profile.arrival_weights, np.float64)
    stays = np.asarray(profile.stay_quantiles_min, np.float64)
    scale = np.asarray(profile.stay_scale_by_hour, np.float64)
    slots = weights.shape[-1]
    hour = np.arange(slots) * step_minutes / 60.0
    table = np.broadcast_to(stays, (24, stays.shape[-1])) if stays.ndim == 1 else stays
    week = np.array([5.0, 2.0 * float(profile.weekend_volume_factor)])
    out = np.zeros(24)
    for start in range(24):
        left_min = (np.mod(start - hour - 1e-9, 24.0) + 1e-9) * 60.0  # (0, 1440]
        h = np.floor(hour).astype(int)
        outlast = np.array(
            [
                1.0 - np.interp(left_min[i] / scale[h[i]], table[h[i]], QUANTILE_PROBS)
                for i in range(slots)
            ]
        )
        per_type = (weights * outlast).sum(axis=-1) / weights.sum(axis=-1)
        out[start] = float((week * per_type).sum() / week.sum())
    return out


def elaad(
    profile: str = "shopping",
    num_days: int = 364,
    seed: int = 0,
    session_model: str = SESSION_MODEL,
    **env,
) -> dict:
    """A bundled NL profile against the ElaadNL connection times it comes from.

    Args:
        profile: a bundled NL profile (``shopping``, ``workplace``, ``residential``).
        num_days: simulated days (from day 0 of the env's prices).
        seed: the evaluation key's seed.
        session_model: the session model (`make_params`'s ``session_model``).
        **env: further `make_params` keywords (e.g. ``episode_start_hour``).

    Returns:
        The AC stays' KS distance to the paper profile's pooled table (the ElaadNL
        connection times), as they are and with the episode's horizon taken out
        (`elaad_stay_ks_censored`), the realised median stays, the share of sessions
        cut by the episode's end (all of them, and those of the AC ports), and the least
        share of the profile's sessions a one-day episode cuts over every start hour
        (`cut_share_by_start_hour`), with that hour.
    """
    params = make_params(user_profile=profile, session_model=session_model, **env)
    sim = simulate_sessions(params, np.arange(num_days), jax.random.PRNGKey(seed))
    table = load_user_profile(profile, session_model="paper").stay_quantiles_min
    by_hour = cut_share_by_start_hour(load_user_profile(profile), params.step_minutes)
    return {
        "profile": profile,
        "env": {k: repr(v) for k, v in env.items()},
        "stay_ks_ac": elaad_stay_ks(sim, np.asarray(table)),
        "stay_ks_ac_censored": elaad_stay_ks_censored(sim, np.asarray(table)),
        "elaad_median_min": float(np.interp(0.5, QUANTILE_PROBS, table)),
        "sim_median_ac_min": float(np.median(sim.stay_min[sim.ac])),
        "sim_median_min": float(np.median(sim.stay_min)),
        "cut_share": float(sim.cut.mean()),
        "cut_share_ac": float(sim.cut[sim.ac].mean()),
        "least_cut_share": float(by_hour.min()),
        "least_cut_start_hour": int(by_hour.argmin()),
        "sessions": int(sim.stay_min.size),
        "sessions_ac": int(sim.ac.sum()),
    }


def table_markdown(rows: list[dict]) -> str:
    """The held-out rows as a Markdown table.

    Args:
        rows: `held_out` rows.

    Returns:
        The table's text.
    """
    head = (
        "| site | held out | stay KS (d) | arrival hour KS (d) | delivered KS (d) "
        "| workday count sd, real / sim | request median kWh, real / sim | requested KS (d) "
        "| served, real / sim |\n"
        "|---|---|---|---|---|---|---|---|---|\n"
    )

    def ks(cell):
        mark = "" if cell["pass"] else " ✗"
        return f"{cell['ks']:.3f} ({cell['d']:.3f}){mark}"

    lines = []
    for r in rows:
        sd, rq, sv = r["daily_sd"], r["request_median"], r["served"]
        lines.append(
            f"| {r['site']} | {r['held_out']} | {ks(r['stay'])} | {ks(r['arrival_hour'])} "
            f"| {ks(r['delivered'])} | {sd['real']:.1f} / {sd['sim']:.1f}"
            f"{'' if sd['pass'] else ' ✗'} | {rq['real']:.1f} / {rq['sim']:.1f}"
            f"{'' if rq['pass'] else ' ✗'} | {ks(r['requested'])} "
            f"| {100 * sv['real']:.0f} % / {100 * sv['sim']:.0f} %{'' if sv['pass'] else ' ✗'} |"
        )
    return head + "\n".join(lines) + "\n"


ELAAD_THRESHOLD = 0.10
"""The AC stays of an NL profile pass when their KS distance to ElaadNL is at most this."""
CUT_SHARE_THRESHOLD = 0.02
"""An overnight profile passes when at most this share of its sessions is cut by the
episode's end."""
ELAAD_RUNS = {
    "shopping": {},
    "workplace": {},
    "residential": {"episode_start_hour": 12},
}
"""The NL profiles compared with ElaadNL, and their `make_params` keywords (residential:
noon-to-noon episodes, the overnight home charging)."""


def elaad_markdown(rows: list[dict]) -> str:
    """The ElaadNL rows as a Markdown table.

    Args:
        rows: `elaad` rows.

    Returns:
        The table's text.
    """
    head = (
        "| profile | settings | AC stay KS to ElaadNL | the same, cut at the episode's end "
        "| median stay min, ElaadNL / AC ports | sessions cut by the episode's end, AC ports "
        "/ all | the profile's sessions a one-day episode cuts, least over start hours |\n"
        "|---|---|---|---|---|---|---|\n"
    )
    lines = [
        f"| {r['profile']} | {', '.join(f'{k}={v}' for k, v in r['env'].items()) or 'defaults'} "
        f"| {r['stay_ks_ac']:.3f}{'' if r['stay_ks_ac'] <= ELAAD_THRESHOLD else ' ✗'} "
        f"| {r['stay_ks_ac_censored']:.3f} "
        f"| {r['elaad_median_min']:.0f} / {r['sim_median_ac_min']:.0f} "
        f"| {100 * r['cut_share_ac']:.1f} % / {100 * r['cut_share']:.1f} % "
        f"| {100 * r['least_cut_share']:.1f} % (from {r['least_cut_start_hour']}:00) |"
        for r in rows
    ]
    return head + "\n".join(lines) + "\n"


def markdown(result: dict) -> str:
    """Both tables of a `run` result, with the settings they were made with.

    Args:
        result: a `run` result.

    Returns:
        Markdown text.
    """
    st = result["settings"]
    return (
        f"Session model {st.get('session_model', 'v2')}. Held out, each ACN site and period "
        f"({st['num_days']} simulated days each, seed {st['seed']}; KS distance, in brackets d, the distance between the period's real "
        "sessions and the site's other periods'; ✗: above max(threshold, d), or a standard "
        f"deviation off by more than {100 * st['daily_sd_tolerance']:.0f} %, or a request median "
        f"off by more than {100 * st['request_median_tolerance']:.0f} %; the requests users "
        "entered, sessions without one left out; served: the share of sessions that received "
        f"at least {100 * SERVED_FRACTION:.0f} % of their request, ✗ when off by more than "
        f"{100 * SERVED_SHARE_TOLERANCE:.0f} points):\n\n"
        + table_markdown(result["held_out"])
        + "\nThe NL profiles against the ElaadNL connection times (✗: KS above "
        f"{ELAAD_THRESHOLD}):\n\n" + elaad_markdown(result["elaad"])
    )


def all_pass(result: dict) -> bool:
    """Whether every held-out statistic and every ElaadNL stay passes its threshold.

    Args:
        result: a `run` result.

    Returns:
        True when all pass.
    """
    keys = (
        "stay",
        "arrival_hour",
        "delivered",
        "daily_sd",
        "request_median",
        "requested",
        "served",
    )
    held = all(row[k]["pass"] for row in result["held_out"] for k in keys)
    nl = all(r["stay_ks_ac"] <= ELAAD_THRESHOLD for r in result["elaad"])
    return held and nl


def run(
    num_days: int = 364,
    seed: int = 0,
    elaad_env: dict | None = None,
    session_model: str = SESSION_MODEL,
) -> dict:
    """Every held-out row and the ElaadNL comparisons.

    Args:
        num_days: simulated days per row.
        seed: the evaluation key's seed.
        elaad_env: per NL profile, further `make_params` keywords of its ElaadNL comparison.
        session_model: the session model validated.

    Returns:
        ``{"held_out": [...], "elaad": [...], "settings": {...}}``.
    """
    rows = [
        held_out(s, p, num_days, seed, session_model) for s in real.SITES for p in HELD_OUT_PERIODS
    ]
    envs = ELAAD_RUNS if elaad_env is None else elaad_env
    nl = [elaad(name, num_days, seed, session_model, **env) for name, env in envs.items()]
    return {
        "held_out": rows,
        "elaad": nl,
        "settings": {
            "num_days": num_days,
            "seed": seed,
            "session_model": session_model,
            "thresholds": THRESHOLDS,
            "daily_sd_tolerance": DAILY_SD_TOLERANCE,
            "request_median_tolerance": REQUEST_MEDIAN_TOLERANCE,
            "site_prices": SITE_PRICES,
            "elaad_threshold": ELAAD_THRESHOLD,
            "min_sessions_per_hour": fit.MIN_SESSIONS_PER_HOUR,
        },
    }
