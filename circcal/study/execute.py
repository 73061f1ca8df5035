"""What a worker does with a task (:class:`circcal.study.plan.Task`): compute its runs and return their rows.

* images: render the seeded fixture on this worker (:mod:`circcal.study.seeded`), then per variant circcal's whole
  pipeline (:func:`circcal.pipeline.calibrate_images`: detect -> calibrate -> re-correct, one detection thread),
  and each reference on its own detector (``calibrate_images``) or on circcal's final centres float32-shared
  (:func:`circcal.validators.shared.share`, as ``circcal validate`` hands them out);
* observations: the cell's fixed views, perfect centres plus ``numpy.random.default_rng(seed).normal(0, sigma)``
  per view in order, then circcal's solver (:func:`circcal.solver.calibrate`), kornia as one batch
  (:mod:`circcal.study.batched`), or any other calibrator's ``calibrate_observations``.

A calibrator failing on its input is a row (status "failed"/"unsupported" with the message); an exception no input
should cause propagates (the task fails, Dask reports it, its runs stay missing and a rerun retries them).
"""

from __future__ import annotations

import json
import time
from functools import cache
from typing import Any

import numpy as np

from circcal.errors import InputError
from circcal.study.batched import KORNIA, solve_batch
from circcal.study.lens import DEFAULT_LENS_MODEL
from circcal.study.plan import Run, Task, geometry_identity
from circcal.study.rows import make_row
from circcal.study.spec import CIRCCAL, CalibratorSpec, CellSpec

__all__ = ["calibrator_for", "execute"]


@cache
def calibrator_for(spec: CalibratorSpec) -> Any:
    """The reference calibrator of a calibrator spec, made once per worker process.

    Parameters
    ----------
    spec : CalibratorSpec

    Returns
    -------
    ReferenceCalibrator
        A registry reference (set up for its lens), or a user's calibrator through
        :func:`circcal.validators.user_calibrator.load_calibrator`.
    """
    if spec.plugin is not None:
        from circcal.validators.user_calibrator import load_calibrator

        return load_calibrator(spec.plugin)
    from circcal.validators import registry

    return registry.get(spec.name)


def execute(task: Task) -> list[dict[str, Any]]:
    """The rows of a task's runs.

    Parameters
    ----------
    task : circcal.study.plan.Task

    Returns
    -------
    list of dict
        One row (:func:`circcal.study.rows.make_row`) per run, in the task's order.
    """
    if not task.runs:
        return []
    return _images(task) if task.cell.kind == "images" else _observations(task)


def _unsupported_lens(run: Run) -> str | None:
    """Why ``run``'s lens model cannot be fitted (None: it can). Every calibrator fits OpenCV's 5 coefficients."""
    if run.lens_model == DEFAULT_LENS_MODEL:
        return None
    return f"no calibrator fits lens model {run.lens_model!r} yet"


def _reference_row(run: Run, study: str, res: Any, truth: Any, **kw: Any) -> dict[str, Any]:
    ok = res.status == "ok"
    n_points = int(sum(len(p) for p in res.image_points)) if ok and res.image_points is not None else -1
    n_views = len(res.image_points) if ok and res.image_points is not None else -1
    return make_row(
        run,
        study,
        status=res.status,
        message=res.message or "",
        truth=truth,
        camera=res.camera if ok else None,
        std=res.std if ok else None,
        errors=res.errors if ok else None,
        n_views=n_views,
        n_points=n_points,
        time_s=float(res.time_s),
        device=str(res.extra.get("device", "")),
        batch_size=int(res.extra.get("batch_size", 1)),
        calibrator_version=str(res.version),
        **kw,
    )


# ----------------------------------------------------------------------------------------------------------------
# images: the full pipeline on a seeded render
# ----------------------------------------------------------------------------------------------------------------


