"""Issue 33: with a lens model given (``detect --model``, the re-detections of ``calibrate``), the board's lattice is
recognised among the candidate dots undistorted by it (:mod:`circcal.detector.locate.undistorted`), where a flat
board's dots lie on one homography however strong the lens.

* The candidates' mapping: a dot's undistorted centre and ellipse, a fisheye's candidates beyond 90 deg dropped, and
  which undistorted positions lie in the image.
* Boards seen through a strong barrel lens (OpenCV's 5 coefficients, k1 -0.4) near the image edge, whose pixels the
  lattice checks refuse: found with the true model, every dot where it truly is; the candidates' recognition alone
  too, with ``order`` indexing the candidates given (clutter and dropped ones before them).
* The wide-lens fixture scenarios: every view found with the true model, labelled as without it (orientation is read
  on the pixel positions) and where the truth puts it.
* Refusals hold with a model given: a staggered 5x5 lattice given as a 7x7 board, a 7x7 board given as 5x5, hostile
  images of :mod:`circcal.fixtures.fuzz` under strong wrong models; and a wrong model loses no board the pixels show.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from circcal.board import Board
from circcal.detector import Reason, detect
from circcal.detector.locate.candidates import Candidate
from circcal.detector.locate.recognise import recognise
from circcal.detector.locate.undistorted import inside_image, undistorted_candidates
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.fuzz import KINDS, fuzz_cases, fuzz_image
from circcal.fixtures.render import render_view, to_uint
from circcal.fixtures.truth import load_truth
from circcal.model import Camera, distort_pixels, project, undistort_pixels
from tests.test_hard_views import MISLABEL_PX, labelled_errors

BARREL = Camera(1280, 960, 600.0, 600.0, 640.0, 480.0, [-0.4, 0.12, 0.0, 0.0, 0.0], lens="opencv5")
"""A strong barrel lens (monotonic to beyond the image corners): a 4x5 board of 40 mm pitch near the image edge
bends beyond what the pixel positions' lattice checks follow."""
FISHEYE = Camera(1280, 1024, 420.0, 420.4, 641.3, 510.8, [0.03, -0.01, 0.002, -0.0004], lens="fisheye")
"""The fisheye of the ``fisheye`` scenarios (~112 deg off axis in the image corners)."""
BOARD = Board(4, 5, 40.0, 20.0)
BARREL_VIEWS = (
    ([-0.123, 0.04, 0.17], [-206.0, -118.3, 171.6]),  # not recognised on the pixels
    ([-0.34, 0.295, -0.186], [-185.8, 20.1, 180.1]),  # not recognised on the pixels
    ([-0.127, 0.415, -0.186], [-200.5, -75.4, 214.5]),  # not recognised on the pixels
    ([0.464, 0.122, -0.289], [-8.2, 64.5, 140.2]),  # the pixels: no lattice; the model's first lattice fit
    ([-0.133, -0.542, -0.172], [64.5, 18.6, 160.0]),  # the pixels: the homography puts board points on bare board
)
"""Poses (rvec rad, tvec mm) of :data:`BOARD` before :data:`BARREL` that detection on the pixels refuses."""


def _candidates(camera: Camera, board: Board, rvec, tvec, n: int = 96) -> list[Candidate]:
    """The candidates a perfect segmentation gives of each dot, in board order: the area centroid, second-moment
    ellipse and area of its projected rim."""
    out = []
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    for c in board.object_points():
        rim = c + board.radius_mm * np.column_stack([np.cos(a), np.sin(a), np.zeros(n)])
        p = project(rim, np.asarray(rvec, float), np.asarray(tvec, float), camera).astype(np.float32)
        m = cv2.moments(p.reshape(-1, 1, 2))
        w, V = np.linalg.eigh(np.array([[m["mu20"], m["mu11"]], [m["mu11"], m["mu02"]]]) / m["m00"])
        centre = np.array([m["m10"], m["m01"]]) / m["m00"]
        out.append(
            Candidate(centre, (2 * np.sqrt(w[1]), 2 * np.sqrt(w[0])), float(np.arctan2(V[1, 1], V[0, 1])), m["m00"])
        )
    return out


