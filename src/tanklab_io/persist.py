"""Durable state files: the plant's checkpoint and the PLC's retentive memory.

:func:`write_atomic` writes a file so that a crash (SIGKILL, power loss) at any moment leaves
either the previous complete copy or the new complete copy, never a torn one:

1. write the new text to ``<name>.tmp`` in the same directory and ``fsync`` it (the data is on
   disk before the name points at it);
2. ``os.replace`` it over ``<name>`` (atomic on POSIX: readers see the old or the new file);
3. ``fsync`` the directory (the rename itself survives a power loss).

Only the tiers' runtimes call this (pure cores return the data, the runtimes store it).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any


def write_atomic(path: Path, text: str) -> None:
    """Replace ``path`` by ``text`` atomically and durably (temp file, fsync, rename, fsync dir).

    Raises
    ------
    OSError
        The directory cannot be created or written (the previous copy, if any, stays).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        data = text.encode("utf-8")
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, path)
    try:
        dir_fd = os.open(path.parent, os.O_RDONLY)
    except OSError:  # a platform without directory handles: the rename is still atomic
        return
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def write_json_atomic(path: Path, data: Any) -> None:
    """:func:`write_atomic` of ``json.dumps(data)``."""
    write_atomic(path, json.dumps(data))


def read_json(path: Path) -> Any:
    """The JSON value stored in ``path`` (``OSError``, ``ValueError`` on a missing or broken file)."""
    return json.loads(path.read_text(encoding="utf-8"))