def _images(task: Task) -> list[dict[str, Any]]:
    import circcal
    from circcal.fixtures.truth import load_truth
    from circcal.study.seeded import rendered, seeded_scenario

    cell = task.cell
    seed = task.runs[0].seed
    variants = [v for v in cell.variants if any(r.variant == v for r in task.runs)]
    sc = seeded_scenario(cell.scenario, seed, cell.vary)
    rows: dict[str, dict[str, Any]] = {}
    t0 = time.perf_counter()
    with rendered(sc, variants, cache=task.cache) as dirs:
        fixture_s = (time.perf_counter() - t0) / len(variants)  # one render of every variant, geometry shared
        for variant in variants:
            truth = load_truth(dirs[variant])
            runs = [r for r in task.runs if r.variant == variant]
            own = _CirccalImages(truth)
            for run in runs:
                kw = {"images_total": len(own.paths), "fixture_s": fixture_s}
                why = _unsupported_lens(run)
                if why is not None:
                    rows[run.key] = make_row(
                        run, task.study, status="unsupported", message=why, truth=truth.camera, **kw
                    )
                elif run.calibrator.name == CIRCCAL:
                    rows[run.key] = own.row(run, task.study, circcal.__version__, **kw)
                elif run.calibrator.observations == "circcal":
                    rows[run.key] = own.reference_on_centres(run, task.study, calibrator_for(run.calibrator), **kw)
                else:
                    ref = calibrator_for(run.calibrator)
                    res = ref.calibrate_images(own.paths, truth.board, own.size, mode=run.calibrator.mode)
                    used = len(res.views) if res.status == "ok" and res.views is not None else -1
                    rows[run.key] = _reference_row(run, task.study, res, truth.camera, images_used=used, **kw)
    return [rows[r.key] for r in task.runs]


class _CirccalImages:
    """circcal's pipeline on one fixture folder, run at most once and shared by the runs that need it."""

    def __init__(self, truth: Any) -> None:
        self.truth = truth
        self.paths = [str(v.image) for v in truth.views]
        self.size = (truth.camera.width, truth.camera.height)
        self._done = False
        self.cal: Any = None
        self.error = ""
        self.time_s = float("nan")
        self._shared: Any = None

    def _run(self) -> None:
        from circcal.pipeline import calibrate_images

        if self._done:
            return
        self._done = True
        t0 = time.perf_counter()
        try:
            self.cal = calibrate_images(self.paths, self.truth.board, progress=False, image_size=self.size, jobs=1)
        except InputError as exc:  # what the images can cause (too few found, degenerate views)
            self.error = f"{type(exc).__name__}: {exc}".splitlines()[0]
        self.time_s = time.perf_counter() - t0

    def row(self, run: Run, study: str, version: str, **kw: Any) -> dict[str, Any]:
        self._run()
        if self.cal is None:
            return make_row(
                run,
                study,
                status="failed",
                message=self.error,
                truth=self.truth.camera,
                time_s=self.time_s,
                calibrator_version=version,
                **kw,
            )
        res = self.cal.result
        n_points = int(sum(int(np.all(np.isfinite(c), axis=1).sum()) for c in self.cal.centres))
        return make_row(
            run,
            study,
            status="ok",
            truth=self.truth.camera,
            camera=res.camera,
            std=res.std,
            errors=res.errors,
            n_views=len(self.cal.used),
            n_points=n_points,
            images_used=len(self.cal.used),
            time_s=self.time_s,
            calibrator_version=version,
            **kw,
        )

    def reference_on_centres(self, run: Run, study: str, ref: Any, **kw: Any) -> dict[str, Any]:
        from circcal.validators.shared import share

        self._run()
        if self.cal is None:
            return make_row(
                run,
                study,
                status="failed",
                truth=self.truth.camera,
                calibrator_version=ref.version,
                message=f"no observations: circcal did not calibrate ({self.error})",
                **kw,
            )
        if self._shared is None:
            self._shared = share(self.cal, self.truth.board)
        s = self._shared
        res = ref.calibrate_observations(s.object_points, s.image_points, s.image_size, mode=run.calibrator.mode)
        return _reference_row(run, study, res, self.truth.camera, images_used=len(self.cal.used), **kw)


