"""Detection at any resolution (issue 17), on rendered images, against the truth (no timing: speed is in
benchmarks/bench_detect.py): 7x7 boards of dots 6, 8 and 12 px across in a 4000x3000 frame, of dots 6 px across in
an 8000x6000 (48 MP) frame, and a 7x7 board spanning 300 px in an 8000x6000 frame, each on a darker background with
sensor noise (what a global threshold or a contrast stretch over the whole frame loses: the board is 0.02-0.2 % of
the pixels); boards only a few noise sigmas deep, found on coarser block means; frames of noise alone refused at
every scale."""

from __future__ import annotations

import numpy as np
import pytest

from circcal.board import Board
from circcal.detector import detect
from circcal.fixtures.frames import embedded_board

BOARD = Board(7, 7, 10.0, 5.0)


@pytest.mark.parametrize(
    "size,dot_px,centre",
    [
        ((4000, 3000), 6.0, (1300.0, 1700.0)),
        ((4000, 3000), 8.0, (2600.0, 900.0)),
        ((4000, 3000), 12.0, (2000.0, 1500.0)),
        ((8000, 6000), 20.0, (5200.0, 2100.0)),  # pitch 40 px: the board spans ~300 px
        ((8000, 6000), 6.0, (6200.0, 4600.0)),  # the floor at its largest frame: 6 px dots in 48 MP
    ],
)
def test_small_board_or_small_dots_in_a_large_frame(size, dot_px, centre):
    img, truth = embedded_board(BOARD, *size, dot_px / 2, centre)
    span = float(np.ptp(truth, axis=0).max())
    d = detect(img, BOARD, time_budget_s=None)
    assert d.found, d.reason
    assert d.complete and np.all(np.isfinite(d.centres))
    e = np.min([np.linalg.norm(d.centres - truth[s.perm], axis=1).max() for s in BOARD.symmetries()])
    print(
        f"\n{size[0]}x{size[1]}, dots {dot_px:g} px, board spanning {span:.0f} px: found at {d.segmentation}, "
        f"max centre error {e:.4f} px"
    )
    if size == (8000, 6000) and dot_px == 20.0:
        assert 280 <= span <= 320
    assert e < 0.05  # 6 px dots under noise 0.005: measured <= 0.016 px


def test_a_large_frame_of_noise_is_not_segmented_into_speckle():
    # a 12 MP frame of noise alone: the stretch would blow the noise up to the full range and every mask would hold
    # ~850,000 specks (40 s of contour search each); the noise is measured and such scales and masks are skipped
    import cv2

    from circcal.detector.locate.segment import MAX_STRETCHED_NOISE, MAX_TRANSITIONS, noise_sigma_u8, speckled

    rng = np.random.default_rng(3)
    noise = rng.normal(128, 20, (400, 600)).clip(0, 255).astype(np.uint8)
    assert noise_sigma_u8(noise) == pytest.approx(20, rel=0.15)
    assert noise_sigma_u8(np.full((50, 60), 7, np.uint8)) == 0.0
    assert noise_sigma_u8(noise) < 2 * MAX_STRETCHED_NOISE  # a noisy but real image stays in
    assert speckled(np.where(noise > 128, 255, 0).astype(np.uint8))
    blobs = np.zeros((400, 600), np.uint8)
    for x in range(20, 600, 40):
        for y in range(20, 400, 40):
            cv2.circle(blobs, (x, y), 10, 255, -1)
    assert not speckled(blobs) and MAX_TRANSITIONS > 0.3
    frame = np.empty((3000, 4000), np.uint8)
    cv2.setRNGSeed(1)
    cv2.randn(frame, 77, 1.3)
    d = detect(frame, BOARD, time_budget_s=None)
    assert not d.found and d.code.value in ("too-few-candidates", "grid-not-recognised")


@pytest.mark.parametrize("contrast", [0.15, 0.1])
def test_a_board_a_few_noise_sigmas_deep_is_found_where_its_pixels_are_averaged(contrast):
    # the paper's weak light at 640x480 with 3x its noise: the dots stand only 5-7 noise sigmas below the white, so
    # the stretched image is too noisy to threshold (above MAX_STRETCHED_NOISE); its 2x2 block means (half the
    # noise) are segmented instead, the edges measured at full resolution. findCirclesGrid finds none of these
    # views, with its blob detector's minThreshold at 5 neither. Measured centre RMS against the truth: 0.11-0.14 px
    # at contrast 0.15, 0.15-0.18 px at 0.1 (the noise's share: 0.08 px at contrast 0.22, ~1 / contrast)
    from circcal.detector.image import normalise_u8
    from circcal.detector.locate.segment import MAX_STRETCHED_NOISE, noise_sigma_u8
    from circcal.fixtures.perturb import apply_perturbations
    from circcal.fixtures.poses import sample_poses
    from circcal.fixtures.render import render_view
    from circcal.model import Camera, project

    f = 4900.0 * 640 / 1920.0
    cam = Camera(640, 480, f, f, 319.5, 239.5)
    steps = [
        {"kind": "gaussian_blur", "sigma_px": 0.7},
        {"kind": "weak", "contrast": contrast, "offset": 0.04},
        {"kind": "noise", "sigma": 0.02, "full_well": 3000},
    ]
    for k, (r, t) in enumerate(sample_poses(cam, BOARD, 3, seed=1, max_tilt_deg=45)):
        img, _, _ = apply_perturbations(render_view(cam, BOARD, r, t), steps, 1000 + k)
        assert noise_sigma_u8(normalise_u8(img)) > MAX_STRETCHED_NOISE  # full resolution: noise only
        d = detect(img, BOARD)
        assert d.found, d.reason
        assert "@1/" in d.segmentation  # found on block means
        e = np.linalg.norm(d.centres - project(BOARD.object_points(), r, t, cam), axis=1)
        assert np.sqrt(np.nanmean(e**2)) < 0.25, k


def test_noise_alone_stays_noise_at_every_scale():
    # the stretch scales pure noise to the whole range at any scale (~50 grey levels of noise), so the coarser
    # scales a too-noisy image is sent on to hold no candidates either
    from circcal.detector.image import normalise_u8
    from circcal.detector.locate.segment import MAX_STRETCHED_NOISE, noise_sigma_u8, shrink

    noise = np.random.default_rng(5).normal(128, 30, (480, 640)).clip(0, 255).astype(np.uint8)
    for s in (1, 2, 4):
        assert noise_sigma_u8(normalise_u8(shrink(noise, s) if s > 1 else noise)) > MAX_STRETCHED_NOISE
    d = detect(noise, BOARD)
    assert not d.found and d.code.value == "too-few-candidates"
    assert "only noise at every scale" in d.reason  # said so, with its level
