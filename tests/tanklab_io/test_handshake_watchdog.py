"""The secure transport's handshake watchdog (``tanklab_io.ua_security._Protocol``) without a server.

A connection without an activated session is closed ``activation_s`` after TCP accept whatever
it did (a hang bound); a silent one (no complete message) already at ``handshake_s``, but only
while more than ``crowd`` connections wait unactivated (parked sockets taking slots). A login
that is merely slow on a loaded machine is not closed at ``handshake_s`` (issue #21). The
bounds are set to 0 here: what is checked is which rule closed the connection, or that none did.
"""

from __future__ import annotations

import logging
from types import SimpleNamespace
from typing import Any

import pytest

from tanklab_io.ua_security import LIMITS, _Protocol


class _Transport:
    def __init__(self) -> None:
        self.closed = 0

    def close(self) -> None:
        self.closed += 1


def _protocol(clients: list[Any], *, activated: bool = False, spoke: bool = False, crowd: int = 2) -> Any:
    p: Any = _Protocol.__new__(_Protocol)
    p.iserver = SimpleNamespace(max_pending_activation_seconds=0.0)
    p.activation_s = 0.0
    p.crowd = crowd
    p.clients = clients
    p.peer_name = ("127.0.0.1", 1)
    p.transport = _Transport()
    p.spoke = spoke
    session = SimpleNamespace(is_activated=lambda: activated)
    p.processor = SimpleNamespace(session=session)
    clients.append(p)
    return p


def _reasons(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage().split(": ", 1)[1] for r in caplog.records if "closing connection" in r.getMessage()
    ]


async def test_a_silent_connection_among_few_waits_for_the_activation_bound(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clients: list[Any] = []
    p = _protocol(clients)
    _protocol(clients)  # two waiting: not more than crowd = 2
    with caplog.at_level(logging.WARNING, "tanklab_io.ua_security"):
        await p._activation_watchdog()
    assert p.transport.closed == 1
    assert _reasons(caplog) == ["no activated session within 0.0 s"]


async def test_silent_connections_in_a_crowd_are_closed_as_parked(caplog: pytest.LogCaptureFixture) -> None:
    clients: list[Any] = []
    p = _protocol(clients)
    for _ in range(2):
        _protocol(clients)  # three waiting: more than crowd = 2
    with caplog.at_level(logging.WARNING, "tanklab_io.ua_security"):
        await p._activation_watchdog()
    assert p.transport.closed == 1
    assert _reasons(caplog) == ["no message within 0.0 s, 2+ connections waiting"]


async def test_a_connection_that_spoke_is_not_parked_even_in_a_crowd(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clients: list[Any] = []
    p = _protocol(clients, spoke=True)
    for _ in range(4):
        _protocol(clients)
    with caplog.at_level(logging.WARNING, "tanklab_io.ua_security"):
        await p._activation_watchdog()
    assert _reasons(caplog) == ["no activated session within 0.0 s"]


async def test_an_activated_session_is_never_closed_and_does_not_count_as_waiting(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clients: list[Any] = []
    p = _protocol(clients, activated=True)
    for _ in range(2):
        _protocol(clients, activated=True)
    silent = _protocol(clients)  # one waiting among three activated: no crowd
    with caplog.at_level(logging.WARNING, "tanklab_io.ua_security"):
        await p._activation_watchdog()
        assert p.transport.closed == 0
        assert silent._unactivated() == 1
        await silent._activation_watchdog()
    assert _reasons(caplog) == ["no activated session within 0.0 s"]


def test_the_bounds() -> None:
    # Parked sockets still go at 2 s when they crowd the server; a login has 30 s however slow
    # the machine (the session timeout's scale: a hang bound, not a speed bound).
    assert LIMITS.handshake_s == 2.0
    assert LIMITS.activation_s == 30.0
    assert 8 < LIMITS.crowd < 200  # a dozen logins at once is no crowd, 200 parked sockets are