def test_a_dots_undistorted_candidate_is_its_undistorted_circle():
    # a circle of 6 px radius in the undistorted image near the corner, its rim distorted by the barrel lens: the
    # candidate of the distorted blob maps back to that circle
    q, r = np.array([1150.0, 120.0]), 6.0
    a = np.linspace(0.0, 2.0 * np.pi, 400, endpoint=False)
    rim = distort_pixels(q + r * np.column_stack([np.cos(a), np.sin(a)]), BARREL).astype(np.float32)
    m = cv2.moments(rim.reshape(-1, 1, 2))
    w, V = np.linalg.eigh(np.array([[m["mu20"], m["mu11"]], [m["mu11"], m["mu02"]]]) / m["m00"])
    axes = 2.0 * np.sqrt(w[::-1])
    assert axes[0] / axes[1] > 1.3  # the distorted blob is far from round
    keep, c, ax, ang, area = undistorted_candidates(
        np.array([[m["m10"], m["m01"]]]) / m["m00"],
        axes[None],
        np.array([np.arctan2(V[1, 1], V[0, 1])]),
        np.array([m["m00"]]),
        BARREL,
    )
    assert keep.tolist() == [0]
    assert np.linalg.norm(c[0] - q) < 0.05
    assert np.allclose(ax[0], r, rtol=0.03) and np.isclose(area[0], np.pi * r * r, rtol=0.05)
    assert np.isfinite(ang[0])


def test_fisheye_candidates_beyond_90_degrees_are_left_out():
    # the image corner lies ~112 deg off axis: no perspective image; the centre and a point at 60 deg have one
    pts = np.array([[2.0, 2.0], [641.3, 510.8], [641.3 + 420.0 * np.pi / 3.0, 510.8], [1277.0, 1021.0]])
    keep, c, *_ = undistorted_candidates(pts, np.full((4, 2), 5.0), np.zeros(4), np.full(4, 78.5), FISHEYE)
    assert keep.tolist() == [1, 2]
    assert np.allclose(c, undistort_pixels(pts[[1, 2]], FISHEYE))


def test_inside_image_is_the_observed_frame_seen_through_the_lens():
    inside = inside_image(BARREL)
    px = np.array([[0.5, 0.5], [1278.5, 958.5], [640.0, 480.0], [-3.0, 100.0], [100.0, 962.0]])
    u = undistort_pixels(px, BARREL)
    assert inside(u).tolist() == [True, True, True, False, False]
    assert not inside(np.array([[np.nan, 5.0]]))[0]
    # a fisheye: the perspective image of a point 80 deg off axis inside the frame; far beyond the frame not
    far = np.array([641.3 + 420.4 * np.tan(np.radians(80.0)), 510.8])
    assert inside_image(FISHEYE)(np.array([far, far * 3]).reshape(-1, 2)).tolist() == [True, False]


@pytest.mark.parametrize("view", BARREL_VIEWS[:2])
def test_recognition_of_a_bent_board_with_the_model_indexes_the_candidates_given(view):
    cands = _candidates(BARREL, BOARD, *view)
    assert recognise(BOARD, cands, (1280, 960)).order is None  # the pixels: no lattice of the board
    # clutter first (a blob beyond the fold's reach is dropped, one in frame is not on the lattice), the dots shuffled
    rng = np.random.default_rng(3)
    perm = rng.permutation(len(cands))
    clutter = [
        Candidate(np.array([30.0, 900.0]), (9.0, 8.0), 0.3, 226.0),
        Candidate(np.array([600.0, 700.0]), (7.0, 7.0), 0.0, 154.0),
    ]
    given = clutter + [cands[k] for k in perm]
    rec = recognise(BOARD, given, (1280, 960), camera=BARREL)
    assert rec.order is not None and rec.complete and np.all(rec.order >= 0)
    # each board point's own dot (the orientation rule labels these views as the board's object points are numbered)
    assert rec.order.tolist() == (len(clutter) + np.argsort(perm)).tolist()


