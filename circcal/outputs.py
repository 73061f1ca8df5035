"""A command's outputs as one unit: checked before the work, staged beside their final places, committed together.

Rules (every ``circcal`` command that writes follows them):

- An output never deletes or replaces anything circcal did not create. A file output may replace a file circcal
  wrote, unchanged since (its folder's :data:`~circcal.commit.RECORD` lists every file circcal wrote there with its
  SHA-256), or an empty file; not any other file, nor one of the command's inputs, a folder, a device, a fifo or a
  socket. A symlink is written through
  (its target is replaced, the link stays). A folder output (``--report DIR``, ``--overlay DIR``) is new, empty, or
  an earlier circcal folder of the same kind, recognised by the manifest :data:`~circcal.commit.MARKER` that lists every file
  circcal wrote there with its SHA-256: a folder holding anything else, or a file changed since, is refused. A folder
  output may not hold an input, another output, or the working folder. Each refusal is an
  :class:`~circcal.errors.InputError` naming the path, raised when the output is planned, before any work.
- A file output that something else writes (or changes) during the work is left as it is at the commit: the run's
  output goes beside it, ``NAME.new-K.SUFFIX``, with a warning naming both.
- Everything is written into staging places beside the final ones (hidden names starting ``.`` and holding
  ``.circcal-``); nothing final is touched until :meth:`Outputs.commit`. A failure or an interruption before it
  removes the staging places and leaves every earlier output as it was.
- The commit (:mod:`circcal.commit`) renames every staged output into place with SIGINT and SIGTERM held back (delivered right after): a
  folder is swapped with ``renameat2(RENAME_EXCHANGE)`` where the kernel has it (one atomic step), else with two
  renames. A journal written first, beside every output, lists the steps; should the process be killed
  (``SIGKILL``, power) between two renames, :func:`~circcal.commit.recover` (called by every later command that plans an output
  in that folder) finishes them, so the outputs of one command end all old or all new.

Example
-------
>>> with Outputs(inputs=images) as out:                             # doctest: +SKIP
...     model = out.file(Path("model.json"), "--out")
...     report = out.folder(Path("report"), "--report", kind="report")
...     ...                                                          # the work: write into model and report
...     out.commit()
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import stat
import tempfile
import warnings
from collections.abc import Iterable
from pathlib import Path

from circcal.commit import (
    _STAGE,
    _UMASK,
    MARKER,
    _apply,
    _fsync_file,
    _fsync_tree,
    _Output,
    _read_marker,
    _record,
    _remove_stale,
    _signals_held,
    _unlink,
    _write_journals,
    recover,
    sha256_file,
    written_by_circcal,
)
from circcal.errors import InputError
from circcal.pathnames import display_name

__all__ = [
    "Outputs",
    "check_folder_output",
    "check_writable_place",
    "folder_manifest",
    "write_manifest",
]


#: Errors of a full disk or quota while outputs are written (named by the output, not by a staging path).
_FULL = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}


def _display(path: Path | str) -> str:
    return display_name(path)


def _resolve(path: Path, option: str) -> Path:
    """``path`` with every symlink followed (a dangling link: its target, which the output then creates)."""
    try:
        return Path(os.path.realpath(path, strict=False))
    except OSError as exc:  # a link loop
        raise InputError(f"{option} {_display(path)}: cannot follow the link ({exc.strerror or exc})") from None


def _existing_ancestor(path: Path) -> Path:
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    return parent


def check_writable_place(path: Path, option: str) -> Path:
    """The nearest existing folder above ``path``, checked writable (permissions, a read-only mount); the staging place
    made in it next is the final proof.

    Parameters
    ----------
    path : Path
        The output.
    option : str
        Names it in messages (e.g. ``"--out"``).

    Returns
    -------
    Path
        That folder.

    Raises
    ------
    InputError
        Naming the path.
    """
    parent = _existing_ancestor(path)
    if not parent.is_dir():
        raise InputError(f"{option} {_display(path)}: {_display(parent)} is not a folder")
    read_only = hasattr(os, "statvfs") and bool(os.statvfs(parent).f_flag & getattr(os, "ST_RDONLY", 1))
    if read_only or not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(
            f"{option} {_display(path)}: folder {_display(parent)} is not writable ("
            f"{'a read-only file system' if read_only else 'permission denied'})"
        )
    return parent


def _kind_of(mode: int) -> str | None:
    """What a non-regular file is, in words (None for a regular file)."""
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a fifo"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def folder_manifest(folder: Path) -> dict[str, str]:
    """Every file under ``folder``, the marker left out.

    Parameters
    ----------
    folder : Path

    Returns
    -------
    dict of str to str
        Relative path -> SHA-256.

    Raises
    ------
    InputError
        An entry that is neither a file nor a folder (a link, a device): circcal writes none.
    """
    out: dict[str, str] = {}
    for root, dirs, files in os.walk(folder):
        for name in sorted(dirs + files):
            p = Path(root) / name
            if p.is_symlink() or not (p.is_file() or p.is_dir()):
                raise InputError(
                    f"{_display(p)} is {'a link' if p.is_symlink() else 'not a file'}: circcal writes none"
                )
        for name in files:
            p = Path(root) / name
            rel = p.relative_to(folder).as_posix()
            if rel != MARKER:
                out[rel] = sha256_file(p)
    return out


def write_manifest(folder: Path, kind: str, commit_id: str = "") -> None:
    """Write :data:`~circcal.commit.MARKER` into ``folder``: its ``kind`` and :func:`folder_manifest`.

    Parameters
    ----------
    folder : Path
    kind : str
        ``"report"``, ``"overlays"``, ...
    commit_id : str
        The commit that writes it.

    Raises
    ------
    InputError
        As :func:`folder_manifest`.
    """
    doc = {"circcal": kind, "commit": commit_id, "files": folder_manifest(folder)}
    (folder / MARKER).write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")


def check_folder_output(path: Path, kind: str, option: str, shown: Path | None = None) -> str:
    """Refuse a folder output that is not new, empty, or an earlier intact circcal folder of ``kind``.

    Parameters
    ----------
    path : Path
    kind : str
        ``"report"``, ``"overlays"``, ...
    option : str
        Names it in messages.
    shown : Path or None
        The path as the user gave it (default ``path``).

    Returns
    -------
    str
        How it stands: ``"new"``, ``"empty"``, ``"earlier"``.

    Raises
    ------
    InputError
        Naming the folder (as ``shown``) and the first foreign entry.
    """
    shown = path if shown is None else shown
    if not path.exists():
        return "new"
    if not path.is_dir():
        raise InputError(f"{option} {_display(shown)}: {_kind_of(path.stat().st_mode) or 'a file'}, not a folder")
    entries = sorted(os.listdir(path))
    if not entries:
        return "empty"
    marker = _read_marker(path)
    why = None
    if marker is None:
        listed = ", ".join(_display(e) for e in entries[:3]) + (", ..." if len(entries) > 3 else "")
        why = f"it holds files circcal did not write ({listed})"
    elif marker.get("circcal") != kind:
        why = f"it is a circcal {marker.get('circcal')!r} folder, not a {kind!r} folder"
    else:
        try:
            now = folder_manifest(path)
        except InputError as exc:
            why = str(exc)
        else:
            extra = sorted(set(now) - set(marker["files"]))
            changed = sorted(k for k in now if k in marker["files"] and marker["files"][k] != now[k])
            if extra:
                why = f"it holds files circcal did not write there ({_display(extra[0])}" + (
                    f" and {len(extra) - 1} more)" if len(extra) > 1 else ")"
                )
            elif changed:
                why = f"{_display(changed[0])} was changed since circcal wrote it"
    if why is not None:
        raise InputError(
            f"{option} {_display(shown)}: {why}; circcal replaces only a folder it wrote: give a new or empty folder"
        )
    return "earlier"


def _not_ours(path: Path) -> bool:
    """A non-empty regular file at ``path`` that circcal did not write (or one changed since)."""
    try:
        return path.is_file() and path.stat().st_size > 0 and not written_by_circcal(path)
    except OSError:
        return True  # unreadable now: not ours to replace


def _free_name(path: Path) -> Path:
    """``NAME.new-K.SUFFIX`` beside ``path``, the first K nothing holds."""
    for k in range(1, 10_000):
        cand = path.with_name(f"{path.stem}.new-{k}{path.suffix}")
        if not (cand.exists() or cand.is_symlink()):
            return cand
    raise InputError(f"{_display(path)}: no free name beside it for this run's output")


class Outputs:
    """The outputs of one command (see the module docstring). Plan each with :meth:`file` or :meth:`folder` before
    the work (the checks run then), write into the staging paths they return, then :meth:`commit`. Used as a
    context manager: leaving the block without a commit removes the staging places.

    Parameters
    ----------
    inputs : iterable of path-like
        The command's input files (images, models): no output may be one, and no folder output may hold one.
    """

    def __init__(self, inputs: Iterable[str | os.PathLike[str]] = ()) -> None:
        self._inputs = [Path(p) for p in inputs]
        self._resolved_inputs = {Path(os.path.realpath(p)) for p in self._inputs}
        self._outputs: list[_Output] = []
        self.committed = False

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if not self.committed:
            self.discard()
        if isinstance(exc, OSError) and exc.errno in _FULL and not self.committed:
            # a full disk or quota while writing a staging file: name what could not be written, not a staging
            # path (or nothing: a write on an open file carries no file name)
            raise OSError(exc.errno, f"{exc.strerror}; nothing written", self._named(exc.filename)) from None

    def _named(self, filename: object) -> str:
        """The outputs as the user gave them: the one whose staging place holds ``filename``, else every one."""
        if isinstance(filename, (str, os.PathLike)):
            f = Path(os.path.abspath(filename))
            for out in self._outputs:
                if f == Path(os.path.abspath(out.staging)) or Path(os.path.abspath(out.staging)) in f.parents:
                    return f"{out.option} {_display(out.shown)}"
        return ", ".join(f"{o.option} {_display(o.shown)}" for o in self._outputs) or "the outputs"

    # planning --------------------------------------------------------------------------------------------------
    def _plan(self, path: Path, option: str, kind: str | None) -> _Output:
        path = Path(path)
        final = _resolve(path, option)
        for out in self._outputs:
            if out.final == final or (out.kind and out.final in final.parents) or (kind and final in out.final.parents):
                raise InputError(
                    f"{option} {_display(path)} and {out.option} {_display(out.shown)} overlap: give "
                    f"each output its own place"
                )
        for inp in self._resolved_inputs:
            if inp == final or (kind and final in inp.parents):
                raise InputError(
                    f"{option} {_display(path)}: "
                    + ("it is one of the inputs" if inp == final else f"the folder holds the input {_display(inp)}")
                    + "; choose another output"
                )
        recover(final.parent if final.parent.exists() else _existing_ancestor(final))
        if final.exists() or final.is_symlink():
            try:
                mode = final.stat().st_mode
            except OSError as exc:
                raise InputError(f"{option} {_display(path)}: {exc.strerror or exc}") from None
            what = _kind_of(mode)
            if kind is None and what is not None:
                raise InputError(f"{option} {_display(path)}: it is {what}; give the path of a file")
            if kind is None:
                for inp in self._inputs:  # hard links and bind mounts: the same file under another name
                    try:
                        if inp.exists() and os.path.samefile(inp, final):
                            raise InputError(
                                f"{option} {_display(path)}: it is the input {_display(inp)}; choose another output"
                            )
                    except OSError:
                        pass
                if not os.access(final, os.W_OK):
                    raise InputError(f"{option} {_display(path)}: not writable (permission denied)")
                try:
                    theirs = final.stat().st_size > 0 and not written_by_circcal(final)
                except OSError as exc:
                    raise InputError(f"{option} {_display(path)}: {exc.strerror or exc}") from None
                if theirs:
                    raise InputError(
                        f"{option} {_display(path)}: a file circcal did not write (or one changed since) is there; "
                        "choose another name, or move it away first"
                    )
        if kind is not None:
            cwd = Path(os.path.realpath(os.getcwd()))
            if final == cwd or final in cwd.parents or final == Path(final.anchor):
                raise InputError(
                    f"{option} {_display(path)}: the folder holds the working folder; give a folder "
                    f"of its own (e.g. {option} report)"
                )
            check_folder_output(final, kind, option, shown=path)
        parent = check_writable_place(final, option)
        _remove_stale(parent, final.name)
        out = _Output(path, final, option, kind)
        prefix = f".{final.name}{_STAGE}{os.getpid()}-"
        try:
            with _signals_held():  # made and recorded together: an interruption cannot orphan it
                if kind is None:
                    # the final suffix kept: writers that pick a format by extension pick the same one
                    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=final.suffix, dir=parent)
                    os.close(fd)
                    out.staging = Path(tmp)
                else:
                    out.staging = Path(tempfile.mkdtemp(prefix=prefix, dir=parent))
                    os.chmod(out.staging, 0o755)  # mkdtemp makes it private; a folder output reads as usual
                self._outputs.append(out)
        except OSError as exc:
            raise InputError(
                f"{option} {_display(path)}: nothing can be made in folder {_display(parent)} ({exc.strerror or exc})"
            ) from None
        return out

    def file(self, path: str | os.PathLike[str], option: str) -> Path:
        """Plan a file output and return its staging path, to write in full before :meth:`commit`.

        Parameters
        ----------
        path : str or PathLike
        option : str
            Names it in messages, e.g. ``"--out"``.

        Returns
        -------
        Path
            The staging path.

        Raises
        ------
        InputError
            See the module docstring.

        Examples
        --------
        >>> with Outputs() as outs:  # doctest: +SKIP
        ...     staging = outs.file("model.json", "--out")
        ...     staging.write_text(text)
        ...     outs.commit()
        """
        return self._plan(Path(path), option, None).staging

    def folder(self, path: str | os.PathLike[str], option: str, *, kind: str) -> Path:
        """Plan a folder output of ``kind`` and return its staging folder (empty), to fill before :meth:`commit`.

        Parameters
        ----------
        path : str or PathLike
        option : str
            Names it in messages.
        kind : str
            ``"report"``, ``"overlays"``, ...

        Returns
        -------
        Path
            The staging folder.

        Raises
        ------
        InputError
        """
        return self._plan(Path(path), option, kind).staging

    def final(self, staging: Path) -> Path:
        """The final place of a staging path (for messages: what the user gave).

        Parameters
        ----------
        staging : Path

        Returns
        -------
        Path
        """
        return next(o.shown for o in self._outputs if o.staging == staging)

    # committing ------------------------------------------------------------------------------------------------
    def commit(self) -> None:
        """Move every staged output into its place, all together (see the module docstring). SIGINT and SIGTERM
        are held back meanwhile and delivered after it."""
        if self.committed:
            raise RuntimeError("outputs already committed")
        commit_id = os.urandom(8).hex()
        with _signals_held():
            for out in self._outputs:
                if out.kind is not None:
                    write_manifest(out.staging, out.kind, commit_id)
                    _fsync_tree(out.staging)
                else:
                    _fsync_file(out.staging)
                    out.sha256 = sha256_file(out.staging)
                    if _not_ours(out.final):  # written by someone else during the work: left as it is
                        out.final = _free_name(out.final)
                        warnings.warn(
                            f"{out.option} {_display(out.shown)} was written by something else during the run: it "
                            f"is left as it is; this run's output is {_display(out.final)}",
                            RuntimeWarning,
                            stacklevel=2,
                        )
                    if out.final.exists():  # a new file gets the mode of the one it replaces
                        os.chmod(out.staging, out.final.stat().st_mode & 0o7777)
                    else:
                        os.chmod(out.staging, 0o666 & ~_UMASK)
            journals = _write_journals(self._outputs, commit_id)
            _apply(self._outputs, commit_id)
            self.committed = True
            _record([(o.final, o.sha256) for o in self._outputs if o.kind is None])
            for j in journals:
                _unlink(j)
            for out in self._outputs:
                if out.old is not None:
                    shutil.rmtree(out.old, ignore_errors=True)

    def discard(self) -> None:
        """Remove every staging place (nothing final is touched)."""
        with _signals_held():
            for out in self._outputs:
                if out.kind is None:
                    _unlink(out.staging)
                else:
                    shutil.rmtree(out.staging, ignore_errors=True)

    def keep_partial(self, staging: Path) -> Path:
        """Instead of committing: move the staged file to a new name beside its final place and return it.

        The name is ``NAME.partial-K.SUFFIX``, the first K free; nothing is replaced. For results done before an
        interruption, kept without touching the earlier output.

        Parameters
        ----------
        staging : Path

        Returns
        -------
        Path
            Where it now lies.

        Raises
        ------
        InputError
            No free name.
        """
        out = next(o for o in self._outputs if o.staging == staging)
        out.final.parent.mkdir(parents=True, exist_ok=True)
        for k in range(1, 10_000):
            cand = out.final.with_name(f"{out.final.stem}.partial-{k}{out.final.suffix}")
            try:
                os.link(out.staging, cand)  # fails when cand exists: never replaces
            except FileExistsError:
                continue
            _unlink(out.staging)
            return cand
        raise InputError(f"{out.option} {_display(out.shown)}: no free name for the partial results")
