"""Triangulation of pixels seen by 2..N cameras of a rig, with each point's covariance from the pixel noise and the
calibration's uncertainty.

The estimate
------------
Each pixel is unprojected to a ray with circcal's one camera model (:func:`circcal.model.unproject`: every lens,
the fisheye beyond 90 deg included) and put in the rig frame (camera ``k``'s centre ``-R_k^T T_k``, direction
``R_k^T ray``). The start is the least-squares point nearest to the rays (the midpoint of two); it is refined by
Gauss-Newton to the point of least reprojection error in px over every camera that sees it (the maximum-likelihood
triangulation for isotropic Gaussian pixel noise). Pixels given as NaN are unseen; a point seen by fewer than two
cameras (or whose rays are parallel, or meet nowhere: Gauss-Newton runs off to infinity) is NaN. A point that lands
behind a camera that sees it (against the direction of its pixel's ray: pixels that do not show one point) is kept
and named in ``behind``.

The covariance (mrcal's definition, doc/triangulation.org: both noise sources, to first order)
----------------------------------------------------------------------------------------------
The point ``X`` solves ``sum_k J_k^T (pi_k(X; theta) - q_k) = 0``; the implicit function theorem at the solution gives
``dX/dq = H^-1 J^T`` and ``dX/dtheta = -H^-1 J^T dpi/dtheta`` with ``H = J^T J`` (Gauss-Newton), every Jacobian
computed with the projection itself (:func:`circcal.model.project_camera_jacobian`). Then

* ``covariance_pixels = sigma^2 H^-1``: independent pixel noise of ``sigma`` px per coordinate (``pixel_sigma``;
  default the calibration's own per-coordinate noise, ``rig.rms_px / sqrt(2)``);
* ``covariance_calibration = B Sigma B^T``, ``B = dX/dtheta`` over the rig's state (:meth:`RigModel.state_vector`:
  every camera's intrinsics, then every non-reference camera's ``rvec, tvec``) and ``Sigma`` the rig's
  ``covariance``. This part is correlated between points (one calibration for all): each point's 3x3 block is given;
* ``covariance = covariance_pixels + covariance_calibration`` (the two are independent).

Units: points in the rig frame (camera 0's, mm), covariances mm^2. tests/test_rig_triangulate.py checks both parts
against Monte-Carlo within 0.8-1.25x (trace and largest eigenvalue).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from circcal.errors import InputError
from circcal.model import project_camera_jacobian, unproject
from circcal.rig.model import RigModel
from circcal.rotation import left_jacobian, rotated_jacobian

__all__ = ["Triangulated", "triangulate"]

#: Gauss-Newton stops when no point moves more than this fraction of its distance from the reference camera.
_STEP_TOL = 1e-13
#: Gauss-Newton's iterations at most (it converges quadratically from the midpoint: ~4 in practice).
_MAX_ITERATIONS = 30
#: Rays closer to parallel than this (the smallest eigenvalue of sum(I - d d^T), ~ the angle^2) give no point.
_MIN_RAY_SPREAD = 1e-14
#: A point whose reprojection normal matrix is conditioned worse than this has no position (its rays meet only at
#: infinity or on a camera's plane: Gauss-Newton ran off).
_MAX_CONDITION = 1e14


@dataclass(frozen=True)
class Triangulated:
    """Triangulated points with their covariances.

    Attributes
    ----------
    points : ndarray, shape (N, 3)
        In the rig frame (camera 0's), mm; NaN where fewer than two cameras see the point.
    covariance : ndarray, shape (N, 3, 3)
        ``covariance_pixels + covariance_calibration``, mm^2.
    covariance_pixels : ndarray, shape (N, 3, 3)
        From the pixel noise alone, mm^2.
    covariance_calibration : ndarray, shape (N, 3, 3)
        From the calibration's covariance alone (zeros when it is not included), mm^2.
    calibration_included : bool
        Whether the rig's covariance was propagated.
    pixel_sigma : float
        The pixel noise used, px per coordinate.
    rms_px : ndarray, shape (N,)
        Reprojection error at the point, RMS over its cameras (2-D norm), px.
    n_views : ndarray, shape (N,)
        How many cameras see each point.
    cameras : tuple of str
        The cameras whose pixels were given.
    behind : ndarray of bool, shape (N, K)
        Per point, per camera of ``cameras``: the point lies behind it, against its pixel's ray (the pixels given for
        the point do not show one point; its position means nothing).
    """

    points: np.ndarray
    covariance: np.ndarray
    covariance_pixels: np.ndarray
    covariance_calibration: np.ndarray
    calibration_included: bool
    pixel_sigma: float
    rms_px: np.ndarray
    n_views: np.ndarray
    cameras: tuple[str, ...]
    behind: np.ndarray

    @property
    def std_mm(self) -> np.ndarray:
        """(N, 3) standard deviations of x, y, z, mm."""
        return np.sqrt(np.maximum(np.diagonal(self.covariance, axis1=1, axis2=2), 0.0))


def triangulate(
    rig: RigModel,
    observations: Mapping[str, np.ndarray],
    *,
    pixel_sigma: float | None = None,
    calibration: bool | None = None,
) -> Triangulated:
    """Triangulate pixels of 2..N cameras of ``rig`` with each point's covariance (see the module).

    Parameters
    ----------
    rig : RigModel
    observations : mapping
        Camera name -> (N, 2) pixels (OpenCV's convention), px; row ``n`` of every camera is point ``n``; NaN rows
        are points that camera does not see.
    pixel_sigma : float, optional
        The pixels' noise, px per coordinate (>= 0); default ``rig.rms_px / sqrt(2)``.
    calibration : bool, optional
        Propagate the rig's covariance: None (default) when the rig has one, True to require it, False never.

    Returns
    -------
    Triangulated

    Raises
    ------
    InputError
        Fewer than two cameras, a name not in the rig, arrays that are not (N, 2) of one N, infinite pixels, no
        ``pixel_sigma`` and no ``rig.rms_px``, a negative or non-finite ``pixel_sigma``, ``calibration=True`` for a
        rig without covariance, or a covariance of the wrong size.
    """
    names = list(observations)
    if len(names) < 2:
        raise InputError(f"triangulation needs pixels of at least two cameras, got {len(names)}")
    idx = [rig.index(n) for n in names]
    uvs = []
    for name in names:
        try:
            uv = np.asarray(observations[name], dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"camera {name!r}'s pixels must be an (N, 2) array of numbers") from None
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise InputError(f"camera {name!r}'s pixels must be an (N, 2) array, got shape {uv.shape}")
        if np.isinf(uv).any():
            raise InputError(f"camera {name!r}'s pixels must be finite (NaN for an unseen point)")
        uvs.append(uv)
    n_pts = len(uvs[0])
    if any(len(u) != n_pts for u in uvs):
        raise InputError(f"every camera needs one row per point, got {[len(u) for u in uvs]} rows")
    sigma = _pixel_sigma(rig, pixel_sigma)
    use_cal = _use_calibration(rig, calibration)

    Rs = [rig.pose(k)[0] for k in idx]
    Ts = [rig.tvecs[k] for k in idx]
    cams = [rig.cameras[k] for k in idx]
    rays = [unproject(u, c) for u, c in zip(uvs, cams)]
    seen = np.stack([np.isfinite(r).all(axis=1) for r in rays])  # (K, N)
    n_views = seen.sum(axis=0)
    X = _nearest_to_rays(rays, Rs, Ts, seen)
    ok = (n_views >= 2) & np.isfinite(X).all(axis=1)
    X[~ok] = (0.0, 0.0, 1.0)  # kept finite through the iterations, NaN again at the end
    seen &= ok
    with np.errstate(divide="ignore", invalid="ignore"):  # a point may sit on a camera's plane: masked below
        for _ in range(_MAX_ITERATIONS):
            H, g, _, _ = _normal_equations(X, uvs, cams, Rs, Ts, seen)
            step = -_solve3(H, g)
            step[~ok] = 0.0
            X = X + step
            scale = np.maximum(np.linalg.norm(X, axis=1), 1.0)
            if np.all(np.abs(step) <= _STEP_TOL * scale[:, None]):
                break
        H, _, Js, res = _normal_equations(X, uvs, cams, Rs, Ts, seen)
        finite = np.isfinite(H).all(axis=(1, 2)) & np.isfinite(X).all(axis=1)
        H = np.where(finite[:, None, None], H, np.eye(3))
        ok &= finite & (np.linalg.cond(H) < _MAX_CONDITION)
        seen &= ok
    Hinv = np.linalg.inv(np.where(ok[:, None, None], H, np.eye(3)))
    cov_px = sigma**2 * Hinv
    cov_cal = np.zeros_like(cov_px)
    if use_cal:
        B = _calibration_jacobian(rig, idx, X, Js, Hinv, seen)
        cov_cal = np.einsum("nip,pq,njq->nij", B, np.asarray(rig.covariance, dtype=np.float64), B)
    sq = np.sum(np.stack([np.where(seen[k][:, None], r**2, 0.0) for k, r in enumerate(res)]), axis=(0, 2))
    rms = np.sqrt(sq / np.maximum(n_views, 1))
    # in front of a camera: the point in its frame has a positive component along the pixel's ray
    along = np.stack([np.sum((X @ R.T + T) * np.nan_to_num(r), axis=1) for R, T, r in zip(Rs, Ts, rays)], axis=1)
    behind = seen.T & (along <= 0.0)
    bad = ~ok
    for a in (X, rms, cov_px, cov_cal):
        a[bad] = np.nan
    return Triangulated(
        X, cov_px + cov_cal, cov_px, cov_cal, use_cal, sigma, rms, n_views, tuple(rig.names[k] for k in idx), behind
    )


def _pixel_sigma(rig: RigModel, pixel_sigma: float | None) -> float:
    """The pixel noise per coordinate, px (see :func:`triangulate`)."""
    if pixel_sigma is None:
        if rig.rms_px is None:
            raise InputError("give pixel_sigma (px per coordinate): the rig has no rms_px to take it from")
        return float(rig.rms_px) / np.sqrt(2.0)
    s = float(pixel_sigma)
    if not np.isfinite(s) or s < 0:
        raise InputError(f"pixel_sigma must be a finite number >= 0 (px), got {pixel_sigma!r}")
    return s


def _use_calibration(rig: RigModel, calibration: bool | None) -> bool:
    """Whether the rig's covariance is propagated; its size checked."""
    if calibration is False or (calibration is None and rig.covariance is None):
        return False
    if rig.covariance is None:
        raise InputError("calibration=True, but the rig has no covariance to propagate")
    n = len(rig.state_vector())
    if np.shape(rig.covariance) != (n, n):
        raise InputError(f"the rig's covariance must be {n} x {n} (its state vector), got {np.shape(rig.covariance)}")
    return True


def _nearest_to_rays(
    rays: list[np.ndarray], Rs: list[np.ndarray], Ts: list[np.ndarray], seen: np.ndarray
) -> np.ndarray:
    """(N, 3) least-squares points nearest to each point's rays (NaN for fewer than two or parallel rays)."""
    n = seen.shape[1]
    A = np.zeros((n, 3, 3))
    b = np.zeros((n, 3))
    for k, (ray, R, T) in enumerate(zip(rays, Rs, Ts)):
        d = np.where(seen[k][:, None], ray, 0.0) @ R  # R^T ray, row-wise
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
        P = np.eye(3) - d[:, :, None] * d[:, None, :]
        P[~seen[k]] = 0.0
        C = -R.T @ T
        A += P
        b += P @ C
    ev = np.linalg.eigvalsh(A)
    good = (seen.sum(axis=0) >= 2) & (ev[:, 0] > _MIN_RAY_SPREAD * np.maximum(ev[:, -1], 1e-300))
    X = np.full((n, 3), np.nan)
    if good.any():
        X[good] = np.linalg.solve(A[good], b[good][:, :, None])[:, :, 0]
    return X


def _normal_equations(
    X: np.ndarray,
    uvs: list[np.ndarray],
    cams: list,
    Rs: list[np.ndarray],
    Ts: list[np.ndarray],
    seen: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, list[tuple[np.ndarray, np.ndarray, np.ndarray]], list[np.ndarray]]:
    """Gauss-Newton's ``H = sum J^T J``, ``g = sum J^T r`` (unseen observations left out), each camera's Jacobians
    ``(d uv / d X, d uv / d intrinsics, d uv / d Xc)`` and residuals ``r = pi(X) - q`` (px)."""
    n = len(X)
    H = np.zeros((n, 3, 3))
    g = np.zeros((n, 3))
    Js, res = [], []
    for k, (uv, cam, R, T) in enumerate(zip(uvs, cams, Rs, Ts)):
        Xc = X @ R.T + T
        proj, J_intr, J_Xc = project_camera_jacobian(Xc, cam.intrinsics, cam.lens)
        r = np.where(seen[k][:, None], proj - np.nan_to_num(uv), 0.0)
        J = np.where(seen[k][:, None, None], J_Xc @ R, 0.0)
        H += np.einsum("nri,nrj->nij", J, J)
        g += np.einsum("nri,nr->ni", J, r)
        Js.append((J, J_intr, J_Xc))
        res.append(r)
    return H, g, Js, res


def _solve3(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Batched ``H^-1 g`` with singular systems giving 0."""
    out = np.zeros_like(g)
    good = np.abs(np.linalg.det(H)) > 0
    if good.any():
        out[good] = np.linalg.solve(H[good], g[good][:, :, None])[:, :, 0]
    return np.nan_to_num(out)


def _calibration_jacobian(
    rig: RigModel,
    idx: list[int],
    X: np.ndarray,
    Js: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    Hinv: np.ndarray,
    seen: np.ndarray,
) -> np.ndarray:
    """(N, 3, P) ``dX / dtheta = -H^-1 sum_k J_k^T d pi_k / d theta`` over the rig's state vector."""
    sizes = [len(c.intrinsics) for c in rig.cameras]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    n_state = len(rig.state_vector())
    n = len(X)
    JtD = np.zeros((n, 3, n_state))
    for pos, k in enumerate(idx):
        J, J_intr, J_Xc = Js[pos]
        mask = seen[pos][:, None, None]
        JtD[:, :, starts[k] : starts[k + 1]] += np.einsum("nri,nrp->nip", J, np.where(mask, J_intr, 0.0))
        if k > 0:
            R = rig.pose(k)[0]
            Y = X @ R.T
            J_rot = rotated_jacobian(J_Xc, Y) @ left_jacobian(rig.rvecs[k])
            J_pose = np.where(mask, np.concatenate([J_rot, J_Xc], axis=2), 0.0)
            p0 = int(starts[-1]) + 6 * (k - 1)
            JtD[:, :, p0 : p0 + 6] += np.einsum("nri,nrp->nip", J, J_pose)
    return -Hinv @ JtD
