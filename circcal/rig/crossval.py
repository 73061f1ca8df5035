"""Cross-validation of a calibrated rig on two halves of its instants (:func:`cross_validate_rig`), the rig's form of
:mod:`circcal.analysis.cross`; the verdict built on it is :mod:`circcal.rig.verdict`.

The instants are split into two disjoint halves (:func:`split_instants`: in name order, each instant given to the
half where the cameras that see it have fewer views, so that every camera's views are halved), each half is
calibrated as a rig with the same settings (:func:`circcal.rig.calibrate_rig_points` on the full solve's final
observations, labels as they are), and the two rigs are compared against their stated uncertainties:

* **each camera's projection**: :func:`circcal.analysis.diff.model_diff` of the halves' intrinsics (at infinity,
  the implied rotation fitted, as ``mrcal-show-projection-diff``) against ``sigma_A + sigma_B`` per pixel, where each
  half's ``sigma`` is the first-order spread of exactly that difference: the projection's Jacobian over the camera's
  intrinsics with the part the fitted rotation absorbs removed (:func:`rotation_free_stdev`), under the half's
  covariance of the camera's intrinsics (the rig's, board poses and the other cameras marginalised). Consistent
  when the difference is within :data:`~circcal.analysis.diff.CONSISTENT_RATIO` x over
  :data:`~circcal.analysis.diff.CONSISTENT_SHARE` of the image (the single-camera rule); a camera whose intrinsics
  were all held (given) has nothing to compare and is named as such;
* **each camera's pose in the rig**: the rotation ``log(R_B R_A^T)`` (rad) and the translation ``T_B - T_A`` (mm)
  against the sum of the halves' 6x6 covariances (rvec mapped by SO(3)'s left Jacobian), as a Mahalanobis distance
  with 6 degrees of freedom: consistent within :data:`POSE_LIMIT` (twice the 99.9% ellipsoid's distance).

Each half's covariance is first order in its residual noise, raised to at least
:data:`~circcal.analysis.diff.NOISE_FLOOR_PX` per coordinate (a clean render's residuals are the detector's own
error, correlated within a view), as a single camera's cross-validation does.

With fewer than :data:`MIN_INSTANTS` instants (or a camera with fewer than 2 x 3 views) it says why it was not done.
Poses follow :mod:`circcal.rig.model`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal.analysis.cross import half_named, noting_warnings
from circcal.analysis.diff import CONSISTENT_RATIO, CONSISTENT_SHARE, ModelDiff, model_diff, noise_floor_factor
from circcal.errors import InputError
from circcal.model import Camera, project_camera_jacobian, unproject
from circcal.observations import MIN_VIEWS
from circcal.progress import progress_bar
from circcal.rig.calibrate import RigCalibration, calibrate_rig_points
from circcal.rig.model import RigModel
from circcal.rotation import left_jacobian, rotation_log, skew
from circcal.solver import CalibrationOptions

__all__ = [
    "MIN_INSTANTS",
    "POSE_CHI2",
    "POSE_LIMIT",
    "PoseCheck",
    "RigCrossValidation",
    "split_instants",
    "rotation_free_stdev",
    "pose_check",
    "cross_validate_rig",
]

#: Two halves of at least the solver's minimum of views each.
MIN_INSTANTS = 2 * MIN_VIEWS
#: The chi-square 99.9% point with 6 degrees of freedom (the 99.9% ellipsoid of a 6-vector of Gaussian errors) ...
POSE_CHI2 = 22.4577
#: ... a camera's pose differs between the halves when the Mahalanobis distance of (rotation, translation) exceeds
#: :data:`~circcal.analysis.diff.CONSISTENT_RATIO` times that ellipsoid's, the factor of two the projection rule allows
#: too: detection biases far below the noise (on the rendered rigs the halves' T differ by ~3x their sigma, as the
#: full rig's T differs from the truth) are not a model or data problem; a rig that moved, instants mismatched across
#: cameras or a lens model too simple reach tens of sigma.
POSE_LIMIT = CONSISTENT_RATIO * float(np.sqrt(POSE_CHI2))


def split_instants(instants: Mapping[str, Sequence[str]]) -> tuple[list[str], list[str]]:
    """Two disjoint halves of a rig's instants, every camera's views halved.

    Parameters
    ----------
    instants : mapping of str to sequence of str
        Per camera the instants (image names) it sees.

    Returns
    -------
    tuple of (list of str, list of str)
        The instants of each half, in name order: each instant, taken in name order, goes to the half where the
        cameras that see it have fewer views so far (ties: alternately).

    Examples
    --------
    >>> split_instants({"a": ["1", "2", "3", "4"], "b": ["3", "4"]})
    (['1', '4'], ['2', '3'])
    """
    sets = [set(v) for v in instants.values()]
    counts = np.zeros((2, len(sets)), dtype=int)
    halves: tuple[list[str], list[str]] = ([], [])
    for k, v in enumerate(sorted(set().union(*sets))):
        cams = [c for c, s in enumerate(sets) if v in s]
        load = counts[:, cams].sum(axis=1)
        h = k % 2 if load[0] == load[1] else int(np.argmin(load))
        counts[h, cams] += 1
        halves[h].append(v)
    return halves


def rotation_free_stdev(camera: Camera, covariance: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """First-order spread of a camera's projection at infinity with the implied rotation fitted out, as
    :func:`circcal.analysis.diff.model_diff` measures two models' difference (see the module).

    Each pixel's ray ``d`` is fixed; the difference a change ``delta`` of the intrinsics makes is
    ``G delta + J_X (w x d)`` with ``w`` the rotation that best aligns the unit rays before and after over every
    given pixel (the linearised fit of ``model_diff``); its covariance is ``G' Sigma G'^T``.

    Parameters
    ----------
    camera : Camera
    covariance : ndarray, shape (n, n)
        Of ``camera.intrinsics`` (px, unitless).
    uv : ndarray, shape (N, 2)
        Pixels, px: the grid the difference is measured on (the fit is over all of them).

    Returns
    -------
    ndarray, shape (N,)
        The worst-direction standard deviation per pixel (the 2x2 covariance's larger eigenvalue's root), px; NaN
        where the pixel has no ray.
    """
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    ray = unproject(uv, camera)
    d = ray / np.linalg.norm(ray, axis=1, keepdims=True)
    ok = np.all(np.isfinite(d), axis=1)
    out = np.full(len(uv), np.nan)
    if not ok.any():
        return out
    d = d[ok]
    _, Ji, JX = project_camera_jacobian(d, camera.intrinsics, camera.lens)
    # a tangent basis of the unit sphere at each ray, and the ray's change with the intrinsics: pi(d(theta), theta)
    # stays at uv, so J_X dd + G dtheta = 0 with dd = T a
    helper = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    T = np.stack([e1, np.cross(d, e1)], axis=2)  # (N, 3, 2)
    U = -T @ np.linalg.solve(JX @ T, Ji)  # (N, 3, p): d ray / d theta
    S = skew(d)  # w x d = -S w
    W = -np.linalg.solve(np.einsum("nji,njk->ik", S, S), np.einsum("nji,njk->ik", S, U))  # w = W delta
    G = Ji - JX @ S @ W  # (N, 2, p)
    cov2 = G @ np.asarray(covariance, dtype=np.float64) @ np.swapaxes(G, 1, 2)
    out[ok] = np.sqrt(np.maximum(np.linalg.eigvalsh(cov2)[:, -1], 0.0))
    return out


@dataclass
class PoseCheck:
    """One camera's pose in the rig as two halves found it.

    Attributes
    ----------
    camera : str
    rotation_deg : float
        The angle of ``R_B R_A^T``, deg.
    translation_mm : float
        ``|T_B - T_A|``, mm.
    rotation_sigma_deg, translation_sigma_mm : float
        Their expected sizes from the halves' covariances (the root of the summed covariance's trace), deg and mm.
    mahalanobis : float
        Of the 6-vector (rotation, translation) under the summed covariance.
    consistent : bool
        ``mahalanobis <= POSE_LIMIT``.
    """

    camera: str
    rotation_deg: float
    translation_mm: float
    rotation_sigma_deg: float
    translation_sigma_mm: float
    mahalanobis: float
    consistent: bool

    def text(self) -> str:
        """The check in words.

        Returns
        -------
        str
        """
        return (
            f"pose of {self.camera}: the halves differ by {self.rotation_deg:.3g} deg (expected ~"
            f"{self.rotation_sigma_deg:.2g}) and {self.translation_mm:.3g} mm (expected ~"
            f"{self.translation_sigma_mm:.2g}), {self.mahalanobis:.2f} sigma (Mahalanobis, 6 dof; within "
            f"{POSE_LIMIT:.2f}, twice the 99.9% ellipsoid, is consistent)"
        )


def _pose_covariance(rig: RigModel, k: int) -> np.ndarray:
    """The 6x6 covariance of camera k's (rotation as a left perturbation, translation), rad and mm."""
    n_intr = sum(len(c.intrinsics) for c in rig.cameras)
    s = n_intr + 6 * (k - 1)
    C = np.asarray(rig.covariance, dtype=np.float64)[s : s + 6, s : s + 6]
    D = np.eye(6)
    D[:3, :3] = left_jacobian(rig.rvecs[k])
    return D @ C @ D.T


