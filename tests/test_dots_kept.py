"""Issue 33: no good dot thrown away. A dot printed paler than the rest under uneven light, a low-contrast print on
a textured matte plate, declared markers in the bad-dot check, and a blob beside a board that is not a row of it:
each rendered with exact truth (:mod:`circcal.fixtures.texture`)."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np

from circcal.board import Board
from circcal.detector import detect
from circcal.detector.measure.baddots import UNEVEN_SHARE, _uneven_inside
from circcal.detector.measure.ellipse import conic_params_batch
from circcal.dotcheck import bad_dots as dotcheck_bad_dots
from circcal.fixtures.poses import pose_looking_at, sample_poses
from circcal.fixtures.render import to_uint
from circcal.fixtures.texture import border_specks, texture_gain, textured_view
from circcal.model import Camera


def test_a_paler_dot_under_a_spotlight_is_kept_and_accurate():
    # a spotlight's flank tilts the inside of a dot printed at 60 % contrast (dark-to-white 0.4) four times as much
    # as a full-contrast one's: the old measure (_uneven_inside) put them past UNEVEN_SHARE; the edge model follows
    # light that multiplies the albedo, so they are measured, and well
    cam = Camera(1280, 960, 1500.0, 1500.0, 639.5, 479.5)
    board = Board(7, 7, 10.0, 6.0)
    r, t = pose_looking_at(cam, board, distance_mm=250, tilt_deg=20, tilt_axis_deg=30, roll_deg=5, target_px=(640, 480))
    yy, xx = np.mgrid[:960, :1280]
    spot = 0.35 + 0.65 * np.exp(-((xx - 560) ** 2 + (yy - 420) ** 2) / (2 * 150.0**2))
    pale = {10: 0.6, 40: 0.6}
    img, truth = textured_view(cam, board, r, t, spot, white=0.9, dark=0.1, pale=pale)
    u8 = to_uint(img, 8)
    d = detect(u8, board, cam)
    assert d.found and not d.dropped, d.dropped
    err = np.linalg.norm(d.centres - truth, axis=1)
    assert err[list(pale)].max() < 0.01
    c, ax, an, _ = conic_params_batch(np.asarray(d.conics)[list(pale)])
    assert np.all(_uneven_inside(u8.astype(np.float32), c, ax, an) > UNEVEN_SHARE)  # the scene is the issue's


def _textured_views(n: int, seed: int, specks: bool = False):
    cam = Camera(1920, 1080, 1400.0, 1400.0, 959.5, 539.5)
    board = Board(14, 16, 4.0, 2.0)
    for k, (r, t) in enumerate(sample_poses(cam, board, n, seed=seed, max_tilt_deg=40, fill=(0.5, 0.75))):
        gain = texture_gain(cam.height, cam.width, seed * 100 + k, low=0.08, grain=0.05, grain_sigma_px=4.0)
        img, truth = textured_view(cam, board, r, t, gain, white=0.75, dark=0.45)
        if specks:  # a speck of the plate one pitch beyond the board's first row's last dot
            step = truth[board.cols - 1] - truth[board.cols - 2]
            rad = np.array([0.15 * np.linalg.norm(step)])  # 0.6 of a dot's radius: within the lattice's area ratio
            img = border_specks(img, truth[board.cols - 1 : board.cols] + step, rad, 0.4, k)
        img = cv2.GaussianBlur(img, (0, 0), 0.8) + np.random.default_rng(k).normal(0.0, 0.003, img.shape)
        yield cam, board, to_uint(img, 8), truth


def test_a_textured_low_contrast_plate_keeps_its_dots():
    # grain of 5 % of the white at 4 px under a print of 0.4 of the white: it darkened arcs of a quarter of the
    # rings (a dark object touches it, 3-6 %) with nothing there; the clearance level follows the view's texture
    kept = total = 0
    for cam, board, img, _ in _textured_views(2, 3):
        d = detect(img, board, cam)
        assert d.found, d.reason
        kept += int(np.sum(np.all(np.isfinite(d.centres), axis=1)))
        total += board.n_points
    assert kept >= 0.98 * total


def test_a_matte_card_keeps_its_dots_and_each_within_two_hundredths():
    # issue 33's "no dot biased beyond 0.02 px kept, >= 98 % kept" at a matte card's texture under a black print:
    # grain 0.5 % of the white over 1 px, mottling 3 % over 60 px (reports/dots-kept.md: measured 0.012-0.016 px at
    # worst; the error grows with the grain over the print's contrast, ~8 px per unit of grain at 1 px here, and no
    # rule can tell which dot carries it: the table there)
    cam = Camera(1920, 1080, 1400.0, 1400.0, 959.5, 539.5)
    board = Board(14, 16, 4.0, 2.0)
    kept = total = 0
    worst = 0.0
    for k, (r, t) in enumerate(sample_poses(cam, board, 2, seed=3, max_tilt_deg=40, fill=(0.5, 0.75))):
        gain = texture_gain(cam.height, cam.width, 300 + k, low=0.03, grain=0.005, grain_sigma_px=1.0)
        img, truth = textured_view(cam, board, r, t, gain, white=0.75, dark=0.1)
        img = cv2.GaussianBlur(img, (0, 0), 0.8) + np.random.default_rng(k).normal(0.0, 0.003, img.shape)
        d = detect(to_uint(img, 8), board, cam)
        assert d.found, d.reason
        seen = np.all(np.isfinite(d.centres), axis=1)
        kept += int(seen.sum())
        total += board.n_points
        worst = max(worst, float(np.linalg.norm(d.centres[seen] - truth[seen], axis=1).max()))
    assert kept >= 0.98 * total
    assert worst <= 0.02


def test_an_occluder_on_a_textured_plate_is_still_caught():
    cam, board, img, truth = next(_textured_views(1, 5))
    f = img.astype(np.float64)
    p = board.cols * 6 + 7  # a dark bar whose edge runs 1.5 px outside one dot's rim
    c, ax, _, _ = conic_params_batch(np.asarray(detect(img, board, cam).conics)[p : p + 1])
    x0 = int(round(c[0, 0] + ax[0, 0] + 1.5))
    f[:, x0 : x0 + 25] = 30.0
    d = detect(np.clip(f, 0, 255).astype(np.uint8), board, cam)
    assert d.found and p in d.dropped, d.dropped.get(p)


def test_a_speck_beside_a_declared_grid_is_not_a_larger_board():
    for cam, board, img, truth in _textured_views(2, 7, specks=True):
        d = detect(img, board, cam)
        assert d.found, d.reason
        seen = np.all(np.isfinite(d.centres), axis=1)
        assert np.linalg.norm(d.centres[seen] - truth[seen], axis=1).max() < 1.0  # every label right


def test_dotcheck_compares_markers_with_their_printed_size():
    # ROS-I's origin dot, 1.6x the diameter: 2.56x the area of its neighbours, as printed
    board = Board(4, 5, 10.0, 5.0, markers=(15,), marker_diameter_mm=8.0)
    r = board.radii_mm() * 3.0  # px
    conics = np.zeros((board.n_points, 3, 3))
    centres = board.object_points()[:, :2] * 3.0
    for k, ((x, y), rad) in enumerate(zip(centres, r)):
        conics[k] = [[1, 0, -x], [0, 1, -y], [-x, -y, x * x + y * y - rad * rad]]
    th = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    rim = [c + rad * np.column_stack([np.cos(th), np.sin(th)]) for c, rad in zip(centres, r)]
    det = SimpleNamespace(dropped={}, edge_points=rim, conics=conics)
    assert [b.index for b in dotcheck_bad_dots(det, 4, 5)] == [15]  # sizes unknown: flagged
    assert dotcheck_bad_dots(det, 4, 5, board.radii_mm()) == []
    plain = Board(4, 5, 10.0, 5.0)  # undeclared: a larger dot is an orientation dot, kept; a smaller one is not
    assert dotcheck_bad_dots(det, 4, 5, plain.radii_mm()) == []
    conics[3, 2, 2] = centres[3] @ centres[3] - (0.6 * r[3]) ** 2
    assert [b.index for b in dotcheck_bad_dots(det, 4, 5, plain.radii_mm())] == [3]
