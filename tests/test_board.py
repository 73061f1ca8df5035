"""Board layouts in OpenCV's object-point order and their geometry."""

from __future__ import annotations

import numpy as np
import pytest

from circcal.board import Board
from circcal.errors import InputError


def test_symmetric_order_matches_opencv():
    b = Board(3, 4, 10.0, 5.0)
    P = b.object_points()
    assert b.pattern_size == (4, 3)
    # OpenCV: for i in rows, for j in cols: (j*s, i*s, 0)
    expected = np.array([(j * 10.0, i * 10.0, 0.0) for i in range(3) for j in range(4)])
    assert np.array_equal(P, expected)


def test_asymmetric_order_matches_opencv():
    b = Board(11, 4, 10.0, 7.0, "asymmetric")
    expected = np.array([((2 * j + i % 2) * 10.0, i * 10.0, 0.0) for i in range(11) for j in range(4)])
    assert np.array_equal(b.object_points(), expected)


def test_checkerboard_corners_and_colours():
    b = Board(8, 11, 14.0, 0.0, "checkerboard")
    assert b.object_points().shape == (88, 3)
    # square with top-left corner (0,0) has a+b = 0 -> dark; its neighbour is white
    sd = b.signed_distance_mm(np.array([[7.0, 7.0], [21.0, 7.0]]))
    assert sd[0] == pytest.approx(-7.0) and sd[1] == pytest.approx(7.0)


def test_signed_distance_is_exact_for_dots():
    b = Board(3, 3, 10.0, 4.0)
    pts = np.array([[0.0, 0.0], [2.0, 0.0], [13.0, 10.0], [5.0, 5.0]])
    assert np.allclose(b.signed_distance_mm(pts), [-2.0, 0.0, 1.0, np.hypot(5, 5) - 2.0])
    a = Board(4, 3, 10.0, 6.0, "asymmetric")  # row 1 is shifted by one pitch
    assert np.allclose(a.signed_distance_mm(np.array([[10.0, 10.0], [0.0, 10.0]])), [-3.0, 10.0 - 3.0])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(rows=1, cols=5, pitch_mm=10, diameter_mm=5), "at least 2x2"),
        (dict(rows=5, cols=5, pitch_mm=10, diameter_mm=10), "would touch"),
        (dict(rows=5, cols=5, pitch_mm=-1, diameter_mm=0.5), "pitch must be positive"),
        (dict(rows=5, cols=5, pitch_mm=10, diameter_mm=5, layout="hex"), "unknown layout"),
    ],
)
def test_invalid_boards_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Board(**kwargs)


@pytest.mark.parametrize(
    "board,n",
    [
        (Board(4, 5, 10, 5), 4),  # rectangle: identity, 180 deg, two mirrors
        (Board(5, 5, 10, 5), 8),  # square: dihedral group
        (Board(5, 4, 10, 5, "asymmetric"), 2),  # odd rows: identity and a mirror only
        (Board(11, 4, 10, 7, "asymmetric"), 2),
        (Board(6, 4, 10, 5, "asymmetric"), 2),  # even rows: identity and 180 deg
    ],
)
def test_board_symmetries(board, n):
    syms = board.symmetries()
    assert len(syms) == n
    obj = board.object_points()[:, :2]
    assert syms[0].label == "rot0" and np.array_equal(syms[0].perm, np.arange(board.n_points))
    assert [s.label for s in board.symmetries(reflections=False)] == [s.label for s in syms if s.det > 0]
    for s in syms:
        p = s.perm
        assert sorted(p.tolist()) == list(range(board.n_points))
        # a rigid map: pairwise distances preserved, and det says whether it is a reflection
        d0 = np.linalg.norm(obj[:, None] - obj[None], axis=-1)
        assert np.allclose(d0, d0[np.ix_(p, p)])
        c = obj - obj.mean(axis=0)
        A = np.linalg.lstsq(c, c[p], rcond=None)[0]
        assert np.allclose(c @ A, c[p]) and np.sign(np.linalg.det(A)) == s.det


@pytest.mark.parametrize(
    "args, message",
    [
        ((7, 7, 1e-300, 0.5e-300), "between 0.001 and 100000 mm"),  # was ZeroDivisionError deep in the detector
        ((7, 7, 2e5, 1e5), "between 0.001 and 100000 mm"),
        ((7, 7, float("nan"), 5.0), "finite number"),
        ((7, 7, 10.0, float("inf")), "finite number"),
        ((True, 7, 10.0, 5.0), "rows must be an integer"),
        ((7, 7.5, 10.0, 5.0), "cols must be an integer"),
        ((7, 1001, 10.0, 5.0), "at most 1000"),
    ],
)
def test_board_values_are_checked(args, message):
    with pytest.raises(InputError, match=message):
        Board(*args)
