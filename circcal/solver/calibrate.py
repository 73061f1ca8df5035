"""Calibration solver: Zhang's closed form, then Levenberg-Marquardt over intrinsics, distortion and all board poses.

Model and conventions are :mod:`circcal.model`'s (OpenCV's pinhole + ``[k1, k2, p1, p2, k3]``, pixel centres at
integer coordinates). The refinement minimises the sum of squared reprojection errors (px) with an analytic
Jacobian that is sparse by construction: each view's residuals depend only on the intrinsics and that view's six
pose parameters (a dense intrinsic block beside a block-diagonal pose part). The default solver
(:func:`_lm_schur`) is Levenberg-Marquardt that solves each damped step exactly by eliminating the 6x6 pose blocks
(Schur complement), as OpenCV does; ``solver="scipy"`` runs ``scipy.optimize.least_squares`` (TRF, sparse Jacobian,
LSMR) on the same residuals and Jacobian as a cross-check (it stops ~1e-7 relative short of the minimum and is
~10x slower, hence not the default). The covariance of the intrinsics is ``sigma^2 (J^T J)^-1`` restricted to the
intrinsics via the Schur complement of the pose blocks (poses marginalised), ``sigma^2 = SSR / (2N - n_params)``:
the same estimate as ``cv2.calibrateCameraExtended``'s standard deviations.

Entry points: :func:`calibrate` (point correspondences in, :class:`CalibrationResult` out) and
:func:`calibrate_images` (detect -> calibrate -> re-correct every centre under the current model -> recalibrate).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from circcal.metrics import error_stats
from circcal.observations import check_observations
from circcal.model import PARAM_NAMES, Camera, project_camera_jacobian
from circcal.rotation import left_jacobian, rodrigues, rotated_jacobian
from circcal.errors import CalibrationError, DegenerateViewsError
from circcal.solver.zhang import view_tilts_deg, zhang

__all__ = [
    "CalibrationError",
    "DegenerateViewsError",
    "CalibrationResult",
    "calibrate",
]

#: A free focal length whose standard deviation per 1 px of per-coordinate noise exceeds this fraction of itself is
#: called unobservable (DegenerateViewsError). Well-spread 14-view sets give ~0.005; boards all within a few degrees
#: of fronto-parallel 0.5 and more.
MAX_UNIT_REL_STD_F = 0.2


# --------------------------------------------------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------------------------------------------------

@dataclass
class CalibrationResult:
    """A calibrated camera with its uncertainty and fit statistics.

    ``std``: standard deviation of each of fx, fy, cx, cy, k1, k2, p1, p2, k3 (px / unitless) from
    ``sigma_px^2 (J^T J)^-1`` with the poses marginalised; 0.0 for a parameter held fixed (listed in ``fixed``); with a
    fixed aspect ratio fx = a * fy, fx's std is a * std(fy). ``correlation``: (9, 9), NaN in the rows and columns of
    fixed parameters. ``rvecs``/``tvecs``: (V, 3) board -> camera (radians / mm). ``residuals``: per view (N_v, 2)
    px, observed - projected. ``errors``: :func:`circcal.metrics.error_stats` over all points (keys name the
    convention: rms_per_point_px = OpenCV's RMS, rms_per_coord_px = mrcal's, mean_2d_px = the paper's eq. 22);
    ``per_view_errors`` the same per view. ``sigma_px``: per-coordinate noise estimate sqrt(SSR / (2N - n_params)).
    ``fixed``: names of parameters held at their initial value, plus ``"aspect_ratio"`` when fx/fy was held.
    ``view_names``: optional label per view (image file names when calibrating images). With board refinement
    (``calibrate(refine_board=True)``): ``board_nominal`` (P, 3) mm the distinct board points in order of first
    appearance, ``board_points`` (P, 3) mm their estimated positions, ``board_std`` (P, 3) mm standard deviations (0
    for held coordinates), ``board_gauge`` the three points that fix the board frame; all None otherwise.
    """

    camera: Camera
    std: dict[str, float]
    correlation: np.ndarray
    rvecs: np.ndarray
    tvecs: np.ndarray
    residuals: list[np.ndarray]
    errors: dict
    per_view_errors: list[dict]
    sigma_px: float
    n_iterations: int
    converged: bool
    fixed: tuple[str, ...]
    view_names: list[str] | None = None
    n_params: int = 0
    board_nominal: np.ndarray | None = None
    board_points: np.ndarray | None = None
    board_std: np.ndarray | None = None
    board_gauge: tuple[int, int, int] | None = None

    def board_lookup(self, object_points: np.ndarray) -> np.ndarray:
        """Nominal board points (N, 3) mm -> the refined ones (N, 3) mm (unchanged without board refinement).
        Raises ValueError for a point the calibration never saw."""
        o = np.asarray(object_points, dtype=np.float64).reshape(-1, 3)
        if self.board_points is None:
            return o.copy()
        index = {tuple(k): i for i, k in enumerate(np.round(self.board_nominal, 6).tolist())}
        try:
            rows = [index[tuple(k)] for k in np.round(o, 6).tolist()]
        except KeyError as e:
            raise ValueError(f"board point {e.args[0]} was not part of the calibration") from None
        return self.board_points[rows]

    def to_model_json(self) -> dict[str, Any]:
        """model.json content: the ``camera`` block (:meth:`Camera.to_dict`), ``std``, ``fixed``, ``correlation``
        (NaN -> None), ``errors`` (overall, convention in each key), ``sigma_px`` and one entry per view (pose and
        errors)."""
        corr = [[None if not np.isfinite(v) else float(v) for v in row] for row in self.correlation]
        views = []
        for i in range(len(self.rvecs)):
            entry: dict[str, Any] = {}
            if self.view_names is not None:
                entry["name"] = self.view_names[i]
            entry["rvec"] = [float(v) for v in self.rvecs[i]]
            entry["tvec_mm"] = [float(v) for v in self.tvecs[i]]
            entry["errors"] = dict(self.per_view_errors[i])
            views.append(entry)
        return {
            "format": "circcal-model",
            "version": 1,
            "camera": self.camera.to_dict(),
            "std": {k: float(v) for k, v in self.std.items()},
            "fixed": list(self.fixed),
            "parameter_order": list(PARAM_NAMES),
            "correlation": corr,
            "errors": dict(self.errors),
            "sigma_px": float(self.sigma_px),
            "n_params": int(self.n_params),
            "n_iterations": int(self.n_iterations),
            "converged": bool(self.converged),
            "views": views,
            **({} if self.board_points is None else {"board_refinement": {
                "gauge": [int(i) for i in self.board_gauge],
                "nominal_mm": np.round(self.board_nominal, 9).tolist(),
                "points_mm": self.board_points.tolist(),
                "std_mm": self.board_std.tolist()}}),
        }


# --------------------------------------------------------------------------------------------------------------------
# Solver
# --------------------------------------------------------------------------------------------------------------------

@dataclass
class _BoardModel:
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


def _board_model(obj: list[np.ndarray], gauge: tuple[int, int, int] | None) -> _BoardModel:
    """Identify the distinct board points across views (by their coordinates) and choose the gauge.

    Default gauge: a = the first point, b = the point farthest from a, c = the point farthest from the line a-b (any
    three non-collinear points give the same intrinsics and residuals; only the board frame changes).
    """
    X = np.concatenate(obj)
    keys = np.round(X, 6)
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
    unseen = [int(i) for i in np.flatnonzero(n_views_seen < 3)]
    held[unseen] = True
    return _BoardModel(nominal, point_index, np.flatnonzero(~held.ravel()), (a, b, c), unseen)


class _Problem:
    """Stacked observations and the free-parameter map for one least-squares solve.

    Parameter vector: the free intrinsics (``nf``), then the free board coordinates (``nb``, only with board
    refinement), then 6 pose parameters per view; ``ng = nf + nb`` "global" parameters are shared by all views.
    """

    def __init__(self, obj, img, base: np.ndarray, free: list[int], aspect: float | None,
                 board: _BoardModel | None = None):
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
        # intrinsics (9,) = base + T @ x_intr
        self.T = np.zeros((9, len(free)))
        for j, k in enumerate(free):
            self.T[k, j] = 1.0
            if aspect is not None and k == 1:
                self.T[0, j] = aspect
        self.nf = len(free)
        self.T_is_identity = self.T.shape == (9, 9) and bool(np.all(self.T == np.eye(9)))
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
        uv, Ji, dP = project_camera_jacobian(Xc, p)
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

    def global_information(self, x: np.ndarray) -> np.ndarray:
        """Schur complement (ng, ng) of the pose blocks in J^T J: the information on the free intrinsics (and board
        coordinates) with the poses marginalised."""
        f, _, Ji, Jp = self.evaluate(x)
        A, _, B, D, _ = _normal_blocks(self, f, Ji, Jp, np.concatenate([[0], np.cumsum(self.counts)[:-1]]))
        S = _schur_complement(A, B, D)[0]
        return 0.5 * (S + S.T)


def _normal_blocks(prob: "_Problem", f: np.ndarray, Ji: np.ndarray, Jp: np.ndarray, starts: np.ndarray):
    """Blocks of J^T J and J^T f: A (ng, ng), gi (ng,), B (V, ng, 6), D (V, 6, 6), gp (V, 6); one matrix product
    per view (each view's rows touch only the global block and its own pose)."""
    ng = Ji.shape[2]
    Jc = np.concatenate([Ji, Jp], axis=2).reshape(-1, ng + 6)         # (2N, ng + 6)
    ends = np.append(starts[1:], len(Ji))
    V = len(starts)
    G = np.empty((V, ng + 6, ng + 6))
    g = np.empty((V, ng + 6))
    for v in range(V):
        Jv = Jc[2 * starts[v]: 2 * ends[v]]
        np.matmul(Jv.T, Jv, out=G[v])
        np.matmul(Jv.T, f[2 * starts[v]: 2 * ends[v]], out=g[v])
    return G[:, :ng, :ng].sum(axis=0), g[:, :ng].sum(axis=0), G[:, :ng, ng:], G[:, ng:, ng:], g[:, ng:]


def _schur_complement(A, B, D) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``S = A - sum_v B_v D_v^-1 B_v^T`` (ng, ng) for the blocks of :func:`_normal_blocks`; also returns
    ``D_v^-1 B_v^T`` (V, 6, ng) and ``[B_1 ... B_V]`` (ng, 6V) for the back-substitution."""
    ng, V = A.shape[0], len(D)
    Dinv_Bt = np.linalg.solve(D, np.transpose(B, (0, 2, 1)))
    Bf = np.transpose(B, (1, 0, 2)).reshape(ng, 6 * V)
    return A - Bf @ Dinv_Bt.reshape(6 * V, ng), Dinv_Bt, Bf


def _schur_step(A, gi, B, D, gp, lam: float) -> np.ndarray:
    """Solve ``(J^T J + lam diag(J^T J)) step = -J^T f`` by eliminating the 6x6 pose blocks. Returns (ng + 6V,)."""
    if lam:
        A = A + lam * np.diag(np.diag(A))
        D = D + lam * np.diagonal(D, axis1=1, axis2=2)[:, :, None] * np.eye(6)
    S, Dinv_Bt, Bf = _schur_complement(A, B, D)
    Dinv_g = np.linalg.solve(D, gp[:, :, None])[:, :, 0]     # (V, 6)
    r = gi - Bf @ Dinv_g.ravel()
    try:
        di = -np.linalg.solve(S, r)
    except np.linalg.LinAlgError:
        return np.full(A.shape[0] + 6 * len(D), np.nan)
    dp = -Dinv_g - np.einsum("vab,b->va", Dinv_Bt, di)
    return np.concatenate([di, dp.ravel()])


def _quadratic_form(A, B, D, di: np.ndarray, dp: np.ndarray) -> float:
    """``s^T (J^T J) s`` for a step split into its global part ``di`` (ng,) and pose part ``dp`` (V, 6)."""
    return float(di @ A @ di + 2.0 * np.einsum("a,vab,vb->", di, B, dp) + np.einsum("va,vab,vb->", dp, D, dp))


def _lm_schur(prob: "_Problem", x0: np.ndarray, max_iterations: int) -> tuple[np.ndarray, int, bool, str]:
    """Levenberg-Marquardt on ``prob`` with exact Schur-complement solves of the damped normal equations.

    Each iteration forms ``J^T J`` blockwise (global block A: intrinsics and any board coordinates; per-view
    coupling B_v and 6x6 pose blocks D_v), damps the diagonal (Marquardt: ``lambda * diag(J^T J)``, scale invariant
    like ``x_scale='jac'``), eliminates the poses (``S = A - sum B_v D_v^-1 B_v^T``) and back-substitutes.
    Stopping: once the damping is negligible (lambda <= 1e-5, the step is Gauss-Newton's) and the step's predicted
    decrease of the cost (from the local quadratic model, exact to rounding even where the cost itself is not) is
    below 1e-10 of the cost, the cost can no longer rank steps and the model is trusted: steps that do not raise
    the cost beyond its rounding are taken until one predicts less than 1e-18 of the cost (or no less than the step
    before it: nothing left to gain), which is taken last.
    The parameters then sit ~1e-9 of their own standard deviations from the minimum. A solve that can no
    longer lower the cost otherwise ends "stalled" and is judged by its gradient.
    Returns ``(x, iterations, converged, message)``.
    """
    starts = np.concatenate([[0], np.cumsum(prob.counts)[:-1]])
    ng = prob.ng
    x = x0.copy()
    f, _, Ji, Jp = prob.evaluate(x)
    cost = float(f @ f)
    lam = 1e-4
    it = 0
    done = stalled = False
    last_trusted = np.inf
    while it < max_iterations and not (done or stalled):
        it += 1
        A, gi, B, D, gp = blocks = _normal_blocks(prob, f, Ji, Jp, starts)
        while True:
            step = _schur_step(*blocks, lam)
            if not np.all(np.isfinite(step)):
                lam *= 10.0
                if lam > 1e12:
                    stalled = True
                    break
                continue
            di, dp = step[:ng], step[ng:].reshape(-1, 6)
            # cost(x + s) ~ cost + 2 g.s + s^T J^T J s
            predicted = -(2.0 * (gi @ di + np.sum(gp * dp)) + _quadratic_form(A, B, D, di, dp))
            # Near the minimum the cost can no longer rank steps (its rounding is ~1e-16 relative) but the
            # quadratic model can: there a step that does not raise the cost beyond rounding is taken.
            trusted = lam <= 1e-5 and predicted <= 1e-10 * cost
            # last step: at rounding level, or the model's decrease stopped shrinking (no progress left to make)
            final = trusted and (predicted <= 1e-18 * cost or predicted >= last_trusted)
            f_new, _, Ji_new, Jp_new = prob.evaluate(x + step)
            cost_new = float(f_new @ f_new) if np.all(np.isfinite(f_new)) else np.inf
            if cost_new < cost or (trusted and cost_new <= cost * (1.0 + 1e-12)):
                x, f, Ji, Jp, cost = x + step, f_new, Ji_new, Jp_new, cost_new
                lam = max(lam / 10.0, 1e-12)
                last_trusted = predicted if trusted else np.inf
                done = final
                break
            lam *= 10.0
            if lam > 1e12:
                stalled = True
                break
    prob.evaluate(x)
    if not (done or stalled):
        return x, it, False, f"iteration limit {max_iterations} reached"
    # Converged if the scaled gradient is negligible at the final point.
    A, gi, B, D, gp = _normal_blocks(prob, f, Ji, Jp, starts)
    scale = np.sqrt(np.concatenate([np.diag(A), np.diagonal(D, axis1=1, axis2=2).ravel()]))
    g = np.concatenate([gi, gp.ravel()]) / np.maximum(scale, 1e-300)
    ok = bool(np.max(np.abs(g)) <= 1e-6 * np.sqrt(cost) + 1e-12)
    return x, it, ok, ("converged" if ok else "stalled: no step lowers the cost but the gradient is not small")


def _solve(prob: _Problem, x0: np.ndarray, max_iterations: int, solver: str) -> tuple[np.ndarray, int, bool, str]:
    """Run the chosen least-squares solver. Returns ``(x, iterations, converged, message)``."""
    if solver == "schur":
        return _lm_schur(prob, x0, max_iterations)
    if solver != "scipy":
        raise ValueError(f"unknown solver {solver!r}; expected 'schur' or 'scipy'")
    from scipy.optimize import least_squares

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        sol = least_squares(prob.fun, x0, jac=prob.jac, method="trf", x_scale="jac", ftol=1e-15, xtol=1e-15,
                            gtol=1e-15, max_nfev=max_iterations, tr_solver="lsmr",
                            tr_options={"atol": 1e-15, "btol": 1e-15, "maxiter": 10 * prob.n})
    prob.evaluate(sol.x)
    return sol.x, int(sol.njev if sol.njev is not None else sol.nfev), bool(sol.status > 0), str(sol.message)


def _sane(prob: _Problem, x: np.ndarray, converged: bool) -> bool:
    """A solve worth keeping: converged, finite, positive focal lengths, every point in front of the camera."""
    if not converged or not np.all(np.isfinite(x)):
        return False
    f, Xc, _, _ = prob.evaluate(x)
    p = prob.intrinsics(x)
    return bool(np.all(np.isfinite(f)) and p[0] > 0 and p[1] > 0 and np.all(Xc[:, 2] > 0))


def _initial_poses(obj, img, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Poses from homographies of the undistorted, normalised observations under ``camera``."""
    from circcal.model import pixel_to_normalized, undistort
    from circcal.solver.zhang import homographies, poses_from_homographies

    xn = [undistort(pixel_to_normalized(p, camera), camera.dist) for p in img]
    if not all(np.all(np.isfinite(x)) for x in xn):
        raise CalibrationError("the initial camera's distortion cannot be inverted at some observed points")
    return poses_from_homographies(homographies([o[:, :2] for o in obj], xn), np.eye(3))


def calibrate(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    *,
    fix_k3: bool = False,
    fix_tangential: bool = False,
    fix_aspect_ratio: bool = False,
    fix_principal_point: bool = False,
    initial: Camera | None = None,
    refine_board: bool = False,
    board_gauge: tuple[int, int, int] | None = None,
    max_iterations: int = 200,
    solver: str = "schur",
) -> CalibrationResult:
    """Calibrate a camera from planar-board correspondences.

    ``object_points``: per view (N_v, 3) board coordinates in mm with z = 0; ``image_points``: per view (N_v, 2)
    pixels (OpenCV convention); views may hold different points (partial boards), N_v >= 6; ``image_size``:
    (width, height). ``fix_k3`` / ``fix_tangential`` hold k3 / (p1, p2) at their initial values (``initial``'s, else
    0); ``fix_principal_point`` holds (cx, cy) at ``initial``'s or the image centre ((w-1)/2, (h-1)/2);
    ``fix_aspect_ratio`` holds fx / fy at ``initial``'s ratio or 1. ``initial``: start from this camera
    (like OpenCV's USE_INTRINSIC_GUESS) instead of Zhang's closed form. ``max_iterations``: Jacobian evaluations
    allowed; reaching it warns and returns ``converged=False``. ``solver``: ``"schur"`` (default) is
    Levenberg-Marquardt with exact Schur-complement solves (:func:`_lm_schur`: reaches the minimum to ~1e-11
    relative, like OpenCV); ``"scipy"`` is ``scipy.optimize.least_squares`` (trust-region reflective, sparse
    analytic Jacobian, LSMR) on the same residuals and Jacobian, slower and stopping ~1e-7 relative short of the
    minimum: an independent cross-check.

    ``refine_board``: also estimate the 3-D position of every board point (a printed board is rarely flat or printed
    to scale; the object-releasing method of Strobl & Hirzinger 2011, ``cv2.calibrateCameraRO``). Board points are
    identified across views by their nominal coordinates. ``board_gauge`` (a, b, c): indices of distinct points, in
    order of first appearance across the views, held at their nominal positions (a and b in x, y, z; c in z only):
    the 7 constraints that fix the board's frame and scale, exactly like calibrateCameraRO's first point,
    ``iFixedPoint`` and last point's z. Default: the first point, the point farthest from it, and the point farthest
    from the line through both. Points seen in fewer than 3 views are held. The refined points come back in
    ``CalibrationResult.board_points``.

    Raises :class:`CalibrationError` (a ValueError) for NaN, out-of-image or non-planar points, fewer than 3 views or
    6 points per view, a diverged solve, and (:class:`DegenerateViewsError`) views that leave the focal length
    unobservable (e.g. boards nearly parallel to the image plane), naming those views.
    """
    obj, img, (w, h) = check_observations(object_points, image_points, image_size)
    centre = (0.5 * (w - 1), 0.5 * (h - 1))
    fixed: list[str] = []
    if fix_aspect_ratio:
        fixed.append("aspect_ratio")
    if fix_principal_point:
        fixed += ["cx", "cy"]
    if fix_tangential:
        fixed += ["p1", "p2"]
    if fix_k3:
        fixed.append("k3")
    aspect = (initial.fx / initial.fy if initial is not None else 1.0) if fix_aspect_ratio else None

    def zhang_start(distortion_rounds: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Intrinsics (9,) and poses from Zhang's closed form, honouring the fixed principal point / aspect."""
        z = zhang(obj, img, (w, h), principal_point=centre if fix_principal_point else None, aspect_ratio=aspect,
                  distortion_rounds=distortion_rounds)
        c = z.camera
        start = np.array([c.fx, c.fy, c.cx, c.cy, c.dist[0], c.dist[1], 0.0, 0.0, 0.0])
        if fix_principal_point:
            start[2:4] = centre
        if aspect is not None:
            start[0] = aspect * start[1]
        return start, z.rvecs, z.tvecs

    if initial is None:
        intr, rvecs, tvecs = zhang_start(0)
    else:
        if (initial.width, initial.height) != (w, h):
            raise ValueError(f"initial camera is {initial.width}x{initial.height} but image_size is {w}x{h}")
        intr = initial.intrinsics.copy()
        rvecs, tvecs = _initial_poses(obj, img, initial)
    if aspect is not None:
        intr[0] = aspect * intr[1]

    free = [k for k, name in enumerate(PARAM_NAMES) if name not in fixed and not (aspect is not None and k == 0)]
    board = _board_model(obj, board_gauge) if refine_board else None
    if board is not None and board.held_unseen:
        warnings.warn(f"board refinement: {len(board.held_unseen)} point(s) seen in fewer than 3 views are held at "
                      f"their nominal positions (indices {board.held_unseen[:10]})", RuntimeWarning, stacklevel=2)
    prob = _Problem(obj, img, intr, free, aspect, board)
    x0 = prob.pack(intr, rvecs, tvecs)

    x, n_iter, converged, message = _solve(prob, x0, max_iterations, solver)
    if initial is None and not _sane(prob, x, converged):
        # Strong distortion can defeat the distortion-free closed form: restart from Zhang with a radial estimate.
        intr, rvecs, tvecs = zhang_start(10)
        prob = _Problem(obj, img, intr, free, aspect, board)
        x, n_iter2, converged, message = _solve(prob, prob.pack(intr, rvecs, tvecs), max_iterations, solver)
        n_iter += n_iter2
    f, Xc, _, _ = prob.evaluate(x)
    p = prob.intrinsics(x)
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(f))):
        raise CalibrationError("the solver diverged (non-finite parameters or residuals); check the point "
                               "correspondences (board order, image_size) and the views")
    if p[0] <= 0 or p[1] <= 0:
        raise CalibrationError(f"the solver diverged to a non-positive focal length (fx={p[0]:.4g}, fy={p[1]:.4g}); "
                               f"check the point correspondences and the views")
    if np.any(Xc[:, 2] <= 0):
        bad = sorted(set(prob.view[Xc[:, 2] <= 0].tolist()))
        raise CalibrationError(f"the solver diverged: board points behind the camera in view(s) {bad}")
    if not converged:
        warnings.warn(f"calibration did not converge ({message}); the model may be inaccurate", RuntimeWarning,
                      stacklevel=2)

    camera = Camera.from_intrinsics(w, h, p)
    rv, tv = prob.poses(x)
    m = 2 * len(prob.X)
    dof = m - prob.n
    ssr = float(f @ f)
    if dof <= 0:
        raise CalibrationError(f"{m} residuals for {prob.n} parameters: add views or points")
    sigma2 = ssr / dof

    # Uncertainty of the intrinsics (and board points), poses marginalised.
    S = prob.global_information(x)
    scale = np.sqrt(np.maximum(np.diag(S), 1e-300))
    Sn = S / np.outer(scale, scale)
    ev = np.linalg.eigvalsh(Sn)
    cond = float(ev[-1] / ev[0]) if ev[0] > 0 else float("inf")
    if not np.isfinite(cond) or cond > 1e14:
        cov_global_unit = np.full(S.shape, np.inf)
    else:
        cov_global_unit = np.linalg.inv(Sn) / np.outer(scale, scale)
    cov_free_unit = cov_global_unit[: prob.nf, : prob.nf]
    cov9_unit = prob.T @ cov_free_unit @ prob.T.T if np.all(np.isfinite(cov_free_unit)) else None
    f_idx = 1 if aspect is not None else 0
    unit_rel = (float(np.sqrt(cov9_unit[f_idx, f_idx]) / p[f_idx]) if cov9_unit is not None else float("inf"))
    if not np.isfinite(unit_rel) or unit_rel > MAX_UNIT_REL_STD_F:
        tilts = view_tilts_deg(rv)
        flat = [int(i) for i in np.flatnonzero(tilts < 10.0)]
        listing = ", ".join(f"{i} ({tilts[i]:.1f} deg)" for i in flat) or "none below 10 deg"
        raise DegenerateViewsError(
            f"focal length is not observable from these {len(obj)} views: std(f) would be {100 * unit_rel:.3g}% of f "
            f"per 1 px of noise (limit {100 * MAX_UNIT_REL_STD_F:g}%); condition number of the intrinsic "
            f"information matrix {cond:.3g}. Views nearly parallel to the image plane: {listing}. Add views with "
            f"the board tilted 20-50 deg about different axes.", flat, cond)
    cov9 = sigma2 * cov9_unit
    std_arr = np.sqrt(np.maximum(np.diag(cov9), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov9 / np.outer(std_arr, std_arr)
    corr[std_arr == 0, :] = np.nan
    corr[:, std_arr == 0] = np.nan
    std = {name: float(s) for name, s in zip(PARAM_NAMES, std_arr)}

    board_points = board_std = None
    if board is not None:
        board_points = prob.board_points(x)
        board_std = np.zeros(board.nominal.size)
        board_std[board.free] = np.sqrt(np.maximum(sigma2 * np.diag(cov_global_unit)[prob.nf:], 0.0))
        board_std = board_std.reshape(-1, 3)

    residuals = [-r for r in np.split(f.reshape(-1, 2), np.cumsum(prob.counts)[:-1])]
    errors = error_stats(np.concatenate(residuals))
    if errors["rms_per_coord_px"] > 2.0:
        warnings.warn(f"large reprojection error after calibration ({errors['rms_per_coord_px']:.3g} px RMS per "
                      f"coordinate): outliers, wrong board geometry or a lens the 5-coefficient model cannot fit",
                      RuntimeWarning, stacklevel=2)
    return CalibrationResult(
        camera=camera, std=std, correlation=corr, rvecs=rv, tvecs=tv, residuals=residuals, errors=errors,
        per_view_errors=[error_stats(r) for r in residuals], sigma_px=float(np.sqrt(sigma2)),
        n_iterations=int(n_iter), converged=bool(converged),
        fixed=tuple(fixed), n_params=int(prob.n),
        board_nominal=None if board is None else board.nominal, board_points=board_points, board_std=board_std,
        board_gauge=None if board is None else board.gauge)