# ----------------------------------------------------------------------------------------------------------------
# observations: fixed views, perfect centres plus Gaussian noise
# ----------------------------------------------------------------------------------------------------------------

#: geometry identity (JSON) -> (camera, object points per view, perfect centres per view): each worker computes a
#: cell's views once (a cell holds dicts, so it cannot be an lru_cache key itself).
_VIEWS: dict[str, tuple[Any, list[np.ndarray], list[np.ndarray]]] = {}


def _views(cell: CellSpec) -> tuple[Any, list[np.ndarray], list[np.ndarray]]:
    """(camera, object points per view, perfect centres per view) of an observations cell: every board point that
    projects inside the image (pixel centres 0..W-1, 0..H-1)."""
    from circcal.board import Board
    from circcal.fixtures.poses import sample_poses
    from circcal.fixtures.scenarios import get_scenario
    from circcal.model import Camera, project

    if cell.geometry is not None:
        g = cell.geometry
        cam, board = Camera.from_dict(g.camera), Board.from_dict(g.board)
        poses = sample_poses(cam, board, g.views, g.pose_seed, max_tilt_deg=g.max_tilt_deg, min_tilt_deg=g.min_tilt_deg)
    else:
        sc = get_scenario(cell.scenario)
        cam, board, poses = sc.camera, sc.board, sc.poses()
    obj = board.object_points()
    objs, ideal = [], []
    for r, t in poses:  # a point the camera does not see is not observed (views partly out of frame)
        q = project(obj, r, t, cam)
        seen = (q[:, 0] >= 0) & (q[:, 0] <= cam.width - 1) & (q[:, 1] >= 0) & (q[:, 1] <= cam.height - 1)
        objs.append(obj[seen])
        ideal.append(q[seen])
    return cam, objs, ideal


def _observations(task: Task) -> list[dict[str, Any]]:
    import circcal
    from circcal.solver import calibrate

    cell = task.cell
    ident = json.dumps(geometry_identity(cell), sort_keys=True)
    if ident not in _VIEWS:
        _VIEWS[ident] = _views(cell)
    cam, obj, ideal = _VIEWS[ident]
    size = (cam.width, cam.height)
    cal = task.runs[0].calibrator
    sigma = task.runs[0].noise_px
    draws = []
    for run in task.runs:
        rng = np.random.default_rng(run.seed)
        draws.append([p + rng.normal(0.0, sigma, p.shape) for p in ideal])
    n_points = int(sum(len(o) for o in obj))
    kw = {"truth": cam, "n_views": len(obj), "n_points": n_points}
    rows = []
    why = _unsupported_lens(task.runs[0])
    if why is not None:
        return [make_row(r, task.study, status="unsupported", message=why, truth=cam) for r in task.runs]
    if cal.name == CIRCCAL:
        for run, img in zip(task.runs, draws):
            t0 = time.perf_counter()
            try:
                res = calibrate(obj, img, size)
            except InputError as exc:
                rows.append(
                    make_row(
                        run,
                        task.study,
                        status="failed",
                        message=f"{type(exc).__name__}: {exc}",
                        time_s=time.perf_counter() - t0,
                        calibrator_version=circcal.__version__,
                        truth=cam,
                    )
                )
                continue
            dt = time.perf_counter() - t0
            rows.append(
                make_row(
                    run,
                    task.study,
                    status="ok",
                    camera=res.camera,
                    std=res.std,
                    errors=res.errors,
                    time_s=dt,
                    calibrator_version=circcal.__version__,
                    **kw,
                )
            )
        return rows
    if cal.name == KORNIA and cal.plugin is None:
        results = solve_batch(obj, draws, size, device=cell.device, mode=cal.mode)
    else:
        ref = calibrator_for(cal)
        results = [ref.calibrate_observations(obj, img, size, mode=cal.mode) for img in draws]
    return [_reference_row(run, task.study, res, cam) for run, res in zip(task.runs, results)]
