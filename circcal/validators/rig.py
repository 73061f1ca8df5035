"""Reference rig calibrations: OpenCV's ``stereoCalibrate`` and ``calibrateMultiview``, and mrcal's N-camera solve
(out of process), each returning a :class:`circcal.rig.RigModel` in circcal's convention, and the comparison of two
rigs.

Conventions (one place; :mod:`circcal.rig.model`): camera 0 the reference, ``X_i = R_i X_0 + T_i``, mm.

* ``cv2.stereoCalibrate`` returns ``R, T`` with ``X_2 = R X_1 + T`` in the object points' unit: the same. It takes one
  ``imageSize`` for both cameras (used only to start intrinsics: with ``CALIB_FIX_INTRINSIC`` or
  ``CALIB_USE_INTRINSIC_GUESS`` the given cameras carry their own sizes) and needs the *same* object points in both
  images of an instant: each instant's points seen by both are kept, and instants seen by one camera are dropped.
* ``cv2.calibrateMultiviewExtended`` (OpenCV 5) returns ``Rs`` (rotation vectors) and ``Ts`` relative to camera 0 with
  the same direction. Measured pitfalls with OpenCV 5.0 from Python: a board in millimetres raises "Pattern points
  are collinear!" (it normalises by the squared extent), so the board goes in metres and ``T`` comes back in metres
  (multiplied by 1000 here); partial views marked (-1, -1) diverge, although documented as supported, so only whole
  views are given (partial ones are counted as dropped).
* mrcal: ``extrinsics_rt_fromref`` is ``x_cam = R x_ref + t`` with camera 0 the reference: the same; one lens model
  for all cameras (mrcal's ``optimize`` takes one), no fisheye (:data:`circcal.formats.mrcal_process.LENSMODELS`).
  ``fair`` mode: no warp, no regularisation, no outlier rejection, started from the caller's rig (a per-instant PnP
  of the board in a camera that saw it gives its pose in the rig frame); ``default``: mrcal's own seed, warp,
  regularisation and outlier rejection, as ``mrcal-calibrate-cameras``.

Views are given as :func:`circcal.rig.calibrate_rig_points` takes them: ``{camera name: {instant: (object points
(N, 3) mm, image points (N, 2) px)}}``, the first camera the reference; the rigs returned name the cameras alike.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal.errors import InputError
from circcal.formats.mrcal_process import LENSMODELS, UnsupportedLayout, board_lattice, mrcal_python, run_worker
from circcal.model import Camera, param_names, project_camera, unproject
from circcal.observations import BOARD_KEY_DECIMALS
from circcal.rig.model import RigModel
from circcal.rotation import rodrigues, rotation_angle_deg
from circcal.solver.holdout import fit_pose

__all__ = [
    "RigViews",
    "RigReference",
    "RigAgreement",
    "opencv_stereo",
    "opencv_multiview",
    "multiview_weights",
    "MULTIVIEW_ROBUST_SCALE_PX2",
    "mrcal_rig",
    "compare_rigs",
    "shared_points",
    "shared_pair",
]

#: ``{camera name: {instant: (object points (N, 3) mm, image points (N, 2) px)}}``
RigViews = Mapping[str, Mapping[str, tuple[np.ndarray, np.ndarray]]]


def _by_instant(views: RigViews) -> tuple[list[str], dict[str, dict[int, tuple[np.ndarray, np.ndarray]]]]:
    """(camera names, ``{instant: {camera index: view}}`` in first-seen instant order)."""
    names = list(views)
    out: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
    for c, name in enumerate(names):
        for inst, v in views[name].items():
            out.setdefault(inst, {})[c] = (np.asarray(v[0], dtype=np.float64), np.asarray(v[1], dtype=np.float64))
    return names, out


@dataclass
class RigReference:
    """One reference's rig, or why there is none.

    Attributes
    ----------
    name : str
        E.g. ``opencv-stereo (fix-intrinsic)``.
    status : {"ok", "unavailable", "failed"}
    rig : RigModel or None
    rms_px : float
        The reference's own RMS as it reports it (its convention in ``notes``), NaN when none.
    notes : list of str
        What was dropped or assumed (instants, partial views, units).
    """

    name: str
    status: str
    rig: RigModel | None = None
    rms_px: float = float("nan")
    notes: list[str] = field(default_factory=list)


def _cv2() -> Any:
    import cv2

    return cv2


def _flags(lens: str) -> int:
    cv2 = _cv2()
    return {
        "opencv5": 0,
        "rational": cv2.CALIB_RATIONAL_MODEL,
        "thin-prism": cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL,
    }[lens]


def shared_points(
    a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The board points two cameras saw at one instant (matched by their board coordinates).

    Parameters
    ----------
    a, b : tuple of ndarray
        Each camera's view: object points (N, 3) mm, image points (N, 2) px.

    Returns
    -------
    object : ndarray, shape (n, 3)
        The shared board points, in ``a``'s order, mm.
    image_a, image_b : ndarray, shape (n, 2)
        Their pixels in each camera.
    """
    ka = {tuple(p): k for k, p in enumerate(np.round(np.asarray(a[0]), BOARD_KEY_DECIMALS).tolist())}
    kb = np.round(np.asarray(b[0]), BOARD_KEY_DECIMALS).tolist()
    pairs = [(ka[q], k) for k, p in enumerate(kb) if (q := tuple(p)) in ka]
    ia = np.array([p[0] for p in pairs], dtype=int)
    ib = np.array([p[1] for p in pairs], dtype=int)
    return np.asarray(a[0])[ia], np.asarray(a[1])[ia], np.asarray(b[1])[ib]


