"""Detection at any resolution (issue 17), on rendered images, against the truth (no timing: speed is in
benchmarks/bench_detect.py): 7x7 boards of dots 6, 8 and 12 px across in a 4000x3000 frame, and a 7x7 board spanning
300 px in an 8000x6000 frame, each on a darker background with sensor noise (what a global threshold or a
contrast stretch over the whole frame loses: the board is 0.04-0.2 % of the pixels)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from circcal.board import Board
from circcal.detector import detect
from circcal.fixtures.poses import pose_looking_at
from circcal.fixtures.render import render_view, to_uint
from circcal.model import Camera, project

BOARD = Board(7, 7, 10.0, 5.0)
NOISE = 0.005
"""Sensor noise, in units of the full range (the background's and the board's)."""
BACKGROUND = 0.3
"""The frame's level around the board (the renderer's background level)."""


def embedded_board(width: int, height: int, radius_px: float, centre: tuple[float, float], *, f: float = 4000.0,
                   tilt_deg: float = 25.0, crop: tuple[int, int] = (800, 600), seed: int = 0
                   ) -> tuple[np.ndarray, np.ndarray]:
    """((H, W) uint8 image, (N, 2) true centres px): ``BOARD`` with dots of ``radius_px`` seen by a pinhole camera
    of focal length ``f`` px (principal point at the frame centre) at ``tilt_deg``, centred at ``centre``; rendered
    exactly in a ``crop`` window (the same camera with its principal point moved) and pasted into a noisy frame."""
    cw, ch = crop
    x0, y0 = int(centre[0] - cw / 2), int(centre[1] - ch / 2)
    cam = Camera(cw, ch, f, f, width / 2 - 0.5 - x0, height / 2 - 0.5 - y0)
    rvec, tvec = pose_looking_at(cam, BOARD, distance_mm=f * BOARD.radius_mm / radius_px, tilt_deg=tilt_deg,
                                 tilt_axis_deg=30.0, roll_deg=10.0, target_px=(cw / 2, ch / 2))
    rng = np.random.default_rng(seed)
    frame = np.empty((height, width), np.uint8)
    cv2.randn(frame, BACKGROUND * 255, NOISE * 255)
    win = render_view(cam, BOARD, rvec, tvec) + rng.normal(0, NOISE, (ch, cw))
    frame[y0:y0 + ch, x0:x0 + cw] = to_uint(win, 8)
    return frame, project(BOARD.object_points(), rvec, tvec, cam) + [x0, y0]


@pytest.mark.parametrize("size,dot_px,centre", [
    ((4000, 3000), 6.0, (1300.0, 1700.0)),
    ((4000, 3000), 8.0, (2600.0, 900.0)),
    ((4000, 3000), 12.0, (2000.0, 1500.0)),
    ((8000, 6000), 20.0, (5200.0, 2100.0)),      # pitch 40 px: the board spans ~300 px
])
def test_small_board_or_small_dots_in_a_large_frame(size, dot_px, centre):
    img, truth = embedded_board(*size, dot_px / 2, centre)
    span = float(np.ptp(truth, axis=0).max())
    d = detect(img, BOARD, time_budget_s=None)
    assert d.found, d.reason
    assert d.complete and np.all(np.isfinite(d.centres))
    e = np.min([np.linalg.norm(d.centres - truth[s.perm], axis=1).max() for s in BOARD.symmetries()])
    print(f"\n{size[0]}x{size[1]}, dots {dot_px:g} px, board spanning {span:.0f} px: found at {d.segmentation}, "
          f"max centre error {e:.4f} px")
    if size == (8000, 6000):
        assert 280 <= span <= 320
    assert e < 0.05    # 6 px dots under noise 0.005: measured <= 0.016 px
