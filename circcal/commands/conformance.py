"""``circcal conformance --calibrator MODULE:FN``: the conformance suite installed with circcal (``python -m pytest
--pyargs circcal.conformance``) against any calibrator, from any folder; prints every case, the calibrators' counts
and the bias of each parameter, and exits 1 when a case fails, a calibrator was checked on no case or is biased."""

from __future__ import annotations

import argparse
import os
import sys

from circcal.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERNAL_ERROR, EXIT_INTERRUPTED, EXIT_OK

#: pytest's exit codes -> circcal's (:mod:`circcal.errors`): no case collected is a negative answer, a bad option
#: bad input.
EXIT_CODES = {
    0: EXIT_OK,
    1: EXIT_FAILED,
    2: EXIT_INTERRUPTED,
    3: EXIT_INTERNAL_ERROR,
    4: EXIT_BAD_INPUT,
    5: EXIT_FAILED,
}


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal conformance`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = sub.add_parser(
        "conformance",
        help="check your calibrator against circcal's solver and the truth (the installed conformance suite)",
        description="Run the conformance suite (python -m pytest --pyargs circcal.conformance) against the given "
        "calibrator(s): a function fn(object_points, image_points, image_size) -> (Camera, std) or a "
        "ReferenceCalibrator class, declaring what it fits with the attributes lens = '...' and fixes = "
        "('k3', ...). Each case compares it with circcal's solve under the same model on identical "
        "observations and with the true camera; a bias test per parameter runs across the cases.",
        epilog="Arguments after -- go to pytest (e.g. -- -k paper -x). Exit 1 when a case fails, a calibrator "
        "was checked on no case or is biased; 2 for a calibrator that cannot be loaded.",
    )
    p.add_argument(
        "--calibrator",
        action="append",
        required=True,
        metavar="[LABEL=]MODULE:ATTR",
        help="the calibrator under test (repeatable); MODULE may be a path to a .py file",
    )
    p.add_argument("--full", action="store_true", help="the whole matrix (default: the fast slice)")
    p.add_argument(
        "--allow-unavailable", action="store_true", help="skip, not fail, a calibrator whose available() says no"
    )
    p.add_argument(
        "--calibrator-tol",
        default=None,
        metavar="PX",
        help="max projection difference to circcal's solve (default 1e-6 px; 'inf': measured only)",
    )
    p.add_argument("--bias-t", default=None, metavar="T", help="|t| bound of the bias test (default 3.023)")
    p.add_argument("pytest_args", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    p.set_defaults(func=run)


def pytest_argv(args: argparse.Namespace) -> list[str]:
    """The pytest command line of :func:`run`.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line.

    Returns
    -------
    list of str
    """
    argv = ["--pyargs", "circcal.conformance", "-q", "--tb=short", "-p", "no:cacheprovider"]
    for spec in args.calibrator:
        argv += ["--calibrator", spec]
    if args.full:
        argv.append("--conformance-full")
    if args.allow_unavailable:
        argv.append("--allow-unavailable")
    if args.calibrator_tol is not None:
        argv += ["--calibrator-tol", str(args.calibrator_tol)]
    if args.bias_t is not None:
        argv += ["--bias-t", str(args.bias_t)]
    extra = list(args.pytest_args or [])
    return argv + (extra[1:] if extra[:1] == ["--"] else extra)


def run(args: argparse.Namespace) -> int:
    """Run the suite in this process and map pytest's exit code onto circcal's.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line.

    Returns
    -------
    int
        0 every case passed; 1 a case failed, a calibrator was checked on no case or is biased, or no case ran; 2 a
        calibrator that cannot be loaded; 70 pytest's internal error; 130 interrupted.
    """
    from importlib.metadata import entry_points

    import pytest

    if os.getcwd() not in sys.path:  # MODULE:FN in the current folder, as `python -m pytest` finds it
        sys.path.insert(0, os.getcwd())
    argv = pytest_argv(args)
    if not any(ep.value == "circcal.validators.pytest_plugin" for ep in entry_points(group="pytest11")):
        argv = ["-p", "circcal.validators.pytest_plugin", *argv]  # installed without its metadata (a bare copy)
    code = int(pytest.main(argv))
    return EXIT_CODES.get(code, EXIT_INTERNAL_ERROR)
