"""tanklab_io.containers.lay_out: per-tier container homes owned by the image's user.

The suite runs as root on the development machines, so the chown to uid 10001 is real here;
the non-root rule is checked through ``euid`` (the caller's uid as the function sees it).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from tanklab.errors import SecurityError
from tanklab.tags import Role
from tanklab_io.containers import CONTAINER_GID, CONTAINER_UID, KEY_OF, TIERS, container_root, lay_out
from tanklab_io.home import SecurityHome
from tanklab_io.pki import IDENTITIES, init_pki
from tanklab_io.users import UsersFile

needs_root = pytest.mark.skipif(os.geteuid() != 0, reason="chown to another uid needs root")


@pytest.fixture(scope="module")
def home(tmp_path_factory: pytest.TempPathFactory) -> SecurityHome:
    sec = SecurityHome(tmp_path_factory.mktemp("home"))
    init_pki(sec.pki.root)
    users = UsersFile.load(sec.users_file)
    users.add("alice", Role.OPERATOR, "alice-password-1")
    users.save()
    return sec


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


@needs_root
def test_each_tier_gets_its_own_key_and_the_public_files_owned_by_the_image_user(home: SecurityHome) -> None:
    laid = lay_out(home)
    assert [c.tier for c in laid] == list(TIERS)
    pki = home.pki
    for c in laid:
        assert c.root == container_root(home) / c.tier
        tier_pki = SecurityHome(c.root).pki
        # Only this tier's private key; never the CA's (key or directory).
        key = KEY_OF.get(c.tier, c.tier)  # the HMI's is the CLI's client key
        assert sorted(p.name for p in tier_pki.private_dir.iterdir()) == [f"{key}.pem"]
        assert tier_pki.key_path(key).read_bytes() == pki.key_path(key).read_bytes()
        assert not (c.root / "pki" / "ca").exists()
        assert all(b"PRIVATE KEY" not in f.read_bytes() for f in c.files if f.parent.name != "private")
        # Every certificate a tier maps to a role, the trust list, the CRL and the users file.
        for name in IDENTITIES:
            assert tier_pki.cert_path(name).read_bytes() == pki.cert_path(name).read_bytes()
        assert sorted(p.name for p in tier_pki.trusted_dir.iterdir()) == sorted(
            p.name for p in pki.trusted_dir.iterdir()
        )
        assert (tier_pki.crl_file).read_bytes() == pki.crl_file.read_bytes()
        assert (c.root / "users.json").read_bytes() == home.users_file.read_bytes()
        # Owned by the container's user; secrets 0600 in 0700 directories, public files 0644.
        for path in [c.root, *c.root.rglob("*")]:
            st = path.stat()
            assert (st.st_uid, st.st_gid) == (CONTAINER_UID, CONTAINER_GID), path
        assert _mode(c.root) == 0o700 and _mode(tier_pki.private_dir) == 0o700
        assert _mode(tier_pki.key_path(key)) == 0o600 and _mode(c.root / "users.json") == 0o600
        assert _mode(tier_pki.cert_path(key)) == 0o644
        assert set(c.files) == {p for p in c.root.rglob("*") if p.is_file()}
    assert _mode(container_root(home)) == 0o755
    # The host's home is untouched: its keys stay 0600 and owned by the caller.
    assert _mode(pki.key_path("plant")) == 0o600 and pki.key_path("plant").stat().st_uid == os.geteuid()


@needs_root
def test_a_second_run_replaces_the_copies(home: SecurityHome, tmp_path: Path) -> None:
    lay_out(home)
    stray = container_root(home) / "plant" / "pki" / "private" / "old.pem"
    stray.write_text("left over")
    users = UsersFile.load(home.users_file)
    users.add("bob", Role.OBSERVER, "bob-password-12")
    users.save()
    (c, *_) = lay_out(home, tiers=("plant",))
    assert not stray.exists()
    assert (c.root / "users.json").read_bytes() == home.users_file.read_bytes()
    assert "bob" in UsersFile.load(c.root / "users.json").names()


def test_a_non_root_caller_may_only_give_the_files_to_itself(home: SecurityHome) -> None:
    with pytest.raises(SecurityError, match=r"uid 10001 needs root \(you are uid 1000\); run it with sudo"):
        lay_out(home, euid=1000)
    with pytest.raises(SecurityError, match="must be >= 0"):
        lay_out(home, uid=-1)


@needs_root
def test_the_callers_own_uid_is_allowed_without_root(home: SecurityHome) -> None:
    (c,) = lay_out(home, tiers=("plc",), uid=1000, gid=1000, euid=1000)
    assert c.root.stat().st_uid == 1000
    assert SecurityHome(c.root).pki.key_path("plc").stat().st_uid == 1000


def test_an_incomplete_home_is_refused(tmp_path: Path) -> None:
    empty = SecurityHome(tmp_path / "none")
    with pytest.raises(SecurityError, match="incomplete PKI; run `tankctl pki init"):
        lay_out(empty, euid=0)
    init_pki(empty.pki.root)
    with pytest.raises(SecurityError, match="no users file"):
        lay_out(empty, euid=0)
    assert not container_root(empty).exists()


def test_the_external_identities_go_with_the_copies(tmp_path: Path) -> None:
    from tanklab_io.external import ExternalIdentities, add_external

    sec = SecurityHome(tmp_path / "home")
    init_pki(sec.pki.root)
    users = UsersFile.load(sec.users_file)
    users.add("alice", Role.OPERATOR, "alice-password-1")
    users.save()
    uid, gid = os.geteuid(), os.getegid()
    (before,) = lay_out(sec, tiers=("plc",), uid=uid, gid=gid, euid=uid)
    assert not (before.root / "external.json").exists()  # none yet: nothing copied
    add_external(sec, "ctl")
    (c,) = lay_out(sec, tiers=("plc",), uid=uid, gid=gid, euid=uid)
    assert _mode(c.root / "external.json") == 0o600
    copied = ExternalIdentities(SecurityHome(c.root)).current()
    assert list(copied.values()) == [("external-ctl", Role.EXTERNAL)]
