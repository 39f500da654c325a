PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: test examples train train-ppo optimal rollout bench bench-peers bench-scaling data data-check clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

venv: $(STAMP)

# The core and view tests run a second time with JAX_ENABLE_X64=1: the state keeps its dtypes
# whatever the flag (2.5 min of CPU; 3 min 14 s wall measured on 2 cores shared with other jobs).
X64_TESTS := tests/test_model.py tests/test_bad_input.py

test: $(STAMP)
	$(PY) -m pytest -n 2 -q
	JAX_ENABLE_X64=1 $(PY) -m pytest -n 2 -q $(X64_TESTS) -k "not under_x64"

# The client examples with heavy dependencies (stable-baselines3, supersuit, tianshou, torch:
# the `clients` extra), each on a tiny budget; not part of `make test`. The dependency-light
# examples (PureJaxRL-style PPO, PettingZoo loop, JaxMARL rollout) run inside `make test`.
CLIENTS_STAMP := $(VENV)/.clients
$(CLIENTS_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e ".[dev,clients]"
	touch $(CLIENTS_STAMP)

examples: $(CLIENTS_STAMP)
	CHARGAX_CLIENT_EXAMPLES=1 $(PY) -m pytest -q -s tests/test_clients.py -k "example or snippet"

# The main job: IPPO on the default shopping scenario (2 seeds) with a progress bar, then
# held-out evaluation against always-max, always-max + battery price rule and price-threshold
# on the same 100 days and cars; writes curve.png, results.json and params.msgpack to
# outputs/train_ippo (about 7.5 min on 2 idle cores).
# No prior: each agent learns from its own share of the station reward (--local-reward-weight 1;
# the evaluation scores the station's profit) with the paper's entropy coefficient 0.01.
SCENARIO_FLAGS := --scenario shopping --traffic medium --seeds 2
train: $(STAMP)
	$(PY) -m baselines.train --algo ippo $(SCENARIO_FLAGS) --ent-coef 0.01 --local-reward-weight 1 --timesteps 1.2e6 --chunks 8 --out outputs/train_ippo

# Single-agent PPO with the always-max prior (a fixed logit offset on each port's full-power action).
train-ppo: $(STAMP)
	$(PY) -m baselines.train --algo ppo $(SCENARIO_FLAGS) --lr 3e-4 --always-max-prior 6 --timesteps 1e6 --chunks 10 --out outputs/train_ppo

# The LP hindsight bound, the MPC and the rule-based policies on the 100 held-out days of the
# default scenario and of a grid-constrained one (grid at 25 %, high traffic); writes
# baselines/results/optimal/*.json and *.png and prints the table (about 25 min on 2 idle cores).
optimal: $(STAMP)
	$(PY) -m baselines.optimal

# One day of the always-max baseline (the former `make train`).
rollout: $(STAMP)
	$(PY) -m chargax_marl.rollout

# Single and multi-agent env-steps/s at 1..4096 envs (one host device per core), then PPO /
# IPPO / MAPPO training s per 100k steps, in one run (~15 min on 2 idle cores).
bench: $(STAMP)
	$(PY) benchmarks/throughput.py --train

# Installs EV2Gym and SustainGym into benchmarks/.peers/ and times them beside chargax_marl.
bench-peers: $(STAMP)
	$(PY) benchmarks/peers.py --ppo

bench-scaling: $(STAMP)
	$(PY) benchmarks/scaling.py

data: $(STAMP)
	$(PY) scripts/build_data.py

data-check: $(STAMP)
	$(PY) scripts/build_data.py --check

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis
