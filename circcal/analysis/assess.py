"""Everything that tells a user whether a calibration of their own photographs can be trusted, gathered for one
:class:`circcal.pipeline.ImagesCalibration`: the projection-uncertainty map (:mod:`circcal.solver.uncertainty`),
where the observations lie (:mod:`circcal.analysis.coverage`), what outlier rejection left out
(:mod:`circcal.solver.outliers`), whether the board is flat (:mod:`circcal.analysis.boardshape`) and, when asked, the cross-validation (:mod:`circcal.analysis.cross`). The
console summary and the calibration report (:mod:`circcal.calreport`) are drawn from it.

Errors name their convention (``rms_per_point_px`` OpenCV's, ``rms_per_coord_px`` mrcal's, ``mean_2d_px`` the
paper's); uncertainties are worst-direction standard deviations in px, at ``distance_mm`` along each pixel's ray
(None: at infinity, mrcal's default).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal.analysis.boardshape import BoardShape, board_shape
from circcal.analysis.compare import GRID_WIDTH, pixel_grid
from circcal.analysis.coverage import Coverage, coverage
from circcal.analysis.cross import CrossValidation, cross_validate_detections
from circcal.analysis.remedy import Remedy, remedy
from circcal.solver import CalibrationOptions
from circcal.solver.lensfield import result_pole
from circcal.solver.modelfit import ModelFit, model_fit
from circcal.solver.outliers import OutlierReason

__all__ = ["Assessment", "UncertaintyMap", "assess", "uncertainty_map"]


@dataclass
class UncertaintyMap:
    """A calibration's projection uncertainty over a grid of its image.

    Attributes
    ----------
    uv : ndarray, shape (H, W, 2)
        The grid, px.
    stdev : ndarray, shape (H, W)
        Worst-direction standard deviation, px.
    worst_px : float
        The largest, px.
    worst_uv : tuple of float
        Where, px.
    centre_px : float
        At the image centre, px.
    distance_mm : float or None
        None: infinity.
    sigma_px : float
        The per-coordinate noise it assumes, px.
    """

    uv: np.ndarray
    stdev: np.ndarray
    worst_px: float
    worst_uv: tuple[float, float]
    centre_px: float
    distance_mm: float | None
    sigma_px: float

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (the grid left out), with the definition in words.

        Returns
        -------
        dict
            ``worst_px``, ``worst_at_px``, ``centre_px``, ``distance_mm``, ``sigma_px``, ``grid_shape``, ``definition``.
        """
        return {
            "worst_px": self.worst_px,
            "worst_at_px": list(self.worst_uv),
            "centre_px": self.centre_px,
            "distance_mm": self.distance_mm,
            "sigma_px": self.sigma_px,
            "grid_shape": list(self.stdev.shape),
            "definition": "worst-direction standard deviation of the projection of a pixel's ray (at the "
            "distance, or at infinity) through the calibration objects' frames and back, first "
            "order, from the covariance of the intrinsics and every board pose (mrcal's "
            "projection_uncertainty)",
        }


def uncertainty_map(
    result: Any, *, distance: float | None = None, gridn_width: int = GRID_WIDTH
) -> UncertaintyMap | None:
    """The projection-uncertainty map of a :class:`~circcal.solver.CalibrationResult`.

    Parameters
    ----------
    result : CalibrationResult
    distance : float or None
        mm along each ray; None: infinity.
    gridn_width : int
        Grid points across the image.

    Returns
    -------
    UncertaintyMap or None
        None when the result has no finite covariance.
    """
    from circcal.solver.uncertainty import result_projection_stdev

    if result.covariance is None:
        return None
    cam = result.camera
    uv = pixel_grid(cam, gridn_width)
    ny = len(uv) // gridn_width
    s = result_projection_stdev(result, uv, distance=distance)
    k = int(np.nanargmax(s))
    c = float(
        result_projection_stdev(result, np.array([[(cam.width - 1) / 2, (cam.height - 1) / 2]]), distance=distance)[0]
    )
    return UncertaintyMap(
        uv.reshape(ny, gridn_width, 2),
        s.reshape(ny, gridn_width),
        float(s[k]),
        (float(uv[k, 0]), float(uv[k, 1])),
        c,
        distance,
        float(result.sigma_px),
    )


