PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: test train bench data data-check clean

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

bench: $(STAMP)
	$(PY) benchmarks/throughput.py

data: $(STAMP)
	$(PY) scripts/build_data.py

data-check: $(STAMP)
	$(PY) scripts/build_data.py --check

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis
