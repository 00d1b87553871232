"""Site identity: which site a tier runs, as a name and a digest of its config.

Every tier publishes ``<Tier>.Identity.SiteName``, ``ConfigDigest`` and ``Config`` (see
:mod:`tanklab.tags`), so an operator command can tell whether the site config it was given is
the one the stack runs, and can take the site from the stack when it was given none.

The digest is ``sha256`` of the canonical JSON of the validated site model (pydantic's
``model_dump(mode="json")``: every default filled in, every number in its field's type), with
sorted keys and no whitespace. So two YAML files that differ only in key order, comments,
formatting, ``1e-3`` versus ``0.001`` or a default written out give the same digest; any
parameter that changes the model, the program or the controller gives another.

Left out, because they say where and how a copy of the site runs rather than what it is, and
differ between two correct views of one stack (``tankctl up`` on a base port, Docker's
``0.0.0.0`` binds, the host CLI's ``127.0.0.1``): ``endpoints``, ``stack``, ``historian``
(where the history goes and how long it stays), ``plant.state_file`` and ``plc.retain_file``.
Decision 0020 records the choice.

Pure: no I/O, no clock.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from typing import Any

from tanklab.config import ConfigError, SiteConfig, site_from_mapping

DEPLOYMENT_FIELDS: dict[str, Any] = {
    "endpoints": True,
    "stack": True,
    "historian": True,
    "plant": {"state_file"},
    "plc": {"retain_file"},
}
"""Fields of a :class:`SiteConfig` outside the digest (pydantic ``exclude`` form)."""

SHORT_DIGEST_HEX = 16
"""Hex digits of the digest shown in messages (64 bits: two different configs of one site
showing the same short digest by chance is not a practical concern); nodes hold all 64."""


def site_document(site: SiteConfig) -> dict[str, Any]:
    """The part of ``site`` the digest covers, as plain JSON data (defaults filled in)."""
    return site.model_dump(mode="json", exclude=DEPLOYMENT_FIELDS)


def canonical_json(site: SiteConfig) -> str:
    """``site_document(site)`` as canonical JSON: sorted keys, no whitespace, UTF-8 text."""
    return json.dumps(site_document(site), sort_keys=True, separators=(",", ":"), ensure_ascii=False)


@dataclass(frozen=True)
class SiteIdentity:
    """A site's name and the sha256 (64 hex digits) of its canonical config."""

    name: str
    digest: str

    @classmethod
    def of(cls, site: SiteConfig) -> SiteIdentity:
        """The identity of a validated site."""
        return cls(site.name, config_digest(site))

    @property
    def short(self) -> str:
        """The first :data:`SHORT_DIGEST_HEX` hex digits of the digest."""
        return self.digest[:SHORT_DIGEST_HEX]

    def __str__(self) -> str:
        return f"{self.name} (config {self.short})"


def config_digest(site: SiteConfig) -> str:
    """sha256 of :func:`canonical_json`, 64 lowercase hex digits."""
    return hashlib.sha256(canonical_json(site).encode("utf-8")).hexdigest()


def site_from_json(text: str, source: str) -> SiteConfig:
    """The site a tier published in ``<Tier>.Identity.Config`` (default endpoints and stack).

    Raises
    ------
    ConfigError
        Not JSON, or not a valid site (one line naming ``source``).
    """
    try:
        data = json.loads(text)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{source}: not a JSON site config ({e})") from None
    return site_from_mapping(data, source)
