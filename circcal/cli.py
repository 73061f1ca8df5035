"""``circcal`` command line: one subcommand per module in :mod:`circcal.commands`.

Each module there exposes ``add_parser(subparsers)``, which registers its subcommand and sets ``func`` (taking the
parsed ``argparse.Namespace`` and returning an exit code). Modules import their heavy dependencies lazily so
``circcal --help`` stays fast.

Exit codes (:mod:`circcal.errors`): 0 done; 1 the job's answer is negative (a check failed, no model, an image
without its grid); 2 bad input (the message names it); 70 a bug in circcal (the traceback is printed: please
report it); 130 interrupted (Ctrl-C); 143 terminated (SIGTERM).
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import threading
import traceback
import warnings
from typing import NoReturn

from circcal.errors import EXIT_BAD_INPUT, EXIT_INTERNAL_ERROR, EXIT_INTERRUPTED, EXIT_TERMINATED, InputError

#: Subcommands, in the order ``--help`` shows them.
COMMANDS = (
    "demo",
    "render",
    "board",
    "detect",
    "calibrate",
    "calibrate-rig",
    "triangulate",
    "convert",
    "diff",
    "validate",
    "validate-rig",
    "conformance",
    "report",
    "study",
)
#: Subcommands whose module in :mod:`circcal.commands` is not named as they are.
MODULES = {"calibrate-rig": "rig", "validate-rig": "validate_rig"}


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line naming the option, with where the help is (the usage only
    with ``-h``): ten lines of usage before the one line that matters hid it."""

    def error(self, message: str) -> NoReturn:
        """Print ``message`` as one line with where the help is and exit with :data:`EXIT_BAD_INPUT`.

        Parameters
        ----------
        message : str
            argparse's reason (it names the option).
        """
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see: {self.prog} -h)\n")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser of every subcommand, or of one.

    Parameters
    ----------
    only : str or None
        A subcommand's name: only its module is imported (what ``main`` builds when the command line names a
        subcommand: the other command modules, and what they import, are not loaded; ~40 ms of start-up).

    Returns
    -------
    argparse.ArgumentParser
        A :class:`OneLineParser` with one subparser per command of :data:`COMMANDS` (or ``only``'s).
    """
    parser = OneLineParser(
        prog="circcal",
        description="Circle-grid camera calibration with unbiased centres, and cross-validation against "
        "reference calibrators. Reprojection errors name their convention: per point (2-D, "
        "OpenCV's RMS), per coordinate (mrcal's RMS) or mean 2-D (the paper's).",
        epilog="Exit codes: 0 done, 1 negative answer (a check failed, no model), 2 bad input, 70 internal error "
        "(a bug: the traceback is printed), 130 interrupted (Ctrl-C), 143 terminated (SIGTERM).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in (only,) if only in COMMANDS else COMMANDS:
        importlib.import_module(f"circcal.commands.{MODULES.get(name, name)}").add_parser(sub)
    return parser


class Terminated(BaseException):
    """SIGTERM turned into an exception, so that a stop request unwinds like Ctrl-C: ``finally`` blocks run,
    temporary files are removed, outputs already complete stay."""


def _terminate(signum: int, frame: object) -> None:
    raise Terminated(signum)


class _Stdout:
    """sys.stdout for one command: once its reader has gone (``circcal calibrate ... | head``), further output is
    dropped instead of ending the command before its outputs are committed (the model is still written; the exit
    status is the command's). Everything else is the wrapped stream's."""

    def __init__(self, stream) -> None:
        self._stream = stream
        self._gone = False

    def _closed_reader(self) -> None:
        self._gone = True
        try:  # the interpreter's last flush at exit must not fail either
            fd = self._stream.fileno()
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, fd)
            os.close(null)
        except (OSError, ValueError, AttributeError):  # no descriptor (a captured stream): dropping suffices
            pass

    def write(self, text: str) -> int:
        if self._gone:
            return len(text)
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._closed_reader()
            return len(text)

    def flush(self) -> None:
        if self._gone:
            return
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._closed_reader()

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def main(argv: list[str] | None = None) -> int:
    """Run one ``circcal`` command.

    Parameters
    ----------
    argv : list of str or None
        The arguments after ``circcal`` (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit code: 0 done; 1 a negative answer; 2 bad input (one line naming it); 70 a bug (its traceback
        printed); 130 interrupted (Ctrl-C); 143 terminated (SIGTERM) (:mod:`circcal.errors`).
    """
    for stream in (sys.stdout, sys.stderr):  # a file name of any bytes never stops a message (circcal.pathnames)
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            reconfigure(errors="backslashreplace")
    words = sys.argv[1:] if argv is None else argv
    parser = build_parser(words[0]) if words and words[0] in COMMANDS else build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_BAD_INPUT
    main_thread = threading.current_thread() is threading.main_thread()
    old_sigterm = signal.signal(signal.SIGTERM, _terminate) if main_thread else None
    old_show = warnings.showwarning

    def show_warning(message, category, filename, lineno, file=None, line=None) -> None:
        # a warning is part of the answer (e.g. "did not converge"): one readable line, not a source location
        print(f"circcal {args.command}: warning: {message}", file=sys.stderr)

    warnings.showwarning = show_warning
    old_stdout = sys.stdout
    sys.stdout = _Stdout(old_stdout)
    try:
        return int(args.func(args) or 0)
    except (KeyboardInterrupt, Terminated) as exc:
        print("terminated" if isinstance(exc, Terminated) else "interrupted", file=sys.stderr)
        return EXIT_TERMINATED if isinstance(exc, Terminated) else EXIT_INTERRUPTED
    except (InputError, OSError) as exc:  # what an input can cause: one clear line, no traceback
        what = f"{exc.filename}: {exc.strerror}" if isinstance(exc, OSError) and exc.filename else str(exc)
        print(f"circcal {args.command}: error: {what}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception:  # noqa: BLE001 - a bug: keep its traceback, and an exit code of its own
        traceback.print_exc()
        print(
            f"circcal {args.command}: internal error (a bug in circcal, not in your input); please report it "
            f"with the traceback above",
            file=sys.stderr,
        )
        return EXIT_INTERNAL_ERROR
    finally:
        sys.stdout = old_stdout
        warnings.showwarning = old_show
        if main_thread:
            signal.signal(signal.SIGTERM, old_sigterm)


if __name__ == "__main__":
    sys.exit(main())
