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

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "Camera",
    "DIST_NAMES",
    "PARAM_NAMES",
    "rodrigues",
    "transform",
    "distort",
    "distort_jacobian",
    "undistort",
    "project",
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

    ``width``/``height`` in pixels; ``fx, fy, cx, cy`` in pixels (OpenCV pixel-centre convention);
    ``dist`` = ``[k1, k2, p1, p2, k3]`` (unitless, on normalised coordinates).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))

    def __post_init__(self) -> None:
        d = np.asarray(self.dist, dtype=np.float64).reshape(-1)
        if d.size != 5:
            raise ValueError(f"dist must hold 5 coefficients [k1, k2, p1, p2, k3], got {d.size}")
        object.__setattr__(self, "dist", d)
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")

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
        """Read a ``camera`` block; raises ``ValueError`` naming the missing key."""
        missing = [k for k in ("width", "height", "fx", "fy", "cx", "cy", "dist") if k not in d]
        if missing:
            raise ValueError(f"camera block lacks {', '.join(missing)}")
        return cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]), float(d["cx"]),
                   float(d["cy"]), np.asarray(d["dist"], dtype=np.float64))


def rodrigues(rvec: np.ndarray) -> np.ndarray:
    """Rotation matrices from axis-angle vectors.

    ``rvec``: (..., 3) radians. Returns (..., 3, 3). Exact (series form) for tiny angles.
    """
    r = np.asarray(rvec, dtype=np.float64)
    theta2 = np.sum(r * r, axis=-1)[..., None, None]
    theta = np.sqrt(theta2)
    small = theta2 < 1e-16
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    zero = np.zeros(r.shape[:-1])
    kx = np.stack(
        [
            np.stack([zero, -r[..., 2], r[..., 1]], -1),
            np.stack([r[..., 2], zero, -r[..., 0]], -1),
            np.stack([-r[..., 1], r[..., 0], zero], -1),
        ],
        -2,
    )
    eye = np.broadcast_to(np.eye(3), kx.shape)
    return eye + a * kx + b * (kx @ kx)


def transform(points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """Board points (N, 3) into the camera frame: ``R(rvec) @ X + tvec``. Returns (N, 3)."""
    R = rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))
    return np.asarray(points, dtype=np.float64) @ R.T + np.asarray(tvec, dtype=np.float64).reshape(3)


def distort(xn: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply Brown distortion to normalised coordinates.

    ``xn``: (..., 2) undistorted normalised coordinates; ``dist``: (5,) k1, k2, p1, p2, k3.
    Returns (..., 2) distorted normalised coordinates.
    """
    k1, k2, p1, p2, k3 = np.asarray(dist, dtype=np.float64)
    x = xn[..., 0]
    y = xn[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    return np.stack([xd, yd], axis=-1)


def distort_jacobian(xn: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distortion with its derivatives.

    ``xn``: (..., 2), ``dist``: (5,). Returns ``(xd, J_x, J_d)``: xd (..., 2); ``J_x`` = d xd / d xn, (..., 2, 2);
    ``J_d`` = d xd / d [k1, k2, p1, p2, k3], (..., 2, 5).
    """
    k1, k2, p1, p2, k3 = np.asarray(dist, dtype=np.float64)
    x = xn[..., 0]
    y = xn[..., 1]
    r2 = x * x + y * y
    r4 = r2 * r2
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4  # d radial / d r2
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    J_x = np.empty(x.shape + (2, 2))
    J_x[..., 0, 0] = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    J_x[..., 0, 1] = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    J_x[..., 1, 0] = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    J_x[..., 1, 1] = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
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


def _distort_jx(x: np.ndarray, y: np.ndarray, dist: np.ndarray):
    """Distortion and its 2x2 Jacobian w.r.t. the normalised point, as separate 1-D arrays (Newton's inner loop)."""
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    xy = x * y
    fx = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    fy = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    off = 2.0 * xy * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    a = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    d = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return fx, fy, a, off, d


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
    fx, fy, a, b, c = _distort_jx(x, y, d)
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
        for _ in range(40):
            nx, ny = x - lam * sx, y - lam * sy
            fx, fy, na, nb, nc = _distort_jx(nx, ny, d)
            nrx, nry = fx - tx, fy - ty
            nerr = np.maximum(np.abs(nrx), np.abs(nry))
            worse = ~(nerr <= err)  # also catches NaN
            if not worse.any():
                break
            lam = np.where(worse, 0.5 * lam, lam)
        x, y, a, b, c, rx, ry, err = nx, ny, na, nb, nc, nrx, nry, nerr
        if worse.any():  # no descent even after 40 halvings: no inverse here (the model folds over)
            out[idx[worse]] = np.nan
            keep = ~worse
            idx, tx, ty, x, y, thr, a, b, c, rx, ry, err = (
                v[keep] for v in (idx, tx, ty, x, y, thr, a, b, c, rx, ry, err))
    if idx.size:
        out[idx] = np.nan
    # A root on the far side of the fold (radial factor <= 0, or the map locally orientation-reversing) is no
    # inverse of a real lens: report it as NaN.
    k1, k2, _, _, k3 = d
    r2 = out[:, 0] ** 2 + out[:, 1] ** 2
    _, _, a, b, c = _distort_jx(out[:, 0], out[:, 1], d)
    bad = ((1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) <= 0) | ((a * c - b * b) <= 0)
    out[bad] = np.nan
    return out.reshape(shape)


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
