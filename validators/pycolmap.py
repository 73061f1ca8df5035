"""pycolmap as a reference: COLMAP's Ceres bundle adjustment with the board held constant.

The calibration is posed as a bundle adjustment: the world frame is the board, every view is an image whose pose
``cam_from_world`` is the board-to-camera transform, and the board points are constant 3-D points (they fix the
gauge; no extra gauge fixing). Intrinsics are refined with ``refine_principal_point=True`` (COLMAP's default is
False).

Models
------
* ``"FULL_OPENCV"`` (default): fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6 with k4-k6 held at 0 by a
  ``pyceres.SubsetManifold`` = OpenCV's 5-coefficient model.
* ``"OPENCV"``: fx, fy, cx, cy, k1, k2, p1, p2; k3 is fixed at 0 (compare with OpenCV's ``CALIB_FIX_K3``).

COLMAP puts the top-left pixel centre at (0.5, 0.5) (OpenCV: (0, 0)); observations are shifted by +0.5 on the way
in and cx, cy by -0.5 on the way out. Standard deviations: ``pycolmap.estimate_ba_covariance`` (unit-noise
covariance of the intrinsics block) times sigma^2 = SSR / (2N - n_free_params), the formula OpenCV uses.
"""
from __future__ import annotations

import time

import numpy as np

from circcal.model import PARAM_NAMES, Camera, project
from circcal.rotation import rodrigues
from circcal.validators.base import BaseCalibrator, ReferenceResult, seed_camera

__all__ = ["PycolmapCalibrator", "MODELS"]

MODELS = ("FULL_OPENCV", "OPENCV")
COLMAP_OFFSET = 0.5  # COLMAP pixel = OpenCV pixel + 0.5



def _import(name: str):
    """Import pycolmap or pyceres without letting their glog take over SIGTERM: glog installs a failure handler that
    prints a native stack dump when the process is merely asked to stop. The handler in place before the import
    (Python's, or the CLI's clean-shutdown one) is put back; glog keeps its handlers for real crashes."""
    import importlib
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():  # signal handlers belong to the main thread
        return importlib.import_module(name)
    before = signal.getsignal(signal.SIGTERM)
    try:
        return importlib.import_module(name)
    finally:
        if before is not None:
            signal.signal(signal.SIGTERM, before)

