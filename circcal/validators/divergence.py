"""When a reference's "ok" solve has diverged (:func:`check_divergence`), a rational pole inside the field
(:func:`rational_pole`) included."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from circcal.model import Camera, transform
from circcal.validators.reference_result import ReferenceResult

__all__ = ["DIVERGED_RMS_PX", "check_divergence", "rational_pole"]

#: A solve whose RMS per point exceeds this (px) is reported as diverged (status "failed").
DIVERGED_RMS_PX = 100.0


def check_divergence(res: ReferenceResult, max_rms_px: float = DIVERGED_RMS_PX) -> ReferenceResult:
    """Turn a diverged "ok" result into status "failed".

    Diverged: non-finite intrinsics or poses, an RMS per point above ``max_rms_px``, or a rational pole inside the
    field (:func:`rational_pole`). The camera is kept for inspection. The result is changed in place.

    Parameters
    ----------
    res : ReferenceResult
        Any result; one that is not ok comes back unchanged.
    max_rms_px : float
        Largest acceptable RMS per point (px).

    Returns
    -------
    ReferenceResult
        ``res`` itself.
    """
    if not res.ok:
        return res
    c = res.camera
    if c is None or not np.all(np.isfinite(c.intrinsics)):
        res.status, res.message = "failed", "diverged: non-finite intrinsics"
        return res
    for label, a in (("rvecs", res.rvecs), ("tvecs", res.tvecs)):
        if a is None or not np.all(np.isfinite(a)):
            res.status, res.message = "failed", f"diverged: non-finite {label}"
            return res
    rms = (res.errors or {}).get("rms_per_point_px", np.nan)
    if not np.isfinite(rms) or rms > max_rms_px:
        res.status, res.message = "failed", f"diverged: RMS per point {rms:.4g} px > {max_rms_px:g} px"
        return res
    pole = rational_pole(c, res.object_points, res.rvecs, res.tvecs)
    if pole:
        res.status, res.message = "failed", pole
    return res


def rational_pole(
    camera: Camera, object_points: Sequence[np.ndarray] | None, rvecs: np.ndarray | None, tvecs: np.ndarray | None
) -> str:
    """Why a rational or thin-prism solution is not a lens ("" when it is).

    Its radial denominator 1 + k4 r^2 + k5 r^4 + k6 r^6 reaches 0 between the axis and the farthest observed point
    (r: the undistorted normalised radius), a pole inside the field where OpenCV's model is undefined. Such a solution
    can fit the observations better than the lens does, numerator and denominator vanishing together, so the suite
    reports it rather than comparing it (the measurement is in docs/validation.md, "Rational poles").

    Parameters
    ----------
    camera : circcal.model.Camera
        The solution; other lens models give "".
    object_points : sequence of ndarray, shape (N_v, 3), or None
        Board points per view, mm.
    rvecs, tvecs : ndarray, shape (V, 3), or None
        Board-to-camera poses (rad; mm).

    Returns
    -------
    str
        "" for a lens (or when an input is None), else one line naming r at the pole and k4, k5, k6.
    """
    if camera.lens not in ("rational", "thin-prism") or object_points is None or rvecs is None or tvecs is None:
        return ""
    d = dict(zip(camera.model.dist_names, np.asarray(camera.dist, dtype=np.float64)))
    k4, k5, k6 = d["k4"], d["k5"], d["k6"]
    r2 = [
        np.sum((X[:, :2] / X[:, 2:3]) ** 2, axis=1)
        for X in (transform(np.asarray(o, dtype=np.float64), r, t) for o, r, t in zip(object_points, rvecs, tvecs))
    ]
    r2max = float(np.max(np.concatenate(r2))) if r2 else 0.0
    s = np.linspace(0.0, r2max, 2001)
    den = 1.0 + k4 * s + k5 * s**2 + k6 * s**3
    if np.all(den > 0):
        return ""
    at = float(np.sqrt(s[np.argmax(den <= 0)]))
    return (
        f"not a lens: the rational denominator 1 + k4 r^2 + k5 r^4 + k6 r^6 reaches 0 at r = {at:.3g} inside "
        f"the observed field (r up to {np.sqrt(r2max):.3g}; k4 {k4:.4g}, k5 {k5:.4g}, k6 {k6:.4g}): a pole "
        "where OpenCV's model is undefined"
    )
