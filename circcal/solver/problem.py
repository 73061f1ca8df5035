"""One least-squares calibration problem: the stacked observations of every view, the map from the free
parameters to intrinsics, board points and poses, and the residuals with their analytic Jacobian.

Parameter vector: the free intrinsics (``nf``), then the free board coordinates (``nb``, only with board
refinement: the object-releasing method of Strobl & Hirzinger 2011, as ``cv2.calibrateCameraRO``), then the board
warp (``nw`` = 2, only with ``board_warp``: mrcal's ``calobject_warp``, :func:`warp_basis`), then 6 pose parameters
per view (rvec, tvec). The ``ng = nf + nb + nw`` global parameters are shared by all views; each view's
residuals depend only on them and its own pose (the sparsity :mod:`circcal.solver.lm` exploits). Residuals are
``projected - observed`` (px); the camera model is :mod:`circcal.model`'s. Everything is computed in chunks of
whole views (:data:`EVALUATE_CHUNK` points): the solver's normal equations are summed chunk by chunk, so the
(2N, ng + 6) Jacobian never exists (only :meth:`Problem.evaluate`, for the scipy cross-check, assembles it).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from circcal.model import distort, lens_model, project_camera_jacobian
from circcal.model.fisheye import fisheye_distort
from circcal.observations import BOARD_KEY_DECIMALS
from circcal.rotation import left_jacobian, rodrigues, rotated_jacobian
from circcal.solver.boardpoints import MIN_VIEWS_PER_BOARD_POINT, BoardModel, board_model, warp_basis, warp_box

if TYPE_CHECKING:  # annotations only
    from scipy.sparse import csr_matrix

__all__ = [
    "BoardModel",
    "board_model",
    "Chunk",
    "chunks",
    "Problem",
    "project_pixels",
    "MIN_VIEWS_PER_BOARD_POINT",
    "BOARD_KEY_DECIMALS",
    "NormalBlocks",
    "warp_box",
    "warp_basis",
]

#: The blocks of ``J^T J`` and ``J^T f`` of :meth:`Problem.normal_equations`: ``(A, gi, B, D, gp)``.
NormalBlocks = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]

#: Points projected at a time (whole views, at least one): the residuals' and the Jacobian's temporaries stay a few
#: MB whatever N (measured as fast as one pass over 49,000 points), and the whole Jacobian never exists.
EVALUATE_CHUNK = 4096


@dataclass(frozen=True)
class Chunk:
    """Consecutive whole views ``v0:v1`` and their stacked observations ``a:b``, evaluated together.

    Attributes
    ----------
    a, b : int
        The chunk's rows among the stacked observations.
    v0, v1 : int
        Its views.
    groups : tuple of (ndarray, ndarray or None)
        ``(views (k,), rows (k c,) into the chunk or None)`` of its views by point count c (one group with rows None
        when every view of the problem holds the same count: its rows are a free reshape).
    """

    a: int
    b: int
    v0: int
    v1: int
    groups: tuple[tuple[np.ndarray, np.ndarray | None], ...]


def chunks(counts: np.ndarray, size: int) -> list[Chunk]:
    """Views in consecutive chunks of at most ``size`` points (at least one view each).

    Parameters
    ----------
    counts : ndarray
        (V,) points per view.
    size : int
        Points per chunk at most.

    Returns
    -------
    list of Chunk
    """
    ends = np.cumsum(counts)
    uniform = bool(np.all(counts == counts[0]))
    out: list[Chunk] = []
    v0 = 0
    groups: tuple[tuple[np.ndarray, np.ndarray | None], ...]
    while v0 < len(counts):
        a = int(ends[v0] - counts[v0])
        v1 = max(v0 + 1, int(np.searchsorted(ends, a + size, side="right")))
        if uniform:
            groups = ((np.arange(v0, v1), None),)
        else:
            starts = ends[v0:v1] - counts[v0:v1] - a
            groups = tuple(
                (v0 + np.flatnonzero(counts[v0:v1] == n), (starts[counts[v0:v1] == n][:, None] + np.arange(n)).ravel())
                for n in np.unique(counts[v0:v1])
            )
        out.append(Chunk(a, int(ends[v1 - 1]), v0, v1, groups))
        v0 = v1
    return out


def project_pixels(Xc: np.ndarray, p: np.ndarray, pinhole: bool) -> np.ndarray:
    """Camera-frame points -> pixels: :func:`circcal.model.project_camera_jacobian`'s value without its derivatives.

    In the same arithmetic: the two agree to the bit, so a trial step's cost is the cost the Jacobian pass sees there.

    Parameters
    ----------
    Xc : ndarray
        (n, 3) mm.
    p : ndarray
        (4 + n_dist,) intrinsics.
    pinhole : bool
        A pinhole lens model (else the fisheye).

    Returns
    -------
    ndarray
        (n, 2) px.
    """
    xd = distort(Xc[:, :2] * (1.0 / Xc[:, 2])[:, None], p[4:]) if pinhole else fisheye_distort(Xc, p[4:])
    uv: np.ndarray = xd * p[:2] + p[2:4]
    return uv


class Problem:
    """Stacked observations and the free-parameter map for one least-squares solve.

    Parameter vector: the free intrinsics (``nf``), then the free board coordinates (``nb``, only with board
    refinement), then the board warp (``nw`` = 2, only with ``warp``), then 6 pose parameters per view;
    ``ng = nf + nb + nw`` "global" parameters are shared by all views.

    Parameters
    ----------
    obj : sequence of ndarray, each shape (N_v, 3)
        Board points per view, mm.
    img : sequence of ndarray, each shape (N_v, 2)
        Their observed image points, px.
    base : ndarray, shape (4 + n_dist,)
        The intrinsics (fx, fy, cx, cy px, distortion); the held ones keep these values.
    free : list of int
        Indices into ``base`` of the free intrinsics.
    aspect : float or None
        With a held aspect ratio: fx = aspect * fy.
    board : BoardModel or None
        Board points as unknowns (board refinement).
    lens : str
        The lens model's name.
    warp : tuple of float or None
        With a board warp: the (x0, x1, y0, y1) mm box it spans (:func:`warp_box`; the warp's form is
        :func:`warp_basis`'s). Not with ``board``.

    Attributes
    ----------
    n_views : int
        V.
    nf, nb, nw, ng, n : int
        Free intrinsics, free board coordinates, warp parameters (0 or 2), global parameters, all parameters
        (ng + 6 V).
    X : ndarray, shape (N, 3)
        The stacked board points, mm.
    uv : ndarray, shape (N, 2)
        The stacked observations, px.
    view : ndarray, shape (N,)
        The view of each.
    chunks : list of Chunk
    """

    def __init__(
        self,
        obj: Sequence[np.ndarray],
        img: Sequence[np.ndarray],
        base: np.ndarray,
        free: list[int],
        aspect: float | None,
        board: BoardModel | None = None,
        lens: str = "opencv5",
        warp: tuple[float, float, float, float] | None = None,
    ) -> None:
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
        self.board = board
        self.nb = 0 if board is None else len(board.free)
        if board is not None:
            # column (within the global block) of each observation's x, y, z; -1 where held
            slot = np.full(board.nominal.size, -1)
            slot[board.free] = self.nf + np.arange(self.nb)
            self.board_cols = slot.reshape(-1, 3)[board.point_index]  # (N, 3)
        if board is not None and warp is not None:
            raise ValueError("a refined board and a board warp cannot be estimated together")
        self.warp_box = warp
        #: (N, 2) d z / d warp of each stacked observation; None without a warp
        self.warp_basis = None if warp is None else warp_basis(self.X, warp)
        self.nw = 0 if warp is None else 2
        self.ng = self.nf + self.nb + self.nw
        self.n = self.ng + 6 * self.n_views
        self.pinhole = lens_model(lens).pinhole
        self.chunks = chunks(self.counts, EVALUATE_CHUNK)
        self._frame_x: bytes | None = None
        self._frame_kept: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
        self._residuals_x: bytes | None = None
        self._residuals: tuple[np.ndarray, np.ndarray] | None = None
        self._normal_x: bytes | None = None
        self._normal: tuple[np.ndarray, NormalBlocks] | None = None

    def intrinsics(self, x: np.ndarray) -> np.ndarray:
        """The camera's parameters at ``x``: ``base + T @ x[:nf]``.

        Parameters
        ----------
        x : ndarray, shape (n,)
            The parameter vector.

        Returns
        -------
        ndarray, shape (4 + n_dist,)
            fx, fy, cx, cy (px), then the distortion coefficients.
        """
        p: np.ndarray = self.base + self.T @ x[: self.nf]
        return p

    def board_points(self, x: np.ndarray) -> np.ndarray | None:
        """The board points at ``x``.

        Parameters
        ----------
        x : ndarray, shape (n,)
            The parameter vector.

        Returns
        -------
        ndarray, shape (P, 3), or None
            mm; None without board refinement.
        """
        if self.board is None:
            return None
        return self._board_points(self.board, x)

    def _board_points(self, board: BoardModel, x: np.ndarray) -> np.ndarray:
        """(P, 3) mm: ``board``'s points with its free coordinates taken from ``x``."""
        pts = board.nominal.copy().ravel()
        pts[board.free] = x[self.nf : self.nf + self.nb]
        return pts.reshape(-1, 3)

    def warp(self, x: np.ndarray) -> np.ndarray | None:
        """The board warp at ``x``.

        Parameters
        ----------
        x : ndarray, shape (n,)
            The parameter vector.

        Returns
        -------
        ndarray, shape (2,), or None
            (w_x, w_y) mm (:func:`warp_basis`); None without a warp.
        """
        if self.warp_basis is None:
            return None
        w: np.ndarray = x[self.nf + self.nb : self.ng].copy()
        return w

    def pack(self, intr: np.ndarray, rvecs: np.ndarray, tvecs: np.ndarray) -> np.ndarray:
        """The parameter vector of given intrinsics and poses (board coordinates at their nominal values, a flat
        board warp).

        Parameters
        ----------
        intr : ndarray, shape (4 + n_dist,)
            The intrinsics (only the free ones are taken).
        rvecs : ndarray, shape (V, 3)
            Board -> camera rotations, rad.
        tvecs : ndarray, shape (V, 3)
            Translations, mm.

        Returns
        -------
        ndarray, shape (n,)
        """
        xi = np.array([intr[k] for k in self.free])
        xb = self.board.nominal.ravel()[self.board.free] if self.board is not None else np.zeros(0)
        return np.concatenate([xi, xb, np.zeros(self.nw), np.column_stack([rvecs, tvecs]).ravel()])

    def poses(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The views' poses at ``x``.

        Parameters
        ----------
        x : ndarray, shape (n,)
            The parameter vector.

        Returns
        -------
        rvecs : ndarray, shape (V, 3)
            Board -> camera rotations, rad (copies).
        tvecs : ndarray, shape (V, 3)
            Translations, mm.
        """
        P = x[self.ng :].reshape(-1, 6)
        return P[:, :3].copy(), P[:, 3:].copy()

    def _times_view_matrix(self, A: np.ndarray, M: np.ndarray, chunk: Chunk) -> np.ndarray:
        """The chunk's rows times their views' matrices: ``A`` (n, 3) or (n, k, 3), ``M`` (V, 3, m) -> (n, m) or
        (n, k, m). One batched product over the chunk's views when every view holds the same number of points (no
        gather), else through the (n, 3, m) gathered matrices."""
        if self.uniform:
            k = chunk.v1 - chunk.v0
            out: np.ndarray = (A.reshape(k, -1, 3) @ M[chunk.v0 : chunk.v1]).reshape(*A.shape[:-1], M.shape[-1])
            return out
        return np.asarray(np.einsum("n...j,njk->n...k", A, M[self.view[chunk.a : chunk.b]]))

    def _frame(self, x: np.ndarray, key: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What every pass needs at ``x`` (``key``: its bytes): intrinsics (4 + n_dist,), rvecs (V, 3), R (V, 3, 3),
        tvecs (V, 3) and the board points (N, 3) mm of the stacked observations. The last is kept: an accepted trial
        step's Jacobian pass follows its residual pass at the same x."""
        if key != self._frame_x:
            rv, tv = self.poses(x)
            X = self.X if self.board is None else self._board_points(self.board, x)[self.board.point_index]
            if self.warp_basis is not None:
                X = self.X.copy()
                X[:, 2] += self.warp_basis @ x[self.nf + self.nb : self.ng]
            self._frame_x, self._frame_kept = key, (self.intrinsics(x), rv, rodrigues(rv), tv, X)
        return self._frame_kept

    def _camera_points(
        self, X: np.ndarray, R: np.ndarray, tv: np.ndarray, chunk: Chunk
    ) -> tuple[np.ndarray, np.ndarray]:
        """The chunk's board points in its views' camera frames: ``(Y = R_v X, Xc = Y + t_v)``, both (n, 3) mm."""
        Y = self._times_view_matrix(X[chunk.a : chunk.b], np.transpose(R, (0, 2, 1)), chunk)
        t = tv[chunk.v0 : chunk.v1].repeat(self.counts[0], axis=0) if self.uniform else tv[self.view[chunk.a : chunk.b]]
        return Y, Y + t

    def residuals(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The residuals without the Jacobian (a trial step's cost), chunk by chunk.

        Equal to the bit to :meth:`normal_equations`' residuals. The last evaluation is kept.

        Parameters
        ----------
        x : ndarray, shape (n,)
            The parameter vector.

        Returns
        -------
        f : ndarray, shape (2N,)
            Projected - observed, px.
        Xc : ndarray, shape (N, 3)
            The board points in the camera frame, mm.
        """
        key = x.tobytes()
        if key == self._residuals_x and self._residuals is not None:
            return self._residuals
        self._residuals_x = self._residuals = None  # freed before the new arrays, unless a caller holds them
        p, _, R, tv, X = self._frame(x, key)
        f = np.empty(2 * len(X))
        Xc = np.empty((len(X), 3))
        for c in self.chunks:
            Xc[c.a : c.b] = self._camera_points(X, R, tv, c)[1]
            f[2 * c.a : 2 * c.b] = (project_pixels(Xc[c.a : c.b], p, self.pinhole) - self.uv[c.a : c.b]).ravel()
        self._residuals_x, self._residuals = key, (f, Xc)
        return f, Xc

    def _jacobian_chunks(
        self, x: np.ndarray, f: np.ndarray, Xc: np.ndarray, *, dense: bool = True
    ) -> Iterator[tuple[Chunk, np.ndarray, np.ndarray, np.ndarray | None]]:
        """Per chunk ``(chunk, J_global (n, 2, ng), J_pose (n, 2, 6), J_board)``: the Jacobian rows of its n
        observations, the global columns and their own view's 6 pose columns (rvec, tvec); fills the residuals ``f``
        (2N,) and camera points ``Xc`` (N, 3) as it goes. Only one chunk's Jacobian exists at a time.

        With board refinement and ``dense=False``, ``J_global`` holds only the ``nf`` intrinsics' columns and
        ``J_board`` (n, 2, 3) each observation's derivative by its own board point's x, y, z (the held coordinates'
        columns zeroed; :attr:`board_cols` says where each goes): each row touches 3 of the ``nb`` board columns, so
        :meth:`normal_equations` sums those blocks sparsely. Otherwise ``J_board`` is None."""
        p, rv, R, tv, X = self._frame(x, x.tobytes())
        Jl = left_jacobian(rv)
        ng, nf = self.ng, self.nf
        for c in self.chunks:
            Y, Xc[c.a : c.b] = self._camera_points(X, R, tv, c)
            uv, Ji, dP = project_camera_jacobian(Xc[c.a : c.b], p, self.lens)
            f[2 * c.a : 2 * c.b] = (uv - self.uv[c.a : c.b]).ravel()
            Jf = Ji if self.T_is_identity else Ji @ self.T
            Jsparse = None
            if self.board is None and self.warp_basis is None:
                Jg = Jf
            else:
                # d uv / d X_board = (d uv / d Xc) R
                Jb = self._times_view_matrix(dP, R, c)  # (n, 2, 3)
                if self.board is not None and not dense:
                    Jg, Jsparse = Jf, Jb * (self.board_cols[c.a : c.b] >= 0)[:, None, :]
                else:
                    Jg = np.empty((len(uv), 2, ng))
                    Jg[:, :, :nf] = Jf
                    if self.board is not None:
                        Jg[:, :, nf:] = 0.0
                        cols = self.board_cols[c.a : c.b]
                        rows, coords = np.nonzero(cols >= 0)
                        Jg[rows, :, cols[rows, coords]] = Jb[rows, :, coords]
                    elif self.warp_basis is not None:  # the warp moves z only: d uv / d w = (d uv / d z) d z / d w
                        Jg[:, :, nf:] = Jb[:, :, 2:3] * self.warp_basis[c.a : c.b, None, :]
            Jp = np.empty((len(uv), 2, 6))
            Jp[:, :, :3] = self._times_view_matrix(rotated_jacobian(dP, Y), Jl, c)
            Jp[:, :, 3:] = dP
            yield c, Jg, Jp, Jsparse

    def normal_equations(self, x: np.ndarray) -> tuple[np.ndarray, NormalBlocks]:
        """The residuals and the blocks of ``J^T J`` and ``J^T f`` at ``x``.

        Each view's rows touch only the global parameters and its own pose. Assembled chunk by chunk, so the
        (2N, ng + 6) Jacobian never exists: per chunk, A and gi are one product over its rows, B, D and gp one batched
        product over its views (views of equal point count are a free reshape, others gathered by count). With board
        refinement each row touches only its own board point's 3 columns: those blocks are summed by index
        (:meth:`_board_blocks`), so the cost grows with the observations, not with their number times the board's
        (the dense product was 0.73 of a 1.07 s refinement of 15 views of a 224-point board). The last evaluation is
        kept (the solver's last step, its convergence test, the information and the covariance all ask at the
        solution); it also sets :meth:`residuals`' kept one.

        Parameters
        ----------
        x : ndarray, shape (n,)
            The parameter vector.

        Returns
        -------
        f : ndarray, shape (2N,)
            Projected - observed, px.
        blocks : tuple (A, gi, B, D, gp)
            A (ng, ng), gi (ng,), B (V, ng, 6), D (V, 6, 6), gp (V, 6).
        """
        key = x.tobytes()
        if key == self._normal_x and self._normal is not None:
            return self._normal
        self._normal_x = self._normal = None
        ng, V = self.ng, self.n_views
        # the Jacobian pass's residuals equal residuals()' to the bit: a kept evaluation at x is refilled in place
        # with the same numbers (no second copy)
        if key == self._residuals_x and self._residuals is not None:
            f, Xc = self._residuals
        else:
            self._residuals_x = self._residuals = None
            f, Xc = np.empty(2 * len(self.X)), np.empty((len(self.X), 3))
        A, gi = np.zeros((ng, ng)), np.zeros(ng)
        sparse = self.board is not None
        B = np.zeros((V, ng, 6)) if sparse else np.empty((V, ng, 6))
        D, gp = np.empty((V, 6, 6)), np.empty((V, 6))
        nd = self.nf if sparse else ng  # the dense global columns
        for c, Jg, Jp, Jb in self._jacobian_chunks(x, f, Xc, dense=not sparse):
            fc = f[2 * c.a : 2 * c.b]
            Jg2 = Jg.reshape(-1, nd)
            A[:nd, :nd] += Jg2.T @ Jg2
            gi[:nd] += Jg2.T @ fc
            for views, rows in c.groups:
                Gv, Pv, Fv = (
                    (Jg, Jp, fc.reshape(-1, 2)) if rows is None else (Jg[rows], Jp[rows], fc.reshape(-1, 2)[rows])
                )
                k = len(views)
                Gv, Pv = Gv.reshape(k, -1, nd), Pv.reshape(k, -1, 6)
                Pt = np.transpose(Pv, (0, 2, 1))
                B[views, :nd] = np.transpose(Gv, (0, 2, 1)) @ Pv
                D[views] = Pt @ Pv
                gp[views] = (Pt @ Fv.reshape(k, -1, 1))[:, :, 0]
            if Jb is not None:
                self._board_blocks(c, Jg, Jp, Jb, fc, A, gi, B)
        self._residuals_x, self._residuals = key, (f, Xc)
        self._normal_x, self._normal = key, (f, (A, gi, B, D, gp))
        return self._normal

    def _board_blocks(
        self,
        c: Chunk,
        Jf: np.ndarray,
        Jp: np.ndarray,
        Jb: np.ndarray,
        fc: np.ndarray,
        A: np.ndarray,
        gi: np.ndarray,
        B: np.ndarray,
    ) -> None:
        """Add one chunk's board-coordinate blocks to ``A``, ``gi`` and ``B`` in place: each observation's
        ``Jb^T Jb`` (3 x 3), ``Jf^T Jb`` (nf x 3), ``Jb^T f`` (3) and ``Jb^T Jp`` (3 x 6) summed into its board point's
        columns by index (``np.bincount``; held coordinates have zero columns in ``Jb`` and column -1, dropped)."""
        ng, nf = self.ng, self.nf
        cols = self.board_cols[c.a : c.b]  # (n, 3), -1 where held
        ok = cols >= 0
        safe = np.where(ok, cols, 0)
        F = fc.reshape(-1, 2)
        # board x board
        bb = np.einsum("nki,nkj->nij", Jb, Jb)
        pair = ok[:, :, None] & ok[:, None, :]
        lin = (safe[:, :, None] * ng + safe[:, None, :])[pair]
        A += np.bincount(lin, weights=bb[pair], minlength=ng * ng).reshape(ng, ng)
        # intrinsics x board (and its transpose)
        fb = np.einsum("nki,nkj->nij", Jf, Jb)  # (n, nf, 3)
        okb = np.broadcast_to(ok[:, None, :], fb.shape)
        lin = (np.arange(nf)[None, :, None] * ng + safe[:, None, :])[okb]
        block = np.bincount(lin, weights=fb[okb], minlength=nf * ng).reshape(nf, ng)
        A[:nf] += block
        A[nf:, :nf] += block[:, nf:].T
        # gradient
        gb = np.einsum("nki,nk->ni", Jb, F)
        gi += np.bincount(safe[ok], weights=gb[ok], minlength=ng)
        # board x pose, into each observation's own view
        bp = np.einsum("nki,nkj->nij", Jb, Jp)  # (n, 3, 6)
        view = self.view[c.a : c.b]
        okp = np.broadcast_to(ok[:, :, None], bp.shape)
        lin = (((view[:, None, None] * ng + safe[:, :, None]) * 6) + np.arange(6)[None, None, :])[okp]
        B += np.bincount(lin, weights=bp[okp], minlength=B.size).reshape(B.shape)

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The residuals and the whole Jacobian, for the scipy cross-check and tests (the Levenberg-Marquardt solver needs
        only :meth:`normal_equations`).

        Parameters
        ----------
        x : ndarray, shape (n,)
            The parameter vector.

        Returns
        -------
        f : ndarray, shape (2N,)
            Projected - observed, px.
        Xc : ndarray, shape (N, 3)
            Camera-frame points, mm.
        J_global : ndarray, shape (N, 2, ng)
        J_pose : ndarray, shape (N, 2, 6)
        """
        N = len(self.X)
        f, Xc = np.empty(2 * N), np.empty((N, 3))
        Jg, Jp = np.empty((N, 2, self.ng)), np.empty((N, 2, 6))
        for c, Jgc, Jpc, _ in self._jacobian_chunks(x, f, Xc):
            Jg[c.a : c.b], Jp[c.a : c.b] = Jgc, Jpc
        return f, Xc, Jg, Jp

    def fun(self, x: np.ndarray) -> np.ndarray:
        """The residuals alone (``scipy.optimize.least_squares``' ``fun``).

        Parameters
        ----------
        x : ndarray, shape (n,)

        Returns
        -------
        ndarray, shape (2N,)
            Projected - observed, px.
        """
        return self.residuals(x)[0]

    def jac(self, x: np.ndarray) -> csr_matrix:
        """The Jacobian as a sparse matrix (``scipy.optimize.least_squares``' ``jac``): each row holds the ng global columns
        and its view's 6 pose columns.

        Parameters
        ----------
        x : ndarray, shape (n,)

        Returns
        -------
        scipy.sparse.csr_matrix, shape (2N, n)
        """
        from scipy.sparse import csr_matrix

        m, row_nnz = 2 * len(self.X), self.ng + 6
        indptr = np.arange(0, m * row_nnz + 1, row_nnz)
        cols_i = np.broadcast_to(np.arange(self.ng), (m, self.ng))
        cols_p = self.ng + 6 * np.repeat(self.view, 2)[:, None] + np.arange(6)
        indices = np.concatenate([cols_i, cols_p], axis=1).ravel()
        _, _, Jg, Jp = self.evaluate(x)
        data = np.concatenate([Jg, Jp], axis=2).ravel()
        return csr_matrix((data, indices, indptr), shape=(m, self.n))
