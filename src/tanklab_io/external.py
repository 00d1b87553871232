"""External controllers: certificate identities in role External (decision 0055).

An external controller is a client program outside tanklab (asyncua, node-opcua, anything that
speaks OPC UA with SignAndEncrypt and an X509 identity token) that drives the PLC loops an
engineer handed to it (``PLC.LIC{j}.RemoteSource`` EXTERNAL). It has no password: its identity
is a certificate of the site PKI, issued by :func:`add_external` (``tankctl user add-external
NAME``) as ``own/external-NAME.der`` with ApplicationUri ``urn:tanklab:external-NAME``, and
recorded in the security home's ``external.json`` (0600, replaced atomically)::

    {"version": 1, "external": {"NAME": {"role": "External", "sha256": "<hex of the DER>"}}}

The record pins the certificate's SHA-256, so a certificate file replaced behind the registry's
back is not an External identity. :class:`ExternalIdentities` is what the PLC's user manager
asks; it re-reads the file when it changes (no restart after ``add-external``), and revoking the
certificate (``tankctl pki revoke``) shuts the identity out at the channel, like every other.

No function here logs, prints or puts key material into an error message.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tanklab.errors import SecurityError
from tanklab.tags import Role
from tanklab_io.home import SecurityHome
from tanklab_io.pki import DEFAULT_DAYS, DEFAULT_HOSTS, issue
from tanklab_io.users import write_private

__all__ = [
    "CERT_PREFIX",
    "EXTERNAL_FILE",
    "ExternalIdentities",
    "ExternalRecord",
    "add_external",
    "application_uri",
    "cert_name",
    "load_external",
    "remove_external",
]

log = logging.getLogger(__name__)

EXTERNAL_FILE = "external.json"
"""The registry's file name in the security home."""

CERT_PREFIX = "external-"
"""An external controller NAME's certificate is ``own/external-NAME.der`` (never a tier's name)."""

FILE_VERSION = 1
_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,48}$")
_HEX = re.compile(r"^[0-9a-f]{64}$")


def cert_name(name: str) -> str:
    """The PKI name of external controller ``name``'s certificate (``external-NAME``)."""
    return CERT_PREFIX + name


def application_uri(name: str) -> str:
    """The ApplicationUri external controller ``name`` connects with (in its certificate)."""
    return f"urn:tanklab:{cert_name(name)}"


def registry_path(home: SecurityHome) -> Path:
    """``external.json`` of ``home``."""
    return home.root / EXTERNAL_FILE


@dataclass(frozen=True)
class ExternalRecord:
    """One external controller: its name and the SHA-256 of its certificate (DER, hex)."""

    name: str
    sha256: str


def _check_name(name: object, where: str) -> str:
    if not isinstance(name, str) or not _NAME.match(name):
        raise SecurityError(f"{where}: external controller name {name!r}: must match [A-Za-z0-9_.-]{{1,48}}")
    return name


def load_external(home: SecurityHome) -> dict[str, ExternalRecord]:
    """The registry of ``home`` (empty when the file does not exist).

    Raises :class:`~tanklab.errors.SecurityError` naming the file, the field and the rule for a
    malformed file.
    """
    path = registry_path(home)
    try:
        raw = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return {}
    try:
        data: Any = json.loads(raw)
    except json.JSONDecodeError as e:
        raise SecurityError(f"{path}: not JSON ({e.msg} at line {e.lineno})") from None
    if not isinstance(data, dict) or data.get("version") != FILE_VERSION:
        raise SecurityError(f"{path}: version: must be {FILE_VERSION}")
    entries = data.get("external", {})
    if not isinstance(entries, dict):
        raise SecurityError(f"{path}: external: must be an object of name -> record")
    out: dict[str, ExternalRecord] = {}
    for name, entry in entries.items():
        _check_name(name, f"{path}: external")
        where = f"{path}: external.{name}"
        if not isinstance(entry, dict) or set(entry) != {"role", "sha256"}:
            raise SecurityError(f"{where}: must be an object with role and sha256 only")
        if entry["role"] != Role.EXTERNAL.value:
            raise SecurityError(f"{where}.role: must be {Role.EXTERNAL.value}, got {entry['role']!r}")
        digest = entry["sha256"]
        if not isinstance(digest, str) or not _HEX.match(digest):
            raise SecurityError(f"{where}.sha256: must be 64 lower-case hex digits")
        out[name] = ExternalRecord(name, digest)
    return out


