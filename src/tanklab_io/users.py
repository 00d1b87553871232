"""Users, passwords, lockout and client credentials: the password side of tanklab's security.

**Password hashes** are scrypt (RFC 7914) with n = 2**14, r = 8, p = 1 (128 * r * n = 16 MiB of
memory per hash), a 16-byte random salt and a 32-byte key, stored as one ASCII string::

    scrypt$<n>$<r>$<p>$<salt, base64>$<key, base64>

**The users file** (``users.json``, 0600, replaced atomically) maps names to a role and a hash::

    {"version": 1, "users": {"alice": {"role": "Operator", "password_hash": "scrypt$16384$8$1$..."}}}

Only the login roles Observer, Operator and Engineer have passwords; Supervisor, PLC and External
(an external controller, :mod:`tanklab_io.external`) are certificate identities and can never log
in with a password.

**Lockout**: 5 consecutive failed logins of a name lock it for 60 s (while locked even the right
password is refused); a success resets the count. :class:`Lockout` is pure: the caller passes
the time (monotonic seconds).

**Client credentials** come from ``TANKLAB_USER`` + ``TANKLAB_PASSWORD`` when both are set,
else from a file of two lines ``user=NAME`` and ``password=SECRET`` that only its owner may
read (0600); a wider file is refused, never silently used.

No function here logs, prints or puts a password or a hash into an error message.
"""

from __future__ import annotations

import base64
import binascii
import functools
import hashlib
import hmac
import json
import os
import re
import secrets
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tanklab.errors import SecurityError
from tanklab.tags import Role
from tanklab_io.persist import write_bytes_atomic

__all__ = [
    "ENV_HOME",
    "ENV_PASSWORD",
    "ENV_USER",
    "LOGIN_ROLES",
    "MIN_PASSWORD_LENGTH",
    "Credentials",
    "Lockout",
    "UserRecord",
    "UsersFile",
    "cli_login",
    "default_home",
    "generate_password",
    "hash_password",
    "load_credentials",
    "parse_credentials",
    "verify_password",
    "write_credentials",
    "write_private",
]

LOGIN_ROLES = (Role.OBSERVER, Role.OPERATOR, Role.ENGINEER)
"""Roles a user name and password may have (Supervisor and PLC are certificate identities)."""

MIN_PASSWORD_LENGTH = 12
"""Shortest password :meth:`UsersFile.add` accepts [characters]."""

SCRYPT_N = 2**14
SCRYPT_R = 8
SCRYPT_P = 1
SALT_BYTES = 16
KEY_BYTES = 32

# Bounds on the parameters verify_password accepts from a stored hash: a tampered file must not
# make one login cost gigabytes or minutes.
_MAX_N = 2**20
_MAX_R = 32
_MAX_P = 16
_MAX_KEY_BYTES = 128

ENV_USER = "TANKLAB_USER"
ENV_PASSWORD = "TANKLAB_PASSWORD"
ENV_HOME = "TANKLAB_HOME"
"""Environment variable naming the security home (:mod:`tanklab_io.home`)."""

USERS_FILE_VERSION = 1
_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


# --------------------------------------------------------------------------------------------
# Password hashing
# --------------------------------------------------------------------------------------------


def _scrypt(password: str, salt: bytes, n: int, r: int, p: int, length: int) -> bytes:
    # OpenSSL's default memory cap is 32 MiB; allow what these parameters need (128 * r * n) plus slack.
    maxmem = 128 * r * (n + p + 2) + 1024 * 1024
    return hashlib.scrypt(password.encode("utf-8"), salt=salt, n=n, r=r, p=p, dklen=length, maxmem=maxmem)


def hash_password(password: str) -> str:
    """``scrypt$16384$8$1$<salt b64>$<key b64>`` for ``password`` with a fresh 16-byte salt."""
    salt = secrets.token_bytes(SALT_BYTES)
    key = _scrypt(password, salt, SCRYPT_N, SCRYPT_R, SCRYPT_P, KEY_BYTES)
    b64 = base64.b64encode
    return f"scrypt${SCRYPT_N}${SCRYPT_R}${SCRYPT_P}${b64(salt).decode()}${b64(key).decode()}"


