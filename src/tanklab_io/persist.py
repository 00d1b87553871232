"""Durable state files: the plant's checkpoint and the PLC's retentive memory.

:func:`write_bytes_atomic` (and :func:`write_atomic` for text) writes a file so that a crash
(SIGKILL, power loss) at any moment leaves either the previous complete copy or the new complete
copy, never a torn one. It is the one writer of every file tanklab keeps: these state files, the
PKI's certificates and keys (``pki.write_file``), the users file and credentials
(``users.write_private``) and the containers' copies:

1. write the new bytes to a temporary file of its own in the same directory (created with the
   final mode, ``O_EXCL``) and ``fsync`` it (the data is on disk before the name points at it);
2. ``os.replace`` it over ``<name>`` (atomic on POSIX: readers see the old or the new file);
3. ``fsync`` the directory (the rename itself survives a power loss).

Only I/O shells call this (pure cores return the data, the runtimes store it).
"""

from __future__ import annotations

import json
import os
import secrets
from pathlib import Path
from typing import Any


def write_bytes_atomic(
    path: Path,
    data: bytes,
    *,
    mode: int = 0o600,
    owner: tuple[int, int] | None = None,
    dir_mode: int = 0o777,
) -> None:
    """Replace ``path`` by ``data`` atomically and durably: the one writer of every file tanklab keeps.

    A new temporary file next to ``path`` is created with ``mode`` (never wider, even briefly;
    ``O_EXCL`` and a per-process name, so two writers never share it), written and fsynced, given
    ``mode`` exactly (the umask may have narrowed it) and to ``owner`` (uid, gid) when one is
    given, renamed over ``path``, and the directory is fsynced so the rename survives a power
    loss. A missing parent directory is created with ``dir_mode`` (less the umask).

    Raises
    ------
    OSError
        The directory cannot be created or written; the previous copy, if any, stays and the
        temporary file is removed.
    """
    path.parent.mkdir(mode=dir_mode, parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    try:
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
            os.fsync(fd)
        finally:
            os.close(fd)
        os.chmod(tmp, mode)
        if owner is not None and (os.stat(tmp).st_uid, os.stat(tmp).st_gid) != owner:
            os.chown(tmp, *owner)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:
        dir_fd = os.open(path.parent, os.O_RDONLY)
    except OSError:  # a platform without directory handles: the rename is still atomic
        return
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def write_atomic(path: Path, text: str) -> None:
    """:func:`write_bytes_atomic` of ``text`` in UTF-8, as a 0600 file."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: Path, data: Any) -> None:
    """:func:`write_atomic` of ``json.dumps(data)``."""
    write_atomic(path, json.dumps(data))


def read_json(path: Path) -> Any:
    """The JSON value stored in ``path`` (``OSError``, ``ValueError`` on a missing or broken file)."""
    return json.loads(path.read_text(encoding="utf-8"))
