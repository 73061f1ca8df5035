"""circcal's rig solver re-run on exactly what a reference rig calibrator fitted (:mod:`circcal.validators.rig_validate`'s
fair mode): the views as circcal's joint solve labelled them, OpenCV's float32 rounding, ``calibrateMultiview``'s
whole views (``stereoCalibrate``'s shared points of a pair: :func:`circcal.validators.rig.shared_pair`, which the
adapter itself uses), and the joint solve on them from circcal's rig (every intrinsic held, or none). Conventions: :mod:`circcal.rig.model`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import replace

import numpy as np

from circcal.board import Board
from circcal.model import param_names
from circcal.rig import RigModel
from circcal.rig.calibrate import RigCalibration, Views
from circcal.rig.problem import CameraObservations, RigProblem, free_intrinsics
from circcal.rig.solve import solve_rig
from circcal.rig.start import board_symmetries
from circcal.rotation import rodrigues, rotation_log
from circcal.solver.holdout import fit_pose

__all__ = ["labelled_views", "float32_views", "whole_views", "resolve", "REWEIGHT_TOL", "REWEIGHT_ROUNDS"]

#: The reweighted solve ends when no global parameter moves more than this (relative to max(1, |x|)) in a round...
REWEIGHT_TOL = 1e-12
#: ... or after this many rounds (measured: 3-5 rounds to 1e-12 at 0.02-0.5 px noise).
REWEIGHT_ROUNDS = 20


def labelled_views(rc: RigCalibration, views: Views, board: Board) -> dict[str, dict[str, tuple]]:
    """The views as circcal's joint solve used them: relabelled by the symmetry it resolved, dropped ones left out.

    Parameters
    ----------
    rc : RigCalibration
        circcal's rig calibration of ``views``.
    views : Views
        What it calibrated (per camera, per instant: object points (N, 3) mm, image points (N, 2) px).
    board : Board

    Returns
    -------
    dict of str to dict of str to (ndarray, ndarray)
        The same form.
    """
    sym = {s.label: s for s in board_symmetries(board)}
    relabel = {(r["camera"], r["instant"]): sym[r["symmetry"]] for r in rc.relabelled}
    out: dict[str, dict[str, tuple]] = {}
    for n in views:
        used = set(rc.instants[n])
        out[n] = {
            v: ((relabel[(n, v)].apply(o) if (n, v) in relabel else o), p)
            for v, (o, p) in views[n].items()
            if v in used
        }
    return out


def float32_views(views: Views) -> dict[str, dict[str, tuple]]:
    """Every coordinate rounded to float32 (OpenCV's input type), kept as float64.

    Parameters
    ----------
    views : Views

    Returns
    -------
    dict of str to dict of str to (ndarray, ndarray)
    """
    return {
        n: {v: tuple(np.asarray(a, np.float32).astype(np.float64) for a in ov) for v, ov in per.items()}
        for n, per in views.items()
    }


def whole_views(views: Views) -> dict[str, dict[str, tuple]]:
    """The views holding every board point (calibrateMultiview's: it diverges on partial ones).

    Parameters
    ----------
    views : Views

    Returns
    -------
    dict of str to dict of str to (ndarray, ndarray)
    """
    full = max(len(o) for per in views.values() for o, _ in per.values())
    return {n: {v: ov for v, ov in per.items() if len(ov[0]) == full} for n, per in views.items()}


def resolve(
    views: Views,
    rig: RigModel,
    board_poses: Mapping[str, tuple[np.ndarray, np.ndarray]],
    hold: bool,
    weight: Callable[[np.ndarray], np.ndarray] | None = None,
) -> RigModel:
    """circcal's joint solve on given views of (some of) a rig's cameras, started from that rig.

    Parameters
    ----------
    views : Views
        Per camera of ``rig`` (the same names, in its order; a prefix of its cameras may be given).
    rig : RigModel
        The start: intrinsics (held with ``hold``) and camera poses.
    board_poses : mapping of str to (ndarray (3,), ndarray (3,))
        Per instant the board pose in the rig frame (rad, mm); an instant absent here starts from a PnP.
    hold : bool
        Hold every intrinsic.
    weight : callable or None
        A reference's per-point weights from the squared reprojection errors (px^2, shape (N,)) for the
        iteratively reweighted solve it runs (each weight evaluated at the current parameters and held in the step:
        :func:`circcal.validators.rig.multiview_weights`), re-solved until the camera poses move less than
        :data:`REWEIGHT_TOL`; None: least squares.

    Returns
    -------
    RigModel
        Of the cameras of ``views``, with its covariance (the weighted problem's where weighted).
    """
    names = list(views)
    cams = [rig.cameras[rig.index(n)] for n in names]
    instants = list(dict.fromkeys(v for n in names for v in views[n]))
    index = {v: i for i, v in enumerate(instants)}
    brv, btv = _board_starts(views, rig, board_poses, instants)
    idx = [rig.index(n) for n in names]
    obs, free, maps = [], [], []
    for n, cam in zip(names, cams):
        obs.append(CameraObservations.stack([(index[v], o, p) for v, (o, p) in views[n].items()]))
        f, m = free_intrinsics(param_names(cam.lens), param_names(cam.lens) if hold else (), None)
        free.append(f)
        maps.append(m)
    intr = [c.intrinsics for c in cams]
    prob = RigProblem(obs, len(instants), intr, [c.lens for c in cams], free, maps)
    sol = solve_rig(prob, prob.pack(intr, rig.rvecs[idx], rig.tvecs[idx], brv, btv), 200)
    plain = prob
    for _ in range(REWEIGHT_ROUNDS if weight is not None else 0):
        e2 = np.sum(plain.residuals(sol.x)[0].reshape(-1, 2) ** 2, axis=1)
        obs = [replace(o, weights=weight(e2[r])) for o, r in zip(obs, plain.camera_rows())]
        prob = RigProblem(obs, len(instants), intr, [c.lens for c in cams], free, maps)
        last = sol.x[: prob.ng]
        sol = solve_rig(prob, sol.x, 200)
        if np.max(np.abs(sol.x[: prob.ng] - last) / np.maximum(1.0, np.abs(last))) < REWEIGHT_TOL:
            break
    rv, tv = prob.rig_poses(sol.x)
    out = [type(c).from_intrinsics(c.width, c.height, prob.intrinsics(sol.x, k), c.lens) for k, c in enumerate(cams)]
    return RigModel(names, out, rv, tv, sol.covariance)


def _board_starts(
    views: Views, rig: RigModel, board_poses: Mapping[str, tuple[np.ndarray, np.ndarray]], instants: list[str]
) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) rvecs and tvecs of each instant's board in the rig frame: given, else a PnP in a camera that saw it."""
    names = list(views)
    brv, btv = [], []
    for v in instants:
        if v in board_poses:
            r, t = board_poses[v]
        else:
            c = next(k for k, n in enumerate(names) if v in views[n])
            r, t = fit_pose(*views[names[c]][v], rig.cameras[rig.index(names[c])])
            Rc, Tc = rig.pose(rig.index(names[c]))
            R = Rc.T @ rodrigues(r)
            r, t = rotation_log(R[None])[0], Rc.T @ (np.asarray(t) - Tc)
        brv.append(np.asarray(r, dtype=np.float64))
        btv.append(np.asarray(t, dtype=np.float64))
    return np.array(brv), np.array(btv)
