"""Committing a command's staged outputs (the rules are :mod:`circcal.outputs`'s docstring): every staged output
renamed into place with SIGINT and SIGTERM held back, a folder swapped with ``renameat2(RENAME_EXCHANGE)`` where the
kernel has it, a journal written first so that :func:`recover` finishes a commit a killed process left half done,
and the staging places of dead processes removed.
"""

from __future__ import annotations

import ctypes
import errno
import glob
import hashlib
import json
import os
import shutil
import signal
import threading
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["MARKER", "RECORD", "iter_staging", "recover", "sha256_file", "written_by_circcal"]

MARKER = ".circcal-output.json"
"""The manifest circcal writes into every folder output: its kind and every file it wrote with its SHA-256."""
RECORD = ".circcal.files.json"
"""Beside circcal's file outputs, one per folder: the name and SHA-256 of every file circcal wrote there, so that a
later run may replace those (unchanged since) and nothing else."""
_STAGE = ".circcal-"
"""Staging places, old folders and journals carry this in their (hidden) names."""
_JOURNAL_PREFIX = ".circcal-commit-"


def _read_marker(folder: Path) -> dict[str, Any] | None:
    try:
        doc = json.loads((folder / MARKER).read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("files"), dict) else None


def sha256_file(path: Path) -> str:
    """The SHA-256 of a file's bytes, hex.

    Parameters
    ----------
    path : Path

    Returns
    -------
    str
    """
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _read_record(folder: Path) -> dict[str, str]:
    try:
        doc = json.loads((folder / RECORD).read_text())
    except (OSError, ValueError):
        return {}
    files = doc.get("files") if isinstance(doc, dict) else None
    return {k: v for k, v in files.items() if isinstance(v, str)} if isinstance(files, dict) else {}


def written_by_circcal(path: Path) -> bool:
    """Whether ``path`` is a file circcal wrote, unchanged since (its folder's :data:`RECORD` lists it).

    Parameters
    ----------
    path : Path
        A regular file (symlinks followed by the caller).

    Returns
    -------
    bool
    """
    recorded = _read_record(path.parent).get(path.name)
    return recorded is not None and recorded == sha256_file(path)


def _record(written: list[tuple[Path, str]]) -> None:
    """Add ``(file, SHA-256)`` to each file's folder's :data:`RECORD` (entries whose file is gone dropped), written
    through a staging name and a rename. Best effort: a record that cannot be written is warned about (the file then
    counts as the user's, never replaced: the safe side); two runs recording in one folder at one instant may
    lose one's entry (the same)."""
    for folder in dict.fromkeys(f.parent for f, _ in written):
        _remove_stale(folder, RECORD)  # a killed run's half-written record
        doc = {k: v for k, v in _read_record(folder).items() if (folder / k).is_file()}
        doc.update({f.name: h for f, h in written if f.parent == folder})
        tmp = folder / f".{RECORD}{_STAGE}{os.getpid()}-{os.urandom(4).hex()}"
        try:
            with open(tmp, "w") as fh:
                fh.write(json.dumps({"circcal": "files", "files": doc}, indent=1, sort_keys=True) + "\n")
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, folder / RECORD)
        except OSError as exc:
            _unlink(tmp)
            warnings.warn(
                f"{folder / RECORD}: not written ({exc.strerror or exc}); a later run will not replace "
                "the files circcal wrote there",
                RuntimeWarning,
                stacklevel=3,
            )


@dataclass
class _Output:
    shown: Path  # as the user gave it
    final: Path  # symlinks followed
    option: str
    kind: str | None  # None: a file; else the folder's kind
    staging: Path = field(default=Path())
    old: Path | None = None
    sha256: str = ""  # a file's, once staged in full


def _remove_stale(parent: Path, name: str) -> None:
    """Remove the staging places of ``name`` in ``parent`` whose process is gone (a killed run's leftovers: their
    names hold the pid that made them; a live process's are never touched)."""
    for p in parent.glob(f".{glob.escape(name)}{_STAGE}*"):
        rest = p.name[1 + len(name) + len(_STAGE) :]
        pid = rest.split("-", 1)[0]
        if not pid.isdigit() or _alive(int(pid)):
            continue  # an earlier folder a killed commit set aside (recover() handles it), or a live run's
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            _unlink(p)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, another user's
        return True
    return True


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_tree(folder: Path) -> None:
    for root, _, files in os.walk(folder):
        for name in files:
            _fsync_file(Path(root) / name)


def _unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _read_umask()


