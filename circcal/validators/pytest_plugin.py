"""pytest plug-in ``circcal`` (entry point ``pytest11``): run circcal's conformance suite against any calibrator.

Installed with circcal (``pip install -e .``), it adds::

    --calibrator SPEC        calibrator(s) under test (repeatable); SPEC is [LABEL=]MODULE:ATTR or [LABEL=]FILE.py:ATTR
    --calibrator-tol PX      max projection difference to circcal's solver on identical observations (default 1e-6;
                             'inf' measures without asserting, for an estimator that is not plain least squares)
    --conformance-full       the whole matrix (default: the fast slice; the slow marker is registered here)
    --allow-unavailable      a --calibrator whose available() says no is skipped, not failed
    --bias-t T               |t| bound of the bias test per parameter across cases (default 3.023)
    --rig-calibrator SPEC    rig calibrator under test in the rig cases (circcal.conformance.test_rig_conformance):
                             MODULE:ATTR or FILE.py:ATTR, fn(views, image_sizes[, lenses=, board=]) -> RigModel

The suite's test is installed as :mod:`circcal.conformance` (``python -m pytest --pyargs circcal.conformance
--calibrator X`` from any folder). A calibrator declares the model it fits with the attributes ``lens`` and ``fixes``
(:func:`circcal.validators.user_case.declared_model`) and is compared with circcal's solve under the same holds
(:func:`circcal.validators.user_case.run_user_case`); the run fails when a calibrator was checked on no case or is
biased (:func:`circcal.validators.bias.bias_tests`).

``ATTR`` may be

* a function ``fn(object_points, image_points, image_size)`` with ``object_points``: per view (N_v, 3) float64 mm
  (z = 0), ``image_points``: per view (N_v, 2) float64 px (OpenCV convention: pixel centres at integer
  coordinates), ``image_size``: (width, height), all copies of circcal's; it returns a
  :class:`circcal.validators.reference_result.ReferenceResult`, or ``(camera, std)`` or ``(camera, std, rvecs,
  tvecs)`` with ``camera`` a :class:`circcal.model.Camera` of that image size, ``std`` a dict of standard deviations
  keyed fx, fy, cx, cy, k1, k2, p1, p2, k3 (finite numbers >= 0; circcal's on the same observations, with a note, for
  those missing: :func:`circcal.validators.parameter_table.stated_sigmas`) or None, rvecs/tvecs (V, 3) board-to-camera
  (without them the poses are solved for its intrinsics to convergence:
  :func:`circcal.validators.user_calibrator.solve_poses`). It is wrapped into a
  :class:`circcal.validators.user_calibrator.FunctionCalibrator` whose calls go through
  :func:`circcal.validators.base.run_safely` (an exception becomes a failed case with its message,
  ``NotImplementedError`` an unsupported one);
* a :class:`~circcal.validators.reference_protocol.ReferenceCalibrator` class, a zero-argument factory returning one
  (a callable that takes no arguments and cannot take three: a function that can is a calibrating function), or an
  instance.

With ``--calibrator`` the conformance cases test only the given calibrator(s) (ids ``<scenario>-<variant>-<label>``,
label: LABEL, else the calibrator's ``name``, else the function's name); without it they test circcal and every
registered reference. Any test that takes the ``conformance_case`` argument is parametrised over the matrix of
:func:`circcal.validators.case_matrix.cases`, slow-marked outside the fast slice. Fixtures: ``conformance_observations``
(session: ``get(scenario, variant) -> Observations``, circcal's calibration computed once per scenario-variant and,
under pytest-xdist, once per run across workers), ``conformance_calibrator`` (``get(case) -> ReferenceCalibrator``).
A summary of every case (key numbers, including those measured and not asserted) is printed at the end.

This module is what pytest loads: it defines the collection hooks and imports the others, so pytest finds them here:
the options and ``pytest_configure`` (:mod:`~circcal.validators.plugin_options`, loading calibrators with
:mod:`~circcal.validators.user_calibrator`), the fixtures (:mod:`~circcal.validators.conformance_fixtures`); the
end-of-run summary is :mod:`~circcal.validators.conformance_summary`.
"""

