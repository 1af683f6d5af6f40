"""Atomic file writes: a crash at any moment leaves the old file or the new one."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes,
                       durable: bool = True) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same folder, then rename.

    Either way a reader, or a restart after the writer was killed at any moment, finds the
    old content or the new one, never a mix.

    Args:
        path: Destination file; its folder is created if missing.
        data: The complete new content.
        durable: fsync the file before the rename and the folder after it, so that the new
            content also survives a power cut (about 0.5 ms per call on the project's VMs).
            False leaves the flush to the kernel (seconds later; ext4 orders the data of a
            file replaced by rename before the rename itself): for the per-cycle resume
            states, which sit on the control cycle's critical path and are re-synced at
            shutdown with :func:`sync_file` (docs/performance.md).
    """
    dest = Path(path)
    dest.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".tmp", dir=dest.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            if durable:
                os.fsync(f.fileno())
        os.replace(tmp, dest)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    if durable:
        _fsync(dest.parent)


def sync_file(path: str | os.PathLike[str] | None) -> None:
    """fsync ``path`` and its folder, if the file exists: makes a non-durable write durable."""
    if path is None:
        return
    try:
        _fsync(path)
    except FileNotFoundError:
        return
    _fsync(Path(path).parent)


def _fsync(path: str | os.PathLike[str]) -> None:
    """fsync a file or a folder by its path."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
