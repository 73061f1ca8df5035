"""The interface every reference calibrator implements, and the result it hands back.

A reference calibrator (OpenCV, mrcal, kornia, pycolmap, or a third party's plug-in) takes the *same* 2-D centres as
circcal and returns a :class:`ReferenceResult`. Nothing raised inside an adapter reaches the caller: :func:`run_safely`
turns a crash, a divergence or bad input into ``status="failed"`` with the message, so one broken reference never
stops the others.

Conventions (those of :mod:`circcal.model`): pixel centres at integer coordinates, OpenCV point order, board points in
mm with z = 0, poses map board to camera (``X_cam = R(rvec) X + tvec``). Residuals are ``observed - projected`` in px.
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from circcal.jsonio import jsonable
from circcal.metrics import error_stats
from circcal.model import Camera, project, transform
from circcal.observations import check_observations

__all__ = [
    "STATUSES",
    "MODES",
    "ReferenceResult",
    "ReferenceCalibrator",
    "BaseCalibrator",
    "run_safely",
    "residuals_of",
    "DIVERGED_RMS_PX",
    "seed_camera",
    "check_divergence",
    "DEFAULT_LENSES",
    "lens_support",
    "fisheye_seed_focal",
    "rational_pole",
]

STATUSES: tuple[str, ...] = ("ok", "unavailable", "unsupported", "failed")
MODES: tuple[str, ...] = ("fair", "default")
Mode = Literal["fair", "default"]

#: The lens models (:data:`circcal.model.LENS_MODELS` names) a reference fits when it does not say: OpenCV's five
#: coefficients. A reference that fits more lists them in its ``lenses`` attribute and takes ``lens=`` in its
#: constructor (``registry.get(name, lens="rational")``); for the others it may say why in ``unsupported_lenses``.
DEFAULT_LENSES: tuple[str, ...] = ("opencv5",)

#: A solve whose RMS per point exceeds this (px) is reported as diverged (status "failed").
DIVERGED_RMS_PX = 100.0


@dataclass
class ReferenceResult:
    """What one reference calibrator produced on one problem.

    Attributes
    ----------
    name, version : str
        The reference and its version.
    mode : str
        "fair" or "default" (see :data:`MODES`).
    status : str
        "ok" | "unavailable" (reference not installed) | "unsupported" (input it cannot handle, e.g. an asymmetric grid
        for mrcal) | "failed" (crash, divergence, bad input).
    message : str
        Why, when the status is not "ok".
    camera : circcal.model.Camera or None
        The calibrated camera (None unless ok).
    std : dict of str to float, or None
        Standard deviations keyed by ``circcal.model.param_names(camera.lens)`` (a fixed parameter has 0.0), or None
        when the reference offers none.
    rvecs, tvecs : ndarray, shape (V, 3), or None
        Board-to-camera poses (rad; mm).
    residuals : list of ndarray, shape (N_v, 2), or None
        Per view, observed - projected in px (NaN for points a reference dropped as outliers).
    errors : dict or None
        :func:`circcal.metrics.error_stats` of all residuals.
    time_s : float
        Wall time of the solve (s).
    object_points, image_points : list of ndarray or None
        The observations actually used, per view: (N_v, 3) mm and (N_v, 2) px.
    views : list of int or None
        Indices (into the caller's views/images) of the views used.
    extra : dict
        Reference-specific facts (fixed parameters, flags, mrcal statistics, seeds) that a report should show.

    Raises
    ------
    ValueError
        ``status`` is not one of :data:`STATUSES` (a bug in the adapter).
    """

    name: str
    version: str
    mode: str
    status: str
    message: str = ""
    camera: Camera | None = None
    std: dict[str, float] | None = None
    rvecs: np.ndarray | None = None
    tvecs: np.ndarray | None = None
    residuals: list[np.ndarray] | None = None
    errors: dict[str, float] | None = None
    time_s: float = 0.0
    object_points: list[np.ndarray] | None = None
    image_points: list[np.ndarray] | None = None
    views: list[int] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {', '.join(STATUSES)}, got {self.status!r}")

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def summary(self) -> str:
        """One line for logs and CLI tables.

        Returns
        -------
        str
            Name, version, mode and status; for an ok result the intrinsics, distortion, RMS per point (px) and time
            (s),
            otherwise the message.
        """
        head = f"{self.name} {self.version} [{self.mode}]: {self.status}"
        if not self.ok:
            return f"{head}: {self.message}"
        c = self.camera
        e = self.errors or {}
        return (
            f"{head}: fx={c.fx:.4f} fy={c.fy:.4f} cx={c.cx:.4f} cy={c.cy:.4f} "
            f"dist={np.array2string(c.dist, precision=5)} rms_per_point={e.get('rms_per_point_px', np.nan):.4f} px "
            f"({self.time_s:.3f} s)"
        )

    def to_dict(self) -> dict[str, Any]:
        """The result as a JSON-ready dict.

        Returns
        -------
        dict
            Every field but the observations; arrays as lists, residuals per view, ``extra`` made JSON-safe.
        """

        def arr(a: Any) -> Any:
            return None if a is None else np.asarray(a, dtype=float).tolist()

        return {
            "name": self.name,
            "version": self.version,
            "mode": self.mode,
            "status": self.status,
            "message": self.message,
            "camera": None if self.camera is None else self.camera.to_dict(),
            "std": self.std,
            "rvecs": arr(self.rvecs),
            "tvecs": arr(self.tvecs),
            "residuals": None if self.residuals is None else [arr(r) for r in self.residuals],
            "errors": self.errors,
            "time_s": float(self.time_s),
            "views": self.views,
            "extra": jsonable(self.extra),
        }


#: What the suite calls on a reference calibrator (the rest of :class:`ReferenceCalibrator` has defaults in
#: :class:`BaseCalibrator`).
REQUIRED_MEMBERS: tuple[str, ...] = ("name", "available", "calibrate_observations")


def missing_members(obj: Any) -> list[str]:
    """The members of :data:`REQUIRED_MEMBERS` that an object lacks.

    Parameters
    ----------
    obj : object
        A candidate reference calibrator (e.g. a plug-in's entry point, loaded).

    Returns
    -------
    list of str
        The missing member names; empty when ``obj`` can be used as a reference.
    """
    return [m for m in REQUIRED_MEMBERS if not hasattr(obj, m)]


@runtime_checkable
class ReferenceCalibrator(Protocol):
    """What the registry hands out.

    Third-party plug-ins implement this (subclassing :class:`BaseCalibrator` is the easy way) and register under the
    entry-point group ``circcal.validators``. The methods never raise: failures come back as a :class:`ReferenceResult`
    status.
    """

    name: str

    @property
    def version(self) -> str: ...

    def available(self) -> tuple[bool, str]:
        """Whether the reference can run here.

        Returns
        -------
        tuple of (bool, str)
            ``(True, "")``, or ``(False, reason)`` when the reference is not installed or cannot run.
        """

    def calibrate_observations(
        self,
        object_points: Sequence[np.ndarray],
        image_points: Sequence[np.ndarray],
        image_size: tuple[int, int],
        *,
        mode: Mode = "fair",
        initial: Camera | None = None,
    ) -> ReferenceResult:
        """Calibrate from given centres (see :meth:`BaseCalibrator.calibrate_observations`).

        Parameters
        ----------
        object_points : sequence of ndarray, shape (N_v, 3)
            Board points per view, mm, z = 0.
        image_points : sequence of ndarray, shape (N_v, 2)
            Detected centres per view, px.
        image_size : tuple of int
            (width, height) px.
        mode : {"fair", "default"}
            Estimator to run.
        initial : circcal.model.Camera, optional
            A starting camera, for references that take one.

        Returns
        -------
        ReferenceResult
            Never raises; failures are a status.
        """

    def calibrate_images(
        self,
        paths: Sequence[Any],
        board: Any,
        image_size: tuple[int, int] | None = None,
        *,
        mode: Mode = "fair",
        initial: Camera | None = None,
    ) -> ReferenceResult:
        """Detect with the reference's own detector, then calibrate.

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
            Never raises; failures are a status.
        """


def lens_support(cal: Any, lens: str) -> tuple[bool, str]:
    """Whether a reference fits a lens model, and why not when it does not.

    A reference without a ``lenses`` attribute fits :data:`DEFAULT_LENSES` only.

    Parameters
    ----------
    cal : ReferenceCalibrator
        Any reference, plug-ins included.
    lens : str
        A :data:`circcal.model.LENS_MODELS` name.

    Returns
    -------
    ok : bool
        True when ``lens`` is one of the reference's ``lenses``.
    why : str
        "" when ok; else the reference's own words from ``unsupported_lenses``, or a generic reason.
    """
    lenses = tuple(getattr(cal, "lenses", DEFAULT_LENSES))
    if lens in lenses:
        return True, ""
    why = dict(getattr(cal, "unsupported_lenses", {}) or {}).get(lens)
    name = getattr(cal, "name", type(cal).__name__)
    return False, why or f"{name} fits the lens models {', '.join(lenses)} only, not {lens!r}"


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
    """
    return [
        np.asarray(p, dtype=np.float64) - project(o, r, t, camera)
        for o, p, r, t in zip(object_points, image_points, np.asarray(rvecs), np.asarray(tvecs))
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
        """
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


def check_divergence(res: ReferenceResult, max_rms_px: float = DIVERGED_RMS_PX) -> ReferenceResult:
    """Turn a diverged "ok" result into status "failed".

    Diverged: non-finite intrinsics or poses, an RMS per point above ``max_rms_px``, or a rational pole inside the
    field (:func:`rational_pole`). The camera is kept for inspection. The result is changed in place.

    Parameters
    ----------
    res : ReferenceResult
        Any result; one that is not ok comes back unchanged.
    max_rms_px : float
        Largest acceptable RMS per point (px).

    Returns
    -------
    ReferenceResult
        ``res`` itself.
    """
    if not res.ok:
        return res
    c = res.camera
    if c is None or not np.all(np.isfinite(c.intrinsics)):
        res.status, res.message = "failed", "diverged: non-finite intrinsics"
        return res
    for label, a in (("rvecs", res.rvecs), ("tvecs", res.tvecs)):
        if a is None or not np.all(np.isfinite(a)):
            res.status, res.message = "failed", f"diverged: non-finite {label}"
            return res
    rms = (res.errors or {}).get("rms_per_point_px", np.nan)
    if not np.isfinite(rms) or rms > max_rms_px:
        res.status, res.message = "failed", f"diverged: RMS per point {rms:.4g} px > {max_rms_px:g} px"
        return res
    pole = rational_pole(c, res.object_points, res.rvecs, res.tvecs)
    if pole:
        res.status, res.message = "failed", pole
    return res


def rational_pole(
    camera: Camera, object_points: Sequence[np.ndarray] | None, rvecs: np.ndarray | None, tvecs: np.ndarray | None
) -> str:
    """Why a rational or thin-prism solution is not a lens ("" when it is).

    Its radial denominator 1 + k4 r^2 + k5 r^4 + k6 r^6 reaches 0 between the axis and the farthest observed point
    (r: the undistorted normalised radius), a pole inside the field where OpenCV's model is undefined. Such a solution
    can fit the observations better than the lens does, numerator and denominator vanishing together, so the suite
    reports it rather than comparing it (the measurement is in docs/validation.md, "Rational poles").

    Parameters
    ----------
    camera : circcal.model.Camera
        The solution; other lens models give "".
    object_points : sequence of ndarray, shape (N_v, 3), or None
        Board points per view, mm.
    rvecs, tvecs : ndarray, shape (V, 3), or None
        Board-to-camera poses (rad; mm).

    Returns
    -------
    str
        "" for a lens (or when an input is None), else one line naming r at the pole and k4, k5, k6.
    """
    if camera.lens not in ("rational", "thin-prism") or object_points is None or rvecs is None or tvecs is None:
        return ""
    d = dict(zip(camera.model.dist_names, np.asarray(camera.dist, dtype=np.float64)))
    k4, k5, k6 = d["k4"], d["k5"], d["k6"]
    r2 = [
        np.sum((X[:, :2] / X[:, 2:3]) ** 2, axis=1)
        for X in (transform(np.asarray(o, dtype=np.float64), r, t) for o, r, t in zip(object_points, rvecs, tvecs))
    ]
    r2max = float(np.max(np.concatenate(r2))) if r2 else 0.0
    s = np.linspace(0.0, r2max, 2001)
    den = 1.0 + k4 * s + k5 * s**2 + k6 * s**3
    if np.all(den > 0):
        return ""
    at = float(np.sqrt(s[np.argmax(den <= 0)]))
    return (
        f"not a lens: the rational denominator 1 + k4 r^2 + k5 r^4 + k6 r^6 reaches 0 at r = {at:.3g} inside "
        f"the observed field (r up to {np.sqrt(r2max):.3g}; k4 {k4:.4g}, k5 {k5:.4g}, k6 {k6:.4g}): a pole "
        "where OpenCV's model is undefined"
    )


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


def seed_camera(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    lens: str = "opencv5",
) -> Camera:
    """A rough pinhole seed (no distortion), for references that need a starting focal length.

    From ``cv2.initCameraMatrix2D`` (Zhang with the principal point at the image centre); used for mrcal's
    ``focal_estimate`` and pycolmap's camera. Only a starting point: each reference then solves its own least-squares
    problem. A non-finite or non-positive focal length falls back to max(w, h).

    Parameters
    ----------
    object_points : sequence of ndarray, shape (N_v, 3)
        Board points per view, mm.
    image_points : sequence of ndarray, shape (N_v, 2)
        Centres per view, px.
    image_size : tuple of int
        (width, height) px.
    lens : str
        The model of the returned camera, its distortion all zero; for "fisheye" (where a pinhole seed means nothing)
        the equidistant focal length of :func:`fisheye_seed_focal`.

    Returns
    -------
    circcal.model.Camera
        Principal point at the image centre ((w - 1) / 2, (h - 1) / 2) px, zero distortion.
    """
    import cv2

    if lens == "fisheye":
        from circcal.model import LENS_MODELS

        w, h = int(image_size[0]), int(image_size[1])
        f = fisheye_seed_focal(object_points, image_points, image_size)
        return Camera(w, h, f, f, (w - 1) / 2.0, (h - 1) / 2.0, np.zeros(len(LENS_MODELS[lens].dist_names)), lens=lens)

    K = cv2.initCameraMatrix2D(
        [np.asarray(o, dtype=np.float32).reshape(-1, 1, 3) for o in object_points],
        [np.asarray(p, dtype=np.float32).reshape(-1, 1, 2) for p in image_points],
        (int(image_size[0]), int(image_size[1])),
    )
    w, h = int(image_size[0]), int(image_size[1])
    fx, fy = float(K[0, 0]), float(K[1, 1])
    if not (np.isfinite(fx) and np.isfinite(fy) and fx > 0 and fy > 0):
        fx = fy = float(max(w, h))
    if lens == "opencv5":
        return Camera(w, h, fx, fy, (w - 1) / 2.0, (h - 1) / 2.0, np.zeros(5))
    from circcal.model import LENS_MODELS

    return Camera(w, h, fx, fy, (w - 1) / 2.0, (h - 1) / 2.0, np.zeros(len(LENS_MODELS[lens].dist_names)), lens=lens)


#: Equidistant focal lengths tried by :func:`fisheye_seed_focal`, relative to max(w, h) / pi (cv2.fisheye's start).
FISHEYE_FOCAL_SWEEP: tuple[float, ...] = (0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.25, 1.4, 1.6)


def fisheye_seed_focal(
    object_points: Sequence[np.ndarray], image_points: Sequence[np.ndarray], image_size: tuple[int, int]
) -> float:
    """A starting equidistant focal length for a fisheye calibration.

    Of :data:`FISHEYE_FOCAL_SWEEP` x max(w, h) / pi, the one whose poses reproject the observations best, with the
    principal point at the image centre and k1-k4 = 0. Per candidate f the observations are lifted to the z = 1 plane
    (theta = r / f, clamped below 90 deg, x = tan(theta) (u - c) / r) and each view's pose comes from ``cv2.solvePnP``
    on them (IPPE for the planar board); the cost is the pixel residual through :func:`circcal.model.project` with
    that camera.

    Parameters
    ----------
    object_points : sequence of ndarray, shape (N_v, 3)
        Board points per view, mm, z = 0.
    image_points : sequence of ndarray, shape (N_v, 2)
        Centres per view, px.
    image_size : tuple of int
        (width, height) px.

    Returns
    -------
    float
        Focal length, px (max(w, h) / pi when no candidate gives a finite cost).
    """
    import cv2

    w, h = int(image_size[0]), int(image_size[1])
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    best_f, best_cost = float(max(w, h)) / np.pi, np.inf
    for rel in FISHEYE_FOCAL_SWEEP:
        f = rel * max(w, h) / np.pi
        cam = Camera(w, h, f, f, c[0], c[1], np.zeros(4), lens="fisheye")
        cost = 0.0
        for o, q in zip(object_points, image_points):
            d = np.asarray(q, dtype=np.float64) - c
            r = np.linalg.norm(d, axis=1)
            theta = np.minimum(r / f, 0.49 * np.pi)
            lift = np.where(r > 0, np.tan(theta) / np.maximum(r, 1e-12), 1.0 / f)
            ok, rv, tv = cv2.solvePnP(
                np.asarray(o, dtype=np.float64), d * lift[:, None], np.eye(3), None, flags=cv2.SOLVEPNP_IPPE
            )
            if not ok:
                cost = np.inf
                break
            cost += float(np.sum((project(o, rv.reshape(3), tv.reshape(3), cam) - q) ** 2))
        if np.isfinite(cost) and cost < best_cost:
            best_f, best_cost = f, cost
    return best_f
