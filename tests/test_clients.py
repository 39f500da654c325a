"""Third-party clients used unmodified: PettingZoo's render, max-cycles and API tests
on the AEC and parallel envs, masks in observations, the silent import, a forked SuperSuit
worker, and the examples (the PureJaxRL-style PPO always; SuperSuit + SB3 and Tianshou only
under ``make examples``, which installs the ``clients`` extra and sets CHARGAX_CLIENT_EXAMPLES=1)."""

from __future__ import annotations

import os
import runpy
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from pettingzoo.test import api_test, max_cycles_test, parallel_api_test, render_test

from chargax_marl.core import make_params
from chargax_marl.evaluation import run_days
from chargax_marl.marl import ChargaxMARL, aec_env, parallel_env
from chargax_marl.marl import pettingzoo_env as pz_module

ROOT = Path(__file__).resolve().parents[1]
HOURLY = dict(step_minutes=60.0)
CLIENT_EXAMPLES = os.environ.get("CHARGAX_CLIENT_EXAMPLES") == "1"


def example(name: str):
    return runpy.run_path(str(ROOT / "examples" / name), run_name="example")


# ------------------------------------------------------------------ PettingZoo's own tests


def test_pettingzoo_max_cycles_test_on_the_module():
    max_cycles_test(
        pz_module
    )  # calls pz_module.parallel_env(max_cycles=4) and pz_module.env(max_cycles=4)


def test_pettingzoo_render_test_on_the_aec_env(capsys):
    render_test(lambda render_mode=None: aec_env(render_mode=render_mode, **HOURLY))
    assert "port_0" in capsys.readouterr().out  # "human" printed the table


def test_parallel_render_human_prints_and_returns_none(capsys):
    env = parallel_env(render_mode="human", **HOURLY)
    env.reset(seed=0)
    assert env.render() is None
    assert "battery_0" in capsys.readouterr().out


@pytest.mark.parametrize("bad", [0, -3, 2.5, True])
def test_bad_max_cycles_names_the_value(bad):
    with pytest.raises(
        ValueError, match=r"max_cycles must be a positive integer.*" + repr(bad).replace(".", r"\.")
    ):
        parallel_env(max_cycles=bad, **HOURLY)


def test_max_cycles_truncates_every_agent():
    env = parallel_env(max_cycles=3, **HOURLY)
    env.reset(seed=0)
    for _ in range(3):
        _, _, _, trunc, _ = env.step({a: 10 for a in env.agents})
    assert all(trunc.values()) and env.agents == []


# ------------------------------------------------------------------ masks in observations


# PettingZoo's api_test advises Box or Discrete observation spaces holding NumPy arrays; a Dict
# space holding the observation and its action mask is the form PettingZoo's own environments
# use for masks, so these two pieces of advice do not apply.
@pytest.mark.filterwarnings("ignore:Observation space for each agent probably should be")
@pytest.mark.filterwarnings("ignore:Observation is not a NumPy array")
def test_masks_in_observations_pass_the_api_tests():
    par = parallel_env(action_mask_in_obs=True, v2g=False, **HOURLY)
    parallel_api_test(par, num_cycles=30)
    api_test(aec_env(action_mask_in_obs=True, v2g=False, **HOURLY), num_cycles=30)
    obs, infos = par.reset(seed=0)
    space = par.observation_space("port_0")
    assert set(space.spaces) == {"observation", "action_mask"}
    mask = obs["port_0"]["action_mask"]
    assert mask.dtype == np.int8 and space.contains(obs["port_0"])
    assert mask[:10].sum() == 0 and mask[10:].all()  # no V2G: the port cannot discharge
    assert obs["battery_0"]["action_mask"].all()  # the battery can
    mask[:] = 1  # writable, and a copy: the env's own masks are unchanged
    assert infos["port_0"]["action_mask"].flags.writeable
    obs2, _, _, _, infos2 = par.step({a: 10 for a in par.agents})
    assert (
        obs2["port_0"]["action_mask"][:10].sum() == 0
        and infos2["port_0"]["action_mask"][:10].sum() == 0
    )


def test_pettingzoo_seeds_and_day_option_errors():
    env = parallel_env(**HOURLY)
    env.reset(seed=2**64)  # no OverflowError
    with pytest.raises(ValueError, match=r"seed must be a non-negative integer.*-5"):
        env.reset(seed=-5)
    with pytest.raises(ValueError, match=r"options\['day'\] must be an integer in \[0, 364\].*'x'"):
        env.reset(options={"day": "x"})
    with pytest.raises(ValueError, match=r"options\['day'\].*400"):
        env.reset(options={"day": 400})


