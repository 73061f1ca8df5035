"""How well a calibration predicts views it was not fitted to: a view's pose fitted with the intrinsics held
(:func:`fit_pose`), the residual of that prediction (:func:`prediction_error`), and the leave-one-view-out loop
(:func:`leave_one_out`) that every held-out check in circcal runs through (the solver's own, the images pipeline's
with re-correction, and any reference calibrator's).

A model that only fits its own views well (over-fitted distortion, a bias absorbed into the intrinsics) predicts
held-out views worse; the residual of a held-out view has 2N - 6 degrees of freedom (its pose is fitted).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from circcal.errors import CalibrationError, InputError
from circcal.metrics import error_stats
from circcal.model import Camera, project
from circcal.solver.calibrate import calibrate
from circcal.solver.options import CalibrationOptions
from circcal.solver.result import CalibrationResult

__all__ = ["pose_start", "fit_pose", "prediction_error", "leave_one_out", "holdout_errors"]


def pose_start(object_points: np.ndarray, image_points: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """A board pose close to the best one for one view with ``camera`` held fixed, in closed form.

    IPPE (``cv2.SOLVEPNP_IPPE``) on the points flattened onto z = 0: through OpenCV's undistortion for OpenCV's lens
    models, through the points' rays (:func:`circcal.model.unproject`, in front of the camera) for a lens OpenCV's pose
    solvers cannot hold (the fisheye). For noise-free points of a flat board exact through the rays, and within
    OpenCV's undistortion's fixed iteration count through it (~1e-3 px on a -0.2 k1 lens); a start for a
    least-squares pose (:func:`fit_pose`) or a joint solve.

    Parameters
    ----------
    object_points : ndarray
        (N, 3) mm on the board (z = 0, or the near-planar points of a refined board).
    image_points : ndarray
        (N, 2) px.
    camera : Camera

    Returns
    -------
    rvec : ndarray
        (3,) rad.
    tvec : ndarray
        (3,) mm.

    Raises
    ------
    CalibrationError
        No pose is found (fewer than 4 points in front of a fisheye, or solvePnP fails).

    Examples
    --------
    >>> rvec, tvec = pose_start(obj, img, camera)  # doctest: +SKIP
    """
    import cv2

    flat = np.array(object_points, dtype=np.float64).reshape(-1, 3)
    flat[:, 2] = 0.0
    img = np.ascontiguousarray(image_points, dtype=np.float64).reshape(-1, 2)
    if camera.model.pinhole:
        ok, rvec, tvec = cv2.solvePnP(flat[:, None], img[:, None], camera.K, camera.dist, flags=cv2.SOLVEPNP_IPPE)
    else:
        from circcal.model import unproject

        rays = unproject(img, camera)
        front = np.all(np.isfinite(rays), axis=1) & (rays[:, 2] > 1e-6)
        if front.sum() < 4:
            raise CalibrationError("no board pose fits this view with the given camera (too few points in front of it)")
        norm = rays[front, :2] / rays[front, 2:3]
        ok, rvec, tvec = cv2.solvePnP(flat[front, None], norm[:, None], np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise CalibrationError("no board pose fits this view with the given camera (solvePnP failed)")
    return rvec.reshape(3), tvec.reshape(3)


def fit_pose(object_points: np.ndarray, image_points: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """The board pose that best explains one view with ``camera`` held fixed.

    :func:`pose_start`, then Levenberg-Marquardt refinement with the actual points to convergence (OpenCV's
    ``solvePnPRefineLM`` for OpenCV's lens models; scipy's least squares on :func:`circcal.model.project`'s pixel
    residuals for the fisheye).

    Parameters
    ----------
    object_points : ndarray
        (N, 3) mm on the board (z = 0, or the near-planar points of a refined board).
    image_points : ndarray
        (N, 2) px.
    camera : Camera

    Returns
    -------
    rvec : ndarray
        (3,) rad.
    tvec : ndarray
        (3,) mm.

    Raises
    ------
    CalibrationError
        No pose is found.
    """
    import cv2

    o = np.ascontiguousarray(object_points, dtype=np.float64).reshape(-1, 3)
    p = np.ascontiguousarray(image_points, dtype=np.float64).reshape(-1, 2)
    rvec, tvec = pose_start(o, p, camera)
    if not camera.model.pinhole:
        from scipy.optimize import least_squares

        def residuals(x: np.ndarray) -> np.ndarray:
            r: np.ndarray = (project(o, x[:3], x[3:], camera) - p).ravel()
            return r

        fit = least_squares(residuals, np.concatenate([rvec, tvec]), xtol=1e-15, ftol=1e-15, gtol=1e-15)
        return fit.x[:3], fit.x[3:]
    # (3, 1) vectors: solvePnPRefineLM leaves a (3,) start nearly where it was
    rvec, tvec = cv2.solvePnPRefineLM(
        o[:, None], p[:, None], camera.K, camera.dist, rvec.reshape(3, 1), tvec.reshape(3, 1),
        (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15),
    )  # fmt: skip
    return rvec.reshape(3), tvec.reshape(3)


def prediction_error(object_points: np.ndarray, image_points: np.ndarray, camera: Camera) -> dict[str, float]:
    """How well ``camera`` predicts a view it was not fitted to (6 pose parameters fitted, intrinsics held).

    Parameters
    ----------
    object_points : ndarray
        (N, 3) mm.
    image_points : ndarray
        (N, 2) px.
    camera : Camera

    Returns
    -------
    dict
        :func:`circcal.metrics.error_stats` of ``image_points`` against the points projected at the pose
        :func:`fit_pose` finds (px).

    Raises
    ------
    CalibrationError
        No pose is found.
    """
    img = np.asarray(image_points, dtype=np.float64)
    rvec, tvec = fit_pose(object_points, img, camera)
    return error_stats(img - project(np.asarray(object_points, dtype=np.float64), rvec, tvec, camera))


def leave_one_out(
    n_views: int, fit: Callable[[list[int]], Any], held_out: Callable[[int, Any], tuple[np.ndarray, np.ndarray, Camera]]
) -> list[dict[str, Any]]:
    """Predict each view from a model fitted to all the others.

    Parameters
    ----------
    n_views : int
    fit : callable
        ``fit(indices of every other view) -> model``.
    held_out : callable
        ``held_out(k, model) -> (object_points (N, 3) mm, image_points (N, 2) px, camera)``: the held-out view's
        points as that model sees them (e.g. its centres re-corrected under it and its refined board points).

    Returns
    -------
    list of dict
        One per view: ``{"view": k, **error_stats}`` (:func:`prediction_error`), or ``{"view": k, "failed": why}``
        where the other views give no model or the view no pose (an :class:`~circcal.errors.InputError`; anything
        else propagates).
    """
    out: list[dict[str, Any]] = []
    for k in range(n_views):
        try:
            model = fit([i for i in range(n_views) if i != k])
            obj, img, camera = held_out(k, model)
            out.append({"view": k, **prediction_error(obj, img, camera)})
        except InputError as exc:
            out.append({"view": k, "failed": f"{type(exc).__name__}: {exc}"})
    return out


def holdout_errors(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    options: CalibrationOptions | None = None,
) -> list[dict[str, Any]]:
    """Leave-one-view-out check of :func:`~circcal.solver.calibrate` on fixed observations.

    Parameters
    ----------
    object_points : sequence of ndarray
        Per view (N_v, 3) mm.
    image_points : sequence of ndarray
        Per view (N_v, 2) px.
    image_size : tuple of int
        (width, height) px.
    options : CalibrationOptions or None
        The calibration's options (None: the defaults; with ``refine_board`` the view's board points are that
        model's refined ones).

    Returns
    -------
    list of dict
        As :func:`leave_one_out`.
    """

    def fit(rest: list[int]) -> CalibrationResult:
        return calibrate([object_points[i] for i in rest], [image_points[i] for i in rest], image_size, options)

    def held_out(k: int, res: CalibrationResult) -> tuple[np.ndarray, np.ndarray, Camera]:
        return res.board_lookup(np.asarray(object_points[k], dtype=np.float64)), image_points[k], res.camera

    return leave_one_out(len(object_points), fit, held_out)
