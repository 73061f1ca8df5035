"""What a found grid must pass before it is reported (:func:`check_grid`, :func:`absent_dots`).

The measured dots together must look like the board, or nothing is reported: the ellipse centres lie on a lattice
(a homography from the board explains them to :data:`MAX_LATTICE_RESIDUAL` of a lattice step, with a quadratic term
for lens distortion on larger grids; a grid bent beyond that by a wide lens is measured dot by dot against the
smooth map of its own lattice neighbours, :func:`~circcal.detector.locate.smooth.local_residual`, and, where a lens
model is given, by one homography of the centres it undistorts), and the dots fill their lattice cells as the
board's printed dots do (:data:`DIAMETER_FACTOR`). Noise specks that happen to line up pass neither. The board
points a partial labelling leaves out must not lie on bare board (:func:`absent_dots`; with a lens model, predicted
in its undistorted image). The single dots left out of a trusted grid: :mod:`circcal.detector.measure.baddots`.

Pixels: OpenCV's convention. Lattice steps: one pitch along the board's x and y (:meth:`Board.lattice_coords`).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from circcal.board import Board
from circcal.detector.kernels.jit import njit
from circcal.detector.locate.smooth import local_residual
from circcal.detector.locate.undistorted import inside_image
from circcal.detector.measure.ellipse import conic_params_batch
from circcal.detector.measure.robust import median
from circcal.model import Camera, distort_pixels, undistort_pixels

__all__ = ["ABSENT_MAX_SHARE", "MAX_GAPS", "absent_dots", "unseen_gaps", "check_grid", "local_steps"]

MAX_LATTICE_RESIDUAL = 0.06
"""The RMS residual of the lattice fit (below) is at most this share of the local lattice step: <= 0.01 on renders
without distortion, <= 0.03 with k1 = -0.3 and on real 640x480 photographs (measured); aligned noise specks: > 0.1.
Where that global fit does not follow the grid (the rows a fisheye or a wide lens bends over a large board), each dot
is measured against the quadratic of its own lattice neighbours instead
(:func:`~circcal.detector.locate.smooth.local_residual`: the same scale, a share of the local step), and the smaller
of the two is held to this bound."""
QUADRATIC_FROM = 20
"""Grids of at least this many dots are fitted with a homography plus a quadratic term in board coordinates (lens
distortion bends rows over a large board); smaller ones with the homography alone (8 parameters: enough)."""
ABSENT_RADIUS_SHARE = 0.5
"""Absent dots (:func:`absent_dots`): the grey level at a board point not seen is the mean over a disk of this share
of the neighbouring dots' radius around its predicted position ..."""
ABSENT_WHITE = 0.75
"""... and the dot is absent from bare board when that mean lies above the dots' dark level by this share of the
contrast to the board's white (a dot there, even blurred or half-hidden, darkens its centre below half the
contrast; a grey occluder (a hand) sits lower)."""
ABSENT_MAX_SHARE = 0.05
"""A partial labelling of an unmarked board is refused when more of the board's dots than this share of the labelled
ones lie on bare board (:func:`absent_dots`): a lattice of another layout leaves about as many bare places as it
labels (a staggered 5x5 lattice read as part of a 7x7 board: 24 for 25). Fewer (one dot in 20 labelled, two in 40)
are dots washed out by glare or missing from the print: the view is kept and they are named among the dots left
out."""
MAX_GAPS = 1
"""A partial labelling of an unmarked board is refused when more than this many separate gaps of unseen board dots
reach the board's edge inside the image (:func:`unseen_gaps`)."""
DIAMETER_FACTOR = 2.5
"""The dots' diameter measured against the lattice (median dot area over cell area, as a diameter over the pitch)
lies within this factor of the board's stated diameter either way: the default diameter is half the dot spacing,
and printed boards use 0.2-0.8 of it. Noise specks that line up are far smaller than their spacing."""


def _steps(board: Board) -> tuple[np.ndarray, np.ndarray]:
    """The two nearest-neighbour lattice steps (2,) of ``board`` in lattice coordinates, and the (2, 2) matrix whose
    inverse maps image derivatives along them to derivatives along the board's x and y (read-only, made once per
    layout)."""
    return _steps_of(board.layout == "asymmetric")


@functools.lru_cache(maxsize=2)
def _steps_of(asymmetric: bool) -> tuple[np.ndarray, np.ndarray]:
    if asymmetric:
        M = np.array([[1, 1], [-1, 1]], np.float64)  # columns: the diagonal steps (1, -1) and (1, 1)
    else:
        M = np.eye(2)
    Minv = np.linalg.inv(M)
    M.flags.writeable = Minv.flags.writeable = False
    return M, Minv


