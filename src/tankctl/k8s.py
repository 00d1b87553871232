"""Kubernetes Secrets for ``deploy/kubernetes/`` from a tanklab security home.

The manifests (docs/kubernetes.md) never hold key material: every tier's pod projects its
security home at ``/etc/tanklab`` from Secrets, laid out as ``tankctl pki containers`` lays out a
container home for docker compose (decision 0021)::

    /etc/tanklab/pki/own/*.der            every application certificate  <- Secret P-pki
    /etc/tanklab/pki/trusted/*.der        the trust list (the CA's copy)  <- Secret P-pki
    /etc/tanklab/pki/crl/ca.crl.{der,pem} the CA's revocation list        <- Secret P-pki
    /etc/tanklab/pki/private/ID.pem       the pod's own key, only it      <- Secret P-key-ID
    /etc/tanklab/users.json               the users file (not the HMI)    <- Secret P-users

``P`` is the name prefix (default ``tanklab``), ``ID`` the identity whose key a workload holds
(:data:`WORKLOAD_IDENTITY`: each tier its own, the HMI the ``cli`` certificate it opens its users'
sessions with). A file ``DIR/NAME`` of the PKI is the key ``DIR.NAME`` of ``P-pki`` (Secret keys
cannot hold a ``/``); the manifests' projected volumes map each key back to its path. The CA's
private key is never read: a tier verifies peers and signs nothing.

:func:`read_home` is the I/O shell (it reads files and names the first one missing);
:func:`secret_manifests` and :func:`render` are pure.
"""

from __future__ import annotations

import base64
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from tanklab.errors import TanklabError
from tanklab_io.home import SecurityHome
from tanklab_io.pki import IDENTITIES

__all__ = [
    "DEFAULT_PREFIX",
    "PUBLIC_FILES",
    "WORKLOAD_IDENTITY",
    "K8sError",
    "SiteSecrets",
    "check_name",
    "public_key",
    "read_home",
    "render",
    "secret_manifests",
]

DEFAULT_PREFIX = "tanklab"
"""Default name prefix of the Secrets (the manifests reference ``tanklab-pki`` and so on)."""

WORKLOAD_IDENTITY: Mapping[str, str] = {
    "plant": "plant",
    "plc": "plc",
    "supervisor": "supervisor",
    "historian": "historian",
    "hmi": "cli",
}
"""Workload (Deployment, or container of a fleet's site pod) -> the identity whose key it mounts."""

PUBLIC_FILES: tuple[str, ...] = (
    *(f"own/{name}.der" for name in IDENTITIES),
    "trusted/tanklab-ca.der",
    "crl/ca.crl.der",
    "crl/ca.crl.pem",
)
"""The PKI files (relative to ``pki/``) every pod mounts; a home without one is incomplete."""

_DNS_LABEL = re.compile(r"^[a-z0-9]([-a-z0-9]*[a-z0-9])?$")


class K8sError(TanklabError):
    """The Secrets cannot be rendered (incomplete home, invalid name); the message is one line."""


@dataclass(frozen=True)
class SiteSecrets:
    """What the Secrets carry, read from a home: file bytes by Secret key.

    ``public``: ``DIR.NAME`` -> bytes for every file of ``pki/own``, ``pki/trusted`` and
    ``pki/crl`` (at least :data:`PUBLIC_FILES`); ``keys``: identity -> its private key (PEM);
    ``users``: the users file (JSON). ``extra``: public keys beyond :data:`PUBLIC_FILES` (e.g. a
    client certificate trusted with ``tankctl pki trust``), which the manifests do not project.
    """

    public: Mapping[str, bytes]
    keys: Mapping[str, bytes]
    users: bytes
    extra: tuple[str, ...] = field(default=())


def public_key(relative: str) -> str:
    """Secret key of the PKI file ``relative`` (``own/plant.der`` -> ``own.plant.der``)."""
    folder, name = relative.split("/", 1)
    return f"{folder}.{name}"


