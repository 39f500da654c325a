"""The real sessions, the session model's fit, and a small held-out comparison with the
thresholds of ``python -m chargax_marl.validation``."""

import dataclasses

import jax
import numpy as np
import pytest
from scipy.stats import spearmanr

from chargax_marl import policies
from chargax_marl.core import datasets as ds
from chargax_marl.core import make_params
from chargax_marl.core.profiles import load_user_profile, marginal_quantiles
from chargax_marl.evaluation import run_policy_days
from chargax_marl.validation import fit, real, report
from chargax_marl.validation.__main__ import main
from chargax_marl.validation.simulated import simulate_sessions


def test_the_bundled_sessions_are_acn_datas():
    caltech, jpl = real.load_sessions("caltech"), real.load_sessions("jpl")
    assert (len(caltech), len(jpl)) == (9802, 17605)
    assert set(caltech.period) == set(real.PERIODS)
    one = jpl.select(["2019-09-01"])
    assert 0 < len(one) < len(jpl) and set(one.period) == {"2019-09-01"}
    assert one.days().shape == (122,)  # 2019-09-01 .. 2019-12-31
    assert (jpl.delivered_kwh >= 0).all() and (jpl.stay_min > 0).all()
    with pytest.raises(ValueError, match="site: unknown 'ucsd'"):
        real.load_sessions("ucsd")
    with pytest.raises(ValueError, match="periods: unknown"):
        jpl.select(["2018-01-01"])


def test_conditional_tables_mix_back_to_the_pooled_table():
    pooled = np.quantile(np.random.default_rng(0).gamma(2.0, 60.0, 20000), ds.QUANTILE_PROBS)
    scale = np.linspace(0.5, 1.5, 24)
    weights = np.full(24, 1 / 24)
    tables = fit.conditional_tables(pooled, scale, weights)
    assert tables.shape == (24, 101) and (np.diff(tables, axis=1) >= 0).all()
    np.testing.assert_allclose(
        marginal_quantiles(tables, np.ones(24), weights)[5:96], pooled[5:96], rtol=0.02
    )
    # the order of the hours' means is kept
    assert (np.diff(tables[:, 50]) >= 0).all()


def test_hour_windows_hold_the_minimum_of_sessions():
    hours = np.concatenate([np.full(500, 8.5), np.full(20, 20.2)])
    masks = fit.hour_windows(hours, minimum=100)
    assert masks[8].sum() == 500 and masks[20].sum() >= 100
    assert masks[20][:500].any()  # widened to reach the morning sessions


def test_the_fit_reads_weekday_and_weekend_volume():
    jpl = real.load_sessions("jpl")
    volume = fit.volume_fit(jpl)
    assert 0.0 < volume["weekend_volume_factor"] < 0.3  # JPL is quiet at weekends
    assert volume["weekday_volume_factors"][4] < 0.85  # Fridays carry less
    np.testing.assert_allclose(volume["weekday_volume_factors"][:5].mean(), 1.0, rtol=1e-9)
    # the spring of 2020 moves its level: raw it looks far more dispersed than around its level
    assert volume["cv_by_period"]["2020-02-01"] < 0.5


def test_simulated_sessions_close_energy_and_count_every_car():
    """Played with the evaluation's keys, the sessions hold every car that parked and every
    kWh the cars took, day by day, and the counts of cars that asked to park."""
    params = make_params(traffic="high")
    days, key = np.arange(3), jax.random.PRNGKey(0)
    sim = simulate_sessions(params, days, key)
    totals = run_policy_days(policies.always_max, params, days, key)
    per_day = np.bincount(sim.day, minlength=3)
    np.testing.assert_array_equal(per_day, np.asarray(totals.cars_arrived))
    np.testing.assert_array_equal(
        sim.day_requested, np.asarray(totals.cars_arrived + totals.cars_rejected)
    )
    np.testing.assert_array_equal(sim.day_sessions, np.asarray(totals.cars_arrived))
    assert (sim.day_sessions < sim.day_requested).any()  # high traffic turns cars away
    delivered = np.bincount(sim.day, weights=sim.delivered_kwh, minlength=3)
    np.testing.assert_allclose(delivered, np.asarray(totals.energy_charged_kwh), rtol=1e-4)
    assert (sim.stay_min[~sim.cut] >= params.step_minutes).all()  # a car stays a step at least
    assert (sim.delivered_kwh <= sim.requested_kwh + 1e-3).all()


