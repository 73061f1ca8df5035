"""Fixtures shared by the detector's test modules: :func:`view`, a rendered view of the 4x5 board that the image,
file and overlay tests write in every image kind."""

from __future__ import annotations

import numpy as np
import pytest

from circcal.fixtures.poses import pose_looking_at
from circcal.fixtures.render import render_view
from circcal.model import Camera
from tests.detector.helpers import BOARD

VIEW_CAM = Camera(480, 360, 600.0, 600.0, 239.5, 179.5)


@pytest.fixture(scope="module")
def view() -> np.ndarray:
    """(360, 480) float a rendered view of the 4x5 board (dots ~9 px radius), values in 0..1."""
    rvec, tvec = pose_looking_at(
        VIEW_CAM,
        BOARD,
        distance_mm=VIEW_CAM.fx * BOARD.radius_mm / 9.0,
        tilt_deg=25,
        tilt_axis_deg=30.0,
        roll_deg=10.0,
        target_px=(240.0, 180.0),
    )
    return render_view(VIEW_CAM, BOARD, rvec, tvec)
