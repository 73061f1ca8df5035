"""The paper's Table 7 on rendered fixtures: one illumination condition of the ``paper`` scenario, circcal and every
reference calibrator on circcal's centres (:func:`circcal.validators.validate.run_validation`), and the OpenCV circle
pipeline (findCirclesGrid with its own blob detector, then calibrateCamera) on the same images."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from circcal.metrics import error_stats
from circcal.report.config import ReportConfig
from circcal.report.rendered import calibrator_row, load_fixture

__all__ = ["paper_condition"]


def _circcal_row(run: Any, views: list[Any], paths: list[str]) -> dict[str, Any]:
    """circcal's row: its model and errors from the run, per-view errors and centre errors on the float32-shared
    observations every reference fitted (``run.shared``: <= 6e-5 px from circcal's own centres)."""
    from circcal.analysis.compare import centre_errors

    cc, truth = run.circcal, run.truth
    if cc["status"] != "ok" or run.shared is None:
        return calibrator_row(
            "circcal",
            cc["status"],
            cc.get("message") or "no shared observations",
            None,
            None,
            None,
            truth,
            detector="circcal",
            observations="own",
        )
    failed = {r.path for r in cc.get("failed") or []}
    used = [i for i, p in enumerate(paths) if p not in failed]
    shared = run.shared
    centre = centre_errors(shared.image_points, [views[i].centres for i in used], board=run.board)
    return calibrator_row(
        "circcal",
        "ok",
        "",
        cc["camera"],
        cc["std"],
        cc["errors"],
        truth,
        centre=centre["overall"],
        per_view=[e["mean_2d_px"] for e in shared.result.per_view_errors],
        views=used,
        detector="circcal",
        observations="own",
        centre_note="circcal's final centres",
    )


def _opencv_pipeline_row(paths: list[str], views: list[Any], run: Any) -> tuple[dict[str, Any], float]:
    """The OpenCV circle pipeline on the images; returns (row, seconds)."""
    from circcal.analysis.compare import centre_errors
    from circcal.validators.opencv import OpenCVCalibrator

    t0 = time.perf_counter()
    ocv = OpenCVCalibrator().calibrate_images(paths, run.board, run.image_size)
    seconds = time.perf_counter() - t0
    label = f"OpenCV {ocv.version} circle pipeline"
    if not ocv.ok:
        return calibrator_row(
            label, ocv.status, ocv.message, None, None, None, run.truth, detector="findCirclesGrid", observations="own"
        ), seconds
    centre = centre_errors(ocv.image_points, [views[i].centres for i in ocv.views], board=run.board)
    return calibrator_row(
        label,
        "ok",
        ocv.message,
        ocv.camera,
        ocv.std,
        ocv.errors,
        run.truth,
        centre=centre["overall"],
        per_view=[error_stats(r)["mean_2d_px"] for r in ocv.residuals],
        views=list(ocv.views),
        detector="findCirclesGrid (SimpleBlobDetector)",
        observations="own",
        centre_note="blob centroids",
    ), seconds


def paper_condition(variant: str, cfg: ReportConfig, *, progress: bool = True) -> tuple[dict[str, Any], dict]:
    """One illumination condition of the ``paper`` scenario.

    Parameters
    ----------
    variant : str
        The condition.
    cfg : ReportConfig
    progress : bool

    Returns
    -------
    numbers : dict
        Every calibrator's row.
    timings : dict
        Run times, s, per calibrator.
    """
    from circcal.validators.validate import run_validation

    truth, views = load_fixture("paper", variant, cfg.n_views, progress)
    paths = [str(v.image) for v in views]
    run = run_validation(
        paths,
        truth.board,
        truth=truth.camera,
        against=cfg.references,
        mode="both",
        progress=progress,
        source={"scenario": "paper", "variant": variant},
    )
    timings: dict[str, float] = {"circcal": run.circcal["time_s"]}
    rows: dict[str, dict] = {"circcal": _circcal_row(run, views, paths)}
    rows["opencv-pipeline"], timings["opencv-pipeline"] = _opencv_pipeline_row(paths, views, run)
    for r in run.references:
        key = f"{r.name}-{r.mode}"
        timings[key] = r.time_s
        rows[key] = calibrator_row(
            f"{r.name} {r.version} [{r.mode}]",
            r.status,
            r.message,
            r.camera,
            r.std,
            r.errors,
            truth.camera,
            detector="circcal",
            observations="circcal's centres",
            centre=rows["circcal"]["centre_error"] if r.ok else None,
            centre_note="circcal's centres (same observations)",
        )
    checks = [
        {"name": c.name, "value": c.value, "bound": c.bound, "passed": c.passed, "note": c.note} for c in run.checks
    ]
    failed = [[Path(r.path).name, r.reason] for r in run.circcal.get("failed") or []]
    return {
        "n_views": len(paths),
        "rows": rows,
        "checks": checks,
        "validation_passed": run.passed,
        "failed_images": failed,
    }, timings
