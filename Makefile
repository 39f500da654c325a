PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: test train train-ippo bench bench-peers bench-scaling data data-check clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

venv: $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -n 2 -q

train: $(STAMP)
	$(PY) -m chargax_marl.rollout

# IPPO on the default shopping scenario with a progress bar, evaluated against the
# rule-based baselines on 100 held-out days (PNG + JSON + checkpoint in the --out folder).
train-ippo: $(STAMP)
	$(PY) -m baselines.train --algo ippo --scenario shopping --traffic medium --timesteps 5e5 --seeds 2 --lr 3e-3 --chunks 5 --out outputs/train_ippo

bench: $(STAMP)
	$(PY) benchmarks/throughput.py

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
