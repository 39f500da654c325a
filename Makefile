PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: test examples train train-ppo train-mappo optimal rollout bench bench-peers bench-scaling data data-check clean

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

# The main job: IPPO on the default shopping scenario (4 seeds) with a progress bar, then
# held-out evaluation against always-max, always-max + battery price rule, price-threshold and
# the LP hindsight bound on the same 100 days and cars; writes curve.png, results.json and
# params.msgpack to outputs/train_ippo (see baselines/README.md for the measured wall time).
# No prior. Ports and battery choose among {discharge, idle, charge} at full power (num_levels 1);
# each agent learns from its own share of the station reward (--local-reward-weight 1; the
# evaluation scores the station's profit); the battery's stored energy is valued by the
# battery-only dynamic programme on the day's known prices (--battery-shaping dp, a potential:
# each step shows the battery its loss against that programme's best action); the battery has
# its own actor and critic (--battery-net) and its own entropy bonus (--battery-ent-coef 0.05);
# advantages are normalised per agent; gamma 0.9 (the shaped rewards are nearly immediate); the
# networks also read each observed price's place in the day's range (--relative-prices). Each
# port's parked car is valued by its best plan under the day's prices, a potential as for the
# battery (--port-shaping plan: each step shows the port its loss against that plan), and each
# agent observes its port's plan advice, charge now or wait (--plan-obs on); see
# baselines/car_value.py.
SCENARIO_FLAGS := --scenario shopping --traffic medium
MARL_FLAGS := --ent-coef 0.01 --gamma 0.9 --local-reward-weight 1 --battery-net on --agent-adv-norm on \
	--relative-prices on --env-kwargs '{"num_levels": 1}' --battery-shaping dp --battery-ent-coef 0.05 \
	--port-shaping plan --plan-obs on
train: $(STAMP)
	$(PY) -m baselines.train --algo ippo $(SCENARIO_FLAGS) --seeds 4 $(MARL_FLAGS) --timesteps 6e5 --chunks 4 --out outputs/train_ippo

# MAPPO with the same flags (centralised critic on the world state).
train-mappo: $(STAMP)
	$(PY) -m baselines.train --algo mappo $(SCENARIO_FLAGS) --seeds 4 $(MARL_FLAGS) --timesteps 6e5 --chunks 4 --out outputs/train_mappo

# Single-agent PPO, no prior: full-power actions (num_levels 1), the battery's energy valued by
# the battery-only dynamic programme (--battery-shaping dp), the port heads and the battery heads
# each learning from their own share of the reward (--split-credit), gamma 0.95, relative prices.
train-ppo: $(STAMP)
	$(PY) -m baselines.train --algo ppo $(SCENARIO_FLAGS) --seeds 4 --gamma 0.95 --relative-prices on --env-kwargs '{"num_levels": 1}' --battery-shaping dp --split-credit on --timesteps 5e6 --chunks 10 --out outputs/train_ppo

# The LP hindsight bound, the MPC and the rule-based policies on the 100 held-out days of the
# default scenario and of three coordination scenarios (grid at 25 % and 10 %, high traffic;
# time-of-use and peak-demand charge), the same in the learned agents' full-power action space
# (num_levels 1: the MPC lines of their learning curves, see `baselines.train --replot`), plus the
# small MILP comparison; writes baselines/results/optimal/*.json and *.png and prints the table
# (about 40 min on 2 idle cores).
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
