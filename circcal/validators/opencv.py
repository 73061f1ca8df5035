"""OpenCV as a reference: ``cv2.findCirclesGrid`` (blob centroids), ``cv2.calibrateCameraExtended`` and
``cv2.fisheye.calibrate``.

Every circcal lens model is fitted (:data:`LENS_FLAGS`); "fair" and "default" are the same estimator here (OpenCV
has no regularisation, warp or outlier rejection). The solver flags, the fisheye seed and why, the float32
rounding and the blob detector are described in docs/references.md ("How the adapters work: OpenCV").
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from circcal.model import LENS_MODELS, Camera, param_names
from circcal.validators.base import BaseCalibrator
from circcal.validators.reference_result import ReferenceResult
from circcal.validators.seeds import seed_camera

__all__ = ["OpenCVCalibrator", "make_blob_detector", "find_circles_grid"]


def _cv2():
    import cv2

    return cv2


def _tight_criteria():
    """500 iterations, eps 1e-16 (OpenCV's default stops after 30)."""
    cv2 = _cv2()
    return (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-16)


def make_blob_detector(
    board: Any,
    image_size: tuple[int, int],
    *,
    min_fill: float = 0.08,
    max_fill: float = 1.2,
    min_area: float | None = None,
    max_area: float | None = None,
    threshold_step: float = 10.0,
    permissive: bool = False,
):
    """A ``cv2.SimpleBlobDetector`` whose area window fits the dots of a board in an image.

    Otherwise OpenCV's defaults (or, with ``permissive``, wider thresholds and looser shape filters). The dot's
    apparent diameter is bounded by assuming the dot grid spans between ``min_fill`` and ``max_fill`` of the image's
    longer side (perspective can enlarge the near dots: the upper bound gets another factor 1.5).

    Parameters
    ----------
    board : circcal.board.Board
        Pitch and diameter in mm.
    image_size : tuple of int
        (width, height) px.
    min_fill, max_fill : float
        Bounds on the grid's extent as a fraction of the image's longer side.
    min_area, max_area : float, optional
        Override the area window, px^2.
    threshold_step : float
        The detector's threshold step (grey levels).
    permissive : bool
        Wider thresholds and looser shape filters.

    Returns
    -------
    cv2.SimpleBlobDetector
    """
    cv2 = _cv2()
    x0, y0, x1, y1 = board.feature_extent_mm()
    extent = max(x1 - x0, y1 - y0)
    long_side = float(max(image_size))
    d_max = 1.5 * max_fill * long_side * board.diameter_mm / extent
    d_min = min_fill * long_side * board.diameter_mm / extent
    spacing_mm = board.pitch_mm * (np.sqrt(2.0) if board.layout == "asymmetric" else 1.0)
    # OpenCV's defaults (thresholds 50..220, inertia >= 0.1, convexity >= 0.95) with the area window fitted to the
    # dots; ``permissive`` widens thresholds and shape filters for low-contrast or strongly tilted dots.
    p = cv2.SimpleBlobDetector_Params()
    p.minArea = float(min_area if min_area is not None else min(25.0, max(4.0, 0.25 * np.pi / 4.0 * d_min**2)))
    p.maxArea = float(max_area if max_area is not None else max(5000.0, np.pi / 4.0 * d_max**2))
    if permissive:
        p.minThreshold = 10.0
        p.maxThreshold = 240.0
        p.thresholdStep = float(threshold_step)
        p.minInertiaRatio = 0.05
        p.minConvexity = 0.85
        p.minDistBetweenBlobs = float(
            max(2.0, min(10.0, 0.5 * min_fill * long_side * (spacing_mm - board.diameter_mm) / extent))
        )
    return cv2.SimpleBlobDetector_create(p)


def find_circles_grid(
    image: np.ndarray, board: Any, *, detector: Any = None, clustering_fallback: bool = True
) -> tuple[np.ndarray | None, str]:
    """Detect a board's grid in a grey image with ``cv2.findCirclesGrid``.

    OpenCV's default blob detector first (its baseline), then the area window fitted to the dot size, then the
    permissive one; each plain, then with ``CALIB_CB_CLUSTERING``.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3)
        uint8; a colour (BGR) image is converted to grey.
    board : circcal.board.Board
        A symmetric or asymmetric circle grid.
    detector : cv2.SimpleBlobDetector, optional
        Use only this detector.
    clustering_fallback : bool
        Retry with ``CALIB_CB_CLUSTERING``.

    Returns
    -------
    centres : ndarray, shape (rows*cols, 2), or None
        float64 px in OpenCV's order; None when not found.
    how : str
        "plain" | "clustering" (prefixed by the detector's label), or the reason it failed.

    Raises
    ------
    ValueError
        The board is not a circle grid.
    """
    cv2 = _cv2()
    if board.layout not in ("symmetric", "asymmetric"):
        raise ValueError(f"findCirclesGrid needs a circle grid, got layout {board.layout!r}")
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    h, w = image.shape[:2]
    # OpenCV's default detector first (its baseline), then the area window fitted to the dot size (large dots exceed
    # the default maxArea of 5000 px^2), then the permissive variant.
    detectors = (
        [("", detector)]
        if detector is not None
        else [
            ("default-detector ", cv2.SimpleBlobDetector_create()),
            ("sized-detector ", make_blob_detector(board, (w, h))),
            ("permissive-detector ", make_blob_detector(board, (w, h), permissive=True)),
        ]
    )
    base = cv2.CALIB_CB_SYMMETRIC_GRID if board.layout == "symmetric" else cv2.CALIB_CB_ASYMMETRIC_GRID
    attempts = [("plain", base)]
    if clustering_fallback:
        attempts.append(("clustering", base | cv2.CALIB_CB_CLUSTERING))
    for label, det in detectors:
        for how, flags in attempts:
            ok, centres = cv2.findCirclesGrid(image, board.pattern_size, flags=flags, blobDetector=det)
            if ok and centres is not None and len(centres) == board.n_points:
                return centres.reshape(-1, 2).astype(np.float64), label + how
    return None, "grid not found (plain and clustering; default, sized and permissive blob detectors)"


#: circcal's lens model -> the calibrateCamera flags that fit it (fisheye: cv2.fisheye.calibrate's).
LENS_FLAGS: dict[str, str] = {
    "opencv5": "0 (the default 5 coefficients)",
    "rational": "CALIB_RATIONAL_MODEL",
    "thin-prism": "CALIB_RATIONAL_MODEL | CALIB_THIN_PRISM_MODEL",
    "fisheye": "cv2.fisheye.calibrate with CALIB_RECOMPUTE_EXTRINSIC | CALIB_FIX_SKEW, CALIB_USE_INTRINSIC_GUESS "
    "from the equidistant seed (base.seed_camera)",
}


def _lens_flags(lens: str) -> int:
    cv2 = _cv2()
    return {
        "opencv5": 0,
        "rational": cv2.CALIB_RATIONAL_MODEL,
        "thin-prism": cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL,
        "fisheye": cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW,
    }[lens]


#: cv2.fisheye works on the z = 1 plane (theta = atan(r)): it cannot take a point at or beyond this angle (deg).
FISHEYE_MAX_THETA_DEG = 90.0


def _fisheye_limit(object_points, image_points, size: tuple[int, int], exc: Exception) -> None:
    """After cv2.fisheye.calibrate failed with ``exc``: ``NotImplementedError`` (status "unsupported", with the
    reason) when the observations reach 90 deg off axis under the equidistant start of circcal's solver (its focal
    length searched for over the whole field: :func:`circcal.solver.fisheye_start.fisheye_start`; only to explain
    the failure, nothing of it enters OpenCV's solve); otherwise return (the caller re-raises: another failure)."""
    from circcal.errors import CalibrationError
    from circcal.solver.fisheye_start import fisheye_start

    try:
        seed = fisheye_start(
            [np.asarray(o, dtype=np.float64) for o in object_points],
            [np.asarray(p, dtype=np.float64) for p in image_points],
            size,
        )[0]
    except CalibrationError:
        return
    uv = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in image_points])
    r = np.hypot((uv[:, 0] - seed.cx) / seed.fx, (uv[:, 1] - seed.cy) / seed.fy)
    theta = float(np.degrees(np.max(r)))
    if theta >= FISHEYE_MAX_THETA_DEG:
        raise NotImplementedError(
            f"cv2.fisheye projects only points in front of the camera (theta = atan(|xy| / z) < 90 deg) and these "
            f"views reach about {theta:.0f} deg off axis (equidistant seed f = {seed.fy:.4g} px); its calibrate "
            f"fails ({str(exc).strip().splitlines()[-1]})"
        ) from None


