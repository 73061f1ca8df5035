"""Renderer speed: one 1920x1080 view of the `paper` scenario, geometry and full variant pipeline, on one core."""

from __future__ import annotations

import time

import numpy as np


def run(repeats: int = 3) -> dict:
    import cv2

    from circcal.fixtures.perturb import apply_perturbations
    from circcal.fixtures.render import render_coverage
    from circcal.fixtures.scenarios import get_scenario

    cv2.setNumThreads(1)
    sc = get_scenario("paper")
    poses = sc.poses()[:repeats]
    geo, full = [], []
    for rvec, tvec in poses:
        t0 = time.perf_counter()
        bc, dc = render_coverage(sc.camera, sc.board, rvec, tvec, supersample=sc.supersample)
        t1 = time.perf_counter()
        lv = sc.levels
        img = lv.background + bc * (lv.board - lv.background) - dc * (lv.board - lv.dark)
        apply_perturbations(img, sc.variants["uneven"], 0, board_mask=bc > 0.5)
        t2 = time.perf_counter()
        geo.append(t1 - t0)
        full.append(t2 - t0)
    return {
        "render_view_s": float(np.median(geo)),
        "render_view_with_perturbations_s": float(np.median(full)),
        "image": f"{sc.camera.width}x{sc.camera.height}",
        "goal_s": 2.0,
        "note": "median over views of scenario `paper`, one thread",
    }
