"""The one camera model of circcal: pinhole + OpenCV's 5-coefficient Brown distortion.

Every part of the project (renderer, detector, solver, metrics, validators) projects through these functions, so a
convention fixed here holds everywhere.

Conventions
-----------
* Pixel coordinates follow OpenCV: integer coordinates are pixel *centres*; the top-left pixel covers
  [-0.5, 0.5] x [-0.5, 0.5]. (COLMAP's convention puts that centre at (0.5, 0.5): convert at the format boundary.)
* Camera frame: x right, y down, z forward (OpenCV). A pose ``(rvec, tvec)`` maps board/world points into the camera
  frame, ``X_cam = R(rvec) @ X_board + tvec``; ``rvec`` is an axis-angle vector in radians, ``tvec`` in the board's
  length unit (mm throughout circcal).
* Distortion vector ``dist = [k1, k2, p1, p2, k3]`` in OpenCV's order, applied to normalised coordinates
  ``x = X/Z, y = Y/Z``::

      r2 = x^2 + y^2,  radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
      xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
      yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y
      u = fx xd + cx,  v = fy yd + cy

  This is exactly ``cv2.projectPoints`` with a 5-element distortion vector (tested to 1e-9 px).
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal.errors import InputError
from circcal.rotation import left_jacobian, rodrigues, rotated_jacobian

__all__ = [
    "Camera",
    "DIST_NAMES",
    "PARAM_NAMES",
    "transform",
    "distort",
    "distort_jacobian",
    "undistort",
    "project",
    "project_jacobian",
    "project_camera",
    "project_camera_jacobian",
    "unproject",
    "pixel_to_normalized",
    "normalized_to_pixel",
    "undistort_pixels",
    "distort_pixels",
]

DIST_NAMES: tuple[str, ...] = ("k1", "k2", "p1", "p2", "k3")
#: The calibrated parameters in OpenCV's order (:attr:`Camera.intrinsics`); every std dict is keyed by these.
PARAM_NAMES: tuple[str, ...] = ("fx", "fy", "cx", "cy") + DIST_NAMES


@dataclass(frozen=True)
class Camera:
    """Intrinsics of a pinhole camera with OpenCV 5-coefficient distortion.

    ``width``/``height`` in pixels (positive integers); ``fx, fy, cx, cy`` in pixels (OpenCV pixel-centre
    convention; finite, focal lengths positive); ``dist`` = ``[k1, k2, p1, p2, k3]`` (unitless, on normalised
    coordinates; finite). Every value is checked on construction (:class:`~circcal.errors.InputError` naming the
    field): a camera that exists holds only values that project.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if not _is_number(v) or not np.isfinite(float(v)) or float(v) != int(v) or int(v) <= 0:
                raise InputError(f"camera {name} must be a positive integer (pixels), got {v!r}")
            object.__setattr__(self, name, int(v))
        for name in ("fx", "fy", "cx", "cy"):
            v = getattr(self, name)
            if not _is_number(v) or not np.isfinite(float(v)):
                raise InputError(f"camera {name} must be a finite number (pixels), got {v!r}")
            object.__setattr__(self, name, float(v))
        if not (self.fx > 0 and self.fy > 0):
            raise InputError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        raw = self.dist
        if isinstance(raw, (str, bytes, dict)) or (np.ndim(raw) == 0 and raw is not None):
            raise InputError(f"camera dist must be a list of {len(DIST_NAMES)} numbers {list(DIST_NAMES)}, "
                             f"got {raw!r}")
        items = list(np.ravel(np.asarray(raw, dtype=object))) if raw is not None else None
        if items is None or len(items) != len(DIST_NAMES):
            raise InputError(f"camera dist must hold {len(DIST_NAMES)} coefficients {list(DIST_NAMES)}, got "
                             f"{0 if items is None else len(items)}")
        for name, v in zip(DIST_NAMES, items):
            if not _is_number(v) or not np.isfinite(float(v)):
                raise InputError(f"camera distortion {name} must be a finite number, got {v!r}")
        object.__setattr__(self, "dist", np.array([float(v) for v in items], dtype=np.float64))

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix (no skew)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def intrinsics(self) -> np.ndarray:
        """The 9 calibrated parameters in OpenCV's order: fx, fy, cx, cy, k1, k2, p1, p2, k3."""
        return np.concatenate([[self.fx, self.fy, self.cx, self.cy], self.dist])

    @classmethod
    def from_intrinsics(cls, width: int, height: int, params: np.ndarray) -> "Camera":
        """Inverse of :attr:`intrinsics`: ``params`` = (9,) fx, fy, cx, cy, k1, k2, p1, p2, k3."""
        p = np.asarray(params, dtype=np.float64)
        return cls(int(width), int(height), float(p[0]), float(p[1]), float(p[2]), float(p[3]), p[4:9].copy())

    def to_dict(self) -> dict[str, Any]:
        """The ``camera`` block of truth.json / model.json."""
        return {
            "width": int(self.width),
            "height": int(self.height),
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "dist": [float(v) for v in self.dist],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Camera":
        """Read a ``camera`` block; every value is checked (see the class) and a missing key named
        (:class:`~circcal.errors.InputError`)."""
        if not isinstance(d, dict):
            raise InputError(f"a camera block must be a mapping, got {type(d).__name__}")
        missing = [k for k in ("width", "height", "fx", "fy", "cx", "cy", "dist") if k not in d]
        if missing:
            raise InputError(f"camera block lacks {', '.join(missing)}")
        return cls(d["width"], d["height"], d["fx"], d["fy"], d["cx"], d["cy"], d["dist"])


def _is_number(v: Any) -> bool:
    """A real number that is not a boolean (``True`` is an int in Python, and no camera value)."""
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def transform(points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """Board points (N, 3) into the camera frame: ``R(rvec) @ X + tvec``. Returns (N, 3)."""
    R = rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))
    return np.asarray(points, dtype=np.float64) @ R.T + np.asarray(tvec, dtype=np.float64).reshape(3)


