"""Atomic file writes: a temporary file beside the target, then os.replace."""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path


def _landing(path: Path) -> Path:
    """The file a write to `path` replaces: a symbolic link's target, so the link stays a
    link (as `>` in a shell writes through it); OSError ELOOP for a link loop."""
    if not path.is_symlink():
        return path
    try:
        target = path.resolve()
    except RuntimeError:  # a loop, on Python < 3.13
        target = path
    if target.is_symlink():
        raise OSError(errno.ELOOP, os.strerror(errno.ELOOP), str(path))
    return target


def atomic_write(path: str | os.PathLike[str], data: bytes | str) -> Path:
    """Write `data` to `path` atomically, with the permissions the umask gives new files.
    Readers see the old file or the new one, never a part; a failed write leaves no temp.
    A symbolic link is written through: its target is replaced, the link stays."""
    path = Path(path)
    target = _landing(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, str):
        data = data.encode("utf-8")
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    except OSError as err:
        Path(tmp).unlink(missing_ok=True)
        if err.errno is None:
            raise
        # name the user's path, not the temporary file beside it
        raise type(err)(err.errno, err.strerror, str(path)) from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
