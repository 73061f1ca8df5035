"""Detector timing on 1920x1080 renders: circcal ``detect`` against ``cv2.findCirclesGrid`` in the same run.

``run() -> dict`` (part of ``make bench``): per-image wall time (best of ``repeats`` runs, the two detectors timed
alternately on the same image so a change of machine load hits both, median over views), the ratio circcal /
OpenCV, with OpenCV's thread pool at one thread (the fair per-core comparison; circcal's compiled loops are
single-threaded) and at its default size (what a user gets; circcal's OpenCV calls use it too); circcal's time with
the segmentation forced to full resolution, and circcal's peak Python-heap memory per image (tracemalloc sees
numpy's buffers; OpenCV's own C++ buffers and numba's are not seen). The first call in a fresh process also pays
numba's compile or cache load: reported separately, not in the per-image time.
"""
from __future__ import annotations

import time
import tracemalloc

import cv2
import numpy as np


def _views(n: int = 4):
    from circcal.board import Board
    from circcal.model import Camera
    from circcal.fixtures.poses import sample_poses
    from circcal.fixtures.render import render_view, to_uint

    cam = Camera(1920, 1080, 4900.0, 4902.5, 963.7, 536.2)  # the paper's camera, 7x7 dots
    board = Board(7, 7, 10.0, 5.0)
    imgs = [to_uint(render_view(cam, board, r, t), 8) for r, t in sample_poses(cam, board, n, seed=1, max_tilt_deg=45)]
    return imgs, board


def _alternating(fns, repeats: int) -> list[tuple[float, object]]:
    """Best wall time and last result of each of ``fns``, timed in turn ``repeats`` times."""
    best = [np.inf] * len(fns)
    out = [None] * len(fns)
    for _ in range(repeats):
        for i, fn in enumerate(fns):
            t0 = time.perf_counter()
            out[i] = fn()
            best[i] = min(best[i], time.perf_counter() - t0)
    return list(zip(best, out))


def run(n_views: int = 4, repeats: int = 7) -> dict:
    import circcal.detector.find as det

    imgs, board = _views(n_views)
    flags = cv2.CALIB_CB_SYMMETRIC_GRID
    t0 = time.perf_counter()
    det.detect(imgs[0], board)  # first call: numba's compile (or cache load), imports, tables
    first_call = time.perf_counter() - t0
    threads = cv2.getNumThreads()   # restored afterwards (another benchmark may have set one thread)
    cv2.setNumThreads(-1)           # OpenCV's default pool
    default = cv2.getNumThreads()
    res: dict[str, list[float]] = {"ours1": [], "cv1": [], "ours": [], "cv": [], "full": []}
    found_ours = found_cv = 0
    scales = det.segmentation_scales
    try:
        for img in imgs:
            ours = lambda: det.detect(img, board)  # noqa: E731
            cvf = lambda: cv2.findCirclesGrid(img, board.pattern_size, flags=flags)  # noqa: E731
            cv2.setNumThreads(1)
            (t_o, d), (t_c, (ok, _)) = _alternating([ours, cvf], repeats)
            res["ours1"].append(t_o)
            res["cv1"].append(t_c)
            found_ours += d.found
            found_cv += bool(ok)
            cv2.setNumThreads(default)
            (t_o, _), (t_c, _) = _alternating([ours, cvf], repeats)
            res["ours"].append(t_o)
            res["cv"].append(t_c)
            cv2.setNumThreads(1)
            det.segmentation_scales = lambda h, w: (1,)
            res["full"].append(_alternating([ours], max(2, repeats // 2))[0][0])
            det.segmentation_scales = scales
    finally:
        det.segmentation_scales = scales
        cv2.setNumThreads(threads)
    tracemalloc.start()
    det.detect(imgs[0], board)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    med = {k: float(np.median(v)) for k, v in res.items()}
    return {
        "image": "1920x1080 uint8, 7x7 symmetric grid (paper setup)",
        "views": len(imgs),
        "circcal_detect_s_per_image": med["ours1"],
        "opencv_findCirclesGrid_s_per_image": med["cv1"],
        "ratio_circcal_over_opencv": med["ours1"] / med["cv1"],
        "opencv_default_threads": default,
        "circcal_detect_s_per_image_default_threads": med["ours"],
        "opencv_findCirclesGrid_s_per_image_default_threads": med["cv"],
        "ratio_circcal_over_opencv_default_threads": med["ours"] / med["cv"],
        "circcal_detect_fullres_segmentation_s_per_image": med["full"],
        "circcal_first_call_s": first_call,
        "circcal_found": int(found_ours),
        "opencv_found": int(found_cv),
        "circcal_peak_python_memory_mb": peak / 2 ** 20,
    }


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=1))
