"""Example calibrators for ``--calibrator`` (and the plug-in's own test): plain functions with the accepted signature
``fn(object_points, image_points, image_size) -> (Camera, std | None)``.

    python -m pytest tests/conformance --calibrator tests/conformance/example_calibrator.py:opencv_calibrate
"""

from __future__ import annotations

import numpy as np

from circcal.model import Camera

NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def opencv_calibrate(object_points, image_points, image_size):
    """cv2.calibrateCameraExtended on the given points. ``object_points``: per view (N, 3) mm; ``image_points``: per
    view (N, 2) px; ``image_size``: (width, height). Returns (Camera, std). Tight termination and one thread: with
    OpenCV's defaults (30 iterations) or several threads the answer is ~1e-4 / ~2e-7 px off the minimum."""
    import cv2

    n = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        _, K, d, _, _, std, _, _ = cv2.calibrateCameraExtended(
            [np.asarray(o, np.float32).reshape(-1, 1, 3) for o in object_points],
            [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in image_points],
            (int(image_size[0]), int(image_size[1])),
            None,
            None,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-16),
        )
    finally:
        cv2.setNumThreads(n)
    cam = Camera(int(image_size[0]), int(image_size[1]), K[0, 0], K[1, 1], K[0, 2], K[1, 2], np.ravel(d)[:5])
    return cam, {k: float(s) for k, s in zip(NAMES, np.ravel(std))}


def opencv_biased(object_points, image_points, image_size):
    """:func:`opencv_calibrate` with fx, fy scaled by 1 + 1e-4 (0.1 px at fx 1000): a calibrator the suite must
    reject (its agreement with circcal's solver is ~0.06 px, far above 1e-6 px)."""
    cam, std = opencv_calibrate(object_points, image_points, image_size)
    return Camera(cam.width, cam.height, cam.fx * 1.0001, cam.fy * 1.0001, cam.cx, cam.cy, cam.dist), std