from __future__ import annotations

import pytest

from circcal.validators.conformance_fixtures import (
    conformance_calibrator,
    conformance_observations,
    conformance_record,
    conformance_run,
)
from circcal.validators.plugin_options import pytest_addoption as _conformance_options
from circcal.validators.plugin_options import (
    pytest_configure,
    pytest_report_header,
    user_calibrators,
)
from circcal.validators.user_calibrator import calibrator_label

# The hooks and fixtures pytest finds in this module (the pytest11 entry point): those defined here and those imported.
__all__ = [
    "pytest_addoption",
    "pytest_configure",
    "pytest_report_header",
    "pytest_generate_tests",
    "pytest_collection_modifyitems",
    "conformance_observations",
    "conformance_calibrator",
    "conformance_record",
    "conformance_run",
    "rig_calibrator",
]


def pytest_addoption(parser: pytest.Parser) -> None:
    """pytest hook: the conformance options (:mod:`circcal.validators.plugin_options`) and ``--rig-calibrator``.

    Parameters
    ----------
    parser : pytest.Parser
    """
    _conformance_options(parser)
    parser.getgroup("circcal").addoption(
        "--rig-calibrator",
        default=None,
        metavar="MODULE:ATTR",
        help="rig calibrator under test in circcal.conformance's rig cases: fn(views, image_sizes[, lenses=, "
        "board=]) -> circcal.rig.RigModel (circcal.validators.rig_conformance.RigCalibrator); MODULE may be a path to "
        "a .py file (default: circcal's rig solve)",
    )


@pytest.fixture(scope="session")
def rig_calibrator(pytestconfig: pytest.Config):
    """The ``--rig-calibrator`` callable, or None for circcal's own rig solve.

    Parameters
    ----------
    pytestconfig : pytest.Config

    Returns
    -------
    callable or None
    """
    from circcal.validators.rig_conformance import load_rig_calibrator

    spec = pytestconfig.getoption("rig_calibrator", default=None)
    if not spec:
        return None
    try:
        return load_rig_calibrator(spec)
    except ValueError as exc:
        raise pytest.UsageError(str(exc)) from None


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """pytest hook: parametrise ``conformance_case`` over :func:`circcal.validators.case_matrix.cases`.

    Cases outside the fast slice are marked ``slow``; a case in ``KNOWN_FAILURES`` is ``xfail(strict=True)``.

    Parameters
    ----------
    metafunc : pytest.Metafunc
    """
    if "conformance_case" not in metafunc.fixturenames:
        return
    from circcal.validators.case_matrix import KNOWN_FAILURES, cases, reference_modes

    cals = user_calibrators(metafunc.config)
    user = [(calibrator_label(c), reference_modes(c)) for c in cals]
    params = []
    for c in cases(user=user):
        marks = [pytest.mark.slow] if c.slow else []
        if not c.user and c.id in KNOWN_FAILURES:
            marks.append(pytest.mark.xfail(strict=True, reason=KNOWN_FAILURES[c.id]))
        params.append(pytest.param(c, id=c.id, marks=marks))
    metafunc.parametrize("conformance_case", params)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """pytest hook: the fast conformance slice by default, the whole matrix with ``--conformance-full``.

    Runs before pytest's own ``-m`` selection: with ``--conformance-full`` the conformance cases lose their ``slow``
    mark (so a ``-m 'not slow'`` in an ini file does not drop them); without it and without ``-m``, the slow cases are
    deselected (outside a project that configures ``-m``, pytest would otherwise run all of them).

    Parameters
    ----------
    config : pytest.Config
    items : list of pytest.Item
    """
    full = config.getoption("conformance_full", default=False)
    keep, dropped = [], []
    for item in items:
        callspec = getattr(item, "callspec", None)
        if callspec is None or "conformance_case" not in callspec.params:
            keep.append(item)
            continue
        if full:
            item.own_markers[:] = [m for m in item.own_markers if m.name != "slow"]
            keep.append(item)
        elif not config.getoption("markexpr", default="") and item.get_closest_marker("slow") is not None:
            dropped.append(item)
        else:
            keep.append(item)
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        items[:] = keep
