"""The solver: Zhang's closed form, then Levenberg-Marquardt over intrinsics, distortion and every board pose, with
the covariance of the result (:mod:`circcal.solver.calibrate`), made as :class:`CalibrationOptions` says
(:mod:`circcal.solver.options`); held-out prediction (:mod:`circcal.solver.holdout`)."""

from circcal.errors import CalibrationError, DegenerateViewsError
from circcal.solver.calibrate import CalibrationResult, calibrate
from circcal.solver.holdout import fit_pose, holdout_errors, leave_one_out, pose_start, prediction_error
from circcal.solver.options import CalibrationOptions

__all__ = [
    "CalibrationError",
    "CalibrationOptions",
    "CalibrationResult",
    "DegenerateViewsError",
    "calibrate",
    "fit_pose",
    "holdout_errors",
    "leave_one_out",
    "pose_start",
    "prediction_error",
]
