"""pytest plug-in ``circcal`` (entry point ``pytest11``): run circcal's conformance suite against any calibrator.

Installed with circcal (``pip install -e .``), it adds::

    --calibrator SPEC        calibrator(s) under test (repeatable); SPEC is [LABEL=]MODULE:ATTR or [LABEL=]FILE.py:ATTR
    --calibrator-tol PX      max projection difference to circcal's solver on identical observations (default 1e-6;
                             'inf' measures without asserting, for an estimator that is not plain least squares)
    --conformance-full       the whole matrix (default: the fast slice; the slow marker is registered here)
    --allow-unavailable      a --calibrator whose available() says no is skipped, not failed
    --bias-t T               |t| bound of the bias test per parameter across cases (default 3.023)

The suite's test is installed as :mod:`circcal.conformance` (``python -m pytest --pyargs circcal.conformance
--calibrator X`` from any folder). A calibrator declares the model it fits with the attributes ``lens`` and ``fixes``
(:func:`circcal.validators.conformance.declared_model`) and is compared with circcal's solve under the same holds
(:func:`circcal.validators.conformance.run_user_case`); the run fails when a calibrator was checked on no case or is
biased (:func:`circcal.validators.conformance.bias_tests`).

``ATTR`` may be

* a function ``fn(object_points, image_points, image_size)`` with ``object_points``: per view (N_v, 3) float64 mm
  (z = 0), ``image_points``: per view (N_v, 2) float64 px (OpenCV convention: pixel centres at integer
  coordinates), ``image_size``: (width, height); it returns a :class:`circcal.validators.base.ReferenceResult`, or
  ``(camera, std)`` or ``(camera, std, rvecs, tvecs)`` with ``camera`` a :class:`circcal.model.Camera`, ``std`` a
  dict of standard deviations keyed fx, fy, cx, cy, k1, k2, p1, p2, k3 or None, rvecs/tvecs (V, 3) board-to-camera
  (without them the poses are solved with cv2.solvePnP for the residuals). It is wrapped into a
  :class:`circcal.validators.base.ReferenceCalibrator` whose calls go through
  :func:`circcal.validators.base.run_safely` (an exception becomes a failed case with its message,
  ``NotImplementedError`` an unsupported one);
* a :class:`~circcal.validators.base.ReferenceCalibrator` class, a zero-argument factory returning one, or an instance.

With ``--calibrator`` the conformance cases test only the given calibrator(s) (ids ``<scenario>-<variant>-<label>``,
label: LABEL, else the calibrator's ``name``, else the function's name); without it they test circcal and every
registered reference. Any test that takes the ``conformance_case`` argument is parametrised over the matrix of
:func:`circcal.validators.conformance.cases`, slow-marked outside the fast slice. Fixtures: ``conformance_observations``
(session: ``get(scenario, variant) -> Observations``, circcal's calibration computed once per scenario-variant and,
under pytest-xdist, once per run across workers), ``conformance_calibrator`` (``get(case) -> ReferenceCalibrator``).
A summary of every case (key numbers, including those measured and not asserted) is printed at the end.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import os
import pickle
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from filelock import FileLock

from circcal import atomic
from circcal.model import Camera
from circcal.validators.base import BaseCalibrator, ReferenceResult, missing_members

__all__ = ["FunctionCalibrator", "load_calibrator", "parse_spec"]

_USER_KEY = pytest.StashKey[list]()
_PROPERTY = "circcal_conformance"
_RECORD = "circcal_conformance_record"


# --------------------------------------------------------------------------------------------------------------------
# Loading a user's calibrator
# --------------------------------------------------------------------------------------------------------------------


class FunctionCalibrator(BaseCalibrator):
    """A plain function as a :class:`~circcal.validators.base.ReferenceCalibrator`.

    See the module docstring for what ``fn`` may return; a wrong return type fails the case with a ``TypeError``
    naming what was expected. Without returned poses they are solved with :func:`circcal.solver.fit_pose`.

    Parameters
    ----------
    fn : callable
        ``fn(object_points, image_points, image_size)``.
    name : str, optional
        The calibrator's name; default the function's ``__name__``.
    """

    modes = ("fair",)

    def __init__(self, fn: Callable[..., Any], name: str | None = None) -> None:
        self.fn = fn
        self.name = name or getattr(fn, "__name__", "calibrator")
        # what the function declares it fits (circcal.validators.conformance.declared_model)
        self.lens = str(getattr(fn, "lens", None) or "opencv5")
        self.lenses = (self.lens,)
        self.fixes = getattr(fn, "fixes", ()) or ()  # checked by declared_model (a bare string is an error)

    def _version(self) -> str:
        mod = sys.modules.get(getattr(self.fn, "__module__", "") or "")
        return str(getattr(mod, "__version__", "unknown"))

    def _calibrate(
        self,
        object_points: list[np.ndarray],
        image_points: list[np.ndarray],
        image_size: tuple[int, int],
        *,
        mode: str,
        initial: Camera | None,
    ) -> ReferenceResult:
        t0 = time.perf_counter()
        out = self.fn(object_points, image_points, image_size)
        if isinstance(out, ReferenceResult):
            return out
        if not isinstance(out, tuple) or len(out) not in (2, 4):
            raise TypeError(
                f"{self.name} returned {type(out).__name__}; expected a ReferenceResult, "
                "(Camera, std | None) or (Camera, std | None, rvecs, tvecs)"
            )
        camera, std = out[0], out[1]
        if not isinstance(camera, Camera):
            raise TypeError(
                f"{self.name} returned {type(camera).__name__} as the camera; expected circcal.model.Camera"
            )
        if std is not None and not isinstance(std, dict):
            raise TypeError(
                f"{self.name} returned std of type {type(std).__name__}; expected a dict keyed fx, fy, "
                "cx, cy, k1, k2, p1, p2, k3 or None"
            )
        if len(out) == 4:
            rvecs, tvecs, poses = out[2], out[3], "returned"
        else:
            rvecs, tvecs = _solve_poses(camera, object_points, image_points)
            poses = "cv2.solvePnP with the returned intrinsics (circcal.solver.fit_pose)"
        return self.finish(mode, camera, rvecs, tvecs, object_points, image_points, t0, std=std, poses=poses)


def _solve_poses(
    camera: Camera, object_points: list[np.ndarray], image_points: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Per-view board poses for given intrinsics (:func:`circcal.solver.fit_pose`): (V, 3) rvecs, (V, 3) tvecs."""
    from circcal.solver import fit_pose

    poses = [fit_pose(o, p, camera) for o, p in zip(object_points, image_points)]
    return np.array([r for r, _ in poses]), np.array([t for _, t in poses])


