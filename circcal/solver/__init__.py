"""The solver: Zhang's closed form, then Levenberg-Marquardt over intrinsics, distortion and every board pose, with
the covariance of the result (see :mod:`circcal.solver.calibrate`)."""
from circcal.errors import CalibrationError, DegenerateViewsError
from circcal.solver.calibrate import CalibrationResult, calibrate, fit_pose, holdout_errors

__all__ = ["CalibrationError", "CalibrationResult", "DegenerateViewsError", "calibrate", "fit_pose",
           "holdout_errors"]
