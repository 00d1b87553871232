"""Test configuration: the repository root, the test security home, the order of the long files.

There is no unauthenticated test path: the session-wide, autouse :func:`security_home`
provisions a PKI and one user per login role before any test runs and points
``TANKLAB_HOME`` at it, so every tier process, every ``tankctl`` command and every client of
:func:`helpers.secure` connects encrypted and authenticated like a real deployment (the CLI as
``engineer`` through the home's 0600 credentials file).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from helpers import (  # tests/ is on pytest's pythonpath (pyproject)
    ROOT,
    TEST_EXTERNAL,
    TEST_PASSWORDS,
    TEST_ROLES,
)
from tanklab_io.external import add_external
from tanklab_io.home import SecurityHome
from tanklab_io.pki import init_pki
from tanklab_io.users import Credentials, UsersFile, write_credentials


@pytest.fixture
def root() -> Path:
    """The repository root (configs/, docs/ live there)."""
    return ROOT


@pytest.fixture(scope="session", autouse=True)
def security_home(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SecurityHome]:
    """The session's security home: PKI, one user per login role, the CLI's credentials."""
    home = SecurityHome(tmp_path_factory.mktemp("tanklab-home"))
    init_pki(home.pki.root)
    users = UsersFile.load(home.users_file)
    for name, role in TEST_ROLES.items():
        users.add(name, role, TEST_PASSWORDS[name])
    users.save()
    write_credentials(home.credentials_file, Credentials("engineer", TEST_PASSWORDS["engineer"]))
    add_external(home, TEST_EXTERNAL)  # the External identity (decision 0055)
    saved = {k: os.environ.get(k) for k in ("TANKLAB_HOME", "TANKLAB_USER", "TANKLAB_PASSWORD")}
    os.environ["TANKLAB_HOME"] = str(home.root)
    os.environ.pop("TANKLAB_USER", None)
    os.environ.pop("TANKLAB_PASSWORD", None)
    yield home
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


# The longest test files, first: under `make test`'s `-n 2 --dist loadfile` (decision 0025) a
# file runs on one worker, in collection order, so the Docker engine's system test (minutes of
# image builds, mostly waiting on the network and the disk) and the longest process files start
# at once and overlap the short ones instead of running last on one worker while the other idles.
LONGEST_FIRST = (
    "tests/system/",
    "tests/integration/test_stack_e2e.py",
    "tests/integration/test_up_lifecycle.py",
    "tests/integration/test_restarts.py",
    "tests/robustness/test_failures.py",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    def rank(item: pytest.Item) -> int:
        return next((k for k, p in enumerate(LONGEST_FIRST) if item.nodeid.startswith(p)), len(LONGEST_FIRST))

    items.sort(key=rank)  # stable: the order within a file and among the rest is unchanged
