"""A rig without covariance in words: the parameters its views leave free, and what to do.

The joint solve's information matrix (board poses marginalised) is singular when the views cannot separate some
combination of parameters: most often a rich lens model's coefficients trading off (a rational camera whose
numerator and denominator move together over the field its views cover), or poses and focal lengths that nearly
fronto-parallel views cannot tell apart. :func:`circcal.rig.solve.weakest_direction` names them; this says it.

The other parameters are still determined: :func:`determined_rig_covariance` rebuilds the last joint solve's
problem from a :class:`~circcal.rig.RigCalibration` and gives their marginal covariance
(:func:`circcal.rig.solve.determined_covariance`), NaN only for the parameters with a component in the null space.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from circcal.rig.problem import CameraObservations, RigProblem, free_intrinsics
from circcal.rig.solve import determined_covariance
from circcal.solver.options import ASPECT_RATIO, CalibrationOptions

__all__ = ["undetermined_lines", "determined_rig_covariance"]

#: The intrinsics that are not a lens model's distortion coefficients.
_PINHOLE = ("fx", "fy", "cx", "cy")


def undetermined_lines(undetermined: Sequence[tuple[str, str]]) -> list[str]:
    """What a rig without covariance means, and what to do: per camera the parameters its views leave free.

    Parameters
    ----------
    undetermined : sequence of (str, str)
        (camera, parameter) pairs of the information's weakest direction; empty where none could be named.

    Returns
    -------
    list of str
    """
    per: dict[str, list[str]] = {}
    for cam, p in undetermined:
        per.setdefault(cam, []).append(p)
    out = [
        "no stated uncertainty: the rig's information matrix is singular (the views leave a combination of "
        + ("; ".join(f"{', '.join(ps)} of camera {c!r}" for c, ps in per.items()) or "its parameters")
        + " free)"
    ]
    lens_only = [c for c, ps in per.items() if all(p not in _PINHOLE and p not in ("rvec", "tvec") for p in ps)]
    if lens_only and len(lens_only) == len(per):
        out.append(
            f"what to do: camera(s) {', '.join(lens_only)}: fit a lens model with fewer coefficients (--lens "
            f"{lens_only[0]}=opencv5), or add views that reach the corners and edges of its image"
        )
    else:
        out.append(
            "what to do: add views (tilted by 20-40 deg, at several distances, filling each image, and shared "
            "between the cameras), or hold what the views cannot separate"
        )
    return out


def determined_rig_covariance(
    calibration: Any, options: CalibrationOptions | Mapping[str, CalibrationOptions] | None
) -> np.ndarray | None:
    """The covariance of ``calibration.rig.state_vector()``: the rig's own where it has one (the same array), else
    the marginal covariance of what its views determine, NaN for the parameters they leave free (see the module).

    Parameters
    ----------
    calibration : circcal.rig.RigCalibration
        With its ``observations``, ``board_poses`` and ``sigma_px`` (the last joint solve's).
    options : CalibrationOptions or mapping of str to CalibrationOptions or None
        What the joint solve held (one for every camera, or per camera name as :func:`circcal.rig.calibrate_rig`
        took them; a camera not named: nothing held). None: the holds are not known, and a rig without covariance
        has none (every sigma unknown).

    Returns
    -------
    ndarray or None
        (n_state, n_state) in ``RigModel.state_vector`` order; None without a covariance and without ``options``, or
        where the information is not finite.
    """
    rig = calibration.rig
    if rig.covariance is not None:
        return np.asarray(rig.covariance)
    if options is None:
        return None
    observed = calibration.observations
    instants = [v for v in calibration.board_poses if any(v in observed.get(n, {}) for n in rig.names)]
    index = {v: i for i, v in enumerate(instants)}  # the solve's order: board_poses keeps it
    obs, free, maps = [], [], []
    for name, cam in zip(rig.names, rig.cameras):
        opts = options if isinstance(options, CalibrationOptions) else options.get(name, CalibrationOptions())
        views = observed.get(name, {})
        obs.append(CameraObservations.stack([(index[v], *views[v]) for v in views if v in index]))
        aspect = cam.fx / cam.fy if ASPECT_RATIO in opts.fixed else None
        f, m = free_intrinsics(cam.model.param_names, opts.fixed, aspect)
        free.append(f)
        maps.append(m)
    intrinsics = [np.asarray(c.intrinsics, dtype=np.float64) for c in rig.cameras]
    prob = RigProblem(obs, len(instants), intrinsics, [c.lens for c in rig.cameras], free, maps)
    poses = [calibration.board_poses[v] for v in instants]
    x = prob.pack(intrinsics, rig.rvecs, rig.tvecs, np.array([p[0] for p in poses]), np.array([p[1] for p in poses]))
    return determined_covariance(prob, x, float(calibration.sigma_px) ** 2)