def test_import_is_silent_and_keeps_the_callers_streams():
    # A module in JaxMARL's import chain resets sys.stdout; the caller's capture (pytest's
    # capsys, a notebook, redirect_stdout) must survive our import of it.
    code = (
        "import io, sys\n"
        "mine_out, mine_err = io.StringIO(), io.StringIO()\n"
        "sys.stdout, sys.stderr = mine_out, mine_err\n"
        "import chargax_marl.marl\n"
        "kept = sys.stdout is mine_out and sys.stderr is mine_err\n"
        "sys.stdout, sys.stderr = sys.__stdout__, sys.__stderr__\n"
        "print(kept, repr(mine_out.getvalue()))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    assert out.stdout.strip() == "True ''"


def test_observation_and_state_spaces_are_finite():
    env = parallel_env(**HOURLY)
    for space in (env.observation_space("port_0"), env.state_space):
        assert np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))
    obs, _ = env.reset(seed=0)
    for _ in range(24):
        assert all(env.observation_space(a).contains(o) for a, o in obs.items())
        assert env.state_space.contains(env.state())
        obs, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})


# ------------------------------------------------------------------ examples


def test_purejaxrl_style_ppo_example_runs():
    out = example("purejaxrl_ppo.py")["main"](
        ["--timesteps", "384", "--num-envs", "4", "--num-steps", "48", "--step-minutes", "60"]
    )
    assert out["episodes"].sum() == 16 and np.isfinite(out["last"])


def test_jaxmarl_style_ippo_example_trains_a_couple_of_updates():
    """``examples/jaxmarl_ippo.py``'s ``make_train`` on a tiny hourly station: two updates of
    two seeds, finite losses, observations grown by the teachers' columns, and a greedy
    policy that plays whole days."""
    ex = example("jaxmarl_ippo.py")
    params = make_params(
        station="single_type",
        station_kwargs={"num_ports": 3, "battery": True},
        num_levels=1,
        **HOURLY,
    )
    train = ex["make_train"](
        {
            "NUM_ENVS": 2,
            "NUM_STEPS": 24,
            "TOTAL_TIMESTEPS": 96,
            "HIDDEN": 8,
            "NUM_MINIBATCHES": 2,
            "UPDATE_EPOCHS": 1,
        },
        params,
    )
    out = jax.jit(jax.vmap(train))(jax.random.split(jax.random.PRNGKey(0), 2))
    assert train.num_updates == 2 and out["metrics"]["total_loss"].shape == (2, 2)
    assert all(
        np.all(np.isfinite(np.asarray(out["metrics"][k])))
        for k in ("total_loss", "critic_loss", "entropy")
    )
    width = 1 + int(params.price_horizon_hours) + 1  # plan advice, relative prices
    assert train.env.observation_space(train.env.agents[0]).shape == (
        ChargaxMARL(params=params).obs_size + width,
    )
    seed0 = jax.tree.map(lambda x: x[0], out["runner_state"][0].params)
    totals = run_days(
        ex["greedy_act"](train.network, seed0, params), params, np.arange(2), jax.random.PRNGKey(0)
    )
    assert np.all(np.isfinite(np.asarray(totals.profit_eur))) and np.asarray(
        totals.profit_eur
    ).shape == (2,)


@pytest.mark.skipif(not CLIENT_EXAMPLES, reason="heavy (torch): run by `make examples`")
def test_supersuit_sb3_multiprocess_example_runs():
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("supersuit")
    out = example("supersuit_sb3.py")["main"](
        ["--timesteps", "2048", "--num-envs", "2", "--num-cpus", "2"]
    )
    assert (
        out["agent_steps"] >= 2048 and out["num_workers"] == 2 and np.isfinite(out["mean_reward"])
    )


@pytest.mark.skipif(not CLIENT_EXAMPLES, reason="heavy (torch): run by `make examples`")
def test_tianshou_masks_example_runs():
    pytest.importorskip("tianshou")
    out = example("tianshou_masks.py")["main"](["--episodes", "2", "--max-cycles", "24"])
    assert out["episodes"] == 2 and out["masked_share"] > 0.3 and out["masked_actions_chosen"] == 0


def test_supersuit_forked_worker_raises_instead_of_hanging():
    ss = pytest.importorskip("supersuit")
    script = (
        "import multiprocessing as mp; mp.set_start_method('fork', force=True)\n"
        "import supersuit as ss\n"
        "from chargax_marl.marl import parallel_env\n"
        "env = parallel_env(step_minutes=60.0); env.reset(seed=0)\n"  # JAX starts in the parent
        "vec = ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(env), 2, num_cpus=2)\n"
        "try:\n"
        "    vec.reset()\n"
        "except Exception as e:\n"
        "    print(type(e).__name__, e)\n"
        "finally:\n"
        "    vec.close()\n"
    )
    del ss
    out = subprocess.run(
        [sys.executable, "-W", "ignore", "-c", script],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )  # the timeout only guards against a hang
    assert "ForkedProcessError" in out.stdout and "spawn" in out.stdout
