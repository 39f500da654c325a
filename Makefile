PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: test dist docs examples train train-ppo train-mappo optimal rollout bench bench-peers bench-scaling data data-check clean

# The project is installed by uv (put into the venv by pip), which resolves the same versions
# as pip and downloads and unpacks them in parallel: a fresh clone's set-up takes a fraction of
# pip's time. The bytecode is compiled at install, as pip does, so no test process compiles the
# dependencies' sources on import. `make examples` keeps pip, which reads the machine's pip
# configuration (the torch wheels on disk).
UV := $(PY) -m uv pip install --quiet --python $(PY) --compile-bytecode

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet "uv>=0.13"
	$(UV) -e ".[dev]"
	touch $(STAMP)

venv: $(STAMP)

# The documentation site (mkdocs.yml: docs/ and the API reference from the docstrings), built
# strictly: a broken link, a missing page or a docstring griffe cannot read fails the build,
# and so `make test`. The `docs` extra is installed on top of `dev`.
DOCS_STAMP := $(VENV)/.docs
$(DOCS_STAMP): $(STAMP)
	$(UV) -e ".[dev,docs]"
	touch $(DOCS_STAMP)

# NO_MKDOCS_2_WARNING: mkdocs-material's banner on its own end of life, not about these docs.
docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --site-dir site

# The core and view tests run a second time with JAX_ENABLE_X64=1: the state keeps its dtypes
# whatever the flag.
X64_TESTS := tests/core/test_model.py tests/core/test_bad_input.py

# The distributions as users get them are built and checked in one place, tests/test_wheel.py:
# `python -m build` (the sdist, then the wheel from it), `twine check --strict`, the wheel
# installed into a fresh venv and the README's quick start and a benchmark score run there.
# CHARGAX_DIST makes it leave them in dist/, whose sizes the targets print.
DIST       := dist
DIST_SIZES := $(PY) -c "import pathlib; [print(f'{p}: {p.stat().st_size} bytes ({p.stat().st_size / 1e6:.2f} MB)') for p in sorted(pathlib.Path('$(DIST)').iterdir())]"

# Each pytest run writes its JUnit XML report (every test's seconds) and
# scripts/check_test_budget.py then fails the target, naming them, when a test took longer than
# the per-test budget it sets. `python benchmarks/suite_phases.py` times every phase of this
# target on a fresh clone (docs/performance.md).
JUNIT := .pytest_cache/junit

test: $(STAMP) $(DOCS_STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	rm -rf $(DIST)
	CHARGAX_DIST=$(CURDIR)/$(DIST) $(PY) -m pytest -n 2 -q --durations=20 --junitxml=$(JUNIT).xml
	$(PY) scripts/check_test_budget.py $(JUNIT).xml
	@$(DIST_SIZES)
	JAX_ENABLE_X64=1 $(PY) -m pytest -n 2 -q --junitxml=$(JUNIT)-x64.xml $(X64_TESTS)
	$(PY) scripts/check_test_budget.py $(JUNIT)-x64.xml
	$(MAKE) docs

# The release's sdist and wheel in dist/, built and checked by the wheel test alone.
dist: $(STAMP)
	rm -rf $(DIST)
	CHARGAX_DIST=$(CURDIR)/$(DIST) $(PY) -m pytest -q tests/test_wheel.py
	@$(DIST_SIZES)

# The client examples with heavy dependencies (stable-baselines3, supersuit, tianshou, torch:
# the `clients` extra), each on a tiny budget; not part of `make test`. The dependency-light
# examples (PureJaxRL-style PPO, PettingZoo loop, JaxMARL rollout) and the quick-start notebook
# (examples/quickstart.ipynb, in a Jupyter kernel: tests/test_notebook.py) run inside `make test`.
CLIENTS_STAMP := $(VENV)/.clients
$(CLIENTS_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e ".[dev,clients]"
	touch $(CLIENTS_STAMP)

examples: $(CLIENTS_STAMP)
	CHARGAX_CLIENT_EXAMPLES=1 $(PY) -m pytest -q -s tests/test_clients.py tests/test_readme.py -k "example or readme"

# Each training target names a config of baselines/configs/ (the settings and why, next to
# their values); `python -m baselines.train --config NAME KEY=value ...` runs any other.
# A target rebuilds its run: --overwrite replaces the run its config's OUT holds (the same
# settings, unless the config file changed), so the directory the docs name is always the
# latest; a second target running into the same OUT at the same time is still refused.
# IPPO on the default scenario, 4 seeds, scored on the held-out days (outputs/train_ippo).
train: $(STAMP)
	$(PY) -m baselines.train --config ippo_v3 --overwrite

train-mappo: $(STAMP)
	$(PY) -m baselines.train --config mappo --overwrite

train-ppo: $(STAMP)
	$(PY) -m baselines.train --config ppo --overwrite

# The LP hindsight bound, the MPC and the rule-based policies on the 100 held-out days of the
# default scenario and of three coordination scenarios (grid at 25 % and 10 %, high traffic;
# time-of-use and peak-demand charge), the same in the learned agents' full-power action space
# (num_levels 1: the MPC lines of their learning curves, see `baselines.train --replot`), plus the
# small MILP comparison; writes results/optimal/*.json and *.png and prints the table
# (about 40 min on 2 idle cores).
optimal: $(STAMP)
	$(PY) -m baselines.analysis.references

# One day of the always-max baseline (the former `make train`).
rollout: $(STAMP)
	$(PY) -m chargax_marl.rollout

# Single and multi-agent (dict API and array path) env-steps/s at 1..4096 envs (one host
# device per core), then PPO / IPPO / MAPPO training s per 100k steps at make train's 2 x 64
# networks, then the MPC's time per step and the LP bound's per day, in one run.
bench: $(STAMP)
	$(PY) benchmarks/throughput.py --train --optimal

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
	rm -rf $(VENV) .pytest_cache .hypothesis site $(DIST) build
