"""The car plan teacher (`chargax_marl.teachers.car_plan`, the trainers' ``PORT_SHAPING="plan"``
through `chargax_marl.teachers.car_plan`): each parked car's remaining demand valued by its best plan
under the day's prices, used as a potential per car."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from baselines.algos import aids, ippo, ppo, ppo_core
from chargax_marl.core import make_params, simulator
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.teachers import car_plan, shaping
from tests.helpers import TINY as HELPER_TINY
from tests.helpers import TINY_ENV

# the paper's sessions: every user of the session model v2 at a DC port leaves when charged,
# and the plan values only the cars that leave at the end of their stay
TINY = {**HELPER_TINY, "ENV_KWARGS": {**TINY_ENV, "num_levels": 1, "session_model": "paper"}}


def test_plan_value_fills_the_cheapest_steps_of_the_stay_first():
    """By hand: buy prices 0.3 0.1 0.5 0.2 0.4 0.6 at steps 0..5, customer price 0.75, path
    efficiency 0.5, 10 kWh per step. A car at step 1 with 3 steps left (steps 1, 2, 3) wanting
    15 kWh takes 10 kWh at step 1 (margin 0.75 - 0.1 / 0.5 = 0.55) and 5 at step 3 (0.75 - 0.4 =
    0.35): 7.25 EUR; step 2 (margin -0.25) is never used. With 2 kWh wanted only step 1:
    1.10. No steps left: 0. A stay past the day's end is cut: from step 4 with 10 steps left
    and efficiency 1, only steps 4 and 5 count (10 kWh at 0.35 and 10 at 0.15)."""
    prices = np.array([0.3, 0.1, 0.5, 0.2, 0.4, 0.6], np.float32)
    order = np.argsort(prices, kind="stable").astype(np.int32)
    got = car_plan.plan_value(
        jnp.asarray(order),
        jnp.asarray(prices[order]),
        1,
        steps_left=[3, 3, 0, 1],
        need_kwh=[15.0, 2.0, 15.0, 15.0],
        step_kwh=[10.0, 10.0, 10.0, 10.0],
        efficiency=[0.5, 0.5, 0.5, 1.0],
        customer_price=0.75,
    )
    # the last car: efficiency 1, one step (step 1): 10 kWh at 0.75 - 0.1
    np.testing.assert_allclose(np.asarray(got), [7.25, 1.10, 0.0, 6.5], rtol=1e-6)
    late = car_plan.plan_value(
        jnp.asarray(order),
        jnp.asarray(prices[order]),
        4,
        steps_left=[10],
        need_kwh=[30.0],
        step_kwh=[10.0],
        efficiency=[1.0],
        customer_price=0.75,
    )
    # steps 4 and 5 only (the day ends): 10 kWh at 0.75 - 0.4 and 10 at 0.75 - 0.6
    np.testing.assert_allclose(np.asarray(late), [3.5 + 1.5], rtol=1e-6)


def _one_car_state(params, minutes_left, need_kwh, charge_sensitive=False):
    """An empty station at step 0 of day 0 with one car on port 0."""
    s = simulator.empty_state(0, params, jax.random.PRNGKey(0))
    port0 = jnp.arange(params.station.num_leaves) == 0
    return s.replace(
        occupied=s.occupied | port0,
        soc=jnp.where(port0, 0.2, s.soc),
        energy_remaining_kwh=jnp.where(port0, need_kwh, s.energy_remaining_kwh),
        time_remaining_min=jnp.where(port0, minutes_left, s.time_remaining_min),
        capacity_kwh=jnp.where(port0, 100.0, s.capacity_kwh),
        max_rate_kw=jnp.where(port0, 1000.0, s.max_rate_kw),
        target_soc=jnp.where(port0, 0.8, s.target_soc),
        tau=jnp.where(port0, 0.8, s.tau),
        charge_sensitive=jnp.where(port0, charge_sensitive, s.charge_sensitive),
    )


def test_shaped_step_scores_the_loss_against_the_plan():
    """A car that needs one step's energy and stays two steps: charging now (dearer than the
    next step) scores ``(margin now - margin next) * q < 0`` after shaping, idling scores 0,
    whichever step is dearer; a charge-sensitive car gets no term."""
    params = make_params(**TINY_ENV, num_levels=1)
    pot = car_plan.car_potential(params)
    prices = car_plan.price_order(params)
    buy = np.empty_like(prices[1][0])
    buy[prices[0][0]] = prices[1][0]  # day 0's buy price of every step
    eff = float(params.station.leaf_path_efficiency[0])
    c = float(params.customer_price_eur_kwh)
    q = (
        car_plan.PLAN_POWER_FRACTION
        * float(params.station.leaf_max_kw[0])
        * float(params.step_hours)
    )
    state = _one_car_state(params, minutes_left=120.0, need_kwh=q)
    shift = pot(state)
    charge = np.zeros(params.station.num_leaves, np.float32)
    charge[0] = q
    m_now, m_next = max(c - buy[0] / eff, 0.0), max(c - buy[1] / eff, 0.0)
    shaped_charge = m_now * q + float(shift(jnp.asarray(charge))[0])
    shaped_idle = float(shift(jnp.zeros_like(jnp.asarray(charge)))[0])
    best_later = max(m_now, m_next) - m_now  # what charging now gives up against the plan
    np.testing.assert_allclose(shaped_charge, -best_later * q, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(
        shaped_idle, -(max(m_now, m_next) - m_next) * q, rtol=1e-5, atol=1e-4
    )
    assert max(shaped_charge, shaped_idle) == pytest.approx(0.0, abs=1e-4)
    sensitive = pot(_one_car_state(params, minutes_left=120.0, need_kwh=q, charge_sensitive=True))
    assert float(jnp.abs(sensitive(jnp.asarray(charge))).max()) == 0.0


@pytest.mark.parametrize("policy", ["always_max", "random_policy"])
def test_car_potential_telescopes_over_a_day(policy):
    """Over a day (5-minute steps, arrivals drawn) the shaping terms add up to minus each
    time-sensitive car's plan value at its first step: the value after a step, computed from
    the state before it, is the value of the env's next state for every car that stays."""
    from chargax_marl import policies

    params = make_params(
        station="single_type",
        station_kwargs={"num_ports": 6, "battery": True},
        num_levels=1,
        session_model="paper",  # time-sensitive users at the DC ports
    )
    pot = car_plan.car_potential(params)
    values = car_plan.car_values(params)
    act = getattr(policies, policy)

    def day(key):
        def body(s, k):
            shift = pot(s)
            s2, info = simulator.step(k, s, act(s, k, params), params)
            v_new = values(s2, s2.timestep, s2.time_remaining_min, s2.energy_remaining_kwh)
            return s2, (
                shift(info.leaf_energy_kwh),
                jnp.where(info.leaf_arrived, v_new, 0.0),
                jnp.sum(info.leaf_arrived),
            )

        s0 = simulator.empty_state(5, params, key)
        _, (terms, entered, arrived) = jax.lax.scan(
            body, s0, jax.random.split(key, int(params.num_steps))
        )
        return terms, entered, arrived

    terms, entered, arrived = jax.jit(day)(jax.random.PRNGKey(2))
    assert float(arrived.sum()) >= 5  # cars came, so the check has something to add up
    assert float(jnp.abs(terms).max()) > 0.01
    np.testing.assert_allclose(float(terms.sum()), -float(entered.sum()), rtol=1e-4, atol=1e-2)


