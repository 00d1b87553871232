"""The security home: where a site's PKI, users, client credentials and audit log live.

Layout (``root`` and every directory in it 0700)::

    root/pki/          the PKI (see :mod:`tanklab_io.pki`)
    root/users.json    the users file (see :mod:`tanklab_io.users`), 0600
    root/credentials   the CLI's own login (``user=`` / ``password=``), 0600
    root/audit/        the servers' audit logs

``root`` is ``$TANKLAB_HOME`` when set, else ``$XDG_CONFIG_HOME/tanklab``, else
``~/.config/tanklab``. :func:`provision` is the first-use set-up ``tankctl up`` runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from tanklab.tags import Role
from tanklab_io.pki import DEFAULT_HOSTS, Pki, init_pki
from tanklab_io.users import (
    ENV_HOME,
    Credentials,
    UsersFile,
    default_home,
    generate_password,
    write_credentials,
)

__all__ = ["ENV_HOME", "FIRST_USER", "SecurityHome", "default_home", "provision"]

FIRST_USER = "engineer"
"""Name of the Engineer account :func:`provision` creates when the users file has no user."""


@dataclass(frozen=True)
class SecurityHome:
    """Paths of the security home rooted at ``root`` (nothing is read or written here)."""

    root: Path

    @property
    def pki(self) -> Pki:
        """The PKI at ``root/pki``."""
        return Pki.at(self.root / "pki")

    @property
    def users_file(self) -> Path:
        """The users file ``root/users.json``."""
        return self.root / "users.json"

    @property
    def credentials_file(self) -> Path:
        """The CLI's credentials file ``root/credentials``."""
        return self.root / "credentials"

    @property
    def audit_dir(self) -> Path:
        """The directory of audit logs ``root/audit``."""
        return self.root / "audit"

    def ensure(self) -> None:
        """Create ``root`` (and missing parents) as 0700 when it does not exist; else leave it."""
        if not self.root.exists():
            self.root.mkdir(mode=0o700, parents=True)


def provision(home: SecurityHome, *, hosts: Sequence[str] = DEFAULT_HOSTS) -> str | None:
    """First-use set-up: a PKI, and an Engineer account when there is no user; idempotent.

    Initializes the PKI when it is incomplete (:func:`tanklab_io.pki.init_pki`). When the users
    file has no user, creates ``engineer`` (role Engineer) with a generated password and writes
    it to the credentials file (0600) so the CLI can log in. Returns that password when the
    account was created (for the caller to show once), else None; a second call changes nothing.
    """
    home.ensure()
    if not home.pki.exists():
        init_pki(home.pki.root, hosts=hosts)
    users = UsersFile.load(home.users_file)
    if users.names():
        return None
    password = generate_password()
    users.add(FIRST_USER, Role.ENGINEER, password)
    # Credentials first: should saving the users file fail, the next call simply provisions again.
    write_credentials(home.credentials_file, Credentials(FIRST_USER, password))
    users.save()
    return password