def test_a_held_out_period_passes_the_thresholds():
    """JPL with its autumn 2019 held out, 120 simulated days: realised stays, arrival hours
    and delivered energies within max(threshold, d), the request median within 10 %."""
    row = report.held_out("jpl", "2019-09-01", num_days=120)
    for name in ("stay", "arrival_hour", "delivered"):
        cell = row[name]
        assert cell["ks"] <= max(report.THRESHOLDS[name], cell["d"]), (name, cell)
    assert row["request_median"]["pass"], row["request_median"]
    assert row["cut_share"] < 0.05


def test_the_daily_count_compares_sessions_as_the_real_data_counts_them(monkeypatch):
    """The real periods count sessions; the simulated count is of the cars that parked, not of
    those that asked (a full station turns some away)."""
    seen = {}

    def recorded(*args, **kwargs):
        sim = simulate_sessions(*args, **kwargs)
        # cars turned away on every day: a count of requests would be off by 5 a day
        sim = dataclasses.replace(sim, day_requested=sim.day_sessions + 5.0)
        seen["sim"] = sim
        return sim

    monkeypatch.setattr(report, "simulate_sessions", recorded)
    row = report.held_out("jpl", "2019-09-01", num_days=14)
    sim = seen["sim"]
    workday = sim.day_sessions[sim.day_workday]
    assert row["daily_sd"]["sim_mean"] == pytest.approx(workday.mean())
    assert row["daily_sd"]["sim"] == pytest.approx(workday.std(ddof=1))


def test_the_requests_users_entered_and_the_served_share_are_compared(monkeypatch):
    """The requests are compared by KS with the requests the held-out period's users entered
    (sessions without one left out), and the share of sessions served at least 95 % of their
    request, real against simulated."""
    seen = {}

    def recorded(*args, **kwargs):
        seen["sim"] = simulate_sessions(*args, **kwargs)
        return seen["sim"]

    monkeypatch.setattr(report, "simulate_sessions", recorded)
    row = report.held_out("caltech", "2019-09-01", num_days=14)
    sim, test = seen["sim"], real.load_sessions("caltech").select(["2019-09-01"])
    entered = test.claimed & (test.requested_kwh > 0)
    assert 0 < entered.sum() < len(test)  # some users gave no request
    held = test.requested_kwh[entered]
    assert row["requested"]["ks"] == pytest.approx(report._ks(held, sim.requested_kwh))
    served = row["served"]
    assert served["real"] == pytest.approx(np.mean(test.delivered_kwh[entered] >= 0.95 * held))
    assert served["sim"] == pytest.approx(np.mean(sim.delivered_kwh >= 0.95 * sim.requested_kwh))
    assert served["pass"] == (abs(served["sim"] - served["real"]) <= 0.05)
    text = report.table_markdown([row])
    assert f"{100 * served['real']:.0f} % / {100 * served['sim']:.0f} %" in text


def test_workplace_ac_stays_match_elaad():
    row = report.elaad("workplace", num_days=60)
    assert row["stay_ks_ac"] <= report.ELAAD_THRESHOLD, row


@pytest.mark.parametrize("profile", ["shopping", "workplace"])
def test_v3_ac_ports_hold_the_elaad_stays_with_the_episode_cut_removed(profile):
    """Under the session model v3 each car parks at a port of the kind it wants, so the AC
    ports hold AC sessions with the data's stays; with the episode's cut taken out their
    distance to ElaadNL is within the threshold."""
    row = report.elaad(profile, num_days=60, session_model="v3")
    assert row["stay_ks_ac_censored"] <= report.ELAAD_THRESHOLD, row


def test_the_command_refuses_fewer_than_a_week():
    with pytest.raises(SystemExit):
        main(["--days", "3"])


