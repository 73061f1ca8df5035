"""circcal's observations of one scenario-variant (:func:`observe`, the expensive part of the conformance suite, once
per scenario-variant), which every reference case of it then fits, and circcal's solve on a subset of them
(:func:`solve_subset`: for a reference that leaves observations out).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from circcal.analysis.compare import match_grid_order
from circcal.board import Board
from circcal.detector import Rejection
from circcal.errors import InputError
from circcal.model import Camera
from circcal.validators.reference_result import ReferenceResult
from circcal.validators.shared import share, ssr

__all__ = ["Observations", "observe", "solve_subset"]


@dataclass
class Observations:
    """circcal's calibration of one scenario-variant and the observations every reference case reuses.

    Picklable (a cache may share it between test workers).

    Attributes
    ----------
    scenario, variant, folder : str
        The fixture and its folder.
    truth : circcal.model.Camera
        The true camera.
    board : circcal.board.Board
        The fixture's board.
    paths : list of str
        Its images.
    lens : str
        The lens model fitted.
    status : str
        "ok" or "failed" (``message`` then holds circcal's error).
    camera, std, correlation, errors
        circcal's calibration: camera, standard deviations by name, (P, P) correlation, error statistics (px).
    used : list of int
        Indices of the images used.
    failed : list of circcal.detector.Rejection
        The rejections themselves (path, code, words).
    accounted : dict of str to str
        Path -> "used" or the reason code (:class:`circcal.detector.Reason` value) it was rejected with, for every
        image that circcal accounted for.
    object_points, image_points : list of ndarray or None
        Per used view (N_v, 3) mm / (N_v, 2) px, circcal's final centres rounded to float32 (OpenCV's input type) and
        back.
    solver_camera, solver_std, solver_ssr
        circcal's solver on exactly those points (what references are compared with); SSR in px^2.
    centre_errors : ndarray, shape (N,), or None
        px, |final centre - true projection| over all used points, grid order matched to the truth.
    time_s : float
        circcal's calibration time, s.
    ok : bool
        ``status == "ok"``.
    image_size : tuple of int
        (width, height) px of the true camera.
    """

    scenario: str
    variant: str
    folder: str
    truth: Camera
    board: Board
    paths: list[str]
    lens: str = "opencv5"
    status: str = "ok"
    message: str = ""
    camera: Camera | None = None
    std: dict[str, float] | None = None
    correlation: np.ndarray | None = None
    errors: dict[str, float] | None = None
    used: list[int] = field(default_factory=list)
    failed: list[Rejection] = field(default_factory=list)
    accounted: dict[str, str] = field(default_factory=dict)
    object_points: list[np.ndarray] | None = None
    image_points: list[np.ndarray] | None = None
    solver_camera: Camera | None = None
    solver_std: dict[str, float] | None = None
    solver_ssr: float = float("nan")
    centre_errors: np.ndarray | None = None
    time_s: float = 0.0

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def image_size(self) -> tuple[int, int]:
        return (self.truth.width, self.truth.height)


def _matched_centre_errors(centres: Sequence[np.ndarray], truth: Sequence[np.ndarray], board: Board) -> np.ndarray:
    """|detected - true| (px) over all finite points; each view's labelling is matched to the truth over the
    board's symmetries (a square grid may come back rotated: a valid labelling, not an error)."""
    errs = []
    for c, t in zip(centres, truth):
        c, _, _ = match_grid_order(c, t, board)
        d = np.linalg.norm(c - np.asarray(t, dtype=np.float64).reshape(-1, 2), axis=1)
        errs.append(d[np.isfinite(d)])
    return np.concatenate(errs) if errs else np.zeros(0)


def observe(scenario: str, variant: str, lens: str | None = None, *, progress: bool = False) -> Observations:
    """Render (or fetch) a fixture and run circcal's :func:`~circcal.pipeline.calibrate_images` on it.

    Never raises for circcal's own failure (an ``InputError``: status "failed" with the message, and the rejections
    when too few images were usable); fixture problems do raise.

    Parameters
    ----------
    scenario, variant : str
        The fixture (:data:`circcal.fixtures.scenarios.SCENARIOS`).
    lens : str, optional
        The lens model fitted; default the true camera's.
    progress : bool
        Show progress while rendering and calibrating.

    Returns
    -------
    Observations

    Examples
    --------
    >>> obs = observe("paper", "normal")  # doctest: +SKIP
    >>> obs.ok, len(obs.object_points)  # doctest: +SKIP
    """
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth
    from circcal.pipeline import TooFewImagesError, calibrate_images
    from circcal.solver import CalibrationOptions

    folder = fixture_dir(scenario, variant, progress=progress)
    truth = load_truth(folder)
    paths = [str(v.image) for v in truth.views]
    lens = truth.camera.lens if lens is None else lens
    obs = Observations(scenario, variant, str(folder), truth.camera, truth.board, paths, lens)
    t0 = time.perf_counter()
    try:
        cal = calibrate_images(
            paths, truth.board, CalibrationOptions(lens=lens), progress=progress, image_size=obs.image_size
        )
    except InputError as exc:
        obs.status, obs.message = "failed", f"{type(exc).__name__}: {exc}"
        if isinstance(exc, TooFewImagesError):
            obs.failed = exc.rejected
            obs.accounted = {r.path: r.code.value for r in exc.rejected}
        obs.time_s = time.perf_counter() - t0
        return obs
    res = cal.result
    obs.camera, obs.std, obs.errors = res.camera, dict(res.std), dict(res.errors)
    obs.correlation = np.asarray(res.correlation, dtype=np.float64)
    obs.used, obs.failed = list(cal.used), list(cal.failed)
    for i in cal.used:
        obs.accounted[paths[i]] = "used"
    for r in obs.failed:
        obs.accounted.setdefault(r.path, r.code.value)
    obs.centre_errors = _matched_centre_errors(cal.centres, [truth.views[i].centres for i in cal.used], truth.board)
    shared = share(cal, truth.board)
    obs.object_points, obs.image_points = shared.object_points, shared.image_points
    obs.solver_camera, obs.solver_std, obs.solver_ssr = shared.result.camera, dict(shared.result.std), shared.ssr
    obs.time_s = time.perf_counter() - t0
    return obs


def solve_subset(
    obs: Observations, res: ReferenceResult, left_out: dict[int, list[int]]
) -> tuple[Camera, float, ReferenceResult]:
    """circcal's solver on the shared observations less the points a reference left out.

    Started from circcal's solve on all of them, so that the agreement check compares the two solves of one problem.

    Parameters
    ----------
    obs : Observations
        An ok observation set.
    res : ReferenceResult
        The reference's result.
    left_out : dict
        View (int or its str) -> indices of the points the reference left out.

    Returns
    -------
    camera : circcal.model.Camera
        circcal's solve on the subset.
    ssr : float
        Its sum of squared residuals, px^2.
    fitted : ReferenceResult
        ``res`` with only the fitted points' residuals.
    """
    from circcal.solver import calibrate

    keep = []
    for v, o in enumerate(obs.object_points):
        m = np.ones(len(o), bool)
        m[list(left_out.get(v, left_out.get(str(v), [])))] = False
        keep.append(m)
    sub = calibrate(
        [o[m] for o, m in zip(obs.object_points, keep)],
        [q[m] for q, m in zip(obs.image_points, keep)],
        obs.image_size,
        initial=obs.solver_camera,
    )
    fitted = replace(res, residuals=None if res.residuals is None else [r[m] for r, m in zip(res.residuals, keep)])
    return sub.camera, ssr(sub.residuals), fitted
