"""A robust start for the joint rig solve: per-camera calibrations, pairwise relative poses averaged robustly over
the instants two cameras share, a spanning tree over the camera graph from the reference, and the board's symmetry
resolved across cameras per instant.

Conventions: :mod:`circcal.rig.model` (``X_c = R_c X_0 + T_c``; board poses ``X_0 = R_v P + t_v``). A camera's board
pose at an instant (``X_c = R_cv P + t_cv``, from its own calibration) and another camera's at the same instant give
one estimate of their relative pose: ``R_ab = R_bv R_av^T``, ``T_ab = t_bv - R_ab t_av``.

Board symmetry: a board whose point set maps onto itself (a symmetric grid turned 180 deg,
:meth:`circcal.board.Board.symmetries`) can be labelled one way in one camera and the other way in another at the
same instant (findCirclesGrid does this about one pair in twelve). Relabelling camera b's points by a symmetry ``H``
(``P -> Q P + q``, a rigid map of the board onto itself) changes its board pose to ``pose_b o H^-1``; the pairwise
estimate takes, per instant, the labelling that agrees with the consensus of the others, and each instant's views are
then relabelled to agree with the one camera that anchors it, by the labelling whose projection through the rig's
start fits the observed points best. A view whose labellings fit about equally (:data:`AMBIGUITY_RATIO`), or none
fits (:data:`INCONSISTENT_PX`), is dropped with the reason, never guessed.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal.analysis.cross import noting_warnings
from circcal.board import Board
from circcal.errors import CalibrationError, InputError
from circcal.model import DEFAULT_LENS, Camera, lens_model, project_camera
from circcal.rotation import rodrigues, rotation_angle_deg, rotation_log
from circcal.solver import CalibrationOptions, calibrate, pose_start

__all__ = [
    "BoardSymmetry",
    "PairEstimate",
    "RigStart",
    "board_symmetries",
    "camera_starts",
    "given_camera_starts",
    "pair_estimate",
    "rig_start",
    "spanning_tree",
    "CLUSTER_DEG",
    "AMBIGUITY_RATIO",
    "INCONSISTENT_PX",
]

#: Per-instant relative rotations within this angle (deg) of each other count as one consensus (a board symmetry
#: turns them by 90 or 180 deg; per-camera starts agree to a degree or better).
CLUSTER_DEG = 10.0
#: An instant's relative pose is an outlier of its pair beyond max(floor, OUTLIER_SCALE x the median deviation).
OUTLIER_SCALE = 4.0
OUTLIER_FLOOR_DEG = 0.5
#: ... translation floor, as a share of the median distance of the board from camera a.
OUTLIER_FLOOR_REL = 0.01
#: A view's labelling is ambiguous when its second-best labelling fits within this factor of its best.
AMBIGUITY_RATIO = 3.0
#: A view no labelling fits to within max(this (px), INCONSISTENT_SCALE x the median fit of every view) is dropped.
INCONSISTENT_PX = 20.0
INCONSISTENT_SCALE = 10.0


@dataclass(frozen=True)
class BoardSymmetry:
    """A rigid map of the board onto itself in board coordinates: ``P -> Q P + q``.

    Attributes
    ----------
    label : str
        ``rot0`` (identity), ``rot90``, ``rot180``, ``rot270`` (:class:`circcal.board.Symmetry`).
    Q : ndarray, shape (3, 3)
        A rotation about the board's normal (exact: entries 0 and +-1).
    q : ndarray, shape (3,)
        mm.
    """

    label: str
    Q: np.ndarray
    q: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """The relabelled object points.

        Parameters
        ----------
        points : ndarray, shape (N, 3)
            mm.

        Returns
        -------
        ndarray, shape (N, 3)
            ``Q P + q``, mm.
        """
        out: np.ndarray = np.asarray(points, dtype=np.float64) @ self.Q.T + self.q
        return out

    def pose(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The board pose of the relabelled points, given that of the points as labelled (``pose o H^-1``).

        Parameters
        ----------
        R : ndarray, shape (3, 3)
        t : ndarray, shape (3,)
            mm.

        Returns
        -------
        R : ndarray, shape (3, 3)
        t : ndarray, shape (3,)
        """
        Rn = R @ self.Q.T
        return Rn, t - Rn @ self.q


