"""The HMI's login sessions: opaque ids, CSRF tokens and the idle timeout (pure, no clock).

A browser that logged in holds a cookie with the session's id (an opaque random token of
:data:`TOKEN_BYTES` bytes from :mod:`secrets`, never derived from the user); every state-changing
request carries the session's CSRF token in a header (synchroniser token: the token is only ever
given to the page by ``GET /api/session`` or the login's answer, which a cross-site page cannot
read). A session is idle from its last request; after ``idle_timeout_s`` without a request and
without an open WebSocket it is closed::

    expired(s, now) = s.sockets == 0 and now - s.last_seen_s >= idle_timeout_s

Time is an argument (``now`` [s], any monotonic origin): the app passes its clock, the tests a
number. The token source is injected too, so a test can name the ids it expects.
"""

from __future__ import annotations

import hmac
import secrets
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["TOKEN_BYTES", "Session", "SessionTable", "new_token"]

TOKEN_BYTES = 32
"""Random bytes in a session id and in a CSRF token (256 bits)."""


def new_token() -> str:
    """A fresh opaque token (URL-safe base64 of :data:`TOKEN_BYTES` random bytes)."""
    return secrets.token_urlsafe(TOKEN_BYTES)


@dataclass
class Session:
    """One logged-in browser session."""

    id: str
    user: str
    role: str
    """The user's login role as the HMI shows it (the tiers enforce their own)."""
    csrf: str
    created_s: float
    last_seen_s: float
    sockets: int = 0
    """Open WebSockets of this session: a session with one is never idle."""


class SessionTable:
    """The sessions of one HMI server, by id.

    Parameters
    ----------
    idle_timeout_s : seconds without a request (and with no open WebSocket) after which a
        session is closed; > 0.
    token : the source of session ids and CSRF tokens (default :func:`new_token`).
    """

    def __init__(self, idle_timeout_s: float = 900.0, token: Callable[[], str] = new_token) -> None:
        if not idle_timeout_s > 0:
            raise ValueError(f"idle_timeout_s must be > 0, got {idle_timeout_s}")
        self.idle_timeout_s = idle_timeout_s
        self._token = token
        self._sessions: dict[str, Session] = {}

    def __len__(self) -> int:
        return len(self._sessions)

    def open(self, user: str, role: str, now: float) -> Session:
        """A new session of ``user`` (a new id and CSRF token), seen at ``now``."""
        sid = self._token()
        if sid in self._sessions:  # only a broken token source repeats itself
            raise ValueError("the token source repeated a session id")
        s = Session(sid, user, role, self._token(), now, now)
        self._sessions[sid] = s
        return s

    def expired(self, s: Session, now: float) -> bool:
        """Whether ``s`` has been idle for the timeout (module docstring)."""
        return s.sockets == 0 and now - s.last_seen_s >= self.idle_timeout_s

    def get(self, sid: str | None, now: float) -> Session | None:
        """The live session of id ``sid``, marked seen at ``now``; None when there is none or it
        has expired (an expired one stays in the table for :meth:`expire` to hand back)."""
        s = self._sessions.get(sid) if sid else None
        if s is None or self.expired(s, now):
            return None
        s.last_seen_s = max(s.last_seen_s, now)
        return s

    def expire(self, now: float) -> list[Session]:
        """Remove and return every session expired at ``now`` (their owner closes what they hold)."""
        gone = [s for s in self._sessions.values() if self.expired(s, now)]
        for s in gone:
            del self._sessions[s.id]
        return gone

    def close(self, sid: str) -> Session | None:
        """Remove session ``sid`` (logout); the removed session, or None."""
        return self._sessions.pop(sid, None)

    def of_user(self, user: str) -> list[Session]:
        """The sessions of ``user`` (expired ones included until :meth:`expire`)."""
        return [s for s in self._sessions.values() if s.user == user]

    def socket_opened(self, s: Session, now: float) -> None:
        s.sockets += 1
        s.last_seen_s = max(s.last_seen_s, now)

    def socket_closed(self, s: Session, now: float) -> None:
        """One WebSocket of ``s`` closed: idle from ``now`` on if it was the last."""
        s.sockets = max(0, s.sockets - 1)
        s.last_seen_s = max(s.last_seen_s, now)

    @staticmethod
    def csrf_ok(s: Session, header: str | None) -> bool:
        """Whether ``header`` is the session's CSRF token (constant-time comparison)."""
        return header is not None and hmac.compare_digest(header.encode(), s.csrf.encode())