def local_steps(board: Board, points: np.ndarray, centres: np.ndarray, *, edge_order: int = 1) -> np.ndarray:
    """The image Jacobian at each of the board points ``points``, from the neighbours among them.

    Central differences, one-sided at the grid's edge (as :func:`numpy.gradient`'s ``edge_order``: of first order,
    or of second order where two neighbours lie on that side, exact for a quadratic map as the central difference
    is: a wide lens's map bends over a pitch, and the first-order difference at the edge of a 4x5 grid seen through
    a fisheye erred by 20 %). The differences along the two nearest-neighbour steps by :func:`_step_differences`
    (one compiled pass over a grid of the lattice), then into board axes.

    Parameters
    ----------
    board : Board
        The board.
    points : numpy.ndarray
        (K,) int board point indices.
    centres : numpy.ndarray
        (K, 2) float their image positions, px.
    edge_order : int, optional
        1 or 2: the order of the one-sided differences at the grid's edge.

    Returns
    -------
    numpy.ndarray
        (K, 2, 2) float px per pitch; columns: along board x, along board y; NaN where an axis has no neighbour.

    Raises
    ------
    ValueError
        ``edge_order`` not 1 or 2 (a caller's bug).

    Examples
    --------
    >>> board = Board(3, 4, 10.0, 5.0)
    >>> local_steps(board, np.arange(12), board.object_points()[:, :2] * 3 + 50)[5].tolist()
    [[30.0, 0.0], [0.0, 30.0]]
    """
    if edge_order not in (1, 2):
        raise ValueError(f"edge_order must be 1 or 2, got {edge_order!r}")
    points = np.asarray(points, np.int64)
    K = len(points)
    if K == 0:
        return np.full((0, 2, 2), np.nan)
    M, Minv = _steps(board)
    Jp = np.empty((K, 2, 2))
    _step_differences(
        np.ascontiguousarray(board.lattice_coords()[points]),
        np.ascontiguousarray(centres, np.float64),
        np.ascontiguousarray(M.T.astype(np.int64)),
        edge_order == 2,
        Jp,
    )
    return Jp @ Minv


@njit(cache=True, nogil=True)
def _step_differences(L, centres, steps, second, out):
    """Writes into ``out`` (K, 2, 2) the image differences (px) along each lattice step ``steps[s]`` (2, 2) int
    (column s of ``out``) at the points of lattice coordinates ``L`` (K, 2) int with image positions ``centres``
    (K, 2): ``(c[next] - c[prev]) / 2`` where both neighbours are among the points, ``c[next] - c`` or ``c - c[prev]``
    where one is (where ``second`` and the one after it is too: ``(4 c[next] - 3 c - c[next2]) / 2``, or
    ``(3 c - 4 c[prev] + c[prev2]) / 2``), NaN where none is."""
    K = len(L)
    lo0, lo1, hi0, hi1 = L[0, 0], L[0, 1], L[0, 0], L[0, 1]
    for k in range(K):
        lo0, lo1 = min(lo0, L[k, 0]), min(lo1, L[k, 1])
        hi0, hi1 = max(hi0, L[k, 0]), max(hi1, L[k, 1])
    lo0 -= 4
    lo1 -= 4
    grid = np.full((hi1 - lo1 + 5, hi0 - lo0 + 5), -1, np.int64)
    for k in range(K):
        grid[L[k, 1] - lo1, L[k, 0] - lo0] = k
    for s in range(2):
        s0, s1 = steps[s, 0], steps[s, 1]
        for k in range(K):
            gx, gy = L[k, 0] - lo0, L[k, 1] - lo1
            f = grid[gy + s1, gx + s0]
            r = grid[gy - s1, gx - s0]
            f2 = grid[gy + 2 * s1, gx + 2 * s0] if second and f >= 0 else -1
            r2 = grid[gy - 2 * s1, gx - 2 * s0] if second and r >= 0 else -1
            for j in range(2):
                if f >= 0 and r >= 0:
                    out[k, j, s] = 0.5 * (centres[f, j] - centres[r, j])
                elif f2 >= 0:
                    out[k, j, s] = 0.5 * (4.0 * centres[f, j] - 3.0 * centres[k, j] - centres[f2, j])
                elif f >= 0:
                    out[k, j, s] = centres[f, j] - centres[k, j]
                elif r2 >= 0:
                    out[k, j, s] = 0.5 * (3.0 * centres[k, j] - 4.0 * centres[r, j] + centres[r2, j])
                elif r >= 0:
                    out[k, j, s] = centres[k, j] - centres[r, j]
                else:
                    out[k, j, s] = np.nan


