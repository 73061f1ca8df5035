"""Issue 33: no good dot of a wide lens's view thrown away by the bad-dot rules
(:mod:`circcal.detector.measure.baddots`).

A wide lens legitimately thins and stretches dots across one view: far off a fisheye's axis and under tilt a dot is
a few px across its minor axis, its fitted ellipse rounded by the edge smoothing (``ROUNDING_PX``), and the lattice
steps at a small grid's edge differ from those at the dot (``local_steps(..., edge_order=2)``). On the fisheye
scenarios every visible dot the detector labels is kept and within 0.02 px of the truth (the true model given); on
renders of the views that lost good dots to the roundness and clearance rules (found by a sweep of random fisheye
poses), none is lost. Nor is a thin dot lost before the lattice sees it: the candidates' inertia test measures a
blob's edge, not its pixel contour half a pixel inside (:data:`circcal.detector.locate.candidates.CONTOUR_INSET_PX`),
so the last column of ``fisheye-central``'s view 6, 73-79 deg off axis and 1:3, is labelled.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from circcal.board import Board
from circcal.detector import detect
from circcal.detector.locate.candidates import find_candidates
from circcal.detector.measure.trust import local_steps
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.poses import pose_looking_at
from circcal.fixtures.render import render_view, to_uint
from circcal.fixtures.scenarios import get_scenario
from circcal.fixtures.truth import load_truth
from circcal.model import project
from tests.test_hard_views import labelled_errors

KEPT = 0.98
"""Share of a found view's visible dots kept (issue 33)."""
GOOD_PX = 0.02
"""A dot whose centre is within this of the truth is a good dot: kept (issue 33)."""


@pytest.mark.parametrize("name", ["fisheye", "fisheye-central"])
@pytest.mark.parametrize("variant", ["clean", "perturbed"])
def test_fisheye_scenarios_keep_their_dots_and_each_is_good(name, variant):
    truth = load_truth(fixture_dir(name, variant))
    failures = []
    for k, v in enumerate(truth.views):
        d = detect(cv2.imread(str(v.image), cv2.IMREAD_UNCHANGED), truth.board, truth.camera)
        if not d.found:
            continue  # (how many are found: tests/test_wide_lenses.py)
        e, perm = labelled_errors(truth.board, d.centres, v.centres)
        kept = np.isfinite(e)
        n_kept = int(np.sum(kept & v.visible[perm]))
        share = n_kept / max(n_kept + sum(1 for p in d.dropped if v.visible[perm[p]]), 1)
        if share < KEPT:
            failures.append(f"view {k}: {share:.1%} of its visible labelled dots kept; dropped {d.dropped}")
        if np.max(e[kept]) > GOOD_PX:
            failures.append(f"view {k}: a kept dot {np.max(e[kept]):.4f} px from the truth")
    assert not failures, "\n".join(failures)


# (rows, cols), dot diameter over the pitch, board centre px, tilt, distance mm, tilt axis, roll (deg): views of the
# scenario's fisheye that lost good dots before (13 thin dots as "not round on the board", axis ratio 1.43-1.50 with
# the limit at 1.45; three 30-40 px dots at a 4x5 grid's edge whose first-order lattice steps erred by 20 %; two at
# a 4x5 grid's edge tilted 50 deg)
HARD_VIEWS = [
    ((8, 11), 0.3, (288.0, 423.0), 43.4, 319.9, 95.4, -1.3),
    ((4, 5), 0.6, (744.0, 518.0), 23.8, 70.3, 67.1, 16.5),
    ((4, 5), 0.3, (461.0, 423.0), 49.7, 101.1, 160.8, -23.6),
]


@pytest.mark.parametrize("view", HARD_VIEWS)
def test_thin_and_large_fisheye_dots_are_kept(view):
    (rows, cols), ratio, target, tilt, distance, axis, roll = view
    cam = get_scenario("fisheye").camera
    board = Board(rows, cols, 25.0, 25.0 * ratio)
    r, t = pose_looking_at(
        cam, board, distance_mm=distance, tilt_deg=tilt, tilt_axis_deg=axis, roll_deg=roll, target_px=target
    )
    img = to_uint(cv2.GaussianBlur(render_view(cam, board, r, t), (0, 0), 0.7), 8)
    d = detect(img, board, cam)
    assert d.found and not d.dropped, d.dropped
    e, _ = labelled_errors(board, d.centres, project(board.object_points(), r, t, cam))
    assert np.max(e) < GOOD_PX


