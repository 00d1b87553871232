"""The operator commands' failures: each becomes one line and an exit code (:func:`tankctl.ops.run.run`)."""

from __future__ import annotations

import socket
from typing import Any

from tanklab.errors import LOGIN_REFUSALS, TanklabError

__all__ = [
    "LOGIN_REFUSALS",
    "CallRefusedError",
    "LoginRefusedError",
    "RefusedError",
    "SiteMismatchError",
    "StoppedError",
    "UnreachableError",
    "UsageError",
    "describe_failure",
]


class UnreachableError(TanklabError):
    """A tier did not answer: refused, timed out, unknown host, no tanklab namespace (exit 2)."""

    def __init__(self, tier: str, url: str, reason: str) -> None:
        super().__init__(f"cannot reach {tier} at {url}: {reason}")
        self.tier = tier
        self.url = url
        self.reason = reason


class LoginRefusedError(TanklabError):
    """A tier refused the session's login (exit 2): wrong password, unknown user, a locked
    account, or an identity the server does not take. Never reported as unreachable: the tier
    answered, it said no."""

    def __init__(self, user: str | None, tier: str, url: str, status: str) -> None:
        who = f"login as {user!r}" if user is not None else "login"
        if status == "BadUserAccessDenied":
            why = "wrong user name or password, or the account is locked"
        else:  # BadIdentityTokenRejected, BadIdentityTokenInvalid
            why = f"the {tier} does not accept this identity ({status})"
        super().__init__(f"{who} refused: {why} ({tier} at {url})")
        self.user = user
        self.tier = tier
        self.url = url
        self.status = status


class SiteMismatchError(TanklabError):
    """A tier runs another site, or the same site with another config, than the command was
    given (``--config`` or the tier asked first), or publishes no identity (exit 2)."""


class RefusedError(TanklabError):
    """A server answered a write with a Bad status code (exit 1)."""

    def __init__(self, path: str, shown: str, status: str) -> None:
        super().__init__(f"{path} = {shown} refused: {status}")
        self.path = path
        self.status = status


class CallRefusedError(RefusedError):
    """A server answered a method call with a Bad status code (exit 1)."""

    def __init__(self, path: str, args: str, status: str, hint: str = "") -> None:
        TanklabError.__init__(self, f"{path}({args}) refused: {status}" + (f" ({hint})" if hint else ""))
        self.path = path
        self.status = status


class UsageError(TanklabError, ValueError):
    """An argument failed the local checks: unknown name, bad number, bad option (exit 2)."""


class StoppedError(TanklabError):
    """Ctrl-C (SIGINT) or SIGTERM stopped a command that was applying changes (exit 130)."""


def describe_failure(e: BaseException, timeout_s: float) -> str:
    """One short reason for a failed connection or request."""
    if isinstance(e, TimeoutError):
        return f"no answer within {timeout_s:g} s"
    if isinstance(e, ConnectionRefusedError):
        return "connection refused"
    if isinstance(e, socket.gaierror):
        return f"unknown host ({e.strerror or e})"
    ua = _ua_if_loaded()
    if ua is not None and isinstance(e, ua.UaStatusCodeError):
        return str(ua.StatusCode(e.code).name)
    if isinstance(e, OSError):
        return str(e.strerror or e) or type(e).__name__
    text = str(e)
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def _ua_if_loaded() -> Any:
    """asyncua's ``ua`` if something imported asyncua (an exception of its can only come from a
    process that did); None on the relay path, which never imports it (decision 0048)."""
    import sys

    if "asyncua" not in sys.modules:
        return None
    from asyncua import ua

    return ua
