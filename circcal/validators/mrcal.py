"""mrcal as a reference, run out of process.

mrcal cannot be imported beside numpy 2 on Python 3.11, so :mod:`circcal.formats.mrcal_worker` runs under another
interpreter (the plumbing is :mod:`circcal.formats.mrcal_process`; its names are re-exported here). Lens models
``opencv5`` / ``rational`` / ``thin-prism`` (``LENSMODEL_OPENCV5`` / ``8`` / ``12``); ``fisheye`` is unsupported;
a staggered (asymmetric) grid is fitted as its full lattice with the absent points unobserved. Modes: "fair" (no board warp, regularisation or outlier rejection) and
"default" (all three). The details are in docs/references.md ("How the adapters work: mrcal").
"""

from __future__ import annotations

import time

import numpy as np

from circcal.formats.mrcal_process import (
    LENSMODELS,
    NOT_FOUND_MESSAGE,
    UNSUPPORTED_LENSES,
    _probe,
    board_lattice,
    mrcal_python,
    run_worker,
)
from circcal.metrics import error_stats
from circcal.model import Camera, project
from circcal.observations import check_observations
from circcal.rotation import rodrigues
from circcal.validators.base import BaseCalibrator, run_safely
from circcal.validators.divergence import check_divergence
from circcal.validators.reference_result import ReferenceResult
from circcal.validators.seeds import seed_camera

__all__ = ["MrcalCalibrator", "mrcal_python", "board_lattice", "run_worker", "NOT_FOUND_MESSAGE", "LENSMODELS"]


def _seed_frames(
    object_points: list[np.ndarray], image_points: list[np.ndarray], seed: Camera, origin: np.ndarray
) -> list[list[float]] | None:
    """The fair mode's starting board poses (Nframes, 6) ``rvec, tvec`` (mrcal's lattice frame, whose origin is
    ``origin`` (3,) mm of ours, -> camera): each view's PnP with the ``seed`` camera (the generic seed, or the
    caller's initial camera; nothing of circcal's solve), in place of mrcal 2.2's own pose seeding, which on partial
    views can start a board a few mm from the camera (mrcal_worker's "Modes"). ``None`` (mrcal's seeding) when a
    view has no pose."""
    from circcal.errors import CalibrationError
    from circcal.solver.holdout import fit_pose

    frames = []
    for o, q in zip(object_points, image_points):
        try:
            rv, tv = fit_pose(np.asarray(o, np.float64) - origin, q, seed)
        except CalibrationError:
            return None
        frames.append([*map(float, rv), *map(float, tv)])
    return frames


