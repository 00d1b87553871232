"""Password hashes, the users file, the lockout, client credentials and the security home.

Oracles are hand-checkable: a hash recomputed here with ``hashlib.scrypt`` directly, the exact
lockout timeline (4 failures free, the 5th locks, locked at +59.9 s, free at +60 s), file modes
read with ``stat``. No clock is read and nothing sleeps.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest

import tanklab_io.users as users_mod
from tanklab.errors import SecurityError
from tanklab.tags import Role
from tanklab_io.home import ENV_HOME, SecurityHome, default_home, provision
from tanklab_io.users import (
    ENV_PASSWORD,
    ENV_USER,
    LOGIN_ROLES,
    Credentials,
    Lockout,
    UsersFile,
    generate_password,
    hash_password,
    load_credentials,
    verify_password,
    write_credentials,
)

PASSWORD = "correct horse battery"


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


# --------------------------------------------------------------------------------------------
# Password hashes
# --------------------------------------------------------------------------------------------


def test_hash_format_and_recomputation() -> None:
    encoded = hash_password(PASSWORD)
    algo, n, r, p, salt_b64, key_b64 = encoded.split("$")
    assert (algo, n, r, p) == ("scrypt", "16384", "8", "1")
    salt, key = base64.b64decode(salt_b64), base64.b64decode(key_b64)
    assert (len(salt), len(key)) == (16, 32)
    assert key == hashlib.scrypt(PASSWORD.encode(), salt=salt, n=2**14, r=8, p=1, dklen=32)
    assert hash_password(PASSWORD) != encoded  # a fresh salt every time


def test_verify_known_vector() -> None:
    salt = bytes(range(16))
    key = hashlib.scrypt(PASSWORD.encode(), salt=salt, n=2**14, r=8, p=1, dklen=32)
    encoded = f"scrypt$16384$8$1${base64.b64encode(salt).decode()}${base64.b64encode(key).decode()}"
    assert verify_password(PASSWORD, encoded)
    assert not verify_password(PASSWORD + " ", encoded)
    assert not verify_password("", encoded)


@pytest.mark.parametrize(
    "encoded",
    [
        "",
        "scrypt",
        "bcrypt$16384$8$1$AAAA$AAAA",
        "scrypt$16384$8$1$AAAA",  # five fields
        "scrypt$abc$8$1$AAAAAAAAAAAAAAAAAAAAAA==$AAAA",
        "scrypt$1000$8$1$AAAAAAAAAAAAAAAAAAAAAA==$AAAA",  # n not a power of 2
        "scrypt$1073741824$8$1$AAAAAAAAAAAAAAAAAAAAAA==$AAAA",  # n = 2**30: a gigabyte per try
        "scrypt$16384$8$1$not-base64!$AAAA",
        "scrypt$16384$8$1$AAAAAAAAAAAAAAAAAAAAAA==$",  # empty key
    ],
)
def test_malformed_hash_is_false(encoded: str) -> None:
    assert verify_password(PASSWORD, encoded) is False


def test_generate_password() -> None:
    a, b = generate_password(), generate_password()
    assert len(a) == 24 and a != b
    assert set(a) <= set("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_")


# --------------------------------------------------------------------------------------------
# Users file
# --------------------------------------------------------------------------------------------


def test_login_roles_exclude_certificate_identities() -> None:
    assert LOGIN_ROLES == (Role.OBSERVER, Role.OPERATOR, Role.ENGINEER)


def test_add_save_load_verify(tmp_path: Path) -> None:
    path = tmp_path / "home" / "users.json"
    users = UsersFile.load(path)  # missing: no users
    assert users.names() == []
    users.add("alice", Role.OPERATOR, "alice-password-1")
    users.add("bob.k", Role.OBSERVER, "bob-password-22")
    users.save()
    assert mode(path) == 0o600
    data = json.loads(path.read_text())
    assert data["version"] == 1
    assert data["users"]["alice"]["role"] == "Operator"
    assert data["users"]["alice"]["password_hash"].startswith("scrypt$16384$8$1$")
    assert "alice-password-1" not in path.read_text()
    again = UsersFile.load(path)
    assert again.names() == ["alice", "bob.k"]
    record = again.get("alice")
    assert record is not None and record.role is Role.OPERATOR
    assert "scrypt" not in repr(record)
    assert again.verify("alice", "alice-password-1") is Role.OPERATOR
    assert again.verify("alice", "bob-password-22") is None
    again.remove("alice")
    assert again.get("alice") is None
    with pytest.raises(SecurityError, match="no user 'alice'"):
        again.remove("alice")


def test_unknown_user_still_costs_one_scrypt(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    users = UsersFile(tmp_path / "users.json")
    users.add("alice", Role.ENGINEER, "alice-password-1")
    calls: list[str] = []
    real = users_mod.verify_password

    def spy(password: str, encoded: str) -> bool:
        calls.append(encoded)
        return real(password, encoded)

    monkeypatch.setattr(users_mod, "verify_password", spy)
    assert users.verify("mallory", "alice-password-1") is None
    assert len(calls) == 1 and calls[0].startswith("scrypt$16384$8$1$")


@pytest.mark.parametrize(
    ("name", "role", "password", "message"),
    [
        ("bad name", Role.OPERATOR, "long-enough-pw", "user name 'bad name'"),
        ("x" * 65, Role.OPERATOR, "long-enough-pw", "must match"),
        ("sup", Role.SUPERVISOR, "long-enough-pw", "must be one of Observer, Operator, Engineer"),
        ("plc", Role.PLC, "long-enough-pw", "must be one of Observer, Operator, Engineer"),
        ("carol", Role.OPERATOR, "11-chars-xx", "at least 12 characters"),
    ],
)
def test_add_refuses(tmp_path: Path, name: str, role: Role, password: str, message: str) -> None:
    with pytest.raises(SecurityError, match=message) as caught:
        UsersFile(tmp_path / "users.json").add(name, role, password)
    assert password not in str(caught.value)


def test_add_twice_needs_replace(tmp_path: Path) -> None:
    users = UsersFile(tmp_path / "users.json")
    users.add("alice", Role.OPERATOR, "twelve-chars")  # exactly 12: accepted
    with pytest.raises(SecurityError, match="exists"):
        users.add("alice", Role.ENGINEER, "another-password")
    users.add("alice", Role.ENGINEER, "another-password", replace=True)
    assert users.verify("alice", "another-password") is Role.ENGINEER
    assert users.verify("alice", "twelve-chars") is None


def _good_hash() -> str:
    return hash_password("alice-password-1")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("{", "users.json: not valid JSON: line 1 column 2: "),
        ("[]", "users.json: must be a JSON object with version and users"),
        ('{"version": 2, "users": {}}', "users.json: version: must be 1, got 2"),
        ('{"users": {}, "extra": 1}', "users.json: unknown field 'extra'"),
        ('{"users": []}', "users.json: users: must be an object mapping names to users"),
        (
            '{"users": {"alice": {"role": "Supervisor", "password_hash": "HASH"}}}',
            "users.json: users.alice.role: must be one of Observer, Operator, Engineer, got 'Supervisor'",
        ),
        ('{"users": {"alice": {"password_hash": "HASH"}}}', "users.json: users.alice.role: missing"),
        (
            '{"users": {"alice": {"role": "Operator", "password_hash": "plain"}}}',
            "users.json: users.alice.password_hash: must be scrypt$N$r$p$SALT$KEY",
        ),
        (
            '{"users": {"alice": {"role": "Operator", "password_hash": "HASH", "x": 1}}}',
            "users.json: users.alice: unknown field 'x'",
        ),
        ('{"users": {"a b": {"role": "Operator", "password_hash": "HASH"}}}', "user name 'a b'"),
    ],
)
def test_load_errors_are_one_line_naming_file_and_field(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "users.json"
    path.write_text(text.replace("HASH", _good_hash()))
    with pytest.raises(SecurityError) as caught:
        UsersFile.load(path)
    assert message in str(caught.value)
    assert str(caught.value).startswith(str(path))
    assert "\n" not in str(caught.value)


# --------------------------------------------------------------------------------------------
# Lockout
# --------------------------------------------------------------------------------------------


def test_lockout_timeline() -> None:
    lock = Lockout()  # 5 failures, 60 s
    for t in (0.0, 1.0, 2.0, 3.0):
        assert lock.failed("alice", t) is False
        assert not lock.locked("alice", t)
    assert lock.failed("alice", 4.0) is True  # the 5th locks
    assert lock.locked("alice", 4.0)
    assert lock.locked("alice", 4.0 + 59.9)
    assert not lock.locked("alice", 4.0 + 60.0)
    assert not lock.locked("bob", 4.0)  # per name


def test_lockout_failures_while_locked_change_nothing_and_count_restarts_after() -> None:
    lock = Lockout(max_failures=5, lock_s=60.0)
    for t in range(5):
        lock.failed("alice", float(t))
    assert lock.failed("alice", 30.0) is False  # locked: not extended
    assert not lock.locked("alice", 64.0)
    for t in (64.0, 65.0, 66.0, 67.0):
        assert lock.failed("alice", t) is False  # a fresh count of 4
    assert lock.failed("alice", 68.0) is True
    assert lock.locked("alice", 127.9) and not lock.locked("alice", 128.0)


def test_success_resets_the_count() -> None:
    lock = Lockout()
    for t in range(4):
        lock.failed("alice", float(t))
    lock.succeeded("alice")
    for t in range(4):
        assert lock.failed("alice", 10.0 + t) is False
    assert lock.failed("alice", 14.0) is True


def test_lockout_arguments() -> None:
    with pytest.raises(ValueError, match="max_failures"):
        Lockout(max_failures=0)
    with pytest.raises(ValueError, match="lock_s"):
        Lockout(lock_s=0.0)


def test_lockout_forgets_unlocked_names_beyond_its_capacity() -> None:
    lock = Lockout(max_failures=2, max_names=3)
    lock.failed("a", 0.0)
    lock.failed("a", 0.0)  # locked until 60
    lock.failed("b", 0.0)
    lock.failed("c", 0.0)
    lock.failed("d", 1.0)  # full: b and c (unlocked) are forgotten, a stays locked
    assert lock.locked("a", 1.0)
    assert lock.failed("b", 1.0) is False  # a fresh count of 1 ...
    assert lock.failed("b", 1.0) is True  # ... and the 2nd locks


# --------------------------------------------------------------------------------------------
# Credentials
# --------------------------------------------------------------------------------------------


@pytest.fixture
def umask_zero() -> Iterator[None]:
    """Files would be created world-readable if the code relied on the umask."""
    old = os.umask(0)
    try:
        yield
    finally:
        os.umask(old)


def test_write_credentials_is_0600_and_round_trips(tmp_path: Path, umask_zero: None) -> None:
    path = tmp_path / "credentials"
    path.write_text("old\n")
    path.chmod(0o644)
    write_credentials(path, Credentials("engineer", "s3cret=with=equals"))
    assert mode(path) == 0o600
    assert path.read_text() == "user=engineer\npassword=s3cret=with=equals\n"
    assert load_credentials(path, {}) == Credentials("engineer", "s3cret=with=equals")


def test_env_wins_when_both_set(tmp_path: Path) -> None:
    path = tmp_path / "credentials"
    write_credentials(path, Credentials("file-user", "file-password"))
    env = {ENV_USER: "env-user", ENV_PASSWORD: "env-password"}
    assert load_credentials(path, env) == Credentials("env-user", "env-password")
    assert load_credentials(None, env) == Credentials("env-user", "env-password")
    assert load_credentials(path, {ENV_USER: "env-user"}) == Credentials("file-user", "file-password")
    assert load_credentials(path, {ENV_USER: "", ENV_PASSWORD: "x"}) == Credentials(
        "file-user", "file-password"
    )


def test_missing_file_or_no_path_is_none(tmp_path: Path) -> None:
    assert load_credentials(tmp_path / "nope", {}) is None
    assert load_credentials(None, {}) is None


@pytest.mark.parametrize("bits", [0o644, 0o640, 0o604, 0o660])
def test_readable_by_others_is_refused(tmp_path: Path, bits: int) -> None:
    path = tmp_path / "credentials"
    write_credentials(path, Credentials("engineer", "file-password"))
    path.chmod(bits)
    with pytest.raises(SecurityError) as caught:
        load_credentials(path, {})
    assert str(caught.value) == f"{path}: permissions {bits:04o}: must be 0600 (chmod 600 {path})"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("user=engineer\n", "password: missing"),
        ("password=hunter2hunter2\n", "user: missing"),
        ("user=engineer\nhunter2hunter2\n", "line 2: expected user=NAME or password=SECRET"),
        ("user=a\nuser=b\npassword=hunter2hunter2\n", "line 2: user given twice"),
    ],
)
def test_malformed_credentials_never_echo_the_secret(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "credentials"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o600)
    os.write(fd, text.encode())
    os.close(fd)
    with pytest.raises(SecurityError, match=message) as caught:
        load_credentials(path, {})
    assert "hunter2" not in str(caught.value)


def test_credentials_repr_hides_the_password() -> None:
    assert "s3cret" not in repr(Credentials("engineer", "s3cret"))


# --------------------------------------------------------------------------------------------
# Security home and provisioning
# --------------------------------------------------------------------------------------------


def test_default_home(tmp_path: Path) -> None:
    assert default_home({ENV_HOME: str(tmp_path / "h"), "XDG_CONFIG_HOME": "/x"}) == tmp_path / "h"
    assert default_home({"XDG_CONFIG_HOME": "/x/config"}) == Path("/x/config/tanklab")
    assert default_home({ENV_HOME: "", "XDG_CONFIG_HOME": "relative"}) == Path.home() / ".config/tanklab"
    assert default_home({}) == Path.home() / ".config" / "tanklab"


def test_security_home_paths(tmp_path: Path) -> None:
    home = SecurityHome(tmp_path)
    assert home.pki.root == tmp_path / "pki"
    assert home.users_file == tmp_path / "users.json"
    assert home.credentials_file == tmp_path / "credentials"
    assert home.audit_dir == tmp_path / "audit"


def _snapshot(root: Path) -> dict[str, tuple[int, bytes]]:
    return {str(p): (p.stat().st_mode, p.read_bytes()) for p in sorted(root.rglob("*")) if p.is_file()}


def test_provision_creates_engineer_once(tmp_path: Path) -> None:
    home = SecurityHome(tmp_path / "home")
    password = provision(home)
    assert password is not None and len(password) == 24
    assert mode(home.root) == 0o700
    assert home.pki.exists()
    assert mode(home.credentials_file) == 0o600
    assert mode(home.users_file) == 0o600
    users = UsersFile.load(home.users_file)
    assert users.names() == ["engineer"]
    assert users.verify("engineer", password) is Role.ENGINEER
    assert load_credentials(home.credentials_file, {}) == Credentials("engineer", password)
    before = _snapshot(home.root)
    assert provision(home) is None
    assert _snapshot(home.root) == before


def test_provision_leaves_existing_users_alone(tmp_path: Path) -> None:
    home = SecurityHome(tmp_path)
    users = UsersFile(home.users_file)
    users.add("alice", Role.OPERATOR, "alice-password-1")
    users.save()
    assert provision(home) is None
    assert UsersFile.load(home.users_file).names() == ["alice"]
    assert not home.credentials_file.exists()
    assert home.pki.exists()
