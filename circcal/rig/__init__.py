"""Rigs of 2..N cameras seeing one board: the rig model, its joint solve, its verdict, stereo outputs and
triangulation.

Conventions: :mod:`circcal.rig.model` (camera 0 the reference, ``X_i = R_i X_0 + T_i``, mm).
"""

from circcal.rig.calibrate import RigCalibration, calibrate_rig, calibrate_rig_points
from circcal.rig.files import (
    essential_fundamental,
    kalibr_camchain_text,
    mrcal_cameramodel_texts,
    opencv_stereo_from_text,
    opencv_stereo_text,
    read_kalibr_camchain,
    read_mrcal_cameramodels,
    read_opencv_stereo,
    read_ros_pair,
    ros_camera_info_pair,
)
from circcal.rig.model import RigModel, relative_pose
from circcal.rig.rectify import (
    Rectification,
    rectification_maps,
    rectified_overlay,
    rectify_pair,
    write_rectified_overlay,
)
from circcal.rig.triangulate import Triangulated, triangulate
from circcal.rig.verdict import RigCrossValidation, RigVerdict, cross_validate_rig, rig_verdict

__all__ = [
    "RigCalibration",
    "calibrate_rig",
    "calibrate_rig_points",
    "RigModel",
    "relative_pose",
    "Rectification",
    "rectify_pair",
    "rectification_maps",
    "rectified_overlay",
    "write_rectified_overlay",
    "essential_fundamental",
    "opencv_stereo_text",
    "opencv_stereo_from_text",
    "read_opencv_stereo",
    "ros_camera_info_pair",
    "read_ros_pair",
    "mrcal_cameramodel_texts",
    "read_mrcal_cameramodels",
    "kalibr_camchain_text",
    "read_kalibr_camchain",
    "Triangulated",
    "triangulate",
    "RigCrossValidation",
    "RigVerdict",
    "cross_validate_rig",
    "rig_verdict",
]
