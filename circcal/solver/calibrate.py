"""Calibration solver: Zhang's closed form, then Levenberg-Marquardt over intrinsics, distortion and all board poses.

Model and conventions are :mod:`circcal.model`'s (``lens``: OpenCV's pinhole + ``[k1, k2, p1, p2, k3]`` by default,
the rational and thin-prism models, or cv2.fisheye's; pixel centres at integer coordinates). The refinement
minimises the sum of squared reprojection errors (px) with an analytic Jacobian that is sparse by construction: each
view's residuals depend only on the intrinsics and that view's six pose parameters (a dense intrinsic block beside a
block-diagonal pose part). The default solver (:func:`circcal.solver.lm.levenberg_marquardt`) is
Levenberg-Marquardt that solves each damped step exactly by eliminating the 6x6 pose blocks (Schur complement), as
OpenCV does; ``CalibrationOptions(solver="scipy")`` runs ``scipy.optimize.least_squares`` (TRF, sparse Jacobian, LSMR) on the same
residuals and Jacobian as a cross-check (it stops ~1e-7 relative short of the minimum and is
~10x slower, hence not the default). The covariance of the intrinsics is ``sigma^2 (J^T J)^-1`` restricted to the
intrinsics via the Schur complement of the pose blocks (poses marginalised), ``sigma^2 = SSR / (2N - n_params)``:
the same estimate as ``cv2.calibrateCameraExtended``'s standard deviations.

Modules: how a calibration is made (:mod:`circcal.solver.options`), the problem (:mod:`circcal.solver.problem`),
the solvers (:mod:`circcal.solver.lm`), Zhang's closed form (:mod:`circcal.solver.zhang`), outlier rejection around
the solve (:mod:`circcal.solver.outliers`), the result (:mod:`circcal.solver.result`); this module ties them together
with the covariance. The images pipeline (detect -> calibrate -> re-correct) is :mod:`circcal.pipeline`.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from circcal.errors import CalibrationError, DegenerateViewsError, InputError
from circcal.metrics import error_stats_per_view
from circcal.model import DEFAULT_LENS, Camera, lens_model, pixel_to_normalized, theta_max, undistort, unproject
from circcal.observations import check_observations
from circcal.solver.boardpoints import board_model, warp_box
from circcal.solver.covariance import normalised_information, state_covariance
from circcal.solver.fisheye_start import fisheye_start, pinhole_start, poses_from_rays
from circcal.solver.lm import global_information, is_sane, solve
from circcal.solver.options import ASPECT_RATIO, CalibrationOptions
from circcal.solver.outliers import reject_outliers
from circcal.solver.problem import Problem
from circcal.solver.result import CalibrationResult
from circcal.solver.zhang import homographies, poses_from_homographies, view_tilts_deg, zhang

__all__ = [
    "CalibrationError",
    "CalibrationOptions",
    "DegenerateViewsError",
    "CalibrationResult",
    "calibrate",
]

#: A free focal length whose standard deviation per 1 px of per-coordinate noise exceeds this fraction of itself is
#: called unobservable (DegenerateViewsError). Well-spread 14-view sets give ~0.005; boards all within a few degrees
#: of fronto-parallel 0.5 and more.
MAX_UNIT_REL_STD_F = 0.2
#: The global information matrix (normalised to a unit diagonal) is taken as singular beyond this condition number:
#: its inverse would be rounding (double precision carries ~16 digits).
MAX_INFORMATION_CONDITION = 1e14
#: Views tilted less than this (deg) against the image plane are named when the focal length is unobservable.
FLAT_VIEW_TILT_DEG = 10.0
#: A residual RMS per coordinate above this (px) after calibration earns a warning: no detector error is that large,
#: so it is an outlier, a wrong board geometry or a lens the model cannot fit.
LARGE_RESIDUAL_PX = 2.0
#: Rounds of Zhang's linear radial estimate for the restart when the distortion-free start fails.
RESTART_DISTORTION_ROUNDS = 10


def initial_poses(
    obj: Sequence[np.ndarray], img: Sequence[np.ndarray], camera: Camera
) -> tuple[np.ndarray, np.ndarray]:
    """Poses from homographies of the undistorted, normalised observations under ``camera``.

    Fisheye: from their rays (:func:`circcal.solver.fisheye_start.poses_from_rays`).

    Parameters
    ----------
    obj : sequence of ndarray
        Per view (N_v, 3) mm.
    img : sequence of ndarray
        Per view (N_v, 2) px.
    camera : Camera

    Returns
    -------
    rvecs : ndarray
        (V, 3) rad.
    tvecs : ndarray
        (V, 3) mm.

    Raises
    ------
    CalibrationError
        A point ``camera`` cannot unproject, or a view without a homography.
    """
    if not camera.model.pinhole:
        rays = [unproject(p, camera) for p in img]
        if not all(np.all(np.isfinite(r)) for r in rays):
            raise CalibrationError("some observed points lie beyond the initial fisheye camera's field")
        return poses_from_rays(obj, rays)
    xn = [undistort(pixel_to_normalized(p, camera), camera.dist) for p in img]
    if not all(np.all(np.isfinite(x)) for x in xn):
        raise CalibrationError("the initial camera's distortion cannot be inverted at some observed points")
    return poses_from_homographies(homographies([o[:, :2] for o in obj], xn), np.eye(3))


def calibrate(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    options: CalibrationOptions | None = None,
    *,
    initial: Camera | None = None,
    start_poses: tuple[np.ndarray, np.ndarray] | None = None,
) -> CalibrationResult:
    """Calibrate a camera from planar-board correspondences.

    Parameters
    ----------
    object_points : sequence of ndarray
        Per view (N_v, 3) board coordinates in mm with z = 0; views may hold different points (partial boards),
        N_v >= 6.
    image_points : sequence of ndarray
        Per view (N_v, 2) pixels (OpenCV convention: pixel centres at integer coordinates).
    image_size : tuple of int
        (width, height) px.
    options : CalibrationOptions or None
        How (:class:`circcal.solver.options.CalibrationOptions`): the lens model, the parameters held, board
        refinement, the solver, outlier rejection. None: the defaults for ``initial``'s lens model (else opencv5).
    initial : Camera or None
        Start from this camera (like OpenCV's USE_INTRINSIC_GUESS) instead of Zhang's closed form; its lens model
        must be ``options.lens``.
    start_poses : tuple of ndarray or None
        ``(rvecs, tvecs)``, each (V, 3) rad / mm: start the views' poses here instead of from ``initial``'s
        homographies (a refit of views a calibration already posed, e.g. leave-one-view-out: it skips V pose
        estimates and starts the solve at its answer). Only with ``initial`` and without ``options.outlier_rule``.

    Returns
    -------
    CalibrationResult
        With ``outliers`` (:class:`circcal.solver.outliers.Rejections`) when ``options.outlier_rule`` is set.

    Raises
    ------
    CalibrationError
        (a ValueError) NaN, out-of-image or non-planar points, fewer than 3 views or 6 points per view, a diverged
        solve, and (:class:`DegenerateViewsError`) views that leave the focal length unobservable (e.g. boards
        nearly parallel to the image plane), naming those views.
    InputError
        fx or fy held without an initial camera.
    ValueError
        ``initial`` of another lens model or image size than the calibration's.

    Notes
    -----
    Held parameters (``options.fixed``) stay at ``initial``'s values, else at their defaults (0 for a distortion
    coefficient, the image centre for cx, cy, 1 for ``aspect_ratio``). Reaching ``options.max_iterations`` warns
    (RuntimeWarning) and returns ``converged=False``. What each option does, the starts and the two solvers:
    docs/solver.md, "calibrate(): options in detail".

    Examples
    --------
    >>> from circcal.solver import CalibrationOptions, calibrate
    >>> res = calibrate(object_points, image_points, (1280, 960), CalibrationOptions(lens="rational"))  # doctest: +SKIP
    >>> res.camera.fx, res.errors["rms_per_coord_px"]  # doctest: +SKIP
    """
    if options is None:
        options = CalibrationOptions(lens=initial.lens if initial is not None else DEFAULT_LENS)
    if start_poses is not None and (initial is None or options.outlier_rule is not None):
        raise ValueError("start_poses need an initial camera and no outlier rule")
    if options.outlier_rule is not None:
        plain = options.replace(outlier_rule=None)
        return reject_outliers(
            lambda o, i, start: calibrate(o, i, image_size, plain, initial=start),
            object_points,
            image_points,
            image_size,
            options.outlier_rule,
            initial,
        )
    return _calibrate(object_points, image_points, image_size, options, initial, start_poses)


def _calibrate(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    options: CalibrationOptions,
    initial: Camera | None,
    start_poses: tuple[np.ndarray, np.ndarray] | None = None,
) -> CalibrationResult:
    """One plain solve (:func:`calibrate` without outlier rejection)."""
    lens = options.lens
    model = lens_model(lens)
    if initial is not None and initial.lens != lens:
        raise ValueError(f"initial camera has lens {initial.lens!r} but lens={lens!r}")
    names = model.param_names
    obj, img, (w, h) = check_observations(object_points, image_points, image_size)
    centre = (0.5 * (w - 1), 0.5 * (h - 1))
    fixed = options.fixed
    if initial is None and {"fx", "fy"} & set(fixed):
        raise InputError("fixed: fx and fy can be held only at an initial camera's values (give initial=)")
    fix_principal_point = "cx" in fixed and "cy" in fixed
    held_dist = [k for k, name in enumerate(names) if k >= 4 and name in fixed]
    aspect = (initial.fx / initial.fy if initial is not None else 1.0) if ASPECT_RATIO in fixed else None

    def zhang_start(distortion_rounds: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Intrinsics (4 + n_dist,) and poses from Zhang's closed form (fisheye: the equidistant start),
        honouring the fixed principal point / aspect."""
        start = np.zeros(len(names))
        c = None
        if model.pinhole:
            try:
                z = zhang(
                    obj,
                    img,
                    (w, h),
                    principal_point=centre if fix_principal_point else None,
                    aspect_ratio=aspect,
                    distortion_rounds=distortion_rounds,
                )
            except DegenerateViewsError as e:
                # a wide lens (rational, thin prism) can defeat the distortion-free closed form where no view is
                # flat: start from the equidistant lens instead, its radial profile atan(r) / r in the rational
                # model's Pade form (1 + 4/15 r^2) / (1 + 3/5 r^2). Otherwise, where at least 3 views are tilted,
                # distortion and noise on nearly flat views defeated it (OpenCV's real multiview rigs): start from
                # the pinhole whose focal length reprojects the views best; the solve's covariance then says
                # whether the focal length is determined.
                if model.n_dist < 8 or e.views:
                    if not e.views or len(obj) - len(e.views) < 3:
                        raise
                    c, rvecs, tvecs = pinhole_start(
                        obj, img, (w, h), principal_point=centre if fix_principal_point else None, aspect_ratio=aspect
                    )
            else:
                c, rvecs, tvecs = z.camera, z.rvecs, z.tvecs
                start[4:6] = c.dist[0], c.dist[1]
            if c is None:  # the wide lens's start (above)
                c, rvecs, tvecs = fisheye_start(
                    obj, img, (w, h), principal_point=centre if fix_principal_point else None, aspect_ratio=aspect
                )
                start[names.index("k1")], start[names.index("k4")] = 4.0 / 15.0, 3.0 / 5.0
        else:
            c, rvecs, tvecs = fisheye_start(
                obj, img, (w, h), principal_point=centre if fix_principal_point else None, aspect_ratio=aspect
            )
        start[:4] = c.fx, c.fy, c.cx, c.cy
        start[held_dist] = 0.0  # held coefficients stay at 0 (the rational fallback's k1, k4 included)
        for k, name in ((2, "cx"), (3, "cy")):
            if name in fixed:
                start[k] = centre[k - 2]
        if aspect is not None:
            start[0] = aspect * start[1]
        return start, rvecs, tvecs

    if initial is None:
        intr, rvecs, tvecs = zhang_start(0)
    else:
        if (initial.width, initial.height) != (w, h):
            raise ValueError(f"initial camera is {initial.width}x{initial.height} but image_size is {w}x{h}")
        intr = initial.intrinsics.copy()
        if start_poses is None:
            rvecs, tvecs = initial_poses(obj, img, initial)
        else:
            rvecs, tvecs = (np.array(v, dtype=np.float64).reshape(len(obj), 3) for v in start_poses)
    if aspect is not None:
        intr[0] = aspect * intr[1]

    free = [k for k, name in enumerate(names) if name not in fixed and not (aspect is not None and k == 0)]
    board = board_model(obj, options.board_gauge) if options.refine_board else None
    if board is not None and board.held_unseen:
        warnings.warn(
            f"board refinement: {len(board.held_unseen)} point(s) seen in fewer than 3 views are held at "
            f"their nominal positions (indices {board.held_unseen[:10]})",
            RuntimeWarning,
            stacklevel=3,
        )
    box = warp_box(obj) if options.board_warp else None
    prob = Problem(obj, img, intr, free, aspect, board, lens, box)
    x0 = prob.pack(intr, rvecs, tvecs)

    max_iterations, solver = options.max_iterations, options.solver
    x, n_iter, converged, message = solve(prob, x0, max_iterations, solver)
    if initial is None and model.pinhole and not is_sane(prob, x, converged):
        # Strong distortion can defeat the distortion-free closed form: restart from Zhang with a radial estimate.
        intr, rvecs, tvecs = zhang_start(RESTART_DISTORTION_ROUNDS)
        prob = Problem(obj, img, intr, free, aspect, board, lens, box)
        x, n_iter2, converged, message = solve(prob, prob.pack(intr, rvecs, tvecs), max_iterations, solver)
        n_iter += n_iter2
    f, Xc = prob.residuals(x)
    p = prob.intrinsics(x)
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(f))):
        raise CalibrationError(
            "the solver diverged (non-finite parameters or residuals); check the point "
            "correspondences (board order, image_size) and the views"
        )
    if p[0] <= 0 or p[1] <= 0:
        raise CalibrationError(
            f"the solver diverged to a non-positive focal length (fx={p[0]:.4g}, fy={p[1]:.4g}); "
            f"check the point correspondences and the views"
        )
    if model.pinhole:
        outside = Xc[:, 2] <= 0
        where = "behind the camera"
    else:
        outside = np.arctan2(np.hypot(Xc[:, 0], Xc[:, 1]), Xc[:, 2]) > theta_max(p[4:])
        where = "beyond the fisheye's one-to-one field"
    if np.any(outside):
        bad = sorted(set(prob.view[outside].tolist()))
        raise CalibrationError(f"the solver diverged: board points {where} in view(s) {bad}")
    if not converged:
        warnings.warn(
            f"calibration did not converge ({message}); the model may be inaccurate", RuntimeWarning, stacklevel=3
        )

    camera = Camera.from_intrinsics(w, h, p, lens)
    rv, tv = prob.poses(x)
    m = 2 * len(prob.X)
    dof = m - prob.n
    ssr = float(f @ f)
    if dof <= 0:
        raise CalibrationError(f"{m} residuals for {prob.n} parameters: add views or points")
    sigma2 = ssr / dof

    # Uncertainty of the intrinsics (and board points), poses marginalised.
    Sn, scale, cond = normalised_information(global_information(prob, x))
    if not np.isfinite(cond) or cond > MAX_INFORMATION_CONDITION:
        cov_global_unit = np.full(Sn.shape, np.inf)
    else:
        cov_global_unit = np.linalg.inv(Sn) / np.outer(scale, scale)
    cov_free_unit = cov_global_unit[: prob.nf, : prob.nf]
    cov9_unit = prob.T @ cov_free_unit @ prob.T.T if np.all(np.isfinite(cov_free_unit)) else None
    f_idx = 1 if aspect is not None else 0
    unit_rel = float(np.sqrt(cov9_unit[f_idx, f_idx]) / p[f_idx]) if cov9_unit is not None else float("inf")
    if cov9_unit is None or not np.isfinite(unit_rel) or unit_rel > MAX_UNIT_REL_STD_F:
        trade = _undetermined_coefficients(Sn, prob, names)
        if trade:  # the singular direction lies in the lens model's coefficients, not in the focal length
            raise CalibrationError(
                f"the {lens} lens model's {', '.join(trade)} are not determined by these {len(obj)} views (they "
                f"trade off against each other; condition number {cond:.3g}): fit a model with fewer coefficients "
                f"(opencv5: calibrate's --lens opencv5 or --lens auto, calibrate-rig's --lens NAME=opencv5), or add views "
                f"that reach the image's corners and edges"
            )
        tilts = view_tilts_deg(rv)
        flat = [int(i) for i in np.flatnonzero(tilts < FLAT_VIEW_TILT_DEG)]
        listing = ", ".join(f"{i} ({tilts[i]:.1f} deg)" for i in flat) or f"none below {FLAT_VIEW_TILT_DEG:g} deg"
        raise DegenerateViewsError(
            f"focal length is not observable from these {len(obj)} views: std(f) would be {100 * unit_rel:.3g}% of f "
            f"per 1 px of noise (limit {100 * MAX_UNIT_REL_STD_F:g}%); condition number of the intrinsic "
            f"information matrix {cond:.3g}. Views nearly parallel to the image plane: {listing}. Add views with "
            f"the board tilted 20-50 deg about different axes.",
            flat,
            cond,
        )
    cov9 = sigma2 * cov9_unit
    std_arr = np.sqrt(np.maximum(np.diag(cov9), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov9 / np.outer(std_arr, std_arr)
    corr[std_arr == 0, :] = np.nan
    corr[:, std_arr == 0] = np.nan
    std = {name: float(s) for name, s in zip(names, std_arr)}

    board_points: np.ndarray | None = None
    board_std: np.ndarray | None = None
    if board is not None:
        board_points = prob.board_points(x)
        std_flat = np.zeros(board.nominal.size)
        std_flat[board.free] = np.sqrt(np.maximum(sigma2 * np.diag(cov_global_unit)[prob.nf :], 0.0))
        board_std = std_flat.reshape(-1, 3)
    warp = prob.warp(x)
    warp_cov = None if warp is None else sigma2 * cov_global_unit[prob.nf + prob.nb :, prob.nf + prob.nb :]

    residuals = [-r for r in np.split(f.reshape(-1, 2), np.cumsum(prob.counts)[:-1])]
    errors, per_view_errors = error_stats_per_view(residuals)  # once per solve, every view in one pass
    if errors["rms_per_coord_px"] > LARGE_RESIDUAL_PX:
        warnings.warn(
            f"large reprojection error after calibration ({errors['rms_per_coord_px']:.3g} px RMS per "
            f"coordinate): outliers, wrong board geometry or a lens the {lens} model cannot fit",
            RuntimeWarning,
            stacklevel=3,
        )
    return CalibrationResult(
        camera=camera,
        std=std,
        correlation=corr,
        rvecs=rv,
        tvecs=tv,
        residuals=residuals,
        errors=errors,
        per_view_errors=per_view_errors,
        sigma_px=float(np.sqrt(sigma2)),
        n_iterations=int(n_iter),
        converged=bool(converged),
        fixed=tuple(fixed),
        n_params=int(prob.n),
        board_nominal=None if board is None else board.nominal,
        board_points=board_points,
        board_std=board_std,
        board_gauge=None if board is None else board.gauge,
        board_warp=warp,
        board_warp_cov=warp_cov,
        board_warp_box=box,
        covariance=state_covariance(prob, x, cov_global_unit, float(np.sqrt(sigma2))),
        object_points=obj,
        image_points=img,
    )


def _undetermined_coefficients(Sn: np.ndarray, prob: Problem, names: tuple[str, ...]) -> list[str]:
    """The distortion coefficients that carry the information matrix's weakest direction (normalised, free
    intrinsics), where they carry at least 90 % of it; empty where the focal length or the principal point is in
    it (then the views, not the lens model, are the question)."""
    block = Sn[: prob.nf, : prob.nf]
    if not np.all(np.isfinite(block)):  # no direction to name: the views, not the lens model, are the question
        return []
    ev, vec = np.linalg.eigh(block)
    weakest = vec[:, 0] ** 2  # unit norm: each free intrinsic's share
    free_names = [names[int(np.flatnonzero(prob.T[:, j])[-1])] for j in range(prob.nf)]
    dist_share = sum(w for n, w in zip(free_names, weakest) if n not in ("fx", "fy", "cx", "cy"))
    if dist_share < 0.9:
        return []
    return [n for n, w in zip(free_names, weakest) if n not in ("fx", "fy", "cx", "cy") and w >= 0.05]