def parse_spec(spec: str) -> tuple[str | None, str, str]:
    """Split a ``--calibrator`` spec.

    Parameters
    ----------
    spec : str
        ``[LABEL=]MODULE:ATTR`` or ``[LABEL=]PATH.py:ATTR``.

    Returns
    -------
    label : str or None
    where : str
        The module or the path.
    attr : str

    Raises
    ------
    ValueError
        The spec has no ``:ATTR`` or an empty part; the message quotes it and the expected forms.

    Examples
    --------
    >>> parse_spec("mine=pkg.mod:calibrate")
    ('mine', 'pkg.mod', 'calibrate')
    """
    label, _, target = spec.rpartition("=") if "=" in spec.split(":", 1)[0] else (None, "", spec)
    where, sep, attr = target.rpartition(":")
    if not sep or not where or not attr:
        raise ValueError(
            f"--calibrator {spec!r}: expected [LABEL=]package.module:function (or a class), or "
            "[LABEL=]path/to/file.py:function"
        )
    return (label or None), where, attr


def _import(where: str) -> Any:
    if where.endswith(".py") or os.sep in where or "/" in where:
        path = Path(where).resolve()
        if not path.is_file():
            raise ValueError(f"--calibrator: no such file {where}")
        name = f"_circcal_user_{path.stem}"
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)  # type: ignore[union-attr]
        return module
    return importlib.import_module(where)