def test_thin_dots_lose_no_good_dot_to_the_clearance_rings():
    # 68 deg of tilt at the fisheye's centre: dots 1.5-2 px across their minor semi-axis, whose fitted ellipses stop
    # short of their tips; rings grown from the fit alone ran through the tips ("a dark object touches it" on 15 of
    # 48, all within 0.02 px). Some are too thin for an edge fit at all ("unmeasurable"): only those are left out.
    cam = get_scenario("fisheye").camera
    board = Board(6, 8, 25.0, 7.5)
    r, t = pose_looking_at(
        cam, board, distance_mm=301.0, tilt_deg=68.0, tilt_axis_deg=18.0, roll_deg=-5.2, target_px=(659.0, 517.0)
    )
    img = cv2.GaussianBlur(render_view(cam, board, r, t), (0, 0), 0.7)
    img = to_uint(img + np.random.default_rng(1).normal(0.0, 0.003, img.shape), 8)
    d = detect(img, board, cam)
    assert d.found
    # Loosened (2026-12-06) with the candidate floor at 6 px^2, from "every dropped dot unmeasurable": dot 41, one
    # of the thinnest (8 sub-pixel edge points: unmeasurable at 12 px^2, where it was no candidate), is now a
    # candidate measured from its own blob, just past the edge-point count, and its ring touches its own tips; it
    # is left out either way. Still 3 dropped (32, 40, 41 at 12 px^2; 40, 41, 42 at 6), and at most one by the ring.
    ring = [p for p, why in d.dropped.items() if why.startswith("a dark object touches it")]
    assert all(why.startswith("unmeasurable") for p, why in d.dropped.items() if p not in ring), d.dropped
    assert len(ring) <= 1 and len(d.dropped) <= 3, d.dropped


def test_second_order_steps_are_exact_on_a_quadratic_map():
    # numpy.gradient's edge_order=2: the one-sided differences at the grid's edge exact for a quadratic map, as the
    # central ones are; the first-order ones err by half the second derivative
    board = Board(4, 5, 10.0, 5.0)
    L = board.lattice_coords().astype(np.float64)
    x, y = L[:, 0], L[:, 1]
    c = np.column_stack([30 * x + 2 * x * x + x * y, 25 * y - 1.5 * y * y + 0.5 * x * y]) + 100.0
    exact = np.stack([np.column_stack([30 + 4 * x + y, 0.5 * y]), np.column_stack([x, 25 - 3 * y + 0.5 * x])], 2)
    pts = np.arange(board.n_points)
    assert np.allclose(local_steps(board, pts, c, edge_order=2), exact, atol=1e-12)
    assert not np.allclose(local_steps(board, pts, c), exact, atol=0.1)
    assert np.array_equal(local_steps(board, pts[:1], c[:1], edge_order=2), np.full((1, 2, 2), np.nan), equal_nan=True)
    with pytest.raises(ValueError, match="edge_order"):
        local_steps(board, pts, c, edge_order=3)


@pytest.mark.parametrize("variant", ["clean", "perturbed"])
def test_the_thin_last_column_of_a_fisheye_view_is_labelled_and_good(variant):
    # fisheye-central's view 6: the board's last column and two dots of its last row, 73-79 deg off the axis and
    # ~1:3, measured (b/a)^2 0.06-0.077 on their half-scale contours (the limit 0.08) and were never candidates
    truth = load_truth(fixture_dir("fisheye-central", variant))
    v = truth.views[6]
    d = detect(cv2.imread(str(v.image), cv2.IMREAD_UNCHANGED), truth.board, truth.camera)
    assert d.found and not d.dropped, d.dropped
    e, _ = labelled_errors(truth.board, d.centres, v.centres)
    assert np.all(np.isfinite(e)), np.nonzero(~np.isfinite(e))[0]
    assert np.max(e) < GOOD_PX


@pytest.mark.parametrize("angle", range(0, 180, 15))
def test_thin_blobs_are_candidates_by_their_edge_and_lines_are_not(angle):
    # cv2.ellipse fills the pixels within its semi-axes: the edge lies half a pixel beyond them. A 1:3.3 blob 7 px
    # across (semi-axes 11.5 x 3.5 at its edge) is a dot seen at ~72 deg of tilt (its contour measures 0.07-0.08);
    # 1:5 (semi-axes 12.5 x 2.5 and 17.5 x 3.5) is a stroke, not a dot
    def kept(a, b):
        mask = np.zeros((60, 60), np.uint8)
        cv2.ellipse(mask, (30, 30), (a, b), angle, 0, 360, 255, -1)
        return len(find_candidates(mask, min_area=12.0, max_area=1e4))

    assert kept(11, 3) == 1
    assert kept(12, 2) == 0
    assert kept(17, 3) == 0