IDENTITY = BoardSymmetry("rot0", np.eye(3), np.zeros(3))


def board_symmetries(board: Board | None) -> tuple[BoardSymmetry, ...]:
    """The proper rotations that map ``board``'s points onto themselves, identity first.

    Parameters
    ----------
    board : Board or None
        None: the identity alone (no relabelling).

    Returns
    -------
    tuple of BoardSymmetry
    """
    if board is None:
        return (IDENTITY,)
    P = board.object_points()
    c = P.mean(axis=0)
    out = [IDENTITY]
    for s in board.symmetries(reflections=False):
        if s.label == "rot0":
            continue
        a = np.radians(float(s.label.removeprefix("rot")))
        Q = np.round(np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]]))
        q = c - Q @ c
        # the labelling that c[perm] gives: pixel j gets point perm^-1(j); check that the map is one of the two
        if np.allclose(P @ Q.T + q, P[np.argsort(s.perm)]) or np.allclose(P @ Q.T + q, P[s.perm]):
            out.append(BoardSymmetry(s.label, Q, q))
    return tuple(out)


@dataclass(frozen=True)
class PairEstimate:
    """Cameras ``a < b``'s relative pose, averaged robustly over their shared instants.

    Attributes
    ----------
    a, b : int
    R : ndarray, shape (3, 3)
    T : ndarray, shape (3,)
        ``X_b = R X_a + T``, mm.
    inliers : tuple of str
        The instants averaged.
    outliers : tuple of str
        Shared instants left out of the average (no labelling within :data:`CLUSTER_DEG` of the consensus, or
        beyond the outlier bounds).
    """

    a: int
    b: int
    R: np.ndarray
    T: np.ndarray
    inliers: tuple[str, ...]
    outliers: tuple[str, ...]


#: The robust mean rotation's last step, rad (6e-8 deg: far below what a start needs).
MEDIAN_TOL_RAD = 1e-9


