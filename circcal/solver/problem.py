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
from circcal.observations import BOARD_KEY_DECIMALS, distinct_points
from circcal.rotation import left_jacobian, rodrigues, rotated_jacobian

__all__ = ["BoardModel", "board_model", "Problem", "MIN_VIEWS_PER_BOARD_POINT", "BOARD_KEY_DECIMALS"]

#: Points projected at a time by :meth:`Problem.evaluate_stacked` (their temporaries ~2 MB; measured as fast as one
#: pass over 49,000 points, and the peak memory of a 1000-view solve drops by ~400 B per point).
EVALUATE_CHUNK = 4096

#: With board refinement, a board point seen in fewer views than this is held at its nominal position (a point seen
#: in one or two views is not constrained beyond its own views' poses).
MIN_VIEWS_PER_BOARD_POINT = 3


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


class Problem:
    """Stacked observations and the free-parameter map for one least-squares solve.

    Parameter vector: the free intrinsics (``nf``), then the free board coordinates (``nb``, only with board
    refinement), then 6 pose parameters per view; ``ng = nf + nb`` "global" parameters are shared by all views.
    """

    def __init__(self, obj, img, base: np.ndarray, free: list[int], aspect: float | None,
                 board: BoardModel | None = None, lens: str = "opencv5"):
        self.counts = np.array([len(o) for o in obj])
        #: every view holds the same number of points: per-view products are one batched product (no gathers)
        self.uniform = bool(np.all(self.counts == self.counts[0]))
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

    def _times_view_matrix(self, A: np.ndarray, M: np.ndarray) -> np.ndarray:
        """Each observation's rows times its view's matrix: ``A`` (N, 3) or (N, k, 3), ``M`` (V, 3, m) ->
        (N, m) or (N, k, m). One batched product over the views when they all hold the same number of points (no
        gather), else through the (N, 3, m) gathered matrices."""
        if self.uniform:
            return (A.reshape(self.n_views, -1, 3) @ M).reshape(*A.shape[:-1], M.shape[-1])
        return np.einsum("n...j,njk->n...k", A, M[self.view])

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """-> (f (2N,) projected - observed px, Xc (N, 3) mm, J_global (N, 2, ng), J_pose (N, 2, 6)); the two
        Jacobians are views of :meth:`evaluate_stacked`'s one array."""
        f, Xc, J = self.evaluate_stacked(x)
        return f, Xc, J[:, :, : self.ng], J[:, :, self.ng:]

    def evaluate_stacked(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """-> (f (2N,) projected - observed px, Xc (N, 3) mm, J (N, 2, ng + 6)): per point the two Jacobian rows,
        the global columns and then its own view's 6 pose columns (rvec, tvec), in one C-contiguous array (what
        :func:`circcal.solver.lm.normal_blocks` multiplies view by view without a copy). All views are computed
        together, :data:`EVALUATE_CHUNK` points at a time. The last evaluation is kept (the solver asks again at the same x); only one
        evaluation's arrays are alive at a time."""
        key = x.tobytes()
        if key == self._cache_x:
            return self._cache
        self._cache_x = self._cache = None
        p = self.intrinsics(x)
        rv, tv = self.poses(x)
        R = rodrigues(rv)
        X = self.X if self.board is None else self.board_points(x)[self.board.point_index]
        Y = self._times_view_matrix(X, np.transpose(R, (0, 2, 1)))                 # R_v X
        Xc = Y + (tv.repeat(self.counts[0], axis=0) if self.uniform else tv[self.view])
        ng, nf = self.ng, self.nf
        f = np.empty(2 * len(X))
        J = np.empty((len(X), 2, ng + 6))
        Jl = left_jacobian(rv)
        # in chunks (whole views when they hold equal counts): the projection's own temporaries stay a few MB,
        # whatever N (the peak is J and its inputs)
        step = max(1, EVALUATE_CHUNK // self.counts[0]) * self.counts[0] if self.uniform else EVALUATE_CHUNK
        for a in range(0, len(X), step):
            sl = slice(a, a + step)
            uv, Ji, dP = project_camera_jacobian(Xc[sl], p, self.lens)
            f[2 * a: 2 * a + 2 * len(uv)] = (uv - self.uv[sl]).ravel()
            J[sl, :, :nf] = Ji if self.T_is_identity else Ji @ self.T
            C = rotated_jacobian(dP, Y[sl])
            if self.uniform:  # this chunk's views times their own left Jacobians, one batched product
                v0 = a // self.counts[0]
                k = len(C) // self.counts[0]
                J[sl, :, ng: ng + 3] = (C.reshape(k, -1, 3) @ Jl[v0: v0 + k]).reshape(C.shape)
            else:
                np.einsum("nij,njk->nik", C, Jl[self.view[sl]], out=J[sl, :, ng: ng + 3])
            J[sl, :, ng + 3:] = dP
        if self.board is not None:
            # d uv / d X_board = (d uv / d Xc) R
            Jb = self._times_view_matrix(np.ascontiguousarray(J[:, :, ng + 3:]), R)   # (N, 2, 3); J's d uv / d Xc
            J[:, :, nf:ng] = 0.0
            rows, coords = np.nonzero(self.board_cols >= 0)
            J[rows, :, self.board_cols[rows, coords]] = Jb[rows, :, coords]
        self._cache_x, self._cache = key, (f, Xc, J)
        return self._cache

    def fun(self, x: np.ndarray) -> np.ndarray:
        return self.evaluate(x)[0]

    def jac(self, x: np.ndarray):
        from scipy.sparse import csr_matrix

        m, row_nnz = 2 * len(self.X), self.ng + 6
        indptr = np.arange(0, m * row_nnz + 1, row_nnz)
        cols_i = np.broadcast_to(np.arange(self.ng), (m, self.ng))
        cols_p = self.ng + 6 * np.repeat(self.view, 2)[:, None] + np.arange(6)
        indices = np.concatenate([cols_i, cols_p], axis=1).ravel()
        data = self.evaluate_stacked(x)[2].ravel()
        return csr_matrix((data, indices, indptr), shape=(m, self.n))
