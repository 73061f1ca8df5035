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

from circcal.model import Camera
from circcal.validators.base import BaseCalibrator
from circcal.validators.reference_protocol import missing_members
from circcal.validators.reference_result import ReferenceResult

__all__ = ["FunctionCalibrator", "load_calibrator", "parse_spec", "calibrator_label"]


class FunctionCalibrator(BaseCalibrator):
    """A plain function as a :class:`~circcal.validators.reference_protocol.ReferenceCalibrator`.

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
