"""The conformance plug-in's options, and the calibrators under test they load (pytest hooks).

``--calibrator``, ``--calibrator-tol``, ``--conformance-full``, ``--allow-unavailable``, ``--bias-t``: see
:mod:`circcal.validators.pytest_plugin`, which imports these hooks.
"""

from __future__ import annotations

import pytest

from circcal.validators.conformance_summary import ConformanceSummary
from circcal.validators.plugin_keys import USER_KEY
from circcal.validators.user_calibrator import calibrator_label, load_calibrator

__all__ = ["pytest_addoption", "pytest_configure", "pytest_report_header", "user_calibrators", "positive_value"]


def positive_value(option: str, value: str | float) -> float:
    """An option's value as a number > 0 (``inf`` allowed: ``--calibrator-tol inf`` measures without asserting).

    Parameters
    ----------
    option : str
        The option, for the message (``--calibrator-tol``, ``--bias-t``).
    value : str or float
        Its value as given.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Not a number, NaN, or <= 0: one line naming the option and the value.
    """
    try:
        v = float(value)
    except ValueError:
        v = float("nan")
    if not v > 0:
        raise ValueError(f"{option}: expected a number > 0 ('inf': no bound), got {value!r}")
    return v


def pytest_addoption(parser: pytest.Parser) -> None:
    """pytest hook: add ``--calibrator`` and ``--calibrator-tol``.

    Parameters
    ----------
    parser : pytest.Parser
    """
    group = parser.getgroup("circcal", "circcal conformance suite")
    group.addoption(
        "--calibrator",
        action="append",
        default=[],
        metavar="[LABEL=]MODULE:ATTR",
        help="calibrator under test (repeatable): a function fn(object_points, image_points, image_size) "
        "-> ReferenceResult or (Camera, std|None), or a ReferenceCalibrator class/factory; "
        "MODULE may be a path to a .py file. Replaces circcal and the built-in references in the "
        "conformance cases.",
    )
    group.addoption(
        "--calibrator-tol",
        type=float,
        default=None,
        metavar="PX",
        help="max projection difference of --calibrator to circcal's solver on identical observations "
        "(default 1e-6 px; 'inf' = measure only)",
    )
    group.addoption(
        "--conformance-full",
        action="store_true",
        default=False,
        help="run the whole conformance matrix (default: the fast slice; the rest is marked slow)",
    )
    group.addoption(
        "--allow-unavailable",
        action="store_true",
        default=False,
        help="a --calibrator whose available() says no is skipped with its reason instead of failing",
    )
    group.addoption(
        "--bias-t",
        type=float,
        default=None,
        metavar="T",
        help="fail the run when a --calibrator's mean truth-normalised error of fx, fy, cx or cy over its cases, less "
        "that of circcal's solve on the same points, has |t| above T (default 3.023: 1%% family-wise over the 4 "
        "parameters)",
    )


def pytest_configure(config: pytest.Config) -> None:
    """pytest hook: load the ``--calibrator`` objects and register the end-of-run summary.

    Parameters
    ----------
    config : pytest.Config

    Raises
    ------
    pytest.UsageError
        ``--calibrator-tol`` or ``--bias-t`` not a number > 0, a spec that cannot be loaded, or two calibrators
        with the same label.
    """
    for option, dest in (("--calibrator-tol", "calibrator_tol"), ("--bias-t", "bias_t")):
        value = config.getoption(dest, default=None)
        if value is not None:
            try:
                positive_value(option, value)
            except ValueError as exc:
                raise pytest.UsageError(str(exc)) from None
    specs = config.getoption("calibrator", default=None) or []
    cals = []
    for spec in specs:
        try:
            cals.append(load_calibrator(spec))
        except ValueError as exc:
            raise pytest.UsageError(str(exc)) from None
    labels = [calibrator_label(c) for c in cals]
    dup = {x for x in labels if labels.count(x) > 1}
    if dup:
        raise pytest.UsageError(
            f"--calibrator: labels must be unique, got {', '.join(sorted(dup))} twice; name them with LABEL=module:attr"
        )
    config.stash[USER_KEY] = cals
    config.addinivalue_line(
        "markers", "slow: outside circcal's fast conformance slice (run with --conformance-full or -m slow)"
    )
    if not config.pluginmanager.has_plugin("circcal-conformance-summary"):
        config.pluginmanager.register(ConformanceSummary(config), "circcal-conformance-summary")


def user_calibrators(config: pytest.Config) -> list:
    """The ``--calibrator`` objects of a run, loaded by :func:`pytest_configure` (here when it has not run yet).

    Parameters
    ----------
    config : pytest.Config

    Returns
    -------
    list of ReferenceCalibrator
        Empty without ``--calibrator``.
    """
    if USER_KEY not in config.stash:  # plug-in registered late (tests/conformance/conftest.py fallback)
        pytest_configure(config)
    return config.stash[USER_KEY]


def pytest_report_header(config: pytest.Config) -> list[str]:
    """pytest hook: name the calibrators under test in the header.

    Parameters
    ----------
    config : pytest.Config

    Returns
    -------
    list of str
        One line, or none without ``--calibrator``.
    """
    cals = config.stash.get(USER_KEY, [])
    if not cals:
        return []
    return [
        "circcal conformance: calibrator(s) under test: "
        + ", ".join(f"{calibrator_label(c)} ({type(c).__name__})" for c in cals)
    ]
