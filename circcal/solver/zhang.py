"""Zhang's closed-form calibration: plane homographies -> image of the absolute conic -> intrinsics -> poses.

The initial guess for :func:`circcal.solver.calibrate` (Zhang 2000, "A flexible new technique for camera
calibration"), written for a zero-skew camera:

1. per view, a Hartley-normalised DLT homography ``H`` from board-plane coordinates (X, Y) in mm to pixels;
2. the image of the absolute conic ``B ~ K^-T K^-1``: each view gives two linear constraints
   ``h1^T B h2 = 0`` and ``h1^T B h1 = h2^T B h2`` on the entries of ``B``; with zero skew ``B`` has 5 entries
   (``B11, B22, B13, B23, B33``; 4 unknowns up to scale, so >= 2 views), or 3 (``B11, B22, B33``) when the principal
   point is given (the variant OpenCV uses for its own initial guess);
3. ``K`` from ``B``; each pose from ``K^-1 H = s [r1 r2 t]``, the rotation orthonormalised by SVD.

Distortion is ignored here (the homographies are fitted to distorted pixels): the result is exact on noiseless,
distortion-free data and a starting point for the joint least-squares refinement otherwise.

Focal length is only observable from views whose board is tilted against the image plane: for a fronto-parallel
board ``H`` has no perspective part and the constraints say nothing about ``f``. :func:`zhang` raises
:class:`DegenerateViewsError` (naming the near-fronto-parallel views) when no positive-definite conic fits; a conic
that fits but is poorly determined is caught after the refinement, from its covariance.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from circcal.errors import CalibrationError, DegenerateViewsError
from circcal.metrics import error_stats
from circcal.model import Camera, normalized_to_pixel, pixel_to_normalized, project, transform, undistort
from circcal.rotation import rodrigues

__all__ = [
    "ZhangResult",
    "homography",
    "homographies",
    "intrinsics_from_homographies",
    "pose_from_homography",
    "poses_from_homographies",
    "view_tilts_deg",
    "zhang",
]

#: Points whose DLT rows are decomposed at a time (whole views): the (2n, 9) design matrices and the SVD's copies
#: of them are ~450 B per point, so a 1000-view start stays a few MB instead of ~20 MB (each view's SVD is its own:
#: the homographies do not depend on the chunking).
HOMOGRAPHY_CHUNK = 4096


@dataclass(frozen=True)
class ZhangResult:
    """Closed-form estimate.

    Attributes
    ----------
    camera : Camera
    rvecs, tvecs : ndarray, shape (V, 3)
        Radians / mm.
    homographies : ndarray, shape (V, 3, 3)
        Board mm -> pixels (of the distortion-corrected points of the kept round).
    condition : float
        Condition number of the normalised IAC system (informative only: noise hides near-degeneracy from it; the
        solver judges observability from the final Jacobian).
    principal_point_fixed : bool
        True when the principal point was given or the free solution was implausible and the image centre was used
        instead.
    """

    camera: Camera
    rvecs: np.ndarray
    tvecs: np.ndarray
    homographies: np.ndarray
    condition: float
    principal_point_fixed: bool


def _similarity_normalisers(pts: np.ndarray) -> np.ndarray:
    """Hartley's normalisation per view: (V, N, 2) -> (V, 3, 3) mapping the centroid to the origin and the mean
    distance from it to sqrt(2)."""
    c = pts.mean(axis=1)
    d = np.mean(np.linalg.norm(pts - c[:, None, :], axis=2), axis=1)
    s = np.where(d > 0, np.sqrt(2.0) / np.where(d > 0, d, 1.0), 1.0)
    T = np.zeros((len(pts), 3, 3))
    T[:, 0, 0] = T[:, 1, 1] = s
    T[:, :2, 2] = -s[:, None] * c
    T[:, 2, 2] = 1.0
    return T


def _homographies_same_size(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Normalised DLT for V views of N points each: ``src``, ``dst`` (V, N, 2) -> (V, 3, 3) (unnormalised scale; NaN
    for a view whose points are collinear or coincident)."""
    Ts, Td = _similarity_normalisers(src), _similarity_normalisers(dst)
    a = np.einsum("vij,vnj->vni", Ts[:, :2, :2], src) + Ts[:, None, :2, 2]
    b = np.einsum("vij,vnj->vni", Td[:, :2, :2], dst) + Td[:, None, :2, 2]
    V, n = a.shape[:2]
    A = np.zeros((V, n, 2, 9))
    A[:, :, 0, 0:2] = a
    A[:, :, 0, 2] = 1.0
    A[:, :, 0, 6:8] = -b[:, :, :1] * a
    A[:, :, 0, 8] = -b[:, :, 0]
    A[:, :, 1, 3:5] = a
    A[:, :, 1, 5] = 1.0
    A[:, :, 1, 6:8] = -b[:, :, 1:2] * a
    A[:, :, 1, 8] = -b[:, :, 1]
    _, sv, Vt = np.linalg.svd(A.reshape(V, 2 * n, 9), full_matrices=False)
    H = np.linalg.solve(Td, Vt[:, -1].reshape(V, 3, 3) @ Ts)
    H[~(sv[:, -2] > 1e-12 * sv[:, 0])] = np.nan
    return H