def test_port_shaping_bad_value_is_refused_by_name():
    with pytest.raises(ValueError, match="PORT_SHAPING.*'bogus'"):
        aids.car_potential({"PORT_SHAPING": "bogus"}, make_params(**TINY_ENV))
    assert aids.car_potential({"PORT_SHAPING": "off"}, make_params(**TINY_ENV)) is None


def test_single_env_reports_each_leaf_s_energy():
    """``info["leaf_energy_kwh"]`` is the core's per-leaf energy; the ports' part adds up to the
    step's delivered energy net of discharge."""
    from chargax_marl.single.env import Chargax

    params = make_params(**TINY_ENV)
    env = Chargax(params=params)
    key = jax.random.PRNGKey(4)
    _, state = env.reset(key, params)
    is_port = np.asarray(params.station.leaf_kind) != KIND_BATTERY
    moved = 0.0
    for _ in range(12):
        key, k_a, k_s = jax.random.split(key, 3)
        action = env.action_space(params).sample(k_a)
        _, state, _, _, info = env.step_env(k_s, state, action, params)
        e = np.asarray(info["leaf_energy_kwh"])
        assert e.shape == (params.station.num_leaves,)
        np.testing.assert_allclose(
            e[is_port].sum(),
            float(info["energy_charged_kwh"] - info["energy_discharged_kwh"]),
            rtol=1e-5,
            atol=1e-4,
        )
        moved += np.abs(e).sum()
    assert moved > 0.1


