# tanklab developer entry points. `make run` and `make test` work on a fresh clone: they create
# .venv on first use. `make run` installs the runtime dependencies only (`pip install -e .`);
# `make test`, `make lint`, `make typecheck` and `make venv` add the dev extras (`.[dev]`), and
# `make bench` the bench extras. Each install has its own stamp, so moving from `make run` to
# `make test` on the same .venv installs the dev extras (docs/decisions/0023-lazy-cli-imports.md).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
RUN_STAMP := $(VENV)/.stamp-runtime
DEV_STAMP := $(VENV)/.stamp-dev
CONFIG ?= configs/three_tank_energies_sim.yaml
PYTEST_ARGS ?=
# Test workers (pytest-xdist, one per core; decision 0025). Each test file runs on one worker.
TEST_WORKERS ?= 2

.PHONY: venv runtime tools node-tools run test lint typecheck unit bench docs clean

# The interpreter and an up-to-date pip, shared by both installs.
$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# Runtime dependencies only: what the stack and the operator commands need.
runtime: $(RUN_STAMP)

$(RUN_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $(RUN_STAMP)

# The dev extras (tests, linters, type checker, plots): a superset of the runtime install.
venv: $(DEV_STAMP)

$(DEV_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(RUN_STAMP) $(DEV_STAMP)

run: runtime
	$(BIN)/tankctl up --config $(CONFIG)

lint: venv
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks

typecheck: venv
	$(BIN)/mypy

# Debian's docker-compose (1.29: tests/test_docker.py's `docker-compose config`), docker.io (the
# dockerd that tests/system/test_docker_engine.py starts, on its own socket, and stops) and
# debootstrap (that test's local base image: no registry is needed). Installed when missing and
# running as root with apt-get (no daemon is started by the package here); otherwise say so, and
# those tests skip. postgresql-15: the binaries (initdb, pg_ctl) of the throw-away cluster the
# historian's store tests run on (tanklab_testing.postgres); those tests fail without them, never
# skip, so this target must install them. chromium and chromium-driver: the headless browser
# (/usr/bin/chromium, driven through /usr/bin/chromedriver by Selenium) of the HMI's browser tests,
# tests/hmi/test_browser*.py (no browser download); those tests fail without them, never skip.
PG_BIN := /usr/lib/postgresql/15/bin

tools:
	@missing=""; \
	command -v docker-compose >/dev/null 2>&1 || missing="$$missing docker-compose"; \
	command -v dockerd >/dev/null 2>&1 || missing="$$missing docker.io"; \
	command -v debootstrap >/dev/null 2>&1 || missing="$$missing debootstrap"; \
	[ -x $(PG_BIN)/initdb ] && [ -x $(PG_BIN)/pg_ctl ] || missing="$$missing postgresql-15"; \
	[ -x /usr/bin/chromium ] || missing="$$missing chromium"; \
	[ -x /usr/bin/chromedriver ] || missing="$$missing chromium-driver"; \
	if [ -z "$$missing" ]; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	  echo "make tools: installing$$missing (Debian packages) for the Docker, historian store and HMI browser tests"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
	    apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	else \
	  echo "make tools:$$missing missing and cannot be installed (needs root and apt-get);" \
	       "the Docker tests will skip and say why, the historian store and HMI browser tests will fail"; \
	fi
	@$(MAKE) --no-print-directory node-tools

# tests/integration/test_node_opcua.py runs node-opcua, pinned by tests/node/package-lock.json:
# `npm ci` there when node_modules is missing or older than package.json / package-lock.json.
# Without node the test skips; with node but without node_modules it fails, naming this target.
NODE_DIR   := tests/node
NODE_STAMP := $(NODE_DIR)/node_modules/.package-lock.json

node-tools:
	@if ! command -v npm >/dev/null 2>&1; then \
	  echo "make tools: npm is missing: tests/integration/test_node_opcua.py needs node and npm"; \
	elif [ ! -f $(NODE_STAMP) ] || [ $(NODE_DIR)/package-lock.json -nt $(NODE_STAMP) ] \
	     || [ $(NODE_DIR)/package.json -nt $(NODE_STAMP) ]; then \
	  echo "make tools: npm ci in $(NODE_DIR) (node-opcua for tests/integration/test_node_opcua.py)"; \
	  cd $(NODE_DIR) && npm ci --no-audit --no-fund --loglevel=error; \
	fi

test: tools lint typecheck
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile $(PYTEST_ARGS)

# Installs the `bench` extra (cvxpy, do-mpc, CasADi) on first use; writes docs/benchmarks.md.
bench: venv
	@$(BIN)/python -c "import cvxpy, casadi, do_mpc" >/dev/null 2>&1 || \
	  $(BIN)/python -m pip install --quiet -e '.[dev,bench]'
	$(BIN)/python -m benchmarks.run

docs: runtime
	$(BIN)/tankctl docs address-space > docs/address-space.md
	$(BIN)/tankctl config schema > docs/config-schema.json

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
