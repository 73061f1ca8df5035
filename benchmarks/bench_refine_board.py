"""Board refinement's cost against OpenCV's ``calibrateCameraRO`` on the issue's case: 15 views of a 224-dot board
(14 x 16, 10 mm pitch) at 1920x1080, boards tilted 5-30 deg, 0.05 px noise, a 0.3 / 0.2 mm sag (issue 34: circcal
<= 0.5x calibrateCameraRO).

Both solve the same float32-rounded points from their own starts: circcal ``calibrate(refine_board=True)`` (Zhang,
Levenberg-Marquardt with the board points as unknowns, the covariance) and ``cv2.calibrateCameraRO`` with its
default criteria and ``iFixedPoint = cols - 1`` (the top-right point, as its documentation suggests), both at one
thread. Also ``with_outliers``: the solve as ``circcal calibrate --refine-board`` runs it (outlier rejection on,
re-solves included).

Timed alternately, 3 rounds (not :data:`benchmarks.timing.MIN_REPEATS`): one calibrateCameraRO takes about 2 min
here, and the ratio measured is hundreds of times below the bar, far beyond any spread between rounds.
"""

from __future__ import annotations

import time

import numpy as np

from benchmarks.timing import pinned, ratio, summary

ROUNDS = 3
BAR = 0.5


def _problem():
    import cv2

    from circcal.board import Board
    from circcal.model import Camera, project

    rng = np.random.default_rng(1)
    board = Board(14, 16, 10.0, 5.0)
    P = board.object_points().copy()
    xr = (P[:, 0] - P[:, 0].min()) / np.ptp(P[:, 0])
    yr = (P[:, 1] - P[:, 1].min()) / np.ptp(P[:, 1])
    warped = P.copy()
    warped[:, 2] += 0.3 * 4 * xr * (1 - xr) + 0.2 * 4 * yr * (1 - yr)
    cam = Camera(1920, 1080, 1400.0, 1400.0, 960.0, 540.0, [-0.1, 0.05, 0, 0, 0])
    obj, img = [], []
    c = P.mean(0)
    for _ in range(15):
        ax = rng.normal(size=3)
        ax /= np.linalg.norm(ax)
        rv = ax * np.radians(rng.uniform(5, 30))
        R = cv2.Rodrigues(rv)[0]
        t = np.array([rng.uniform(-40, 40), rng.uniform(-25, 25), rng.uniform(250, 350)]) - R @ c
        uv = project(warped, rv, t, cam) + rng.normal(scale=0.05, size=(len(P), 2))
        obj.append(P.astype(np.float32))
        img.append(uv.astype(np.float32))
    return board, obj, img


def run(rounds: int = ROUNDS) -> dict:
    import cv2

    from circcal.solver import CalibrationOptions, calibrate
    from circcal.solver.outliers import OutlierRule

    board, obj, img = _problem()
    obj64 = [o.astype(np.float64) for o in obj]
    img64 = [p.astype(np.float64) for p in img]
    held: dict = {}

    def ours() -> None:
        held["circcal"] = calibrate(obj64, img64, (1920, 1080), CalibrationOptions(refine_board=True))

    def ours_outliers() -> None:
        calibrate(obj64, img64, (1920, 1080), CalibrationOptions(refine_board=True, outlier_rule=OutlierRule()))

    def opencv() -> None:
        held["opencv"] = cv2.calibrateCameraRO(obj, img, (1920, 1080), board.cols - 1, None, None)

    t: dict[str, list[float]] = {"circcal": [], "with_outliers": [], "opencv": []}
    with pinned(1) as threads:
        for _ in range(rounds):
            for name, fn in (("circcal", ours), ("with_outliers", ours_outliers), ("opencv", opencv)):
                t0 = time.perf_counter()
                fn()
                t[name].append(time.perf_counter() - t0)
    r = ratio(t["circcal"], t["opencv"])
    res, cv = held["circcal"], held["opencv"]
    return {
        "threads": threads,
        "views_points": f"{len(obj)} x {len(obj[0])}",
        "circcal_refine_board_s": summary(t["circcal"]),
        "circcal_with_outlier_rejection_s": summary(t["with_outliers"]),
        "opencv_calibrateCameraRO_s": summary(t["opencv"]),
        "ratio_circcal_to_opencv": r,
        "ratio_with_outliers_to_opencv": ratio(t["with_outliers"], t["opencv"]),
        "bar": f"<= {BAR:g}x calibrateCameraRO: {'met' if r['max'] <= BAR else 'MISSED'}",
        "fx_circcal_opencv_px": f"{res.camera.fx:.6f} / {cv[1][0, 0]:.6f}",
        "rms_per_point_circcal_opencv_px": f"{res.errors['rms_per_point_px']:.8f} / {cv[0]:.8f}",
    }
