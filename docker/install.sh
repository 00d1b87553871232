#!/bin/sh
# Build tanklab's wheel and install it, with its runtime dependencies, into a fresh venv.
#
#   docker/install.sh [SOURCE_DIR] [VENV_DIR] [WHEEL_DIR]     (defaults: . /opt/venv /tmp/wheels)
#   docker/install.sh --deps-only [SOURCE_DIR] [VENV_DIR]     only [project].dependencies of
#                                                             SOURCE_DIR/pyproject.toml
#
# The Dockerfile runs --deps-only first, in a layer of its own that only pyproject.toml feeds,
# so that a change to src/ does not download and install the dependencies again.
# The one place these install steps live: the Dockerfile's builder stage runs this script, and
# tests/test_docker.py runs it against a temporary venv and starts `tankctl plant` from it, so
# the image's install and start steps are exercised without a Docker engine. $PYTHON picks the
# interpreter that creates the venv (default python3). Every dependency installs from a binary
# wheel (--only-binary), so no compiler is ever needed, in the builder stage or here.
# A pip-ca.crt next to this script (the Dockerfile copies docker/ with it; docs/docker.md) is
# the CA bundle pip trusts, unless PIP_CERT is set already.
set -eu

here=$(dirname "$0")
if [ -z "${PIP_CERT:-}" ] && [ -s "$here/pip-ca.crt" ]; then
    PIP_CERT="$here/pip-ca.crt"
    export PIP_CERT
fi

deps_only=
if [ "${1:-}" = --deps-only ]; then
    deps_only=1
    shift
fi
src=${1:-.}
venv=${2:-/opt/venv}
wheels=${3:-/tmp/wheels}

"${PYTHON:-python3}" -m venv "$venv"
if [ -n "$deps_only" ]; then
    "$venv/bin/python" -c 'import sys, tomllib
print("\n".join(tomllib.load(open(sys.argv[1], "rb"))["project"]["dependencies"]))' \
        "$src/pyproject.toml" > "$venv/tanklab-requirements.txt"
    "$venv/bin/python" -m pip install --only-binary=:all: -r "$venv/tanklab-requirements.txt"
    exit 0
fi
"$venv/bin/python" -m pip wheel --no-deps --wheel-dir "$wheels" "$src"
"$venv/bin/python" -m pip install --only-binary=:all: "$wheels"/tanklab-*.whl
"$venv/bin/tankctl" --help >/dev/null