class OpenCVCalibrator(BaseCalibrator):
    """Reference: OpenCV's calibrateCameraExtended / cv2.fisheye.calibrate and findCirclesGrid.

    Parameters
    ----------
    lens : str
        The lens model fitted (every circcal model; :data:`LENS_FLAGS`).
    fix_k3 : bool
        Hold k3 at its initial value (0 unless ``initial`` says otherwise) (``CALIB_FIX_K3``; the fisheye's k3 is its
        theta^6 coefficient).
    criteria : tuple, optional
        cv2 termination criteria (default: 500 iterations, eps 1e-16).

    Raises
    ------
    ValueError
        An unknown lens model.
    """

    name = "opencv"
    modes = ("fair",)
    lenses = tuple(LENS_FLAGS)

    def __init__(self, *, lens: str = "opencv5", fix_k3: bool = False, criteria: tuple | None = None) -> None:
        if lens not in LENS_MODELS:
            raise ValueError(f"unknown lens model {lens!r}; expected one of {', '.join(LENS_MODELS)}")
        self.lens = lens
        self.fix_k3 = bool(fix_k3)
        self.criteria = criteria

    def _version(self) -> str:
        return _cv2().__version__

    def _available(self) -> tuple[bool, str]:
        try:
            _cv2()
        except ImportError as exc:
            return False, f"OpenCV not importable ({exc}); pip install opencv-contrib-python-headless"
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
        cv2 = _cv2()
        t0 = time.perf_counter()
        lens = self.lens
        n_dist = len(LENS_MODELS[lens].dist_names)
        obj32 = [np.ascontiguousarray(o, dtype=np.float32).reshape(-1, 1, 3) for o in object_points]
        img32 = [np.ascontiguousarray(p, dtype=np.float32).reshape(-1, 1, 2) for p in image_points]
        flags = _lens_flags(lens)
        K0, d0 = None, None
        if initial is not None:
            if initial.lens != lens:
                raise ValueError(f"initial camera has lens {initial.lens!r}, this reference fits {lens!r}")
            flags |= cv2.CALIB_USE_INTRINSIC_GUESS
            K0, d0 = initial.K.copy(), initial.dist.copy().reshape(1, n_dist)
        fixed = []
        if self.fix_k3:
            flags |= cv2.CALIB_FIX_K3
            fixed.append("k3")
        criteria = self.criteria or _tight_criteria()
        size = (int(image_size[0]), int(image_size[1]))
        # one thread: with several, OpenCV's parallel sums make the result vary run to run by ~2e-7 px
        n_threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            if lens == "fisheye":
                if K0 is None:
                    flags |= cv2.CALIB_USE_INTRINSIC_GUESS
                    seed = seed_camera(object_points, image_points, size, lens="fisheye")
                    K0, d0 = seed.K.copy(), seed.dist.copy()
                try:
                    rms, K, dist, rvecs, tvecs = cv2.fisheye.calibrate(
                        [o.reshape(1, -1, 3).astype(np.float64) for o in obj32],
                        [p.reshape(1, -1, 2).astype(np.float64) for p in img32],
                        size,
                        K0,
                        d0.reshape(4, 1),
                        flags=flags,
                        criteria=criteria,
                    )
                except cv2.error as exc:  # OpenCV 5.0: an assertion beyond 90 deg
                    _fisheye_limit(object_points, image_points, size, exc)
                    raise
                if not (K[0, 0] > 0 and K[1, 1] > 0 and np.all(np.isfinite(K)) and np.all(np.isfinite(dist))):
                    # OpenCV 5.1 returns there instead, with negative focal lengths (measured: fx -15647 px)
                    bad = ValueError(f"it returned fx = {K[0, 0]:.6g}, fy = {K[1, 1]:.6g} px")
                    _fisheye_limit(object_points, image_points, size, bad)
                    raise bad
                std_in = per_view = None
            else:
                rms, K, dist, rvecs, tvecs, std_in, _std_ex, per_view = cv2.calibrateCameraExtended(
                    obj32, img32, size, K0, d0, flags=flags, criteria=criteria
                )
        finally:
            cv2.setNumThreads(n_threads)
        dist = np.asarray(dist, dtype=np.float64).reshape(-1)[:n_dist]
        cam = Camera(size[0], size[1], float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), dist, lens)
        std = None
        if std_in is not None:
            std_v = np.asarray(std_in, dtype=np.float64).reshape(-1)
            std = {n: float(std_v[i]) for i, n in enumerate(param_names(lens))}
        used_obj = [o.reshape(-1, 3).astype(np.float64) for o in obj32]
        used_img = [p.reshape(-1, 2).astype(np.float64) for p in img32]
        rv = np.array([np.asarray(r, dtype=np.float64).reshape(3) for r in rvecs])
        tv = np.array([np.asarray(t, dtype=np.float64).reshape(3) for t in tvecs])
        extra = {} if per_view is None else {"per_view_rms_px": np.asarray(per_view, dtype=float).reshape(-1).tolist()}
        return self.finish(
            mode,
            cam,
            rv,
            tv,
            used_obj,
            used_img,
            t0,
            std=std,
            fixed=fixed,
            flags=int(flags),
            lens_flags=LENS_FLAGS[lens],
            rms_opencv_per_point_px=float(rms),
            **extra,
            criteria=list(criteria),
            note="OpenCV has no regularisation/warp/outlier rejection: fair == default"
            + ("; cv2.fisheye.calibrate gives no standard deviations" if std is None else ""),
        )

    def detect(self, paths: Sequence[Any], board: Any, *, detector: Any = None) -> dict[str, Any]:
        """Run :func:`find_circles_grid` on every image.

        Parameters
        ----------
        paths : sequence of path-like
            Image files.
        board : circcal.board.Board
            The calibration target.
        detector : cv2.SimpleBlobDetector, optional
            Use only this detector.

        Returns
        -------
        dict
            ``{"image_points": [(N, 2) px ...], "views": [indices found], "how": {index: "plain"|"clustering"},
            "missed": {path: reason}, "image_size": (w, h) or None}``; an unreadable image or one whose size differs
            from the first is missed with the reason.
        """
        cv2 = _cv2()
        image_points, views, how, missed = [], [], {}, {}
        size = None
        for i, path in enumerate(paths):
            img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if img is None:
                missed[str(path)] = "could not read image"
                continue
            s = (img.shape[1], img.shape[0])
            if size is None:
                size = s
            elif s != size:
                missed[str(path)] = f"image size {s} differs from the first image's {size}"
                continue
            centres, h = find_circles_grid(img, board, detector=detector)
            if centres is None:
                missed[str(path)] = h
                continue
            image_points.append(centres)
            views.append(i)
            how[i] = h
        return {"image_points": image_points, "views": views, "how": how, "missed": missed, "image_size": size}

    def _calibrate_images(
        self, paths: Sequence[Any], board: Any, image_size: tuple[int, int] | None, *, mode: str, initial: Camera | None
    ) -> ReferenceResult:
        t0 = time.perf_counter()
        paths = [Path(p) for p in paths]
        det = self.detect(paths, board)
        size = tuple(image_size) if image_size is not None else det["image_size"]
        if size is None:
            raise ValueError("no image could be read: " + "; ".join(f"{k}: {v}" for k, v in det["missed"].items()))
        if len(det["views"]) < 3:
            return self.result(
                mode,
                "failed",
                f"findCirclesGrid found the grid in {len(det['views'])} of "
                f"{len(paths)} images (need 3); missed: {det['missed']}",
                extra={"missed": det["missed"]},
            )
        obj = [board.object_points() for _ in det["views"]]
        res = self.calibrate_observations(obj, det["image_points"], size, mode=mode, initial=initial)
        res.views = det["views"]
        res.time_s = time.perf_counter() - t0
        res.extra.update(
            detection_how={str(paths[k]): v for k, v in det["how"].items()}, missed=det["missed"], n_images=len(paths)
        )
        if det["missed"]:
            res.message = (
                res.message + "; " if res.message else ""
            ) + f"grid not found in {len(det['missed'])} of {len(paths)} images"
        return res