def test_fisheye_recognition_leaves_out_candidates_beyond_90_degrees_and_keeps_the_indices():
    rvec, tvec = [0.1, -0.3, 0.05], [-40.0, 20.0, 160.0]
    cands = _candidates(FISHEYE, BOARD, rvec, tvec)
    corner = [
        Candidate(np.array([5.0, 5.0]), (8.0, 8.0), 0.0, 201.0),
        Candidate(np.array([1275.0, 5.0]), (8.0, 8.0), 0.0, 201.0),
    ]
    given = corner + cands
    rec = recognise(BOARD, given, (1280, 1024), camera=FISHEYE)
    assert rec.complete and sorted(rec.order.tolist()) == list(range(2, 2 + BOARD.n_points))
    assert rec.order.tolist() == list(range(len(corner), len(given)))


@pytest.mark.parametrize("view", BARREL_VIEWS)
def test_a_bent_board_refused_on_its_pixels_is_found_with_the_model(view):
    rvec, tvec = (np.asarray(v, float) for v in view)
    img = to_uint(render_view(BARREL, BOARD, rvec, tvec))
    truth = project(BOARD.object_points(), rvec, tvec, BARREL)
    plain = detect(img, BOARD)
    if plain.found:  # views 2 and 4 since the candidate test measures thin dots at their edge: labelled right
        # (their centres, corrected without the lens, are up to 1.3 px off; a wrong label is a whole step off)
        e, _ = labelled_errors(BOARD, plain.centres, truth)
        step = np.min(np.linalg.norm(truth[:, None] - truth[None], axis=-1) + np.eye(len(truth)) * 1e9)
        assert np.all(e[np.isfinite(e)] < 0.25 * step)
    d = detect(img, BOARD, BARREL)
    assert d.found, d.reason
    seen = np.all(np.isfinite(d.centres), axis=1)
    assert seen.sum() >= 8  # (the measuring leaves out some of the most distorted dots)
    assert np.max(np.linalg.norm(d.centres[seen] - truth[seen], axis=1)) < 0.05  # labels right, centres exact


@pytest.mark.parametrize("name", ["fisheye", "fisheye-central", "rational-wide"])
def test_wide_lens_scenarios_found_with_the_model_and_labelled_as_without(name):
    truth = load_truth(fixture_dir(name, "perturbed"))
    board = truth.board
    for k, v in enumerate(truth.views):
        img = cv2.imread(str(v.image), cv2.IMREAD_UNCHANGED)
        d = detect(img, board, truth.camera)
        assert d.found, f"view {k}: {d.reason}"
        e, perm = labelled_errors(board, d.centres, v.centres)
        seen = np.isfinite(e)
        assert seen.sum() >= 0.9 * board.n_points and np.all(e[seen] < MISLABEL_PX), f"view {k}"
        plain = detect(img, board)
        if plain.found:  # the same labels: orientation is read on the pixel positions either way
            both = seen & np.all(np.isfinite(plain.centres), axis=1)
            assert np.max(np.linalg.norm(d.centres[both] - plain.centres[both], axis=1)) < MISLABEL_PX, f"view {k}"


def _staggered(rows: int, cols: int, pitch: float = 40.0, radius: float = 9.0) -> np.ndarray:
    """(480, 640) uint8: a staggered lattice of dark dots, anti-aliased and lightly blurred."""
    img = np.full((480, 640), 220, np.uint8)
    for i in range(rows):
        for j in range(cols):
            x, y = 100 + (2 * j + i % 2) * pitch, 80 + i * pitch
            cv2.circle(img, (int(x * 16), int(y * 16)), int(radius * 16), 30, -1, cv2.LINE_AA, 4)
    return cv2.GaussianBlur(img, (0, 0), 1.0)