def pose_check(a: RigModel, b: RigModel, k: int) -> PoseCheck:
    """Camera ``k``'s pose in two rigs of the same cameras, weighed against their covariances.

    Parameters
    ----------
    a, b : RigModel
        Two calibrations of the rig (each with its covariance).
    k : int
        A camera other than the reference (0).

    Returns
    -------
    PoseCheck

    Raises
    ------
    InputError
        ``k`` the reference or not a camera, or a rig without covariance.
    """
    if not 0 < k < a.n_cameras or a.n_cameras != b.n_cameras:
        raise InputError(f"pose check: camera {k} must be a non-reference camera of both rigs")
    if a.covariance is None or b.covariance is None:
        raise InputError("pose check: both rigs need their covariance")
    Ra, ta = a.pose(k)
    Rb, tb = b.pose(k)
    delta = np.concatenate([rotation_log(Rb @ Ra.T), tb - ta])
    C = _pose_covariance(a, k) + _pose_covariance(b, k)
    try:
        m2 = float(delta @ np.linalg.solve(C, delta))
    except np.linalg.LinAlgError:
        m2 = float("inf")
    m = float(np.sqrt(max(m2, 0.0)))
    return PoseCheck(
        a.names[k],
        float(np.degrees(np.linalg.norm(delta[:3]))),
        float(np.linalg.norm(delta[3:])),
        float(np.degrees(np.sqrt(max(np.trace(C[:3, :3]), 0.0)))),
        float(np.sqrt(max(np.trace(C[3:, 3:]), 0.0))),
        m,
        bool(m <= POSE_LIMIT),
    )


