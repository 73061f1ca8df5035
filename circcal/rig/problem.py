"""One least-squares problem for a rig: every camera's observations of one board at shared instants, the map from the
free parameters to intrinsics, camera poses in the rig and board poses, and the residuals with their analytic
Jacobian.

Parameter vector (conventions: :mod:`circcal.rig.model`): the global parameters first -- every camera's free
intrinsics (camera 0's, then camera 1's, ...; each camera its own lens model and image size), then the pose in the rig
of every camera but the reference (``rvec, tvec``: ``X_c = R(rvec) X_0 + tvec``, rad and mm) -- then one board pose
per instant (``rvec, tvec``: ``X_0 = R(rvec) P + tvec``). The board poses are the per-view locals of
:mod:`circcal.solver.lm`: each observation's residual depends only on the global parameters of its own camera and on
its own instant's pose, so :func:`circcal.solver.lm.levenberg_marquardt` solves each damped step by eliminating the
6x6 board-pose blocks (Schur complement), exactly as for one camera. Residuals are ``projected - observed`` (px;
times ``sqrt(w)`` where the observations carry weights), stacked camera by camera; the camera model is :mod:`circcal.model`'s (:func:`~circcal.model.project_camera_jacobian`,
one implementation for every lens).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from circcal.model import lens_model, project_camera_jacobian, theta_max
from circcal.rotation import left_jacobian, rodrigues, rotated_jacobian
from circcal.solver.problem import NormalBlocks, project_pixels

__all__ = ["CameraObservations", "RigProblem", "free_intrinsics"]


@dataclass(frozen=True)
class CameraObservations:
    """One camera's observations, stacked over the instants it saw, sorted by instant.

    Attributes
    ----------
    X : ndarray, shape (N, 3)
        Board points, mm (z = 0).
    uv : ndarray, shape (N, 2)
        Observed pixels.
    instant : ndarray of int, shape (N,)
        The instant (index into the problem's instants) of each point, non-decreasing.
    weights : ndarray, shape (N,), or None
        Each point's weight on its squared reprojection error (both its residuals scaled by ``sqrt(w)``: the
        residuals, Jacobian and covariance are then the weighted problem's); None: 1 (least squares).
    """

    X: np.ndarray
    uv: np.ndarray
    instant: np.ndarray
    weights: np.ndarray | None = None

    @classmethod
    def stack(cls, views: Sequence[tuple[int, np.ndarray, np.ndarray]]) -> CameraObservations:
        """Stack ``(instant, object points (n, 3), image points (n, 2))`` views.

        Parameters
        ----------
        views : sequence of (int, ndarray, ndarray)
            One entry per instant the camera saw (at most one per instant).

        Returns
        -------
        CameraObservations
        """
        views = sorted(views, key=lambda v: v[0])
        if not views:
            return cls(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0, dtype=np.int64))
        return cls(
            np.concatenate([np.asarray(o, dtype=np.float64).reshape(-1, 3) for _, o, _ in views]),
            np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for _, _, p in views]),
            np.concatenate([np.full(len(o), i, dtype=np.int64) for i, o, _ in views]),
        )


def free_intrinsics(
    param_names: Sequence[str], fixed: Sequence[str], aspect: float | None
) -> tuple[list[int], np.ndarray]:
    """The free intrinsics of one camera and the map from them to its intrinsics.

    Parameters
    ----------
    param_names : sequence of str
        The lens model's parameter names (fx, fy, cx, cy, then its coefficients).
    fixed : sequence of str
        Held parameter names (``CalibrationOptions.fixed``; ``"aspect_ratio"`` holds fx / fy).
    aspect : float or None
        fx / fy when the aspect ratio is held.

    Returns
    -------
    free : list of int
        Indices of the free intrinsics.
    T : ndarray, shape (len(param_names), len(free))
        d intrinsics / d free intrinsics (with a held aspect ratio, fx's row carries ``aspect`` in fy's column).
    """
    free = [k for k, n in enumerate(param_names) if n not in fixed and not (aspect is not None and k == 0)]
    T = np.zeros((len(param_names), len(free)))
    for j, k in enumerate(free):
        T[k, j] = 1.0
        if aspect is not None and k == 1:
            T[0, j] = aspect
    return free, T


class RigProblem:
    """The joint problem of a rig (see the module for the parameter layout).

    Parameters
    ----------
    observations : sequence of CameraObservations
        One per camera, camera 0 the reference.
    n_instants : int
        V; every instant must be seen by at least one camera.
    intrinsics : sequence of ndarray
        Per camera (4 + n_dist,) intrinsics; held ones keep these values.
    lenses : sequence of str
        Per camera lens model name.
    free : sequence of list of int
        Per camera indices of its free intrinsics (:func:`free_intrinsics`).
    maps : sequence of ndarray
        Per camera (4 + n_dist, n_free) d intrinsics / d free intrinsics (:func:`free_intrinsics`).

    Attributes
    ----------
    n_cameras, n_views : int
        C and V (the board poses are the solver's per-view locals).
    ng, n : int
        Global parameters (free intrinsics + 6 (C - 1)) and all parameters (ng + 6 V).
    intr_cols : list of ndarray
        Per camera the columns of its free intrinsics.
    pose_cols : list of ndarray
        Per camera the 6 columns of its pose in the rig (empty for camera 0).
    """

    def __init__(
        self,
        observations: Sequence[CameraObservations],
        n_instants: int,
        intrinsics: Sequence[np.ndarray],
        lenses: Sequence[str],
        free: Sequence[list[int]],
        maps: Sequence[np.ndarray],
    ) -> None:
        self.obs = list(observations)
        self.n_cameras = len(self.obs)
        self.n_views = int(n_instants)
        self.lenses = list(lenses)
        self.pinhole = [lens_model(le).pinhole for le in self.lenses]
        self.maps = [np.asarray(m, dtype=np.float64) for m in maps]
        self.base = []
        for p, m in zip(intrinsics, self.maps):
            b = np.asarray(p, dtype=np.float64).copy()
            b[np.any(m != 0, axis=1)] = 0.0  # the free ones (and fx under a held aspect) come from x
            self.base.append(b)
        self.free = [list(f) for f in free]
        nf = [len(f) for f in self.free]
        starts = np.concatenate([[0], np.cumsum(nf)])
        self.nf = int(starts[-1])
        self.intr_cols = [np.arange(starts[c], starts[c + 1]) for c in range(self.n_cameras)]
        self.pose_cols = [np.zeros(0, dtype=np.int64)] + [
            self.nf + 6 * (c - 1) + np.arange(6) for c in range(1, self.n_cameras)
        ]
        self.ng = self.nf + 6 * (self.n_cameras - 1)
        self.n = self.ng + 6 * self.n_views
        self.n_points = sum(len(o.X) for o in self.obs)
        # per camera: the instants it saw and where each one's residual rows start and end (rows sorted by instant)
        self._instants = []
        for o in self.obs:
            inst, first = np.unique(o.instant, return_index=True)
            self._instants.append((inst, 2 * np.r_[first, len(o.instant)]))
        self._rows = [
            np.empty((len(o.X), 2, len(m) + (6 if c else 0) + 7)) for c, (o, m) in enumerate(zip(self.obs, self.maps))
        ]
        self._kept: dict[str, tuple[bytes, object]] = {}

    # --- the parameter vector -------------------------------------------------------------------------------------

    def intrinsics(self, x: np.ndarray, c: int) -> np.ndarray:
        """Camera ``c``'s intrinsics at ``x``.

        Parameters
        ----------
        x : ndarray, shape (n,)
        c : int

        Returns
        -------
        ndarray, shape (4 + n_dist,)
            fx, fy, cx, cy (px), then the coefficients.
        """
        p: np.ndarray = self.base[c] + self.maps[c] @ x[self.intr_cols[c]]
        return p

    def rig_poses(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every camera's pose in the rig at ``x``.

        Parameters
        ----------
        x : ndarray, shape (n,)

        Returns
        -------
        rvecs, tvecs : ndarray, shape (C, 3)
            ``X_c = R(rvecs[c]) X_0 + tvecs[c]`` (rad, mm); row 0 zero.
        """
        P = np.zeros((self.n_cameras, 6))
        P[1:] = x[self.nf : self.ng].reshape(-1, 6)
        return P[:, :3].copy(), P[:, 3:].copy()

    def board_poses(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every instant's board pose at ``x``.

        Parameters
        ----------
        x : ndarray, shape (n,)

        Returns
        -------
        rvecs, tvecs : ndarray, shape (V, 3)
            ``X_0 = R(rvecs[v]) P + tvecs[v]`` (rad, mm).
        """
        P = x[self.ng :].reshape(-1, 6)
        return P[:, :3].copy(), P[:, 3:].copy()

    def pack(
        self,
        intrinsics: Sequence[np.ndarray],
        rig_rvecs: np.ndarray,
        rig_tvecs: np.ndarray,
        board_rvecs: np.ndarray,
        board_tvecs: np.ndarray,
    ) -> np.ndarray:
        """The parameter vector of given intrinsics and poses.

        Parameters
        ----------
        intrinsics : sequence of ndarray
            Per camera (4 + n_dist,) (only the free ones are taken).
        rig_rvecs, rig_tvecs : ndarray, shape (C, 3)
            Cameras' poses in the rig (row 0 ignored), rad and mm.
        board_rvecs, board_tvecs : ndarray, shape (V, 3)
            Board poses in the rig frame, rad and mm.

        Returns
        -------
        ndarray, shape (n,)
        """
        xi = [np.asarray(p, dtype=np.float64)[f] for p, f in zip(intrinsics, self.free)]
        rig = np.column_stack([np.asarray(rig_rvecs), np.asarray(rig_tvecs)])[1:].ravel()
        board = np.column_stack([np.asarray(board_rvecs), np.asarray(board_tvecs)]).ravel()
        return np.concatenate([*xi, rig, board]).astype(np.float64)

    def camera_rows(self) -> list[slice]:
        """The rows of each camera's points among the stacked points (residual pairs ``2 a : 2 b``).

        Returns
        -------
        list of slice
            Per camera, into the (N,) stacked points.
        """
        ends = np.cumsum([len(o.X) for o in self.obs])
        return [slice(int(e - len(o.X)), int(e)) for e, o in zip(ends, self.obs)]

    # --- evaluation -----------------------------------------------------------------------------------------------

    def _frames(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every instant's board rotation (V, 3, 3) and translation (V, 3), every camera's rotation (C, 3, 3) and
        translation (C, 3) in the rig at ``x`` (kept for the last ``x``: each camera's points use them)."""
        key = x.tobytes()
        kept = self._kept.get("frames")
        if kept is not None and kept[0] == key:
            return kept[1]  # type: ignore[return-value]
        rv, tv = self.board_poses(x)
        rc, tc = self.rig_poses(x)
        out = (rodrigues(rv), tv, rodrigues(rc), tc)
        self._kept["frames"] = (key, out)
        return out

    def _points(self, x: np.ndarray, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Camera ``c``'s points at ``x``: board points rotated into the rig (Y = R_v P), then in the rig
        (X0 = Y + t_v), rotated into the camera (Z = R_c X0), and in the camera (Xc = Z + T_c); all (N_c, 3) mm."""
        o = self.obs[c]
        Rb, tb, Rc, tc = self._frames(x)
        Y = np.einsum("nij,nj->ni", Rb[o.instant], o.X)
        X0 = Y + tb[o.instant]
        Z = X0 @ Rc[c].T
        return Y, X0, Z, Z + tc[c]

    def residuals(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The residuals without the Jacobian (a trial step's cost).

        Parameters
        ----------
        x : ndarray, shape (n,)

        Returns
        -------
        f : ndarray, shape (2N,)
            Projected - observed, px, camera by camera.
        Xc : ndarray, shape (N, 3)
            Each point in its own camera's frame, mm.
        """
        key = x.tobytes()
        kept = self._kept.get("residuals")
        if kept is not None and kept[0] == key:
            return kept[1]  # type: ignore[return-value]
        f, Xc = np.empty(2 * self.n_points), np.empty((self.n_points, 3))
        for c, rows in enumerate(self.camera_rows()):
            if rows.stop == rows.start:
                continue
            Xc[rows] = self._points(x, c)[3]
            uv = project_pixels(Xc[rows], self.intrinsics(x, c), self.pinhole[c])
            w = self.obs[c].weights
            r = uv - self.obs[c].uv if w is None else (uv - self.obs[c].uv) * np.sqrt(w)[:, None]
            f[2 * rows.start : 2 * rows.stop] = r.ravel()
        self._kept["residuals"] = (key, (f, Xc))
        return f, Xc

    def _derivatives(self, x: np.ndarray, c: int) -> tuple[np.ndarray, np.ndarray, int]:
        """Camera ``c``'s points and, per residual, its row ``[M_global | M_board | f]`` before the parameter maps
        (:meth:`_maps`): the derivatives with respect to all its intrinsics, a left perturbation of its rotation in
        the rig and its translation (none for camera 0) -- ``g`` columns -- then a left perturbation of the point's
        board rotation and its board translation (6), then the residual (projected - observed, px).

        Returns ``Xc`` (N_c, 3) mm, the rows (N_c, 2, g + 7; overwritten by the next call) and ``g``."""
        o = self.obs[c]
        Y, X0, Z, Xc = self._points(x, c)
        uv, Ji, dP = project_camera_jacobian(Xc, self.intrinsics(x, c), self.lenses[c])
        p = Ji.shape[2]
        g = p + (6 if c else 0)
        W = self._rows[c]  # reused: a fresh array of this size each evaluation costs its page faults again
        W[:, :, :p] = Ji
        if c:
            rotated_jacobian(dP, Z, out=W[:, :, p : p + 3])
            W[:, :, p + 3 : g] = dP
        dPR = (dP.reshape(-1, 3) @ self._frames(x)[2][c]).reshape(dP.shape)  # d uv / d X0
        rotated_jacobian(dPR, Y, out=W[:, :, g : g + 3])
        W[:, :, g + 3 : g + 6] = dPR
        np.subtract(uv, o.uv, out=W[:, :, -1])
        if o.weights is not None:
            W *= np.sqrt(o.weights)[:, None, None]
        return Xc, W, g

    def _maps(self, x: np.ndarray, c: int) -> tuple[np.ndarray, np.ndarray]:
        """The maps from :meth:`_derivatives`' columns to the parameters': camera ``c``'s global one (p [+ 6], k) --
        its intrinsics' map, its rotation's left Jacobian -- and every instant's board one (V, 6, 6)."""
        p, k_i = self.maps[c].shape
        Tg = np.zeros((p + (6 if c else 0), k_i + (6 if c else 0)))
        Tg[:p, :k_i] = self.maps[c]
        if c:
            Tg[p : p + 3, k_i : k_i + 3] = left_jacobian(self.rig_poses(x)[0][c])
            Tg[p + 3 :, k_i + 3 :] = np.eye(3)
        key = x.tobytes()
        kept = self._kept.get("board_maps")
        if kept is not None and kept[0] == key:  # shared by every camera
            return Tg, kept[1]  # type: ignore[return-value]
        Tb = np.zeros((self.n_views, 6, 6))
        Tb[:, :3, :3] = left_jacobian(self.board_poses(x)[0])
        Tb[:, 3:, 3:] = np.eye(3)
        self._kept["board_maps"] = (key, Tb)
        return Tg, Tb

    def jacobian(self, x: np.ndarray, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Camera ``c``'s residuals and Jacobian rows.

        Parameters
        ----------
        x : ndarray, shape (n,)
        c : int

        Returns
        -------
        f : ndarray, shape (N_c, 2)
            Projected - observed, px.
        Xc : ndarray, shape (N_c, 3)
            mm.
        J_global : ndarray, shape (N_c, 2, k)
            With respect to the camera's global columns (:meth:`global_cols`): its free intrinsics, then its pose in
            the rig (rvec, tvec; none for camera 0).
        J_board : ndarray, shape (N_c, 2, 6)
            With respect to each point's own instant's board pose (rvec, tvec).
        """
        Xc, W, g = self._derivatives(x, c)
        Tg, Tb = self._maps(x, c)
        return W[:, :, -1].copy(), Xc, W[:, :, :g] @ Tg, W[:, :, g : g + 6] @ Tb[self.obs[c].instant]

    def global_cols(self, c: int) -> np.ndarray:
        """Camera ``c``'s columns among the global parameters.

        Parameters
        ----------
        c : int

        Returns
        -------
        ndarray of int
            Its free intrinsics' columns, then its pose's 6 (none for camera 0).
        """
        return np.concatenate([self.intr_cols[c], self.pose_cols[c]]).astype(np.int64)

    def normal_equations(self, x: np.ndarray) -> tuple[np.ndarray, NormalBlocks]:
        """The residuals and the blocks of ``J^T J`` and ``J^T f`` at ``x`` (the interface of
        :meth:`circcal.solver.problem.Problem.normal_equations`, board poses as the per-view blocks).

        Each camera's rows ``[M_global | M_board | f]`` (:meth:`_derivatives`) are multiplied out per instant (its
        rows are contiguous: one Gram matrix each); the parameter maps (:meth:`_maps`) are applied to those small
        blocks, not to every point.

        Parameters
        ----------
        x : ndarray, shape (n,)

        Returns
        -------
        f : ndarray, shape (2N,)
            Projected - observed, px.
        blocks : tuple (A, gi, B, D, gp)
            A (ng, ng), gi (ng,), B (V, ng, 6), D (V, 6, 6), gp (V, 6).
        """
        key = x.tobytes()
        kept = self._kept.get("normal")
        if kept is not None and kept[0] == key:
            return kept[1]  # type: ignore[return-value]
        ng, V = self.ng, self.n_views
        f, Xc = np.empty(2 * self.n_points), np.empty((self.n_points, 3))
        A, gi = np.zeros((ng, ng)), np.zeros(ng)
        B, D, gp = np.zeros((V, ng, 6)), np.zeros((V, 6, 6)), np.zeros((V, 6))
        for c, rows in enumerate(self.camera_rows()):
            if rows.stop == rows.start:
                continue
            Xc[rows], W, g = self._derivatives(x, c)
            f[2 * rows.start : 2 * rows.stop] = W[:, :, -1].ravel()
            Tg, Tb = self._maps(x, c)
            inst, bounds = self._instants[c]
            W2 = W.reshape(-1, g + 7)
            G = np.stack([W2[a:b].T @ W2[a:b] for a, b in zip(bounds[:-1], bounds[1:])])  # (S, g + 7, g + 7)
            cols = self.global_cols(c)
            Gg = G[:, :g].sum(axis=0)
            A[np.ix_(cols, cols)] += Tg.T @ Gg[:, :g] @ Tg
            gi[cols] += Tg.T @ Gg[:, -1]
            Tbi = Tb[inst]
            TbiT = np.transpose(Tbi, (0, 2, 1))
            B[np.ix_(inst, cols, np.arange(6))] += (Tg.T @ G[:, :g, g : g + 6]) @ Tbi
            D[inst] += TbiT @ G[:, g : g + 6, g : g + 6] @ Tbi
            gp[inst] += (TbiT @ G[:, g : g + 6, -1:])[:, :, 0]
        out = (f, (A, gi, B, D, gp))
        self._kept["normal"] = (key, out)
        self._kept["residuals"] = (key, (f, Xc))
        return out

    def dense_jacobian(self, x: np.ndarray) -> np.ndarray:
        """The whole (2N, n) Jacobian (tests and small problems only).

        Parameters
        ----------
        x : ndarray, shape (n,)

        Returns
        -------
        ndarray, shape (2N, n)
        """
        J = np.zeros((2 * self.n_points, self.n))
        for c, rows in enumerate(self.camera_rows()):
            if rows.stop == rows.start:
                continue
            _, _, Jg, Jb = self.jacobian(x, c)
            r = np.arange(2 * rows.start, 2 * rows.stop)
            J[np.ix_(r, self.global_cols(c))] = Jg.reshape(-1, Jg.shape[2])
            cols = self.ng + 6 * np.repeat(self.obs[c].instant, 2)[:, None] + np.arange(6)
            J[r[:, None], cols] = Jb.reshape(-1, 6)
        return J

    def outside(self, x: np.ndarray) -> list[tuple[int, int]]:
        """Points a camera cannot see at ``x``: behind a pinhole camera, beyond a fisheye's one-to-one field.

        Parameters
        ----------
        x : ndarray, shape (n,)

        Returns
        -------
        list of (int, int)
            ``(camera, instant)`` pairs with such points, sorted.
        """
        Xc = self.residuals(x)[1]
        bad: set[tuple[int, int]] = set()
        for c, rows in enumerate(self.camera_rows()):
            P = Xc[rows]
            if self.pinhole[c]:
                out = P[:, 2] <= 0
            else:
                out = np.arctan2(np.hypot(P[:, 0], P[:, 1]), P[:, 2]) > theta_max(self.intrinsics(x, c)[4:])
            bad |= {(c, int(v)) for v in np.unique(self.obs[c].instant[out])}
        return sorted(bad)
