"""The one camera model of circcal: a pinhole with OpenCV's distortion (5, 8 or 12 coefficients) or cv2.fisheye's
equidistant Kannala-Brandt lens.

Every part of the project (renderer, detector, solver, uncertainty, metrics, validators) projects through these
functions, so a convention fixed here holds everywhere.

Conventions
-----------
* Pixel coordinates follow OpenCV: integer coordinates are pixel *centres*; the top-left pixel covers
  [-0.5, 0.5] x [-0.5, 0.5]. (COLMAP's convention puts that centre at (0.5, 0.5): convert at the format boundary.)
* Camera frame: x right, y down, z forward (OpenCV). A pose ``(rvec, tvec)`` maps board/world points into the camera
  frame, ``X_cam = R(rvec) @ X_board + tvec``; ``rvec`` is an axis-angle vector in radians, ``tvec`` in the board's
  length unit (mm throughout circcal).
* Lens models (:data:`LENS_MODELS`; ``Camera.lens``), each ``u = fx xd + cx, v = fy yd + cy`` (no skew) of the
  distorted normalised coordinates ``(xd, yd)``:

  ``opencv5``    ``dist = [k1, k2, p1, p2, k3]``: ``cv2.projectPoints`` with a 5-vector (:mod:`.brown`)
  ``rational``   ``[k1, k2, p1, p2, k3, k4, k5, k6]``: OpenCV's 8-vector, ``CALIB_RATIONAL_MODEL``
  ``thin-prism`` ``[k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4]``: OpenCV's 12-vector, ``CALIB_THIN_PRISM_MODEL``
  ``fisheye``    ``[k1, k2, k3, k4]``: ``cv2.fisheye`` (theta polynomial, skew alpha 0; :mod:`.fisheye`)

  Each equals its OpenCV projection to 1e-9 px (tests/test_model.py).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal.errors import InputError
from circcal.model.brown import (
    _distort_jacobian_into,
    check_dist,
    denominator_minimum,
    distort,
    distort_jacobian,
    undistort,
)
from circcal.model.fisheye import _check as check_fisheye
from circcal.model.fisheye import _fisheye, fisheye_distort, fisheye_distort_jacobian, fisheye_rays, theta_max
from circcal.rotation import left_jacobian, rodrigues, rotated_jacobian

__all__ = [
    "Camera",
    "fisheye_distort_jacobian",
    "LensModel",
    "LENS_MODELS",
    "DEFAULT_LENS",
    "DIST_NAMES",
    "PARAM_NAMES",
    "param_names",
    "lens_model",
    "transform",
    "distort",
    "distort_jacobian",
    "undistort",
    "denominator_minimum",
    "theta_max",
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


@dataclass(frozen=True)
class LensModel:
    """One lens model of :data:`LENS_MODELS`.

    Attributes
    ----------
    name : str
        The model's name (``Camera.lens``).
    dist_names : tuple of str
        Its distortion coefficients' names in the order of ``Camera.dist`` (OpenCV's order).
    pinhole : bool
        True when the image is a distorted perspective projection (z > 0 only; :func:`undistort` inverts it), False
        for the fisheye (any direction, theta up to pi).
    description : str
        One line in words.
    """

    name: str
    dist_names: tuple[str, ...]
    pinhole: bool
    description: str

    @property
    def n_dist(self) -> int:
        """The number of distortion coefficients (``len(dist_names)``)."""
        return len(self.dist_names)

    @property
    def param_names(self) -> tuple[str, ...]:
        """fx, fy, cx, cy, then :attr:`dist_names`: the order of :attr:`Camera.intrinsics`."""
        return ("fx", "fy", "cx", "cy") + self.dist_names


DEFAULT_LENS = "opencv5"
#: The lens models by name (see the module docstring for the formulas).
LENS_MODELS: dict[str, LensModel] = {
    m.name: m
    for m in (
        LensModel(
            "opencv5",
            ("k1", "k2", "p1", "p2", "k3"),
            True,
            "OpenCV pinhole + 5 distortion coefficients [k1, k2, p1, p2, k3]",
        ),
        LensModel(
            "rational",
            ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
            True,
            "OpenCV rational model (CALIB_RATIONAL_MODEL) [k1, k2, p1, p2, k3, k4, k5, k6]",
        ),
        LensModel(
            "thin-prism",
            ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4"),
            True,
            "OpenCV rational + thin prism (CALIB_THIN_PRISM_MODEL) [k1, ..., k6, s1, s2, s3, s4]",
        ),
        LensModel(
            "fisheye",
            ("k1", "k2", "k3", "k4"),
            False,
            "cv2.fisheye equidistant Kannala-Brandt theta_d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)",
        ),
    )
}

DIST_NAMES: tuple[str, ...] = LENS_MODELS[DEFAULT_LENS].dist_names
#: The calibrated parameters of the default ``opencv5`` model in OpenCV's order (kept for callers that know only
#: that model); :func:`param_names` gives every model's.
PARAM_NAMES: tuple[str, ...] = LENS_MODELS[DEFAULT_LENS].param_names


def lens_model(name: str) -> LensModel:
    """The :class:`LensModel` called ``name``.

    Parameters
    ----------
    name : str
        A :data:`LENS_MODELS` name: ``opencv5``, ``rational``, ``thin-prism`` or ``fisheye``.

    Returns
    -------
    LensModel

    Raises
    ------
    InputError
        ``name`` is not a known model (the message lists the known ones).

    Examples
    --------
    >>> lens_model("rational").n_dist
    8
    """
    if not isinstance(name, str) or name not in LENS_MODELS:
        raise InputError(f"unknown lens model {name!r}; known: {', '.join(LENS_MODELS)}")
    return LENS_MODELS[name]


def param_names(lens: str = DEFAULT_LENS) -> tuple[str, ...]:
    """The names of :attr:`Camera.intrinsics` for ``lens``.

    Parameters
    ----------
    lens : str
        A :data:`LENS_MODELS` name (default ``opencv5``).

    Returns
    -------
    tuple of str
        fx, fy, cx, cy, then the distortion coefficients' names.

    Raises
    ------
    InputError
        Unknown lens model.

    Examples
    --------
    >>> param_names("fisheye")
    ('fx', 'fy', 'cx', 'cy', 'k1', 'k2', 'k3', 'k4')
    """
    return lens_model(lens).param_names


@dataclass(frozen=True)
class Camera:
    """Intrinsics of a camera: pinhole ``K`` (no skew) and one lens model's distortion.

    Every value is checked on construction: a camera that exists holds only values that project.

    Parameters
    ----------
    width, height : int
        Image size in px (positive integers; an integral float is accepted).
    fx, fy, cx, cy : float
        Focal lengths and principal point in px (OpenCV pixel-centre convention; finite, focal lengths positive).
    dist : array_like of float, optional
        The coefficients of ``lens`` in ``LENS_MODELS[lens].dist_names`` order (unitless, finite); default all 0.
        Stored as a float64 (n_dist,) array.
    lens : str
        A :data:`LENS_MODELS` name (default ``opencv5``: ``[k1, k2, p1, p2, k3]``).

    Raises
    ------
    InputError
        A value of the wrong type, not finite, out of range, the wrong number of coefficients or an unknown lens
        model; the message names the field.

    Examples
    --------
    >>> cam = Camera(1280, 960, 1000.0, 1000.0, 639.5, 479.5, [-0.1, 0.01, 0.0, 0.0, 0.0])
    >>> float(cam.K[0, 2]), cam.model.n_dist
    (639.5, 5)
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    # None stands for "all zeros" (their number depends on ``lens``); __post_init__ replaces it with an array
    dist: np.ndarray = field(default=None)  # type: ignore[arg-type]
    lens: str = DEFAULT_LENS

    def __post_init__(self) -> None:
        model = lens_model(self.lens)
        for name in ("width", "height"):
            v = getattr(self, name)
            if not _is_number(v) or not _finite(v) or float(v) != int(v) or int(v) <= 0:
                raise InputError(f"camera {name} must be a positive integer (pixels), got {v!r}")
            object.__setattr__(self, name, int(v))
        for name in ("fx", "fy", "cx", "cy"):
            v = getattr(self, name)
            if not _is_number(v) or not _finite(v):
                raise InputError(f"camera {name} must be a finite number (pixels), got {v!r}")
            object.__setattr__(self, name, float(v))
        if not (self.fx > 0 and self.fy > 0):
            raise InputError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        names = model.dist_names
        raw = np.zeros(len(names)) if self.dist is None else self.dist
        if isinstance(raw, (str, bytes, dict)) or np.ndim(raw) == 0:
            raise InputError(
                f"camera dist must be a list of {len(names)} numbers {list(names)} ({model.name}), got {raw!r}"
            )
        items = list(np.ravel(np.asarray(raw, dtype=object)))
        if len(items) != len(names):
            raise InputError(
                f"camera dist must hold {len(names)} coefficients {list(names)} (lens {model.name}), got {len(items)}"
            )
        for name, v in zip(names, items):
            if not _is_number(v) or not _finite(v):
                raise InputError(f"camera distortion {name} must be a finite number, got {v!r}")
        object.__setattr__(self, "dist", np.array([float(v) for v in items], dtype=np.float64))

    @property
    def model(self) -> LensModel:
        """The :class:`LensModel` of :attr:`lens`."""
        return LENS_MODELS[self.lens]

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix (no skew)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def intrinsics(self) -> np.ndarray:
        """The calibrated parameters (4 + n_dist,) in :func:`param_names` order: fx, fy, cx, cy, then ``dist``."""
        return np.concatenate([[self.fx, self.fy, self.cx, self.cy], self.dist])

    @classmethod
    def from_intrinsics(cls, width: int, height: int, params: np.ndarray, lens: str = DEFAULT_LENS) -> Camera:
        """The camera of a parameter vector: the inverse of :attr:`intrinsics`.

        Parameters
        ----------
        width, height : int
            Image size in px.
        params : ndarray
            (4 + n_dist,) fx, fy, cx, cy in px, then ``lens``'s coefficients.
        lens : str
            A :data:`LENS_MODELS` name (default ``opencv5``).

        Returns
        -------
        Camera

        Raises
        ------
        InputError
            A value the camera refuses (see the class).
        """
        p = np.asarray(params, dtype=np.float64)
        n = lens_model(lens).n_dist
        return cls(
            int(width), int(height), float(p[0]), float(p[1]), float(p[2]), float(p[3]), p[4 : 4 + n].copy(), lens
        )

    def to_dict(self) -> dict[str, Any]:
        """The ``camera`` block of truth.json / model.json.

        Returns
        -------
        dict
            ``width``, ``height`` (int px), ``fx``, ``fy``, ``cx``, ``cy`` (float px), ``dist`` (list of float) and
            ``lens`` for every model but the default ``opencv5``, where it is left out: files (and fixture content
            hashes) of 5-coefficient cameras stay as they were, and readers take a missing ``lens`` as ``opencv5``.
        """
        d: dict[str, Any] = {
            "width": int(self.width),
            "height": int(self.height),
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "dist": [float(v) for v in self.dist],
        }
        if self.lens != DEFAULT_LENS:
            d["lens"] = self.lens
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Camera:
        """Read a ``camera`` block (the inverse of :meth:`to_dict`).

        Parameters
        ----------
        d : dict
            ``width``, ``height``, ``fx``, ``fy``, ``cx``, ``cy``, ``dist`` and optionally ``lens`` (default
            ``opencv5``).

        Returns
        -------
        Camera

        Raises
        ------
        InputError
            Not a mapping, a missing key (named), ``dist`` None, or a value the camera refuses (see the class).
        """
        if not isinstance(d, dict):
            raise InputError(f"a camera block must be a mapping, got {type(d).__name__}")
        missing = [k for k in ("width", "height", "fx", "fy", "cx", "cy", "dist") if k not in d]
        if missing:
            raise InputError(f"camera block lacks {', '.join(missing)}")
        if d["dist"] is None:
            raise InputError("camera dist must be a list of numbers, got None")
        return cls(d["width"], d["height"], d["fx"], d["fy"], d["cx"], d["cy"], d["dist"], d.get("lens", DEFAULT_LENS))


