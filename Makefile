# tanklab developer entry points. `make run` and `make test` work on a fresh clone:
# they create .venv and install the project (with its dev extras) on first use.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
CONFIG ?= configs/three_tank_energies_sim.yaml
PYTEST_ARGS ?=

.PHONY: venv tools run test lint typecheck unit bench docs clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

run: venv
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
# those tests skip.
tools:
	@missing=""; \
	command -v docker-compose >/dev/null 2>&1 || missing="$$missing docker-compose"; \
	command -v dockerd >/dev/null 2>&1 || missing="$$missing docker.io"; \
	command -v debootstrap >/dev/null 2>&1 || missing="$$missing debootstrap"; \
	if [ -z "$$missing" ]; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	  echo "make tools: installing$$missing (Debian packages) for tests/test_docker.py and tests/system/test_docker_engine.py"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
	    apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	else \
	  echo "make tools:$$missing missing and cannot be installed (needs root and apt-get);" \
	       "the Docker tests will skip and say why"; \
	fi

test: tools lint typecheck
	$(BIN)/python -m pytest -q $(PYTEST_ARGS)

# Installs the `bench` extra (cvxpy, do-mpc, CasADi) on first use; writes docs/benchmarks.md.
bench: venv
	@$(BIN)/python -c "import cvxpy, casadi, do_mpc" >/dev/null 2>&1 || \
	  $(BIN)/python -m pip install --quiet -e '.[dev,bench]'
	$(BIN)/python -m benchmarks.run

docs: venv
	$(BIN)/tankctl docs address-space > docs/address-space.md
	$(BIN)/tankctl config schema > docs/config-schema.json

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