def load_calibrator(spec: str) -> Any:
    """The calibrator named by a ``--calibrator`` spec (see :func:`parse_spec`), as a ReferenceCalibrator.

    A class or zero-argument factory is called; a plain function is wrapped in :class:`FunctionCalibrator`; the
    label, when given, is stored as ``label``.

    Parameters
    ----------
    spec : str
        ``[LABEL=]MODULE:ATTR`` or ``[LABEL=]PATH.py:ATTR``.

    Returns
    -------
    ReferenceCalibrator

    Raises
    ------
    ValueError
        Saying what is wrong: a bad spec, a missing file, an import error, a missing attribute, a constructor that
        fails, or an object that lacks a required member.
    """
    label, where, attr = parse_spec(spec)
    try:
        module = _import(where)
    except ValueError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise ValueError(f"--calibrator {spec!r}: cannot import {where!r}: {type(exc).__name__}: {exc}") from exc
    try:
        obj = getattr(module, attr)
    except AttributeError:
        raise ValueError(f"--calibrator {spec!r}: {where} has no attribute {attr!r}") from None
    if inspect.isclass(obj) or (callable(obj) and not hasattr(obj, "calibrate_observations") and _no_args(obj)):
        try:
            obj = obj()
        except Exception as exc:  # noqa: BLE001
            raise ValueError(f"--calibrator {spec!r}: constructing {attr} failed: {type(exc).__name__}: {exc}") from exc
        if not hasattr(obj, "calibrate_observations"):
            raise ValueError(
                f"--calibrator {spec!r}: {attr}() returned {type(obj).__name__}, which lacks "
                "calibrate_observations (see circcal.validators.base.ReferenceCalibrator)"
            )
    elif not hasattr(obj, "calibrate_observations"):
        if not callable(obj):
            raise ValueError(
                f"--calibrator {spec!r}: {attr} is a {type(obj).__name__}, not a function or a ReferenceCalibrator"
            )
        obj = FunctionCalibrator(obj, label or attr)
    missing = missing_members(obj)
    if missing:
        raise ValueError(
            f"--calibrator {spec!r}: the calibrator lacks {missing[0]!r} (see "
            "circcal.validators.base.ReferenceCalibrator)"
        )
    from circcal.validators.conformance import declared_model

    try:
        declared_model(obj)
    except ValueError as exc:
        raise ValueError(f"--calibrator {spec!r}: {exc}") from None
    if label:
        obj.label = label
    return obj


def _no_args(fn: Callable[..., Any]) -> bool:
    """True for a callable that can be called with no arguments (a factory), False for fn(obj, img, size)."""
    try:
        inspect.signature(fn).bind()
    except TypeError:
        return False
    except ValueError:  # no signature (a builtin): treat as a calibrating function
        return False
    return True


def calibrator_label(cal: Any) -> str:
    """The label a calibrator's case ids use.

    Parameters
    ----------
    cal : ReferenceCalibrator
        A calibrator under test.

    Returns
    -------
    str
        Its ``label``, else its ``name``, else "calibrator"; characters other than letters, digits, "_" and "."
        replaced by "_".
    """
    label = str(getattr(cal, "label", None) or getattr(cal, "name", "calibrator"))
    return "".join(ch if ch.isalnum() or ch in "_." else "_" for ch in label)


