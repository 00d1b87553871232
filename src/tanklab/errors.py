"""The small error hierarchy of tanklab.

Errors are raised early and never printed or swallowed inside the library; the CLI turns them
into one-line messages with a non-zero exit code. Built-in ``ValueError`` and ``TypeError`` are
used for bad values and wrong types in pure code; the classes here mark failures that a user
must act on (a broken config file, an unreachable endpoint, a solver that did not converge).
"""

from __future__ import annotations


class TanklabError(Exception):
    """Base class of every error tanklab raises on purpose."""


class ConfigError(TanklabError, ValueError):
    """A configuration or scenario file is unreadable or invalid.

    The message is one line naming the file, the field and the rule, e.g.
    ``configs/x.yaml: plant.tanks[0].area_m2: Input should be greater than 0``.
    """


class IntegrationError(TanklabError, RuntimeError):
    """The plant integrator failed to advance the state (solver failure or non-finite state)."""


class LinkError(TanklabError, ConnectionError):
    """An OPC UA endpoint could not be reached or answered with an error."""


class SecurityError(TanklabError, ValueError):
    """A PKI, users or credentials file is invalid or unsafe, or a security operation was refused.

    The message is one line naming the file and the rule, e.g.
    ``~/.config/tanklab/credentials: permissions 0644: must be 0600 (chmod 600 FILE)``; it never
    contains a password or key material.
    """


LOGIN_REFUSALS = frozenset({"BadUserAccessDenied", "BadIdentityTokenRejected", "BadIdentityTokenInvalid"})
"""What a server answers a refused ActivateSession with (asyncua raises them as
``UaStatusCodeError`` subclasses from ``Client.connect``): tanklab's user manager answers
BadUserAccessDenied to a wrong password, an unknown name and a locked account alike (so that
a refusal tells an attacker nothing), BadIdentityTokenRejected to an anonymous session."""


class ControllerError(TanklabError, ValueError):
    """A supervisory controller named by dotted path cannot be used: the path is malformed, its
    module is not importable, the name is missing, the class does not implement the interface or
    its construction failed. One line naming the path and the problem (decision 0054)."""
