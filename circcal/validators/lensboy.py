"""lensboy as a reference: its Ceres calibration of OpenCV's model from any target's points.

lensboy (MIT, PyPI; 4.0.3 checked) fits ``lensboy.OpenCV`` (fx, fy, cx, cy and OpenCV's 14-coefficient vector in
OpenCV's order, ``lensboy/camera_models/opencv.py``) with a mask of the coefficients it frees
(``OpenCVConfig.included_distortion_coefficients``, shape (14,)); it projects with ``cv2.projectPoints``, so its
pixels are OpenCV's (integer coordinates are pixel centres). It seeds itself (a centred stereographic model, PnP per
frame over a focal-length sweep). Lens models: ``opencv5`` (k1, k2, p1, p2, k3: ``OpenCVConfig.STANDARD``),
``rational`` (+ k4, k5, k6), ``thin-prism`` (+ s1-s4); ``fisheye`` is unsupported (lensboy has OpenCV's pinhole
model and splined pinhole models, no equidistant one).

Modes
-----
* ``"fair"``: ``estimate_target_warp=False, outlier_threshold_stddevs=None``: plain least squares over the rigid board,
  the estimator of cv2.calibrateCamera and of circcal. It stops short of the minimum, and no option lensboy exposes
  changes that: its Ceres solve (``lensboy_bindings.calibrate_opencv``; source ``cpp_src/calibrate_opencv.cpp`` of
  Robertleoj/lensboy: plain squared residuals, no loss function, the board warp applied only when estimated; the 4.0.3
  binary holds only the warped cost function, ``ReprojectionError<2, 18, 6, 3, 5>``, the source read is a later
  revision) keeps Ceres's default tolerances, and Ceres ends a solve without taking a step that would lower the cost by
  at most :data:`CERES_FUNCTION_TOLERANCE` (1e-6) of it. On the flat directions of a distortion fit that leaves it
  1.6e-4 .. 5.6e-3 px from circcal's solution while its own cost exceeds circcal's by 2.8e-9 .. 7.8e-7 (relative, on
  lensboy's own objective; true centres of 12 circle-board scenario-lenses; on the 43 compared fair conformance cases
  9.5e-6 .. 8.7e-3 px, 3e-10 .. 1.0e-6): circcal's solution is the lower point of lensboy's objective, and lensboy
  started there stays there (tests/test_lens_references.py). Restarted from its answer it takes no step; from its answer
  with f moved by 1e-5 .. 1e-3 it stops 1.3e-3 .. 2.9e-3 px away again (rational-wide). Hence ``SOLVER_LENSBOY_PX``, and
  a lensboy difference beyond 1e-6 px passes only with its cost above circcal's (``checks.STOPS_SHORT``).
* ``"default"``: lensboy's defaults: a Legendre-polynomial board warp (a, b, c, d, e along the board normal) and
  outlier filtering (5 robust sigma of the residual norm, two passes). Its residuals are lensboy's own (warped
  board; outliers NaN), as mrcal's default mode reports them; a view lensboy drops entirely is left out of ``views``.

Install: ``pip install --no-deps lensboy``. Its declared dependency ``opencv-contrib-python`` would install a second
OpenCV distribution over the ``opencv-contrib-python-headless`` that provides ``cv2`` here; lensboy's calibration
runs on that cv2 (5.0) as it is, except one path: a frame whose first PnP fails is re-posed through
``cv2.undistortPointsIter``, which OpenCV 5 removed (that run is reported failed, with this reason).
lensboy states no parameter standard deviations: ``std`` is None.
"""

from __future__ import annotations

import contextlib
import io
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from circcal.model import Camera, param_names
from circcal.observations import distinct_points
from circcal.validators.base import BaseCalibrator, ReferenceResult

if TYPE_CHECKING:
    import lensboy

__all__ = ["LensboyCalibrator", "COEFFICIENTS", "INSTALL_HINT", "CERES_FUNCTION_TOLERANCE", "to_lensboy"]

#: OpenCV's 14-vector order, as lensboy's ``K1, K2, P1, P2, K3, K4, K5, K6, S1, S2, S3, S4, TX, TY``
COEFFICIENTS: tuple[str, ...] = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx", "ty")
#: lensboy's stopping rule in fair mode: Ceres's default ``function_tolerance`` (lensboy's
#: ``cpp_src/calibrate_opencv.cpp`` sets only ``max_num_iterations = 200`` and ``use_nonmonotonic_steps``). Ceres ends
#: the solve, without taking the step, when the step would lower the cost by at most this fraction of the cost
#: (what lensboy 4.0.3 is measured to do: tests/test_lens_references.py).
CERES_FUNCTION_TOLERANCE = 1e-6
INSTALL_HINT = (
    "pip install --no-deps lensboy (its declared opencv-contrib-python would replace the "
    "opencv-contrib-python-headless that provides cv2)"
)