def check_grid(
    board: Board,
    points: np.ndarray,
    centres: np.ndarray,
    conics: np.ndarray,
    params: tuple[np.ndarray, ...] | None = None,
    H: np.ndarray | None = None,
    camera: Camera | None = None,
) -> str | None:
    """Why the measured dots are not trusted to be the board, or ``None`` (module docstring).

    Parameters
    ----------
    board : Board
        The board.
    points : numpy.ndarray
        (K,) int board points of the measured dots.
    centres : numpy.ndarray
        (K, 2) float ellipse centres, px.
    conics : numpy.ndarray
        (K, 3, 3) float their conics.
    params : tuple of numpy.ndarray or None, optional
        ``conic_params_batch(conics)`` where the caller has it.
    H : numpy.ndarray or None, optional
        (3, 3) the least-squares homography board mm -> ``centres`` where the caller has it
        (``cv2.findHomography``, all points; the detector hands it on to the centre correction).
    camera : Camera or None, optional
        The lens model, where given; a lattice fit that the pixels fail is tried on the centres undistorted by it too
        (:func:`_undistorted_residual`).

    Returns
    -------
    str or None
        One line saying why not (too few dots, no lattice, dots that do not fill their cells, ...); ``None`` when
        trusted.
    """
    K = len(points)
    if K < 4:
        return f"only {K} dots measured"
    obj_mm = board.object_points()[points, :2]
    obj = obj_mm / board.pitch_mm
    if H is None:
        H, _ = cv2.findHomography(obj_mm, centres, 0)
    if H is None or not np.all(np.isfinite(H)):
        return "no homography from the board explains the dots"
    q = cv2.perspectiveTransform(obj_mm.reshape(-1, 1, 2), H).reshape(-1, 2)
    res = centres - q
    if K >= QUADRATIC_FROM:  # lens distortion: a quadratic term in board coordinates
        x, y = (obj - obj.mean(axis=0)).T / max(float(np.ptp(obj)), 1.0)
        A = np.column_stack([np.ones(K), x, y, x * x, x * y, y * y])
        coef, *_ = np.linalg.lstsq(A, res, rcond=None)
        res = res - A @ coef
    J = local_steps(board, points, centres)
    finite = np.all(np.isfinite(J), axis=(1, 2))
    det = np.full(K, np.nan)
    if np.any(finite):
        det[finite] = np.linalg.det(J[finite])
    step = median(np.sqrt(np.abs(det[finite]))) if np.any(finite) else np.nan
    if not np.isfinite(step) or step <= 0:
        return "the dots have no lattice neighbours"
    rel = float(np.sqrt(np.mean(np.sum(res**2, axis=1)))) / step
    if rel > MAX_LATTICE_RESIDUAL:  # a grid bent by a wide lens: each dot against the smooth map of its neighbours
        local = local_residual(obj, centres)
        rel = rel if local is None else min(rel, local)
    if rel > MAX_LATTICE_RESIDUAL and camera is not None:
        rel = min(rel, _undistorted_residual(board, points, centres, camera))
    if rel > MAX_LATTICE_RESIDUAL:
        return (
            f"the dots are not on a regular lattice (RMS {rel:.2f} of a lattice step off the best fit; at most "
            f"{MAX_LATTICE_RESIDUAL:g})"
        )
    _, axes, _, ok = params if params is not None else conic_params_batch(conics)
    plain = ok & ~board.is_marker()[points] & finite
    if np.any(plain):
        fill = np.pi * axes[plain, 0] * axes[plain, 1] / np.abs(det[plain])
        d_rel = float(np.sqrt(median(fill) / np.pi)) * 2.0  # measured diameter / pitch
        stated = board.diameter_mm / board.pitch_mm
        if not stated / DIAMETER_FACTOR <= d_rel <= stated * DIAMETER_FACTOR:
            return (
                f"the dots measure {d_rel:.2f} pitches across, the board's are {stated:.2f} (--diameter, "
                f"--pitch): not this board"
            )
    return None