# --------------------------------------------------------------------------------------------------------------------
# Hooks
# --------------------------------------------------------------------------------------------------------------------


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
        A spec that cannot be loaded, or two calibrators with the same label.
    """
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
    config.stash[_USER_KEY] = cals
    config.addinivalue_line(
        "markers", "slow: outside circcal's fast conformance slice (run with --conformance-full or -m slow)"
    )
    if not config.pluginmanager.has_plugin("circcal-conformance-summary"):
        config.pluginmanager.register(_Summary(config), "circcal-conformance-summary")


def _user(config: pytest.Config) -> list:
    if _USER_KEY not in config.stash:  # plug-in registered late (tests/conformance/conftest.py fallback)
        pytest_configure(config)
    return config.stash[_USER_KEY]


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
    cals = config.stash.get(_USER_KEY, [])
    if not cals:
        return []
    return [
        "circcal conformance: calibrator(s) under test: "
        + ", ".join(f"{calibrator_label(c)} ({type(c).__name__})" for c in cals)
    ]


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """pytest hook: parametrise ``conformance_case`` over :func:`circcal.validators.conformance.cases`.

    Cases outside the fast slice are marked ``slow``; a case in ``KNOWN_FAILURES`` is ``xfail(strict=True)``.

    Parameters
    ----------
    metafunc : pytest.Metafunc
    """
    if "conformance_case" not in metafunc.fixturenames:
        return
    from circcal.validators import conformance

    cals = _user(metafunc.config)
    user = [(calibrator_label(c), conformance.reference_modes(c)) for c in cals]
    params = []
    for c in conformance.cases(user=user):
        marks = [pytest.mark.slow] if c.slow else []
        if not c.user and c.id in conformance.KNOWN_FAILURES:
            marks.append(pytest.mark.xfail(strict=True, reason=conformance.KNOWN_FAILURES[c.id]))
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


class _Summary:
    """Collects each case's summary line and record from the test reports (the controller's, under xdist); prints
    them, the calibrators' counts and bias tests; fails the run for a calibrator checked on no case or biased."""

    def __init__(self, config: pytest.Config) -> None:
        self.config = config
        self.lines: list[str] = []
        self.records: list[dict] = []
        self.verdict: list[str] = []
        self.biases: list[Any] = []

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        if report.when != "call":
            return
        for key, value in getattr(report, "user_properties", ()):
            if key == _PROPERTY:
                self.lines.append(str(value))
            elif key == _RECORD:
                self.records.append(dict(value))

    def pytest_sessionfinish(self, session: pytest.Session) -> None:
        config = self.config
        cals = config.stash.get(_USER_KEY, [])
        if not cals or hasattr(config, "workerinput") or config.getoption("collectonly", default=False):
            return
        from circcal.validators.bounds import BIAS_T
        from circcal.validators.conformance import bias_tests

        bound = config.getoption("bias_t", default=None)
        bound = BIAS_T if bound is None else float(bound)
        labels = [calibrator_label(c) for c in cals]
        mine = [r for r in self.records if r.get("label") in labels]
        self.biases = bias_tests(mine, bound)
        for label in labels:
            n = sum(1 for r in mine if r["label"] == label and r["status"] == "checked")
            if n == 0:
                self.verdict.append(
                    f"{label} was checked on 0 cases: nothing was verified (see each case's reason above; run "
                    "`python -m pytest --pyargs circcal.conformance --calibrator ...`)"
                )
        self.verdict += [f"{b.label}: {b.words()}" for b in self.biases if b.biased]
        if self.verdict and session.exitstatus == 0:
            session.exitstatus = pytest.ExitCode.TESTS_FAILED

    def pytest_terminal_summary(self, terminalreporter: Any) -> None:
        if self.lines:
            terminalreporter.section("circcal conformance: every case (key numbers; FAIL = a check failed)")
            for line in sorted(self.lines):
                terminalreporter.write_line(line)
        cals = self.config.stash.get(_USER_KEY, [])
        if not cals or hasattr(self.config, "workerinput"):
            return
        terminalreporter.section("circcal conformance: calibrators under test")
        for label in (calibrator_label(c) for c in cals):
            counts: dict[str, int] = {}
            for r in self.records:
                if r.get("label") == label:
                    status = "FAIL" if r.get("failed") else r["status"]
                    counts[status] = counts.get(status, 0) + 1
            terminalreporter.write_line(
                f"{label}: " + (", ".join(f"{v} {k}" for k, v in sorted(counts.items())) or "no case ran")
            )
            mine = [b for b in self.biases if b.label == label]
            # the most telling first: a bias beyond the bound, then the largest difference to circcal's solve
            mine.sort(key=lambda b: (not b.biased, -abs(b.excess_t)))
            for b in mine:
                terminalreporter.write_line(f"  {b.words()}", red=b.biased)
            for r in self.records:
                if r.get("label") == label and r.get("reason"):
                    terminalreporter.write_line(f"  {r['status']} {r['case']}: {r['reason']}")
        for line in self.verdict:
            terminalreporter.write_line(f"FAILED: {line}", red=True, bold=True)


