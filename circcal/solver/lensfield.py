"""Whether a fitted lens is a lens over the field its views observed: a pole, or nearly one, of the rational model.

The rational model divides by ``1 + k4 r^2 + k5 r^4 + k6 r^6`` (1 on the axis). Where the views do not determine
k1..k6 the numerator and the denominator trade off, and the fit can land where both (nearly) vanish at one radius
inside the field: the residuals stay small, but the coefficients and their first-order sigmas mean little, and where
the denominator crosses zero projection is singular and pixels around it have no inverse (NaN). Measured on 40
re-solves of the ``two`` rig's 512x384 rational camera from 0.1 px noise (the true lens's denominator >= 1): 14 fits
went to 0.008 or below inside the observed field (one of them through zero), the others stayed above 0.066.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from circcal.model import Camera, denominator_minimum
from circcal.rotation import rodrigues

__all__ = ["pole_in_field", "result_pole", "NEAR_POLE"]

#: The rational denominator's smallest value in the observed field (1 on the axis) below which a fit is called
#: degenerate: numerator and denominator cancelling 20-fold (measured in the module docstring: 0.008 or below, or
#: 0.066 and above).
NEAR_POLE = 0.05


def pole_in_field(camera: Camera, Xc: np.ndarray) -> str | None:
    """What to tell a user whose fitted rational lens has a pole, or nearly one, inside the observed field.

    Parameters
    ----------
    camera : Camera
        The fitted camera.
    Xc : ndarray, shape (N, 3)
        The observed board points in the camera's frame at the solution, mm.

    Returns
    -------
    str or None
        One sentence (the angle off the optical axis, the observed field's extent, the way out); None when the
        denominator stays above :data:`NEAR_POLE` over the observed field (always for the other lens models).

    Examples
    --------
    >>> cam = Camera(640, 480, 500.0, 500.0, 319.5, 239.5, [0.1, 0, 0, 0, 0, -4.0, 0, 0], "rational")
    >>> pole_in_field(cam, np.array([[0.4, 0.0, 1.0]])) is None  # 1 - 4 r^2 >= 0.36 out to r = 0.4
    True
    """
    front = Xc[Xc[:, 2] > 0]
    if not camera.model.pinhole or front.size == 0:
        return None
    r_max = float(np.max(np.hypot(front[:, 0], front[:, 1]) / front[:, 2]))
    den, r = denominator_minimum(camera.dist, r_max)
    if den > NEAR_POLE:
        return None
    where = (
        f"{np.degrees(np.arctan(r)):.1f} deg off the optical axis, inside the field the views observed (out to "
        f"{np.degrees(np.arctan(r_max)):.1f} deg)"
    )
    if den <= 0:
        return (
            f"the {camera.lens} lens's denominator 1 + k4 r^2 + k5 r^4 + k6 r^6 vanishes {where}: the fit is no lens "
            f"there (projection singular, pixels near that angle without an inverse); k1..k6 are not determined by "
            f"these views: fit the opencv5 lens, or add views that fill the image's corners"
        )
    return (
        f"the {camera.lens} lens's denominator 1 + k4 r^2 + k5 r^4 + k6 r^6 falls to {den:.2g} (1 on the axis) "
        f"{where}: numerator and denominator nearly cancel, k1..k6 are not determined by these views (their values "
        f"and stated sigmas mean little, though the fit may reproject well where the views were): fit the opencv5 "
        f"lens, or add views that fill the image's corners"
    )


def result_pole(result: Any) -> str | None:
    """:func:`pole_in_field` for a calibration: its camera over its own views' board points.

    Parameters
    ----------
    result : CalibrationResult
        With ``object_points`` (per view (N, 3) mm, or a refined board's ``board_points``), ``rvecs`` and ``tvecs``.

    Returns
    -------
    str or None
        As :func:`pole_in_field`; None without object points.
    """
    if not result.object_points:
        return None
    Xc = [
        np.asarray(o, dtype=np.float64).reshape(-1, 3) @ rodrigues(rv).T + tv
        for o, rv, tv in zip(result.object_points, result.rvecs, result.tvecs)
    ]
    return pole_in_field(result.camera, np.concatenate(Xc))
