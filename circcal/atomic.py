"""Atomic writes of one file: a reader sees the old file or the complete new one, never a half-written one. (A
command's outputs together, folders included: :mod:`circcal.outputs`.)"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same folder, flushed to disk, and a rename.

    A reader (and a crash, a full disk, a quota) sees the old file or the whole new one. The temporary file is removed
    when the write fails; the error propagates.

    Parameters
    ----------
    path : str or Path
    text : str
        Written UTF-8.

    Raises
    ------
    OSError
        The write failed (the old file, if any, is intact).
    """
    write_bytes(path, text.encode())


def write_bytes(path: str | Path, data: bytes) -> None:
    """:func:`write_text` for bytes (an image, a pickle). Missing parent folders are made.

    Parameters
    ----------
    path : str or Path
    data : bytes

    Raises
    ------
    OSError
        The write failed (the old file, if any, is intact).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, path.stat().st_mode & 0o7777 if path.exists() else _NEW_FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _read_umask() -> int:
    """The process's umask (read by setting and restoring it: there is no getter; done once, at import)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


#: A new file gets the mode a plain ``open(path, "w")`` would give it (mkstemp's own is 0600).
_NEW_FILE_MODE = 0o666 & ~_read_umask()
