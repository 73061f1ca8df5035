"""lensboy as a reference: its Ceres calibration of OpenCV's model from any target's points.

lensboy (MIT, PyPI; 4.0.3 checked) fits ``lensboy.OpenCV`` with a mask of the coefficients it frees. Lens models:
``opencv5``, ``rational``, ``thin-prism``; ``fisheye`` is unsupported. Modes: "fair" (plain least squares over the
rigid board; it stops short of the minimum, hence ``SOLVER_LENSBOY_PX``) and "default" (lensboy's board warp and
outlier filtering). Install: ``pip install --no-deps lensboy``. The details and measurements are in
docs/references.md ("How the adapters work: lensboy").
"""

from __future__ import annotations

import contextlib
import io
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from circcal.model import Camera, param_names
from circcal.observations import distinct_points
from circcal.validators.base import BaseCalibrator
from circcal.validators.reference_result import ReferenceResult

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
    """A circcal camera as a ``lensboy.OpenCV``.

    Parameters
    ----------
    camera : circcal.model.Camera
        An opencv5, rational or thin-prism camera.

    Returns
    -------
    lensboy.OpenCV
        The same intrinsics, the coefficients placed in lensboy's 14-vector (OpenCV's order; the absent ones 0).
    """
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
    """Reference: lensboy's ``calibrate_camera`` with ``OpenCVConfig``.

    lensboy states no parameter standard deviations: ``std`` is None.

    Parameters
    ----------
    lens : {"opencv5", "rational", "thin-prism"}
        The lens model fitted ("fisheye" answers "unsupported" with the reason).
    """

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
