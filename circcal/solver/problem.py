"""One least-squares calibration problem: the stacked observations of every view, the map from the free
parameters to intrinsics, board points and poses, and the residuals with their analytic Jacobian.

Parameter vector: the free intrinsics (``nf``), then the free board coordinates (``nb``, only with board
refinement: the object-releasing method of Strobl & Hirzinger 2011, as ``cv2.calibrateCameraRO``), then 6 pose
parameters per view (rvec, tvec). The ``ng = nf + nb`` global parameters are shared by all views; each view's
residuals depend only on them and its own pose (the sparsity :mod:`circcal.solver.lm` exploits). Residuals are
``projected - observed`` (px); the camera model is :mod:`circcal.model`'s.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from circcal.errors import CalibrationError
from circcal.model import project_camera_jacobian
from circcal.rotation import left_jacobian, rodrigues, rotated_jacobian

__all__ = ["BoardModel", "board_model", "Problem", "MIN_VIEWS_PER_BOARD_POINT", "BOARD_KEY_DECIMALS"]

#: With board refinement, a board point seen in fewer views than this is held at its nominal position (a point seen
#: in one or two views is not constrained beyond its own views' poses).
MIN_VIEWS_PER_BOARD_POINT = 3
#: Board points are identified across views by their nominal coordinates rounded to this many decimals (mm).
BOARD_KEY_DECIMALS = 6


@dataclass
class BoardModel:
    """Board points as unknowns (the object-releasing method of Strobl & Hirzinger 2011, ``cv2.calibrateCameraRO``).

    ``nominal``: (P, 3) mm, the distinct board points in order of first appearance; ``point_index``: (N,) the board
    point of each stacked observation; ``free``: indices into ``nominal.ravel()`` of the coordinates estimated (the
    rest are held: the gauge and points seen in fewer than 3 views); ``gauge``: (a, b, c) point indices: a and b held
    in x, y, z, c in z (7 constraints: the similarity transform a planar board's shape cannot fix by itself).
    """

    nominal: np.ndarray
    point_index: np.ndarray
    free: np.ndarray
    gauge: tuple[int, int, int]
    held_unseen: list[int]


def board_model(obj: list[np.ndarray], gauge: tuple[int, int, int] | None) -> BoardModel:
    """Identify the distinct board points across views (by their coordinates) and choose the gauge.

    Default gauge: a = the first point, b = the point farthest from a, c = the point farthest from the line a-b (any
    three non-collinear points give the same intrinsics and residuals; only the board frame changes).
    """
    X = np.concatenate(obj)
    keys = np.round(X, BOARD_KEY_DECIMALS)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    point_index = rank[np.asarray(inverse).ravel()]
    nominal = X[first[order]].copy()
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


class Problem:
    """Stacked observations and the free-parameter map for one least-squares solve.

    Parameter vector: the free intrinsics (``nf``), then the free board coordinates (``nb``, only with board
    refinement), then 6 pose parameters per view; ``ng = nf + nb`` "global" parameters are shared by all views.
    """

    def __init__(self, obj, img, base: np.ndarray, free: list[int], aspect: float | None,
                 board: BoardModel | None = None, lens: str = "opencv5"):
        self.counts = np.array([len(o) for o in obj])
        self.view = np.repeat(np.arange(len(obj)), self.counts)
        self.X = np.concatenate(obj)
        self.uv = np.concatenate(img)
        self.n_views = len(obj)
        self.base = base.copy()
        self.base[free] = 0.0
        if aspect is not None:
            self.base[0] = 0.0
        self.free = free
        self.aspect = aspect
        self.lens = lens
        # intrinsics (4 + n_dist,) = base + T @ x_intr
        n_intr = len(self.base)
        self.T = np.zeros((n_intr, len(free)))
        for j, k in enumerate(free):
            self.T[k, j] = 1.0
            if aspect is not None and k == 1:
                self.T[0, j] = aspect
        self.nf = len(free)
        self.T_is_identity = self.T.shape == (n_intr, n_intr) and bool(np.all(self.T == np.eye(n_intr)))
        ends = np.cumsum(self.counts)
        self.slices = [slice(a, b) for a, b in zip(ends - self.counts, ends)]
        self.board = board
        self.nb = 0 if board is None else len(board.free)
        if board is not None:
            # column (within the global block) of each observation's x, y, z; -1 where held
            slot = np.full(board.nominal.size, -1)
            slot[board.free] = self.nf + np.arange(self.nb)
            self.board_cols = slot.reshape(-1, 3)[board.point_index]          # (N, 3)
        self.ng = self.nf + self.nb
        self.n = self.ng + 6 * self.n_views
        m = 2 * len(self.X)
        row_nnz = self.ng + 6
        self.indptr = np.arange(0, m * row_nnz + 1, row_nnz)
        cols_i = np.broadcast_to(np.arange(self.ng), (m, self.ng))
        cols_p = self.ng + 6 * np.repeat(self.view, 2)[:, None] + np.arange(6)
        self.indices = np.concatenate([cols_i, cols_p], axis=1).ravel()
        self._cache_x: bytes | None = None

    def intrinsics(self, x: np.ndarray) -> np.ndarray:
        return self.base + self.T @ x[: self.nf]

    def board_points(self, x: np.ndarray) -> np.ndarray | None:
        """(P, 3) mm: the board points at ``x`` (None without board refinement)."""
        if self.board is None:
            return None
        pts = self.board.nominal.copy().ravel()
        pts[self.board.free] = x[self.nf: self.ng]
        return pts.reshape(-1, 3)

    def pack(self, intr: np.ndarray, rvecs: np.ndarray, tvecs: np.ndarray) -> np.ndarray:
        xi = np.array([intr[k] for k in self.free])
        xb = self.board.nominal.ravel()[self.board.free] if self.board is not None else np.zeros(0)
        return np.concatenate([xi, xb, np.column_stack([rvecs, tvecs]).ravel()])

    def poses(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        P = x[self.ng:].reshape(-1, 6)
        return P[:, :3].copy(), P[:, 3:].copy()

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """-> (f (2N,) projected - observed, Xc (N, 3), J_global (N, 2, ng), J_pose (N, 2, 6))."""
        key = x.tobytes()
        if key == self._cache_x:
            return self._cache
        p = self.intrinsics(x)
        rv, tv = self.poses(x)
        R = rodrigues(rv)
        Jl = left_jacobian(rv)
        X = self.X if self.board is None else self.board_points(x)[self.board.point_index]
        Y = np.empty_like(X)
        for v, sl in enumerate(self.slices):
            np.matmul(X[sl], R[v].T, out=Y[sl])
        Xc = Y + np.repeat(tv, self.counts, axis=0)
        uv, Ji, dP = project_camera_jacobian(Xc, p, self.lens)
        f = (uv - self.uv).ravel()
        C = rotated_jacobian(dP, Y)
        Jp = np.empty((len(X), 2, 6))
        for v, sl in enumerate(self.slices):
            np.matmul(C[sl], Jl[v], out=Jp[sl, :, :3])
        Jp[:, :, 3:] = dP
        Jg = Ji if self.T_is_identity else Ji @ self.T
        if self.board is not None:
            # d uv / d X_board = (d uv / d Xc) R
            Jb = dP @ R[self.view]                                            # (N, 2, 3)
            Jg = np.concatenate([Jg, np.zeros((len(Xc), 2, self.nb))], axis=2)
            rows, coords = np.nonzero(self.board_cols >= 0)
            Jg[rows, :, self.board_cols[rows, coords]] = Jb[rows, :, coords]
        self._cache_x, self._cache = key, (f, Xc, Jg, Jp)
        return self._cache

    def fun(self, x: np.ndarray) -> np.ndarray:
        return self.evaluate(x)[0]

    def jac(self, x: np.ndarray):
        from scipy.sparse import csr_matrix

        _, _, Ji, Jp = self.evaluate(x)
        data = np.concatenate([Ji.reshape(-1, self.ng), Jp.reshape(-1, 6)], axis=1).ravel()
        return csr_matrix((data, self.indices, self.indptr), shape=(2 * len(self.X), self.n))