class _signals_held:
    """Hold SIGINT and SIGTERM back in the block and deliver them after it (main thread only: elsewhere Python
    runs no signal handler). The handlers are swapped for a recorder rather than the signals masked, because a
    signal that arrived just before the block may still be waiting for the interpreter to run its handler."""

    def __enter__(self) -> None:
        self._got: list[int] = []
        self._old: dict[int, object] = {}
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, lambda signum, frame: self._got.append(signum))

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]
        for sig in dict.fromkeys(self._got):
            handler = self._old[sig]
            if callable(handler):
                handler(sig, None)
            elif handler == signal.SIG_DFL and sig == signal.SIGINT:
                raise KeyboardInterrupt
            elif handler == signal.SIG_DFL:
                os.kill(os.getpid(), sig)


def _write_journals(outputs: list[_Output], commit_id: str) -> list[Path]:
    """The commit's steps, written (and synced) beside every output: any of them lets :func:`recover` finish."""
    steps = [
        {
            "final": os.fsencode(o.final).hex(),
            "staging": os.fsencode(o.staging).hex(),
            "folder": o.kind,
            "sha256": o.sha256,
        }
        for o in outputs
    ]
    text = json.dumps({"commit": commit_id, "steps": steps}) + "\n"
    paths = []
    for d in dict.fromkeys(o.staging.parent for o in outputs):
        p = d / f"{_JOURNAL_PREFIX}{commit_id}.json"
        with open(p, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        paths.append(p)
    return paths


_RENAME_EXCHANGE = 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False where the system lacks it."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd = -100
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.EPERM):
        return False
    raise OSError(err, os.strerror(err), os.fsdecode(b))


def _rename(src: Path, dst: Path) -> None:
    """One rename of the commit (a seam for the tests that interrupt at each one)."""
    os.replace(src, dst)


def _apply(outputs: list[_Output], commit_id: str) -> None:
    for out in outputs:
        out.final.parent.mkdir(parents=True, exist_ok=True)
        if out.kind is None or not out.final.exists():
            _rename(out.staging, out.final)
        elif _exchange(out.staging, out.final):
            out.old = out.staging  # the earlier folder now lies at the staging name
        else:
            out.old = out.final.with_name(f".{out.final.name}{_STAGE}old-{commit_id}")
            _rename(out.final, out.old)
            _rename(out.staging, out.final)


def _marker_commit(folder: Path) -> str | None:
    doc = _read_marker(folder) if folder.is_dir() else None
    return None if doc is None else doc.get("commit")


def recover(folder: Path) -> list[Path]:
    """Finish the commits a killed circcal process left half done in ``folder`` (their journals name the steps).

    The staged outputs still waiting are moved into place, the earlier folders they replace removed. A journal whose
    staging places are all gone is removed.

    Parameters
    ----------
    folder : Path

    Returns
    -------
    list of Path
        The outputs it put in place.
    """
    done: list[Path] = []
    try:
        journals = sorted(Path(folder).glob(f"{_JOURNAL_PREFIX}*.json"))
    except OSError:
        return done
    for j in journals:
        try:
            doc = json.loads(j.read_text())
            commit_id = doc["commit"]
            steps = [
                (
                    Path(os.fsdecode(bytes.fromhex(s["final"]))),
                    Path(os.fsdecode(bytes.fromhex(s["staging"]))),
                    s["folder"],
                    str(s.get("sha256", "")),
                )
                for s in doc["steps"]
            ]
        except (OSError, ValueError, KeyError, TypeError):
            continue  # not one of ours, or unreadable: left alone
        written = []
        for final, staging, kind, sha in steps:
            if kind is None:
                if staging.is_file():
                    final.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(staging, final)
                    done.append(final)
                if sha and final.is_file() and sha256_file(final) == sha:
                    written.append((final, sha))
                continue
            old = final.with_name(f".{final.name}{_STAGE}old-{commit_id}")
            if _marker_commit(final) == commit_id:  # in place: only the earlier folder may be left
                for leftover in (staging, old):
                    if leftover.is_dir() and _marker_commit(leftover) != commit_id:
                        shutil.rmtree(leftover, ignore_errors=True)
                continue
            if _marker_commit(staging) == commit_id:
                if final.exists():
                    os.replace(final, old)
                final.parent.mkdir(parents=True, exist_ok=True)
                os.replace(staging, final)
                shutil.rmtree(old, ignore_errors=True)
                done.append(final)
        if written:
            _record(written)
        for d in {s.parent for _, s, _, _ in steps}:
            _unlink(d / j.name)
        _unlink(j)
    return done


def iter_staging(folder: Path) -> Iterator[Path]:
    """circcal's staging places left in ``folder`` by a killed process (for a clean-up or a test).

    Parameters
    ----------
    folder : Path

    Yields
    ------
    Path
    """
    yield from (p for p in Path(folder).iterdir() if p.name.startswith(".") and _STAGE in p.name)
