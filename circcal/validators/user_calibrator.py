"""A user's calibrator for the conformance suite, from a ``--calibrator`` spec (:func:`load_calibrator`).

A spec is ``[LABEL=]MODULE:ATTR`` or ``[LABEL=]FILE.py:ATTR``; a plain function is wrapped in
:class:`FunctionCalibrator` (see :mod:`circcal.validators.pytest_plugin` for what it may return).
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from circcal.model import Camera, project, project_jacobian
from circcal.validators.base import BaseCalibrator, camera_size_problem, pose_problem
from circcal.validators.reference_protocol import missing_members
from circcal.validators.reference_result import ReferenceResult

__all__ = ["FunctionCalibrator", "load_calibrator", "parse_spec", "calibrator_label", "solve_poses"]


class FunctionCalibrator(BaseCalibrator):
    """A plain function as a :class:`~circcal.validators.reference_protocol.ReferenceCalibrator`.

    See the module docstring for what ``fn`` may return; a wrong return type fails the case with a ``TypeError``
    naming what was expected, a camera of another image size or poses of the wrong shape a failed result saying so
    in one line. Without returned poses they are solved for the returned intrinsics (:func:`solve_poses`). The
    function gets copies of the points (changing them in place changes nothing outside it).

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
        # what the function declares it fits (circcal.validators.user_case.declared_model)
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
        # copies: a function that changes its arguments in place changes neither the points its residuals are
        # measured on nor what the next calibrator gets
        out = self.fn([o.copy() for o in object_points], [p.copy() for p in image_points], tuple(image_size))
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
        if (camera.width, camera.height) != tuple(image_size):
            return self.result(mode, "failed", camera_size_problem(camera, image_size))
        if len(out) == 4:
            problem = pose_problem(out[2], out[3], len(object_points))
            if problem:
                return self.result(mode, "failed", f"the returned {problem}")
            rvecs, tvecs, poses = out[2], out[3], "returned"
        else:
            rvecs, tvecs = solve_poses(camera, object_points, image_points)
            poses = "cv2.solvePnP, then Gauss-Newton to convergence, for the returned intrinsics (solve_poses)"
        return self.finish(mode, camera, rvecs, tvecs, object_points, image_points, t0, std=std, poses=poses)


#: Pose refinement (:func:`solve_poses`) stops at a Gauss-Newton step predicted to lower a view's sum of squares by
#: less than this share of it: nothing is left above double precision (the sum itself carries ~1e-13 of rounding
#: at 0.02 px residuals on ~1000 px coordinates), far below the agreement check's cost tie-break
#: (:data:`circcal.validators.bounds.COST_TIE_REL`, 1e-10).
POSE_PREDICTED_REL = 1e-16
#: At most this many Gauss-Newton steps per view (from OpenCV's pose, 1-3 are taken).
POSE_MAX_STEPS = 50


def solve_poses(
    camera: Camera, object_points: list[np.ndarray], image_points: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Per-view board poses that minimise the reprojection error of given intrinsics, to convergence.

    :func:`circcal.solver.fit_pose` (OpenCV's ``solvePnPRefineLM``) starts each view; Gauss-Newton steps on
    :func:`circcal.model.project_jacobian` (the intrinsics held) follow until none is left that would lower the
    view's cost above double precision (:data:`POSE_PREDICTED_REL`). OpenCV's refinement alone stops where its own
    tolerance says (OpenCV 5.1's: ~6e-9 of the cost above the minimum on the paper camera), which the agreement
    check's cost tie-break would hold against the calibrator: its cost must be measured at its poses' minimum.

    Parameters
    ----------
    camera : circcal.model.Camera
        The intrinsics, held.
    object_points : list of ndarray, shape (N_v, 3)
        Board points per view, mm.
    image_points : list of ndarray, shape (N_v, 2)
        Observed centres per view, px.

    Returns
    -------
    rvecs, tvecs : ndarray, shape (V, 3)
        rad; mm.

    Raises
    ------
    CalibrationError
        A view without a pose (:func:`circcal.solver.fit_pose`).
    """
    from circcal.solver import fit_pose

    poses = [_converged_pose(o, p, camera, *fit_pose(o, p, camera)) for o, p in zip(object_points, image_points)]
    return np.array([r for r, _ in poses]).reshape(-1, 3), np.array([t for _, t in poses]).reshape(-1, 3)


def _converged_pose(
    o: np.ndarray, p: np.ndarray, camera: Camera, rvec: np.ndarray, tvec: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton on one view's pose from (rvec, tvec), the camera held, until no step is left to take."""
    o = np.asarray(o, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)

    def cost(x: np.ndarray) -> float:
        r = p - project(o, x[:3], x[3:], camera)
        c = float(np.sum(r * r))
        return c if np.isfinite(c) else np.inf

    x = np.concatenate([np.ravel(rvec), np.ravel(tvec)]).astype(np.float64)
    c = cost(x)
    for _ in range(POSE_MAX_STEPS):
        uv, _, J = project_jacobian(o, x[:3], x[3:], camera)
        J = J.reshape(-1, 6)
        step = np.linalg.lstsq(J, (p - uv).reshape(-1), rcond=None)[0]
        if not float(np.sum((J @ step) ** 2)) > POSE_PREDICTED_REL * c:  # at the minimum
            break
        for scale in (1.0, 0.5, 0.25, 0.125):  # a step that raises the cost is shortened, then given up
            c_new = cost(x + scale * step)
            if c_new <= c:
                break
        else:
            break
        x, c = x + scale * step, c_new
    return x[:3], x[3:]


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

    A class or zero-argument factory (a callable that takes no arguments and cannot take three) is called; a plain
    function is wrapped in :class:`FunctionCalibrator` (also one whose parameters all have defaults, or that takes
    ``*args``); the label, when given, is stored as ``label``.

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
    if inspect.isclass(obj) or (callable(obj) and not hasattr(obj, "calibrate_observations") and _is_factory(obj)):
        try:
            obj = obj()
        except Exception as exc:  # noqa: BLE001
            raise ValueError(f"--calibrator {spec!r}: constructing {attr} failed: {type(exc).__name__}: {exc}") from exc
        if not hasattr(obj, "calibrate_observations"):
            raise ValueError(
                f"--calibrator {spec!r}: {attr}() returned {type(obj).__name__}, which lacks "
                "calibrate_observations (see circcal.validators.reference_protocol.ReferenceCalibrator)"
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
            "circcal.validators.reference_protocol.ReferenceCalibrator)"
        )
    from circcal.validators.user_case import declared_model

    try:
        declared_model(obj)
    except ValueError as exc:
        raise ValueError(f"--calibrator {spec!r}: {exc}") from None
    if label:
        obj.label = label
    return obj


def _is_factory(fn: Callable[..., Any]) -> bool:
    """True for a zero-argument factory: a callable that can be called with no arguments and cannot be called as
    ``fn(object_points, image_points, image_size)``. A calibrating function whose parameters all have defaults or
    that takes ``*args`` can be called both ways: it is a calibrating function."""
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):  # no signature (a builtin): treat as a calibrating function
        return False
    try:
        sig.bind()
    except TypeError:
        return False
    try:
        sig.bind(None, None, None)
    except TypeError:
        return True
    return False


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