def check_name(what: str, value: str, max_len: int = 63) -> str:
    """``value`` if it is a DNS-1123 label of at most ``max_len`` characters, else K8sError."""
    if len(value) > max_len or not _DNS_LABEL.match(value):
        raise K8sError(
            f"{what} {value!r}: must be lower-case letters, digits and '-', starting and ending "
            f"with a letter or digit, at most {max_len} characters (a DNS-1123 label)"
        )
    return value


def _read(path: Path, hint: str) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise K8sError(f"{path}: missing; {hint}") from None
    except OSError as e:
        raise K8sError(f"{path}: cannot read: {e.strerror or e}") from None


def read_home(
    home: SecurityHome, identities: Sequence[str] = tuple(WORKLOAD_IDENTITY.values())
) -> SiteSecrets:
    """Read the certificates, trust list, CRL, users file and ``identities``' keys of ``home``.

    Raises
    ------
    K8sError
        Naming the first missing file (the home is incomplete) or one that cannot be read.
    """
    pki = home.pki
    if not home.root.is_dir():
        raise K8sError(f"{home.root}: no security home there (run `tankctl pki init --home {home.root}`)")
    incomplete = f"the security home is incomplete (run `tankctl pki init --home {home.root}`)"
    public = {public_key(rel): _read(pki.root / rel, incomplete) for rel in PUBLIC_FILES}
    extra: list[str] = []
    for folder in ("own", "trusted", "crl"):
        for path in sorted((pki.root / folder).iterdir()):
            key = public_key(f"{folder}/{path.name}")
            if path.is_file() and key not in public:
                public[key] = _read(path, incomplete)
                extra.append(key)
    keys = {name: _read(pki.key_path(name), incomplete) for name in dict.fromkeys(identities)}
    users = _read(
        home.users_file, f"add a user first (`tankctl user add NAME --role ROLE --home {home.root}`)"
    )
    return SiteSecrets(public, keys, users, tuple(extra))


def _secret(name: str, namespace: str | None, component: str, data: Mapping[str, bytes]) -> dict[str, Any]:
    metadata: dict[str, Any] = {"name": name}
    if namespace is not None:
        metadata["namespace"] = namespace
    metadata["labels"] = {
        "app.kubernetes.io/name": "tanklab",
        "app.kubernetes.io/part-of": "tanklab",
        "app.kubernetes.io/component": component,
    }
    return {
        "apiVersion": "v1",
        "kind": "Secret",
        "metadata": metadata,
        "type": "Opaque",
        "data": {key: base64.b64encode(value).decode("ascii") for key, value in sorted(data.items())},
    }


def secret_manifests(
    secrets: SiteSecrets, *, namespace: str | None = None, prefix: str = DEFAULT_PREFIX
) -> list[dict[str, Any]]:
    """The Secret objects: ``P-pki``, ``P-users`` and one ``P-key-ID`` per identity.

    Parameters
    ----------
    secrets : what :func:`read_home` read.
    namespace : ``metadata.namespace`` of each Secret (None: left to ``kubectl -n`` / kustomize).
    prefix : the names' prefix (a DNS-1123 label).

    Raises
    ------
    K8sError
        The namespace or the prefix is not a DNS-1123 label.
    """
    if namespace is not None:
        check_name("--namespace", namespace)
    check_name("--name-prefix", prefix, 63 - len("-key-supervisor"))
    out = [
        _secret(f"{prefix}-pki", namespace, "pki", secrets.public),
        _secret(f"{prefix}-users", namespace, "users", {"users.json": secrets.users}),
    ]
    out += [
        _secret(f"{prefix}-key-{name}", namespace, "key", {f"{name}.pem": key})
        for name, key in secrets.keys.items()
    ]
    return out


def render(manifests: Sequence[Mapping[str, Any]]) -> str:
    """The objects as one YAML stream (``---`` between documents)."""
    return yaml.safe_dump_all([dict(m) for m in manifests], sort_keys=False, explicit_start=True)