def _undistorted_residual(board: Board, points: np.ndarray, centres: np.ndarray, camera: Camera) -> float:
    """RMS residual, over the median local lattice step, of the homography board -> the ellipse centres undistorted
    by ``camera`` (where a flat board's dots lie on one homography however strong the lens); ``inf`` where fewer
    than 5 of them undistort (4 fix a homography: nothing to test) or no homography fits.

    Parameters
    ----------
    board : Board
    points : ndarray
        (K,) board points.
    centres : ndarray
        (K, 2) px, their ellipse centres in the observed image.
    camera : Camera

    Returns
    -------
    float
        A share of the lattice step, as :func:`check_grid` measures the pixels.
    """
    u = undistort_pixels(centres, camera)
    ok = np.all(np.isfinite(u), axis=1)
    if np.sum(ok) < 5:
        return float("inf")
    pts, u = np.asarray(points)[ok], u[ok]
    obj_mm = board.object_points()[pts, :2]
    H, _ = cv2.findHomography(obj_mm, u, 0)
    if H is None or not np.all(np.isfinite(H)):
        return float("inf")
    res = u - cv2.perspectiveTransform(obj_mm.reshape(-1, 1, 2), H).reshape(-1, 2)
    J = local_steps(board, pts, u)
    finite = np.all(np.isfinite(J), axis=(1, 2))
    if not np.any(finite):
        return float("inf")
    step = median(np.sqrt(np.abs(np.linalg.det(J[finite]))))
    if not np.isfinite(step) or step <= 0:
        return float("inf")
    return float(np.sqrt(np.mean(np.sum(res**2, axis=1)))) / step