class PycolmapCalibrator(BaseCalibrator):
    """Reference: pycolmap's Ceres bundle adjustment. ``model``: "FULL_OPENCV" (k4-k6 fixed at 0) or "OPENCV"
    (no k3: k3 = 0). ``max_iterations``: Ceres iterations (tolerances are set tight)."""

    name = "pycolmap"
    modes = ("fair",)

    def __init__(self, *, model: str = "FULL_OPENCV", max_iterations: int = 500) -> None:
        if model not in MODELS:
            raise ValueError(f"unknown pycolmap model {model!r}; expected one of {', '.join(MODELS)}")
        self.model = model
        self.max_iterations = int(max_iterations)

    def _version(self) -> str:
        pycolmap = _import("pycolmap")

        return pycolmap.__version__

    def _available(self) -> tuple[bool, str]:
        try:
            pycolmap = _import("pycolmap")  # noqa: F841
        except ImportError as exc:
            return False, f"pycolmap not importable ({exc}); pip install pycolmap pyceres"
        if self.model == "FULL_OPENCV":
            try:
                pyceres = _import("pyceres")  # noqa: F841
            except ImportError as exc:
                return False, (f"pyceres not importable ({exc}): needed to hold k4-k6 fixed in FULL_OPENCV; "
                               "pip install pyceres, or use model='OPENCV'")
        return True, ""

    def _calibrate(self, object_points: list[np.ndarray], image_points: list[np.ndarray],
                   image_size: tuple[int, int], *, mode: str, initial: Camera | None) -> ReferenceResult:
        pycolmap = _import("pycolmap")

        t0 = time.perf_counter()
        w, h = image_size
        seed = initial if initial is not None else seed_camera(object_points, image_points, image_size)
        cam = pycolmap.Camera.create_from_model_name(1, self.model, float(seed.fx), int(w), int(h))
        n_par = 12 if self.model == "FULL_OPENCV" else 8
        p = np.zeros(n_par)
        p[:4] = [seed.fx, seed.fy, seed.cx + COLMAP_OFFSET, seed.cy + COLMAP_OFFSET]
        p[4:8] = seed.dist[:4]
        if self.model == "FULL_OPENCV":
            p[8] = seed.dist[4]
        cam.params = p
        rec = pycolmap.Reconstruction()
        rec.add_camera_with_trivial_rig(cam)

        # one 3-D point per distinct board point (views may observe different subsets)
        keys: dict[tuple, int] = {}
        xyz: list[np.ndarray] = []
        idx_per_view = []
        for o in object_points:
            ids = []
            for X in o:
                k = tuple(np.round(X, 9))
                if k not in keys:
                    keys[k] = len(xyz)
                    xyz.append(np.asarray(X, dtype=np.float64))
                ids.append(keys[k])
            idx_per_view.append(ids)

        est = pycolmap.AbsolutePoseEstimationOptions()
        est.ransac.max_error = 0.02 * max(w, h)  # seed has no distortion: be generous
        for v, (o, q) in enumerate(zip(object_points, image_points)):
            pose = pycolmap.estimate_and_refine_absolute_pose(q + COLMAP_OFFSET, o, cam, est)
            if pose is None:
                raise RuntimeError(f"view {v}: pycolmap could not estimate an initial pose")
            img = pycolmap.Image(name=f"view{v:04d}", keypoints=q + COLMAP_OFFSET, camera_id=1, image_id=v + 1)
            rec.add_image_with_trivial_frame(img, pose["cam_from_world"])
        point_ids = []
        for j, X in enumerate(xyz):
            track = pycolmap.Track()
            for v, ids in enumerate(idx_per_view):
                for k, pid in enumerate(ids):
                    if pid == j:
                        track.add_element(v + 1, k)
            point_ids.append(rec.add_point3D(X, track))

        cfg = pycolmap.BundleAdjustmentConfig()
        for v in range(len(object_points)):
            cfg.add_image(v + 1)
        for pid in point_ids:
            cfg.add_constant_point(pid)
        opts = pycolmap.BundleAdjustmentOptions()
        opts.refine_focal_length = True
        opts.refine_principal_point = True
        opts.refine_extra_params = True
        opts.print_summary = False
        so = opts.ceres.solver_options
        so.max_num_iterations = self.max_iterations
        so.function_tolerance = 1e-16
        so.gradient_tolerance = 1e-16
        so.parameter_tolerance = 1e-16
        so.num_threads = 1
        ba = pycolmap.create_default_ceres_bundle_adjuster(opts, cfg, rec)
        cam_ref = rec.cameras[1]
        fixed: list[str]
        manifold = None
        if self.model == "FULL_OPENCV":
            pyceres = _import("pyceres")

            # keep a Python reference: Ceres does not own the manifold, and a collected temporary segfaults the solve
            manifold = pyceres.SubsetManifold(12, [9, 10, 11])  # k4, k5, k6 (index 8 is k3: it stays free)
            ba.problem.set_manifold(cam_ref.params, manifold)
            fixed = ["k4", "k5", "k6"]
        else:
            fixed = ["k3"]
        summary = ba.solve()
        cp = np.asarray(rec.cameras[1].params, dtype=np.float64)
        dist = np.zeros(5)
        dist[:4] = cp[4:8]
        if self.model == "FULL_OPENCV":
            dist[4] = cp[8]
            if np.any(cp[9:12] != 0):
                raise RuntimeError(f"k4-k6 moved off zero ({cp[9:12]}): SubsetManifold not applied")
        camera = Camera(int(w), int(h), float(cp[0]), float(cp[1]), float(cp[2] - COLMAP_OFFSET),
                        float(cp[3] - COLMAP_OFFSET), dist)
        import cv2

        rvecs, tvecs = [], []
        for v in range(len(object_points)):
            T = rec.images[v + 1].cam_from_world()
            M = np.asarray(T.matrix())
            rv, _ = cv2.Rodrigues(M[:, :3])
            rvecs.append(rv.reshape(3))
            tvecs.append(M[:, 3])
        rvecs_a, tvecs_a = np.array(rvecs), np.array(tvecs)
        # sanity: our rotation convention equals COLMAP's
        assert np.allclose(rodrigues(rvecs_a[0]), np.asarray(rec.images[1].cam_from_world().matrix())[:, :3],
                           atol=1e-9)

        # standard deviations
        std = None
        std_note = ""
        try:
            cov = pycolmap.estimate_ba_covariance(pycolmap.BACovarianceOptions(), rec, ba)
            C = None if cov is None else cov.get_other_params_cov(rec.cameras[1].params)
            if C is None:
                std_note = "estimate_ba_covariance returned nothing"
            else:
                C = np.asarray(C)
                n_free_intr = C.shape[0]
                n_obs = 2 * sum(len(q) for q in image_points)
                n_free = n_free_intr + 6 * len(object_points)
                ssr = 0.0
                for o, q, r, t in zip(object_points, image_points, rvecs_a, tvecs_a):
                    ssr += float(np.sum((project(o, r, t, camera) - q) ** 2))
                sigma2 = ssr / max(n_obs - n_free, 1)
                sd = np.sqrt(np.clip(np.diag(C), 0, None) * sigma2)
                # tangent order: the free parameters in COLMAP's order (fx fy cx cy k1 k2 p1 p2 [k3])
                names = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"] + (["k3"] if self.model == "FULL_OPENCV"
                                                                           else [])
                if len(names) != n_free_intr:
                    std_note = f"unexpected covariance size {n_free_intr} for {self.model}"
                else:
                    std = {n: 0.0 for n in PARAM_NAMES}
                    std.update({n: float(s) for n, s in zip(names, sd)})
        except Exception as exc:  # noqa: BLE001
            std_note = f"covariance failed: {type(exc).__name__}: {exc}"
        del manifold  # only now may the manifold go (the adjuster and covariance are done with it)
        term = str(getattr(summary, "termination_type", ""))
        return self.finish(mode, camera, rvecs_a, tvecs_a, object_points, image_points, t0, std=std,
                           fixed=fixed, model=self.model, ceres_termination=term,
                           ceres_iterations=int(getattr(summary, "num_iterations", -1))
                           if hasattr(summary, "num_iterations") else None,
                           std_note=std_note, seed_fx=float(seed.fx),
                           note="pixel convention converted from COLMAP's (0.5, 0.5) top-left centre")