def _brown(x: np.ndarray, y: np.ndarray, dist: np.ndarray, jacobian: bool):
    """The distortion polynomial, written once: ``(xd, yd)`` of normalised ``(x, y)`` (same-shape arrays), and with
    ``jacobian`` also ``radial`` and the 2x2 Jacobian ``d(xd, yd)/d(x, y)`` as ``(a, b, c)`` =
    ``[[a, b], [b, c]]`` (it is symmetric)."""
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    if not jacobian:
        return xd, yd
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    a = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    b = xy2 * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    c = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, radial, a, b, c


def distort(xn: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply Brown distortion to normalised coordinates.

    ``xn``: (..., 2) undistorted normalised coordinates; ``dist``: (5,) k1, k2, p1, p2, k3.
    Returns (..., 2) distorted normalised coordinates.
    """
    xn = np.asarray(xn, dtype=np.float64)
    xd, yd = _brown(xn[..., 0], xn[..., 1], np.asarray(dist, dtype=np.float64), False)
    return np.stack([xd, yd], axis=-1)


def distort_jacobian(xn: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distortion with its derivatives.

    ``xn``: (..., 2), ``dist``: (5,). Returns ``(xd, J_x, J_d)``: xd (..., 2); ``J_x`` = d xd / d xn, (..., 2, 2);
    ``J_d`` = d xd / d [k1, k2, p1, p2, k3], (..., 2, 5).
    """
    xn = np.asarray(xn, dtype=np.float64)
    x, y = xn[..., 0], xn[..., 1]
    xd, yd, _, a, b, c = _brown(x, y, np.asarray(dist, dtype=np.float64), True)
    J_x = np.empty(x.shape + (2, 2))
    J_x[..., 0, 0] = a
    J_x[..., 0, 1] = J_x[..., 1, 0] = b
    J_x[..., 1, 1] = c
    r2 = x * x + y * y
    r4 = r2 * r2
    J_d = np.empty(x.shape + (2, 5))
    J_d[..., 0, 0] = x * r2
    J_d[..., 0, 1] = x * r4
    J_d[..., 0, 2] = 2.0 * x * y
    J_d[..., 0, 3] = r2 + 2.0 * x * x
    J_d[..., 0, 4] = x * r4 * r2
    J_d[..., 1, 0] = y * r2
    J_d[..., 1, 1] = y * r4
    J_d[..., 1, 2] = r2 + 2.0 * y * y
    J_d[..., 1, 3] = 2.0 * x * y
    J_d[..., 1, 4] = y * r4 * r2
    return np.stack([xd, yd], axis=-1), J_x, J_d


#: A Newton step of :func:`undistort` that does not lower a point's residual is halved, at most this many times
#: before the point is declared beyond the lens's fold (NaN).
_MAX_STEP_HALVINGS = 40


def undistort(
    xd: np.ndarray,
    dist: np.ndarray,
    *,
    x0: np.ndarray | None = None,
    tol: float = 1e-15,
    max_iter: int = 60,
) -> np.ndarray:
    """Invert :func:`distort` by a vectorised, damped Newton iteration.

    ``xd``: (..., 2) distorted normalised coordinates; ``dist``: (5,); ``x0``: optional (..., 2) initial guess (e.g. a
    neighbouring solution: two Newton steps then suffice). Stops when every residual ``|distort(x) - xd|`` (max norm,
    normalised units) is below ``tol`` (relative to ``|xd|`` beyond 1); 1e-15 normalised is ~1e-11 px for f up to
    10^4 px. A step that does not reduce a point's residual is halved (guards strong barrel distortion).
    Returns (..., 2) undistorted normalised coordinates. Points where the model folds over (no unique inverse,
    far outside a sensible field of view) come back as NaN rather than a wrong value.
    """
    xd = np.asarray(xd, dtype=np.float64)
    d = np.asarray(dist, dtype=np.float64)
    if not np.any(d):
        return xd.copy()
    shape = xd.shape
    t = xd.reshape(-1, 2)
    out = (t.copy() if x0 is None else np.asarray(x0, dtype=np.float64).reshape(-1, 2).copy())
    idx = np.arange(t.shape[0])                     # points still iterating
    tx, ty = t[:, 0].copy(), t[:, 1].copy()
    x, y = out[:, 0].copy(), out[:, 1].copy()
    thr = tol * np.maximum(1.0, np.maximum(np.abs(tx), np.abs(ty)))
    fx, fy, _, a, b, c = _brown(x, y, d, True)
    rx, ry = fx - tx, fy - ty
    err = np.maximum(np.abs(rx), np.abs(ry))
    for _ in range(max_iter):
        done = err <= thr
        if done.any():
            out[idx[done], 0] = x[done]
            out[idx[done], 1] = y[done]
            keep = ~done
            idx, tx, ty, x, y, thr, a, b, c, rx, ry, err = (
                v[keep] for v in (idx, tx, ty, x, y, thr, a, b, c, rx, ry, err))
        if idx.size == 0:
            break
        det = a * c - b * b
        det = np.where(np.abs(det) < 1e-300, 1e-300, det)
        sx = (c * rx - b * ry) / det
        sy = (a * ry - b * rx) / det
        lam = np.ones_like(x)
        for _ in range(_MAX_STEP_HALVINGS):
            nx, ny = x - lam * sx, y - lam * sy
            fx, fy, _, na, nb, nc = _brown(nx, ny, d, True)
            nrx, nry = fx - tx, fy - ty
            nerr = np.maximum(np.abs(nrx), np.abs(nry))
            worse = ~(nerr <= err)  # also catches NaN
            if not worse.any():
                break
            lam = np.where(worse, 0.5 * lam, lam)
        x, y, a, b, c, rx, ry, err = nx, ny, na, nb, nc, nrx, nry, nerr
        if worse.any():  # no descent even after every halving: no inverse here (the model folds over)
            out[idx[worse]] = np.nan
            keep = ~worse
            idx, tx, ty, x, y, thr, a, b, c, rx, ry, err = (
                v[keep] for v in (idx, tx, ty, x, y, thr, a, b, c, rx, ry, err))
    if idx.size:
        out[idx] = np.nan
    # A root on the far side of the fold (radial factor <= 0, or the map locally orientation-reversing) is no
    # inverse of a real lens: report it as NaN.
    _, _, radial, a, b, c = _brown(out[:, 0], out[:, 1], d, True)
    bad = (radial <= 0) | ((a * c - b * b) <= 0)
    out[bad] = np.nan
    return out.reshape(shape)


def project_camera_jacobian(Xc: np.ndarray, params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera-frame points (N, 3) -> pixels, with derivatives: the projection of :func:`project` after the pose.

    ``params``: (9,) intrinsics in :data:`PARAM_NAMES` order (:attr:`Camera.intrinsics`). Returns ``(uv (N, 2) px,
    J_intr (N, 2, 9) = d uv / d params, J_X (N, 2, 3) = d uv / d Xc)``.
    """
    fx, fy = params[0], params[1]
    iz = 1.0 / Xc[:, 2]
    xn = Xc[:, :2] * iz[:, None]
    xd, Jx, Jd = distort_jacobian(xn, params[4:9])
    n = len(Xc)
    uv = np.empty((n, 2))
    uv[:, 0] = fx * xd[:, 0] + params[2]
    uv[:, 1] = fy * xd[:, 1] + params[3]
    Ji = np.zeros((n, 2, 9))
    Ji[:, 0, 0] = xd[:, 0]
    Ji[:, 1, 1] = xd[:, 1]
    Ji[:, 0, 2] = 1.0
    Ji[:, 1, 3] = 1.0
    Ji[:, 0, 4:] = fx * Jd[:, 0, :]
    Ji[:, 1, 4:] = fy * Jd[:, 1, :]
    # d uv / d Xc = diag(f) Jx d xn / d Xc, with d xn / d Xc = [[1/z, 0, -x/z], [0, 1/z, -y/z]]
    A = Jx * np.array([fx, fy])[None, :, None]
    J_X = np.empty((n, 2, 3))
    J_X[:, :, 0] = A[:, :, 0] * iz[:, None]
    J_X[:, :, 1] = A[:, :, 1] * iz[:, None]
    J_X[:, :, 2] = -(A[:, :, 0] * xn[:, 0:1] + A[:, :, 1] * xn[:, 1:2]) * iz[:, None]
    return uv, Ji, J_X


def project_jacobian(points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, camera: Camera
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`project` with derivatives, for one view.

    ``points``: (N, 3) mm. Returns ``(uv, J_intr, J_pose)``: uv (N, 2) px; ``J_intr`` (N, 2, 9) with respect to
    fx, fy, cx, cy, k1, k2, p1, p2, k3; ``J_pose`` (N, 2, 6) with respect to rvec (3) then tvec (3).
    """
    r = np.asarray(rvec, dtype=np.float64).reshape(3)
    Y = np.asarray(points, dtype=np.float64) @ rodrigues(r).T
    uv, Ji, J_X = project_camera_jacobian(Y + np.asarray(tvec, dtype=np.float64).reshape(3), camera.intrinsics)
    return uv, Ji, np.concatenate([rotated_jacobian(J_X, Y) @ left_jacobian(r), J_X], axis=2)


def project_camera(P: np.ndarray, camera: Camera) -> np.ndarray:
    """Camera-frame points or rays (N, 3) -> pixels (N, 2); NaN for points at or behind the camera (z <= 0)."""
    P = np.asarray(P, dtype=np.float64)
    z = np.where(P[:, 2] > 0, P[:, 2], np.nan)
    return normalized_to_pixel(distort(P[:, :2] / z[:, None], camera.dist), camera)


def project(
    points: np.ndarray,
    rvec: np.ndarray,
    tvec: np.ndarray,
    camera: Camera,
) -> np.ndarray:
    """Project board points into the image: (N, 3) board coordinates -> (N, 2) pixels (OpenCV convention).

    Equals ``cv2.projectPoints(points, rvec, tvec, camera.K, camera.dist)``.
    """
    Xc = transform(points, rvec, tvec)
    xn = Xc[:, :2] / Xc[:, 2:3]
    return normalized_to_pixel(distort(xn, camera.dist), camera)


def unproject(uv: np.ndarray, camera: Camera) -> np.ndarray:
    """Pixels (N, 2) -> rays (N, 3) with z = 1 (undistorted normalised coordinates); NaN where the distortion has no
    unique inverse (see :func:`undistort`)."""
    xn = undistort(pixel_to_normalized(uv, camera), camera.dist)
    return np.concatenate([xn, np.ones((len(xn), 1))], axis=1)


def pixel_to_normalized(uv: np.ndarray, camera: Camera) -> np.ndarray:
    """(..., 2) pixels -> (..., 2) *distorted* normalised coordinates (K^-1 only)."""
    uv = np.asarray(uv, dtype=np.float64)
    return np.stack([(uv[..., 0] - camera.cx) / camera.fx, (uv[..., 1] - camera.cy) / camera.fy], axis=-1)


def normalized_to_pixel(xn: np.ndarray, camera: Camera) -> np.ndarray:
    """(..., 2) normalised coordinates -> (..., 2) pixels (K only)."""
    xn = np.asarray(xn, dtype=np.float64)
    return np.stack([xn[..., 0] * camera.fx + camera.cx, xn[..., 1] * camera.fy + camera.cy], axis=-1)


def undistort_pixels(uv: np.ndarray, camera: Camera) -> np.ndarray:
    """Distorted pixels (..., 2) -> ideal pinhole pixels (..., 2) with the same K (distortion removed)."""
    return normalized_to_pixel(undistort(pixel_to_normalized(uv, camera), camera.dist), camera)


def distort_pixels(uv: np.ndarray, camera: Camera) -> np.ndarray:
    """Ideal pinhole pixels (..., 2) -> distorted pixels (..., 2); inverse of :func:`undistort_pixels`."""
    return normalized_to_pixel(distort(pixel_to_normalized(uv, camera), camera.dist), camera)