def to_lensboy(camera: Camera) -> lensboy.OpenCV:
    """``camera`` (opencv5, rational or thin-prism) as a ``lensboy.OpenCV``: the same intrinsics, its coefficients
    placed in lensboy's 14-vector (OpenCV's order; the absent ones 0)."""
    import lensboy as lb

    d = dict(zip(param_names(camera.lens)[4:], camera.dist))
    return lb.OpenCV(
        image_width=camera.width,
        image_height=camera.height,
        fx=camera.fx,
        fy=camera.fy,
        cx=camera.cx,
        cy=camera.cy,
        distortion_coeffs=np.array([d.get(c, 0.0) for c in COEFFICIENTS]),
    )


def _coefficient_mask(lens: str) -> np.ndarray:
    """lensboy's (14,) bool mask of the coefficients ``lens`` frees (its names in OpenCV's order)."""
    names = param_names(lens)[4:]
    return np.array([c in names for c in COEFFICIENTS], dtype=bool)


class LensboyCalibrator(BaseCalibrator):
    """Reference: lensboy's ``calibrate_camera`` with ``OpenCVConfig``. ``lens``: "opencv5", "rational" or
    "thin-prism"."""

    name = "lensboy"
    modes = ("fair", "default")
    lenses = ("opencv5", "rational", "thin-prism")
    unsupported_lenses = {
        "fisheye": "lensboy has no fisheye (equidistant Kannala-Brandt) model: its models are OpenCV's pinhole model "
        "(up to 14 coefficients) and splined pinhole models"
    }

    def __init__(self, *, lens: str = "opencv5") -> None:
        self.lens = lens

    def _version(self) -> str:
        import importlib.metadata

        return importlib.metadata.version("lensboy")

    def _available(self) -> tuple[bool, str]:
        try:
            import lensboy  # noqa: F401
        except ImportError as exc:
            return False, f"lensboy not importable ({exc}); {INSTALL_HINT}"
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
        import lensboy as lb

        t0 = time.perf_counter()
        w, h = int(image_size[0]), int(image_size[1])
        target, idx = distinct_points(object_points)
        frames = [
            lb.Frame(target_point_indices=i, detected_points_in_image=np.asarray(q, dtype=np.float64))
            for i, q in zip(idx, image_points)
        ]
        config = lb.OpenCVConfig(
            image_height=h, image_width=w, included_distortion_coefficients=_coefficient_mask(self.lens)
        )
        init = None
        if initial is not None:
            if initial.lens != self.lens:
                raise ValueError(f"initial camera has lens {initial.lens!r}, this reference fits {self.lens!r}")
            init = to_lensboy(initial)
        fair = mode == "fair"
        log = io.StringIO()
        try:
            with contextlib.redirect_stdout(log):  # lensboy prints its progress
                res = lb.calibrate_camera(
                    target,
                    frames,
                    config,
                    initial_camera_model=init,
                    estimate_target_warp=not fair,
                    outlier_threshold_stddevs=None if fair else 5.0,
                )
        except AttributeError as exc:
            if "undistortPointsIter" not in str(exc):
                raise
            raise RuntimeError(
                "lensboy re-posed a frame through cv2.undistortPointsIter, which OpenCV 5 removed "
                f"(lensboy wants opencv-contrib-python; cv2 here is {_cv2_version()})"
            ) from exc
        m = res.camera_model
        coeffs = dict(zip(COEFFICIENTS, np.asarray(m.distortion_coeffs, dtype=np.float64)))
        camera = Camera(
            w,
            h,
            float(m.fx),
            float(m.fy),
            float(m.cx),
            float(m.cy),
            np.array([coeffs[n] for n in param_names(self.lens)[4:]]),
            lens=self.lens,
        )
        views = [v for v, p in enumerate(res.cameras_from_target) if p is not None]
        M = [np.asarray(res.cameras_from_target[v].matrix, dtype=np.float64) for v in views]
        import cv2

        rvecs = np.array([cv2.Rodrigues(T[:3, :3])[0].reshape(3) for T in M])
        tvecs = np.array([T[:3, 3] for T in M])
        obj = [object_points[v] for v in views]
        img = [image_points[v] for v in views]
        extra: dict[str, Any] = dict(
            lens=self.lens,
            fixed=[c for c in COEFFICIENTS if c not in param_names(self.lens)],
            n_outliers=int(res.num_outliers()),
            log=log.getvalue()[-2000:],
            target_warp=None if res.target_warp is None else [float(c) for c in res.target_warp.object_warp],
        )
        if fair:
            return self.finish(mode, camera, rvecs, tvecs, obj, img, t0, views=views, **extra)
        residuals = []
        for v in views:
            diag = res.frame_diagnostics[v]
            r = np.asarray(diag.residuals, dtype=np.float64).copy()  # detected - projected: ours
            r[~np.asarray(diag.inlier_mask, dtype=bool)] = np.nan
            residuals.append(r)
        dropped = len(object_points) - len(views)
        return self.finish(
            mode,
            camera,
            rvecs,
            tvecs,
            obj,
            img,
            t0,
            views=views,
            residuals=residuals,
            message=f"lensboy default: board warp {np.round(extra['target_warp'] or [], 6).tolist()}, "
            f"{extra['n_outliers']} outliers filtered, {dropped} views dropped",
            **extra,
        )


def _cv2_version() -> str:
    import cv2

    return cv2.__version__