def _rotation_median(Rs: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """A robust mean rotation: component-wise medians of the tangent vectors about the running estimate, to
    :data:`MEDIAN_TOL_RAD` (a start: the joint solve refines it)."""
    R = seed
    for _ in range(20):
        w = rotation_log(Rs @ R.T)
        d = np.median(w, axis=0)
        R = rodrigues(d) @ R
        if np.linalg.norm(d) < MEDIAN_TOL_RAD:
            break
    return R


def pair_estimate(
    a: int,
    b: int,
    poses_a: Mapping[str, tuple[np.ndarray, np.ndarray]],
    poses_b: Mapping[str, tuple[np.ndarray, np.ndarray]],
    symmetries: Sequence[BoardSymmetry] = (IDENTITY,),
) -> PairEstimate | None:
    """The relative pose of cameras ``a`` and ``b`` from their board poses at shared instants.

    Parameters
    ----------
    a, b : int
        Camera indices.
    poses_a, poses_b : mapping of str to (ndarray (3, 3), ndarray (3,))
        Per instant the board -> camera pose (``X = R P + t``, mm) of each camera.
    symmetries : sequence of BoardSymmetry
        The board's (:func:`board_symmetries`): each instant is tried with camera b's points relabelled by each.

    Returns
    -------
    PairEstimate or None
        None when the cameras share no instant.
    """
    shared = [v for v in poses_a if v in poses_b]
    if not shared:
        return None
    cands = []  # (instant, R_ab, T_ab as a function of R)
    for v in shared:
        Ra, ta = poses_a[v]
        for s in symmetries:
            Rb, tb = s.pose(*poses_b[v])
            cands.append((v, Rb @ Ra.T, Ra, ta, Rb, tb))
    Rc = np.array([c[1] for c in cands])
    ang = rotation_angle_deg(Rc[:, None] @ np.transpose(Rc, (0, 2, 1))[None])
    inst = np.array([shared.index(c[0]) for c in cands])
    near = ang < CLUSTER_DEG
    support = np.array([len(set(inst[near[i]].tolist())) for i in range(len(cands))])
    spread = np.array([np.sum(np.where(near[i], ang[i], 0.0)) for i in range(len(cands))])
    seed = int(np.lexsort((spread, -support))[0])
    members: list[int] = []
    for k in range(len(shared)):
        idx = np.flatnonzero(inst == k)
        best = idx[np.argmin(ang[seed, idx])]
        if ang[seed, best] < CLUSTER_DEG:
            members.append(int(best))
    R = _rotation_median(Rc[members], Rc[seed])
    dist = np.median([np.linalg.norm(cands[i][3]) for i in members])

    def translations(R: np.ndarray, ids: list[int]) -> np.ndarray:
        return np.array([cands[i][5] - R @ cands[i][3] for i in ids])

    T = np.median(translations(R, members), axis=0)
    d_rot = rotation_angle_deg(Rc[members] @ R.T)
    d_tr = np.linalg.norm(translations(R, members) - T, axis=1)
    keep = (d_rot <= max(OUTLIER_FLOOR_DEG, OUTLIER_SCALE * np.median(d_rot))) & (
        d_tr <= max(OUTLIER_FLOOR_REL * dist, OUTLIER_SCALE * np.median(d_tr))
    )
    inliers = [members[i] for i in np.flatnonzero(keep)]
    R = _rotation_median(Rc[inliers], R)
    T = np.median(translations(R, inliers), axis=0)
    used = tuple(cands[i][0] for i in inliers)
    return PairEstimate(a, b, R, T, used, tuple(v for v in shared if v not in used))


def camera_starts(
    names: Sequence[str],
    views: Sequence[Mapping[str, tuple[np.ndarray, np.ndarray]]],
    image_sizes: Sequence[tuple[int, int]],
    options: Sequence[CalibrationOptions],
) -> tuple[list[Camera], list[dict[str, tuple[np.ndarray, np.ndarray]]]]:
    """Each camera calibrated alone (:func:`circcal.solver.calibrate`) on its own views.

    Parameters
    ----------
    names : sequence of str
    views : sequence of mapping of str to (ndarray (N, 3), ndarray (N, 2))
        Per camera, per instant its object points (mm) and image points (px).
    image_sizes : sequence of (int, int)
        Per camera (width, height) px.
    options : sequence of CalibrationOptions
        Per camera.

    Returns
    -------
    cameras : list of Camera
    poses : list of dict of str to (ndarray (3, 3), ndarray (3,))
        Per camera, per instant its board -> camera pose (mm).

    Raises
    ------
    CalibrationError
        A camera's calibration fails (the message names the camera).
    """
    cameras, poses = [], []
    for name, vs, size, opt in zip(names, views, image_sizes, options):
        keys = list(vs)
        obj, img = [vs[k][0] for k in keys], [vs[k][1] for k in keys]
        said: list[str] = []
        try:
            who = f"the start of camera {name!r} (calibrated alone, before the joint solve)"
            res = noting_warnings(said, who, lambda args: calibrate(*args), (obj, img, size, opt))
            camera = res.camera
        except CalibrationError as exc:
            # a rich pinhole model its own views cannot determine (its coefficients trade off) may be determined by
            # the rig, whose other cameras fix the board poses: start it from the 5-coefficient model, extra terms 0
            start = _simpler_start(obj, img, size, opt)
            if start is None:
                raise CalibrationError(f"camera {name!r}: {str(exc).splitlines()[0]}") from exc
            res, camera = start
        for line in said:  # a start's own troubles, named as such (the joint solve says its own)
            warnings.warn(line, RuntimeWarning, stacklevel=3)
        cameras.append(camera)
        poses.append({k: (rodrigues(r), t.copy()) for k, r, t in zip(keys, res.rvecs, res.tvecs)})
    return cameras, poses


def given_camera_starts(
    names: Sequence[str], cameras: Sequence[Camera], views: Sequence[Mapping[str, tuple[np.ndarray, np.ndarray]]]
) -> tuple[list[Camera], list[dict[str, tuple[np.ndarray, np.ndarray]]]]:
    """:func:`camera_starts`' form for given intrinsics: each view's board pose in closed form
    (:func:`circcal.solver.pose_start`, IPPE); the joint solve refines them with everything else.

    Parameters
    ----------
    names : sequence of str
        Camera names (for the errors).
    cameras : sequence of Camera
        Each camera's intrinsics.
    views : sequence of mapping of str to (ndarray (N, 3), ndarray (N, 2))
        Per camera, per instant its observations (object points mm, image points px).

    Returns
    -------
    cameras : list of Camera
        ``cameras``.
    poses : list of dict of str to (ndarray (3, 3), ndarray (3,))
        Per camera, per instant its board -> camera pose (mm).

    Raises
    ------
    CalibrationError
        A view no pose fits with its camera (named by camera and instant).
    """
    poses: list[dict[str, tuple[np.ndarray, np.ndarray]]] = []
    for name, cam, vs in zip(names, cameras, views):
        rt = []
        for v, (obj, img) in vs.items():
            try:
                rt.append(pose_start(obj, img, cam))
            except CalibrationError as exc:
                raise CalibrationError(f"camera {name!r}, instant {v!r}: {exc}") from None
        Rs = rodrigues(np.array([r for r, _ in rt]).reshape(-1, 3))
        poses.append({v: (R, t) for v, R, (_, t) in zip(vs, Rs, rt)})
    return list(cameras), poses


def _simpler_start(
    obj: Sequence[np.ndarray], img: Sequence[np.ndarray], size: tuple[int, int], opt: CalibrationOptions
) -> tuple[Any, Camera] | None:
    """A camera of ``opt``'s rich pinhole model (rational, thin prism) started from its views' opencv5 calibration,
    the extra coefficients 0, with that calibration's result (its poses); None for other models or where that fails
    too or cannot hold the same parameters."""
    model = lens_model(opt.lens)
    if not model.pinhole or model.n_dist <= 5:
        return None
    try:
        res = calibrate(obj, img, size, opt.replace(lens=DEFAULT_LENS))
    except (CalibrationError, InputError):
        return None
    p = np.zeros(4 + model.n_dist)
    names = model.param_names
    for k, n in enumerate(res.camera.model.param_names):
        p[names.index(n)] = res.camera.intrinsics[k]
    return res, Camera.from_intrinsics(size[0], size[1], p, opt.lens)


@dataclass
class RigStart:
    """The start of the joint solve.

    Attributes
    ----------
    rig_R : ndarray, shape (C, 3, 3)
    rig_T : ndarray, shape (C, 3)
        Each camera's pose in the rig (``X_c = R X_0 + T``, mm); camera 0 the identity.
    board_R : dict of str to ndarray (3, 3)
    board_t : dict of str to ndarray (3,)
        Per instant the board pose in the rig frame (mm).
    labels : dict of (int, str) to BoardSymmetry
        Per kept view (camera, instant) the relabelling applied to its object points (identity mostly).
    dropped : list of (int, str, str)
        Views left out: (camera, instant, reason).
    pairs : list of PairEstimate
        Every pair of cameras that shares an instant.
    tree : list of (int, int)
        The spanning tree's edges (parent, child), from camera 0.
    """

    rig_R: np.ndarray
    rig_T: np.ndarray
    board_R: dict[str, np.ndarray]
    board_t: dict[str, np.ndarray]
    labels: dict[tuple[int, str], BoardSymmetry]
    dropped: list[tuple[int, str, str]] = field(default_factory=list)
    pairs: list[PairEstimate] = field(default_factory=list)
    tree: list[tuple[int, int]] = field(default_factory=list)


def spanning_tree(names: Sequence[str], links: dict[tuple[int, int], int]) -> list[tuple[int, int]]:
    """The maximum spanning tree of the camera graph from camera 0 (Prim's).

    Parameters
    ----------
    names : sequence of str
        Camera names, ``names[0]`` the reference.
    links : dict of (int, int) to int
        ``(a, b) -> weight`` (instants shared); a weight of 0 is no link.

    Returns
    -------
    list of (int, int)
        The edges (parent, child), each child linked to a camera reached before it.

    Raises
    ------
    CalibrationError
        A camera the tree cannot reach: named, with the cameras linked to the reference that it shares no instant
        with.
    """
    n = len(names)
    reached, edges = {0}, []
    while len(reached) < n:
        best = max(
            ((w, a, b) for (a, b), w in links.items() if (a in reached) != (b in reached) and w > 0),
            default=None,
        )
        if best is None:
            lost = [i for i in range(n) if i not in reached]
            linked = ", ".join(repr(names[i]) for i in sorted(reached))
            raise CalibrationError(
                f"camera(s) {', '.join(repr(names[i]) for i in lost)} share no instant (no image name with the board "
                f"found in both) with camera(s) {linked}, which are linked to the reference {names[0]!r}: the rig "
                f"cannot place them; add images in which the board is seen by one of each at the same time"
            )
        _, a, b = best
        parent, child = (a, b) if a in reached else (b, a)
        edges.append((parent, child))
        reached.add(child)
    return edges


def rig_start(
    names: Sequence[str],
    cameras: Sequence[Camera],
    poses: Sequence[Mapping[str, tuple[np.ndarray, np.ndarray]]],
    views: Sequence[Mapping[str, tuple[np.ndarray, np.ndarray]]],
    symmetries: Sequence[BoardSymmetry] = (IDENTITY,),
) -> RigStart:
    """Pairwise relative poses, the spanning tree from camera 0, the board's labelling per view and the board poses.

    Parameters
    ----------
    names : sequence of str
        Camera names, ``names[0]`` the reference.
    cameras : sequence of Camera
        Per-camera calibrations (:func:`camera_starts`).
    poses : sequence of mapping of str to (ndarray (3, 3), ndarray (3,))
        Per camera, per instant its board -> camera pose from its own calibration (mm).
    views : sequence of mapping of str to (ndarray (N, 3), ndarray (N, 2))
        Per camera, per instant its observations (object points mm, image points px).
    symmetries : sequence of BoardSymmetry
        The board's (:func:`board_symmetries`).

    Returns
    -------
    RigStart

    Raises
    ------
    CalibrationError
        A camera linked to the reference by no chain of shared instants (named, with the cameras it shares none
        with).
    """
    n = len(names)
    pairs = [p for a in range(n) for b in range(a + 1, n) if (p := pair_estimate(a, b, poses[a], poses[b], symmetries))]
    tree = spanning_tree(names, {(p.a, p.b): len(p.inliers) for p in pairs})
    rel = {(p.a, p.b): (p.R, p.T) for p in pairs}
    rig_R, rig_T = np.repeat(np.eye(3)[None], n, axis=0), np.zeros((n, 3))
    for parent, child in tree:
        if (parent, child) in rel:
            R, T = rel[(parent, child)]
        else:  # X_parent = R X_child + T  ->  X_child = R^T X_parent - R^T T
            R0, T0 = rel[(child, parent)]
            R, T = R0.T, -R0.T @ T0
        rig_R[child] = R @ rig_R[parent]
        rig_T[child] = R @ rig_T[parent] + T

    labels: dict[tuple[int, str], BoardSymmetry] = {}
    board_R: dict[str, np.ndarray] = {}
    board_t: dict[str, np.ndarray] = {}
    instants = list(dict.fromkeys(v for p in poses for v in p))
    # every instant's board pose from each camera that saw it (the anchor), and through it every other camera's
    # projection of its own view under each labelling of the board: one projection per camera for all of them
    starts: dict[str, list[tuple[int, tuple[np.ndarray, np.ndarray]]]] = {}
    chunks: list[list[np.ndarray]] = [[] for _ in range(n)]
    observed: list[list[np.ndarray]] = [[] for _ in range(n)]  # the observed points, once per labelling
    jobs: list[list[tuple[str, int, int]]] = [[] for _ in range(n)]  # (instant, anchor, points) per camera
    for v in instants:
        seen = [c for c in range(n) if v in poses[c]]
        starts[v] = []
        for anchor in seen:
            Ra, ta = poses[anchor][v]
            R0, t0 = rig_R[anchor].T @ Ra, rig_R[anchor].T @ (ta - rig_T[anchor])
            starts[v].append((anchor, (R0, t0)))
            for c in seen:
                if c != anchor:
                    obj = views[c][v][0]
                    P = np.concatenate([s.apply(obj) for s in symmetries])
                    chunks[c].append(P @ (rig_R[c] @ R0).T + (rig_R[c] @ t0 + rig_T[c]))
                    observed[c].append(np.tile(views[c][v][1], (len(symmetries), 1)))
                    jobs[c].append((v, anchor, len(obj)))
    found: dict[tuple[str, int], dict[int, tuple[BoardSymmetry, float, float]]] = {}
    for c in range(n):
        if not jobs[c]:
            continue
        uv_all = project_camera(np.concatenate(chunks[c]), cameras[c])  # NaN behind a pinhole camera
        # every (job, labelling)'s RMS px in one pass: its points' squared errors summed by segment
        d2 = np.sum((uv_all - np.concatenate(observed[c])) ** 2, axis=1)
        counts = np.repeat([m for _, _, m in jobs[c]], len(symmetries))
        rms = np.sqrt(np.add.reduceat(d2, np.r_[0, np.cumsum(counts)[:-1]]) / counts)
        err = np.where(np.isfinite(rms), rms, np.inf).reshape(len(jobs[c]), len(symmetries))
        order = np.argsort(err, axis=1)
        for (v, anchor, _), e, o in zip(jobs[c], err.tolist(), order.tolist()):
            second = e[o[1]] if len(o) > 1 else np.inf
            found.setdefault((v, anchor), {})[c] = (symmetries[o[0]], e[o[0]], second)
    # instant -> [(anchor, its board pose, {camera: (best symmetry, best px, second px)})]
    trials = {v: [(anchor, pose, found.get((v, anchor), {})) for anchor, pose in starts[v]] for v in instants}
    # the typical agreement, of the fits that put the board in front of the camera
    best_fits = [f[1] for opts in trials.values() for _, _, fits in opts for f in fits.values() if np.isfinite(f[1])]
    limit = max(INCONSISTENT_PX, INCONSISTENT_SCALE * float(np.median(best_fits))) if best_fits else INCONSISTENT_PX
    dropped: list[tuple[int, str, str]] = []
    for v, options in trials.items():
        # the anchor that the most other views agree with, then the closest agreement
        anchor, (R0, t0), fits = min(
            options,
            key=lambda o: (sum(f[1] > limit for f in o[2].values()), sum(min(f[1], limit) for f in o[2].values())),
        )
        board_R[v], board_t[v] = R0, t0
        labels[(anchor, v)] = IDENTITY
        for c, (s, best, second) in fits.items():
            if best > limit:
                dropped.append(
                    (
                        c,
                        v,
                        (
                            f"inconsistent with the rig's start: its board points land {best:.3g} px from the "
                            f"observed ones at best (limit {limit:.3g} px)"
                            if np.isfinite(best)
                            else "inconsistent with the rig's start: under every labelling some of its board points "
                            "fall behind the camera or outside its lens's field"
                        ),
                    )
                )
            elif second < AMBIGUITY_RATIO * best:
                dropped.append(
                    (
                        c,
                        v,
                        f"the board's symmetry could not be resolved across cameras: two labellings fit within "
                        f"{second / max(best, 1e-300):.3g}x of each other ({best:.3g} px, {second:.3g} px)",
                    )
                )
            else:
                labels[(c, v)] = s
    return RigStart(rig_R, rig_T, board_R, board_t, labels, dropped, pairs, tree)