KEYS = jax.random.split(jax.random.PRNGKey(0), 2)


@pytest.fixture(scope="module")
def plan_obs_runs():
    """``run(mod, mode, **hyper)``: two seeds of ``mod``'s tiny trainer with the plan advice
    observed (``PLAN_OBS``) and ``PORT_SHAPING=mode``, trained by one program of its
    hyper-parameter values (so the run with the shaping weighed 0 is the same compiled program
    as the shaped run); each trainer is compiled once and each run trained once for the
    module. Returns ``(train, {"runner_state", "metrics"})``."""
    programs, runs = {}, {}

    def run(mod, mode, **hyper):
        if (mod, mode) not in programs:
            config = {**TINY, "PORT_SHAPING": mode, "PLAN_OBS": True, "SPLIT_CREDIT": mod is ppo}
            if mod is ippo:
                config["LOCAL_REWARD_WEIGHT"] = 1.0
            train = mod.make_train(config)

            @jax.jit
            def seeds(keys, values):
                rs = jax.vmap(train.init, in_axes=(0, None))(keys, values)
                rs, metrics = jax.vmap(lambda r: train.run_updates(r, train.num_updates))(rs)
                return {"runner_state": rs, "metrics": metrics}

            programs[mod, mode] = train, seeds
        train, seeds = programs[mod, mode]
        key = (mod, mode, tuple((k, float(v)) for k, v in sorted(hyper.items())))
        if key not in runs:
            values = {**ppo_core.hyper_values(train.config), **hyper}
            runs[key] = jax.device_get(seeds(KEYS, values))
        return train, runs[key]

    return run


@pytest.mark.parametrize("mod", [ppo, ippo])
def test_port_shaping_trains_and_keeps_the_logged_profit(mod, plan_obs_runs):
    """The trainers run with the port shaping; it changes the learning signal, not the
    profit the env logs (same seeds, same first rollout). ``SHAPING_WEIGHT`` 0, a value of the
    runner state, takes the shaping out again."""
    off = plan_obs_runs(mod, "off")[1]["metrics"]
    plan = plan_obs_runs(mod, "plan")[1]["metrics"]
    unshaped = plan_obs_runs(mod, "plan", SHAPING_WEIGHT=jnp.float32(0.0))[1]["metrics"]
    for m in (off, plan):
        for k in ("actor_loss", "value_loss"):
            assert np.all(np.isfinite(m[k])), (k, m[k])
    np.testing.assert_allclose(
        plan["episode_profit_eur"][:, 0], off["episode_profit_eur"][:, 0], rtol=1e-5
    )
    assert not np.allclose(plan["value_loss"], off["value_loss"], rtol=1e-3)
    np.testing.assert_allclose(unshaped["value_loss"], off["value_loss"], rtol=1e-4)


def test_mix_own_terms_adds_up_like_the_rewards():
    own = jnp.asarray([[1.0, -2.0, 0.5]])
    np.testing.assert_allclose(np.asarray(shaping.mix_own_terms(own, 1.0)), np.asarray(own))
    np.testing.assert_allclose(np.asarray(shaping.mix_own_terms(own, 0.0)), [[-0.5, -0.5, -0.5]])
    mixed = shaping.mix_own_terms(own, 0.3)
    np.testing.assert_allclose(float(mixed.sum()), float(own.sum()) * (0.7 * 3 + 0.3), rtol=1e-6)


def test_plan_rule_charges_in_the_plan_s_step_only():
    """A car that needs one plan step's energy and stays two steps charges now exactly when
    now is no dearer than the next step; a charge-sensitive car always charges; the battery
    idles with ``battery="idle"``."""
    params = make_params(**TINY_ENV, num_levels=1)
    act = car_plan.plan_action(params, battery="idle")
    order, sorted_prices = car_plan.price_order(params)
    buy = np.empty_like(sorted_prices[0])
    buy[order[0]] = sorted_prices[0]
    q = (
        car_plan.PLAN_POWER_FRACTION
        * float(params.station.leaf_max_kw[0])
        * float(params.step_hours)
    )
    is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
    for t in range(6):
        state = _one_car_state(params, minutes_left=120.0, need_kwh=q).replace(
            timestep=jnp.int32(t)
        )
        levels = np.asarray(act(state, None, params))
        assert levels[0] == int(buy[t] <= buy[t + 1]), (t, buy[t], buy[t + 1])
        assert np.all(levels[1:][~is_bat[1:]] == 0) and np.all(levels[is_bat] == 0)
        sensitive = _one_car_state(params, minutes_left=120.0, need_kwh=q, charge_sensitive=True)
        assert np.asarray(act(sensitive.replace(timestep=jnp.int32(t)), None, params))[0] == 1


