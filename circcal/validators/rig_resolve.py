"""circcal's rig solver re-run on exactly what a reference rig calibrator fitted (:mod:`circcal.validators.rig_validate`'s
fair mode): the views as circcal's joint solve labelled them, OpenCV's float32 rounding, ``calibrateMultiview``'s
whole views (``stereoCalibrate``'s shared points of a pair: :func:`circcal.validators.rig.shared_pair`, which the
adapter itself uses), and the joint solve on them from circcal's rig (every intrinsic held, or none). Conventions: :mod:`circcal.rig.model`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from circcal.board import Board
from circcal.model import param_names
from circcal.rig import RigModel
from circcal.rig.calibrate import RigCalibration, Views
from circcal.rig.problem import CameraObservations, RigProblem, free_intrinsics
from circcal.rig.solve import solve_rig
from circcal.rig.start import board_symmetries
from circcal.rotation import rodrigues
from circcal.solver.holdout import fit_pose

__all__ = ["labelled_views", "float32_views", "whole_views", "resolve"]


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
    views: Views, rig: RigModel, board_poses: Mapping[str, tuple[np.ndarray, np.ndarray]], hold: bool
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

    Returns
    -------
    RigModel
        Of the cameras of ``views``, with its covariance.
    """
    names = list(views)
    cams = [rig.cameras[rig.index(n)] for n in names]
    instants = list(dict.fromkeys(v for n in names for v in views[n]))
    index = {v: i for i, v in enumerate(instants)}
    brv, btv = _board_starts(views, rig, board_poses, instants)
    idx = [rig.index(n) for n in names]
    if hold:
        # circcal.rig.problem cannot take a reference camera with every intrinsic held (no global column: numpy
        # refuses the reshape of its empty Jacobian), so the held problem is solved here with scipy's least squares
        return _resolve_held(views, rig, idx, instants, brv, btv)
    obs, free, maps = [], [], []
    for n, cam in zip(names, cams):
        obs.append(CameraObservations.stack([(index[v], o, p) for v, (o, p) in views[n].items()]))
        f, m = free_intrinsics(param_names(cam.lens), param_names(cam.lens) if hold else (), None)
        free.append(f)
        maps.append(m)
    prob = RigProblem(obs, len(instants), [c.intrinsics for c in cams], [c.lens for c in cams], free, maps)
    x0 = prob.pack([c.intrinsics for c in cams], rig.rvecs[idx], rig.tvecs[idx], brv, btv)
    sol = solve_rig(prob, x0, 200)
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
            r, t = _rotvec(R), Rc.T @ (np.asarray(t) - Tc)
        brv.append(np.asarray(r, dtype=np.float64))
        btv.append(np.asarray(t, dtype=np.float64))
    return np.array(brv), np.array(btv)


def _resolve_held(
    views: Views, rig: RigModel, idx: list[int], instants: list[str], brv: np.ndarray, btv: np.ndarray
) -> RigModel:
    """The camera poses (but the first's) and board poses of ``views`` with every intrinsic held at ``rig``'s:
    Gauss-Newton with per-view central-difference Jacobians (each view depends on its board pose and its camera's
    pose only), until the step is below 1e-12 of the parameters."""
    from circcal.model import project

    names = list(views)
    cams = [rig.cameras[i] for i in idx]
    nc, nv = len(names), len(instants)
    blocks = [(c, instants.index(v), o, p) for c, n in enumerate(names) for v, (o, p) in views[n].items()]
    npose = 6 * (nc - 1)
    n = npose + 6 * nv

    def cols(c: int, k: int) -> np.ndarray:
        own = np.arange(npose + 6 * k, npose + 6 * k + 6)
        return np.r_[np.arange(6 * (c - 1), 6 * c), own] if c else own

    def block(x: np.ndarray, c: int, k: int, o: np.ndarray, p: np.ndarray) -> np.ndarray:
        Rc = rodrigues(x[6 * (c - 1) : 6 * (c - 1) + 3]) if c else np.eye(3)
        Tc = x[6 * (c - 1) + 3 : 6 * c] if c else np.zeros(3)
        b = x[npose + 6 * k : npose + 6 * k + 6]
        R = Rc @ rodrigues(b[:3])
        return (project(o, _rotvec(R), Rc @ b[3:] + Tc, cams[c]) - p).ravel()

    x = np.concatenate([np.r_[rig.rvecs[i], rig.tvecs[i]] for i in idx[1:]] + [np.r_[r, t] for r, t in zip(brv, btv)])
    cost, prev = np.inf, x
    for _ in range(50):
        A, g, f2 = np.zeros((n, n)), np.zeros(n), 0.0
        for c, k, o, p in blocks:
            f = block(x, c, k, o, p)
            cc = cols(c, k)
            J = np.empty((len(f), len(cc)))
            for j, col in enumerate(cc):
                h = 1e-6 * max(1.0, abs(x[col]))
                xp, xm = x.copy(), x.copy()
                xp[col] += h
                xm[col] -= h
                J[:, j] = (block(xp, c, k, o, p) - block(xm, c, k, o, p)) / (2 * h)
            A[np.ix_(cc, cc)] += J.T @ J
            g[cc] += J.T @ f
            f2 += float(f @ f)
        if f2 > cost * (1 + 1e-12):
            x = prev  # the last step went uphill: its start is the minimum to rounding
            break
        cost, prev = f2, x
        step = np.linalg.solve(A, -g)
        x = x + step
        if np.max(np.abs(step) / np.maximum(1.0, np.abs(x))) < 1e-12:
            break
    rv = np.vstack([np.zeros(3)] + [x[6 * (c - 1) : 6 * (c - 1) + 3] for c in range(1, nc)])
    tv = np.vstack([np.zeros(3)] + [x[6 * (c - 1) + 3 : 6 * c] for c in range(1, nc)])
    return RigModel(names, cams, rv, tv)


def _rotvec(R: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(R)[0].ravel()