def shared_pair(views: RigViews) -> dict[str, dict[str, tuple]]:
    """Cameras 0 and 1 at the instants both saw (>= 6 shared points), their shared points only (stereoCalibrate's).

    Parameters
    ----------
    views : RigViews

    Returns
    -------
    dict of str to dict of str to (ndarray, ndarray)
        The first two cameras only.
    """
    a, b = list(views)[:2]
    out: dict[str, dict[str, tuple]] = {a: {}, b: {}}
    for v in views[a]:
        if v not in views[b]:
            continue
        o, pa, pb = shared_points(views[a][v], views[b][v])
        if len(o) >= 6:
            out[a][v], out[b][v] = (o, pa), (o, pb)
    return out


def opencv_stereo(views: RigViews, cameras: Sequence[Camera], mode: str = "fix-intrinsic") -> RigReference:
    """``cv2.stereoCalibrate`` of cameras 0 and 1 (``cv2.fisheye.stereoCalibrate`` for two fisheyes).

    Parameters
    ----------
    views : RigViews
        Instants; those that both cameras saw (with at least 6 shared points) are used.
    cameras : sequence of Camera
        The two cameras' intrinsics: held (``fix-intrinsic``) or the start (``intrinsic-guess``); both of one OpenCV
        lens family.
    mode : {"fix-intrinsic", "intrinsic-guess"}

    Returns
    -------
    RigReference
        ``failed`` with OpenCV's words when it raises; ``unavailable`` for lens models OpenCV's stereo cannot take
        (a pinhole and a fisheye together).
    """
    cv2 = _cv2()
    name = f"opencv-stereo ({mode})"
    names, by_inst = _by_instant(views)
    c0, c1 = cameras[0], cameras[1]
    fisheye = {c0.lens, c1.lens} == {"fisheye"}
    if "fisheye" in (c0.lens, c1.lens) and not fisheye:
        return RigReference(name, "unavailable", notes=[f"OpenCV's stereo takes one lens family: {c0.lens}, {c1.lens}"])
    if c0.lens != c1.lens and mode != "fix-intrinsic":
        return RigReference(
            name,
            "unavailable",
            notes=[f"stereoCalibrate fits one distortion model for both cameras: {c0.lens}, {c1.lens}"],
        )
    pair = shared_pair(views)
    a, b = names[:2]
    used = list(pair[a])
    obj = [pair[a][v][0].astype(np.float32).reshape(-1, 1, 3) for v in used]
    p0 = [pair[a][v][1].astype(np.float32).reshape(-1, 1, 2) for v in used]
    p1 = [pair[b][v][1].astype(np.float32).reshape(-1, 1, 2) for v in used]
    notes = [f"{len(used)} instants seen by both cameras (of {len(by_inst)})", "T in mm, X_1 = R X_0 + T"]
    if len(used) < 3:
        return RigReference(name, "failed", notes=notes + ["fewer than 3 shared instants"])
    flag = cv2.CALIB_FIX_INTRINSIC if mode == "fix-intrinsic" else cv2.CALIB_USE_INTRINSIC_GUESS
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 1000, 1e-12)
    try:
        if fisheye:
            out = cv2.fisheye.stereoCalibrate(
                obj, p0, p1, c0.K.copy(), c0.dist.reshape(4, 1).copy(), c1.K.copy(), c1.dist.reshape(4, 1).copy(),
                (c0.width, c0.height),
                flags=flag | cv2.fisheye.CALIB_FIX_SKEW, criteria=crit,
            )  # fmt: skip
            rms, K0, d0, K1, d1, R, T = out[:7]
        else:
            # both cameras' coefficients at one length (zeros appended): OpenCV projects with every coefficient given
            # (a held camera keeps its own model); the copies keep OpenCV's in-place writes off the callers' cameras
            n = max(len(c0.dist), len(c1.dist))
            lens = c0.lens if len(c0.dist) >= len(c1.dist) else c1.lens
            d0_in, d1_in = (np.concatenate([c.dist, np.zeros(n - len(c.dist))]) for c in (c0, c1))
            rms, K0, d0, K1, d1, R, T, _, _ = cv2.stereoCalibrate(
                obj, p0, p1, c0.K.copy(), d0_in, c1.K.copy(), d1_in, (c0.width, c0.height),
                flags=flag | _flags(lens), criteria=crit,
            )  # fmt: skip
    except cv2.error as exc:
        return RigReference(name, "failed", notes=notes + [f"OpenCV: {str(exc).strip().splitlines()[-1]}"])
    cams = [_camera_like(c0, K0, d0), _camera_like(c1, K1, d1)]
    rig = RigModel(names[:2], cams, [np.zeros(3), cv2.Rodrigues(R)[0].ravel()], [np.zeros(3), np.ravel(T)])
    return RigReference(name, "ok", rig, float(rms), notes + ["rms: OpenCV's, per point (2-D norm)"])


