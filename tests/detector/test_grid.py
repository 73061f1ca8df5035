"""Grid ordering: board symmetries, the orientation rule, clutter."""

import numpy as np
import pytest

from circcal.board import Board
from circcal.detector.locate.grid import canonical_order, orientation_sign
from circcal.detector.locate.recognise import order_grid


def _view(board, angle_deg, tilt=0.2):
    obj = board.object_points()[:, :2]
    a = np.deg2rad(angle_deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    H = np.eye(3)
    H[:2, :2] = (300.0 / np.ptp(obj, axis=0).max()) * R
    H[:2, 2] = [400, 300]
    H[2, :2] = [tilt * 1e-3, 0.0]
    p = np.column_stack([obj - obj.mean(0), np.ones(len(obj))]) @ H.T
    return p[:, :2] / p[:, 2:]


@pytest.mark.parametrize(
    "board",
    [Board(4, 5, 10, 5), Board(5, 5, 10, 5), Board(5, 4, 10, 5, "asymmetric"), Board(6, 4, 10, 5, "asymmetric")],
)
@pytest.mark.parametrize("angle", [0, 30, 100, 200, 290])
def test_canonical_order_is_unique_and_front_facing(board, angle):
    pts = _view(board, angle)
    results = set()
    for p in (s.perm for s in board.symmetries()):  # every equivalent labelling, mirrored ones included
        lab = pts[p]
        idx = canonical_order(board, lab)
        out = lab[idx]
        assert orientation_sign(board, out) > 0
        results.add(tuple(np.round(out.ravel(), 6)))
    assert len(results) == 1
    out = np.array(next(iter(results))).reshape(-1, 2)
    # the rule: first point nearest to the image's top-left among front-facing labellings
    cands = [pts[s.perm] for s in board.symmetries() if orientation_sign(board, pts[s.perm]) > 0]
    assert np.hypot(*out[0]) == pytest.approx(min(np.hypot(*c[0]) for c in cands))


def test_fronto_parallel_unrotated_is_opencv_order():
    board = Board(4, 5, 10, 5)
    pts = _view(board, 0, tilt=0.0)
    assert np.array_equal(canonical_order(board, pts), np.arange(20))


@pytest.mark.parametrize("board", [Board(4, 5, 10, 5), Board(4, 11, 10, 7, "asymmetric")])
def test_order_grid_with_clutter(board):
    rng = np.random.default_rng(3)
    pts = _view(board, 20)
    clutter = np.column_stack([rng.uniform(0, 100, 6), rng.uniform(0, 600, 6)])  # off the board (left strip)
    allp = np.concatenate([pts, clutter])
    perm = rng.permutation(len(allp))
    radii = np.full(len(allp), 2.0)
    idx = order_grid(board, allp[perm], radii, (600, 800))
    assert idx is not None
    got = allp[perm][idx]
    want = pts[canonical_order(board, pts)]
    assert np.allclose(got, want)


def test_order_grid_reports_missing():
    board = Board(4, 5, 10, 5)
    pts = _view(board, 0)[:-3]
    assert order_grid(board, pts, np.full(len(pts), 2.0), (600, 800)) is None
