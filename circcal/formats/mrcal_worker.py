#!/usr/bin/env python3
"""mrcal worker: runs under an interpreter that can ``import mrcal`` (Debian's /usr/bin/python3 with mrcal 2.2, or a
Python 3.12 with PyPI's mrcal 2.5). It imports nothing from circcal (that side runs numpy 2, which mrcal cannot sit
beside).

Protocol: one JSON object on stdin, one JSON object on stdout; exit status 0 on success, 1 with ``{"error": ...}``.

``python mrcal_worker.py --probe`` prints ``{"version": ..., "api": ...}`` and exits.

A request with ``"command": "export"``, ``"uncertainty"`` or ``"rig"`` runs :func:`export`, :func:`uncertainty` or
:func:`rig` (a rig of N cameras; see there); without ``"command"`` it is a calibration (below).

Request::

    {"modes": ["fair", "default"],          # each solved from its seed (see Modes)
     "width_n": W, "height_n": H,           # board lattice (points per row, rows)
     "spacing": s,                          # lattice pitch, caller's unit (mm)
     "observations": [[[[x, y, w], ...]]],  # (Nframes, H, W, 3); w = 1 observed, -1 missing
     "imagersize": [width, height],
     "focal_estimate": f,                   # seed focal length (px)
     "lensmodel": "LENSMODEL_OPENCV5",      # or OPENCV8 / OPENCV12 (OpenCV's 8- and 12-vectors, OpenCV's order)
     "seed_intrinsics": null | [fx, fy, cx, cy, *distortion of lensmodel],
     "seed_frames_fair": null | [[rx, ry, rz, tx, ty, tz], ...]}   # (Nframes, 6) lattice -> camera: fair mode's
                                            # board poses, instead of mrcal's own seed (see Modes)

Reply::

    {"version": "2.2-4+b1", "version_source": "...", "api": "2.2" | "2.5",
     "results": [{"mode", "intrinsics" (4 + n,), "frames_rt_toref" (Nframes, 6), "rms_per_coord_px",
                  "x_board" (Nframes, H, W, 2) mrcal's residuals projected - observed (0 for outliers/missing),
                  "weights" (Nframes, H, W) after outlier rejection, "n_outliers", "calobject_warp" | null,
                  "stats_keys"}]}

Modes
-----
* ``fair``: the estimator of cv2.calibrateCamera: no board warp, no regularisation, no outlier rejection
  (as ``mrcal-calibrate-cameras --skip-calobject-warp-solve --skip-regularization --skip-outlier-rejection``:
  a regularised pass first keeps the solve from wandering, then the final pass without regularisation).
  Its board poses start from ``seed_frames_fair`` where given (the caller's PnP of each view with the generic seed
  camera): mrcal 2.2's own pose seeding put three partial views of the ``occluded/bar`` scenario within 8-13 mm of
  the camera (PnP: 215-249 mm), from where the solve ended at fx 1396 px (true 550); from the PnP poses it reaches
  the shared minimum. The fair mode checks mrcal's solve, not its seeding.
* ``default``: what mrcal users get: board warp solved, regularisation on, outlier rejection on, from mrcal's own
  seed (as ``mrcal-calibrate-cameras``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from types import ModuleType
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # annotations only: the worker imports numpy (mrcal's) inside its functions
    import numpy as np

# This script sits beside formats/mrcal.py: drop its own folder from the path so `import mrcal` finds mrcal.
_HERE = os.path.dirname(os.path.realpath(__file__))
sys.path[:] = [p for p in sys.path if os.path.realpath(p or os.curdir) != _HERE]


def _version(mrcal: ModuleType) -> tuple[str, str]:
    v = getattr(mrcal, "__version__", None)
    if v:
        return str(v), "mrcal.__version__"
    try:
        import importlib.metadata as md

        return md.version("mrcal"), "importlib.metadata"
    except Exception:  # noqa: BLE001
        pass
    for pkg in ("python3-mrcal", "mrcal"):
        try:
            out = subprocess.run(["dpkg-query", "-W", "-f=${Version}", pkg], capture_output=True, text=True, timeout=20)
            if out.returncode == 0 and out.stdout.strip():
                return out.stdout.strip(), f"dpkg-query {pkg}"
        except Exception:  # noqa: BLE001
            pass
    return "unknown", "none"


def _api(mrcal: ModuleType) -> str:
    return "2.5" if hasattr(mrcal, "measurements_board") else "2.2"


def _names(api: str) -> tuple[str, str]:
    """(camera-extrinsics key, frame-poses key) of optimize()'s inputs."""
    return ("rt_cam_ref", "rt_ref_frame") if api == "2.5" else ("extrinsics_rt_fromref", "frames_rt_toref")