def _save(home: SecurityHome, records: Mapping[str, ExternalRecord]) -> None:
    body = {
        "version": FILE_VERSION,
        "external": {
            n: {"role": Role.EXTERNAL.value, "sha256": r.sha256} for n, r in sorted(records.items())
        },
    }
    write_private(registry_path(home), (json.dumps(body, indent=2) + "\n").encode("utf-8"))


def add_external(
    home: SecurityHome,
    name: str,
    *,
    hosts: Sequence[str] = DEFAULT_HOSTS,
    days: int = DEFAULT_DAYS,
    replace: bool = False,
) -> tuple[Path, Path]:
    """Issue external controller ``name``'s certificate from the site CA and record it in role
    External; returns (certificate DER, private key PEM).

    Refused (SecurityError, nothing written) for a bad name, an existing name without
    ``replace``, or a home without a PKI.
    """
    _check_name(name, "add-external")
    pki = home.pki
    if not (pki.ca_cert.is_file() and pki.ca_key.is_file()):
        raise SecurityError(f"{pki.root}: no CA; run `tankctl pki init --home {home.root}` first")
    records = load_external(home)
    if name in records and not replace:
        raise SecurityError(
            f"{registry_path(home)}: external controller {name!r} exists (use --replace to re-issue)"
        )
    cert, key = issue(pki, cert_name(name), application_uri(name), hosts=hosts, days=days)
    records[name] = ExternalRecord(name, hashlib.sha256(cert.read_bytes()).hexdigest())
    _save(home, records)
    return cert, key


def remove_external(home: SecurityHome, name: str) -> None:
    """Drop ``name`` from the registry (its certificate files stay; revoke them with
    ``tankctl pki revoke``). SecurityError for an unknown name."""
    records = load_external(home)
    if name not in records:
        raise SecurityError(f"{registry_path(home)}: no external controller {name!r}")
    del records[name]
    _save(home, records)


class ExternalIdentities:
    """The External certificate identities of a security home, for a server's user manager.

    :meth:`current` maps each registered certificate's DER to ``(external-NAME, Role.EXTERNAL)``;
    the registry is re-read when its file changes. A record whose certificate file is missing or
    differs from the pinned SHA-256 is left out (and logged once per reload); a malformed
    registry maps nobody (logged), it never stops the server.
    """

    def __init__(self, home: SecurityHome) -> None:
        self.home = home
        self._stamp: tuple[float, int] | None = None
        self._current: dict[bytes, tuple[str, Role]] = {}
        self._loaded = False

    def current(self) -> dict[bytes, tuple[str, Role]]:
        path = registry_path(self.home)
        try:
            st = path.stat()
            stamp: tuple[float, int] | None = (st.st_mtime, st.st_size)
        except FileNotFoundError:
            stamp = None
        if not self._loaded or stamp != self._stamp:
            self._stamp, self._loaded = stamp, True
            self._current = self._read()
        return self._current

    def _read(self) -> dict[bytes, tuple[str, Role]]:
        try:
            records = load_external(self.home)
        except SecurityError as e:
            log.error("external controllers refused: %s", e)
            return {}
        out: dict[bytes, tuple[str, Role]] = {}
        for name, rec in records.items():
            path = self.home.pki.cert_path(cert_name(name))
            try:
                der = path.read_bytes()
            except OSError:
                log.error("external controller %s: no certificate %s", name, path)
                continue
            if hashlib.sha256(der).hexdigest() != rec.sha256:
                log.error("external controller %s: %s is not the certificate recorded", name, path)
                continue
            out[der] = (cert_name(name), Role.EXTERNAL)
        return out