def _parse_hash(encoded: str) -> tuple[int, int, int, bytes, bytes] | None:
    """(n, r, p, salt, key) of a well-formed hash within the accepted bounds, else None."""
    parts = encoded.split("$") if isinstance(encoded, str) else []
    if len(parts) != 6 or parts[0] != "scrypt" or not all(s.isdigit() for s in parts[1:4]):
        return None
    n, r, p = int(parts[1]), int(parts[2]), int(parts[3])
    if not (2 <= n <= _MAX_N and n & (n - 1) == 0 and 1 <= r <= _MAX_R and 1 <= p <= _MAX_P):
        return None
    try:
        salt = base64.b64decode(parts[4], validate=True)
        key = base64.b64decode(parts[5], validate=True)
    except (binascii.Error, ValueError):
        return None
    if not salt or not 1 <= len(key) <= _MAX_KEY_BYTES:
        return None
    return n, r, p, salt, key


def verify_password(password: str, encoded: str) -> bool:
    """True when ``password`` matches ``encoded`` (constant-time compare); a malformed hash is False."""
    parsed = _parse_hash(encoded)
    if parsed is None:
        return False
    n, r, p, salt, key = parsed
    return hmac.compare_digest(_scrypt(password, salt, n, r, p, len(key)), key)


@functools.cache
def _dummy_hash() -> str:
    """A hash of a random password, computed once: unknown users still cost one scrypt."""
    return hash_password(secrets.token_urlsafe(18))


def generate_password() -> str:
    """A random password of 24 URL-safe characters (18 bytes = 144 bits of entropy)."""
    return secrets.token_urlsafe(18)


# --------------------------------------------------------------------------------------------
# Users file
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class UserRecord:
    """One user: a name, a login role and a password hash (never the password)."""

    name: str
    role: Role
    password_hash: str = field(repr=False)


def _roles_text() -> str:
    return ", ".join(r.value for r in LOGIN_ROLES)


def _check_name(name: str, where: str) -> None:
    if not isinstance(name, str) or not _NAME.match(name):
        raise SecurityError(f"{where}: user name {name!r}: must match [A-Za-z0-9_.-]{{1,64}}")


def _check_role(role: object, where: str) -> Role:
    """The login role ``role`` names (a Role or its value), else a SecurityError."""
    for r in LOGIN_ROLES:
        if role == r.value:  # a Role is a StrEnum: equal to its value
            return r
    if isinstance(role, str) and role.lower() == Role.EXTERNAL.value.lower():
        raise SecurityError(
            f"{where}: External is a certificate identity, never a password login "
            "(use `tankctl user add-external NAME`)"
        )
    raise SecurityError(f"{where}: must be one of {_roles_text()}, got {role!r}")


def _record(path: Path, name: Any, entry: Any) -> UserRecord:
    """Validate one ``users.NAME`` entry of the file; every failure names the file and the field."""
    where = f"{path}: users.{name}"
    _check_name(name, f"{path}: users")
    if not isinstance(entry, dict):
        raise SecurityError(f"{where}: must be an object with role and password_hash")
    extra = sorted(set(entry) - {"role", "password_hash"})
    if extra:
        raise SecurityError(f"{where}: unknown field {extra[0]!r}")
    if "role" not in entry:
        raise SecurityError(f"{where}.role: missing")
    role = _check_role(entry["role"], f"{where}.role")
    encoded = entry.get("password_hash")
    if not isinstance(encoded, str) or _parse_hash(encoded) is None:
        raise SecurityError(f"{where}.password_hash: must be scrypt$N$r$p$SALT$KEY")
    return UserRecord(name, role, encoded)


