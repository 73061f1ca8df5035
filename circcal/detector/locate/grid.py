"""Grid recognition and ordering of candidate dot centres, with one documented orientation rule.

Recognition itself lives in :mod:`circcal.detector.locate.recognise` (lattice patches grown among the candidates,
:mod:`circcal.detector.locate.lattice`, in time about linear in their number). Here: the direct ordering of a symmetric
board whose candidates are exactly its dots (the usual clean case: :func:`order_lattice`, hull corners, one
homography, every candidate on its own grid node), :func:`circcal.detector.locate.recognise.order_grid` (recognition of the whole board from bare
centres and radii), and the one orientation rule every labelling follows.

Orientation rule (:func:`canonical_order`)
------------------------------------------
A board's point set is symmetric under some rigid relabelings (a symmetric rows x cols grid under 180 deg rotation,
and under 90 deg rotations when square; an asymmetric grid with an even number of rows under 180 deg rotation; with
an odd number of rows, under a mirror only). Among the labelings allowed by those symmetries, circcal keeps only those
whose image handedness matches the board frame seen from the front (board x right and y down map to an image frame
with positive orientation, i.e. the board-to-image homography has a positive Jacobian determinant: x right, y down
in the image as in the board), and among those picks the one whose first point (object point 0) lies nearest to the
image's top-left corner (pixel (0, 0)). So a fronto-parallel, unrolled symmetric board is numbered row by row from
the top-left, like OpenCV's object points; asymmetric grids are at most 2-fold ambiguous and the same rule decides.
"""

from __future__ import annotations

import cv2
import numpy as np

from circcal.board import Board

__all__ = ["canonical_order", "order_lattice", "orient", "orientation_sign"]

LATTICE_TOLERANCE = 0.3
"""The direct ordering of a symmetric grid (:func:`order_lattice`) takes a candidate as a grid node's when the
homography from the hull corners puts it within this many cells of the node (under perspective it lands on its node
up to noise; at 0.5 a candidate could be taken for either of two nodes; strong distortion fails and falls back)."""


def orientation_sign(board: Board, centres: np.ndarray) -> float:
    """Sign of the Jacobian determinant, at the grid centre, of the homography board -> image fitted to ``centres``.

    Parameters
    ----------
    board : Board
        The board.
    centres : numpy.ndarray
        (N, 2) float px in board order; NaN rows: points not seen, left out.

    Returns
    -------
    float
        +1.0 when the board is seen from the front (see module docstring), -1.0 mirrored, 0.0 when fewer than 4
        points are seen or no homography fits.

    Examples
    --------
    >>> board = Board(3, 4, 10.0, 5.0)
    >>> centres = board.object_points()[:, :2] * 3 + 50
    >>> orientation_sign(board, centres), orientation_sign(board, centres[:, ::-1])
    (1.0, -1.0)
    """
    obj = board.object_points()[:, :2]
    centres = np.asarray(centres, np.float64)
    seen = np.all(np.isfinite(centres), axis=1)
    if seen.sum() < 4:
        return 0.0
    H, _ = cv2.findHomography(obj[seen], centres[seen], 0)
    if H is None:
        return 0.0
    c = obj.mean(axis=0)
    w = H[2] @ np.array([c[0], c[1], 1.0])
    J = (H[:2, :2] * w - np.outer(H[:2] @ np.array([c[0], c[1], 1.0]), H[2, :2])) / (w * w)
    return float(np.sign(np.linalg.det(J)))


def canonical_order(board: Board, centres: np.ndarray) -> np.ndarray:
    """Indices ``idx`` so that ``centres[idx]`` follows the orientation rule of this module.

    One homography is fitted: relabelling by a board symmetry ``S`` composes it with ``S`` (the least-squares fit of
    the relabelled points is ``H S``), so a labelling's orientation sign is ``orientation_sign(centres) * det S``.

    Parameters
    ----------
    board : Board
        The board.
    centres : numpy.ndarray
        (N, 2) float px in some valid board labelling (e.g. OpenCV's output, possibly rotated or mirrored).

    Returns
    -------
    numpy.ndarray
        (N,) int indices into ``centres``.

    Raises
    ------
    ValueError
        No labelling of the grid is seen from the board's front (a mirrored image?).

    Examples
    --------
    >>> board = Board(3, 4, 10.0, 5.0)
    >>> centres = board.object_points()[:, :2] * 3 + 50
    >>> canonical_order(board, centres[::-1]).tolist()
    [11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0]
    """
    centres = np.asarray(centres, dtype=np.float64)
    s0 = orientation_sign(board, centres)
    best, best_d = None, np.inf
    for sym in board.symmetries():
        # new labelling: point k of the board is the old point sym.perm[k]
        if s0 * sym.det <= 0:
            continue
        d = np.hypot(*centres[sym.perm[0]])
        if d < best_d - 1e-9:
            best, best_d = sym.perm, d
    if best is None:
        raise ValueError("no labelling of the detected grid is seen from the board's front (mirrored image?)")
    return best.copy()