def _stereographic_seed(
    mrcal: ModuleType,
    common: dict[str, Any],
    obs: Any,
    indices_frame_camera: Any,
    focal: float,
    names: tuple[str, str],
    frames: Any,
) -> tuple[Any, Any, Any]:
    """mrcal's seed of N cameras (as ``mrcal-calibrate-cameras``): ``seed_stereographic``, then the stereographic
    lens solved for the geometry alone and then with its core. ``frames``: the board poses to start from instead of
    mrcal's (None: mrcal's). Returns (intrinsics (Ncam, 4), extrinsics (Ncam - 1, 6), frames (Nframes, 6))."""
    import numpy as np

    seeded = mrcal.seed_stereographic(
        imagersizes=common["imagersizes"],
        focal_estimate=focal,
        indices_frame_camera=indices_frame_camera,
        observations=obs,
        object_spacing=common["calibration_object_spacing"],
    )
    intr, ext, fr = (np.ascontiguousarray(a, dtype=np.float64) for a in seeded)
    if frames is not None:
        fr = frames
    for core in (False, True):
        inputs = dict(
            common,
            observations_board=obs,
            intrinsics=intr,
            lensmodel="LENSMODEL_STEREOGRAPHIC",
            do_optimize_intrinsics_core=core,
            do_optimize_intrinsics_distortions=False,
            do_optimize_calobject_warp=False,
            calobject_warp=None,
            do_apply_outlier_rejection=False,
            do_apply_regularization=False,
        )
        inputs[names[0]], inputs[names[1]] = ext, fr
        mrcal.optimize(**inputs)
    return intr, ext, fr


