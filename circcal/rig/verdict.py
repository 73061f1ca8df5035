"""Is a calibrated rig right? The verdict in words (:func:`rig_verdict`): the cross-validation on two halves of the
instants (:mod:`circcal.rig.crossval`), outlier views per camera, the coverage of each camera's image and of the
field two cameras share, cameras at one point and lens poles in the observed field.

The rig is **consistent** when every camera's projection and every pose agree between the halves and no view is an
outlier; otherwise a **model or data problem**, said per camera with what to do. An outlier view
(:func:`view_outliers`) is one whose residual RMS per point exceeds :data:`OUTLIER_RATIO` times that camera's median
over its views. Where the cross-validation cannot be done (too few instants) it says why and the rig stands.

Errors per point are OpenCV's convention (the RMS of the 2-D norm); poses follow :mod:`circcal.rig.model`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal.analysis.coverage import Coverage, coverage
from circcal.analysis.remedy import RICHER_LENS
from circcal.rig.calibrate import RigCalibration, lens_poles
from circcal.rig.coincident import CoincidentCameras, coincident_cameras
from circcal.rig.crossval import (
    MIN_INSTANTS,
    POSE_CHI2,
    POSE_LIMIT,
    PoseCheck,
    RigCrossValidation,
    cross_validate_rig,
    pose_check,
    rotation_free_stdev,
    split_instants,
)
from circcal.rig.undetermined import undetermined_lines
from circcal.solver import CalibrationOptions

__all__ = [
    "MIN_INSTANTS",
    "OUTLIER_RATIO",
    "POSE_CHI2",
    "POSE_LIMIT",
    "PoseCheck",
    "ViewOutlier",
    "RigCrossValidation",
    "RigVerdict",
    "split_instants",
    "rotation_free_stdev",
    "pose_check",
    "view_outliers",
    "camera_coverage",
    "shared_coverage",
    "cross_validate_rig",
    "rig_verdict",
]

#: A view whose residual RMS per point exceeds this many times its camera's median over its views is an outlier (a
#: view with its points' noise alone stays within ~1.5x on views of 12 points or more).
OUTLIER_RATIO = 3.0


@dataclass
class ViewOutlier:
    """A view whose residuals are far above its camera's others.

    Attributes
    ----------
    camera, instant : str
    rms_px : float
        Its RMS per point (2-D norm, OpenCV's convention), px.
    median_px : float
        The camera's median of that over its views, px.
    ratio : float
    """

    camera: str
    instant: str
    rms_px: float
    median_px: float
    ratio: float

    def text(self) -> str:
        """The outlier in words.

        Returns
        -------
        str
        """
        return (
            f"{self.camera} {self.instant}: RMS per point {self.rms_px:.3g} px, {self.ratio:.1f}x that camera's "
            f"median {self.median_px:.3g} px"
        )


def view_outliers(cal: RigCalibration, ratio: float = OUTLIER_RATIO) -> list[ViewOutlier]:
    """Views whose residual RMS per point exceeds ``ratio`` times their camera's median over its views.

    Parameters
    ----------
    cal : RigCalibration
    ratio : float

    Returns
    -------
    list of ViewOutlier
        Per camera, worst first.
    """
    out = []
    for name, per in cal.residuals.items():
        rms = {v: float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) for v, r in per.items() if len(r)}
        if not rms:
            continue
        med = float(np.median(list(rms.values())))
        bad = [ViewOutlier(name, v, e, med, e / med) for v, e in rms.items() if med > 0 and e > ratio * med]
        out += sorted(bad, key=lambda o: -o.ratio)
    return out


def camera_coverage(cal: RigCalibration) -> dict[str, Coverage]:
    """Each camera's coverage of its own image by the points of the joint solve.

    Parameters
    ----------
    cal : RigCalibration

    Returns
    -------
    dict of str to Coverage
        :func:`circcal.analysis.coverage.coverage` per camera.
    """
    out = {}
    for name, cam in zip(cal.rig.names, cal.rig.cameras):
        pts = [img for _, img in cal.observations.get(name, {}).values()]
        out[name] = coverage(pts, cam.width, cam.height)
    return out


def shared_coverage(cal: RigCalibration, i: int = 0, j: int = 1) -> tuple[Coverage, Coverage]:
    """The coverage of the field cameras ``i`` and ``j`` share: in each one's image, the board points the other
    camera observed at the same instant.

    Parameters
    ----------
    cal : RigCalibration
    i, j : int
        Two cameras of the rig.

    Returns
    -------
    tuple of Coverage
        In camera ``i``'s image and in camera ``j``'s.
    """
    names, cams = cal.rig.names, cal.rig.cameras
    obs_i, obs_j = cal.observations.get(names[i], {}), cal.observations.get(names[j], {})
    pts_i, pts_j = [], []
    for v in sorted(set(obs_i) & set(obs_j)):
        (Pi, qi), (Pj, qj) = obs_i[v], obs_j[v]
        ki = {tuple(np.round(p, 6)): n for n, p in enumerate(Pi)}
        pairs = [(ki[key], m) for m, p in enumerate(Pj) if (key := tuple(np.round(p, 6))) in ki]
        if pairs:
            a, b = np.array(pairs).T
            pts_i.append(qi[a])
            pts_j.append(qj[b])
    return (
        coverage(pts_i, cams[i].width, cams[i].height),
        coverage(pts_j, cams[j].width, cams[j].height),
    )


@dataclass
class RigVerdict:
    """Whether a rig calibration can be trusted, and what to do.

    Attributes
    ----------
    verdict : str
        ``"consistent"`` (cross-validated, no outlier view), ``"model-or-data-problem"``, or ``"not-checked"``
        (the cross-validation skipped or not possible, no outlier view).
    cross : RigCrossValidation or None
        None when skipped.
    outliers : list of ViewOutlier
    lens_poles : dict of str to str
        Per camera whose fitted rational lens has a pole, or nearly one, in its observed field, what to tell the user
        (:func:`circcal.rig.calibrate.lens_poles`).
    coincident : list of CoincidentCameras
        Cameras at one point (:func:`coincident_cameras`); those given the same images make the verdict a data
        problem.
    undetermined : list of (str, str)
        Where the rig has no covariance (its information is singular, a model problem): the (camera, parameter)
        pairs of the weakest direction (:attr:`circcal.rig.calibrate.RigCalibration.undetermined`).
    """

    verdict: str
    cross: RigCrossValidation | None
    outliers: list[ViewOutlier]
    lens_poles: dict[str, str] = field(default_factory=dict)
    coincident: list[CoincidentCameras] = field(default_factory=list)
    undetermined: list[tuple[str, str]] | None = None

    def lines(self) -> list[str]:
        """The verdict first, then what to do.

        Returns
        -------
        list of str
        """
        out = []
        if self.verdict == "consistent":
            out.append(
                "verdict: consistent: two halves of the instants give the same rig within its stated uncertainty, "
                "and no view is an outlier"
            )
        elif self.verdict == "not-checked":
            why = "skipped (--no-cross-validate)" if self.cross is None else self.cross.message
            out.append(f"verdict: not cross-validated: {why}; no view is an outlier")
            if self.cross is not None:
                out += [f"  (the check's own fits) {n}" for n in self.cross.notes]
        else:
            out.append("verdict: a model or data problem")
        if self.cross is not None and self.cross.verdict == "model-or-data-problem":
            out += [f"  {p}" for p in self.cross.problems()]
            proj = [n for n, d in self.cross.projections.items() if not d.consistent]
            lenses = dict(zip(self.cross.rigs[0].rig.names, (c.lens for c in self.cross.rigs[0].rig.cameras)))
            for name in proj:
                lens = lenses.get(name, "")
                richer = RICHER_LENS.get(lens)
                model = (
                    f"a lens model too simple for the lens (try --lens {name}={richer}, or fisheye for a wide lens), "
                    if richer
                    else f"the {lens} lens model unlike the lens, "
                    if lens
                    else "a lens model unlike the lens, "
                )
                out.append(
                    f"  what to do: camera {name!r}: {model}biased centres, or a board unlike the one given (pitch, "
                    f"flatness)"
                )
            if any(not p.consistent for p in self.cross.poses):
                out.append(
                    "  what to do: the cameras moved against each other during the capture, or one file name does "
                    "not name the same instant in every camera: check the capture, and that the images of one "
                    "instant share their name"
                )
        if self.outliers:
            out.append(f"  {len(self.outliers)} outlier view(s) (RMS above {OUTLIER_RATIO:g}x the camera's median):")
            out += [f"    {o.text()}" for o in self.outliers]
            out.append(
                "  what to do: look at these images (blur, a board partly hidden, a wrong detection) and leave them "
                "out of that camera's images"
            )
        out += [f"  camera {n!r}: {why}" for n, why in self.lens_poles.items()]
        out += [f"  {line}" for c in self.coincident for line in c.lines()]
        if self.undetermined is not None:
            out += [f"  {line}" for line in undetermined_lines(self.undetermined)]
        return out

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary.

        Returns
        -------
        dict
            ``verdict``, ``cross_validation`` (or None), ``outliers``, ``lens_poles``, ``coincident``,
            ``undetermined`` (None where the rig has its covariance).
        """
        return {
            "verdict": self.verdict,
            "cross_validation": None if self.cross is None else self.cross.to_dict(),
            "outliers": [dict(o.__dict__) for o in self.outliers],
            "lens_poles": dict(self.lens_poles),
            "coincident": [dict(c.__dict__) for c in self.coincident],
            "undetermined": None if self.undetermined is None else [list(u) for u in self.undetermined],
        }


def rig_verdict(
    cal: RigCalibration,
    options: CalibrationOptions | Mapping[str, CalibrationOptions] | None = None,
    *,
    cross_validate: bool = True,
    progress: bool = False,
) -> RigVerdict:
    """The verdict on a rig calibration: cross-validation (:func:`cross_validate_rig`), outlier views, any lens
    with a pole in its observed field (:func:`circcal.rig.calibrate.lens_poles`) and cameras at one point
    (:func:`coincident_cameras`).

    Parameters
    ----------
    cal : RigCalibration
    options : CalibrationOptions, mapping of str to CalibrationOptions, or None
        The settings ``cal`` was made with.
    cross_validate : bool
        False: skip the cross-validation (the verdict is then at best ``"not-checked"``).
    progress : bool
        Show the cross-validation's progress bar.

    Returns
    -------
    RigVerdict

    Raises
    ------
    InputError
        Bad ``options``.
    """
    cross = cross_validate_rig(cal, options, progress=progress) if cross_validate else None
    outliers = view_outliers(cal)
    coincident = coincident_cameras(cal)
    undetermined = list(cal.undetermined) if cal.rig.covariance is None else None
    problem = bool(outliers) or undetermined is not None or any(c.same_points for c in coincident)
    if problem or (cross is not None and cross.verdict == "model-or-data-problem"):
        verdict = "model-or-data-problem"
    elif cross is not None and cross.verdict == "consistent":
        verdict = "consistent"
    else:
        verdict = "not-checked"
    return RigVerdict(verdict, cross, outliers, lens_poles(cal), coincident, undetermined)