@dataclass
class RigCrossValidation:
    """The outcome of :func:`cross_validate_rig`.

    Attributes
    ----------
    status : str
        ``"ok"``, ``"too-few-instants"`` or ``"failed"`` (a half could not be calibrated).
    message : str
        In words.
    halves : tuple of (list of str, list of str)
        The instants of each half.
    rigs : list of RigCalibration
        The halves' calibrations.
    projections : dict of str to ModelDiff
        Per camera B against A with both uncertainties.
    poses : list of PoseCheck
        Per camera but the reference.
    verdict : str or None
        ``"consistent"`` or ``"model-or-data-problem"`` (None unless ok).
    notes : list of str
        What the halves' own calibrations warned of (each once, named by the half): the check's trials, not the
        rig above.
    held : list of str
        The cameras whose intrinsics were held (given): the same in both halves, not compared.
    """

    status: str
    message: str
    halves: tuple[list[str], list[str]] = ([], [])
    rigs: list[RigCalibration] = field(default_factory=list)
    projections: dict[str, ModelDiff] = field(default_factory=dict)
    poses: list[PoseCheck] = field(default_factory=list)
    verdict: str | None = None
    notes: list[str] = field(default_factory=list)
    held: list[str] = field(default_factory=list)

    def problems(self) -> list[str]:
        """One sentence per camera projection or pose the halves disagree on.

        Returns
        -------
        list of str
        """
        out = []
        for name, d in self.projections.items():
            if not d.consistent:
                where = ", ".join(f"{r} ({100 * s:.0f}%)" for r, s in d.where[:4]) or "spread over the image"
                out.append(
                    f"camera {name}: the halves' projections differ by {d.rms_px:.3g} px RMS (max {d.max_px:.3g}), "
                    f"within {CONSISTENT_RATIO:g}x their uncertainty over {100 * (d.share_within or 0):.1f}% of "
                    f"the image only (>= {100 * CONSISTENT_SHARE:g}% needed); exceeded in the {where}"
                )
        out += [p.text() for p in self.poses if not p.consistent]
        return out

    def lines(self) -> list[str]:
        """The console summary: the message, then each camera's projection and pose check.

        Returns
        -------
        list of str
        """
        out = [f"cross-validation (two halves of the instants, {len(self.halves[0])} + {len(self.halves[1])}): "]
        out[0] += self.message
        for name, d in self.projections.items():
            out.append(
                f"  projection of {name}: halves differ by {d.rms_px:.3g} px RMS (p95 {d.p95_px:.3g}, max "
                f"{d.max_px:.3g}), within {CONSISTENT_RATIO:g}x their uncertainty over "
                f"{100 * (d.share_within or 0):.1f}% of the image"
            )
        out += [f"  projection of {name}: intrinsics held (given), the same in both halves" for name in self.held]
        out += [f"  {p.text()}" for p in self.poses]
        out += [f"  (the check's own fits) {n}" for n in self.notes]
        return out

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary.

        Returns
        -------
        dict
            ``status``, ``message``, ``verdict``, ``halves``, ``projections`` (per camera
            :meth:`ModelDiff.summary`), ``poses``, ``notes``, ``held``.
        """
        return {
            "status": self.status,
            "message": self.message,
            "verdict": self.verdict,
            "halves": [list(h) for h in self.halves],
            "projections": {n: d.summary() for n, d in self.projections.items()},
            "poses": [dict(p.__dict__) for p in self.poses],
            "notes": list(self.notes),
            "held": list(self.held),
        }


def cross_validate_rig(
    cal: RigCalibration,
    options: CalibrationOptions | Mapping[str, CalibrationOptions] | None = None,
    *,
    progress: bool = False,
) -> RigCrossValidation:
    """Cross-validate a rig calibration on two halves of its instants (see the module).

    Parameters
    ----------
    cal : RigCalibration
        With its ``observations`` (:func:`circcal.rig.calibrate_rig` and :func:`~circcal.rig.calibrate_rig_points`
        keep them).
    options : CalibrationOptions, mapping of str to CalibrationOptions, or None
        The settings ``cal`` was made with (one for all cameras or one per camera name).
    progress : bool
        Show a progress bar over the two halves' solves.

    Returns
    -------
    RigCrossValidation
        ``status`` ``"too-few-instants"`` or ``"failed"`` with the reason in ``message`` when it could not be done.

    Raises
    ------
    InputError
        Bad ``options`` (as :func:`calibrate_rig_points`).
    """
    rig = cal.rig
    instants = {n: list(cal.observations.get(n, {})) for n in rig.names}
    n_all = len(set().union(*map(set, instants.values())))
    held = _held(rig)
    short = [f"{n} ({len(v)})" for n, v in instants.items() if len(v) < 2 * (1 if n in held else MIN_VIEWS)]
    if n_all < MIN_INSTANTS or short:
        return RigCrossValidation(
            "too-few-instants",
            f"not done: {n_all} instants"
            + (f", views per camera {', '.join(short)}" if short else "")
            + f"; two independent halves need at least {MIN_INSTANTS} instants and {2 * MIN_VIEWS} views of every "
            f"camera ({MIN_VIEWS} per half, the least a calibration takes; 2 of a camera whose intrinsics are held). "
            f"The rig above stands; take more views to check it",
        )
    halves = split_instants(instants)
    sizes = {n: (c.width, c.height) for n, c in zip(rig.names, rig.cameras)}
    rigs, said = [], []

    def fit(keep: set[str]) -> RigCalibration:
        obs = {n: {v: cal.observations[n][v] for v in instants[n] if v in keep} for n in rig.names}
        return calibrate_rig_points(obs, sizes, options, initial=cal)

    with progress_bar(len(halves), "rig cross-validation", "half", progress) as bar:
        for h in halves:
            who = half_named(h, "instants")
            try:
                rigs.append(noting_warnings(said, who, fit, set(h)))
            except InputError as exc:  # CalibrationError included: too few views of a camera, a disconnected one
                return RigCrossValidation(
                    "failed",
                    f"not done: the half {h[:6]}{'...' if len(h) > 6 else ''} gives no rig ({exc})",
                    halves,
                    notes=said,
                )
            bar.update()
    if rig.covariance is None and any(r.rig.covariance is None for r in rigs):
        return RigCrossValidation("failed", "not done: the information matrix is singular", halves, rigs, notes=said)
    covs, notes = [], []
    for k, r in enumerate(rigs):
        if r.rig.covariance is not None:
            covs.append(np.asarray(r.rig.covariance, dtype=np.float64) * noise_floor_factor(r.sigma_px) ** 2)
            continue
        # information adds up over the instants: a half holding a share of the points has about 1/share of the
        # full rig's covariance (a nearly degenerate lens model, e.g. rational, is singular on half the views)
        share = _points(r) / _points(cal)
        covs.append(np.asarray(rig.covariance, dtype=np.float64) * noise_floor_factor(cal.sigma_px) ** 2 / share)
        notes.append(f"{k + 1} ({100 * share:.0f}% of the points)")
    a, b = rigs[0].rig, rigs[1].rig
    a = RigModel(a.names, a.cameras, a.rvecs, a.tvecs, covs[0], a.rms_px)
    b = RigModel(b.names, b.cameras, b.rvecs, b.tvecs, covs[1], b.rms_px)
    projections, held = {}, []
    start = 0
    for name, ca, cb in zip(rig.names, a.cameras, b.cameras):
        n = len(ca.intrinsics)
        sa = covs[0][start : start + n, start : start + n]
        sb = covs[1][start : start + n, start : start + n]
        start += n
        if not np.any(sa) and not np.any(sb):  # every intrinsic held: nothing of them to compare
            held.append(name)
            continue
        projections[name] = model_diff(
            ca,
            cb,
            uncertainty_a=lambda uv, c=ca, s=sa: rotation_free_stdev(c, s, uv),
            uncertainty_b=lambda uv, c=cb, s=sb: rotation_free_stdev(c, s, uv),
        )
    poses = [pose_check(a, b, k) for k in range(1, rig.n_cameras)]
    cv = RigCrossValidation("ok", "", halves, rigs, projections, poses, notes=said, held=held)
    bad = cv.problems()
    if bad:
        cv.verdict = "model-or-data-problem"
        cv.message = "the halves disagree beyond their stated uncertainty: " + "; ".join(bad)
    else:
        cv.verdict = "consistent"
        cameras = "every camera's projection" + (f" (held, not compared: {', '.join(held)})" if held else "")
        cv.message = (
            f"consistent: {cameras} within {CONSISTENT_RATIO:g}x the halves' uncertainty over >= "
            f"{100 * CONSISTENT_SHARE:g}% of its image, and every pose within {POSE_LIMIT:.2f} sigma"
        )
    if notes:
        cv.message += (
            f" (the information matrix of half {' and '.join(notes)} is singular: its covariance is taken as the "
            f"full rig's divided by its share of the points)"
        )
    return cv


def _held(rig: RigModel) -> set[str]:
    """The cameras whose intrinsics the rig's covariance holds (every variance 0): given, not estimated."""
    if rig.covariance is None:
        return set()
    var = np.diag(np.asarray(rig.covariance, dtype=np.float64))
    out, start = set(), 0
    for name, cam in zip(rig.names, rig.cameras):
        n = len(cam.intrinsics)
        if not np.any(var[start : start + n]):
            out.add(name)
        start += n
    return out


def _points(cal: RigCalibration) -> int:
    """The observed points of a rig calibration, every camera's."""
    return sum(len(img) for per in cal.observations.values() for _, img in per.values())