def _is_number(v: Any) -> bool:
    """A real number that is not a boolean (``True`` is an int in Python, and no camera value)."""
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def _finite(v: Any) -> bool:
    """A number that is finite as a float (an integer too large for a float is not: ``float`` would raise)."""
    try:
        return bool(np.isfinite(float(v)))
    except OverflowError:
        return False


def transform(points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """Board points into the camera frame: ``R(rvec) @ X + tvec``.

    Parameters
    ----------
    points : ndarray
        (N, 3) board coordinates, mm.
    rvec : ndarray
        (3,) axis-angle rotation, rad.
    tvec : ndarray
        (3,) translation, mm.

    Returns
    -------
    ndarray
        (N, 3) camera-frame points, mm.
    """
    R = rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))
    Xc: np.ndarray = np.asarray(points, dtype=np.float64) @ R.T + np.asarray(tvec, dtype=np.float64).reshape(3)
    return Xc


def _is_pinhole(lens: str) -> bool:
    return lens_model(lens).pinhole


def project_camera_jacobian(
    Xc: np.ndarray, params: np.ndarray, lens: str = DEFAULT_LENS
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera-frame points -> pixels, with derivatives: the projection of :func:`project` after the pose.

    Parameters
    ----------
    Xc : ndarray
        (N, 3) camera-frame points, mm.
    params : ndarray
        (4 + n_dist,) intrinsics in :func:`param_names` order (:attr:`Camera.intrinsics`) of ``lens``: px, then
        unitless coefficients.
    lens : str
        A :data:`LENS_MODELS` name (default ``opencv5``).

    Returns
    -------
    uv : ndarray
        (N, 2) px.
    J_intr : ndarray
        (N, 2, 4 + n_dist): d uv / d params.
    J_X : ndarray
        (N, 2, 3): d uv / d Xc, px per mm.

    Raises
    ------
    InputError
        Unknown lens model.
    ValueError
        ``params`` of the wrong length for ``lens``.
    """
    params = np.asarray(params, dtype=np.float64)
    Xc = np.asarray(Xc, dtype=np.float64)
    n = len(Xc)
    fx, fy, cx, cy = (float(v) for v in params[:4])
    Ji = np.empty((n, 2, len(params)))
    Ji[:, :, :4] = _D_UV_D_K  # d uv / d (fx, fy, cx, cy), xd and yd filled in below
    if not _is_pinhole(lens):
        JP = np.empty((n, 2, 3))
        xdn = _fisheye(Xc, check_fisheye(params[4:]), JP, Ji[:, :, 4:], (fx, fy))
        xd, yd = xdn[:, 0], xdn[:, 1]
    else:
        # every term one contiguous (n,) product written into its strided place, the focal lengths folded in
        mul = np.multiply
        iz = 1.0 / Xc[:, 2]
        x, y = Xc[:, 0] * iz, Xc[:, 1] * iz
        xd, yd, a, b, e, c = _distort_jacobian_into(x, y, check_dist(params[4:]), Ji[:, :, 4:], (fx, fy))
        # d xd / d Xc = Jx d xn / d Xc, with d xn / d Xc = [[1/z, 0, -x/z], [0, 1/z, -y/z]], Jx = [[a, b], [e, c]]
        JP = np.empty((n, 2, 3))
        for row, (jx, jy), f in ((0, (a, b), fx), (1, (e, c), fy)):
            jxz, jyz = jx * iz, jy * iz
            mul(jxz, f, out=JP[:, row, 0])
            mul(jyz, f, out=JP[:, row, 1])
            w = jxz * x
            w += jyz * y
            mul(w, -f, out=JP[:, row, 2])
    Ji[:, 0, 0] = xd
    Ji[:, 1, 1] = yd
    uv = np.empty((n, 2))
    np.multiply(xd, fx, out=uv[:, 0])
    np.multiply(yd, fy, out=uv[:, 1])
    uv[:, 0] += cx
    uv[:, 1] += cy
    return uv, Ji, JP


#: d (u, v) / d (fx, fy, cx, cy) but for its xd (row 0, col 0) and yd (row 1, col 1) entries
_D_UV_D_K = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def project_jacobian(
    points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, camera: Camera
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`project` with derivatives, for one view.

    Parameters
    ----------
    points : ndarray
        (N, 3) board coordinates, mm.
    rvec, tvec : ndarray
        (3,) the pose: rad (axis-angle) and mm.
    camera : Camera

    Returns
    -------
    uv : ndarray
        (N, 2) px.
    J_intr : ndarray
        (N, 2, 4 + n_dist) with respect to :attr:`Camera.intrinsics`.
    J_pose : ndarray
        (N, 2, 6) with respect to rvec (3) then tvec (3).
    """
    r = np.asarray(rvec, dtype=np.float64).reshape(3)
    Y = np.asarray(points, dtype=np.float64) @ rodrigues(r).T
    uv, Ji, J_X = project_camera_jacobian(
        Y + np.asarray(tvec, dtype=np.float64).reshape(3), camera.intrinsics, camera.lens
    )
    return uv, Ji, np.concatenate([rotated_jacobian(J_X, Y) @ left_jacobian(r), J_X], axis=2)


def _distorted_normalised(P: np.ndarray, camera: Camera) -> np.ndarray:
    """Camera-frame points (N, 3) -> distorted normalised coordinates (N, 2); pinhole models: NaN for z <= 0."""
    if camera.model.pinhole:
        z = np.where(P[:, 2] > 0, P[:, 2], np.nan)
        return distort(P[:, :2] / z[:, None], camera.dist)
    return fisheye_distort(P, camera.dist)


def project_camera(P: np.ndarray, camera: Camera) -> np.ndarray:
    """Camera-frame points or rays -> pixels.

    Parameters
    ----------
    P : ndarray
        (N, 3) camera-frame points (mm) or ray directions.
    camera : Camera

    Returns
    -------
    ndarray
        (N, 2) px. Pinhole models: NaN for points at or behind the camera (z <= 0); fisheye: any direction (theta
        = atan2(|xy|, z) up to pi; NaN only straight behind).
    """
    P = np.asarray(P, dtype=np.float64)
    return normalized_to_pixel(_distorted_normalised(P, camera), camera)


def project(
    points: np.ndarray,
    rvec: np.ndarray,
    tvec: np.ndarray,
    camera: Camera,
) -> np.ndarray:
    """Project board points into the image (OpenCV's pixel convention).

    Equals ``cv2.projectPoints(points, rvec, tvec, camera.K, camera.dist)`` for the pinhole models and
    ``cv2.fisheye.projectPoints`` for ``fisheye`` (points in front of the camera; see :func:`project_camera`).

    Parameters
    ----------
    points : ndarray
        (N, 3) board coordinates, mm.
    rvec : ndarray
        (3,) axis-angle rotation board -> camera, rad.
    tvec : ndarray
        (3,) translation, mm.
    camera : Camera

    Returns
    -------
    ndarray
        (N, 2) px. Pinhole models divide by z whatever its sign, as OpenCV does.

    Examples
    --------
    >>> cam = Camera(640, 480, 500.0, 500.0, 319.5, 239.5)
    >>> project(np.array([[0.0, 0.0, 0.0]]), np.zeros(3), np.array([0.0, 0.0, 100.0]), cam)
    array([[319.5, 239.5]])
    """
    Xc = transform(points, rvec, tvec)
    if camera.model.pinhole:  # OpenCV divides by z whatever its sign
        return normalized_to_pixel(distort(Xc[:, :2] / Xc[:, 2:3], camera.dist), camera)
    return normalized_to_pixel(fisheye_distort(Xc, camera.dist), camera)


def unproject(uv: np.ndarray, camera: Camera) -> np.ndarray:
    """Pixels -> rays.

    Parameters
    ----------
    uv : ndarray
        (N, 2) px.
    camera : Camera

    Returns
    -------
    ndarray
        (N, 3). Pinhole models: z = 1 (undistorted normalised coordinates), NaN where the distortion has no unique
        inverse (see :func:`undistort`). Fisheye: unit-norm rays (theta up to pi, z < 0 beyond 90 deg), NaN beyond
        the lens's one-to-one field (:func:`theta_max`).
    """
    xd = pixel_to_normalized(uv, camera)
    if not camera.model.pinhole:
        return fisheye_rays(xd, camera.dist)
    xn = undistort(xd, camera.dist)
    return np.concatenate([xn, np.ones(xn.shape[:-1] + (1,))], axis=-1)


def pixel_to_normalized(uv: np.ndarray, camera: Camera) -> np.ndarray:
    """Pixels -> *distorted* normalised coordinates (K^-1 only).

    Parameters
    ----------
    uv : ndarray
        (..., 2) px.
    camera : Camera

    Returns
    -------
    ndarray
        (..., 2) unitless.
    """
    uv = np.asarray(uv, dtype=np.float64)
    return np.stack([(uv[..., 0] - camera.cx) / camera.fx, (uv[..., 1] - camera.cy) / camera.fy], axis=-1)


def normalized_to_pixel(xn: np.ndarray, camera: Camera) -> np.ndarray:
    """Normalised coordinates -> pixels (K only).

    Parameters
    ----------
    xn : ndarray
        (..., 2) unitless.
    camera : Camera

    Returns
    -------
    ndarray
        (..., 2) px.
    """
    xn = np.asarray(xn, dtype=np.float64)
    return np.stack([xn[..., 0] * camera.fx + camera.cx, xn[..., 1] * camera.fy + camera.cy], axis=-1)


def undistort_pixels(uv: np.ndarray, camera: Camera) -> np.ndarray:
    """Distorted pixels -> ideal pinhole pixels with the same K (distortion removed).

    Parameters
    ----------
    uv : ndarray
        (..., 2) px.
    camera : Camera

    Returns
    -------
    ndarray
        (..., 2) px; NaN where the inverse does not exist. For the fisheye the perspective image exists only in
        front of the camera: NaN for rays at or beyond 90 deg.
    """
    if camera.model.pinhole:
        return normalized_to_pixel(undistort(pixel_to_normalized(uv, camera), camera.dist), camera)
    rays = unproject(uv, camera)
    z = np.where(rays[..., 2] > 0, rays[..., 2], np.nan)
    return normalized_to_pixel(rays[..., :2] / z[..., None], camera)


def distort_pixels(uv: np.ndarray, camera: Camera) -> np.ndarray:
    """Ideal pinhole pixels -> distorted pixels: the inverse of :func:`undistort_pixels`.

    Parameters
    ----------
    uv : ndarray
        (..., 2) px.
    camera : Camera

    Returns
    -------
    ndarray
        (..., 2) px.
    """
    xn = pixel_to_normalized(uv, camera)
    if camera.model.pinhole:
        return normalized_to_pixel(distort(xn, camera.dist), camera)
    shape = xn.shape
    rays = np.concatenate([xn.reshape(-1, 2), np.ones((xn.size // 2, 1))], axis=1)
    return normalized_to_pixel(fisheye_distort(rays, camera.dist), camera).reshape(shape)