def test_plan_advice_is_the_rule_s_port_decision():
    """``plan_advice`` is 1 exactly where the plan rule charges a port: never for batteries or
    empty ports, always for a charge-sensitive car."""
    params = make_params(**TINY_ENV, num_levels=1)
    advice = car_plan.plan_advice(params)
    act = car_plan.plan_action(params, battery="idle")
    is_bat = np.asarray(params.station.leaf_kind) == KIND_BATTERY
    q = (
        car_plan.PLAN_POWER_FRACTION
        * float(params.station.leaf_max_kw[0])
        * float(params.step_hours)
    )
    for t in range(6):
        state = _one_car_state(params, minutes_left=120.0, need_kwh=q).replace(
            timestep=jnp.int32(t)
        )
        a = np.asarray(advice(state))
        np.testing.assert_array_equal(
            a, (np.asarray(act(state, None, params)) > 0).astype(np.float32)
        )
        assert np.all(a[1:] == 0)
        sensitive = _one_car_state(params, minutes_left=120.0, need_kwh=q, charge_sensitive=True)
        assert float(advice(sensitive.replace(timestep=jnp.int32(t)))[0]) == 1.0
    assert not is_bat[0] and is_bat.any()


def test_ippo_plan_obs_appends_the_advice_to_every_agent_s_observation(plan_obs_runs):
    """With ``PLAN_OBS`` the actor reads one more column, the plan advice of its leaf, in the
    rollout and in the greedy evaluation act."""
    from chargax_marl.marl.env import ChargaxMARL

    train, out = plan_obs_runs(ippo, "off")
    assert train.config["PLAN_OBS"] and train.config["PORT_SHAPING"] == "off"
    assert np.all(np.isfinite(np.asarray(out["metrics"]["actor_loss"])))
    env = ChargaxMARL(params=train.env_params)
    assert train.policy.obs_dim == env.obs_size + 1
    params = make_params(**TINY_ENV, num_levels=1)
    state = _one_car_state(params, minutes_left=120.0, need_kwh=5.0, charge_sensitive=True)
    rows = train.policy.with_plan(env.get_obs_matrix(state), state)
    np.testing.assert_array_equal(
        np.asarray(rows[:, -1]), np.asarray(car_plan.plan_advice(params)(state))
    )
    assert float(rows[0, -1]) == 1.0
    seed0 = jax.tree.map(lambda x: x[0], out["runner_state"].params)
    levels = train.make_act(params)(seed0)(state, None)
    assert np.asarray(levels).shape == (params.station.num_leaves,)


def test_ppo_plan_obs_appends_every_leaf_s_advice(plan_obs_runs):
    from chargax_marl.core.observation import flat_obs

    train, out = plan_obs_runs(ppo, "plan")
    assert train.config["PLAN_OBS"] and train.config["SPLIT_CREDIT"]
    assert np.all(np.isfinite(np.asarray(out["metrics"]["actor_loss"])))
    params = make_params(**TINY_ENV, num_levels=1)
    state = _one_car_state(params, minutes_left=120.0, need_kwh=5.0, charge_sensitive=True)
    obs = train.policy.with_plan(flat_obs(state, params), state)
    n = params.station.num_leaves
    np.testing.assert_array_equal(
        np.asarray(obs[-n:]), np.asarray(car_plan.plan_advice(params)(state))
    )
    seed0 = jax.tree.map(lambda x: x[0], out["runner_state"].params)
    assert np.asarray(train.make_act(params)(seed0)(state, None)).shape == (n,)


@settings(max_examples=30, deadline=None)
@given(
    width=st.integers(1, 300),
    rows=st.integers(1, 3),
    density=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**31 - 1),
)
def test_prefix_count_is_the_cumulative_sum_exactly(width, rows, density, seed):
    """The plan's rank of a step among its car's stay: the blocked count equals the cumulative
    sum exactly, whatever the width (a multiple of the block or not) and the leading axes."""
    mask = np.random.default_rng(seed).random((rows, 2, width)) < density
    got = np.asarray(jax.jit(car_plan.prefix_count)(jnp.asarray(mask)))  # one compile per shape
    assert got.dtype == np.float32 and got.shape == mask.shape
    np.testing.assert_array_equal(got, np.cumsum(mask, axis=-1))