# --------------------------------------------------------------------------------------------------------------------
# Fixtures
# --------------------------------------------------------------------------------------------------------------------


class ObservationCache:
    """circcal's observations per (scenario, variant, lens model), computed once.

    Under pytest-xdist the workers share a folder in the run's base temp directory (unique per run) and a file lock,
    so each scenario-variant is calibrated once per run, not once per worker. Call it as
    ``cache(scenario, variant, lens=None)`` (lens default: the scenario's own) to get an
    :class:`~circcal.validators.conformance.Observations`.

    Parameters
    ----------
    shared : Path or None
        The shared folder; None: memory only.
    """

    def __init__(self, shared: Path | None) -> None:
        self.shared = shared
        self.memory: dict[tuple[str, str], Any] = {}

    def __call__(self, scenario: str, variant: str, lens: str | None = None):
        from circcal.validators.conformance import observe, scenario_lens

        lens = scenario_lens(scenario) if lens is None else lens
        key = (scenario, variant, lens)
        if key in self.memory:
            return self.memory[key]
        if self.shared is None:
            obs = observe(scenario, variant, lens)
        else:
            self.shared.mkdir(parents=True, exist_ok=True)
            f = self.shared / f"{scenario}--{variant}--{lens}.pkl"
            with FileLock(self.shared / f"{scenario}--{variant}--{lens}.lock"):
                if f.exists():
                    obs = pickle.loads(f.read_bytes())
                else:
                    obs = observe(scenario, variant, lens)
                    atomic.write_bytes(f, pickle.dumps(obs))
        self.memory[key] = obs
        return obs