def _camera_like(c: Camera, K: np.ndarray, d: np.ndarray) -> Camera:
    """``c``'s size and lens with OpenCV's K and coefficients."""
    n = c.model.n_dist
    p = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], np.ravel(d)[:n]])
    return Camera.from_intrinsics(c.width, c.height, p, c.lens)


#: ``calibrateMultiview``'s robust scale (``RBS_FNC_SCALE`` in ``modules/calib/src/multiview_calibration.cpp``):
#: each point weighted by ``exp(-e^2 / 30)`` in its joint solve, ``e`` its reprojection error in px.
MULTIVIEW_ROBUST_SCALE_PX2 = 30.0


def multiview_weights(e2: np.ndarray) -> np.ndarray:
    """``calibrateMultiview``'s per-point weights (``RobustExpFunction``), from the squared reprojection errors.

    Parameters
    ----------
    e2 : ndarray, shape (N,)
        Squared reprojection errors, px^2.

    Returns
    -------
    ndarray, shape (N,)
        ``exp(-e2 / 30)``: 0.9987 at 0.2 px, 0.967 at 1 px, 0.43 at 5 px.
    """
    return np.exp(-np.asarray(e2, dtype=np.float64) / MULTIVIEW_ROBUST_SCALE_PX2)


def opencv_multiview(
    views: RigViews,
    sizes: Sequence[tuple[int, int]],
    lens: str | Sequence[str] = "opencv5",
    cameras: Sequence[Camera] | None = None,
) -> RigReference:
    """``cv2.calibrateMultiviewExtended`` (OpenCV 5) over every camera, pinhole lens models only.

    Its estimator (``modules/calib/src/multiview_calibration.cpp``): each camera's intrinsics from
    ``cv2.calibrateCamera`` on its own views (or given, with ``CALIB_USE_INTRINSIC_GUESS``), then held while one
    Levenberg-Marquardt solve refines the camera poses and board poses, every point weighted by ``exp(-e^2 / 30)``
    (``e`` its reprojection error, px). The intrinsics are not refined with the rig.

    Parameters
    ----------
    views : RigViews
        Whole-board views are used; a camera's partial view of an instant is dropped (module docstring).
    sizes : sequence of (int, int)
        Each camera's (width, height) px.
    lens : {"opencv5", "rational", "thin-prism"} or sequence of them
        One for every camera, or one per camera (``flagsForIntrinsics`` per camera).
    cameras : sequence of Camera or None
        Every camera's intrinsics, held (``CALIB_USE_INTRINSIC_GUESS``; their lens models are used); None: OpenCV
        calibrates each camera on its own views.

    Returns
    -------
    RigReference
        ``unavailable`` where this OpenCV has no calibrateMultiviewExtended or for the fisheye (OpenCV 5.0 from
        Python raises in ``arithm_op`` given a camera with ``isFisheye = 1``, measured on the ``fisheye`` rig).
    """
    cv2 = _cv2()
    name = "opencv-multiview"
    lenses = [lens] * len(sizes) if isinstance(lens, str) else list(lens)
    if cameras is not None:
        lenses = [c.lens for c in cameras]
    if not hasattr(cv2, "calibrateMultiviewExtended"):
        return RigReference(name, "unavailable", notes=[f"OpenCV {cv2.__version__} has no calibrateMultiview"])
    bad = sorted({le for le in lenses if le not in ("opencv5", "rational", "thin-prism")})
    if bad:
        return RigReference(
            name, "unavailable", notes=[f"lens {', '.join(bad)}: OpenCV 5.0's calibrateMultiview raises on a fisheye"]
        )
    names, by_inst = _by_instant(views)
    ncam = len(sizes)
    full = max(len(o) for per in by_inst.values() for o, _ in per.values())
    board = None
    instants, partial = [], 0
    for inst, per in by_inst.items():
        whole = {c: v for c, v in per.items() if len(v[0]) == full}
        partial += len(per) - len(whole)
        if whole:
            instants.append((inst, whole))
            board = next(iter(whole.values()))[0] if board is None else board
    if board is None:
        return RigReference(name, "failed", notes=["no whole-board view"])
    order = {tuple(np.round(p, BOARD_KEY_DECIMALS)): k for k, p in enumerate(board)}
    obj = [(board / 1000.0).astype(np.float32) for _ in instants]
    img = [[np.full((full, 2), -1, np.float32) for _ in instants] for _ in range(ncam)]
    mask = np.zeros((ncam, len(instants)), np.uint8)
    for f, (_, whole) in enumerate(instants):
        for c, (o, p) in whole.items():
            idx = [order[tuple(np.round(q, BOARD_KEY_DECIMALS))] for q in o]
            img[c][f][idx] = p
            mask[c, f] = 1
    notes = [
        f"{len(instants)} instants, {partial} partial views dropped (OpenCV 5.0 diverges on them)",
        "board in metres (millimetres raise 'Pattern points are collinear!'); T converted to mm",
    ]
    Ks_in, ds_in, flags = None, None, 0
    if cameras is not None:
        Ks_in, ds_in = [c.K.copy() for c in cameras], [c.dist.reshape(1, -1).copy() for c in cameras]
        flags = cv2.CALIB_USE_INTRINSIC_GUESS
        notes.append("intrinsics given and held (CALIB_USE_INTRINSIC_GUESS)")
    try:
        out = cv2.calibrateMultiviewExtended(
            obj, img, [tuple(int(v) for v in s) for s in sizes], mask, np.zeros(ncam, np.uint8), Ks_in, ds_in, None,
            None, flagsForIntrinsics=np.array([_flags(le) for le in lenses]), flags=flags,
        )  # fmt: skip
    except cv2.error as exc:
        return RigReference(name, "failed", notes=notes + [f"OpenCV: {str(exc).strip().splitlines()[-1]}"])
    rms, Ks, ds, Rs, Ts = out[:5]
    cams = [
        Camera.from_intrinsics(
            sizes[c][0],
            sizes[c][1],
            np.concatenate(
                [
                    [Ks[c][0, 0], Ks[c][1, 1], Ks[c][0, 2], Ks[c][1, 2]],
                    np.ravel(ds[c])[: len(param_names(lenses[c])) - 4],
                ]
            ),
            lenses[c],
        )
        for c in range(ncam)
    ]
    rv = [np.ravel(Rs[c]) if np.size(Rs[c]) == 3 else cv2.Rodrigues(np.asarray(Rs[c]))[0].ravel() for c in range(ncam)]
    tv = [1000.0 * np.ravel(Ts[c]) for c in range(ncam)]
    rv[0], tv[0] = np.zeros(3), np.zeros(3)
    rig = RigModel(names, cams, rv, tv)
    return RigReference(name, "ok", rig, float(rms), notes + ["rms: OpenCV's, per point (2-D norm)"])


