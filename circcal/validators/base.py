"""The convenience base of reference adapters (:class:`BaseCalibrator`) and running a reference safely.

Nothing raised inside an adapter reaches the caller: :func:`run_safely` turns a crash, a divergence or bad input into
``status="failed"`` with the message, so one broken reference never stops the others. The interface itself is
:class:`~circcal.validators.reference_protocol.ReferenceCalibrator`, the result
:class:`~circcal.validators.reference_result.ReferenceResult`.

Conventions (those of :mod:`circcal.model`): pixel centres at integer coordinates, OpenCV point order, board points in
mm with z = 0, poses map board to camera (``X_cam = R(rvec) X + tvec``). Residuals are ``observed - projected`` in px.
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from circcal.metrics import error_stats
from circcal.model import Camera, project
from circcal.observations import check_observations
from circcal.validators.divergence import check_divergence
from circcal.validators.lens_support import DEFAULT_LENSES, lens_support
from circcal.validators.reference_result import MODES, Mode, ReferenceResult

__all__ = ["BaseCalibrator", "run_safely", "residuals_of", "pose_problem", "camera_size_problem"]


def pose_problem(rvecs: Any, tvecs: Any, n_views: int) -> str:
    """What is wrong with a calibrator's poses for ``n_views`` views, in one line ("" when they are usable).

    Each of ``rvecs``, ``tvecs`` must hold ``n_views`` poses of 3 numbers: shape (V, 3), or OpenCV's (V, 3, 1) / a
    list of V arrays of shape (3, 1). (Non-finite values are :func:`check_divergence`'s: "diverged".)

    Parameters
    ----------
    rvecs, tvecs : array_like
        The poses as returned (rad; mm).
    n_views : int
        V, the number of views calibrated.

    Returns
    -------
    str
        e.g. "rvecs: expected 8 poses of 3 numbers (shape (8, 3)), got shape (2, 7)"; "" when both are usable.
    """
    for name, value in (("rvecs", rvecs), ("tvecs", tvecs)):
        try:
            a = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):  # ragged, or not numbers
            return f"{name}: expected {n_views} poses of 3 numbers (shape ({n_views}, 3)), got {type(value).__name__}"
        if a.ndim < 1 or len(a) != n_views or a.size != 3 * n_views:
            return f"{name}: expected {n_views} poses of 3 numbers (shape ({n_views}, 3)), got shape {a.shape}"
    return ""


def camera_size_problem(camera: Camera, image_size: tuple[int, int]) -> str:
    """What is wrong with a returned camera's image size, in one line ("" when it is the calibrated size).

    Parameters
    ----------
    camera : circcal.model.Camera
        The returned camera.
    image_size : tuple of int
        (width, height) px the calibrator was given.

    Returns
    -------
    str
        e.g. "the returned camera is 960x540 px; the images are 1920x1080 px (Camera's width, height)".
    """
    w, h = (int(v) for v in image_size)
    if (camera.width, camera.height) == (w, h):
        return ""
    return (
        f"the returned camera is {camera.width}x{camera.height} px; the images are {w}x{h} px (Camera's width, height)"
    )


def residuals_of(
    camera: Camera,
    rvecs: np.ndarray,
    tvecs: np.ndarray,
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
) -> list[np.ndarray]:
    """Per-view residuals ``observed - projected``, projected with :func:`circcal.model.project`.

    Parameters
    ----------
    camera : circcal.model.Camera
        The calibrated camera.
    rvecs, tvecs : ndarray, shape (V, 3)
        Board-to-camera poses (rad; mm).
    object_points : sequence of ndarray, shape (N_v, 3)
        Board points per view, mm.
    image_points : sequence of ndarray, shape (N_v, 2)
        Observed centres per view, px.

    Returns
    -------
    list of ndarray, shape (N_v, 2)
        Residuals per view, px.

    Raises
    ------
    ValueError
        Not one pose per view (the message gives both counts).
    """
    rvecs, tvecs = np.asarray(rvecs), np.asarray(tvecs)
    if not len(rvecs) == len(tvecs) == len(object_points) == len(image_points):
        raise ValueError(
            f"{len(rvecs)} rvecs and {len(tvecs)} tvecs for {len(object_points)} views of object points and "
            f"{len(image_points)} of image points: expected one pose per view"
        )
    return [
        np.asarray(p, dtype=np.float64) - project(o, r, t, camera)
        for o, p, r, t in zip(object_points, image_points, rvecs, tvecs)
    ]


class BaseCalibrator:
    """Convenience base for reference adapters.

    Subclasses set ``name``, implement ``_version``, ``_available`` and ``_calibrate`` (and ``_calibrate_images`` where
    the reference has its own detector). The public methods never raise.

    Attributes
    ----------
    name : str
        The reference's registry name.
    modes : tuple of str
        Modes this reference distinguishes; others give the same estimator for both.
    lenses : tuple of str
        Lens models this reference fits (:data:`circcal.model.LENS_MODELS` names).
    lens : str
        The one it fits now (subclasses take ``lens=`` in their constructor).
    unsupported_lenses : dict of str to str
        Lens -> why not, for the others.
    """

    name: str = "base"
    #: modes this reference distinguishes; others give the same estimator for both.
    modes: tuple[str, ...] = MODES
    #: lens models this reference fits (:data:`circcal.model.LENS_MODELS` names); ``lens``: the one it fits now
    #: (subclasses take ``lens=`` in their constructor); ``unsupported_lenses``: lens -> why not, for the others.
    lenses: tuple[str, ...] = DEFAULT_LENSES
    lens: str = "opencv5"
    unsupported_lenses: dict[str, str] = {}

    # -- to implement ---------------------------------------------------------------------------------------------
    def _version(self) -> str:
        return "unknown"

    def _available(self) -> tuple[bool, str]:
        return True, ""

    def _calibrate(
        self,
        object_points: list[np.ndarray],
        image_points: list[np.ndarray],
        image_size: tuple[int, int],
        *,
        mode: str,
        initial: Camera | None,
    ) -> ReferenceResult:
        raise NotImplementedError

    def _calibrate_images(
        self, paths: Sequence[Any], board: Any, image_size: tuple[int, int] | None, *, mode: str, initial: Camera | None
    ) -> ReferenceResult:
        return self.result(
            mode,
            "unsupported",
            f"{self.name} has no circle-grid detector of its own; with --observations circcal it fits circcal's centres",
        )

    # -- public, never raising ------------------------------------------------------------------------------------
    @property
    def version(self) -> str:
        try:
            return str(self._version())
        except Exception as exc:  # noqa: BLE001
            return f"unknown ({exc})"

    def available(self) -> tuple[bool, str]:
        """Whether the reference can run here (never raises).

        Returns
        -------
        tuple of (bool, str)
            ``(True, "")``, or ``(False, reason)``; an exception in ``_available`` becomes its type and message.
        """
        try:
            ok, why = self._available()
            return bool(ok), str(why)
        except Exception as exc:  # noqa: BLE001
            return False, f"{type(exc).__name__}: {exc}"

    def calibrate_observations(
        self,
        object_points: Sequence[np.ndarray],
        image_points: Sequence[np.ndarray],
        image_size: tuple[int, int],
        *,
        mode: Mode = "fair",
        initial: Camera | None = None,
    ) -> ReferenceResult:
        """Calibrate from given centres.

        The observations are checked with :func:`circcal.observations.check_observations` and the lens with
        :func:`lens_support`; the whole call runs under :func:`run_safely`, so it never raises.

        Parameters
        ----------
        object_points : sequence of ndarray, shape (N_v, 3)
            Board points per view, mm, z = 0.
        image_points : sequence of ndarray, shape (N_v, 2)
            Detected centres per view, px.
        image_size : tuple of int
            (width, height) px.
        mode : {"fair", "default"}
            "fair": plain least squares, the estimator of cv2.calibrateCamera; "default": what the reference's users get
            out of the box.
        initial : circcal.model.Camera, optional
            A starting camera, for references that take one.

        Returns
        -------
        ReferenceResult
            Status "ok", or "unavailable" / "unsupported" / "failed" with the reason (bad observations, an unfitted
            lens,
            a crash or a divergence).
        """

        def go() -> ReferenceResult:
            self._check_lens()
            obj, img, size = check_observations(object_points, image_points, image_size)
            return self._calibrate(obj, img, size, mode=mode, initial=initial)

        return run_safely(go, name=self.name, version=lambda: self.version, mode=mode, available=self.available)

    def calibrate_images(
        self,
        paths: Sequence[Any],
        board: Any,
        image_size: tuple[int, int] | None = None,
        *,
        mode: Mode = "fair",
        initial: Camera | None = None,
    ) -> ReferenceResult:
        """Detect with the reference's own detector, then calibrate (never raises).

        Parameters
        ----------
        paths : sequence of path-like
            Image files.
        board : circcal.board.Board
            The calibration target.
        image_size : tuple of int, optional
            (width, height) px; from the images when None.
        mode : {"fair", "default"}
            Estimator to run.
        initial : circcal.model.Camera, optional
            A starting camera, for references that take one.

        Returns
        -------
        ReferenceResult
            "unsupported" when the reference has no detector of its own.
        """

        def go() -> ReferenceResult:
            self._check_lens()
            return self._calibrate_images(list(paths), board, image_size, mode=mode, initial=initial)

        return run_safely(go, name=self.name, version=lambda: self.version, mode=mode, available=self.available)

    # -- helpers for subclasses -----------------------------------------------------------------------------------
    def _check_lens(self) -> None:
        """``NotImplementedError`` (status "unsupported", the reason as message) when ``self.lens`` is not one of
        ``self.lenses``."""
        ok, why = lens_support(self, self.lens)
        if not ok:
            raise NotImplementedError(why)

    def result(self, mode: str, status: str, message: str = "", **kw: Any) -> ReferenceResult:
        """A :class:`ReferenceResult` stamped with this reference's name and version.

        Parameters
        ----------
        mode : str
            The mode solved.
        status : str
            One of :data:`STATUSES`.
        message : str
            Why, when not ok.
        **kw
            Further :class:`ReferenceResult` fields.

        Returns
        -------
        ReferenceResult
        """
        return ReferenceResult(name=self.name, version=self.version, mode=mode, status=status, message=message, **kw)

    def finish(
        self,
        mode: str,
        camera: Camera,
        rvecs: np.ndarray,
        tvecs: np.ndarray,
        object_points: list[np.ndarray],
        image_points: list[np.ndarray],
        t0: float,
        *,
        std: dict[str, float] | None = None,
        residuals: list[np.ndarray] | None = None,
        views: list[int] | None = None,
        message: str = "",
        **extra: Any,
    ) -> ReferenceResult:
        """Assemble an "ok" result and check it for divergence.

        Parameters
        ----------
        mode : str
            The mode solved.
        camera : circcal.model.Camera
            The calibrated camera.
        rvecs, tvecs : array_like, shape (V, 3)
            Board-to-camera poses (rad; mm); reshaped to (V, 3).
        object_points : list of ndarray, shape (N_v, 3)
            Board points used, per view, mm.
        image_points : list of ndarray, shape (N_v, 2)
            Centres used, per view, px.
        t0 : float
            ``time.perf_counter()`` at the start of the solve (s).
        std : dict of str to float, optional
            Standard deviations by parameter name.
        residuals : list of ndarray, shape (N_v, 2), optional
            Residuals in px; computed with :mod:`circcal.model` (:func:`residuals_of`) when None.
        views : list of int, optional
            Indices of the views used; all, in order, when None.
        message : str
            A note for the result.
        **extra
            Stored in ``extra``.

        Returns
        -------
        ReferenceResult
            Status "ok", or "failed" when :func:`check_divergence` finds it diverged.

        Raises
        ------
        ValueError
            Poses that are not one (3,) rvec and tvec per view (:func:`pose_problem`).
        """
        problem = pose_problem(rvecs, tvecs, len(object_points))
        if problem:
            raise ValueError(problem)
        rvecs = np.asarray(rvecs, dtype=np.float64).reshape(-1, 3)
        tvecs = np.asarray(tvecs, dtype=np.float64).reshape(-1, 3)
        if residuals is None:
            residuals = residuals_of(camera, rvecs, tvecs, object_points, image_points)
        errors = error_stats(np.concatenate([r.reshape(-1, 2) for r in residuals]))
        res = self.result(
            mode,
            "ok",
            message,
            camera=camera,
            std=std,
            rvecs=rvecs,
            tvecs=tvecs,
            residuals=residuals,
            errors=errors,
            time_s=time.perf_counter() - t0,
            object_points=object_points,
            image_points=image_points,
            views=list(range(len(object_points))) if views is None else list(views),
            extra=dict(extra),
        )
        return check_divergence(res)


def run_safely(
    fn: Callable[[], ReferenceResult],
    *,
    name: str,
    version: str | Callable[[], str] = "unknown",
    mode: str = "fair",
    available: Callable[[], tuple[bool, str]] | None = None,
) -> ReferenceResult:
    """Run an adapter call and always return a :class:`ReferenceResult`.

    ``available`` (optional) is checked first: a missing reference gives status "unavailable" with its reason. Any
    exception becomes status "failed" with ``"<ExceptionType>: message"`` (traceback in ``extra``); a
    ``NotImplementedError`` becomes "unsupported". An "ok" result still goes through :func:`check_divergence`.

    Parameters
    ----------
    fn : callable
        Takes nothing, returns a :class:`ReferenceResult`.
    name : str
        The reference's name, for the results built here.
    version : str or callable
        Its version, or a function giving it (an exception there gives "unknown (...)").
    mode : str
        The mode; one not in :data:`MODES` gives status "failed".
    available : callable, optional
        Returns ``(ok, why)``.

    Returns
    -------
    ReferenceResult
        Never raises.
    """
    t0 = time.perf_counter()

    def ver() -> str:
        try:
            return version() if callable(version) else str(version)
        except Exception as exc:  # noqa: BLE001
            return f"unknown ({exc})"

    if mode not in MODES:
        return ReferenceResult(
            name, ver(), str(mode), "failed", f"unknown mode {mode!r}; expected one of {', '.join(MODES)}"
        )
    if available is not None:
        try:
            ok, why = available()
        except Exception as exc:  # noqa: BLE001
            ok, why = False, f"{type(exc).__name__}: {exc}"
        if not ok:
            return ReferenceResult(name, ver(), mode, "unavailable", why)
    try:
        res = fn()
        if not isinstance(res, ReferenceResult):
            raise TypeError(f"adapter returned {type(res).__name__}, expected ReferenceResult")
        return check_divergence(res)
    except NotImplementedError as exc:
        return ReferenceResult(
            name, ver(), mode, "unsupported", str(exc) or "not supported", time_s=time.perf_counter() - t0
        )
    except Exception as exc:  # noqa: BLE001
        return ReferenceResult(
            name,
            ver(),
            mode,
            "failed",
            f"{type(exc).__name__}: {exc}",
            time_s=time.perf_counter() - t0,
            extra={"traceback": traceback.format_exc()},
        )