def solve(req: dict[str, Any]) -> dict[str, Any]:
    """A calibration by mrcal, in each of the request's modes (module docstring: Request, Reply, Modes).

    Parameters
    ----------
    req : dict
        The request (module docstring).

    Returns
    -------
    dict
        The reply: ``version``, ``version_source``, ``api``, ``results`` (one per mode).
    """
    import mrcal
    import numpy as np

    api = _api(mrcal)
    k_ext, k_frames = _names(api)
    version, vsrc = _version(mrcal)
    W, H = int(req["width_n"]), int(req["height_n"])
    spacing = float(req["spacing"])
    obs0 = np.ascontiguousarray(np.asarray(req["observations"], dtype=np.float64).reshape(-1, H, W, 3))
    nf = obs0.shape[0]
    imagersizes = np.array([req["imagersize"]], dtype=np.int32)
    indices_frame_camera = np.array([[i, 0] for i in range(nf)], dtype=np.int32)
    indices_fce = np.array([[i, 0, -1] for i in range(nf)], dtype=np.int32)

    common = dict(
        points=None,
        observations_board=obs0.copy(),
        indices_frame_camintrinsics_camextrinsics=indices_fce,
        observations_point=None,
        indices_point_camintrinsics_camextrinsics=None,
        imagersizes=imagersizes,
        calibration_object_spacing=spacing,
        verbose=False,
    )
    lensmodel = str(req.get("lensmodel", "LENSMODEL_OPENCV5"))
    n_intr = int(mrcal.lensmodel_num_params(lensmodel))

    def seed(frames_given: Any) -> tuple[np.ndarray, np.ndarray]:
        """(intrinsics (1, n_intr), frames (Nframes, 6)): stereographic, geometry only, then + core (as
        mrcal-calibrate-cameras does), from mrcal's own pose seed or ``frames_given``."""
        given = None
        if frames_given is not None:
            given = np.ascontiguousarray(np.asarray(frames_given, dtype=np.float64).reshape(nf, 6))
        intrinsics, _, frames = _stereographic_seed(
            mrcal, common, obs0.copy(), indices_frame_camera, float(req["focal_estimate"]), (k_ext, k_frames), given
        )
        if req.get("seed_intrinsics") is not None:
            seed_intr = np.asarray(req["seed_intrinsics"], dtype=np.float64).reshape(1, n_intr)
        else:
            rng = np.random.default_rng(0)  # tiny non-zero distortion seed, as the CLI does (deterministic here)
            seed_intr = np.concatenate([intrinsics, (rng.random((1, n_intr - 4)) - 0.5) * 2e-6], axis=1)
        return seed_intr, frames.copy()

    seeds: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    results: list[dict[str, Any]] = []
    for mode in req["modes"]:
        given = req.get("seed_frames_fair") if mode == "fair" else None
        key = "fair" if given is not None else "mrcal"
        if key not in seeds:
            seeds[key] = seed(given)
        seed_intr, seed_frames = seeds[key]
        obs = obs0.copy()
        intr = seed_intr.copy()
        fr = seed_frames.copy()
        ext = np.zeros((0, 6))
        base = dict(
            common,
            observations_board=obs,
            intrinsics=intr,
            lensmodel=lensmodel,
            do_optimize_intrinsics_core=True,
            do_optimize_intrinsics_distortions=True,
            do_optimize_extrinsics=True,
            do_optimize_frames=True,
        )
        base[k_ext] = ext
        base[k_frames] = fr
        # main solve from the seed (the CLI's solve_initial): regularised, no warp
        first = dict(
            base,
            calobject_warp=None,
            do_optimize_calobject_warp=False,
            do_apply_regularization=True,
            do_apply_outlier_rejection=(mode == "default"),
        )
        mrcal.optimize(**first)
        warp = None
        if mode == "fair":
            final = dict(
                base,
                calobject_warp=None,
                do_optimize_calobject_warp=False,
                do_apply_regularization=False,
                do_apply_outlier_rejection=False,
            )
        elif mode == "default":
            warp = np.zeros(2, dtype=np.float64)
            final = dict(
                base,
                calobject_warp=warp,
                do_optimize_calobject_warp=True,
                do_apply_regularization=True,
                do_apply_outlier_rejection=True,
            )
        else:
            raise ValueError(f"unknown mode {mode!r}")
        stats = mrcal.optimize(**final)
        x = np.asarray(stats["x"], dtype=np.float64)[: nf * H * W * 2].reshape(nf, H, W, 2)
        n_out = stats.get("Noutliers_board", stats.get("Noutliers", 0))
        results.append(
            {
                "mode": mode,
                "lensmodel": lensmodel,
                "intrinsics": intr.reshape(-1).tolist(),
                "frames_rt_toref": fr.tolist(),
                "rms_per_coord_px": float(stats["rms_reproj_error__pixels"]),
                "x_board": x.tolist(),
                "weights": obs[..., 2].tolist(),
                "n_outliers": int(n_out),
                "calobject_warp": None if warp is None else warp.tolist(),
                "stats_keys": sorted(str(k) for k in stats.keys()),
            }
        )
    return {"version": version, "version_source": vsrc, "api": api, "results": results}