def mrcal_rig(
    views: RigViews, sizes: Sequence[tuple[int, int]], lens: str, mode: str = "fair", seed: RigModel | None = None
) -> RigReference:
    """mrcal's N-camera solve, out of process (:mod:`circcal.formats.mrcal_worker`'s ``rig`` command).

    Parameters
    ----------
    views : RigViews
    sizes : sequence of (int, int)
    lens : {"opencv5", "rational", "thin-prism"}
        One lens model for every camera (mrcal's).
    mode : {"fair", "default"}
        Module docstring.
    seed : RigModel or None
        ``fair`` mode's start (needed there); its cameras' poses of each instant come from a PnP in a camera that
        saw it.

    Returns
    -------
    RigReference
        ``unavailable`` without mrcal, for the fisheye or an off-lattice board.
    """
    name = f"mrcal-rig ({mode})"
    py, why, _ = mrcal_python()
    if py is None:
        return RigReference(name, "unavailable", notes=[why])
    if lens not in LENSMODELS:
        return RigReference(name, "unavailable", notes=[f"mrcal has no model for lens {lens}"])
    if mode == "fair" and seed is None:
        raise ValueError("mrcal's fair mode needs a seed rig")
    names, by_inst = _by_instant(views)
    insts = list(by_inst)
    rows = [(f, c) for f, inst in enumerate(insts) for c in sorted(by_inst[inst])]
    try:
        lat = board_lattice([by_inst[insts[f]][c][0] for f, c in rows])
    except UnsupportedLayout as exc:
        return RigReference(name, "unavailable", notes=[str(exc)])
    W, H, s, origin = lat["width_n"], lat["height_n"], lat["spacing"], lat["origin"]
    obs = np.zeros((len(rows), H, W, 3))
    obs[..., 2] = -1.0
    for k, ((f, c), ij) in enumerate(zip(rows, lat["ij"])):
        obs[k, ij[:, 0], ij[:, 1], :2] = by_inst[insts[f]][c][1]
        obs[k, ij[:, 0], ij[:, 1], 2] = 1.0
    req: dict[str, Any] = {
        "command": "rig",
        "modes": [mode],
        "width_n": W,
        "height_n": H,
        "spacing": s,
        "observations": obs.tolist(),
        "indices_frame_camera": rows,
        "imagersizes": [list(map(int, sz)) for sz in sizes],
        "lensmodel": LENSMODELS[lens],
        "focal_estimate": float(np.mean([c.fx for c in seed.cameras])) if seed else 0.7 * float(max(sizes[0])),
    }
    if mode == "fair" and seed is not None:
        req["seed_intrinsics"] = [c.intrinsics.tolist() for c in seed.cameras]
        req["seed_extrinsics"] = [np.concatenate([seed.rvecs[c], seed.tvecs[c]]).tolist() for c in range(1, len(sizes))]
        req["seed_frames"] = [_frame_in_rig(by_inst[inst], seed, origin).tolist() for inst in insts]
    try:
        reply = run_worker(py, req, 600.0)
    except RuntimeError as exc:
        return RigReference(name, "failed", notes=[str(exc)])
    r = reply["results"][0]
    intr = np.asarray(r["intrinsics"], dtype=np.float64)
    ext = np.asarray(r["extrinsics_rt_fromref"], dtype=np.float64).reshape(-1, 6)
    notes = [
        f"mrcal {reply['version']}",
        "rms: mrcal's, per coordinate, over its whole lattice (an asymmetric grid's absent points count as zeros)",
    ]
    try:
        cams = [Camera.from_intrinsics(sizes[c][0], sizes[c][1], intr[c], lens) for c in range(len(sizes))]
    except InputError as exc:  # mrcal's own seed can end in a camera that does not project (asymmetric boards)
        return RigReference(name, "failed", notes=notes + [f"mrcal's solve ended in no camera: {exc}"])
    rig = RigModel(
        names,
        cams,
        np.vstack([np.zeros(3), ext[:, :3]]),
        np.vstack([np.zeros(3), ext[:, 3:]]),
    )
    if r["calobject_warp"] is not None:
        notes.append(f"board warp {np.round(r['calobject_warp'], 6).tolist()} (mrcal's units)")
    return RigReference(name, "ok", rig, float(r["rms_per_coord_px"]), notes)


