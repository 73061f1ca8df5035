"""The board as the solver sees it: its points as unknowns (board refinement: which points, which coordinates
held for the gauge) and mrcal's 2-parameter board warp (``calobject_warp``): the box it spans and how each point's
z moves with it. The renderer draws warped boards with the same :func:`warp_basis`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from circcal.errors import CalibrationError
from circcal.observations import distinct_points

__all__ = ["BoardModel", "board_model", "warp_box", "warp_basis", "MIN_VIEWS_PER_BOARD_POINT"]

#: With board refinement, a board point seen in fewer views than this is held at its nominal position (a point seen
#: in one or two views is not constrained beyond its own views' poses).
MIN_VIEWS_PER_BOARD_POINT = 3


def warp_box(obj: Sequence[np.ndarray]) -> tuple[float, float, float, float]:
    """The rectangle the board warp spans: the bounding box of every board point the views hold.

    mrcal's lattice of the same observations (:func:`circcal.formats.mrcal_process.board_lattice`) starts at the
    smallest x, y and ends at the largest, so the warp's edges are mrcal's.

    Parameters
    ----------
    obj : sequence of ndarray
        Per view (N_v, 3) board points, mm.

    Returns
    -------
    tuple of float
        (x0, x1, y0, y1) mm.

    Raises
    ------
    CalibrationError
        Board points that do not spread along both x and y (the warp would be undefined).
    """
    allp = np.concatenate([np.asarray(o, dtype=np.float64).reshape(-1, 3) for o in obj])
    x0, y0 = (float(v) for v in allp[:, :2].min(axis=0))
    x1, y1 = (float(v) for v in allp[:, :2].max(axis=0))
    if not (x1 > x0 and y1 > y0):
        raise CalibrationError(
            f"board warp: the board points span x {x0:g}..{x1:g} mm, y {y0:g}..{y1:g} mm; the warp needs both"
        )
    return x0, x1, y0, y1


def warp_basis(X: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    """How each board point's z moves with the board warp: mrcal's ``calobject_warp`` (``mrcal.ref_calibration_object``).

    ``z = w_x * 4 xr (1 - xr) + w_y * 4 yr (1 - yr)`` with ``xr = (x - x0) / (x1 - x0)``, ``yr = (y - y0) / (y1 - y0)``:
    two parabolas along the board's x and y axes, zero at the box's edges, ``w`` (mm, mrcal's units scaled) the
    deflection at its centre.

    Parameters
    ----------
    X : ndarray, shape (N, 3)
        Nominal board points, mm.
    box : tuple of float
        (x0, x1, y0, y1) mm (:func:`warp_box`).

    Returns
    -------
    ndarray, shape (N, 2)
        ``d z / d (w_x, w_y)`` (unitless).
    """
    x0, x1, y0, y1 = box
    xr = (np.asarray(X, dtype=np.float64)[:, 0] - x0) / (x1 - x0)
    yr = (np.asarray(X, dtype=np.float64)[:, 1] - y0) / (y1 - y0)
    return np.column_stack([4.0 * xr * (1.0 - xr), 4.0 * yr * (1.0 - yr)])


@dataclass
class BoardModel:
    """Board points as unknowns (the object-releasing method of Strobl & Hirzinger 2011, ``cv2.calibrateCameraRO``).

    Attributes
    ----------
    nominal : ndarray, shape (P, 3)
        The distinct board points in order of first appearance, mm.
    point_index : ndarray, shape (N,)
        The board point of each stacked observation.
    free : ndarray
        Indices into ``nominal.ravel()`` of the coordinates estimated (the rest are held: the gauge and points seen
        in fewer than 3 views).
    gauge : tuple of int, (a, b, c)
        Point indices: a and b held in x, y, z, c in z (7 constraints: the similarity transform a planar board's
        shape cannot fix by itself).
    held_unseen : list of int
        The points held because fewer than 3 views saw them.
    """

    nominal: np.ndarray
    point_index: np.ndarray
    free: np.ndarray
    gauge: tuple[int, int, int]
    held_unseen: list[int]


def board_model(obj: list[np.ndarray], gauge: tuple[int, int, int] | None) -> BoardModel:
    """Identify the distinct board points across views (by their coordinates) and choose the gauge.

    Parameters
    ----------
    obj : list of ndarray
        Per view (N_v, 3) mm.
    gauge : tuple of int or None
        (a, b, c) point indices, in order of first appearance. Default: a = the first point, b = the point farthest
        from a, c = the point farthest from the line a-b (any three non-collinear points give the same intrinsics and
        residuals; only the board frame changes).

    Returns
    -------
    BoardModel

    Raises
    ------
    CalibrationError
        Fewer than 4 distinct board points.
    ValueError
        A gauge of repeated, out-of-range or collinear points.
    """
    nominal, per_view = distinct_points(obj)
    point_index = np.concatenate(per_view)
    n_pts = len(nominal)
    if n_pts < 4:
        raise CalibrationError(f"board refinement needs at least 4 distinct board points, got {n_pts}")
    if gauge is None:
        a = 0
        b = int(np.argmax(np.linalg.norm(nominal - nominal[a], axis=1)))
        ab = nominal[b] - nominal[a]
        off = nominal - nominal[a]
        c = int(np.argmax(np.linalg.norm(off - np.outer(off @ ab / (ab @ ab), ab), axis=1)))
        gauge = (a, b, c)
    a, b, c = (int(i) for i in gauge)
    if len({a, b, c}) != 3 or min(a, b, c) < 0 or max(a, b, c) >= n_pts:
        raise ValueError(f"board gauge needs three distinct point indices in 0..{n_pts - 1}, got {gauge!r}")
    ab, ac = nominal[b] - nominal[a], nominal[c] - nominal[a]
    if np.linalg.norm(np.cross(ab, ac)) <= 1e-6 * (ab @ ab + ac @ ac):
        raise ValueError(f"board gauge points {gauge!r} are collinear")
    held = np.zeros((n_pts, 3), dtype=bool)
    held[a] = held[b] = True
    held[c, 2] = True
    view = np.repeat(np.arange(len(obj)), [len(o) for o in obj])
    n_views_seen = np.bincount(np.unique(np.column_stack([point_index, view]), axis=0)[:, 0], minlength=n_pts)
    unseen = [int(i) for i in np.flatnonzero(n_views_seen < MIN_VIEWS_PER_BOARD_POINT)]
    held[unseen] = True
    return BoardModel(nominal, point_index, np.flatnonzero(~held.ravel()), (a, b, c), unseen)