def _export_inputs(req: dict[str, Any], api: str) -> dict[str, Any]:
    """mrcal.optimize() inputs at a given solution (no optimisation run): ``req["lensmodel"]`` (default
    LENSMODEL_OPENCV5; OPENCV4 when k3 is held at 0), the board lattice observations, the frames (lengths in the
    caller's unit: the export sends metres), the board warp (``req["calobject_warp"]``, metres, marked as estimated;
    else a flat board held: zeros(2)), and the fair-mode switches (no regularisation, no outlier rejection:
    circcal's estimator, whose optimum this is)."""
    import numpy as np

    k_ext, k_frames = _names(api)
    W, H = int(req["width_n"]), int(req["height_n"])
    obs = np.ascontiguousarray(np.asarray(req["observations"], dtype=np.float64).reshape(-1, H, W, 3))
    nf = obs.shape[0]
    intr = np.asarray(req["intrinsics"], dtype=np.float64).reshape(1, -1)
    lensmodel = str(req.get("lensmodel", "LENSMODEL_OPENCV5"))
    if req.get("opencv4"):
        lensmodel, intr = "LENSMODEL_OPENCV4", intr[:, :8]
    inputs = dict(
        intrinsics=np.ascontiguousarray(intr),
        lensmodel=lensmodel,
        points=None,
        observations_board=obs,
        indices_frame_camintrinsics_camextrinsics=np.array([[i, 0, -1] for i in range(nf)], dtype=np.int32),
        observations_point=None,
        indices_point_camintrinsics_camextrinsics=None,
        imagersizes=np.array([req["imagersize"]], dtype=np.int32),
        calibration_object_spacing=float(req["spacing"]),
        # the caller's fitted warp (metres), else a flat board, given as an array either way: mrcal's tools that
        # re-solve with the warp freed (mrcal-convert-lensmodel) need one to seed it ("calobject_warp MUST be given
        # as an array")
        calobject_warp=np.asarray(req.get("calobject_warp") or (0.0, 0.0), dtype=np.float64),
        do_optimize_intrinsics_core=True,
        do_optimize_intrinsics_distortions=True,
        do_optimize_extrinsics=True,
        do_optimize_frames=True,
        # an estimated warp is part of the state mrcal's uncertainty propagates (as circcal's covariance has it)
        do_optimize_calobject_warp=req.get("calobject_warp") is not None,
        do_apply_outlier_rejection=False,
        do_apply_regularization=False,
        verbose=False,
    )
    inputs[k_ext] = np.zeros((0, 6))
    inputs[k_frames] = np.ascontiguousarray(np.asarray(req["frames_rt_toref"], dtype=np.float64).reshape(nf, 6))
    return inputs


def _uncertainty_at(mrcal: ModuleType, model: Any, uv: Any, distance: float | None, sigma: float | None) -> list[float]:
    """mrcal.projection_uncertainty (worst-direction stdev, px) at pixels ``uv`` (N, 2), ``distance`` along each
    ray (None: infinity) and per-coordinate noise ``sigma`` (None: mrcal's estimate from the residuals)."""
    import numpy as np

    q = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    v = mrcal.unproject(q, *model.intrinsics(), normalize=True)
    p = v if distance is None else v * float(distance)
    s = mrcal.projection_uncertainty(
        p, model=model, atinfinity=distance is None, what="worstdirection-stdev", observed_pixel_uncertainty=sigma
    )
    return np.asarray(s, dtype=np.float64).reshape(-1).tolist()


def export(req: dict[str, Any]) -> dict[str, Any]:
    """A ``.cameramodel`` carrying mrcal's optimisation inputs, built from circcal's observations and solution.

    Parameters
    ----------
    req : dict
        ``{"command": "export", "width_n", "height_n", "spacing", "observations" (Nframes, H, W, 3) with w = 1
        observed and -1 missing, "imagersize", "lensmodel" (optional, default LENSMODEL_OPENCV5), "intrinsics"
        (4 + n,), "frames_rt_toref" (Nframes, 6) in mrcal's board frame, "opencv4": bool (k3 held at 0), "note": str,
        "uncertainty": null | {"uv", "distance", "observed_pixel_uncertainty"}}``.

    Returns
    -------
    dict
        ``{"version", "api", "cameramodel" (the file's text), "rms_per_coord_px" (mrcal's, from its own residuals at
        this state), "max_abs_gradient" (of mrcal's cost in its packed state: ~0 at an optimum),
        "uncertainty_stdev" (px, when asked)}``.
    """
    import io

    import mrcal
    import numpy as np

    api = _api(mrcal)
    version, vsrc = _version(mrcal)
    inputs = _export_inputs(req, api)
    cb = mrcal.optimizer_callback(**inputs)
    x, J = np.asarray(cb[1], dtype=np.float64), cb[2]
    nobs = int(np.sum(inputs["observations_board"][..., 2] > 0))
    model = mrcal.cameramodel(optimization_inputs=inputs, icam_intrinsics=0)
    f = io.StringIO()
    model.write(f, note=req.get("note"))
    out = {
        "version": version,
        "version_source": vsrc,
        "api": api,
        "cameramodel": f.getvalue(),
        "rms_per_coord_px": float(np.sqrt(np.sum(x * x) / (2 * nobs))),
        "max_abs_gradient": float(np.max(np.abs(J.T @ x))),
    }
    if req.get("uncertainty"):
        u = req["uncertainty"]
        out["uncertainty_stdev"] = _uncertainty_at(
            mrcal, model, u["uv"], u.get("distance"), u.get("observed_pixel_uncertainty")
        )
    return out