class UsersFile:
    """The users of a site, as stored in ``users.json``; change it, then :meth:`save`.

    Parameters
    ----------
    path : Path
        Where :meth:`save` writes.
    users : mapping of str to UserRecord, optional
        Initial users (default: none).
    """

    def __init__(self, path: Path, users: Mapping[str, UserRecord] | None = None) -> None:
        self.path = Path(path)
        self._users: dict[str, UserRecord] = dict(users or {})

    @classmethod
    def load(cls, path: Path) -> UsersFile:
        """Read ``path``; a missing file has no users; a bad file is one-line SecurityError."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return cls(path)
        except (OSError, UnicodeDecodeError) as e:
            reason = e.strerror if isinstance(e, OSError) and e.strerror else "not UTF-8 text"
            raise SecurityError(f"{path}: cannot read: {reason}") from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as e:
            where = f"line {e.lineno} column {e.colno}"
            raise SecurityError(f"{path}: not valid JSON: {where}: {e.msg}") from None
        if not isinstance(data, dict):
            raise SecurityError(f"{path}: must be a JSON object with version and users")
        extra = sorted(set(data) - {"version", "users"})
        if extra:
            raise SecurityError(f"{path}: unknown field {extra[0]!r}")
        if data.get("version", USERS_FILE_VERSION) != USERS_FILE_VERSION:
            raise SecurityError(f"{path}: version: must be {USERS_FILE_VERSION}, got {data['version']!r}")
        users = data.get("users", {})
        if not isinstance(users, dict):
            raise SecurityError(f"{path}: users: must be an object mapping names to users")
        return cls(path, {name: _record(path, name, entry) for name, entry in users.items()})

    def to_json(self) -> str:
        """The file's text: version, then users sorted by name."""
        users = {n: {"role": u.role.value, "password_hash": u.password_hash} for n, u in self._sorted()}
        return json.dumps({"version": USERS_FILE_VERSION, "users": users}, indent=2) + "\n"

    def _sorted(self) -> list[tuple[str, UserRecord]]:
        return sorted(self._users.items())

    def save(self) -> None:
        """Write the file atomically (a new 0600 file renamed over the old one)."""
        write_private(self.path, self.to_json().encode("utf-8"))

    def add(self, name: str, role: Role, password: str, *, replace: bool = False) -> None:
        """Add a user (or replace one when ``replace``); checks name, login role and password length."""
        _check_name(name, str(self.path))
        checked = _check_role(role, f"{self.path}: users.{name}.role")
        if name in self._users and not replace:
            raise SecurityError(f"{self.path}: user {name!r} exists (use --replace to change it)")
        if not isinstance(password, str) or len(password) < MIN_PASSWORD_LENGTH:
            raise SecurityError(f"password of {name!r}: must have at least {MIN_PASSWORD_LENGTH} characters")
        self._users[name] = UserRecord(name, checked, hash_password(password))

    def remove(self, name: str) -> None:
        """Remove a user; an unknown name is a SecurityError."""
        if name not in self._users:
            raise SecurityError(f"{self.path}: no user {name!r}")
        del self._users[name]

    def get(self, name: str) -> UserRecord | None:
        """The user called ``name``, or None."""
        return self._users.get(name)

    def names(self) -> list[str]:
        """User names, sorted."""
        return sorted(self._users)

    def verify(self, name: str, password: str) -> Role | None:
        """The user's role when ``password`` is right, else None.

        An unknown user costs the same scrypt as a known one (checked against a dummy hash), so
        the response time does not tell which names exist.
        """
        user = self._users.get(name)
        if user is None:
            verify_password(password, _dummy_hash())
            return None
        return user.role if verify_password(password, user.password_hash) else None


# --------------------------------------------------------------------------------------------
# Lockout
# --------------------------------------------------------------------------------------------


@dataclass
class _Failures:
    count: int = 0
    locked_until: float | None = None


class Lockout:
    """Consecutive failed logins per name; ``max_failures`` of them lock the name for ``lock_s``.

    Pure: every method takes the time ``now`` [s] from the caller's monotonic clock. A name is
    locked on ``[t5, t5 + lock_s)`` where ``t5`` is the time of the locking failure; afterwards
    the count starts again from zero. Failures reported while locked change nothing. At most
    ``max_names`` names are remembered; beyond that, unlocked ones are forgotten first.
    """

    def __init__(self, max_failures: int = 5, lock_s: float = 60.0, max_names: int = 10_000) -> None:
        if max_failures < 1:
            raise ValueError(f"max_failures must be >= 1, got {max_failures}")
        if not lock_s > 0:
            raise ValueError(f"lock_s must be > 0 s, got {lock_s}")
        self.max_failures = max_failures
        self.lock_s = lock_s
        self.max_names = max_names
        self._state: dict[str, _Failures] = {}

    def locked(self, name: str, now: float) -> bool:
        """True while ``name`` is locked at time ``now`` [s]."""
        state = self._state.get(name)
        return state is not None and state.locked_until is not None and now < state.locked_until

    def failed(self, name: str, now: float) -> bool:
        """Record a failed login of ``name`` at ``now`` [s]; True if this failure locks the name."""
        if self.locked(name, now):
            return False
        state = self._state.get(name)
        if state is None:
            self._prune(now)
            state = self._state.setdefault(name, _Failures())
        if state.locked_until is not None:  # an expired lock: count afresh
            state.count, state.locked_until = 0, None
        state.count += 1
        if state.count >= self.max_failures:
            state.locked_until = now + self.lock_s
            return True
        return False

    def succeeded(self, name: str) -> None:
        """Record a successful login: the count of ``name`` starts again from zero."""
        self._state.pop(name, None)

    def _prune(self, now: float) -> None:
        if len(self._state) < self.max_names:
            return
        for name in [n for n in self._state if not self.locked(n, now)]:
            del self._state[name]


# --------------------------------------------------------------------------------------------
# Client credentials
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Credentials:
    """A user name and password a client logs in with (``repr`` hides the password)."""

    username: str
    password: str

    def __repr__(self) -> str:
        return f"Credentials(username={self.username!r}, password='***')"


