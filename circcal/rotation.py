"""Rotations as axis-angle vectors (OpenCV's ``rvec``): the matrix, its derivative, and the best rotation between
two point sets.

Convention: ``R(rvec)`` is Rodrigues' formula, ``rvec`` in radians (its direction the axis, its length the angle),
as ``cv2.Rodrigues``. Derivatives perturb a rotation on the left: ``R(r + dr) = Exp(J_l(r) dr) R(r)`` to first
order, with :func:`left_jacobian` ``J_l``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "rodrigues",
    "skew",
    "rotation_angle_deg",
    "rotation_log",
    "left_jacobian",
    "rotated_jacobian",
    "fit_rotation",
]

#: Below this squared angle (rad^2) the closed forms switch to their Taylor series (the division by t^2 loses
#: precision there; the series terms kept are exact to double precision).
_SMALL_ANGLE2_ROTATION = 1e-16
_SMALL_ANGLE2_JACOBIAN = 1e-10


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]x`` (``[v]x w = v x w``).

    Parameters
    ----------
    v : ndarray, shape (..., 3)

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    v = np.asarray(v, dtype=np.float64)
    K = np.zeros(v.shape[:-1] + (3, 3))  # six entries written in place (four nested np.stack calls cost ~3x)
    K[..., 0, 1] = -v[..., 2]
    K[..., 0, 2] = v[..., 1]
    K[..., 1, 0] = v[..., 2]
    K[..., 1, 2] = -v[..., 0]
    K[..., 2, 0] = -v[..., 1]
    K[..., 2, 1] = v[..., 0]
    return K


def rodrigues(rvec: np.ndarray) -> np.ndarray:
    """Rotation matrices from axis-angle vectors. Exact (series form) for tiny angles. Equals ``cv2.Rodrigues``.

    Parameters
    ----------
    rvec : ndarray, shape (..., 3)
        rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)

    Examples
    --------
    >>> np.round(rodrigues(np.array([0.0, 0.0, np.pi / 2])) @ [1.0, 0.0, 0.0], 12) + 0.0
    array([0., 1., 0.])
    """
    r = np.asarray(rvec, dtype=np.float64)
    theta2 = np.sum(r * r, axis=-1)[..., None, None]
    small = theta2 < _SMALL_ANGLE2_ROTATION
    tiny = bool(small.any())  # the series (and its np.where) only where an angle needs it
    safe = np.where(small, 1.0, np.sqrt(theta2)) if tiny else np.sqrt(theta2)
    a = np.sin(safe) / safe
    b = (1.0 - np.cos(safe)) / (safe * safe)
    if tiny:
        a = np.where(small, 1.0 - theta2 / 6.0, a)
        b = np.where(small, 0.5 - theta2 / 24.0, b)
    kx = skew(r)
    eye = np.broadcast_to(np.eye(3), kx.shape)
    return eye + a * kx + b * (kx @ kx)


def _axial_angle(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The axial vector ``2 sin(t) axis`` (..., 3) and the angle ``t`` (...) rad of rotation matrices, the angle by
    ``atan2`` (exact to rounding near 0 and near pi)."""
    m = np.asarray(R, dtype=np.float64)
    axial = np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], axis=-1)
    cos2 = np.trace(m, axis1=-2, axis2=-1) - 1.0  # 2 cos t
    return axial, np.arctan2(np.linalg.norm(axial, axis=-1), cos2)


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Rotation angles of matrices, precise at every angle.

    ``arccos((trace - 1) / 2)`` cannot tell angles below ~1e-6 deg from zero in double precision (1 - cos t is
    t^2 / 2); the angle here is ``atan2(|axial vector|, (trace - 1) / 2)``, exact to rounding near 0 and near 180 deg.

    Parameters
    ----------
    R : ndarray, shape (..., 3, 3)
        Rotation matrices.

    Returns
    -------
    ndarray, shape (...)
        deg, in [0, 180].

    Examples
    --------
    >>> float(rotation_angle_deg(rodrigues(np.radians([0.0, 1e-9, 0.0]))))  # doctest: +ELLIPSIS
    1e-09...
    """
    return np.degrees(_axial_angle(R)[1])


#: Beyond this angle (rad) the axial vector (2 sin t) no longer fixes the axis to double precision:
#: :func:`rotation_log` takes the axis from the symmetric part, ``(R + R^T) / 2 - cos t I = (1 - cos t) a a^T``.
_LOG_AXIAL_MAX = np.radians(170.0)


def rotation_log(R: np.ndarray) -> np.ndarray:
    """Axis-angle vectors of rotation matrices: the inverse of :func:`rodrigues`, batched (``cv2.Rodrigues`` one
    matrix at a time costs ~10 us of call overhead each), precise at every angle.

    Parameters
    ----------
    R : ndarray, shape (..., 3, 3)
        Rotation matrices.

    Returns
    -------
    ndarray, shape (..., 3)
        rad, angle in [0, pi].

    Examples
    --------
    >>> np.round(rotation_log(rodrigues(np.array([0.1, -0.2, 0.3]))), 12) + 0.0
    array([ 0.1, -0.2,  0.3])
    """
    axial, t = _axial_angle(R)
    s = np.sin(t)
    scale = np.where(t < 1e-8, 0.5 + t * t / 12.0, t / (2.0 * np.where(s > 0, s, 1.0)))
    out: np.ndarray = axial * scale[..., None]
    wide = t > _LOG_AXIAL_MAX
    if np.any(wide):
        m = np.asarray(R, dtype=np.float64)[wide]
        tw = t[wide]
        cos = np.cos(tw)[:, None, None]
        aa = (0.5 * (m + np.swapaxes(m, -1, -2)) - cos * np.eye(3)) / (1.0 - cos)  # a a^T
        k = np.argmax(np.diagonal(aa, axis1=-2, axis2=-1), axis=-1)
        a = aa[np.arange(len(aa)), :, k]  # the column of the largest diagonal: a_k a
        a /= np.linalg.norm(a, axis=-1, keepdims=True)
        a[np.sum(a * axial[wide], axis=-1) < 0] *= -1.0  # the axis along sin(t) a (either at a half turn)
        out[wide] = a * tw[:, None]
    return out


def left_jacobian(rvec: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3) at an axis-angle vector.

    ``J_l = I + (1 - cos t)/t^2 [r]x + (t - sin t)/t^3 [r]x^2`` (series form near t = 0).

    Parameters
    ----------
    rvec : ndarray, shape (..., 3)
        rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    r = np.asarray(rvec, dtype=np.float64)
    t2 = np.sum(r * r, axis=-1)[..., None, None]
    small = t2 < _SMALL_ANGLE2_JACOBIAN
    tiny = bool(small.any())
    safe = np.where(small, 1.0, np.sqrt(t2)) if tiny else np.sqrt(t2)
    a = (1.0 - np.cos(safe)) / (safe * safe)
    b = (safe - np.sin(safe)) / (safe * safe * safe)
    if tiny:
        a = np.where(small, 0.5 - t2 / 24.0, a)
        b = np.where(small, 1.0 / 6.0 - t2 / 120.0, b)
    K = skew(r)
    return np.eye(3) + a * K + b * (K @ K)


def rotated_jacobian(J_Y: np.ndarray, Y: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``J_Y (-[Y]x)``: the derivative of a function of the rotated points ``Y = R X`` with respect to a left
    perturbation of the rotation, given its derivative ``J_Y`` with respect to ``Y``.

    Row j is ``Y x J_Y[:, j]``. Times :func:`left_jacobian` of the rotation's rvec it is the derivative with respect
    to rvec.

    Parameters
    ----------
    J_Y : ndarray, shape (N, k, 3)
    Y : ndarray, shape (N, 3)
    out : ndarray, shape (N, k, 3), optional
        Written in place and returned (a view into a larger array of rows may be given); not ``J_Y`` itself.

    Returns
    -------
    ndarray, shape (N, k, 3)
    """
    y0, y1, y2 = Y[:, 0], Y[:, 1], Y[:, 2]
    if out is None:
        out = np.empty_like(J_Y)
    for j in range(J_Y.shape[1]):  # per row j, (N,) products: broadcasting over the small k axis runs ~1.7x slower
        a0, a1, a2 = J_Y[:, j, 0], J_Y[:, j, 1], J_Y[:, j, 2]
        np.subtract(y1 * a2, y2 * a1, out=out[:, j, 0])
        np.subtract(y2 * a0, y0 * a2, out=out[:, j, 1])
        np.subtract(y0 * a1, y1 * a0, out=out[:, j, 2])
    return out


def fit_rotation(A: np.ndarray, B: np.ndarray, *, translation: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid alignment ``B ~ R A + t`` of point sets (Kabsch, through scipy's ``Rotation.align_vectors``).

    Parameters
    ----------
    A, B : ndarray, shape (N, 3)
    translation : bool
        Without it the points are not centred (aligning directions: rotation only) and t = 0.

    Returns
    -------
    R : ndarray, shape (3, 3)
    t : ndarray, shape (3,)
        In the points' unit.
    """
    from scipy.spatial.transform import Rotation

    A = np.asarray(A, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)
    ca = A.mean(axis=0) if translation else np.zeros(3)
    cb = B.mean(axis=0) if translation else np.zeros(3)
    rot, _ = Rotation.align_vectors(B - cb, A - ca)
    R = rot.as_matrix()
    return R, cb - R @ ca