@pytest.fixture(scope="session")
def conformance_observations(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> ObservationCache:
    """Session fixture: circcal's observations of a scenario-variant, computed once.

    Parameters
    ----------
    request : pytest.FixtureRequest
    tmp_path_factory : pytest.TempPathFactory

    Returns
    -------
    ObservationCache
        ``get(scenario, variant, lens=None) -> circcal.validators.conformance.Observations`` (circcal's calibration
        with that lens model, default the scenario's own).
    """
    shared = None
    if hasattr(request.config, "workerinput"):  # a pytest-xdist worker: basetemp/.. is this run's, shared
        shared = tmp_path_factory.getbasetemp().parent / "circcal-conformance"
    return ObservationCache(shared)


@pytest.fixture(scope="session")
def conformance_calibrator(request: pytest.FixtureRequest) -> Callable[[Any], Any]:
    """Session fixture: the calibrator of a case.

    Parameters
    ----------
    request : pytest.FixtureRequest

    Returns
    -------
    callable
        ``get(case) -> ReferenceCalibrator``: the ``--calibrator`` object for a user case, else the registry's
        reference set up for the case's lens model (one instance per name and lens:
        :func:`circcal.validators.registry.get_for_lens`). A reference that cannot be loaded raises ``ImportError``
        with the cause.
    """
    from circcal.validators.registry import get_for_lens

    user = {calibrator_label(c): c for c in _user(request.config)}
    made: dict[tuple[str, str], Any] = {}

    def get(case: Any) -> Any:
        if case.user:
            return user[case.reference]
        key = (case.reference, case.lens)
        if key not in made:
            made[key] = get_for_lens(case.reference, case.lens)
        return made[key]

    return get


@pytest.fixture
def conformance_record(record_property: Callable[[str, Any], None]) -> Callable[[Any], None]:
    """Fixture: add a case's one-line summary to the end-of-run table (works under xdist).

    Parameters
    ----------
    record_property : callable
        pytest's ``record_property`` fixture.

    Returns
    -------
    callable
        ``record(outcome)``.
    """
    from circcal.validators.conformance import failed_checks, summary_line

    def record(outcome: Any) -> None:
        record_property(_PROPERTY, summary_line(outcome))
        record_property(
            _RECORD,
            {
                "label": outcome.case.reference,
                "case": outcome.case.id,
                "status": outcome.status,
                "failed": bool(failed_checks(outcome)),
                "reason": outcome.skip_reason,
                "params": {k: {kk: float(vv) for kk, vv in v.items()} for k, v in outcome.params.items()},
            },
        )

    return record


def solver_tolerance(config: pytest.Config, case: Any) -> float | None:
    """The agreement bound for a case.

    Parameters
    ----------
    config : pytest.Config
    case : circcal.validators.conformance.Case

    Returns
    -------
    float or None
        px: ``--calibrator-tol`` for user calibrators (default 1e-6), else None (the module default,
        :func:`~circcal.validators.checks.solver_bound`).
    """
    if case.user:
        tol = config.getoption("calibrator_tol", default=None)
        return 1e-6 if tol is None else float(tol)
    return None


@pytest.fixture
def conformance_run(
    request: pytest.FixtureRequest,
    conformance_observations: ObservationCache,
    conformance_calibrator: Callable[[Any], Any],
    conformance_record: Callable[[Any], None],
) -> Callable[[Any], Any]:
    """Fixture: run one conformance case as a test (the body of ``circcal.conformance``'s test).

    Parameters
    ----------
    request : pytest.FixtureRequest
    conformance_observations, conformance_calibrator, conformance_record
        The fixtures above.

    Returns
    -------
    callable
        ``run(case) -> Outcome``: prints the case, records it for the summary, skips with the reason (no
        observations, a model that cannot represent the truth, an unavailable built-in reference outside CI) and
        fails with every check when one fails (a calibrator's exception: its traceback).
    """
    from circcal.validators import conformance

    config = request.config

    def run(case: Any) -> Any:
        obs = conformance_observations(case.scenario, case.variant, case.lens)
        if case.reference == conformance.CIRCCAL:
            outcome = conformance.run_circcal_case(case, obs)
        elif case.user:
            outcome = conformance.run_user_case(
                case,
                obs,
                conformance_calibrator(case),
                solver_px=solver_tolerance(config, case),
                allow_unavailable=bool(config.getoption("allow_unavailable", default=False)),
            )
        else:
            cal = conformance_calibrator(case)
            ok, why = cal.available()
            if not ok:  # a built-in reference that is not installed; under CI, where all are, a failure
                if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
                    pytest.fail(f"{cal.name} unavailable under CI: {why}")
                pytest.skip(f"{cal.name} unavailable: {why}")
            outcome = conformance.run_reference_case(case, obs, cal, solver_px=solver_tolerance(config, case))
        text = conformance.format_outcome(outcome)
        print(text)
        conformance_record(outcome)
        failed = conformance.failed_checks(outcome)
        if outcome.skip_reason and not failed:
            pytest.skip(f"{outcome.status}: {outcome.skip_reason}" if outcome.status != "skip" else outcome.skip_reason)
        assert not failed, text
        return outcome

    return run