def _unseen_in_image(
    board: Board,
    points: np.ndarray,
    centres: np.ndarray,
    radii: np.ndarray,
    shape: tuple[int, ...],
    camera: Camera | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The board points a partial labelling does not see, where the labelled ones' homography puts them, and which
    lie inside the image by two dot radii: ``(missing (U,), positions (U, 2) px, inside (U,) bool)``; None where
    there is nothing to predict (fewer than 4 labelled points, none missing, no homography)."""
    H_img, W_img = shape[:2]
    missing = np.setdiff1d(np.arange(board.n_points), points)
    if len(points) < 4 or len(missing) == 0:
        return None
    obj = board.object_points()[:, :2]
    at = centres if camera is None else undistort_pixels(centres, camera)
    ok = np.all(np.isfinite(at), axis=1)
    if np.sum(ok) < 4:
        return None
    Hm, _ = cv2.findHomography(obj[points][ok], at[ok], 0)
    if Hm is None or not np.all(np.isfinite(Hm)):
        return None
    q = cv2.perspectiveTransform(obj[missing].reshape(-1, 1, 2), Hm).reshape(-1, 2)
    if camera is not None:
        # in the image only where in front of the camera (the labelled dots' side of the vanishing line) and where
        # the lens images the undistorted position (inside_image: the round trip through the model holds)
        w = Hm[2] @ np.vstack([obj[missing].T, np.ones(len(missing))])
        w_seen = Hm[2] @ np.vstack([obj[points][ok].T, np.ones(int(np.sum(ok)))])
        front = np.sign(w) == np.sign(np.median(w_seen))
        q = np.where((front & inside_image(camera)(q))[:, None], distort_pixels(q, camera), np.nan)
    pad = 2.0 * float(np.median(radii))
    with np.errstate(invalid="ignore"):
        inside = (q[:, 0] >= pad) & (q[:, 1] >= pad) & (q[:, 0] <= W_img - 1 - pad) & (q[:, 1] <= H_img - 1 - pad)
    return missing, q, inside


def unseen_gaps(
    board: Board,
    points: np.ndarray,
    centres: np.ndarray,
    radii: np.ndarray,
    shape: tuple[int, ...],
    camera: Camera | None = None,
    skip: np.ndarray | None = None,
) -> int:
    """How many separate gaps of a partial labelling reach the board's edge inside the image.

    A board seen in part is cut by the image border (its unseen dots lie outside the image) or hidden by something
    in front of it: its unseen dots inside the image then form one region that reaches the board's edge (an
    occluder coming in from one side). A dot lattice of another shape whose part fits the board (a staggered lattice
    on a card, whose diagonals make a square lattice spanning the board) leaves unseen board dots inside the image
    in several separate places around the lattice, where the card ends.

    Parameters
    ----------
    board : Board
        The board.
    points : numpy.ndarray
        (K,) int labelled board points.
    centres : numpy.ndarray
        (K, 2) float their rough centres, px.
    radii : numpy.ndarray
        (K,) float their rough radii, px.
    shape : tuple of int
        The image's (H, W).
    camera : Camera or None, optional
        The lens model, where given.
    skip : numpy.ndarray or None, optional
        Board points not counted (dots found absent from bare board: :func:`absent_dots`).

    Returns
    -------
    int
        Connected groups (neighbours on the board's lattice) of unseen board points inside the image, each with a
        point on the board's outer rows or columns; 0 where nothing can be predicted.
    """
    predicted = _unseen_in_image(board, points, centres, radii, shape, camera)
    if predicted is None:
        return 0
    missing, _, inside = predicted
    gap = missing[inside]
    if skip is not None and len(skip):
        gap = np.setdiff1d(gap, skip)
    if len(gap) == 0:
        return 0
    # groups: 8-connected on the board's (row, column) grid (either layout's lattice neighbours are among them);
    # linear in the board's size (a 1000 x 1000 board's gaps included)
    i, j = np.divmod(gap, board.cols)
    grid = np.zeros((board.rows, board.cols), np.uint8)
    grid[i, j] = 1
    _, labels = cv2.connectedComponents(grid, connectivity=8)
    label = labels[i, j]
    edge = (i == 0) | (i == board.rows - 1) | (j == 0) | (j == board.cols - 1)
    return len(set(label[edge].tolist()))


def absent_dots(
    board: Board,
    points: np.ndarray,
    centres: np.ndarray,
    radii: np.ndarray,
    gray: np.ndarray,
    camera: Camera | None = None,
) -> np.ndarray:
    """Board points of an unmarked board's partial labelling that the image shows as bare board.

    Where the board has a dot, inside the image, the image is as bright as the board's white (a lattice of another
    layout labelled as part of the board, e.g. a staggered 5x5 grid whose diagonals make a square lattice spanning
    7x7: a dot hidden by an occluder is not bright there). Positions of the other board points from the homography of
    the labelled ones (:data:`ABSENT_RADIUS_SHARE`, :data:`ABSENT_WHITE`); with a lens model ``camera``, the
    homography of their undistorted positions, its predictions distorted back (a wide lens bends the rows away from
    any homography of the pixels).

    Parameters
    ----------
    board : Board
        The board.
    points : numpy.ndarray
        (K,) int labelled board points.
    centres : numpy.ndarray
        (K, 2) float their rough centres, px.
    radii : numpy.ndarray
        (K,) float their rough radii, px.
    gray : numpy.ndarray
        (H, W) the image.
    camera : Camera or None, optional
        The lens model, where given.

    Returns
    -------
    numpy.ndarray
        (A,) int64 the absent board points (empty when none, or when the image cannot tell: no homography, no
        board point predicted inside the image, no white between labelled neighbours).
    """
    predicted = _unseen_in_image(board, points, centres, radii, gray.shape, camera)
    if predicted is None:
        return np.zeros(0, np.int64)
    missing, q, inside = predicted
    if not np.any(inside):
        return np.zeros(0, np.int64)
    obj = board.object_points()[:, :2]
    r = float(np.median(radii))
    g = np.asarray(gray)
    if g.dtype not in (np.uint8, np.uint16, np.float32):
        g = g.astype(np.float32)
    k = max(1.0, ABSENT_RADIUS_SHARE * r)
    th = np.linspace(0.0, 2.0 * np.pi, 12, endpoint=False)
    rho = np.array([0.0, 0.5 * k, k])
    dx = np.concatenate([[0.0], (rho[1:, None] * np.cos(th)).ravel()])
    dy = np.concatenate([[0.0], (rho[1:, None] * np.sin(th)).ravel()])

    def mean_at(c: np.ndarray) -> np.ndarray:
        x = (c[:, 0:1] + dx).astype(np.float32)
        y = (c[:, 1:2] + dy).astype(np.float32)
        return cv2.remap(g, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64).mean(1)

    dark = float(np.median(mean_at(centres)))
    # the board's white: half-way between labelled neighbours (midpoints of the board's nearest-neighbour pairs)
    step = board.pitch_mm * (np.sqrt(2.0) if board.layout == "asymmetric" else 1.0)
    d = np.linalg.norm(obj[points][:, None] - obj[points][None], axis=-1)
    i, j = np.nonzero(np.triu(np.abs(d - step) < 1e-6 * step, 1))
    if len(i) == 0:
        return np.zeros(0, np.int64)
    white = float(np.median(mean_at(0.5 * (centres[i] + centres[j]))))
    if not white > dark:
        return np.zeros(0, np.int64)
    level = mean_at(q[inside])
    return missing[inside][level > dark + ABSENT_WHITE * (white - dark)]
