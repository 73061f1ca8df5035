"""What a calibration returns: :class:`CalibrationResult`, the camera with its uncertainty, poses, residuals and
fit statistics, and its sections of model.json."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from circcal.formats import model_json
from circcal.model import Camera
from circcal.solver.boardpoints import warp_basis
from circcal.solver.covariance import StateCovariance

if TYPE_CHECKING:  # annotations only (outliers refers to this module the same way)
    from circcal.solver.outliers import Rejections

__all__ = ["CalibrationResult"]


@dataclass
class CalibrationResult:
    """A calibrated camera with its uncertainty and fit statistics.

    Attributes
    ----------
    camera : Camera
    std : dict of str to float
        Standard deviation of each of the camera's parameters (``camera.model.param_names``: fx, fy, cx, cy in px,
        then the distortion coefficients, unitless) from ``sigma_px^2 (J^T J)^-1`` with the poses marginalised; 0.0
        for a parameter held fixed (listed in ``fixed``); with a fixed aspect ratio fx = a * fy, fx's std is
        a * std(fy).
    correlation : ndarray, shape (4 + n_dist, 4 + n_dist)
        NaN in the rows and columns of fixed parameters.
    rvecs, tvecs : ndarray, shape (V, 3)
        Board -> camera (radians / mm).
    residuals : list of ndarray, each shape (N_v, 2)
        Per view, px, observed - projected.
    errors : dict of str to float
        :func:`circcal.metrics.error_stats` over all points (keys name the convention: rms_per_point_px = OpenCV's
        RMS, rms_per_coord_px = mrcal's, mean_2d_px = the paper's eq. 22).
    per_view_errors : list of dict
        The same per view.
    sigma_px : float
        Per-coordinate noise estimate sqrt(SSR / (2N - n_params)), px.
    n_iterations : int
    converged : bool
    fixed : tuple of str
        Names of parameters held at their initial value, plus ``"aspect_ratio"`` when fx/fy was held.
    view_names : list of str or None
        Optional label per view (image file names when calibrating images).
    n_params : int
    board_nominal : ndarray, shape (P, 3), or None
        With board refinement (``calibrate(refine_board=True)``): the distinct board points in order of first
        appearance, mm; None otherwise (as the next three).
    board_points : ndarray, shape (P, 3), or None
        Their estimated positions, mm.
    board_std : ndarray, shape (P, 3), or None
        Standard deviations, mm (0 for held coordinates).
    board_gauge : tuple of int or None
        The three points that fix the board frame.
    board_warp : ndarray, shape (2,), or None
        With ``CalibrationOptions(board_warp=True)``: mrcal's ``calobject_warp`` (w_x, w_y), mm: the board's sag at
        the centre of :attr:`board_warp_box` along its x and y axes (:func:`circcal.solver.problem.warp_basis`);
        None otherwise (as the next two).
    board_warp_cov : ndarray, shape (2, 2), or None
        Its covariance, mm^2 (``sigma_px^2 (J^T J)^-1``, poses marginalised).
    board_warp_box : tuple of float or None
        (x0, x1, y0, y1) mm: the rectangle the warp spans (the board points' bounding box).
    covariance : StateCovariance or None
        The first-order covariance of the whole state (intrinsics, board coordinates, every pose;
        :class:`circcal.solver.covariance.StateCovariance`), None when the information matrix is singular: projection
        uncertainty (:mod:`circcal.solver.uncertainty`) needs it.
    object_points, image_points : list of ndarray or None
        Per view (N_v, 3) mm / (N_v, 2) px, the observations the model was fitted to (after any outlier rejection).
    outliers : Rejections or None
        What outlier rejection left out (:class:`circcal.solver.outliers.Rejections`), None when it did not run.
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
    board_warp: np.ndarray | None = None
    board_warp_cov: np.ndarray | None = None
    board_warp_box: tuple[float, float, float, float] | None = None
    covariance: StateCovariance | None = None
    object_points: list[np.ndarray] | None = None
    image_points: list[np.ndarray] | None = None
    outliers: Rejections | None = None

    @property
    def board_warp_std(self) -> np.ndarray | None:
        """(2,) mm: the board warp's standard deviations (None without a warp)."""
        if self.board_warp_cov is None:
            return None
        return np.sqrt(np.maximum(np.diag(self.board_warp_cov), 0.0))

    def board_lookup(self, object_points: np.ndarray) -> np.ndarray:
        """Nominal board points -> the refined ones, or the warped ones (unchanged with neither).

        Parameters
        ----------
        object_points : ndarray, shape (N, 3)
            Nominal board points, mm.

        Returns
        -------
        ndarray, shape (N, 3)
            mm.

        Raises
        ------
        ValueError
            A point the calibration never saw (a caller's bug, not an input error).
        """
        o = np.asarray(object_points, dtype=np.float64).reshape(-1, 3)
        if self.board_warp is not None and self.board_warp_box is not None:
            out = o.copy()
            out[:, 2] += warp_basis(o, self.board_warp_box) @ self.board_warp
            return out
        if self.board_points is None or self.board_nominal is None:  # set together, by board refinement
            return o.copy()
        index = {tuple(k): i for i, k in enumerate(np.round(self.board_nominal, 6).tolist())}
        try:
            rows = [index[tuple(k)] for k in np.round(o, 6).tolist()]
        except KeyError as e:
            raise ValueError(f"board point {e.args[0]} was not part of the calibration") from None
        return self.board_points[rows]

    def model_sections(self) -> dict[str, Any]:
        """This result's sections of model.json (:func:`circcal.formats.model_json`).

        Returns
        -------
        dict
            ``std``, ``fixed``, ``parameter_order``, ``correlation`` (NaN -> null), ``errors`` (overall, convention in
            each key), ``sigma_px``, solver facts, one entry per view (name, pose, errors, the observations it
            contributed and the points outlier rejection left out of it) and, with board refinement, the refined board
            (with a board warp, the warp).
        """
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
        """``{"board_refinement": ...}`` of :meth:`model_sections` with board refinement, ``{"board_warp": ...}`` with
        a warp, else empty."""
        if self.board_warp is not None and self.board_warp_cov is not None and self.board_warp_box is not None:
            return {
                "board_warp": {
                    "warp_mm": [float(v) for v in self.board_warp],
                    "covariance_mm2": np.asarray(self.board_warp_cov, dtype=np.float64).tolist(),
                    "box_mm": [float(v) for v in self.board_warp_box],
                    "definition": "mrcal's calobject_warp in mm: z += w[0] 4 xr (1 - xr) + w[1] 4 yr (1 - yr), "
                    "xr = (x - x0) / (x1 - x0), yr = (y - y0) / (y1 - y0) over box_mm [x0, x1, y0, y1]",
                }
            }
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
        """model.json content (:func:`circcal.formats.model_json`) of this result alone.

        Returns
        -------
        dict

        Examples
        --------
        >>> text = circcal.jsonio.dumps(result.to_model_json())  # doctest: +SKIP
        """
        return model_json(self.camera, **self.model_sections())