def homographies(object_xy: Sequence[np.ndarray], image_points: Sequence[np.ndarray]) -> np.ndarray:
    """Plane homographies board -> pixels, one per view.

    Hartley-normalised direct linear transform over all points (algebraic least squares; exact on noiseless data),
    batched over views with equal point counts, :data:`HOMOGRAPHY_CHUNK` points at a time.

    Parameters
    ----------
    object_xy : sequence of ndarray
        Per view (N_v, 2) board coordinates, mm, N_v >= 4.
    image_points : sequence of ndarray
        Per view (N_v, 2) px.

    Returns
    -------
    ndarray
        (V, 3, 3), each scaled to unit Frobenius norm with ``H[2, 2] >= 0``.

    Raises
    ------
    CalibrationError
        Fewer than 4 points, or collinear / coincident points.
    """
    src = [np.asarray(o, dtype=np.float64).reshape(-1, 2) for o in object_xy]
    dst = [np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in image_points]
    counts = np.array([len(o) for o in src])
    if np.any(counts < 4):
        raise CalibrationError(f"a plane homography needs >= 4 points, got {int(counts.min())}")
    H = np.empty((len(src), 3, 3))
    for n in np.unique(counts):
        same = np.flatnonzero(counts == n)
        step = max(1, HOMOGRAPHY_CHUNK // int(n))
        for idx in (same[i : i + step] for i in range(0, len(same), step)):
            H[idx] = _homographies_same_size(np.stack([src[i] for i in idx]), np.stack([dst[i] for i in idx]))
    bad = np.flatnonzero(~np.isfinite(H).all(axis=(1, 2)))
    if bad.size:
        raise CalibrationError(
            f"could not fit a plane homography to view(s) {bad[:10].tolist()}{'...' if bad.size > 10 else ''}: "
            f"their points are collinear or coincident"
        )
    H /= np.linalg.norm(H, axis=(1, 2))[:, None, None]
    H[H[:, 2, 2] < 0] *= -1.0
    return H


def homography(object_xy: np.ndarray, image_points: np.ndarray) -> np.ndarray:
    """One view's plane homography: :func:`homographies` for a single view.

    Parameters
    ----------
    object_xy : ndarray
        (N, 2) mm, N >= 4.
    image_points : ndarray
        (N, 2) px.

    Returns
    -------
    ndarray
        (3, 3).

    Raises
    ------
    CalibrationError
        Fewer than 4 points, or collinear / coincident points.
    """
    H: np.ndarray = homographies([object_xy], [image_points])[0]
    return H


def _pixel_normaliser(image_size: tuple[int, int]) -> np.ndarray:
    """(3, 3) map taking pixels to centred coordinates of order 1 (conditions the IAC system)."""
    w, h = image_size
    s = 0.5 * max(w, h)
    return np.array([[1.0 / s, 0.0, -0.5 * (w - 1) / s], [0.0, 1.0 / s, -0.5 * (h - 1) / s], [0.0, 0.0, 1.0]])


def _constraint_rows(Hs: np.ndarray, principal_point_known: bool) -> np.ndarray:
    """The two IAC constraints per view, (2V, 5) for (B11, B22, B13, B23, B33) or (2V, 3) for (B11, B22, B33)."""
    h1 = Hs[:, :, 0]
    h2 = Hs[:, :, 1]

    def v(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        cols = [a[:, 0] * b[:, 0], a[:, 1] * b[:, 1]]
        if not principal_point_known:
            cols += [a[:, 0] * b[:, 2] + a[:, 2] * b[:, 0], a[:, 1] * b[:, 2] + a[:, 2] * b[:, 1]]
        cols.append(a[:, 2] * b[:, 2])
        return np.stack(cols, axis=-1)

    rows = np.empty((2 * len(Hs), 3 if principal_point_known else 5))
    rows[0::2] = v(h1, h2)
    rows[1::2] = v(h1, h1) - v(h2, h2)
    rows /= np.maximum(np.linalg.norm(rows, axis=1, keepdims=True), 1e-300)
    return rows


def intrinsics_from_homographies(
    homographies: np.ndarray,
    image_size: tuple[int, int],
    *,
    principal_point: tuple[float, float] | None = None,
    aspect_ratio: float | None = None,
) -> tuple[np.ndarray, float]:
    """Zero-skew ``K`` from the image of the absolute conic.

    Parameters
    ----------
    homographies : ndarray
        (V, 3, 3) board -> pixels.
    image_size : tuple of int
        (width, height) px.
    principal_point : tuple of float or None
        (cx, cy) px to hold fixed (then ``V >= 1``; else ``V >= 2``).
    aspect_ratio : float or None
        fx / fy to impose on the solution (applied after the linear solve, as the geometric mean).

    Returns
    -------
    K : ndarray
        (3, 3) px; NaN when the conic is not positive definite (inconsistent or degenerate views).
    condition : float
        s_1 / s_{n-1} of the normalised constraint matrix (its smallest singular direction is the solution; a second
        near-zero singular value means the solution is not determined).
    """
    T = _pixel_normaliser(image_size)
    Hs = np.asarray(homographies, dtype=np.float64)
    known = principal_point is not None
    if principal_point is not None:
        Tc = np.array([[1.0, 0.0, -principal_point[0]], [0.0, 1.0, -principal_point[1]], [0.0, 0.0, 1.0]])
        s = 0.5 * max(image_size)
        T = np.diag([1.0 / s, 1.0 / s, 1.0]) @ Tc
    Hn = T @ Hs
    Hn /= np.linalg.norm(Hn, axis=(1, 2), keepdims=True)
    A = _constraint_rows(Hn, known)
    _, sv, Vt = np.linalg.svd(A, full_matrices=False)
    n = A.shape[1]
    condition = float(sv[0] / sv[n - 2]) if sv.size >= n - 1 and sv[n - 2] > 0 else float("inf")
    if A.shape[0] < n - 1:
        condition = float("inf")
    b = Vt[-1]
    nan_K = np.full((3, 3), np.nan)
    if known:
        B11, B22, B33 = b
        if B11 * B33 <= 0 or B22 * B33 <= 0:  # B ~ diag(1/fx^2, 1/fy^2, 1) up to a (signed) scale
            return nan_K, condition
        fx_n, fy_n = np.sqrt(B33 / B11), np.sqrt(B33 / B22)
        cxn = cyn = 0.0
    else:
        B11, B22, B13, B23, B33 = b
        if B11 * B22 <= 0:
            return nan_K, condition
        cxn, cyn = -B13 / B11, -B23 / B22
        lam = B33 - B13 * B13 / B11 - B23 * B23 / B22
        if lam / B11 <= 0 or lam / B22 <= 0:
            return nan_K, condition
        fx_n, fy_n = np.sqrt(lam / B11), np.sqrt(lam / B22)
    if aspect_ratio is not None:
        fy_n = np.sqrt(fx_n * fy_n / aspect_ratio)
        fx_n = aspect_ratio * fy_n
    Kn = np.array([[fx_n, 0.0, cxn], [0.0, fy_n, cyn], [0.0, 0.0, 1.0]])
    K = np.linalg.solve(T, Kn)
    return K / K[2, 2], condition


def poses_from_homographies(Hs: np.ndarray, K: np.ndarray, *, signed: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Board poses from homographies and intrinsics.

    ``K^-1 H = s [r1 r2 t]``; ``s`` from the mean norm of the first two columns, the sign so the board lies in front
    of the camera, ``[r1 r2 r1xr2]`` orthonormalised by SVD.

    Parameters
    ----------
    Hs : ndarray
        (V, 3, 3) board mm -> pixels.
    K : ndarray
        (3, 3) px.
    signed : bool
        Keep the sign ``Hs`` carries (homographies onto rays in any direction) instead of choosing it.

    Returns
    -------
    rvecs : ndarray
        (V, 3) rad.
    tvecs : ndarray
        (V, 3) mm.
    """
    import cv2

    M = np.linalg.solve(K, np.asarray(Hs, dtype=np.float64).reshape(-1, 3, 3))
    s = 2.0 / (np.linalg.norm(M[:, :, 0], axis=1) + np.linalg.norm(M[:, :, 1], axis=1))
    if not signed:
        s = np.where(M[:, 2, 2] < 0, -s, s)
    r1, r2, t = s[:, None] * M[:, :, 0], s[:, None] * M[:, :, 1], s[:, None] * M[:, :, 2]
    R = np.stack([r1, r2, np.cross(r1, r2)], axis=2)
    U, _, Vt = np.linalg.svd(R)
    flip = np.linalg.det(U @ Vt) < 0
    U[flip, :, 2] *= -1.0
    R = U @ Vt
    rvecs = np.stack([cv2.Rodrigues(r)[0].ravel() for r in R])
    return rvecs, t


def pose_from_homography(H: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One view's pose: :func:`poses_from_homographies` for a single homography.

    Parameters
    ----------
    H : ndarray
        (3, 3) board mm -> pixels.
    K : ndarray
        (3, 3) px.

    Returns
    -------
    rvec : ndarray
        (3,) rad.
    tvec : ndarray
        (3,) mm.
    """
    rv, tv = poses_from_homographies(np.asarray(H)[None], K)
    return rv[0], tv[0]


def view_tilts_deg(rvecs: np.ndarray) -> np.ndarray:
    """The angle between each board's normal and the optical axis.

    Parameters
    ----------
    rvecs : ndarray
        (V, 3) rad.

    Returns
    -------
    ndarray
        (V,) degrees, 0 for a fronto-parallel board.
    """
    R = rodrigues(np.asarray(rvecs, dtype=np.float64).reshape(-1, 3))
    tilts: np.ndarray = np.degrees(np.arccos(np.clip(np.abs(R[:, 2, 2]), 0.0, 1.0)))
    return tilts


def _radial_from_poses(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    camera: Camera,
    rvecs: np.ndarray,
    tvecs: np.ndarray,
) -> np.ndarray:
    """Linear least-squares (k1, k2) given intrinsics and poses (Zhang 2000, sec. 3.3): observed pixel offsets from
    the ideal projections are ``(u - cx) (k1 r^2 + k2 r^4)``."""
    rows, rhs = [], []
    for o, p, r, t in zip(object_points, image_points, rvecs, tvecs):
        Xc = transform(o, r, t)
        xn = Xc[:, :2] / Xc[:, 2:3]
        r2 = np.sum(xn * xn, axis=1)
        ideal = normalized_to_pixel(xn, camera)
        d = ideal - np.array([camera.cx, camera.cy])
        rows.append(np.stack([d * r2[:, None], d * (r2 * r2)[:, None]], axis=-1).reshape(-1, 2))
        rhs.append((np.asarray(p, dtype=np.float64) - ideal).reshape(-1))
    k: np.ndarray = np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)[0]
    return k


def _rms(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    camera: Camera,
    rvecs: np.ndarray,
    tvecs: np.ndarray,
) -> float:
    """RMS reprojection error per coordinate (px); inf when a point does not project."""
    r = np.concatenate(
        [project(o, rv, tv, camera) - p for o, p, rv, tv in zip(object_points, image_points, rvecs, tvecs)]
    )
    return error_stats(r)["rms_per_coord_px"] if np.all(np.isfinite(r)) else float("inf")


def zhang(
    object_points: list[np.ndarray],
    image_points: list[np.ndarray],
    image_size: tuple[int, int],
    *,
    principal_point: tuple[float, float] | None = None,
    aspect_ratio: float | None = None,
    distortion_rounds: int = 10,
    min_tilt_deg: float = 10.0,
) -> ZhangResult:
    """Closed-form intrinsics and poses from planar views, with an optional linear radial-distortion estimate.

    With ``principal_point`` None the zero-skew IAC is solved for (fx, fy, cx, cy) (needs >= 2 views); if that gives
    an implausible principal point (outside the image) or a non-positive conic, the image centre ``((w-1)/2,
    (h-1)/2)`` is used and only (fx, fy) are solved, as OpenCV does. ``distortion_rounds`` > 0 alternates (Zhang 2000,
    sec. 3.3): linear (k1, k2) from the current intrinsics and poses, undistort the observations with them, re-solve
    the closed form; the round with the lowest reprojection RMS is kept (round 0 is the plain closed form with zero
    distortion).

    Parameters
    ----------
    object_points : list of ndarray
        Per view (N_v, 3) mm with z = 0, N_v >= 4.
    image_points : list of ndarray
        Per view (N_v, 2) px.
    image_size : tuple of int
        (width, height) px.
    principal_point : tuple of float or None
        (cx, cy) px to hold fixed.
    aspect_ratio : float or None
        fx / fy to impose.
    distortion_rounds : int
        Rounds of the linear radial estimate (>= 0; 0: the plain closed form).
    min_tilt_deg : float
        Views tilted less than this are named when the focal length is not observable.

    Returns
    -------
    ZhangResult
        Its camera carries ``dist = [k1, k2, 0, 0, 0]``.

    Raises
    ------
    DegenerateViewsError
        No positive-definite conic exists (e.g. all views fronto-parallel), naming the views tilted less than
        ``min_tilt_deg``.
    CalibrationError
        Fewer than 4 points in a view, or collinear / coincident points.
    """
    w, h = image_size
    obj = [np.asarray(o, dtype=np.float64) for o in object_points]
    img = [np.asarray(p, dtype=np.float64) for p in image_points]
    all_img = np.concatenate(img)
    splits = np.cumsum([len(p) for p in img])[:-1]
    x_prev = None
    best: tuple[ZhangResult, float] | None = None
    k = np.zeros(2)
    for _ in range(distortion_rounds + 1):
        if best is not None and np.any(k):  # k is non-zero only once a round has been kept
            cam0 = best[0].camera
            cam_k = Camera(int(w), int(h), cam0.fx, cam0.fy, cam0.cx, cam0.cy, np.array([k[0], k[1], 0, 0, 0]))
            und = undistort(pixel_to_normalized(all_img, cam_k), cam_k.dist, x0=x_prev, tol=1e-12)
            if not np.all(np.isfinite(und)):
                break
            x_prev = und
            pts = np.split(normalized_to_pixel(und, cam0), splits)
        else:
            pts = img
        try:
            res = _closed_form(obj, pts, image_size, principal_point, aspect_ratio, min_tilt_deg)
        except DegenerateViewsError:
            if best is None:
                raise
            break
        cam = Camera(
            int(w),
            int(h),
            res.camera.fx,
            res.camera.fy,
            res.camera.cx,
            res.camera.cy,
            np.array([k[0], k[1], 0.0, 0.0, 0.0]),
        )
        res = ZhangResult(cam, res.rvecs, res.tvecs, res.homographies, res.condition, res.principal_point_fixed)
        if distortion_rounds == 0:
            return res
        rms = _rms(obj, img, cam, res.rvecs, res.tvecs)
        if best is None or rms < best[1]:
            best = (res, rms)
        elif rms > best[1]:
            break
        k_new = _radial_from_poses(obj, img, cam, res.rvecs, res.tvecs)
        if np.all(np.abs(k_new - k) <= 1e-4 * (np.abs(k_new) + 1e-3)):
            break
        k = k_new
    if best is None:
        raise ValueError(f"distortion_rounds must be >= 0, got {distortion_rounds}")
    return best[0]


def _closed_form(
    obj: Sequence[np.ndarray],
    img: Sequence[np.ndarray],
    image_size: tuple[int, int],
    principal_point: tuple[float, float] | None,
    aspect_ratio: float | None,
    min_tilt_deg: float,
) -> ZhangResult:
    w, h = image_size
    Hs = homographies([o[:, :2] for o in obj], img)
    centre = (0.5 * (w - 1), 0.5 * (h - 1))
    pp_fixed = principal_point is not None
    K = None
    condition = float("inf")
    if not pp_fixed and len(Hs) >= 2:
        K, condition = intrinsics_from_homographies(Hs, image_size, aspect_ratio=aspect_ratio)
        ok = (
            np.all(np.isfinite(K))
            and -0.5 <= K[0, 2] <= w - 0.5
            and -0.5 <= K[1, 2] <= h - 0.5
            and 0.2 < K[0, 0] / K[1, 1] < 5.0
        )
        if not ok:
            K = None
    if K is None:
        pp = principal_point if pp_fixed else centre
        K, condition = intrinsics_from_homographies(Hs, image_size, principal_point=pp, aspect_ratio=aspect_ratio)
        pp_fixed = True
    if not np.all(np.isfinite(K)):
        f_guess = float(max(w, h))
        K_guess = np.array([[f_guess, 0.0, centre[0]], [0.0, f_guess, centre[1]], [0.0, 0.0, 1.0]])
        tilts = view_tilts_deg(poses_from_homographies(Hs, K_guess)[0])
        flat = [int(i) for i in np.flatnonzero(tilts < min_tilt_deg)]
        if flat:
            listing = ", ".join(f"{i} ({tilts[i]:.1f} deg)" for i in flat)
            hint = (
                f"Views nearly fronto-parallel (tilt < {min_tilt_deg:g} deg, measured with a nominal "
                f"f = {f_guess:.0f} px): {listing}. Add views with the board tilted 20-50 deg about different "
                f"axes."
            )
        else:
            hint = (
                "No view is nearly fronto-parallel, so the homographies are inconsistent with any pinhole "
                "camera: check the point correspondences (board order, rows/cols) and the object points."
            )
        raise DegenerateViewsError(
            f"focal length is not observable from these {len(Hs)} views: the image of the absolute conic is not "
            f"positive definite (condition number {condition:.3g}). {hint}",
            flat,
            condition,
        )
    rvecs, tvecs = poses_from_homographies(Hs, K)
    camera = Camera(int(w), int(h), float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), np.zeros(5))
    return ZhangResult(camera, rvecs, tvecs, Hs, condition, pp_fixed)
