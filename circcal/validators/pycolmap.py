"""pycolmap as a reference: COLMAP's Ceres bundle adjustment with the board held constant.

The world frame is the board, every view an image whose pose ``cam_from_world`` is the board-to-camera transform,
and the board points are constant 3-D points. Lens models ``opencv5`` and ``rational`` (``FULL_OPENCV``), ``fisheye``
(``OPENCV_FISHEYE``); ``thin-prism`` is unsupported. COLMAP puts the top-left pixel centre at (0.5, 0.5)
(OpenCV: (0, 0)). The models, parameter orders and standard deviations are described in docs/references.md ("How
the adapters work: pycolmap").
"""

from __future__ import annotations

import time

import numpy as np

from circcal.model import Camera, param_names, project
from circcal.observations import distinct_points
from circcal.rotation import rodrigues
from circcal.validators.base import BaseCalibrator
from circcal.validators.reference_result import ReferenceResult
from circcal.validators.seeds import seed_camera

__all__ = ["PycolmapCalibrator", "MODELS"]

MODELS = ("FULL_OPENCV", "OPENCV", "OPENCV_FISHEYE")
#: circcal lens -> the COLMAP model fitting it, and the COLMAP models a lens may be given
LENS_TO_MODEL: dict[str, str] = {"opencv5": "FULL_OPENCV", "rational": "FULL_OPENCV", "fisheye": "OPENCV_FISHEYE"}
_LENS_MODELS: dict[str, tuple[str, ...]] = {
    "opencv5": ("FULL_OPENCV", "OPENCV"),
    "rational": ("FULL_OPENCV",),
    "fisheye": ("OPENCV_FISHEYE",),
}
#: COLMAP's parameter names per model (``pycolmap.Camera.params_info``)
MODEL_PARAMS: dict[str, tuple[str, ...]] = {
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
}
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


def to_colmap_params(camera: Camera, model: str) -> np.ndarray:
    """COLMAP parameters of a camera for a COLMAP model.

    circcal's names map one to one; the principal point is shifted by +0.5 px (COLMAP's pixel convention); a COLMAP
    parameter the camera's lens lacks (k4-k6 of FULL_OPENCV for opencv5) is 0.

    Parameters
    ----------
    camera : circcal.model.Camera
        The camera.
    model : str
        One of :data:`MODELS`.

    Returns
    -------
    ndarray, shape (P,)
        In COLMAP's order (:data:`MODEL_PARAMS`); px for fx, fy, cx, cy.

    Raises
    ------
    ValueError
        The camera has a coefficient ``model`` lacks and it is not 0 (k3 in OPENCV).
    """
    values = dict(zip(param_names(camera.lens), np.asarray(camera.intrinsics, dtype=np.float64)))
    values["cx"] += COLMAP_OFFSET
    values["cy"] += COLMAP_OFFSET
    names = MODEL_PARAMS[model]
    lost = [n for n, v in values.items() if n not in names and v != 0.0]
    if lost:
        raise ValueError(f"COLMAP's {model} has no {', '.join(lost)}")
    return np.array([values.get(n, 0.0) for n in names])


def from_colmap_params(params: np.ndarray, model: str, lens: str, width: int, height: int) -> Camera:
    """The circcal camera of a lens from COLMAP model parameters (the inverse of :func:`to_colmap_params`).

    Parameters
    ----------
    params : ndarray, shape (P,)
        In COLMAP's order (:data:`MODEL_PARAMS`).
    model : str
        One of :data:`MODELS`.
    lens : str
        The circcal lens model.
    width, height : int
        Image size, px.

    Returns
    -------
    circcal.model.Camera

    Raises
    ------
    ValueError
        A COLMAP parameter the lens lacks is not 0.
    """
    values = dict(zip(MODEL_PARAMS[model], np.asarray(params, dtype=np.float64)))
    values["cx"] -= COLMAP_OFFSET
    values["cy"] -= COLMAP_OFFSET
    names = param_names(lens)
    lost = [n for n, v in values.items() if n not in names and v != 0.0]
    if lost:
        raise ValueError(f"lens {lens!r} has no {', '.join(lost)} (COLMAP {model})")
    return Camera.from_intrinsics(width, height, np.array([values.get(n, 0.0) for n in names]), lens=lens)


