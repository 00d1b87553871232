"""Operator logins refused, said so: ``python -m tankctl`` against a real PLC with the test users.

A refused login (wrong password, unknown user, a locked account) is one line ``tankctl: login
as 'NAME' refused: wrong user name or password, or the account is locked (plc at URL)`` with
exit code 2, never "unreachable"; a user name without a password (or a password without a
user name) is one line and exit 2 before anything connects, never a login as the credentials
file's user. The PLC's audit log (its own directory here) is read after each command: a
refused login is recorded as a refused activation with no role, and nothing is ever recorded
in the name of a user who did not log in.

The PLC refuses password checks for a minute past ten failed logins (any names); this module
causes eight, on its own PLC process, so every refusal here is the one under test.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua

from helpers import ROOT, TEST_PASSWORDS, free_base_port, identity, session_home
from tanklab_io.ua_security import ClientIdentity, secure_client
from tanklab_io.users import Credentials
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process

CONFIG = str(ROOT / "configs/three_tank_energies_sim.yaml")
REFUSED = "wrong user name or password, or the account is locked"


@dataclass
class Plc:
    url: str
    audit: Path

    def records(self) -> list[dict[str, Any]]:
        if not self.audit.exists():
            return []
        return [json.loads(line) for line in self.audit.read_text(encoding="utf-8").splitlines() if line]


@pytest.fixture(scope="module")
def plc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plc]:
    audit_dir = tmp_path_factory.mktemp("audit")
    # The PLC alone, from the test-support Stack: its plant URL (the stack's base port) has no
    # plant behind it; logins only.
    stack = Stack(Path(CONFIG), free_base_port(), env=dict(os.environ, TANKLAB_AUDIT_DIR=str(audit_dir)))
    with stack.serving(("plc",)):
        yield Plc(stack.plc_url, audit_dir / "plc.log")


@dataclass
class Ran:
    code: int
    stdout: str
    stderr: str


def tankctl(plc: Plc, *args: str, env: dict[str, str] | None = None) -> Ran:
    """``python -m tankctl ARGS --plc-url URL`` with ``env`` over the test environment (where
    neither TANKLAB_USER nor TANKLAB_PASSWORD is set: the CLI logs in from the credentials file
    as ``engineer``)."""
    full = dict(os.environ, **(env or {}))
    for var in ("TANKLAB_USER", "TANKLAB_PASSWORD"):
        if full.get(var) is None:
            full.pop(var, None)
    done = subprocess.run(
        [sys.executable, "-m", "tankctl", *args, "--config", CONFIG, "--plc-url", plc.url],
        capture_output=True,
        check=False,
        text=True,
        cwd=ROOT,
        env=full,
        timeout=60,
    )
    ran = Ran(done.returncode, done.stdout, done.stderr)
    assert "Traceback" not in ran.stdout + ran.stderr
    return ran


def one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


def read_sp(plc: Plc) -> float:
    async def main() -> float:
        client = Client(plc.url, timeout=4)
        await secure_client(client, identity("engineer"))
        async with client:
            idx = await client.get_namespace_index("urn:tanklab")
            return float(await client.get_node(ua.NodeId("PLC.LIC1.SP", idx)).read_value())

    return asyncio.run(main())


def refused_line(user: str, plc: Plc) -> str:
    return f"tankctl: login as {user!r} refused: {REFUSED} (plc at {plc.url})"


def test_the_credentials_file_user_logs_in_and_is_audited(plc: Plc) -> None:
    before = len(plc.records())
    ran = tankctl(plc, "setpoint", "LIC1", "0.41")
    assert ran.code == 0, ran.stderr
    new = plc.records()[before:]
    assert [(r["action"], r["user"], r["status"]) for r in new if r["action"] == "write"] == [
        ("write", "engineer", "Good")
    ]


def test_a_wrong_password_is_a_refused_login_not_an_unreachable_plc(plc: Plc) -> None:
    sp = read_sp(plc)
    before = len(plc.records())
    env = {"TANKLAB_USER": "operator", "TANKLAB_PASSWORD": "not-the-operator-password"}
    ran = tankctl(plc, "setpoint", "LIC1", "0.43", env=env)
    assert ran.code == 2
    assert one_line(ran.stderr) == refused_line("operator", plc)
    assert "reach" not in ran.stderr.lower()
    assert read_sp(plc) == sp
    new = plc.records()[before:]
    assert [(r["action"], r["user"], r["role"], r["status"]) for r in new] == [
        ("activate", "operator", "none", "BadUserAccessDenied")
    ]


def test_an_unknown_user_is_refused_the_same_way(plc: Plc) -> None:
    before = len(plc.records())
    env = {"TANKLAB_USER": "alice", "TANKLAB_PASSWORD": "alice-has-no-account"}
    ran = tankctl(plc, "setpoint", "LIC1", "0.43", env=env)
    assert ran.code == 2
    assert one_line(ran.stderr) == refused_line("alice", plc)
    new = plc.records()[before:]
    assert [(r["action"], r["user"], r["role"]) for r in new] == [("activate", "alice", "none")]


def test_status_with_a_refused_login_is_one_line_and_shows_nothing_unreachable(plc: Plc) -> None:
    env = {"TANKLAB_USER": "operator", "TANKLAB_PASSWORD": "still-not-the-password"}
    ran = tankctl(plc, "status", env=env)
    assert ran.code == 2
    assert ran.stdout == ""
    line = one_line(ran.stderr)
    assert line.startswith("tankctl: login as 'operator' refused: " + REFUSED)
    assert "UNREACHABLE" not in ran.stdout + ran.stderr


@pytest.mark.parametrize(
    ("env", "line"),
    [
        (
            {"TANKLAB_USER": "alice"},
            "tankctl: TANKLAB_USER is set ('alice') but TANKLAB_PASSWORD is not: set both, or "
            "neither to log in as the user of {cred}",
        ),
        (
            {"TANKLAB_USER": "alice", "TANKLAB_PASSWORD": ""},
            "tankctl: TANKLAB_USER is set ('alice') but TANKLAB_PASSWORD is not: set both, or "
            "neither to log in as the user of {cred}",
        ),
        (
            {"TANKLAB_PASSWORD": "a-password-alone"},
            "tankctl: TANKLAB_PASSWORD is set but TANKLAB_USER is not: set both, or neither to "
            "log in as the user of {cred}",
        ),
    ],
)
def test_half_a_login_in_the_environment_is_an_error_before_connecting(
    plc: Plc, env: dict[str, str], line: str
) -> None:
    sp = read_sp(plc)
    before = len(plc.records())
    ran = tankctl(plc, "setpoint", "LIC1", "0.44", env=env)
    assert ran.code == 2
    assert one_line(ran.stderr) == line.format(cred=session_home().credentials_file)
    # Nothing connected: no session, no record, in particular none as the file's engineer.
    assert plc.records()[before:] == []
    assert read_sp(plc) == sp


async def _failed_login(url: str, user: str, password: str) -> None:
    client = Client(url, timeout=4)
    await secure_client(client, ClientIdentity(session_home(), "cli", Credentials(user, password)))
    with pytest.raises(ua.uaerrors.BadUserAccessDenied):
        await client.connect()


def test_a_locked_account_is_refused_even_with_its_right_password(plc: Plc) -> None:
    async def lock() -> None:
        for k in range(5):  # five failures lock the name for 60 s
            await _failed_login(plc.url, "observer", f"wrong-observer-password-{k}")

    asyncio.run(lock())
    before = len(plc.records())
    env = {"TANKLAB_USER": "observer", "TANKLAB_PASSWORD": TEST_PASSWORDS["observer"]}
    ran = tankctl(plc, "status", env=env)
    assert ran.code == 2
    assert one_line(ran.stderr).startswith(refused_line("observer", plc).removesuffix(f" (plc at {plc.url})"))
    new = plc.records()[before:]
    assert new and all((r["action"], r["user"], r["role"]) == ("activate", "observer", "none") for r in new)
    assert {r["new"] for r in new} == {"locked"}


def test_no_record_names_a_user_who_did_not_log_in(plc: Plc) -> None:
    records = plc.records()
    # Every accepted action is the engineer's (the only successful login of this module); the
    # refused ones name the user who tried, with no role.
    for r in records:
        if r["action"] == "activate":
            assert r["role"] == "none" and r["status"] == "BadUserAccessDenied"
        else:
            assert (r["user"], r["role"]) == ("engineer", "Engineer"), r
    assert not [r for r in records if r["user"] == "engineer" and r["action"] == "activate"]