def _frame_in_rig(
    per_cam: Mapping[int, tuple[np.ndarray, np.ndarray]], rig: RigModel, origin: np.ndarray
) -> np.ndarray:
    """mrcal's ``rt_toref`` of one instant's board (lattice origin at ``origin`` mm) from a PnP in the first camera
    that saw it, moved into the rig frame."""
    c = min(per_cam)
    o, p = per_cam[c]
    rv, tv = fit_pose(np.asarray(o, dtype=np.float64), np.asarray(p, dtype=np.float64), rig.cameras[c])
    Rc, Tc = rig.pose(c)
    R = Rc.T @ rodrigues(rv)
    t = Rc.T @ (np.asarray(tv) - Tc) + R @ origin
    cv2 = _cv2()
    return np.concatenate([cv2.Rodrigues(R)[0].ravel(), t])


@dataclass(frozen=True)
class RigAgreement:
    """How far a rig is from a reference rig, per camera (OpenCV's multiview test measures).

    Attributes
    ----------
    rotation_deg : ndarray, shape (n_cameras,)
        ``acos((trace(R_a^T R_b) - 1) / 2)`` of each camera's pose in the rig.
    position_mm : ndarray, shape (n_cameras,)
        ``|R_a^T T_a - R_b^T T_b|``: the distance between the camera centres in the reference camera's frame.
    projection_px : ndarray, shape (n_cameras,)
        The median difference of the two intrinsics' projections of the same rays over a 10 x 10 grid of each
        camera's image (the intrinsics alone; OpenCV's multiview test bounds it by 0.3 px).
    projection_max_px : ndarray, shape (n_cameras,)
        The largest (the image corners: where no board was seen, models extrapolate).
    """

    rotation_deg: np.ndarray
    position_mm: np.ndarray
    projection_px: np.ndarray
    projection_max_px: np.ndarray


