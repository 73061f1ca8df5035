"""``circcal conformance --calibrator MODULE:FN``: the conformance suite installed with circcal (``python -m pytest
--pyargs circcal.conformance``) against any calibrator, from any folder; prints every case, the calibrators' counts
and the bias of each parameter, and exits 1 when a case fails, a calibrator was checked on no case or is biased."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from circcal.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERNAL_ERROR, EXIT_INTERRUPTED, EXIT_OK, InputError

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


#: The start of the warning pytest gives for the plug-in's package, already imported by the command line.
REWRITE_WARNING = "Module already imported so cannot be rewritten; circcal"


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
        "was checked on no case or is biased; 2 for a calibrator that cannot be loaded, a bad option value, or pytest "
        "not installed. The pytest configuration of the current folder (pytest.ini, pyproject.toml, conftest.py) is "
        "not read.",
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
        help="max projection difference to circcal's solve, px > 0 (default 1e-6 px; 'inf': measured only)",
    )
    p.add_argument(
        "--bias-t", default=None, metavar="T", help="|t| bound of the bias test, > 0 (default 3.023; 'inf': none)"
    )
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
    from circcal import conformance

    suite = str(Path(conformance.__file__).resolve().parent)
    # The installed suite (what `--pyargs circcal.conformance` names), by its folder, isolated from the pytest set-up
    # of the folder it runs in: no configuration file (-c os.devnull: no pytest.ini, pyproject.toml, tox.ini or
    # setup.cfg addopts), the suite's folder as the root and the lowest folder whose conftest.py is read (pytest
    # reads the current folder's conftest.py for a --pyargs name, not for a path), no cache written there.
    argv = [suite, "-q", "--tb=short", "-p", "no:cacheprovider", "-c", os.devnull, "--rootdir", suite]
    argv += ["--confcutdir", suite]
    # circcal itself is imported before pytest marks the plug-in's package for assertion rewriting: nothing to warn
    argv += ["-W", f"ignore:{REWRITE_WARNING}:pytest.PytestAssertRewriteWarning"]
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
        calibrator that cannot be loaded, or a pytest option pytest refuses; 70 pytest's internal error; 130
        interrupted.

    Raises
    ------
    InputError
        pytest is not installed, or ``--calibrator-tol`` / ``--bias-t`` is not a number > 0 (one line naming it).
    """
    from importlib.metadata import entry_points

    try:
        import pytest
    except ModuleNotFoundError as exc:
        if exc.name != "pytest":
            raise
        raise InputError(
            "circcal conformance runs the suite with pytest, which is not installed in this environment: "
            "pip install pytest"
        ) from None
    from circcal.validators.plugin_options import positive_value

    for option, value in (("--calibrator-tol", args.calibrator_tol), ("--bias-t", args.bias_t)):
        if value is not None:
            try:
                positive_value(option, value)
            except ValueError as exc:
                raise InputError(str(exc)) from None

    if os.getcwd() not in sys.path:  # MODULE:FN in the current folder, as `python -m pytest` finds it
        sys.path.insert(0, os.getcwd())
    argv = pytest_argv(args)
    if not any(ep.value == "circcal.validators.pytest_plugin" for ep in entry_points(group="pytest11")):
        argv = ["-p", "circcal.validators.pytest_plugin", *argv]  # installed without its metadata (a bare copy)
    code = int(pytest.main(argv))
    return EXIT_CODES.get(code, EXIT_INTERNAL_ERROR)
