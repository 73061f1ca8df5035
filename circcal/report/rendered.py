"""What the studies on rendered fixtures share: a fixture's first views, a calibrated camera's error against the true
one, and one calibrator's row of a condition table.

"vs truth" is the projection difference between the true and the calibrated camera over a
:data:`~circcal.report.config.PROJECTION_GRID_WIDTH`-wide pixel grid of the image: ``rms_px`` / ``max_px`` with
the implied rotation fitted (:func:`circcal.analysis.compare.projection_diff`), ``nofit_*`` without.
"""

from __future__ import annotations

from typing import Any

from circcal.model import Camera
from circcal.report.config import PROJECTION_GRID_WIDTH
from circcal.report.results import error_summary

__all__ = ["calibrator_row", "fixture_summary", "load_fixture", "vs_truth"]


def load_fixture(scenario: str, variant: str, n_views: int | None, progress: bool) -> tuple[Any, list[Any]]:
    """The truth of ``scenario``/``variant`` (rendered on demand into the fixture cache) and its first ``n_views``
    views (all for None)."""
    from circcal.fixtures.scenarios import fixture_dir, load_truth

    truth = load_truth(fixture_dir(scenario, variant, progress=progress))
    views = truth.views if n_views is None else truth.views[:n_views]
    return truth, list(views)


def vs_truth(truth: Camera, camera: Camera | None) -> dict[str, float] | None:
    """RMS and max projection difference (px) of ``camera`` to ``truth``, rotation fitted and not (None for no
    camera)."""
    from circcal.analysis.compare import projection_diff

    if camera is None:
        return None
    fit = projection_diff(truth, camera, gridn_width=PROJECTION_GRID_WIDTH, fit=True)
    raw = projection_diff(truth, camera, gridn_width=PROJECTION_GRID_WIDTH, fit=False)
    return {
        "rms_px": fit["rms_px"],
        "max_px": fit["max_px"],
        "nofit_rms_px": raw["rms_px"],
        "nofit_max_px": raw["max_px"],
    }


def calibrator_row(
    label: str,
    status: str,
    message: str,
    camera: Camera | None,
    std: dict | None,
    errors: dict | None,
    truth: Camera,
    *,
    centre: dict | None = None,
    centre_note: str = "",
    per_view: list | None = None,
    views: list | None = None,
    detector: str = "",
    observations: str = "",
) -> dict[str, Any]:
    """One calibrator on one condition: its model and stated sigmas, reprojection errors (three conventions),
    error vs truth, detector centre error against the true projections, per-view mean 2-D error (px) with the
    indices of the views used."""
    return {
        "label": label,
        "status": status,
        "message": message,
        "detector": detector,
        "observations": observations,
        "camera": camera,
        "std": std,
        "errors": error_summary(errors),
        "vs_truth": vs_truth(truth, camera) if status == "ok" else None,
        "centre_error": error_summary(centre),
        "centre_note": centre_note,
        "per_view_mean_2d_px": per_view,
        "views": views,
    }


def fixture_summary(scenario: str) -> dict[str, Any]:
    """The geometry of a scenario as the report states it: its true camera, its board and how many views it
    renders."""
    from circcal.fixtures.scenarios import get_scenario

    sc = get_scenario(scenario)
    return {"camera": sc.camera, "board": sc.board, "n_views": sc.n_views}
