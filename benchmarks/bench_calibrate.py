"""Solve time of circcal's calibration against ``cv2.calibrateCameraExtended`` on the same points, and the whole
pipeline against OpenCV's, every ratio timed alternately (benchmarks/timing.py: medians with min-max, threads pinned
and stated).

* Solver: identical float32-rounded observations of a 7x7 board (0.1 px noise, 1920x1080, f 1500, moderate
  distortion), 14 views and 1000 views; each solve to its tightest tolerance (circcal: closed-form start +
  Levenberg-Marquardt + covariance; OpenCV: calibrateCameraExtended, which also computes the standard deviations).
  Goals (issue "Speed that holds on any machine"): <= 0.7x at 14 views with the same minimum to 1e-9 relative,
  <= 0.4x at 1000 views.
* Pipeline, in process: the `paper` scenario (normal light, 14 rendered 1920x1080 views): ``calibrate_images``
  (detect, calibrate, re-correct, recalibrate until the centres settle) against OpenCV's pipeline on the same images
  (findCirclesGrid + calibrateCameraExtended, circcal.validators.opencv), both one image at a time, and circcal
  with its default parallel detection.
* Pipeline, whole processes: ``circcal calibrate`` on the 14 paper images against a plain Python script that imports
  cv2, runs findCirclesGrid on each image and calibrateCamera (goal <= 1.2x), with each process's peak memory.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.timing import alternate, alternate_processes, pinned, ratio, summary

#: Repeats of the 1000-view solves (each takes seconds; still the minimum of the alternation rule).
REPEATS_LARGE = 9

OPENCV_SCRIPT = """\
import sys
import cv2
import numpy as np
rows, cols, pitch = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
obj = np.zeros((rows * cols, 3), np.float32)
obj[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * pitch
objs, imgs, size = [], [], None
for path in sys.argv[4:]:
    img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    size = img.shape[::-1]
    ok, c = cv2.findCirclesGrid(img, (cols, rows), flags=cv2.CALIB_CB_SYMMETRIC_GRID)
    if ok:
        objs.append(obj)
        imgs.append(c)
rms, K, d, _, _ = cv2.calibrateCamera(objs, imgs, size, None, None)
print(len(objs), rms, K[0, 0])
"""


def _problem(n_views: int, seed: int = 0):
    from circcal.board import Board
    from circcal.fixtures.poses import sample_poses
    from circcal.model import Camera, project

    cam = Camera(1920, 1080, 1500.0, 1502.0, 955.0, 545.0, np.array([-0.2, 0.1, 0.001, -0.0005, -0.02]))
    board = Board(7, 7, 10.0, 5.0)
    rng = np.random.default_rng(seed)
    poses = sample_poses(cam, board, n_views, seed, max_tilt_deg=40.0)
    obj = [board.object_points().astype(np.float32) for _ in poses]
    img = [(project(board.object_points(), r, t, cam) + rng.normal(0.0, 0.1, (49, 2))).astype(np.float32)
           for r, t in poses]
    return obj, img, (cam.width, cam.height)


def _solver(n_views: int, repeats: int) -> dict:
    import cv2

    from circcal.solver import calibrate

    obj, img, size = _problem(n_views)
    obj64 = [o.astype(np.float64) for o in obj]
    img64 = [p.astype(np.float64) for p in img]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 1000, 1e-15)
    out = {}
    t = alternate({"circcal": lambda: out.__setitem__("res", calibrate(obj64, img64, size)),
                   "opencv": lambda: out.__setitem__("ref", cv2.calibrateCameraExtended(obj, img, size, None, None,
                                                                                           criteria=crit))},
                  repeats=repeats)
    K, d = out["ref"][1], out["ref"][2].ravel()
    ref_p = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d[:5]])
    p = out["res"].camera.intrinsics
    key = f"solve_{n_views}_views"
    return {f"{key}_points": int(sum(len(o) for o in obj)), f"{key}_circcal_s": summary(t["circcal"]),
            f"{key}_opencv_s": summary(t["opencv"]), f"{key}_ratio": ratio(t["circcal"], t["opencv"]),
            f"{key}_iterations": out["res"].n_iterations,
            f"{key}_max_rel_param_diff_vs_opencv": float(np.max(np.abs(p - ref_p) / np.abs(ref_p)))}


def _pipeline(repeats: int) -> dict:
    """Whole-pipeline timings on the paper fixture in this process (rendering not timed: cached)."""
    from circcal.fixtures.scenarios import DEFAULT_SCENARIO, fixture_dir, load_truth
    from circcal.pipeline import calibrate_images
    from circcal.validators.opencv import OpenCVCalibrator

    truth = load_truth(fixture_dir(DEFAULT_SCENARIO, "normal"))
    paths = [v.image for v in truth.views]
    size = (truth.camera.width, truth.camera.height)
    held: dict = {}
    t = alternate({"circcal": lambda: held.__setitem__("cal", calibrate_images(paths, truth.board, progress=False,
                                                                                  jobs=1)),
                   "opencv": lambda: OpenCVCalibrator().calibrate_images(paths, truth.board, size),
                   "circcal_parallel": lambda: calibrate_images(paths, truth.board, progress=False, jobs=None)},
                  repeats=repeats)
    return {"paper_pipeline_views": len(paths), "paper_circcal_rounds": len(held["cal"].rounds),
            "paper_circcal_calibrate_s": summary(t["circcal"]), "paper_opencv_pipeline_s": summary(t["opencv"]),
            "paper_pipeline_ratio": ratio(t["circcal"], t["opencv"]),
            "paper_circcal_calibrate_parallel_s": summary(t["circcal_parallel"]),
            "paper_pipeline_parallel_ratio": ratio(t["circcal_parallel"], t["opencv"])}


def _whole_process(repeats: int) -> dict:
    from circcal.fixtures.scenarios import DEFAULT_SCENARIO, fixture_dir, load_truth

    truth = load_truth(fixture_dir(DEFAULT_SCENARIO, "normal"))
    b = truth.board
    paths = [str(v.image) for v in truth.views]
    circcal = Path(sys.executable).with_name("circcal")
    with tempfile.TemporaryDirectory() as tmp:
        script = Path(tmp) / "opencv_calibrate.py"
        script.write_text(OPENCV_SCRIPT)
        t = alternate_processes({
            "circcal": [str(circcal), "calibrate", *paths, "--grid", f"{b.rows}x{b.cols}", "--pitch",
                        f"{b.pitch_mm}mm", "--diameter", f"{b.diameter_mm}mm", "--no-progress", "--out",
                        str(Path(tmp) / "model.json")],
            "opencv": [sys.executable, str(script), str(b.rows), str(b.cols), str(b.pitch_mm), *paths]},
            repeats=repeats)
    return {"process_calibrate_circcal_s": summary(t["circcal"]["wall_s"]),
            "process_calibrate_opencv_s": summary(t["opencv"]["wall_s"]),
            "process_calibrate_ratio": ratio(t["circcal"]["wall_s"], t["opencv"]["wall_s"]),
            "process_calibrate_circcal_peak_mib": summary(t["circcal"]["peak_mib"]),
            "process_calibrate_opencv_peak_mib": summary(t["opencv"]["peak_mib"]),
            "process_note": "circcal calibrate (default parallel detection) vs a plain cv2 script: findCirclesGrid "
                            "on each image + calibrateCamera, both whole processes, start-up included"}


def run(repeats: int = 15) -> dict:
    with pinned(1) as threads:
        out = {"threads": threads, **_solver(14, repeats), **_solver(1000, REPEATS_LARGE), **_pipeline(9)}
    out.update(_whole_process(9))
    return out


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=2))
