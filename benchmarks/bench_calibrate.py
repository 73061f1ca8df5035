"""Solve time of circcal's calibration vs ``cv2.calibrateCamera`` on the same 14-view points.

Both get identical float32-rounded observations (7x7 board, 14 tilted views, 0.1 px noise, 1920x1080, f 1500,
moderate distortion) and solve to their tightest tolerance; the time is the median of repeated full solves
(closed-form start + refinement + covariance for circcal; calibrateCameraExtended, which also computes the
standard deviations, for OpenCV). ``ratio`` = circcal / OpenCV (goal <= 1.0).

Also the whole pipeline on the `paper` scenario (normal light, 14 rendered 1920x1080 views): ``circcal calibrate``'s
work (detect, calibrate, re-correct, recalibrate until the centres settle) against OpenCV's pipeline on the same
images (findCirclesGrid + calibrateCameraExtended, circcal.validators.opencv), both one image at a time; and circcal with
its images detected in parallel (``jobs=None``: one thread per CPU, what ``circcal calibrate`` does by default).
"""
from __future__ import annotations

import time

import numpy as np


def _problem():
    from circcal.board import Board
    from circcal.model import Camera, project
    from circcal.fixtures.poses import sample_poses

    cam = Camera(1920, 1080, 1500.0, 1502.0, 955.0, 545.0, np.array([-0.2, 0.1, 0.001, -0.0005, -0.02]))
    board = Board(7, 7, 10.0, 5.0)
    rng = np.random.default_rng(0)
    poses = sample_poses(cam, board, 14, 0, max_tilt_deg=40.0)
    obj = [board.object_points().astype(np.float32) for _ in poses]
    img = [(project(board.object_points(), r, t, cam) + rng.normal(0.0, 0.1, (49, 2))).astype(np.float32)
           for r, t in poses]
    return obj, img, (cam.width, cam.height)


def _median_time(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def _pipeline(repeats: int = 3) -> dict:
    """Whole-pipeline timings on the paper fixture (rendering not timed: cached)."""
    from circcal.pipeline import calibrate_images
    from circcal.fixtures.scenarios import DEFAULT_SCENARIO, fixture_dir, load_truth
    from circcal.validators.opencv import OpenCVCalibrator

    truth = load_truth(fixture_dir(DEFAULT_SCENARIO, "normal"))
    paths = [v.image for v in truth.views]
    size = (truth.camera.width, truth.camera.height)
    holder: dict = {}

    def ours(jobs):
        holder["cal"] = calibrate_images(paths, truth.board, progress=False, jobs=jobs)

    t_ours = _median_time(lambda: ours(1), repeats)
    t_cv = _median_time(lambda: OpenCVCalibrator().calibrate_images(paths, truth.board, size), repeats)
    t_par = _median_time(lambda: ours(None), repeats)
    cal = holder["cal"]
    return {"paper_pipeline_views": len(paths), "paper_circcal_calibrate_s": t_ours,
            "paper_circcal_rounds": len(cal.rounds), "paper_opencv_pipeline_s": t_cv,
            "paper_pipeline_ratio": t_ours / t_cv, "paper_circcal_calibrate_parallel_s": t_par,
            "paper_pipeline_parallel_ratio": t_par / t_cv}


def run(repeats: int = 15) -> dict:
    import cv2

    from circcal.solver import calibrate

    obj, img, size = _problem()
    obj64 = [o.astype(np.float64) for o in obj]
    img64 = [p.astype(np.float64) for p in img]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 1000, 1e-15)
    threads = cv2.getNumThreads()
    t_cv = _median_time(lambda: cv2.calibrateCameraExtended(obj, img, size, None, None, criteria=crit), repeats)
    cv2.setNumThreads(1)
    t_cv1 = _median_time(lambda: cv2.calibrateCameraExtended(obj, img, size, None, None, criteria=crit), repeats)
    cv2.setNumThreads(threads)
    t_cc = _median_time(lambda: calibrate(obj64, img64, size), repeats)
    t_sp = _median_time(lambda: calibrate(obj64, img64, size, solver="scipy"), max(3, repeats // 5))
    res = calibrate(obj64, img64, size)
    # the parameter check against one cv2 thread: its parallel reductions vary ~1e-7..1e-5 relative run to run
    cv2.setNumThreads(1)
    ref = cv2.calibrateCamera(obj, img, size, None, None, criteria=crit)
    cv2.setNumThreads(threads)
    K, d = ref[1], ref[2].ravel()
    ref_p = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d[:5]])
    return {
        "views": len(obj),
        "points": int(sum(len(o) for o in obj)),
        "circcal_s": t_cc,
        "circcal_scipy_s": t_sp,
        "opencv_s": t_cv,
        "opencv_1thread_s": t_cv1,
        "ratio": t_cc / t_cv,
        "ratio_vs_1thread": t_cc / t_cv1,
        "circcal_iterations": res.n_iterations,
        "max_rel_param_diff_vs_opencv": float(np.max(np.abs(res.camera.intrinsics - ref_p) / np.abs(ref_p))),
        **_pipeline(),
    }


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=2))
