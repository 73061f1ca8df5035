"""The sign of ROS's P2[0,3] with the physically right camera as the rig's reference: positive (stereo_image_proc's
baseline -P2[0,3] / fx' negative, -0.08 m for an 80 mm pair), as cv2.stereoRectify gives for the same R, T; the
rig's documentation says so."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import yaml

from circcal.model import Camera
from circcal.rig import RigModel, ros_camera_info_pair
from circcal.rig.files import M_PER_MM

DOCS = Path(__file__).resolve().parents[1] / "docs" / "rigs.md"


def test_p2_is_positive_with_the_right_camera_as_reference():
    cam = Camera(640, 480, 560.0, 561.0, 320.5, 240.5, [-0.1, 0.05, 0.0, 0.0, 0.0])
    # the reference is the right camera; the second (left) camera's centre 80 mm to its left: X_2 = X_1 + (80, 0, 0)
    rvec, T = np.array([0.002, -0.01, 0.001]), np.array([80.0, 0.5, -1.0])
    rig = RigModel(["right", "left"], [cam, cam], [np.zeros(3), rvec], [np.zeros(3), T])
    P2 = np.array(yaml.safe_load(ros_camera_info_pair(rig)[1])["projection_matrix"]["data"]).reshape(3, 4)
    K, D = cam.K, np.asarray(cam.dist)
    cv = cv2.stereoRectify(K, D, K, D, (cam.width, cam.height), cv2.Rodrigues(rvec)[0], T.reshape(3, 1))[3]
    assert P2[0, 3] > 0 and np.isclose(P2[0, 3], cv[0, 3] * M_PER_MM, rtol=1e-9), (P2[0, 3], cv[0, 3])
    assert abs(-P2[0, 3] / P2[0, 0] + 0.08) < 1e-3  # stereo_image_proc's baseline, m
    text = " ".join(DOCS.read_text().split())
    assert "with the physically right camera as the reference, B < 0 and `P2[0,3]` is positive" in text
