"""What a calibration returns: :class:`CalibrationResult`, the camera with its uncertainty, poses, residuals and
fit statistics, and its sections of model.json."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from circcal.formats import model_json
from circcal.model import Camera
from circcal.solver.covariance import StateCovariance

if TYPE_CHECKING:  # annotations only (outliers refers to this module the same way)
    from circcal.solver.outliers import Rejections

__all__ = ["CalibrationResult"]


@dataclass
class CalibrationResult:
    """A calibrated camera with its uncertainty and fit statistics.

    ``std``: standard deviation of each of the camera's parameters (``camera.model.param_names``: fx, fy, cx, cy in
    px, then the distortion coefficients, unitless) from ``sigma_px^2 (J^T J)^-1`` with the poses marginalised; 0.0
    for a parameter held fixed (listed in ``fixed``); with a fixed aspect ratio fx = a * fy, fx's std is a * std(fy).
    ``correlation``: (4 + n_dist, 4 + n_dist), NaN in the rows and columns of
    fixed parameters. ``rvecs``/``tvecs``: (V, 3) board -> camera (radians / mm). ``residuals``: per view (N_v, 2)
    px, observed - projected. ``errors``: :func:`circcal.metrics.error_stats` over all points (keys name the
    convention: rms_per_point_px = OpenCV's RMS, rms_per_coord_px = mrcal's, mean_2d_px = the paper's eq. 22);
    ``per_view_errors`` the same per view. ``sigma_px``: per-coordinate noise estimate sqrt(SSR / (2N - n_params)).
    ``fixed``: names of parameters held at their initial value, plus ``"aspect_ratio"`` when fx/fy was held.
    ``view_names``: optional label per view (image file names when calibrating images). With board refinement
    (``calibrate(refine_board=True)``): ``board_nominal`` (P, 3) mm the distinct board points in order of first
    appearance, ``board_points`` (P, 3) mm their estimated positions, ``board_std`` (P, 3) mm standard deviations (0
    for held coordinates), ``board_gauge`` the three points that fix the board frame; all None otherwise.
    ``covariance``: the first-order covariance of the whole state (intrinsics, board coordinates, every pose;
    :class:`circcal.solver.covariance.StateCovariance`), None when the information matrix is singular: projection
    uncertainty (:mod:`circcal.solver.uncertainty`) needs it. ``object_points`` / ``image_points``: per view (N_v, 3)
    mm / (N_v, 2) px, the observations the model was fitted to (after any outlier rejection). ``outliers``: what
    outlier rejection left out (:class:`circcal.solver.outliers.Rejections`), None when it did not run.
    """

    camera: Camera
    std: dict[str, float]
    correlation: np.ndarray
    rvecs: np.ndarray
    tvecs: np.ndarray
    residuals: list[np.ndarray]
    errors: dict[str, float]
    per_view_errors: list[dict[str, float]]
    sigma_px: float
    n_iterations: int
    converged: bool
    fixed: tuple[str, ...]
    view_names: list[str] | None = None
    n_params: int = 0
    board_nominal: np.ndarray | None = None
    board_points: np.ndarray | None = None
    board_std: np.ndarray | None = None
    board_gauge: tuple[int, int, int] | None = None
    covariance: StateCovariance | None = None
    object_points: list[np.ndarray] | None = None
    image_points: list[np.ndarray] | None = None
    outliers: Rejections | None = None

    def board_lookup(self, object_points: np.ndarray) -> np.ndarray:
        """Nominal board points (N, 3) mm -> the refined ones (N, 3) mm (unchanged without board refinement).
        Raises ``ValueError`` for a point the calibration never saw."""
        o = np.asarray(object_points, dtype=np.float64).reshape(-1, 3)
        if self.board_points is None or self.board_nominal is None:  # set together, by board refinement
            return o.copy()
        index = {tuple(k): i for i, k in enumerate(np.round(self.board_nominal, 6).tolist())}
        try:
            rows = [index[tuple(k)] for k in np.round(o, 6).tolist()]
        except KeyError as e:
            raise ValueError(f"board point {e.args[0]} was not part of the calibration") from None
        return self.board_points[rows]

    def model_sections(self) -> dict[str, Any]:
        """This result's sections of model.json (:func:`circcal.formats.model_json`): ``std``, ``fixed``,
        ``parameter_order``, ``correlation`` (NaN -> null), ``errors`` (overall, convention in each key), ``sigma_px``,
        solver facts, one entry per view (name, pose, errors, the observations it contributed and the points outlier
        rejection left out of it) and, with board refinement, the refined board."""
        views = []
        for i in range(len(self.rvecs)):
            entry: dict[str, Any] = {}
            if self.view_names is not None:
                entry["name"] = self.view_names[i]
            entry["rvec"] = [float(v) for v in self.rvecs[i]]
            entry["tvec_mm"] = [float(v) for v in self.tvecs[i]]
            entry["errors"] = dict(self.per_view_errors[i])
            if self.object_points is not None and self.image_points is not None:
                # the observations this view contributed: what mrcal's optimisation inputs, a later uncertainty or
                # a re-solve need (board points nominal, mm; pixels OpenCV's)
                entry["object_mm"] = np.asarray(self.object_points[i], dtype=np.float64).tolist()
                entry["image_px"] = np.asarray(self.image_points[i], dtype=np.float64).tolist()
            if self.outliers is not None:
                entry["outliers"] = self.outliers.view_entries(i)
            views.append(entry)
        return {
            "std": {k: float(v) for k, v in self.std.items()},
            "fixed": list(self.fixed),
            "parameter_order": list(self.camera.model.param_names),
            "correlation": self.correlation,
            "errors": dict(self.errors),
            "sigma_px": float(self.sigma_px),
            "n_params": int(self.n_params),
            "n_iterations": int(self.n_iterations),
            "converged": bool(self.converged),
            "views": views,
            **self._board_section(),
        }

    def _board_section(self) -> dict[str, Any]:
        """``{"board_refinement": ...}`` of :meth:`model_sections` with board refinement, else empty."""
        if self.board_points is None:
            return {}
        if self.board_nominal is None or self.board_std is None or self.board_gauge is None:
            raise ValueError("board_points is set without board_nominal, board_std and board_gauge")
        return {
            "board_refinement": {
                "gauge": [int(i) for i in self.board_gauge],
                "nominal_mm": np.round(self.board_nominal, 9).tolist(),
                "points_mm": self.board_points.tolist(),
                "std_mm": self.board_std.tolist(),
            }
        }

    def to_model_json(self) -> dict[str, Any]:
        """model.json content (:func:`circcal.formats.model_json`) of this result alone."""
        return model_json(self.camera, **self.model_sections())