def write_private(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically as a 0600 file (created 0600: never readable by others).

    The parent directory is created 0700 when missing.
    """
    write_bytes_atomic(Path(path), data, mode=0o600, dir_mode=0o700)


def write_credentials(path: Path, creds: Credentials) -> None:
    """Write ``user=NAME`` and ``password=SECRET`` to a 0600 file (see :func:`write_private`)."""
    for key, value in (("user", creds.username), ("password", creds.password)):
        if not value or "\n" in value or "\r" in value:
            raise SecurityError(f"{path}: {key}: must be non-empty and on one line")
    write_private(Path(path), f"user={creds.username}\npassword={creds.password}\n".encode())


def parse_credentials(text: str, where: str) -> Credentials:
    """Credentials from the file format; errors name ``where`` and the line, never its content."""
    values: dict[str, str] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        key, sep, value = line.partition("=")
        key = key.strip()
        if not sep or key not in ("user", "password"):
            raise SecurityError(f"{where}: line {number}: expected user=NAME or password=SECRET")
        if key in values:
            raise SecurityError(f"{where}: line {number}: {key} given twice")
        values[key] = value
    for key in ("user", "password"):
        if not values.get(key):
            raise SecurityError(f"{where}: {key}: missing (expected a line {key}=...)")
    return Credentials(values["user"].strip(), values["password"])


def load_credentials(path: Path | None, environ: Mapping[str, str]) -> Credentials | None:
    """The client's credentials: TANKLAB_USER + TANKLAB_PASSWORD, else the file, else None.

    The environment wins when both variables are non-empty. A file readable or writable by the
    group or others (``mode & 0o077``) is refused with a SecurityError saying how to fix it; a
    missing file (or ``path`` None) gives None.
    """
    user, password = environ.get(ENV_USER), environ.get(ENV_PASSWORD)
    if user and password:
        return Credentials(user, password)
    if path is None:
        return None
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return None
    except OSError as e:
        raise SecurityError(f"{path}: cannot read: {e.strerror or e}") from None
    with os.fdopen(fd, "rb") as f:
        mode = os.fstat(f.fileno()).st_mode & 0o777  # the mode of the file read, not of a later one
        if mode & 0o077:
            raise SecurityError(f"{path}: permissions {mode:04o}: must be 0600 (chmod 600 {path})")
        data = f.read()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise SecurityError(f"{path}: not UTF-8 text") from None
    return parse_credentials(text, str(path))


def default_home(environ: Mapping[str, str] | None = None) -> Path:
    """``$TANKLAB_HOME``, else ``$XDG_CONFIG_HOME/tanklab``, else ``~/.config/tanklab``.

    Empty variables count as unset, and so does a relative ``XDG_CONFIG_HOME`` (the XDG base
    directory spec says to ignore it). ``environ`` defaults to ``os.environ``. (Here, not in
    :mod:`tanklab_io.home`, so that the CLI's relay path finds its login without the PKI's
    cryptography.)
    """
    env = os.environ if environ is None else environ
    home = env.get(ENV_HOME)
    if home:
        return Path(home).expanduser()
    xdg = env.get("XDG_CONFIG_HOME")
    if xdg and Path(xdg).is_absolute():
        return Path(xdg) / "tanklab"
    return Path.home() / ".config" / "tanklab"


def cli_login(credentials_file: Path, environ: Mapping[str, str] | None = None) -> Credentials | None:
    """The CLI's login: ``TANKLAB_USER`` + ``TANKLAB_PASSWORD``, else ``credentials_file``, else None.

    Raises
    ------
    SecurityError
        Only one of ``TANKLAB_USER`` and ``TANKLAB_PASSWORD`` is set (non-empty): a user name
        without its password is an error before connecting, never a login as the file's user;
        or the file is unreadable, too widely readable or malformed (:func:`load_credentials`).
    """
    env = os.environ if environ is None else environ
    # Half a login in the environment must not fall back to the file's user: the session and the
    # audit trail would then be someone else's than the operator asked for.
    user, password = env.get(ENV_USER), env.get(ENV_PASSWORD)
    if bool(user) != bool(password):
        given, missing = (ENV_USER, ENV_PASSWORD) if user else (ENV_PASSWORD, ENV_USER)
        named = f" ({user!r})" if user else ""
        raise SecurityError(
            f"{given} is set{named} but {missing} is not: set both, or neither to log in as "
            f"the user of {credentials_file}"
        )
    return load_credentials(credentials_file, env)
