"""circcal: circle-grid camera calibration with unbiased circle-centre projections.

The public API: the same functions the ``circcal`` command line calls, imported on first use (``import circcal``
itself loads nothing heavy).

========================  =================================================================================
name                      what it is
========================  =================================================================================
:class:`Board`            a circle-grid board (rows, cols, pitch and dot diameter in mm, layout, markers)
:class:`Camera`           a camera model (fx, fy, cx, cy in px; a lens model's distortion)
:class:`CalibrationOptions`  how a calibration is made (lens model, held parameters, outlier rule, ...)
:func:`detect`            one image (an array) -> a :class:`~circcal.detector.Detection`
:func:`detect_files`      image files -> one Detection each (a bad file is a rejection with its reason)
:func:`recorrect`         a detection's centres corrected again under a camera model
:func:`calibrate`         image files (or observations) -> :class:`~circcal.analysis.calibration.Calibration`: the
                          model, sigmas, residuals, projection uncertainty and verdict (images: detect, calibrate,
                          re-correct until the centres settle)
:func:`calibrate_points`  object and image points -> a :class:`~circcal.solver.CalibrationResult`
:func:`assess`            the verdict on a calibration: outliers, uncertainty, model fit, cross-validation
:func:`load_model`        a camera from any file circcal reads (model.json, OpenCV, mrcal, COLMAP, ROS)
:func:`save_model`        a camera to any of those formats (by extension), atomically
:func:`validate`          calibrate images with circcal and the reference calibrators and compare
:func:`diff`              the projection difference between two cameras (implied rotation fitted)
:func:`read_board`        a board described in a file (circcal's YAML/JSON, ROS-Industrial's, Kalibr's)
:class:`RigModel`         a rig: every camera's intrinsics and pose in it (camera 0 the reference, mm)
:func:`calibrate_rig`     each camera's image files -> :class:`~circcal.rig.RigCalibration` (one joint solve)
:func:`calibrate_rig_points`  each camera's observations -> a RigCalibration (``initial=`` given intrinsics)
:func:`rig_verdict`       the verdict on a rig: cross-validation, outlier views, cameras at one point, what to do
:func:`triangulate`       pixels seen by two or more cameras of a rig -> 3-D points with their covariance
========================  =================================================================================

Example
-------
>>> import circcal                                                   # doctest: +SKIP
>>> board = circcal.Board(7, 9, pitch_mm=10.0, diameter_mm=4.0)
>>> cal = circcal.calibrate(sorted(Path("photos").glob("*.png")), board)
>>> print(cal.camera, cal.std["fx"], cal.verdict[0])
>>> circcal.save_model("model.json", cal.camera)
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: public name -> (module, attribute): what ``circcal.NAME`` is
_API: dict[str, tuple[str, str]] = {
    "Board": ("circcal.board", "Board"),
    "Camera": ("circcal.model", "Camera"),
    "CalibrationOptions": ("circcal.solver.options", "CalibrationOptions"),
    "detect": ("circcal.detector.find", "detect"),
    "detect_files": ("circcal.detector.files", "detect_files"),
    "recorrect": ("circcal.detector.find", "recorrect"),
    "calibrate": ("circcal.analysis.calibration", "calibrate"),
    "calibrate_points": ("circcal.solver.calibrate", "calibrate"),
    "assess": ("circcal.analysis.assess", "assess"),
    "load_model": ("circcal.formats", "read_camera"),
    "save_model": ("circcal.formats", "write_camera"),
    "validate": ("circcal.validators.validate", "run_validation"),
    "diff": ("circcal.analysis.diff", "model_diff"),
    "read_board": ("circcal.formats.boardfile", "read_board_file"),
    "RigModel": ("circcal.rig.model", "RigModel"),
    "calibrate_rig": ("circcal.rig.calibrate", "calibrate_rig"),
    "calibrate_rig_points": ("circcal.rig.calibrate", "calibrate_rig_points"),
    "rig_verdict": ("circcal.rig.verdict", "rig_verdict"),
    "triangulate": ("circcal.rig.triangulate", "triangulate"),
}

__all__ = ["__version__", *_API]


def __getattr__(name: str) -> Any:
    """``circcal.NAME`` for the names of :data:`_API`, imported on first use."""
    if name not in _API:
        raise AttributeError(f"module 'circcal' has no attribute {name!r}")
    module, attribute = _API[name]
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))