def uncertainty(req: dict[str, Any]) -> dict[str, Any]:
    """mrcal's projection uncertainty of a ``.cameramodel`` with optimisation inputs.

    Parameters
    ----------
    req : dict
        ``{"command": "uncertainty", "cameramodel": text, "uv": (N, 2), "distance": mm | null,
        "observed_pixel_uncertainty": px | null}``.

    Returns
    -------
    dict
        ``{"version", "api", "stdev" (N,) px, "lensmodel", "imagersize"}``.

    Raises
    ------
    ValueError
        The model has no optimisation inputs (:func:`main` replies ``{"error"}``).
    """
    import io

    import mrcal

    version, _ = _version(mrcal)
    model = mrcal.cameramodel(io.StringIO(req["cameramodel"]))
    if model.optimization_inputs() is None:
        raise ValueError("the model has no optimization_inputs: mrcal cannot compute its uncertainty")
    return {
        "version": version,
        "api": _api(mrcal),
        "lensmodel": model.intrinsics()[0],
        "imagersize": [int(v) for v in model.imagersize()],
        "stdev": _uncertainty_at(mrcal, model, req["uv"], req.get("distance"), req.get("observed_pixel_uncertainty")),
    }


def rig(req: dict[str, Any]) -> dict[str, Any]:
    """A rig's calibration by mrcal: N stationary cameras, one board per frame (``"command": "rig"``).

    Request: ``width_n``, ``height_n``, ``spacing`` (as a calibration's); ``observations`` (Nobs, H, W, 3) with
    ``indices_frame_camera`` (Nobs, 2) [frame, camera], sorted by frame then camera; ``imagersizes`` (Ncam, 2);
    ``focal_estimate``; ``lensmodel`` (one for every camera: mrcal's optimize takes one); ``modes``; for ``fair``
    the seed ``seed_intrinsics`` (Ncam, n), ``seed_extrinsics`` (Ncam - 1, 6) rt_fromref and ``seed_frames``
    (Nframes, 6) rt_toref (the caller's start; mrcal's stereographic seed where absent).

    Parameters
    ----------
    req : dict

    Returns
    -------
    dict
        ``version``, ``api``, ``results``: per mode ``intrinsics`` (Ncam, n), ``extrinsics_rt_fromref`` (Ncam - 1, 6;
        ``x_cam = R x_ref + t``, camera 0 the reference), ``frames_rt_toref``, ``rms_per_coord_px``, ``n_outliers``,
        ``calobject_warp``.
    """
    import mrcal
    import numpy as np

    api = _api(mrcal)
    k_ext, k_frames = _names(api)
    version, vsrc = _version(mrcal)
    W, H = int(req["width_n"]), int(req["height_n"])
    spacing = float(req["spacing"])
    obs0 = np.ascontiguousarray(np.asarray(req["observations"], dtype=np.float64).reshape(-1, H, W, 3))
    ifc = np.ascontiguousarray(np.asarray(req["indices_frame_camera"], dtype=np.int32).reshape(-1, 2))
    imagersizes = np.ascontiguousarray(np.asarray(req["imagersizes"], dtype=np.int32).reshape(-1, 2))
    ncam = len(imagersizes)
    ifce = np.ascontiguousarray(np.column_stack([ifc, ifc[:, 1] - 1]).astype(np.int32))
    lensmodel = str(req.get("lensmodel", "LENSMODEL_OPENCV5"))
    n_intr = int(mrcal.lensmodel_num_params(lensmodel))
    common = dict(
        points=None,
        indices_frame_camintrinsics_camextrinsics=ifce,
        observations_point=None,
        indices_point_camintrinsics_camextrinsics=None,
        imagersizes=imagersizes,
        calibration_object_spacing=spacing,
        verbose=False,
    )

    def mrcal_seed() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        intr, ext, frames = _stereographic_seed(
            mrcal, common, obs0.copy(), ifc, float(req["focal_estimate"]), (k_ext, k_frames), None
        )
        rng = np.random.default_rng(0)
        intr = np.concatenate([intr, (rng.random((ncam, n_intr - 4)) - 0.5) * 2e-6], axis=1)
        return intr, ext, frames

    results: list[dict[str, Any]] = []
    for mode in req["modes"]:
        if mode == "fair" and req.get("seed_intrinsics") is not None:
            intr = np.asarray(req["seed_intrinsics"], dtype=np.float64).reshape(ncam, n_intr).copy()
            ext = np.asarray(req["seed_extrinsics"], dtype=np.float64).reshape(ncam - 1, 6).copy()
            fr = np.asarray(req["seed_frames"], dtype=np.float64).reshape(-1, 6).copy()
        else:
            intr, ext, fr = (np.ascontiguousarray(a) for a in mrcal_seed())
        obs = obs0.copy()
        base = dict(
            common,
            observations_board=obs,
            intrinsics=intr,
            lensmodel=lensmodel,
            do_optimize_intrinsics_core=True,
            do_optimize_intrinsics_distortions=True,
            do_optimize_extrinsics=True,
            do_optimize_frames=True,
        )
        base[k_ext], base[k_frames] = ext, fr
        default = mode == "default"
        if mode not in ("fair", "default"):
            raise ValueError(f"unknown mode {mode!r}")
        mrcal.optimize(
            **dict(
                base,
                calobject_warp=None,
                do_optimize_calobject_warp=False,
                do_apply_regularization=True,
                do_apply_outlier_rejection=default,
            )
        )
        warp = np.zeros(2, dtype=np.float64) if default else None
        stats = mrcal.optimize(
            **dict(
                base,
                calobject_warp=warp,
                do_optimize_calobject_warp=default,
                do_apply_regularization=default,
                do_apply_outlier_rejection=default,
            )
        )
        results.append(
            {
                "mode": mode,
                "lensmodel": lensmodel,
                "intrinsics": intr.tolist(),
                "extrinsics_rt_fromref": ext.tolist(),
                "frames_rt_toref": fr.tolist(),
                "rms_per_coord_px": float(stats["rms_reproj_error__pixels"]),
                "n_outliers": int(stats.get("Noutliers_board", stats.get("Noutliers", 0))),
                "calobject_warp": None if warp is None else warp.tolist(),
            }
        )
    return {"version": version, "version_source": vsrc, "api": api, "results": results}


COMMANDS = {"export": export, "uncertainty": uncertainty, "rig": rig}


def main(argv: list[str]) -> int:
    """The worker's entry point: ``--probe``, or one request from stdin answered on stdout (module docstring).

    Parameters
    ----------
    argv : list of str
        The command line's arguments.

    Returns
    -------
    int
        The exit status: 0 on success, 1 with ``{"error": ..., "traceback": ...}`` on stdout.
    """
    if "--probe" in argv:
        try:
            import mrcal
        except Exception as exc:  # noqa: BLE001
            print(json.dumps({"error": f"cannot import mrcal: {type(exc).__name__}: {exc}"}))
            return 1
        v, src = _version(mrcal)
        print(json.dumps({"version": v, "version_source": src, "api": _api(mrcal), "python": sys.version.split()[0]}))
        return 0
    try:
        req = json.loads(sys.stdin.read())
        out = COMMANDS[req["command"]](req) if "command" in req else solve(req)
    except Exception as exc:  # noqa: BLE001
        import traceback

        print(json.dumps({"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}))
        return 1
    sys.stdout.write(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