class MrcalCalibrator(BaseCalibrator):
    """Reference: mrcal (out of process).

    mrcal offers projection uncertainty rather than parameter standard deviations: ``std`` is None.

    Parameters
    ----------
    lens : str
        The circcal lens model fitted (:data:`LENSMODELS`).
    python : str, optional
        Interpreter to use; default ``$CIRCCAL_MRCAL_PYTHON`` or ``/usr/bin/python3``.
    timeout_s : float
        Limit for one worker run, s.
    """

    name = "mrcal"
    modes = ("fair", "default")
    lenses = tuple(LENSMODELS)
    unsupported_lenses = UNSUPPORTED_LENSES

    def __init__(self, *, lens: str = "opencv5", python: str | None = None, timeout_s: float = 300.0) -> None:
        self.lens = lens
        self.python = python
        self.timeout_s = float(timeout_s)

    def _interp(self) -> tuple[str | None, str, dict]:
        if self.python:
            ok, why, info = _probe(self.python)
            return (self.python, "", info) if ok else (None, f"{NOT_FOUND_MESSAGE} ({self.python}: {why})", {})
        return mrcal_python()

    def _version(self) -> str:
        py, why, info = self._interp()
        return str(info.get("version", "unavailable")) if py else "unavailable"

    def _available(self) -> tuple[bool, str]:
        py, why, _ = self._interp()
        return (py is not None), why

    def _calibrate(
        self,
        object_points: list[np.ndarray],
        image_points: list[np.ndarray],
        image_size: tuple[int, int],
        *,
        mode: str,
        initial: Camera | None,
    ) -> ReferenceResult:
        return self._run(object_points, image_points, image_size, [mode], initial)[0]

    def calibrate_modes(
        self,
        object_points: list[np.ndarray],
        image_points: list[np.ndarray],
        image_size: tuple[int, int],
        *,
        modes: tuple[str, ...] = ("fair", "default"),
        initial: Camera | None = None,
    ) -> list[ReferenceResult]:
        """Several modes from one worker run (same seed); never raises.

        Parameters
        ----------
        object_points : list of ndarray, shape (N_v, 3)
            Board points per view, mm, z = 0.
        image_points : list of ndarray, shape (N_v, 2)
            Centres per view, px.
        image_size : tuple of int
            (width, height) px.
        modes : tuple of str
            The modes to solve, each of "fair" and "default".
        initial : circcal.model.Camera, optional
            Not used by mrcal's seed; passed through.

        Returns
        -------
        list of ReferenceResult
            One per mode, in order; a failure (bad observations, an unsupported lens or grid, a worker error) is the
            same
            for every mode.
        """
        holder: dict[str, list[ReferenceResult]] = {}

        def go() -> ReferenceResult:
            self._check_lens()
            obj, img, size = check_observations(object_points, image_points, image_size)
            holder["r"] = self._run(obj, img, size, list(modes), initial)
            return holder["r"][0]

        first = run_safely(go, name=self.name, version=lambda: self.version, mode=modes[0], available=self.available)
        if "r" in holder:
            return [check_divergence(r) for r in holder["r"]]
        out = []
        for m in modes:  # same failure for every mode
            out.append(
                ReferenceResult(
                    first.name,
                    first.version,
                    m,
                    first.status,
                    first.message,
                    time_s=first.time_s,
                    extra=dict(first.extra),
                )
            )
        return out

    def _run(
        self,
        object_points: list[np.ndarray],
        image_points: list[np.ndarray],
        image_size: tuple[int, int],
        modes: list[str],
        initial: Camera | None,
    ) -> list[ReferenceResult]:
        t0 = time.perf_counter()
        py, why, info = self._interp()
        if py is None:
            return [self.result(m, "unavailable", why) for m in modes]
        lat = board_lattice(object_points)
        W, H, s, origin = lat["width_n"], lat["height_n"], lat["spacing"], lat["origin"]
        nf = len(object_points)
        obs = np.zeros((nf, H, W, 3))
        obs[..., 2] = -1.0
        for v, (ij, q) in enumerate(zip(lat["ij"], image_points)):
            obs[v, ij[:, 0], ij[:, 1], :2] = q
            obs[v, ij[:, 0], ij[:, 1], 2] = 1.0
        if initial is not None and initial.lens != self.lens:
            raise ValueError(f"initial camera has lens {initial.lens!r}, this reference fits {self.lens!r}")
        seed = initial if initial is not None else seed_camera(object_points, image_points, image_size)
        lensmodel = LENSMODELS[self.lens]
        req = {
            "modes": modes,
            "width_n": W,
            "height_n": H,
            "spacing": s,
            "observations": obs.tolist(),
            "imagersize": [int(image_size[0]), int(image_size[1])],
            "focal_estimate": float(0.5 * (seed.fx + seed.fy)),
            "lensmodel": lensmodel,
            "seed_intrinsics": None if initial is None else initial.intrinsics.tolist(),
            "seed_frames_fair": _seed_frames(object_points, image_points, seed, origin),
        }
        reply = run_worker(py, req, self.timeout_s)
        wall = time.perf_counter() - t0
        out = []
        for r in reply["results"]:
            intr = np.asarray(r["intrinsics"], dtype=np.float64)
            cam = Camera.from_intrinsics(image_size[0], image_size[1], intr, lens=self.lens)
            rt = np.asarray(r["frames_rt_toref"], dtype=np.float64).reshape(nf, 6)
            rvecs = rt[:, :3]
            # mrcal's board frame starts at the lattice origin: ours is shifted by `origin`
            tvecs = np.array([rt[v, 3:] - rodrigues(rt[v, :3]) @ origin for v in range(nf)])
            x = np.asarray(r["x_board"], dtype=np.float64).reshape(nf, H, W, 2)
            wts = np.asarray(r["weights"], dtype=np.float64).reshape(nf, H, W)
            mrcal_res = []
            for v, ij in enumerate(lat["ij"]):
                rv = -x[v, ij[:, 0], ij[:, 1]]  # ours: observed - projected
                rv[wts[v, ij[:, 0], ij[:, 1]] <= 0] = np.nan
                mrcal_res.append(rv)
            extra = dict(
                api=reply["api"],
                version_source=reply.get("version_source"),
                interpreter=py,
                lattice={"width_n": W, "height_n": H, "spacing_mm": s, "origin_mm": origin.tolist()},
                rms_per_coord_px_mrcal=r["rms_per_coord_px"],
                n_outliers=r["n_outliers"],
                calobject_warp=r["calobject_warp"],
                seed_focal_px=req["focal_estimate"],
                seed_from="cv2.initCameraMatrix2D focal (mrcal needs a focal estimate)"
                if initial is None
                else "initial camera",
                worker_wall_s=wall,
                lensmodel=lensmodel,
                lens=self.lens,
            )
            if r["mode"] == "fair":
                res = self.finish(r["mode"], cam, rvecs, tvecs, object_points, image_points, t0, **extra)
                # mrcal's own residuals agree with ours (flat board, same model): record the check
                ours = np.concatenate(res.residuals)
                extra_check = float(np.nanmax(np.abs(ours - np.concatenate(mrcal_res))))
                res.extra["max_abs_residual_diff_vs_mrcal_px"] = extra_check
            else:
                res = self.finish(
                    r["mode"],
                    cam,
                    rvecs,
                    tvecs,
                    object_points,
                    image_points,
                    t0,
                    residuals=mrcal_res,
                    message=f"mrcal default: board warp {np.round(r['calobject_warp'], 6).tolist()}, "
                    f"regularisation, {r['n_outliers']} outliers rejected",
                    **extra,
                )
                res.extra["errors_flat_board_no_outlier_rejection"] = error_stats(
                    np.concatenate(
                        [p - project(o, rv, tv, cam) for o, p, rv, tv in zip(object_points, image_points, rvecs, tvecs)]
                    )
                )
            res.time_s = wall / len(reply["results"])
            out.append(res)
        return out

    def _calibrate_images(self, paths, board, image_size, *, mode, initial) -> ReferenceResult:
        return self.result(
            mode,
            "unsupported",
            "mrcal has no circle-grid detector (its finder, mrgingham, finds chessboards): "
            "with --observations circcal it fits circcal's centres",
        )