def orient(board: Board, centres: np.ndarray, order: np.ndarray) -> np.ndarray | None:
    """``order`` relabelled by the orientation rule of this module, for a board seen whole or in part.

    With every point seen this is :func:`canonical_order`; otherwise the image of point 0 of each labelling comes from
    the homography of the points seen.

    Parameters
    ----------
    board : Board
        The board.
    centres : numpy.ndarray
        (N, 2) float px of the points in ``order``'s labelling; NaN where not seen.
    order : numpy.ndarray
        (N,) int candidate index per board point, -1 where not seen.

    Returns
    -------
    numpy.ndarray or None
        (N,) int ``order`` relabelled; ``None`` when no labelling is seen from the board's front (or no homography
        fits the points seen).
    """
    centres = np.asarray(centres, np.float64)
    order = np.asarray(order, np.int64)
    if np.all(np.isfinite(centres)):
        try:
            return order[canonical_order(board, centres)]
        except ValueError:
            return None
    seen = np.all(np.isfinite(centres), axis=1)
    obj = board.object_points()[:, :2]
    H, _ = cv2.findHomography(obj[seen], centres[seen], 0)
    if H is None:
        return None
    s0 = orientation_sign(board, centres)
    best, best_d = None, np.inf
    for sym in board.symmetries():
        if s0 * sym.det <= 0:
            continue
        q = H @ np.array([*obj[sym.perm[0]], 1.0])
        d = float(np.hypot(q[0] / q[2], q[1] / q[2]))
        if d < best_d - 1e-9:
            best, best_d = sym.perm, d
    return None if best is None else order[best]


def order_lattice(board: Board, points: np.ndarray, tol: float = LATTICE_TOLERANCE) -> np.ndarray | None:
    """Fast ordering of a symmetric board whose candidates are exactly its N dots (no clutter).

    The grid's four corners are the convex-hull vertices with the largest turning angles; the homography from them
    to the grid's integer coordinates must put every candidate within ``tol`` cells of a distinct grid node. Under
    perspective this is the grid itself, and exactly the assignment OpenCV's finder returns (up to a symmetry, which
    :func:`canonical_order` removes); strong lens distortion fails the test and falls back.

    Parameters
    ----------
    board : Board
        The board; only a symmetric layout is ordered here.
    points : numpy.ndarray
        (N, 2) float candidate centres, px.
    tol : float, optional
        Largest distance of a candidate from its grid node, in cells (:data:`LATTICE_TOLERANCE`).

    Returns
    -------
    numpy.ndarray or None
        (N,) int indices into ``points`` in a valid board labelling (not yet canonical), or ``None`` when the
        candidates do not form the grid unambiguously (the caller then runs OpenCV's grid finder), when the board is
        not symmetric or the count differs from N.

    Examples
    --------
    >>> board = Board(3, 4, 10.0, 5.0)
    >>> order_lattice(board, board.object_points()[:, :2] * 3 + 50).tolist()  # rotated 180 deg: not canonical
    [11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0]
    """
    N = board.n_points
    if board.layout != "symmetric" or len(points) != N:
        return None
    hull = cv2.convexHull(points.astype(np.float32), returnPoints=False).reshape(-1)
    if len(hull) < 4:
        return None
    P = points[hull]
    a = P - np.roll(P, 1, axis=0)
    b = np.roll(P, -1, axis=0) - P
    turn = np.abs(np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], np.sum(a * b, axis=1)))
    corners = P[np.sort(np.argsort(turn)[-4:])].astype(np.float32)  # (4, 2) in hull order
    cols, rows = board.cols, board.rows
    grid = np.array([[0, 0], [cols - 1, 0], [cols - 1, rows - 1], [0, rows - 1]], np.float32)
    for shift in (0, 1):
        Hg = cv2.getPerspectiveTransform(corners, np.roll(grid, shift, axis=0))
        q = cv2.perspectiveTransform(points.reshape(-1, 1, 2), Hg).reshape(-1, 2)
        if not np.all(np.isfinite(q)):
            continue
        r = np.round(q)
        if (
            np.max(np.abs(q - r)) >= tol
            or r[:, 0].min() < 0
            or r[:, 1].min() < 0
            or r[:, 0].max() > cols - 1
            or r[:, 1].max() > rows - 1
        ):
            continue
        k = (r[:, 1] * cols + r[:, 0]).astype(int)  # board index of each candidate
        idx = np.full(N, -1)
        idx[k] = np.arange(N)
        if np.all(idx >= 0):
            return idx
    return None