class PycolmapCalibrator(BaseCalibrator):
    """Reference: pycolmap's Ceres bundle adjustment.

    Parameters
    ----------
    lens : str
        The circcal lens model fitted: "opencv5", "rational" or "fisheye" (docs/references.md).
    model : str, optional
        The COLMAP model; default the one of :data:`LENS_TO_MODEL`; for ``opencv5`` also "OPENCV" (no k3: k3 = 0).
    max_iterations : int
        Ceres iterations (tolerances are set tight).

    Raises
    ------
    ValueError
        An unknown COLMAP model, or one that does not fit ``lens``.
    """

    name = "pycolmap"
    modes = ("fair",)
    lenses = tuple(LENS_TO_MODEL)
    unsupported_lenses = {
        "thin-prism": "COLMAP has no pinhole model with OpenCV's thin-prism terms s1-s4 (its THIN_PRISM_FISHEYE and "
        "RAD_TAN_THIN_PRISM_FISHEYE are equidistant fisheye models)"
    }

    def __init__(self, *, lens: str = "opencv5", model: str | None = None, max_iterations: int = 500) -> None:
        if model is not None and model not in MODELS:
            raise ValueError(f"unknown pycolmap model {model!r}; expected one of {', '.join(MODELS)}")
        if lens in _LENS_MODELS and model is not None and model not in _LENS_MODELS[lens]:
            raise ValueError(
                f"COLMAP model {model} does not fit lens {lens!r}; it needs {' or '.join(_LENS_MODELS[lens])}"
            )
        self.lens = lens
        self.model = model if model is not None else LENS_TO_MODEL.get(lens, "FULL_OPENCV")
        self.max_iterations = int(max_iterations)

    def _version(self) -> str:
        pycolmap = _import("pycolmap")

        return pycolmap.__version__

    def _available(self) -> tuple[bool, str]:
        try:
            pycolmap = _import("pycolmap")  # noqa: F841
        except ImportError as exc:
            return False, f"pycolmap not importable ({exc}); pip install pycolmap pyceres"
        if self.model == "FULL_OPENCV" and self.lens == "opencv5":
            try:
                pyceres = _import("pyceres")  # noqa: F841
            except ImportError as exc:
                return False, (
                    f"pyceres not importable ({exc}): needed to hold k4-k6 fixed in FULL_OPENCV; "
                    "pip install pyceres, or use model='OPENCV'"
                )
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
        pycolmap = _import("pycolmap")

        t0 = time.perf_counter()
        w, h = image_size
        lens = self.lens
        if initial is not None and initial.lens != lens:
            raise ValueError(f"initial camera has lens {initial.lens!r}, this reference fits {lens!r}")
        seed = initial if initial is not None else seed_camera(object_points, image_points, image_size, lens=lens)
        cam = pycolmap.Camera.create_from_model_name(1, self.model, float(seed.fx), int(w), int(h))
        cam.params = to_colmap_params(seed, self.model)
        rec = pycolmap.Reconstruction()
        rec.add_camera_with_trivial_rig(cam)

        # one 3-D point per distinct board point (views may observe different subsets)
        xyz, idx_per_view = distinct_points(object_points)

        est = pycolmap.AbsolutePoseEstimationOptions()
        est.ransac.max_error = 0.02 * max(w, h)  # seed has no distortion: be generous
        # COLMAP seeds its RANSAC from the clock by default (-1): the initial poses, and through them the last
        # digits of the solution (~1e-9 relative), changed from run to run; a fixed seed makes runs repeatable
        est.ransac.random_seed = 0
        for v, (o, q) in enumerate(zip(object_points, image_points)):
            pose = pycolmap.estimate_and_refine_absolute_pose(q + COLMAP_OFFSET, o, cam, est)
            if pose is None:
                raise RuntimeError(f"view {v}: pycolmap could not estimate an initial pose")
            img = pycolmap.Image(name=f"view{v:04d}", keypoints=q + COLMAP_OFFSET, camera_id=1, image_id=v + 1)
            rec.add_image_with_trivial_frame(img, pose["cam_from_world"])
        # COLMAP's bundle adjustment takes no track of one observation (bundle_adjustment_ceres.cc checks track
        # length > 1, constant points too): a board point seen in one view only is left out, and said so (the
        # conformance suite then compares with circcal's solve on the same subset, ``extra["left_out"]``)
        views_of = np.bincount(np.concatenate(idx_per_view), minlength=len(xyz)) if len(xyz) else np.zeros(0, int)
        left_out = {v: [int(k) for k, pid in enumerate(ids) if views_of[pid] < 2] for v, ids in enumerate(idx_per_view)}
        left_out = {v: ks for v, ks in left_out.items() if ks}
        point_ids = []
        for j, X in enumerate(xyz):
            if views_of[j] < 2:
                continue
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
        fixed: list[str] = []  # COLMAP parameters held at 0 (a k3 absent from OPENCV counts as fixed)
        manifold = None
        if self.model == "FULL_OPENCV" and lens == "opencv5":
            pyceres = _import("pyceres")

            # keep a Python reference: Ceres does not own the manifold, and a collected temporary segfaults the solve
            manifold = pyceres.SubsetManifold(12, [9, 10, 11])  # k4, k5, k6 (index 8 is k3: it stays free)
            ba.problem.set_manifold(cam_ref.params, manifold)
            fixed = ["k4", "k5", "k6"]
        elif self.model == "OPENCV":
            fixed = ["k3"]
        summary = ba.solve()
        cp = np.asarray(rec.cameras[1].params, dtype=np.float64)
        if manifold is not None and np.any(cp[9:12] != 0):
            raise RuntimeError(f"k4-k6 moved off zero ({cp[9:12]}): SubsetManifold not applied")
        camera = from_colmap_params(cp, self.model, lens, int(w), int(h))
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
        assert np.allclose(rodrigues(rvecs_a[0]), np.asarray(rec.images[1].cam_from_world().matrix())[:, :3], atol=1e-9)

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
                n_obs = 2 * (sum(len(q) for q in image_points) - sum(map(len, left_out.values())))
                n_free = n_free_intr + 6 * len(object_points)
                ssr = 0.0
                for v, (o, q, r, t) in enumerate(zip(object_points, image_points, rvecs_a, tvecs_a)):
                    use = np.ones(len(q), bool)
                    use[left_out.get(v, [])] = False  # (the observations the adjustment fitted)
                    ssr += float(np.sum((project(o[use], r, t, camera) - q[use]) ** 2))
                sigma2 = ssr / max(n_obs - n_free, 1)
                sd = np.sqrt(np.clip(np.diag(C), 0, None) * sigma2)
                # tangent order: the free parameters in COLMAP's order
                names = [n for n in MODEL_PARAMS[self.model] if n not in fixed]
                if len(names) != n_free_intr:
                    std_note = f"unexpected covariance size {n_free_intr} for {self.model}"
                else:
                    std = {n: 0.0 for n in param_names(lens)}
                    std.update({n: float(s) for n, s in zip(names, sd)})
        except Exception as exc:  # noqa: BLE001
            std_note = f"covariance failed: {type(exc).__name__}: {exc}"
        del manifold  # only now may the manifold go (the adjuster and covariance are done with it)
        term = str(getattr(summary, "termination_type", ""))
        return self.finish(
            mode,
            camera,
            rvecs_a,
            tvecs_a,
            object_points,
            image_points,
            t0,
            std=std,
            fixed=fixed,
            model=self.model,
            lens=lens,
            ceres_termination=term,
            ceres_iterations=int(getattr(summary, "num_iterations", -1))
            if hasattr(summary, "num_iterations")
            else None,
            std_note=std_note,
            seed_fx=float(seed.fx),
            left_out=left_out,
            note="pixel convention converted from COLMAP's (0.5, 0.5) top-left centre"
            + (
                f"; {sum(map(len, left_out.values()))} observations of board points seen in one view "
                "only left out (COLMAP takes no single-view track)"
                if left_out
                else ""
            ),
        )
