"""Shared test helpers: the test security home's logins and secured clients, and the test-support
package's processes, ports and bounded waits under the names the tests use.

The processes, ports and waits are :mod:`tanklab_testing`'s (decision 0032), shared with the
benchmarks; what is here is only what belongs to the tests: the users of the session's security
home (``conftest.security_home``) and clients secured as them.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
from pathlib import Path

from asyncua import Client

from tanklab.tags import Role
from tanklab_io.home import SecurityHome
from tanklab_io.ua_client import new_client
from tanklab_io.ua_security import ClientIdentity, ServerSecurity, secure_client
from tanklab_io.users import Credentials
from tanklab_testing.logins import Logins
from tanklab_testing.procs import ROOT, TankctlProcess, UpProcess, free_base_port, free_port, tankctl_pids_on
from tanklab_testing.waits import hang_bound, wait_until, wait_until_sync

__all__ = [
    "ROOT",
    "TEST_EXTERNAL",
    "TEST_PASSWORDS",
    "TEST_ROLES",
    "TierProcess",
    "UpProcess",
    "engineer_logins",
    "free_base_port",
    "free_port",
    "hang_bound",
    "identity",
    "secure",
    "server_security",
    "session_home",
    "stop_process",
    "tanklab_pids",
    "wait_until",
    "wait_until_sync",
]

TEST_EXTERNAL = "testctl"
"""The session home's external controller (``tankctl user add-external``; certificate
``external-testctl``, role External on the PLC)."""

TEST_ROLES = {"observer": Role.OBSERVER, "operator": Role.OPERATOR, "engineer": Role.ENGINEER}
"""The login users of the test security home (see conftest.security_home)."""
TEST_PASSWORDS = {name: f"{name}-test-password" for name in TEST_ROLES}

TierProcess = TankctlProcess
"""A tier started as ``python -m tankctl ...``: the test-support wrapper with its defaults (wait
for the banner, stderr dropped, this process's environment)."""


def tanklab_pids(base: int) -> list[int]:
    """Live tankctl processes bound (by their arguments) to the ports base..base+3, the
    historian's included (``tanklab_testing.procs.tankctl_pids``, which the restart benchmark
    counts with too)."""
    return tankctl_pids_on(base, 4)


def stop_process(proc: subprocess.Popen[str], deadline_s: float = 20.0) -> None:
    """SIGTERM a plain subprocess this test started, SIGKILL after ``deadline_s`` (bounded), and
    reap it."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=deadline_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def session_home() -> SecurityHome:
    """The session's security home (``TANKLAB_HOME``, set by conftest.security_home)."""
    return SecurityHome(Path(os.environ["TANKLAB_HOME"]))


def engineer_logins() -> Logins:
    """The session's security home with the test engineer's login (for probes and fuzz sessions)."""
    return Logins(session_home(), {"engineer": Credentials("engineer", TEST_PASSWORDS["engineer"])})


def server_security(audit_dir: Path | None = None) -> ServerSecurity:
    """What an in-process tier server of a test is secured with; ``audit_dir`` gives it an audit
    log of its own (None: the session home's, which every test of the session writes to)."""
    return ServerSecurity(session_home(), audit_dir)


def identity(
    user: str = "engineer", *, tier: str | None = None, policy: str = "Basic256Sha256"
) -> ClientIdentity:
    """A test user's login (``user``), or a tier's certificate identity (``tier``; ``external``
    for the session's External identity)."""
    if tier == "external":
        return ClientIdentity(session_home(), f"external-{TEST_EXTERNAL}", policy=policy)
    if tier is not None:
        return ClientIdentity(session_home(), tier, policy=policy)
    return ClientIdentity(session_home(), "cli", Credentials(user, TEST_PASSWORDS[user]), policy=policy)


async def secure(
    url: str, user: str = "engineer", *, tier: str | None = None, timeout_s: float = 4.0
) -> Client:
    """A client of ``url`` set up (not connected) to connect as a test user or a tier:
    ``async with await secure(url, "operator") as client: ...``."""
    client = new_client(url, timeout_s)
    await secure_client(client, identity(user, tier=tier))
    return client


async def tankctl_at(
    base: int, *args: str, env: dict[str, str] | None = None, bound_s: float = 120.0
) -> subprocess.CompletedProcess[str]:
    """Run an operator command (``python -m tankctl ARGS --base-port BASE``) against the stack
    at ``base``, in a thread: the test's event loop (and the OPC UA clients it holds) keeps
    running while the command does. ``bound_s`` bounds a hang (not a speed check)."""
    return await asyncio.to_thread(
        subprocess.run,
        [sys.executable, "-m", "tankctl", *args, "--base-port", str(base)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=bound_s,
        check=False,
        env=env,
    )
