#!/bin/sh
# Build tanklab's wheel and install it, with its runtime dependencies, into a fresh venv.
#
#   docker/install.sh [SOURCE_DIR] [VENV_DIR] [WHEEL_DIR]     (defaults: . /opt/venv /tmp/wheels)
#
# The one place these install steps live: the Dockerfile's builder stage runs this script, and
# tests/test_docker.py runs it against a temporary venv and starts `tankctl plant` from it, so
# the image's install and start steps are exercised without a Docker engine. $PYTHON picks the
# interpreter that creates the venv (default python3). Every dependency installs from a binary
# wheel (--only-binary), so no compiler is ever needed, in the builder stage or here.
set -eu

src=${1:-.}
venv=${2:-/opt/venv}
wheels=${3:-/tmp/wheels}

"${PYTHON:-python3}" -m venv "$venv"
"$venv/bin/python" -m pip wheel --no-deps --wheel-dir "$wheels" "$src"
"$venv/bin/python" -m pip install --only-binary=:all: "$wheels"/tanklab-*.whl
"$venv/bin/tankctl" --help >/dev/null
