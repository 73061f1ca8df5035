"""Calibrating a rig: images (or observations) of one board from 2..N cameras in, a :class:`RigCalibration` out.

:func:`calibrate_rig` runs circcal's single-camera pipeline per camera (:func:`circcal.pipeline.calibrate_images`:
detection, calibration, centre re-correction), starts the rig from those calibrations (:mod:`circcal.rig.start`),
solves every camera's intrinsics, every camera's pose in the rig and one board pose per instant jointly
(:mod:`circcal.rig.solve`), then re-corrects each camera's centres under its joint model and solves again until no
centre moves more than ``tol_px``. :func:`calibrate_rig_points` is the same on given observations. Instants are
matched by image file name across cameras (the same name = the same instant; :mod:`circcal.rig.instants`); a view
seen by some cameras only, or partly, is used. Conventions: :mod:`circcal.rig.model`.

Errors are reported per point as OpenCV does: the RMS of the 2-D reprojection error's norm (``rms_px``), px.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from circcal import detector as det_mod
from circcal.board import Board
from circcal.errors import CalibrationError, InputError
from circcal.formats import read_camera
from circcal.imagefiles import image_list
from circcal.model import Camera, project_camera
from circcal.observations import MIN_VIEWS, check_image_size, check_observations
from circcal.pipeline import MAX_ROUNDS, ImagesCalibration, TooFewImagesError, calibrate_images
from circcal.progress import progress_bar
from circcal.rig.held import (
    LocatedImages,
    check_given_names,
    given_cameras,
    held_cameras,
    is_held,
    locate_held_camera,
)
from circcal.rig.instants import rig_instants
from circcal.rig.model import RigModel
from circcal.rig.problem import CameraObservations, RigProblem, free_intrinsics
from circcal.rig.solve import RigSolution, solve_rig, weakest_direction
from circcal.rig.start import (
    BoardSymmetry,
    RigStart,
    board_symmetries,
    camera_starts,
    given_camera_starts,
    rig_start,
    spanning_tree,
)
from circcal.rotation import rodrigues, rotation_log
from circcal.solver import CalibrationOptions
from circcal.solver.lensfield import pole_in_field
from circcal.solver.options import ASPECT_RATIO
from circcal.solver.zhang import homographies

__all__ = ["RigCalibration", "calibrate_rig", "calibrate_rig_points", "lens_poles", "Views"]

#: Per camera, per instant name: object points (N, 3) mm and image points (N, 2) px.
Views = Mapping[str, Mapping[str, tuple[np.ndarray, np.ndarray]]]


@dataclass
class RigCalibration:
    """Outcome of :func:`calibrate_rig` / :func:`calibrate_rig_points`.

    Attributes
    ----------
    rig : RigModel
        The cameras and their poses in the rig, with the covariance of ``rig.state_vector()`` and ``rig.rms_px``
        (RMS over every camera's points of the 2-D reprojection error's norm, OpenCV's convention).
    rms_px : dict of str to float
        Per camera the RMS per point (2-D norm, OpenCV's convention), px.
    instants : dict of str to list of str
        Per camera the instants (image names) in the joint solve.
    dropped : list of dict
        Views left out: ``{"camera", "instant", "reason"}`` (an inconsistent view, an unresolved board symmetry).
    relabelled : list of dict
        Views whose points were relabelled by a board symmetry to agree with the other cameras at that instant:
        ``{"camera", "instant", "symmetry"}``.
    board_poses : dict of str to (ndarray (3,), ndarray (3,))
        Per instant the board pose in the rig frame: ``X_0 = R(rvec) P + tvec`` (rad, mm).
    residuals : dict of str to dict of str to ndarray
        Per camera, per instant observed - projected (N, 2) px.
    sigma_px : float
        The per-coordinate noise estimate sqrt(SSR / (2N - n)) that scales the covariance, px.
    iterations : int
        Jacobian evaluations of the last joint solve.
    converged : bool
    start : RigStart
        The start (pairwise estimates, spanning tree).
    rounds : list of dict
        Per joint solve ``{"round", "rms_px", "max_centre_shift_px"}`` (images only).
    per_camera : dict of str to ImagesCalibration or LocatedImages
        Each camera's own calibration (images only); a camera whose intrinsics were given and held:
        :class:`circcal.rig.held.LocatedImages` (its images searched and corrected under them, not calibrated alone).
    images : dict of str to dict of str to str
        Per camera, per instant its image file (images only; :mod:`circcal.rig.instants` named the instants).
    observations : dict of str to dict of str to (ndarray (N, 3), ndarray (N, 2))
        Per camera, per instant the views of the last joint solve: object points (mm, relabelled by the board
        symmetry found) and image points (px, the final re-corrected centres): what
        :func:`calibrate_rig_points` takes to recalibrate a subset of the instants (``board=None``).
    undetermined : list of (str, str)
        Where the rig has no covariance (its information is singular): the (camera, parameter) pairs that carry the
        weakest direction (:func:`circcal.rig.solve.weakest_direction`), e.g. ``("right", "k4")``.
    placed : dict of str to list of str
        Per camera the instants whose view its detector refused as an ambiguous part of a board without markers and
        the rig placed (the part near where the other cameras put the board; images only).
    """

    rig: RigModel
    rms_px: dict[str, float]
    instants: dict[str, list[str]]
    dropped: list[dict[str, str]]
    relabelled: list[dict[str, str]]
    board_poses: dict[str, tuple[np.ndarray, np.ndarray]]
    residuals: dict[str, dict[str, np.ndarray]]
    sigma_px: float
    iterations: int
    converged: bool
    start: RigStart
    rounds: list[dict[str, Any]] = field(default_factory=list)
    per_camera: dict[str, ImagesCalibration | LocatedImages] = field(default_factory=dict)
    images: dict[str, dict[str, str]] = field(default_factory=dict)
    observations: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] = field(default_factory=dict)
    undetermined: list[tuple[str, str]] = field(default_factory=list)
    placed: dict[str, list[str]] = field(default_factory=dict)

    def std(self) -> np.ndarray:
        """Standard deviations of ``rig.state_vector()`` (intrinsics px / unitless, rvec rad, tvec mm).

        Returns
        -------
        ndarray, shape (n_state,)
            NaN where the covariance is not known.
        """
        if self.rig.covariance is None:
            n = sum(len(c.intrinsics) for c in self.rig.cameras) + 6 * (self.rig.n_cameras - 1)
            return np.full(n, np.nan)
        return np.sqrt(np.maximum(np.diag(self.rig.covariance), 0.0))


def _per_camera_options(
    names: Sequence[str], options: CalibrationOptions | Mapping[str, CalibrationOptions] | None
) -> list[CalibrationOptions]:
    """One checked CalibrationOptions per camera (InputError naming the camera and the option)."""
    if options is None or isinstance(options, CalibrationOptions):
        per = [options or CalibrationOptions()] * len(names)
    else:
        unknown = [k for k in options if k not in names]
        if unknown:
            raise InputError(f"options for unknown camera(s) {unknown}; the cameras are {list(names)}")
        per = [options.get(n, CalibrationOptions()) for n in names]
    for n, o in zip(names, per):
        if not isinstance(o, CalibrationOptions):
            raise InputError(f"camera {n!r}: options must be a CalibrationOptions, got {type(o).__name__}")
        if o.refine_board:
            raise InputError(f"camera {n!r}: refine_board is not supported in a rig calibration")
        if o.outlier_rule is not None:
            raise InputError(f"camera {n!r}: outlier_rule is not supported in a rig calibration yet")
        if o.solver != "schur":
            raise InputError(f"camera {n!r}: a rig is solved by the 'schur' solver only, got solver={o.solver!r}")
    return per


def _check_names(names: Sequence[str]) -> None:
    if len(names) < 2:
        raise InputError(f"a rig needs at least two cameras, got {len(names)}")
    if len(set(names)) != len(names) or any(not isinstance(n, str) or not n for n in names):
        raise InputError(f"rig camera names must be distinct non-empty strings, got {list(names)}")


def calibrate_rig_points(
    observations: Views,
    image_sizes: Mapping[str, tuple[int, int]],
    options: CalibrationOptions | Mapping[str, CalibrationOptions] | None = None,
    *,
    board: Board | None = None,
    initial: RigCalibration | Mapping[str, Camera | str | os.PathLike[str]] | None = None,
) -> RigCalibration:
    """Calibrate a rig from given observations.

    Parameters
    ----------
    observations : mapping of str to mapping of str to (ndarray (N, 3), ndarray (N, 2))
        Per camera (the first is the reference), per instant name its object points (mm, z = 0) and image points
        (px, OpenCV's convention); views may be partial, and an instant may be seen by some cameras only.
    image_sizes : mapping of str to (int, int)
        Per camera (width, height) px.
    options : CalibrationOptions, mapping of str to CalibrationOptions, or None
        How each camera is modelled (lens model, held parameters); one for all or one per camera name (missing
        ones: the defaults). ``refine_board``, ``outlier_rule`` and the scipy solver are refused.
    board : Board or None
        The board, to resolve its symmetry across cameras (:mod:`circcal.rig.start`); None: labellings are taken
        as given.
    initial : RigCalibration, mapping of str to Camera or path, or None
        Where the joint solve starts instead of each camera calibrated alone. A calibration of the same cameras (the
        same lens models) whose instants include every one given: its cameras and board poses (a subset of the
        instants, e.g. the halves of :func:`circcal.rig.crossval.cross_validate_rig`, too few for a camera alone).
        Or each camera's intrinsics by name (of its image size and lens model; e.g. from its own calibration on more
        views), a Camera or a model file (any format :func:`circcal.formats.read_camera` reads): every view's board
        pose from :func:`circcal.solver.pose_start`, the intrinsics refined with the rig as ``cv2.stereoCalibrate``
        does with ``CALIB_USE_INTRINSIC_GUESS`` (``options``' ``fixed`` holds them).

    Returns
    -------
    RigCalibration

    Raises
    ------
    InputError
        Fewer than two cameras, bad observations (named by camera and instant), a size missing, bad options, an
        ``initial`` of other cameras (names, lens models, image sizes) or without an instant given.
    CalibrationError
        A camera's own calibration fails, a camera linked to the reference by no shared instant, a camera left
        with fewer than 3 views, or a diverged joint solve.
    """
    names = list(observations)
    _check_names(names)
    opts = _per_camera_options(names, options)
    missing = [n for n in names if n not in image_sizes]
    if missing:
        raise InputError(f"image_sizes has no size for camera(s) {missing}")
    sizes = [check_image_size(image_sizes[n]) for n in names]
    given = (
        None if initial is None or isinstance(initial, RigCalibration) else given_cameras(initial, names, sizes, opts)
    )
    start = dict(zip(initial.rig.names, initial.rig.cameras)) if isinstance(initial, RigCalibration) else given
    held = held_cameras(names, opts, start or {})
    views: list[dict[str, tuple[np.ndarray, np.ndarray]]] = []
    for n, size in zip(names, sizes):
        keys = [str(k) for k in observations[n]]
        try:
            obj, img, _ = check_observations(
                [observations[n][k][0] for k in keys],
                [observations[n][k][1] for k in keys],
                size,
                view_names=keys,
                min_views=1 if n in held else MIN_VIEWS,
            )
        except InputError as exc:
            raise InputError(f"camera {n!r}: {str(exc).splitlines()[0]}") from None
        _refuse_degenerate(n, keys, obj, img)
        views.append(dict(zip(keys, zip(obj, img))))
    if initial is None:
        cameras, poses = camera_starts(names, views, sizes, opts)
    elif isinstance(initial, RigCalibration):
        cameras, poses = _initial_starts(initial, names, views, opts)
    else:
        assert given is not None
        cameras, poses = given_camera_starts(names, [given[n] for n in names], views)
    return _calibrate(names, views, opts, board, cameras, poses)[2]


def _refuse_degenerate(name: str, keys: list[str], obj: list[np.ndarray], img: list[np.ndarray]) -> None:
    """Refuse camera ``name``'s views whose points fit no plane homography (collinear or coincident), named by
    instant (the single-camera solver names them by index)."""
    try:
        homographies([o[:, :2] for o in obj], img)
    except CalibrationError:
        bad = []
        for k, o, p in zip(keys, obj, img):
            try:
                homographies([o[:, :2]], [p])
            except CalibrationError:
                bad.append(k)
        raise InputError(
            f"camera {name!r}: view(s) {bad[:10]}{'...' if len(bad) > 10 else ''}: their image (or board) points are "
            f"collinear or coincident (no plane homography fits them); remove them or fix their points"
        ) from None


def lens_poles(result: RigCalibration) -> dict[str, str]:
    """Per camera whose fitted rational lens has a pole, or nearly one, in the field its views observed, what to tell
    the user (:func:`circcal.solver.lensfield.pole_in_field`).

    Parameters
    ----------
    result : RigCalibration

    Returns
    -------
    dict of str to str
        Camera name -> the sentence; empty when every lens is a lens over its observed field.
    """
    out = {}
    for c, n in enumerate(result.rig.names):
        Xc = []
        for v, (obj, _) in result.observations[n].items():
            R, t = _board_in_camera(result.rig, result.board_poses[v], c)
            Xc.append(obj @ R.T + t)
        why = pole_in_field(result.rig.cameras[c], np.concatenate(Xc)) if Xc else None
        if why:
            out[n] = why
    return out


def _initial_starts(
    initial: RigCalibration,
    names: list[str],
    views: list[dict[str, tuple[np.ndarray, np.ndarray]]],
    opts: list[CalibrationOptions],
) -> tuple[list[Camera], list[dict[str, tuple[np.ndarray, np.ndarray]]]]:
    """The cameras and per-camera board poses of ``initial`` (:func:`camera_starts`' form) for ``views``."""
    rig = initial.rig
    if list(rig.names) != names or any(c.lens != o.lens for c, o in zip(rig.cameras, opts)):
        raise InputError(
            f"initial: a rig of cameras {list(rig.names)} ({', '.join(c.lens for c in rig.cameras)}), not of "
            f"{names} ({', '.join(o.lens for o in opts)})"
        )
    poses = []
    for c, vs in enumerate(views):
        missing = [v for v in vs if v not in initial.board_poses]
        if missing:
            raise InputError(f"initial: no board pose of instant(s) {missing[:5]} of camera {names[c]!r}")
        poses.append({v: _board_in_camera(rig, initial.board_poses[v], c) for v in vs})
    return list(rig.cameras), poses


def _board_in_camera(rig: RigModel, board_pose: tuple[np.ndarray, np.ndarray], c: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera ``c``'s board pose ``(R, t)`` (``X_c = R P + t``, mm) from an instant's board pose in the rig frame
    (``rvec, tvec``: ``X_0 = R(rvec) P + tvec``) and the camera's pose in the rig."""
    Rc, Tc = rig.pose(c)
    return Rc @ rodrigues(board_pose[0]), Rc @ board_pose[1] + Tc


def _calibrate(
    names: list[str],
    views: list[dict[str, tuple[np.ndarray, np.ndarray]]],
    opts: list[CalibrationOptions],
    board: Board | None,
    cameras: list[Camera],
    poses: list[dict[str, tuple[np.ndarray, np.ndarray]]],
) -> tuple[_Layout, RigSolution, RigCalibration]:
    """The start and the joint solve from per-camera calibrations."""
    start = rig_start(names, cameras, poses, views, board_symmetries(board))
    need = [1 if is_held(c, o) else MIN_VIEWS for c, o in zip(cameras, opts)]  # a held camera: its pose only
    layout = _Layout(names, views, start, need)
    prob = layout.problem(views, cameras, opts)
    x0 = prob.pack(
        [c.intrinsics for c in cameras],
        rotation_log(start.rig_R),
        start.rig_T,
        rotation_log(np.array([start.board_R[v] for v in layout.instants])),
        np.array([start.board_t[v] for v in layout.instants]),
    )
    sol = solve_rig(prob, x0, max(o.max_iterations for o in opts))
    return layout, sol, layout.result(prob, sol, cameras)


class _Layout:
    """Which views the joint solve uses (after the start's drops), with their labels, and the problem over them."""

    def __init__(
        self,
        names: list[str],
        views: list[dict[str, tuple[np.ndarray, np.ndarray]]],
        start: RigStart,
        need: list[int],
    ):
        self.names, self.start = names, start
        gone = {(c, v) for c, v, _ in start.dropped}
        self.kept = [[v for v in views[c] if (c, v) not in gone and (c, v) in start.labels] for c in range(len(names))]
        for c, kept in enumerate(self.kept):
            if len(kept) < need[c]:
                why = "; ".join(f"{v}: {r}" for cc, v, r in start.dropped if cc == c)
                raise CalibrationError(
                    f"camera {names[c]!r} keeps {len(kept)} view(s) for the rig, at least {need[c]} are needed"
                    + (f" (left out: {why})" if why else "")
                )
        # every camera must still be linked to the reference through kept shared instants
        sets = [set(k) for k in self.kept]
        spanning_tree(
            names, {(a, b): len(sets[a] & sets[b]) for a in range(len(names)) for b in range(a + 1, len(names))}
        )
        self.instants = list(dict.fromkeys(v for k in self.kept for v in k))
        self.index = {v: i for i, v in enumerate(self.instants)}

    def label(self, c: int, v: str) -> BoardSymmetry:
        return self.start.labels[(c, v)]

    def problem(
        self,
        views: list[dict[str, tuple[np.ndarray, np.ndarray]]],
        cameras: list[Camera],
        opts: list[CalibrationOptions],
    ) -> RigProblem:
        obs, free, maps = [], [], []
        self.observed = {
            n: {v: (self.label(c, v).apply(views[c][v][0]), views[c][v][1]) for v in self.kept[c]}
            for c, n in enumerate(self.names)
        }
        for c, cam in enumerate(cameras):
            obs.append(
                CameraObservations.stack([(self.index[v], *self.observed[self.names[c]][v]) for v in self.kept[c]])
            )
            aspect = cam.fx / cam.fy if ASPECT_RATIO in opts[c].fixed else None
            f, m = free_intrinsics(cam.model.param_names, opts[c].fixed, aspect)
            free.append(f)
            maps.append(m)
        self.order = [[v for v in sorted(self.kept[c], key=self.index.__getitem__)] for c in range(len(cameras))]
        self.counts = [[len(views[c][v][0]) for v in self.order[c]] for c in range(len(cameras))]
        return RigProblem(
            obs, len(self.instants), [c.intrinsics for c in cameras], [c.lens for c in cameras], free, maps
        )

    def weakest(self, params: list[tuple[int, str]]) -> str:
        """Where a solve that did not converge crawls: the parameters of the information's weakest direction."""
        per: dict[str, list[str]] = {}
        for c, p in params:
            per.setdefault(self.names[c], []).append(p)
        if not per:
            return ""
        where = "; ".join(f"{', '.join(ps)} of camera {n!r}" for n, ps in per.items())
        return (
            f" along what its views determine least ({where}): fewer lens coefficients for that camera, views that "
            "reach its image's corners, or more iterations (max_iterations)"
        )

    def result(self, prob: RigProblem, sol: RigSolution, cameras: list[Camera]) -> RigCalibration:
        if not sol.converged:
            warnings.warn(
                f"the rig solve did not converge ({sol.message}); the rig may be inaccurate"
                + self.weakest(weakest_direction(prob, sol.x)),
                RuntimeWarning,
                stacklevel=3,
            )
        rv, tv = prob.rig_poses(sol.x)
        cams = [
            Camera.from_intrinsics(c.width, c.height, prob.intrinsics(sol.x, k), c.lens) for k, c in enumerate(cameras)
        ]
        res = -sol.residuals
        rows = prob.camera_rows()
        per_cam = {n: float(np.sqrt(np.mean(np.sum(res[r] ** 2, axis=1)))) for n, r in zip(self.names, rows)}
        residuals: dict[str, dict[str, np.ndarray]] = {}
        for c, (n, r) in enumerate(zip(self.names, rows)):
            parts = np.split(res[r], np.cumsum(self.counts[c])[:-1])
            residuals[n] = dict(zip(self.order[c], parts))
        brv, btv = prob.board_poses(sol.x)
        rig = RigModel(
            self.names,
            cams,
            rv,
            tv,
            sol.covariance,
            float(np.sqrt(np.mean(np.sum(res**2, axis=1)))),
        )
        return RigCalibration(
            rig=rig,
            rms_px=per_cam,
            instants={n: list(self.order[c]) for c, n in enumerate(self.names)},
            dropped=[{"camera": self.names[c], "instant": v, "reason": r} for c, v, r in self.start.dropped],
            relabelled=[
                {"camera": self.names[c], "instant": v, "symmetry": s.label}
                for (c, v), s in self.start.labels.items()
                if s.label != "rot0" and v in self.index and v in self.kept[c]
            ],
            board_poses={v: (brv[i].copy(), btv[i].copy()) for v, i in self.index.items()},
            residuals=residuals,
            sigma_px=sol.sigma_px,
            iterations=sol.iterations,
            converged=sol.converged,
            start=self.start,
            observations=self.observed,
            undetermined=[(self.names[k], p) for k, p in sol.undetermined],
        )


def _rig_placed_views(
    result: RigCalibration,
    per_camera: dict[str, ImagesCalibration | LocatedImages],
    instant: dict[str, dict[str, str]],
    board: Board,
    instants: set[str],
) -> dict[str, dict[str, Any]]:
    """Views a camera's detector refused as an ambiguous part of an unmarked board, found again where the rig
    expects the board at that instant: per camera, instant -> its detection.

    A part of a board without markers fits several places on it; at an instant another camera saw, the rig's
    solution projects every board point into this camera, and the detector labels the part by the place near it
    (:func:`circcal.detector.locate.labels.nearest_labelling`, its 1/4-spacing and 3x rules), or refuses it again.
    """
    rig = result.rig
    P = board.object_points()
    out: dict[str, dict[str, Any]] = {}
    for c, n in enumerate(rig.names):
        cal = per_camera[n]
        cam = rig.cameras[c]
        for i, det in enumerate(cal.detections):
            v = instant[n].get(cal.paths[i])
            if det.found or det.code != det_mod.Reason.AMBIGUOUS_VIEW or v not in instants:
                continue
            R, t = _board_in_camera(rig, result.board_poses[v], c)
            Xc = P @ R.T + t
            expected = np.where((Xc[:, 2] > 0)[:, None], project_camera(Xc, cam), np.nan)
            image = det_mod.read_image(Path(cal.paths[i]))
            if image is None:
                continue
            again = det_mod.detect(image, board, cam, expected=expected)
            if again.found:
                out.setdefault(n, {})[v] = again
    return out


def calibrate_rig(
    images: Mapping[str, str | os.PathLike[str] | Iterable[str | os.PathLike[str]]],
    board: Board,
    options: CalibrationOptions | Mapping[str, CalibrationOptions] | None = None,
    *,
    progress: bool | None = None,
    jobs: int | None = None,
    max_rounds: int = MAX_ROUNDS,
    tol_px: float = 1e-4,
    initial: Mapping[str, Camera | str | os.PathLike[str]] | None = None,
) -> RigCalibration:
    """Calibrate a rig from images: each camera through circcal's pipeline, then the joint solve with the detector's
    re-correction loop per camera.

    Parameters
    ----------
    images : mapping of str to path or iterable of paths
        Per camera (the first is the reference) its image files: a list, a generator such as ``Path.glob``, or a
        folder standing for its images (:func:`circcal.imagefiles.image_list`). The same file name in two cameras is
        the same instant (where no file name links the cameras, the same name between each camera's prefix and
        suffix: ``left01.png``, ``right01.png``; ``0001/left.png``, ``0001/right.png``; :mod:`circcal.rig.instants`).
        Instants are named so in the result.
    board : Board
    options : CalibrationOptions, mapping of str to CalibrationOptions, or None
        As :func:`calibrate_rig_points`.
    progress : bool or None
        Show the detector's progress bars and the joint solve's (one step per re-correction round).
    jobs : int or None
        Images detected at once (:func:`circcal.detector.detect_files`).
    max_rounds, tol_px
        The joint re-correction loop's limits: joint solves at most, and the largest centre shift (px) at which it
        has settled.
    initial : mapping of str to Camera or path, or None
        Some cameras' intrinsics by name (of their image size and lens model), a Camera or a model file: the joint
        solve starts those cameras from them (and ``options``' ``fixed`` holds them: every parameter name is
        ``cv2.stereoCalibrate``'s ``CALIB_FIX_INTRINSIC``). A camera held so is not calibrated alone: its board is
        searched and its centres corrected under the given intrinsics (:func:`circcal.rig.held.locate_images`), and
        one view another camera shares is enough for it. A camera started from them but not held still goes through
        its own pipeline, which finds and corrects its centres.

    Returns
    -------
    RigCalibration
        With ``per_camera`` (each camera's own :class:`~circcal.pipeline.ImagesCalibration`, or a held camera's
        :class:`~circcal.rig.held.LocatedImages`; its images left out in ``failed``) and ``rounds``.

    Raises
    ------
    InputError
        Fewer than two cameras, a camera without images, one file name twice in one camera, bad options.
    CalibrationError
        As :func:`calibrate_rig_points`, and (:class:`circcal.pipeline.TooFewImagesError`) a camera whose board is
        found in fewer than 3 images (named; a held camera: in none).
    """
    images = {n: image_list(ps, f"camera {n!r}") for n, ps in images.items()}  # a generator is read once here
    names = list(images)
    _check_names(names)
    opts = _per_camera_options(names, options)
    instant = rig_instants(images).of  # refuses two images of one instant, naming both
    if initial is not None:  # model files read before the work (their errors name them)
        check_given_names(initial, names, every=False)
        initial = {n: read_camera(os.fspath(c)) if isinstance(c, (str, os.PathLike)) else c for n, c in initial.items()}
    given_names = set() if initial is None else set(map(str, initial))
    per_camera: dict[str, ImagesCalibration | LocatedImages] = {}
    for n, o in zip(names, opts):
        paths = images[n]
        if not paths:
            raise InputError(f"camera {n!r}: no images given")
        if initial is not None and n in initial and is_held(initial[n], o):
            per_camera[n] = locate_held_camera(n, paths, board, initial[n], o, progress=bool(progress), jobs=jobs)
            continue
        own = replace(o, fixed=()) if n in given_names else o
        try:
            per_camera[n] = calibrate_images(paths, board, own, progress=bool(progress), jobs=jobs)
        except TooFewImagesError as exc:
            raise TooFewImagesError(
                f"camera {n!r}: {str(exc).splitlines()[0]}; or hold its intrinsics, calibrated on more views "
                f"(calibrate-rig's --intrinsics {n}=MODEL_FILE, calibrate_rig's initial=): then one view another "
                f"camera shares is enough",
                exc.rejected,
            ) from exc
        except CalibrationError as exc:
            raise CalibrationError(f"camera {n!r}: {str(exc).splitlines()[0]}") from exc
    board_pts = board.object_points()
    dets: list[dict[str, Any]] = []
    centres: list[dict[str, np.ndarray]] = []
    for n in names:
        cal = per_camera[n]
        dets.append({instant[n][cal.paths[i]]: cal.detections[i] for i in cal.used})
        centres.append({instant[n][cal.paths[i]]: c for i, c in zip(cal.used, cal.centres)})

    def views_of(cs: list[dict[str, np.ndarray]]) -> list[dict[str, tuple[np.ndarray, np.ndarray]]]:
        out = []
        for per in cs:
            vs = {}
            for v, c in per.items():
                ok = np.all(np.isfinite(c), axis=1)
                vs[v] = (board_pts[ok], c[ok])
            out.append(vs)
        return out

    cameras, poses = [], []
    for n, cal in per_camera.items():  # a held camera's poses: from its given intrinsics, below
        own = not isinstance(cal, LocatedImages)
        cameras.append(cal.result.camera if own else cal.camera)
        rt = zip(cal.used, cal.result.rvecs, cal.result.tvecs) if own else []
        poses.append({instant[n][cal.paths[i]]: (rodrigues(rv), tv.copy()) for i, rv, tv in rt})
    views = views_of(centres)
    if initial is not None:
        sizes = [(c.width, c.height) for c in cameras]
        given = given_cameras(initial, names, sizes, opts, every=False)
        for c, n in enumerate(names):
            if n in given:
                cameras[c] = given[n]
                poses[c] = given_camera_starts([n], [given[n]], [views[c]])[1][0]
    with progress_bar(max_rounds, "rig joint solve", "round", bool(progress)) as bar:
        layout, sol, result = _calibrate(names, views, opts, board, cameras, poses)
        found = _rig_placed_views(result, per_camera, instant, board, set(layout.instants))
        for c, n in enumerate(names):  # each placed view with its board pose in its own labelling, as the others'
            for v, det in list(found.get(n, {}).items()):
                view = views_of([{v: np.asarray(det.centres, np.float64)}])[0]
                try:
                    poses[c].update(given_camera_starts([n], [cameras[c]], [view])[1][0])
                except CalibrationError:  # no pose fits it: not a part of this board after all
                    del found[n][v]
                    continue
                dets[c][v], centres[c][v] = det, np.asarray(det.centres, np.float64)
        if any(found.values()):  # parts of the board the rig placed: the joint solve again with them
            views = views_of(centres)
            layout, sol, result = _calibrate(names, views, opts, board, cameras, poses)
        bar.update()
        max_it = max(o.max_iterations for o in opts)
        rounds: list[dict[str, Any]] = []
        rounds.append({"round": 0, "rms_px": result.rig.rms_px, "max_centre_shift_px": float("nan")})
        for r in range(1, max_rounds):
            bar.update()
            shift = 0.0
            new_centres = []
            for c in range(len(names)):
                cam = result.rig.cameras[c]
                per: dict[str, np.ndarray] = {}
                for v in layout.kept[c]:
                    old = centres[c][v]
                    new = np.asarray(det_mod.recorrect(dets[c][v], board, cam), dtype=np.float64)
                    new = np.where(np.isfinite(old) & np.isfinite(new), new, old)  # the same points every round
                    shift = max(shift, float(np.nanmax(np.linalg.norm(new - old, axis=1))))
                    per[v] = new
                new_centres.append({**centres[c], **per})
            views = views_of(new_centres)
            prob = layout.problem(views, list(result.rig.cameras), opts)
            try:
                sol = solve_rig(prob, sol.x, max_it)
            except CalibrationError as exc:
                warnings.warn(
                    f"rig centre re-correction stopped after round {r - 1}, whose rig is kept: {exc}",
                    RuntimeWarning,
                    stacklevel=2,
                )
                break
            centres = new_centres
            result = layout.result(prob, sol, cameras)
            rounds.append({"round": r, "rms_px": result.rig.rms_px, "max_centre_shift_px": shift})
            if shift < tol_px:
                bar.update(max_rounds - 1 - r)  # converged: the rounds left are not needed
                break
    result.rounds = rounds
    result.placed = {n: sorted(v for v in vs if v in result.instants[n]) for n, vs in found.items() if vs}
    result.per_camera = per_camera
    result.images = {n: {v: p for p, v in instant[n].items()} for n in names}
    return result
