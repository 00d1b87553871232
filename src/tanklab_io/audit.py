"""Append-only audit trail of a tier: every write, call and failed session activation.

One JSON object per line in ``<audit dir>/<tier>.log``::

    {"time": "2026-11-22T05:40:01.123456+00:00", "tier": "plc", "action": "write",
     "user": "alice", "role": "Operator", "node": "PLC.LIC1.SP", "old": 0.1, "new": 0.15,
     "status": "Good"}

``action`` is ``write``, ``call`` or ``activate`` (a refused session activation: ``node`` is
empty, ``new`` names the identity that was tried, ``status`` the reason). The file is kept
open with ``O_APPEND`` and each record is one ``write``, so records are never interleaved or
rewritten, and it is created 0600: it names users. The OPC UA side (events on the server object) is
:class:`tanklab_io.ua_security.AuditEvents`; it subscribes to :meth:`AuditLog.record` through
``listeners``.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AuditRecord:
    """One audited action."""

    time: str
    tier: str
    action: str
    user: str
    role: str
    node: str
    old: Any
    new: Any
    status: str

    def line(self) -> str:
        """The record as one JSON line (non-finite floats as strings: JSON has none)."""
        return json.dumps({k: _jsonable(v) for k, v in asdict(self).items()}, separators=(",", ":"))


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, str | int | float | bool) or value is None:
        return value
    return repr(value)


class AuditLog:
    """The audit trail of one tier (``directory/<tier>.log``), append-only."""

    def __init__(self, directory: Path, tier: str) -> None:
        self.tier = tier
        self.path = Path(directory) / f"{tier}.log"
        self.path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        self.listeners: list[Callable[[AuditRecord], None]] = []
        self.records = 0
        self._fd: int | None = None

    def close(self) -> None:
        """Close the file (the next record reopens it)."""
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)

    def record(
        self,
        action: str,
        *,
        user: str,
        role: str,
        node: str = "",
        old: Any = None,
        new: Any = None,
        status: str,
    ) -> AuditRecord:
        """Append one record and hand it to the listeners; returns it."""
        rec = AuditRecord(
            time=datetime.now(UTC).isoformat(),
            tier=self.tier,
            action=action,
            user=user,
            role=role,
            node=node,
            old=old,
            new=new,
            status=status,
        )
        data = (rec.line() + "\n").encode()
        try:
            if self._fd is None:
                self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
            os.write(self._fd, data)  # one write(2) per record: whole lines, never interleaved
        except OSError as e:
            # The audit trail failing must not take the control tier down; say so loudly.
            log.error("audit log %s: cannot append: %s", self.path, e)
            self.close()
        self.records += 1
        for listener in self.listeners:
            listener(rec)
        return rec


def read_audit(path: Path) -> list[dict[str, Any]]:
    """All records of an audit file (for tests and ``tankctl`` tooling)."""
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
