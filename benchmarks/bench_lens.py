"""Solve time of circcal's calibration for every lens model against the matching OpenCV call on the same points,
timed alternately (benchmarks/timing.py: medians with min-max, threads pinned and stated). Goal (issue 15): each
ratio <= 1.0.

* Observations: a 9x9 board (20 mm pitch), float32-rounded projections + 0.05 px noise, the first view on the axis
  and the others tilted 15-45 deg with their centre up to ``max_theta`` off axis (the problems of
  tests/test_calibrate_lens.py): ``opencv5`` the same 1920x1080 wide lens as ``rational`` fitted with 5 coefficients
  (20 views, 55 deg); ``rational`` / ``thin-prism`` a ~125 deg lens (30 views, 70 deg);
  ``fisheye`` a 1280x1024 fisheye (20 views, 75 deg).
* OpenCV: ``cv2.calibrateCameraExtended`` (default / ``CALIB_RATIONAL_MODEL`` / ``| CALIB_THIN_PRISM_MODEL``; it
  also computes the standard deviations, as circcal does) and ``cv2.fisheye.calibrate`` (``CALIB_RECOMPUTE_EXTRINSIC
  | CALIB_FIX_SKEW``, no standard deviations), criteria (COUNT | EPS, 1000, 1e-15). circcal: its start (Zhang; the
  fisheye's equidistant focal search) + Levenberg-Marquardt + covariance.
* Agreement: the largest difference between the two cameras' projections of every observed pixel's ray (px).
"""

from __future__ import annotations

import numpy as np

from benchmarks.timing import MIN_REPEATS, alternate, pinned, ratio, summary

#: (lens, camera, views, seed, max_theta_deg, distance range mm) of each problem
PROBLEMS = (
    (
        "opencv5",
        (1920, 1080, 900.0, 905.0, 962.3, 541.7, [0.27, 0.01, 2e-4, -3e-4, 5e-4, 0.6, 0.02, 0.001], "rational"),
        20,
        1,
        55,
        (250.0, 600.0),
    ),
    (
        "rational",
        (1920, 1080, 900.0, 905.0, 962.3, 541.7, [0.27, 0.01, 2e-4, -3e-4, 5e-4, 0.6, 0.02, 0.001], "rational"),
        30,
        3,
        70,
        (250.0, 600.0),
    ),
    (
        "thin-prism",
        (
            1920,
            1080,
            900.0,
            905.0,
            962.3,
            541.7,
            [0.27, 0.01, 2e-4, -3e-4, 5e-4, 0.6, 0.02, 0.001, 1e-3, -2e-5, -8e-4, 3e-5],
            "thin-prism",
        ),
        30,
        3,
        70,
        (250.0, 600.0),
    ),
    (
        "fisheye",
        (1280, 1024, 520.0, 521.5, 641.2, 509.8, [0.02, -0.006, 0.001, -1e-4], "fisheye"),
        20,
        2,
        75,
        (150.0, 400.0),
    ),
)


def _views(cam, n: int, seed: int, max_theta_deg: float, distance, noise: float = 0.05):
    """``n`` views of a 9x9 board wholly inside the image (see the module), float32-rounded."""
    from circcal.board import Board
    from circcal.fixtures.poses import off_axis_observations

    obj, img = off_axis_observations(cam, Board(9, 9, 20.0, 8.0), n, seed, max_theta_deg, distance, noise)
    return [o.astype(np.float32) for o in obj], [p.astype(np.float32) for p in img]


def _opencv(lens: str, obj, img, size):
    """The matching OpenCV solve; returns its camera."""
    import cv2

    from circcal.model import Camera

    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 1000, 1e-15)
    if lens == "fisheye":
        _, K, D, _, _ = cv2.fisheye.calibrate(
            [o[None].astype(np.float64) for o in obj],
            [p[None].astype(np.float64) for p in img],
            size,
            None,
            None,
            flags=cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW,
            criteria=crit,
        )
        return Camera(size[0], size[1], K[0, 0], K[1, 1], K[0, 2], K[1, 2], np.ravel(D), "fisheye")
    flags = {
        "opencv5": 0,
        "rational": cv2.CALIB_RATIONAL_MODEL,
        "thin-prism": cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL,
    }[lens]
    out = cv2.calibrateCameraExtended(obj, img, size, None, None, flags=flags, criteria=crit)
    n = {"opencv5": 5, "rational": 8, "thin-prism": 12}[lens]
    K, d = out[1], np.ravel(out[2])
    return Camera(size[0], size[1], K[0, 0], K[1, 1], K[0, 2], K[1, 2], d[:n], lens)


def _one(lens: str, cam_args, n: int, seed: int, max_theta: float, distance, repeats: int) -> dict:
    from circcal.model import Camera, project_camera, unproject
    from circcal.solver import CalibrationOptions, calibrate

    truth = Camera(*cam_args[:6], cam_args[6], cam_args[7])
    obj, img = _views(truth, n, seed, max_theta, distance)
    size = (truth.width, truth.height)
    obj64 = [o.astype(np.float64) for o in obj]
    img64 = [p.astype(np.float64) for p in img]
    out: dict = {}
    t = alternate(
        {
            "circcal": lambda: out.__setitem__("res", calibrate(obj64, img64, size, CalibrationOptions(lens=lens))),
            "opencv": lambda: out.__setitem__("ref", _opencv(lens, obj, img, size)),
        },
        repeats=repeats,
    )
    uv = np.concatenate(img64)
    res, ref = out["res"], out["ref"]
    diff = float(np.max(np.abs(project_camera(unproject(uv, res.camera), ref) - uv)))
    key = f"lens_{lens}"
    return {
        f"{key}_views": n,
        f"{key}_circcal_s": summary(t["circcal"]),
        f"{key}_opencv_s": summary(t["opencv"]),
        f"{key}_ratio": ratio(t["circcal"], t["opencv"]),
        f"{key}_iterations": res.n_iterations,
        f"{key}_max_projection_diff_vs_opencv_px": diff,
    }


def run(repeats: int = MIN_REPEATS) -> dict:
    with pinned(1) as threads:
        out: dict = {"threads": threads}
        for lens, cam_args, n, seed, max_theta, distance in PROBLEMS:
            out.update(_one(lens, cam_args, n, seed, max_theta, distance, repeats))
    return out


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=2))
