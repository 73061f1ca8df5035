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
    """The truth of a fixture (rendered on demand into the fixture cache) and its first views.

    Parameters
    ----------
    scenario, variant : str
        The fixture.
    n_views : int or None
        How many views; None: all.
    progress : bool
        Show rendering progress.

    Returns
    -------
    truth : circcal.fixtures.truth.Truth
    views : list of circcal.fixtures.truth.View

    Raises
    ------
    circcal.errors.InputError
        An unknown scenario or variant.
    """
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth

    truth = load_truth(fixture_dir(scenario, variant, progress=progress))
    views = truth.views if n_views is None else truth.views[:n_views]
    return truth, list(views)


def vs_truth(truth: Camera, camera: Camera | None) -> dict[str, float] | None:
    """The projection difference of a camera to the true one, rotation fitted and not.

    Parameters
    ----------
    truth : circcal.model.Camera
    camera : circcal.model.Camera or None

    Returns
    -------
    dict of str to float or None
        ``rms_px``, ``max_px`` (rotation fitted), ``nofit_rms_px``, ``nofit_max_px``, px; None for no camera.
    """
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
    """One calibrator on one condition, as a row of the condition table.

    Parameters
    ----------
    label : str
        The calibrator as the table names it.
    status, message : str
        Its status and why.
    camera : circcal.model.Camera or None
        Its model.
    std : dict or None
        Its stated standard deviations by parameter name.
    errors : dict or None
        Reprojection errors (three conventions), px.
    truth : circcal.model.Camera
        The true camera (for the error vs truth).
    centre : dict, optional
        Detector centre error against the true projections, px.
    centre_note : str
        How the centres were matched.
    per_view : list, optional
        Per-view mean 2-D error, px.
    views : list, optional
        Indices of the views used.
    detector, observations : str
        Which detector and whose centres.

    Returns
    -------
    dict
    """
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
    """The geometry of a scenario as the report states it.

    Parameters
    ----------
    scenario : str
        A scenario name.

    Returns
    -------
    dict
        Its true camera, its board and how many views it renders.
    """
    from circcal.fixtures.scenarios import get_scenario

    sc = get_scenario(scenario)
    return {"camera": sc.camera, "board": sc.board, "n_views": sc.n_views}
