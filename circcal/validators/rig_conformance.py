"""The conformance check of anyone's rig calibrator (:class:`RigCalibrator`) against the truth of the rig fixtures
(:mod:`circcal.fixtures.rig`): every scenario x variant (:func:`rig_cases`), each parameter within
:data:`RIG_TRUTH_SIGMAS` stated sigmas of the truth (:func:`run_rig_case`); circcal's own rig calibration of a case
(:func:`calibrate_scenario`), which :mod:`circcal.validators.rig_validate` compares with the reference tools.
Conventions: :mod:`circcal.rig.model` (camera 0 the reference, ``X_i = R_i X_0 + T_i``, mm).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from statistics import NormalDist
from typing import Any, Protocol

import numpy as np

from circcal.board import Board
from circcal.errors import CalibrationError, InputError
from circcal.fixtures.rig import (
    RIG_SCENARIOS,
    RIG_VARIANTS,
    RigScenario,
    is_rendered,
    rig_fixture_dir,
    rig_scenario,
    rig_variant_observations,
)
from circcal.rig import RigModel, calibrate_rig, calibrate_rig_points
from circcal.rig.calibrate import RigCalibration, Views
from circcal.solver import CalibrationOptions
from circcal.validators.rig_conventions import convention_hint

__all__ = [
    "RigCalibrator",
    "RIG_TRUTH_SIGMAS",
    "circcal_rig",
    "call_calibrator",
    "truth_z",
    "scenario_sizes",
    "calibrate_scenario",
    "RigCase",
    "rig_cases",
    "run_rig_case",
    "load_rig_calibrator",
]


class RigCalibrator(Protocol):
    """A rig calibrator under test: ``fn(views, image_sizes[, lenses=..., board=...]) -> RigModel``.

    ``views``: :data:`circcal.rig.calibrate.Views` (per camera, the first the reference, per instant name: object
    points (N, 3) mm, z = 0, and image points (N, 2) px, OpenCV's convention; partial views and instants seen by
    some cameras only included). ``image_sizes``: per camera (width, height) px. Given only when the callable takes a
    parameter of that name (or ``**kwargs``): ``lenses``, per camera the true camera's lens model name (the model to
    fit), and ``board``, the :class:`circcal.board.Board` (to resolve a symmetric grid's labelling across cameras).
    It returns a :class:`circcal.rig.RigModel` naming the cameras alike, camera 0 the reference; a ``covariance`` of
    ``state_vector()``, when given, supplies the sigmas the truth is checked in (else circcal's on the same views).
    """

    def __call__(self, views: Views, image_sizes: Mapping[str, tuple[int, int]], **kwargs: Any) -> RigModel: ...


#: circcal's rig against the truth: |estimate - truth| of fx, fy, cx, cy of every camera and the rvec, tvec of every
#: camera's pose, in stated sigmas. Bonferroni over the rig conformance matrix's observation cases (3 scenarios x 4
#: variants: 208 parameters) at 1% family-wise, two-sided.
RIG_TRUTH_SIGMAS = round(NormalDist().inv_cdf(1 - 0.01 / (2 * 208)), 2)


def circcal_rig(
    views: Views,
    image_sizes: Mapping[str, tuple[int, int]],
    *,
    lenses: Mapping[str, str] | None = None,
    board: Board | None = None,
) -> RigModel:
    """circcal's rig solve as a :class:`RigCalibrator` (the conformance suite's default).

    Parameters
    ----------
    views : Views
    image_sizes : mapping of str to (int, int)
    lenses : mapping of str to str or None
        Per camera lens model (default opencv5).
    board : Board or None

    Returns
    -------
    RigModel
        With its covariance.
    """
    opts = {n: CalibrationOptions(lens=(lenses or {}).get(n, "opencv5")) for n in views}
    return calibrate_rig_points(views, image_sizes, opts, board=board).rig


def call_calibrator(
    cal: Callable[..., Any],
    views: Views,
    image_sizes: Mapping[str, tuple[int, int]],
    lenses: Mapping[str, str],
    board: Board,
) -> RigModel:
    """Call a :class:`RigCalibrator` with the keywords it takes.

    Parameters
    ----------
    cal : RigCalibrator
    views : Views
    image_sizes : mapping of str to (int, int)
    lenses : mapping of str to str
    board : Board

    Returns
    -------
    RigModel

    Raises
    ------
    TypeError
        It returned something else than a RigModel of the views' cameras.
    """
    try:
        params = inspect.signature(cal).parameters
    except (TypeError, ValueError):
        params = {}
    var_kw = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
    kw = {k: v for k, v in (("lenses", lenses), ("board", board)) if var_kw or k in params}
    rig = cal(views, image_sizes, **kw)
    if not isinstance(rig, RigModel):
        raise TypeError(f"the rig calibrator returned {type(rig).__name__}; expected circcal.rig.RigModel")
    if list(rig.names) != list(views):
        raise TypeError(f"the rig calibrator returned cameras {list(rig.names)}; expected {list(views)}")
    return rig


def _truth_indices(rig: RigModel) -> list[tuple[str, int]]:
    """(label, index into state_vector) of fx, fy, cx, cy per camera and rvec, tvec per camera but the reference."""
    out, k = [], 0
    for n, c in zip(rig.names, rig.cameras):
        out += [(f"{n}.{p}", k + j) for j, p in enumerate(("fx", "fy", "cx", "cy"))]
        k += len(c.intrinsics)
    for n in rig.names[1:]:
        out += [(f"{n}.{p}", k + j) for j, p in enumerate(("rx", "ry", "rz", "tx", "ty", "tz"))]
        k += 6
    return out


def truth_z(rig: RigModel, truth: RigModel, covariance: np.ndarray | None = None) -> dict[str, float]:
    """|rig - truth| in stated sigmas of fx, fy, cx, cy of every camera and every pose's rvec and tvec.

    Parameters
    ----------
    rig, truth : RigModel
        Of the same cameras and lens models.
    covariance : ndarray or None
        Of ``rig.state_vector()``; None: ``rig.covariance``.

    Returns
    -------
    dict of str to float
        ``camera.parameter`` -> |z|; empty without a covariance of the right shape.
    """
    cov = rig.covariance if covariance is None else covariance
    x, t = rig.state_vector(), truth.state_vector()
    if cov is None or x.shape != t.shape or np.shape(cov) != (len(x),) * 2:
        return {}
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return {k: float(abs(x[i] - t[i]) / sd[i]) if sd[i] > 0 else float("inf") for k, i in _truth_indices(rig)}


def scenario_sizes(sc: RigScenario) -> dict[str, tuple[int, int]]:
    """Each camera's image size in a rig scenario.

    Parameters
    ----------
    sc : RigScenario

    Returns
    -------
    dict of str to (int, int)
        Per camera name (width, height) px.
    """
    return {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}


def calibrate_scenario(sc: RigScenario, variant: str, seed: int) -> tuple[RigCalibration, dict[str, dict[str, tuple]]]:
    """circcal's rig calibration of a scenario variant and the raw views it calibrated.

    Parameters
    ----------
    sc : RigScenario
    variant : str
        A :data:`circcal.fixtures.rig.RIG_VARIANTS` name: projected observations, or rendered images through
        :func:`circcal.rig.calibrate_rig`.
    seed : int
        Seed of the observation noise (projected variants).

    Returns
    -------
    RigCalibration
    dict of str to dict of str to (ndarray (N, 3), ndarray (N, 2))
        Per camera, per instant its object points (mm) and image points (px): the observations, or the detected
        centres of the rendered images.
    """
    opts = {n: CalibrationOptions(lens=c.lens) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    if not is_rendered(variant):
        views, _ = rig_variant_observations(sc, variant, seed)
        return calibrate_rig_points(views, scenario_sizes(sc), opts, board=sc.board), views
    folder = rig_fixture_dir(sc.name, variant)
    images = {n: sorted((Path(folder) / n).glob("*.png")) for n in sc.rig.names}
    rc = calibrate_rig(images, sc.board, opts, progress=False)
    P = sc.board.object_points()
    views = {}
    for n in sc.rig.names:
        cal = rc.per_camera[n]
        views[n] = {}
        for i, c in zip(cal.used, cal.centres):
            ok = np.all(np.isfinite(c), axis=1)
            views[n][Path(cal.paths[i]).name] = (P[ok], np.asarray(c, dtype=np.float64)[ok])
    return rc, views


@dataclass(frozen=True)
class RigCase:
    """One rig conformance case.

    Attributes
    ----------
    scenario, variant : str
    slow : bool
        Rendered (outside the fast slice).
    """

    scenario: str
    variant: str
    slow: bool

    @property
    def id(self) -> str:
        """``<scenario>-<variant>``."""
        return f"{self.scenario}-{self.variant}"


def rig_cases() -> list[RigCase]:
    """Every rig scenario x variant (rendered ones slow; only the ``rendered-noise`` one of them per scenario).

    Returns
    -------
    list of RigCase
    """
    return [
        RigCase(s, v, is_rendered(v))
        for s in RIG_SCENARIOS
        for v in RIG_VARIANTS
        if not is_rendered(v) or v == "rendered-noise"
    ]


def run_rig_case(case: RigCase, calibrator: Callable[..., Any] | None = None, seed: int = 0) -> list[str]:
    """A rig calibrator on one case, checked against the truth.

    The calibrator gets the case's views (rendered cases: circcal's detections of the images) and must reach the
    truth within :data:`RIG_TRUTH_SIGMAS` on every fx, fy, cx, cy and pose parameter, in its own stated sigmas when
    it returns a covariance (of circcal's ``state_vector`` layout), else in circcal's on the same views.

    Parameters
    ----------
    case : RigCase
    calibrator : RigCalibrator or None
        None: :func:`circcal_rig`.
    seed : int

    Returns
    -------
    list of str
        The failures in words; empty: passed.
    """
    sc = rig_scenario(case.scenario)
    rc, views = calibrate_scenario(sc, case.variant, seed)
    if calibrator is None:
        rig = rc.rig
    else:
        lenses = {n: c.lens for n, c in zip(sc.rig.names, sc.rig.cameras)}
        try:
            rig = call_calibrator(calibrator, views, scenario_sizes(sc), lenses, sc.board)
        except (CalibrationError, InputError) as exc:
            return [f"the calibrator failed: {type(exc).__name__}: {exc}"]
    if [c.lens for c in rig.cameras] != [c.lens for c in sc.rig.cameras]:
        return [f"lens models {[c.lens for c in rig.cameras]}, the truth's {[c.lens for c in sc.rig.cameras]}"]
    z = truth_z(rig, sc.rig) or truth_z(rig, sc.rig, rc.rig.covariance)
    if not z:
        return ["no covariance to check the truth in"]
    k, worst = max(z.items(), key=lambda kv: kv[1])
    if worst <= RIG_TRUTH_SIGMAS:
        return []
    hint = convention_hint(rig, sc.rig)  # a calibrator's R, T inverted or T in metres, said so
    return [f"{k} is {worst:.2f} stated sigmas from the truth (bound {RIG_TRUTH_SIGMAS})"] + ([hint] if hint else [])


def load_rig_calibrator(spec: str) -> Callable[..., Any]:
    """The rig calibrator named by a ``--rig-calibrator`` spec: ``MODULE:ATTR`` or ``PATH.py:ATTR``.

    Parameters
    ----------
    spec : str

    Returns
    -------
    RigCalibrator
        A callable (a class or zero-argument factory is not called: the attribute itself must be the callable).

    Raises
    ------
    ValueError
        A bad spec, a missing file or attribute, an import error, or an attribute that is not callable.
    """
    import importlib
    import importlib.util
    import sys

    where, sep, attr = spec.rpartition(":")
    if not sep or not where or not attr:
        raise ValueError(f"--rig-calibrator {spec!r}: expected package.module:function or path/to/file.py:function")
    try:
        if where.endswith(".py") or "/" in where:
            path = Path(where).resolve()
            if not path.is_file():
                raise ValueError(f"--rig-calibrator {spec!r}: no such file {where}")
            name = f"_circcal_rig_user_{path.stem}"
            mspec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(mspec)  # type: ignore[arg-type]
            sys.modules[name] = module
            mspec.loader.exec_module(module)  # type: ignore[union-attr]
        else:
            module = importlib.import_module(where)
    except ValueError:
        raise
    except Exception as exc:  # noqa: BLE001 -- any error of the user's module, reported in one line
        raise ValueError(f"--rig-calibrator {spec!r}: cannot import {where!r}: {type(exc).__name__}: {exc}") from exc
    fn = getattr(module, attr, None)
    if fn is None or not callable(fn):
        raise ValueError(f"--rig-calibrator {spec!r}: {where} has no callable {attr!r}")
    return fn