def test_the_command_refuses_an_unusable_out_before_the_comparison(tmp_path, monkeypatch, capsys):
    """An --out under a file failed only after the whole comparison had run."""

    def compared(*args, **kwargs):
        raise AssertionError("the comparison ran")

    monkeypatch.setattr(report, "run", compared)
    (tmp_path / "a_file").write_text("x")
    for out in (str(tmp_path / "a_file" / "sessions"), "", str(tmp_path) + "/"):
        with pytest.raises(SystemExit):
            main(["--days", "7", "--out", out])
        assert "field '--out' must name a usable output prefix" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--days", "7", "--seed", "-1"])


def test_the_command_keeps_the_prefix_as_typed(tmp_path, monkeypatch):
    """``--out .../sessions.v2`` wrote ``sessions.json``, dropping the prefix's ``.v2``."""
    monkeypatch.setattr(report, "run", lambda days, seed, session_model: {"days": days})
    monkeypatch.setattr(report, "markdown", lambda result: "table\n")
    monkeypatch.setattr(report, "all_pass", lambda result: True)
    assert main(["--days", "7", "--out", str(tmp_path / "sessions.v2")]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sessions.v2.json", "sessions.v2.md"]


def test_rank_corr_is_spearmans_with_ties():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 20, 500).astype(float)  # many ties
    b = a + rng.normal(0, 5, 500)
    assert fit.rank_corr(a, b) == pytest.approx(spearmanr(a, b).statistic, abs=1e-12)
    assert fit.rank_corr(np.ones(5), np.arange(5.0)) == 0.0


def test_the_copula_correlation_is_recovered_from_joined_sessions():
    """Sessions drawn from a Gaussian copula of correlation 0.5 (any marginals, in every
    arrival hour) give back 0.5; independent ones 0."""
    rng = np.random.default_rng(1)
    n = 20_000
    hours = rng.uniform(6, 20, n)
    z = rng.multivariate_normal([0, 0], [[1, 0.5], [0.5, 1]], n)
    stays, energies = np.exp(z[:, 0]) * 100 + hours, np.exp(z[:, 1]) * 5
    windows = fit.hour_windows(hours)
    assert fit.stay_demand_corr(stays, energies, hours, windows) == pytest.approx(0.5, abs=0.03)
    shuffled = rng.permutation(energies)
    assert abs(fit.stay_demand_corr(stays, shuffled, hours, windows)) < 0.03


def test_the_acn_fits_join_longer_stays_to_more_energy():
    for site, name in real.SITES.items():
        assert 0.1 < fit.fit_profile(real.load_sessions(site), name).stay_demand_corr < 0.5
        assert ds.load_user_profile(name).stay_demand_corr > 0.1  # the bundled profile has it


def test_the_cut_share_by_start_hour_by_hand():
    """Every car arrives at 20:00 and stays 6 h: an episode from midnight cuts them all, one
    from noon none, one from 23:00 all (3 h left), on workdays and weekends alike."""
    base = load_user_profile("residential")
    weights = np.zeros_like(np.asarray(base.arrival_weights))
    weights[:, 20 * 12] = 1.0
    stays = np.full_like(np.asarray(base.stay_quantiles_min), 360.0)
    stays += np.linspace(0.0, 1e-3, stays.shape[-1])  # a strictly increasing table
    profile = dataclasses.replace(base, arrival_weights=weights, stay_quantiles_min=stays)
    share = report.cut_share_by_start_hour(profile)
    assert share.shape == (24,)
    assert share[0] == pytest.approx(1.0) and share[23] == pytest.approx(1.0)
    assert share[12] == pytest.approx(0.0) and share[20] == pytest.approx(0.0)


def test_the_simulated_ac_cut_share_is_the_profile_s():
    """Residential users on the session model v2, noon-to-noon episodes: the AC ports' simulated share of sessions
    cut by the episode's end is the one `cut_share_by_start_hour` expects from the profile
    (the all-ports share is far smaller: the DC ports' users leave when charged)."""
    row = report.elaad("residential", num_days=60, session_model="v2", episode_start_hour=12)
    expected = report.cut_share_by_start_hour(load_user_profile("residential"))[12]
    assert row["cut_share_ac"] == pytest.approx(expected, abs=0.05), row
    assert row["cut_share"] < row["cut_share_ac"]
    assert row["least_cut_share"] == pytest.approx(
        report.cut_share_by_start_hour(load_user_profile("residential")).min()
    )