def _square(rows: int, cols: int, pitch: float = 50.0, radius: float = 12.0) -> np.ndarray:
    """(480, 640) uint8: a square lattice of dark dots, centred."""
    img = np.full((480, 640), 220, np.uint8)
    x0, y0 = 320 - (cols - 1) * pitch / 2, 240 - (rows - 1) * pitch / 2
    for i in range(rows):
        for j in range(cols):
            cv2.circle(
                img, (int((x0 + j * pitch) * 16), int((y0 + i * pitch) * 16)), int(radius * 16), 30, -1, cv2.LINE_AA, 4
            )
    return cv2.GaussianBlur(img, (0, 0), 1.0)


VGA_BARREL = Camera(640, 480, 500.0, 500.0, 320.0, 240.0, [-0.25, 0.05, 0.0, 0.0, 0.0], lens="opencv5")
VGA_FISHEYE = Camera(640, 480, 300.0, 300.0, 320.0, 240.0, [0.02, -0.01, 0.0, 0.0], lens="fisheye")


@pytest.mark.parametrize("camera", [None, VGA_BARREL, VGA_FISHEYE], ids=["none", "barrel", "fisheye"])
def test_wrong_lattices_are_refused_with_a_model_as_without(camera):
    # a staggered 5x5 lattice given as a 7x7 board: its diagonals' square lattice leaves bare board where the 7x7
    # would have dots; found as what it is
    img = _staggered(5, 5)
    d = detect(img, Board(7, 7, 10.0, 5.0), camera)
    assert not d.found and d.code in (Reason.GRID_NOT_RECOGNISED, Reason.GRID_MISMATCH), d.reason
    assert detect(img, Board(5, 5, 10.0, 5.0, layout="asymmetric"), camera).found
    # a 7x7 board given as 5x5: the lattice goes on beyond the board
    img = _square(7, 7)
    d = detect(img, Board(5, 5, 10.0, 4.8), camera)
    assert not d.found and d.code == Reason.GRID_MISMATCH, d.reason
    assert detect(img, Board(7, 7, 10.0, 4.8), camera).found


def test_hostile_images_show_no_board_under_strong_wrong_models():
    boards = (Board(7, 7, 10.0, 5.0), Board(11, 4, 10.0, 7.0, "asymmetric"), Board(4, 5, 10.0, 5.0))
    found = []
    for k, (kind, seed) in enumerate(fuzz_cases(2 * len(KINDS), 5)):
        board = boards[k % len(boards)]
        img = fuzz_image(kind, seed, board)
        H, W = img.shape[:2]
        if k % 2:
            camera = Camera(W, H, 0.5 * W, 0.5 * W, W / 2, H / 2, [-0.4, 0.12, 0.0, 0.0, 0.0], lens="opencv5")
        else:
            camera = Camera(W, H, 0.3 * W, 0.3 * W, W / 2, H / 2, [0.03, -0.01, 0.002, -0.0004], lens="fisheye")
        d = detect(img, board, camera)
        if d.found:
            found.append((kind, seed))
    assert found == []


def test_a_wrong_model_loses_no_board_the_pixels_show():
    # an undistorted render given a strong barrel model: found all the same, each dot labelled where it is
    cam = Camera(1280, 960, 900.0, 900.0, 640.0, 480.0, [0.0, 0.0, 0.0, 0.0, 0.0], lens="opencv5")
    board = Board(6, 8, 25.0, 12.0)
    rvec, tvec = np.array([0.3, -0.2, 0.1]), np.array([-80.0, -60.0, 420.0])
    img = to_uint(render_view(cam, board, rvec, tvec))
    wrong = Camera(1280, 960, 900.0, 900.0, 640.0, 480.0, [-0.4, 0.12, 0.0, 0.0, 0.0], lens="opencv5")
    d = detect(img, board, wrong)
    assert d.found, d.reason
    plain = detect(img, board)
    assert plain.found
    assert np.nanmax(np.linalg.norm(d.centres - plain.centres, axis=1)) < 0.25 * 25.0 * 900.0 / 420.0
