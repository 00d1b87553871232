"""Per-tier security homes for containers: what each tier's container mounts at /etc/tanklab.

A tier in a container runs as the image's user (uid/gid 10001, see the Dockerfile), while the
host's security home is 0700 directories and 0600 keys owned by whoever ran ``tankctl pki
init``. Bind-mounting those files as they are gives the container files it cannot read
(issue 21: "plant cannot serve: Permission denied"). :func:`lay_out` therefore writes, for each
tier, a complete but minimal copy of the home owned by the container's user::

    root/containers/                 0755, owned by the caller (only a parent)
    root/containers/{tier}/          0700, uid:gid   -> mounted read-only at /etc/tanklab
        pki/own/*.der                0644  every application certificate (public)
        pki/trusted/*                0644  the trust list (the CA's copy, external certs)
        pki/crl/*                    0644  the CRL
        pki/private/{tier}.pem       0600  this tier's private key, and only this one (the HMI's:
                                           cli.pem, the client certificate it opens its users'
                                           sessions with)
        users.json                   0600  the users file (password hashes)
        external.json                0600  the External identities (when the home has any)

The CA and its private key are never copied: a tier verifies peers against ``trusted/`` and
``crl/`` and never signs anything. Every run replaces the copies from the host home, so after
``tankctl user add``, ``pki revoke`` or ``pki init --force`` the command is simply run again (a
tier re-reads users and CRL files when they change, so a running container sees the change).

Ownership by another uid needs root: as any other user, :func:`lay_out` refuses unless the
target uid is the caller's own (decision 0021).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from tanklab.errors import SecurityError
from tanklab_io.external import EXTERNAL_FILE
from tanklab_io.home import SecurityHome
from tanklab_io.pki import write_file

__all__ = ["CONTAINER_GID", "CONTAINER_UID", "KEY_OF", "TIERS", "ContainerHome", "container_root", "lay_out"]

CONTAINER_UID = 10001
"""uid of the image's ``tanklab`` user (Dockerfile ``useradd --uid``)."""

CONTAINER_GID = 10001
"""gid of the image's ``tanklab`` group (Dockerfile ``groupadd --gid``)."""

TIERS = ("plant", "plc", "supervisor", "historian", "hmi")
"""The services that run as containers (docker-compose.yml's services)."""

KEY_OF = {"hmi": "cli"}
"""A service whose key is another identity's: the HMI is an OPC UA client with the CLI's
certificate (each user logs in with their own password over it, decision 0047)."""


@dataclass(frozen=True)
class ContainerHome:
    """One tier's container home as laid out: its root and the files written into it."""

    tier: str
    root: Path
    files: tuple[Path, ...]


def container_root(home: SecurityHome) -> Path:
    """``home.root/containers``: the parent of the per-tier homes."""
    return home.root / "containers"


def _check_owner(uid: int, gid: int, euid: int) -> None:
    """Refuse ownership the caller cannot give (a non-root caller only owns files as itself)."""
    if uid < 0 or gid < 0:
        raise SecurityError(f"pki containers: uid and gid must be >= 0, got {uid}:{gid}")
    if euid not in (0, uid):  # root may give files to anyone, others only to themselves
        raise SecurityError(
            f"pki containers: making keys readable by uid {uid} needs root (you are uid {euid}); "
            f"run it with sudo, or pass --uid {euid} for an image whose user is uid {euid}"
        )


def _copy(src: Path, dst: Path, mode: int, uid: int, gid: int) -> Path:
    """Copy ``src`` to ``dst`` atomically, created with ``mode`` (never wider) and owned by uid:gid."""
    write_file(dst, src.read_bytes(), mode, owner=(uid, gid))
    return dst


def _fresh_dir(path: Path, mode: int, uid: int, gid: int) -> None:
    """An empty directory ``path`` with ``mode`` owned by uid:gid (an old one is removed first)."""
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.exists():
        shutil.rmtree(path)
    path.mkdir(mode=mode)
    os.chmod(path, mode)
    os.chown(path, uid, gid)


def lay_out(
    home: SecurityHome,
    *,
    tiers: Sequence[str] = TIERS,
    uid: int = CONTAINER_UID,
    gid: int = CONTAINER_GID,
    euid: int | None = None,
) -> list[ContainerHome]:
    """Write ``root/containers/{tier}/`` for each tier from ``home`` (see the module docstring).

    Parameters
    ----------
    home : the host's security home; its PKI must be complete and its users file present.
    tiers : the tiers to lay out (default plant, plc, supervisor, historian).
    uid, gid : owner of every copied file and directory (the container's user).
    euid : the caller's effective uid (default ``os.geteuid()``); not root means ``uid`` must
        be the caller's own.

    Raises
    ------
    SecurityError
        The PKI is incomplete, the users file is missing, or the ownership needs root.
    """
    _check_owner(uid, gid, os.geteuid() if euid is None else euid)
    pki = home.pki
    if not pki.exists():
        raise SecurityError(f"{pki.root}: incomplete PKI; run `tankctl pki init --home {home.root}` first")
    if not home.users_file.is_file():
        raise SecurityError(
            f"{home.users_file}: no users file; add a user first (`tankctl user add NAME --role ROLE`)"
        )
    public = {
        "own": sorted(p for p in pki.own_dir.iterdir() if p.is_file()),
        "trusted": sorted(p for p in pki.trusted_dir.iterdir() if p.is_file()),
        "crl": sorted(p for p in pki.crl_dir.iterdir() if p.is_file()),
    }
    parent = container_root(home)
    parent.mkdir(mode=0o755, exist_ok=True)
    os.chmod(parent, 0o755)  # only directory names; each tier's directory is 0700
    out = []
    for tier in tiers:
        key = pki.key_path(KEY_OF.get(tier, tier))
        if not key.is_file():
            raise SecurityError(f"{key}: no private key for tier {tier!r}")
        root = parent / tier
        _fresh_dir(root, 0o700, uid, gid)
        files: list[Path] = []
        _fresh_dir(root / "pki", 0o700, uid, gid)
        for sub, sources in public.items():
            _fresh_dir(root / "pki" / sub, 0o755, uid, gid)
            files += [_copy(src, root / "pki" / sub / src.name, 0o644, uid, gid) for src in sources]
        _fresh_dir(root / "pki" / "private", 0o700, uid, gid)
        files.append(_copy(key, root / "pki" / "private" / key.name, 0o600, uid, gid))
        files.append(_copy(home.users_file, root / "users.json", 0o600, uid, gid))
        external = home.root / EXTERNAL_FILE
        if external.is_file():  # the PLC maps its certificates to role External (decision 0055)
            files.append(_copy(external, root / EXTERNAL_FILE, 0o600, uid, gid))
        out.append(ContainerHome(tier, root, tuple(files)))
    return out