@dataclass
class Assessment:
    """Everything that says whether a calibration is right.

    Attributes
    ----------
    cal : ImagesCalibration
        The calibration.
    board : Board
    uncertainty : UncertaintyMap or None
    coverage : Coverage
    crossval : CrossValidation or None
        :class:`~circcal.analysis.cross.CrossValidation`; None: not asked.
    timings : dict of str to float
        s.
    lens_fit : ModelFit or None
        Whether the lens model fits (:mod:`circcal.solver.modelfit`; None: too few points to tell).
    remedy : Remedy or None
        What to do next (:mod:`circcal.analysis.remedy`): the candidate that makes the halves agree, or where more
        views are needed; None: nothing to remedy.
    board_shape : BoardShape or None
        Whether the board is flat, and which board model predicts held-out views better
        (:mod:`circcal.analysis.boardshape`); None: not checked.
    result : CalibrationResult
        ``cal.result`` (property).
    """

    cal: Any
    board: Any
    uncertainty: UncertaintyMap | None
    coverage: Coverage
    crossval: CrossValidation | None
    timings: dict[str, float] = field(default_factory=dict)
    lens_fit: ModelFit | None = None
    remedy: Remedy | None = None
    board_shape: BoardShape | None = None

    @property
    def result(self) -> Any:
        """The calibration's :class:`~circcal.solver.CalibrationResult` (``cal.result``)."""
        return self.cal.result

    def verdict(self) -> list[str]:
        """The verdict: the error in the three conventions, the cross-validation, the worst uncertainty, a rational
        lens with a pole, or nearly one, in the observed field (:func:`circcal.solver.lensfield.result_pole`) and, where the
        board-shape check (:attr:`board_shape`) finds something to say, the board's shape: a board that is not flat,
        a fitted warp that is not needed, a refined board's shift from the flat board's solution (a flat board is
        reported among the :meth:`details`).

        Returns
        -------
        list of str
        """
        e = self.result.errors
        v = len(self.result.rvecs)
        lines = [
            f"reprojection error over {e['n_points']} points of {v} views: RMS per point (OpenCV) "
            f"{e['rms_per_point_px']:.4f} px, RMS per coordinate (mrcal) {e['rms_per_coord_px']:.4f} px, "
            f"mean 2-D (paper eq. 22) {e['mean_2d_px']:.4f} px"
        ]
        cv = self.crossval
        if cv is None:
            lines.append(
                "cross-validation: not run (the command line runs it unless --no-cross-validate; in Python "
                "calibrate(..., cross_validate=True)): the views split in two and compared"
            )
        elif cv.status != "ok":
            lines.append(f"cross-validation: {cv.message}")
        else:
            if cv.verdict is None or cv.diff is None or cv.diff.share_within is None:
                raise ValueError("a cross-validation with status 'ok' carries its verdict and its diff's share")
            lines.append(
                f"cross-validation: {cv.verdict.replace('-', ' ')}"
                + (f", {len(cv.flagged_views)} view(s) disagree" if cv.flagged_views else "")
                + f" (halves within 2x their combined uncertainty over {100 * cv.diff.share_within:.1f}% of the "
                f"image)"
            )
        u = self.uncertainty
        at = "at infinity" if (u is None or u.distance_mm is None) else f"at {u.distance_mm:g} mm"
        lines.append(
            f"projection uncertainty {at}: worst {u.worst_px:.3g} px at ({u.worst_uv[0]:.0f}, "
            f"{u.worst_uv[1]:.0f}), centre {u.centre_px:.3g} px (1 sigma, worst direction)"
            if u is not None
            else "projection uncertainty: none (the information matrix is singular)"
        )
        pole = self.lens_pole()
        if pole:
            lines.append(f"lens model {self.result.camera.lens}: {pole}")
        if self.board_shape is not None and self.board_shape.notable:
            lines.append(self.board_shape.line())
        return lines

    def lens_pole(self) -> str | None:
        """What to tell the user of a rational lens whose denominator vanishes, or nearly, inside the observed field
        (:func:`circcal.solver.lensfield.result_pole`).

        Returns
        -------
        str or None
            None where the lens is a lens over the field its views observed.
        """
        return result_pole(self.result)

    def lines(self) -> list[str]:
        """The console summary of what the calibration summary does not already say: the verdict, what to do next
        (:attr:`remedy`), then :meth:`details`.

        Returns
        -------
        list of str
        """
        return self.verdict() + self.next_lines() + self.details()

    def next_lines(self) -> list[str]:
        """What to do next: the remedy's lines, then the board model the board-shape check recommends where it is not
        the one fitted (empty when there is nothing to do).

        Returns
        -------
        list of str
        """
        shape = None if self.board_shape is None else self.board_shape.recommendation()
        target = None if self.remedy is None else self.remedy.target()
        if shape and self.lens_in_question():
            shape = (
                "board shape: decide after the lens model (a lens the model cannot follow reads as a warped board): "
                "the recommended run's own board-shape check says whether the board is flat"
            )
        elif (
            shape
            and target is not None
            and self.remedy is not None
            and self.remedy.headline().startswith(f"recommended: {target.label}:")
            and {"--refine-board", "--board-warp"} & set(target.options)
        ):
            # the run recommended above changes the board model already: one recommendation, not two that cannot
            # be given together (--refine-board and --board-warp each model the board's shape)
            shape = (
                "board shape: "
                + shape.removeprefix("recommended: ")
                + f" (the run recommended above, {target.label}, models the board itself; its own board-shape check "
                "decides, and --refine-board and --board-warp are not given together)"
            )
        return ([] if self.remedy is None else self.remedy.lines()) + ([shape] if shape else [])

    def lens_in_question(self) -> bool:
        """Whether the lens model is in doubt: its residuals show a radial pattern, or the remedy recommends another
        lens. The board-shape check fits the board to this lens, so its recommendation waits for the lens.

        Returns
        -------
        bool
        """
        if self.lens_fit is not None and not self.lens_fit.fits:
            return True
        target = None if self.remedy is None else self.remedy.target()
        return target is not None and "--lens" in target.options

    def details(self) -> list[str]:
        """The board's shape where the verdict does not carry it (a flat board), the lens-model fit, the outliers, the
        coverage and the cross-validation's details, in lines.

        Returns
        -------
        list of str
        """
        out: list[str] = []
        if self.board_shape is not None and not self.board_shape.notable:
            out.append(self.board_shape.line())
        if self.lens_fit is not None:
            out.append(self.lens_fit.message())
        rej = self.result.outliers
        if rej is not None:
            if rej.items:
                bad = sum(r.reason == OutlierReason.BAD_DOT for r in rej.items)
                solved = len(rej.items) - bad
                said = [f"{bad} bad dot(s) the detector could tell before any solve"] if bad else []
                said += [f"{solved} by the residual rule"] if solved else []
                out.append(
                    f"outliers: {len(rej.items)} left out ({', '.join(said)}; the rule: residual beyond "
                    f"{rej.rule.k:g} sigma in x or y, sigma floored at {rej.rule.sigma_floor_px:g} px; {rej.rounds} "
                    f"solve(s)):"
                )
                names = self.cal_view_names()
                for r in rej.items:
                    where = names[r.view] if r.view < len(names) else f"view {r.view}"
                    if r.point is None:
                        what = "whole view"
                    elif np.all(np.isfinite(r.image_px)):
                        what = f"point {r.point} at ({r.image_px[0]:.1f}, {r.image_px[1]:.1f}) px"
                    else:  # a dot the detector dropped has no measured centre: "(nan, nan) px" said nothing
                        what = f"point {r.point}"
                    out.append(f"  {where}: {what}: {r.reason.value}: {r.detail}")
            else:
                out.append(
                    f"outliers: none (rule: residual beyond {rej.rule.k:g} sigma in x or y, sigma floored "
                    f"at {rej.rule.sigma_floor_px:g} px; bad dots by ellipse fit and area)"
                )
        for w in self.coverage.warnings:
            out.append(f"coverage: {w}")
        if not self.coverage.warnings:
            out.append(
                f"coverage: every ninth of the image holds observations ({100 * self.coverage.covered_share:.0f}"
                f"% of the map's cells)"
            )
        if self.crossval is not None and self.crossval.status == "ok":
            out += self.crossval.lines()
        elif self.crossval is not None:
            out += [f"cross-validation: (the check's own fits) {n}" for n in self.crossval.notes]
        return out

    def cal_view_names(self) -> list[str]:
        """Names of the views as given to the solve (before outlier rejection dropped any).

        Returns
        -------
        list of str
        """
        rej = self.result.outliers
        if rej is not None and rej.view_names:
            return list(rej.view_names)
        return list(self.result.view_names or [])

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary.

        Returns
        -------
        dict
            ``verdict``, ``uncertainty``, ``coverage``, ``outliers``, ``cross_validation``, ``lens_fit``, ``remedy``,
            ``board_shape``, ``timings_s``.
        """
        return {
            "verdict": self.verdict(),
            "uncertainty": None if self.uncertainty is None else self.uncertainty.to_dict(),
            "coverage": self.coverage.to_dict(),
            "outliers": None if self.result.outliers is None else self.result.outliers.to_dict(),
            "cross_validation": None if self.crossval is None else self.crossval.to_dict(),
            "lens_fit": None if self.lens_fit is None else self.lens_fit.to_dict(),
            "remedy": None if self.remedy is None else self.remedy.to_dict(),
            "board_shape": None if self.board_shape is None else self.board_shape.to_dict(),
            "timings_s": dict(self.timings),
        }


def assess(
    cal: Any,
    board: Any,
    options: CalibrationOptions = CalibrationOptions(),
    *,
    distance: float | None = None,
    cross_validate: bool = False,
    split: str = "alternate",
    seed: int = 0,
    check_board: bool = True,
) -> Assessment:
    """Assess ``cal`` (see the module).

    Parameters
    ----------
    cal : circcal.pipeline.ImagesCalibration
    board : circcal.board.Board
    options : CalibrationOptions
        The settings ``cal`` was made with, for the cross-validation's halves.
    distance : float or None
        mm along each pixel's ray at which uncertainty and cross-validation are evaluated (None: infinity).
    cross_validate : bool
        Also cross-validate (:func:`circcal.analysis.cross.cross_validate_detections`, ``split`` and ``seed``) and,
        where it finds a problem, try the candidates on its halves (:func:`circcal.analysis.remedy.remedy`).
    split, seed
        How the cross-validation halves the views (``"alternate"`` or ``"random"`` with ``seed``).
    check_board : bool
        Also fit the other board model and weigh the two (:func:`circcal.analysis.boardshape.board_shape`).

    Returns
    -------
    Assessment
    """
    t0 = time.perf_counter()
    res = cal.result
    unc = uncertainty_map(res, distance=distance)
    t1 = time.perf_counter()
    cov = coverage(res.image_points or [], res.camera.width, res.camera.height)
    cv = None
    if cross_validate:
        cv = cross_validate_detections(cal, board, options, split=split, seed=seed, distance=distance)
    t2 = time.perf_counter()
    fix = remedy(cal, board, options, cv, uncertainty=unc, coverage=cov, distance=distance)
    t3 = time.perf_counter()
    shape = board_shape(res, options) if check_board else None
    t4 = time.perf_counter()
    timings = {"uncertainty_s": t1 - t0, "cross_validation_s": t2 - t1, "remedy_s": t3 - t2, "board_shape_s": t4 - t3}
    return Assessment(cal, board, unc, cov, cv, timings, model_fit(res), fix, shape)
