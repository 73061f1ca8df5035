"""Detector timing on 1920x1080 renders: circcal ``detect`` against ``cv2.findCirclesGrid`` in the same run.

``run() -> dict`` (part of ``make bench``): per-image wall time (best of ``repeats`` runs, median over
views) of both, timed alternately on the same images, the ratio circcal / OpenCV, circcal's time with the
segmentation forced to full resolution (the path whose centres equal the original per-dot detector to ~1e-7 px,
float32 smoothing), and circcal's peak Python-heap memory per image (tracemalloc sees numpy's buffers; OpenCV's own C++ buffers are not
seen).
"""
from __future__ import annotations

import time
import tracemalloc

import cv2
import numpy as np


def _views(n: int = 4):
    from circcal.board import Board
    from circcal.model import Camera
    from fixtures.poses import sample_poses
    from fixtures.render import render_view, to_uint

    cam = Camera(1920, 1080, 4900.0, 4902.5, 963.7, 536.2)  # the paper's camera, 7x7 dots
    board = Board(7, 7, 10.0, 5.0)
    imgs = [to_uint(render_view(cam, board, r, t), 8) for r, t in sample_poses(cam, board, n, seed=1, max_tilt_deg=45)]
    return imgs, board


def _best(fn, repeats: int) -> tuple[float, object]:
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def run(n_views: int = 4, repeats: int = 5) -> dict:
    import circcal.detect as det

    imgs, board = _views(n_views)
    flags = cv2.CALIB_CB_SYMMETRIC_GRID
    t_ours, t_full, t_cv = [], [], []
    found_ours = found_cv = 0
    scales = det._segmentation_scales
    for img in imgs:
        det.detect(img, board)  # warm-up (imports, tables)
        t, d = _best(lambda: det.detect(img, board), repeats)
        t_ours.append(t)
        found_ours += d.found
        t, (ok, _) = _best(lambda: cv2.findCirclesGrid(img, board.pattern_size, flags=flags), repeats)
        t_cv.append(t)
        found_cv += bool(ok)
        det._segmentation_scales = lambda h, w: (1,)
        try:
            t_full.append(_best(lambda: det.detect(img, board), repeats)[0])
        finally:
            det._segmentation_scales = scales
    tracemalloc.start()
    det.detect(imgs[0], board)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    ours, cvt = float(np.median(t_ours)), float(np.median(t_cv))
    return {
        "image": "1920x1080 uint8, 7x7 symmetric grid (paper setup)",
        "views": len(imgs),
        "circcal_detect_s_per_image": ours,
        "opencv_findCirclesGrid_s_per_image": cvt,
        "ratio_circcal_over_opencv": ours / cvt,
        "circcal_detect_fullres_segmentation_s_per_image": float(np.median(t_full)),
        "circcal_found": int(found_ours),
        "opencv_found": int(found_cv),
        "circcal_peak_python_memory_mb": peak / 2 ** 20,
    }


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=1))
