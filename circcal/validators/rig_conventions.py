"""Which rig convention a calibrator under test used, when its rig misses the truth: R, T inverted (the camera's
pose in the reference frame instead of the reference's in the camera's), T in metres or centimetres instead of
millimetres, or both (issue 37: R/T conventions inverted between tools are a recurring pain of rig users).

circcal's convention (:mod:`circcal.rig.model`): camera 0 the reference, ``X_i = R_i X_0 + T_i``, T in mm.
"""

from __future__ import annotations

import numpy as np

from circcal.rig.model import RigModel
from circcal.rotation import rotation_angle_deg

__all__ = ["MATCH_DEG", "MATCH_REL", "convention_hint"]

#: A candidate reading matches the truth when every camera's rotation is within this (deg) ...
MATCH_DEG = 1.0
#: ... and its translation within this share of the truth's baseline.
MATCH_REL = 0.05

_UNITS = {"mm": 1.0, "m": 1000.0, "cm": 10.0}


def _matches(poses: list[tuple[np.ndarray, np.ndarray]], truth: RigModel) -> bool:
    for c, (R, T) in enumerate(poses, start=1):
        Rt, Tt = truth.pose(c)
        if rotation_angle_deg(R @ Rt.T) > MATCH_DEG or np.linalg.norm(T - Tt) > MATCH_REL * np.linalg.norm(Tt):
            return False
    return True


def convention_hint(rig: RigModel, truth: RigModel) -> str | None:
    """The convention under which ``rig``'s camera poses match ``truth``'s where they do not as given.

    Parameters
    ----------
    rig : RigModel
        A calibrator's rig, read in circcal's convention.
    truth : RigModel
        Of the same cameras.

    Returns
    -------
    str or None
        What the calibrator did and what circcal expects, in one sentence; None when the rig matches as given (its
        failure is elsewhere) or under no candidate reading.

    Examples
    --------
    >>> hint = convention_hint(users_rig, truth)  # doctest: +SKIP
    """
    given = [rig.pose(c) for c in range(1, rig.n_cameras)]
    if rig.n_cameras != truth.n_cameras or rig.n_cameras < 2 or _matches(given, truth):
        return None
    for inverted in (False, True):
        for unit, scale in _UNITS.items():
            if not inverted and unit == "mm":
                continue
            poses = [(R.T, -R.T @ T) if inverted else (R, T) for R, T in given]
            if _matches([(R, T * scale) for R, T in poses], truth):
                what = []
                if inverted:
                    what.append("R, T inverted (each camera's pose in the reference camera's frame, X_0 = R X_i + T)")
                if unit != "mm":
                    what.append(f"T in {unit}")
                return (
                    f"the rig matches the truth read with {' and '.join(what)}: circcal's convention is "
                    f"X_i = R_i X_0 + T_i with T in mm (OpenCV's stereo R, T), camera 0 the reference"
                )
    return None