def compare_rigs(a: RigModel, b: RigModel) -> RigAgreement:
    """Per-camera agreement of two rigs of the same cameras (in the same order).

    Parameters
    ----------
    a, b : RigModel

    Returns
    -------
    RigAgreement

    Raises
    ------
    ValueError
        Rigs of different camera counts.
    """
    if a.n_cameras != b.n_cameras:
        raise ValueError(f"rigs of {a.n_cameras} and {b.n_cameras} cameras")
    rot, pos, proj, worst = [], [], [], []
    for c in range(a.n_cameras):
        Ra, Ta = a.pose(c)
        Rb, Tb = b.pose(c)
        rot.append(float(rotation_angle_deg(Ra.T @ Rb)))
        pos.append(float(np.linalg.norm(Ra.T @ Ta - Rb.T @ Tb)))
        ca, cb = a.cameras[c], b.cameras[c]
        u, v = np.meshgrid(np.linspace(0, ca.width - 1, 10), np.linspace(0, ca.height - 1, 10))
        uv = np.column_stack([u.ravel(), v.ravel()])
        rays = unproject(uv, ca)
        ok = np.isfinite(rays).all(axis=1)
        got = project_camera(rays[ok], cb)
        d = np.linalg.norm(got - uv[ok], axis=1)
        proj.append(float(np.nanmedian(d)) if ok.any() else float("nan"))
        worst.append(float(np.nanmax(d)) if ok.any() else float("nan"))
    return RigAgreement(np.array(rot), np.array(pos), np.array(proj), np.array(worst))
