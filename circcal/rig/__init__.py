"""Rigs of 2..N cameras seeing one board: the rig model, its joint solve, stereo outputs and triangulation.

Conventions: :mod:`circcal.rig.model` (camera 0 the reference, ``X_i = R_i X_0 + T_i``, mm).
"""

from circcal.rig.calibrate import RigCalibration, calibrate_rig, calibrate_rig_points
from circcal.rig.model import RigModel, relative_pose

__all__ = ["RigCalibration", "calibrate_rig", "calibrate_rig_points", "RigModel", "relative_pose"]
