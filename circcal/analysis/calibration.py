"""One calibration with its verdict: what ``circcal.calibrate`` (the public API) and ``circcal calibrate`` (the CLI)
return. Images go through the detect -> calibrate -> re-correct pipeline (:func:`circcal.pipeline.calibrate_images`);
observations straight to the solver (:func:`circcal.solver.calibrate`); either way the result is assessed
(:func:`circcal.analysis.assess.assess`: outliers, projection uncertainty, lens-model fit, coverage, the board's
shape (:mod:`circcal.analysis.boardshape`) and, when asked, cross-validation)."""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from circcal.analysis.assess import Assessment, assess
from circcal.errors import InputError
from circcal.model import Camera
from circcal.pipeline import ImagesCalibration, calibrate_images
from circcal.solver import CalibrationOptions, CalibrationResult
from circcal.solver import calibrate as solve

__all__ = ["Calibration", "calibrate"]


@dataclass(frozen=True)
class Calibration:
    """A calibration and everything that says whether it is right.

    Attributes
    ----------
    result : CalibrationResult
        The solve: camera, sigmas, residuals, poses, covariance (:class:`circcal.solver.CalibrationResult`).
    assessment : Assessment
        Outliers, projection uncertainty, lens-model fit, coverage, cross-validation
        (:class:`circcal.analysis.assess.Assessment`).
    images : ImagesCalibration or None
        From images: the detections, the images used and left out (with their reasons), the re-correction rounds;
        None from observations.
    """

    result: CalibrationResult
    assessment: Assessment
    images: ImagesCalibration | None = None

    @property
    def camera(self) -> Camera:
        """The calibrated camera (fx, fy, cx, cy in px and the lens model's distortion)."""
        return self.result.camera

    @property
    def std(self) -> dict[str, float]:
        """Each parameter's standard deviation (px for fx, fy, cx, cy; unitless for distortion)."""
        return dict(self.result.std)

    @property
    def residuals(self) -> list[np.ndarray]:
        """Per view, (N_v, 2) px: observed - projected."""
        return list(self.result.residuals)

    @property
    def uncertainty(self) -> Any:
        """The projection uncertainty over the image (:class:`circcal.analysis.assess.UncertaintyMap`; 1-sigma,
        worst direction, px), or None where it cannot be computed."""
        return self.assessment.uncertainty

    @property
    def board_shape(self) -> Any:
        """Whether the board is flat and which board model predicts held-out views better
        (:class:`circcal.analysis.boardshape.BoardShape`: the warp with its sigma, the flatness test, the intrinsics'
        shift in stated sigmas, the recommended model), or None where it was not checked."""
        return self.assessment.board_shape

    @property
    def verdict(self) -> list[str]:
        """The verdict in words: its first lines say whether to trust the model and what to do next."""
        return list(self.assessment.verdict())

    def lines(self) -> list[str]:
        """What the assessment says, in lines.

        Returns
        -------
        list of str
            The verdict, then the lens-model fit, the outliers, the coverage and the cross-validation (what the CLI
            prints after the summary).
        """
        return self.assessment.lines()


def calibrate(
    images: str | os.PathLike[str] | Iterable[str | os.PathLike[str]] | None = None,
    board: Any = None,
    options: CalibrationOptions = CalibrationOptions(),
    *,
    observations: tuple[Sequence[np.ndarray], Sequence[np.ndarray]] | None = None,
    image_size: tuple[int, int] | None = None,
    cross_validate: bool = False,
    distance: float | None = None,
    split: str = "alternate",
    seed: int = 0,
    lens_candidates: Sequence[str] | None = None,
    progress: bool = False,
    jobs: int | None = None,
) -> Calibration:
    """Calibrate a camera from images of a board, or from observations, and assess the result.

    Parameters
    ----------
    images : str, Path, iterable of them, or None
        Image files, or a folder standing for its images (:func:`circcal.imagefiles.image_list`); None, the
        default, with ``observations``.
    board : circcal.board.Board
        The board the images show (required; a keyword with ``observations``).
    options : CalibrationOptions
        Lens model, held parameters, outlier rule, board refinement.
    observations : (object_points, image_points) or None
        Instead of images: per view (N_v, 3) mm on the board and (N_v, 2) px, with ``image_size``.
    image_size : tuple of int or None
        (width, height) px: required with ``observations``; with images, the camera mode to calibrate (default: the
        size most images share).
    cross_validate : bool
        Also calibrate two disjoint halves and weigh their difference against their combined uncertainty.
    distance : float or None
        mm along each pixel's ray at which uncertainty and cross-validation are evaluated (None: infinity).
    split, seed
        How the halves are drawn (``"alternate"`` or ``"random"`` with ``seed``).
    lens_candidates : sequence of str or None
        Images only: choose the lens model among these (``--lens auto``; :func:`circcal.pipeline.choose_lens`).
    progress : bool
        Show a progress bar while detecting.
    jobs : int or None
        Images detected at once (None: one per CPU).

    Returns
    -------
    Calibration
        The model, its sigmas and residuals, its projection uncertainty and its verdict.

    Raises
    ------
    InputError
        Neither or both of images and observations; no board; observations without ``image_size``.
    CalibrationError
        No trustworthy model (too few views, degenerate poses, no convergence): the message says why.

    Examples
    --------
    >>> import circcal                                                # doctest: +SKIP
    >>> cal = circcal.calibrate(sorted(Path("photos").glob("*.png")), circcal.Board(7, 9, 10.0, 4.0))
    >>> print(cal.camera, cal.std["fx"], cal.verdict[0])
    """
    if (images is None) == (observations is None):
        raise InputError("give images or observations (object_points, image_points), one of them")
    if board is None:
        raise InputError("give board= (a circcal.Board: the board the views show)")
    if images is not None:
        run = calibrate_images(
            images, board, options, progress=progress, jobs=jobs, image_size=image_size, lens_candidates=lens_candidates
        )
        options = options.replace(lens=run.result.camera.lens)
        assessment = assess(
            run, board, options, distance=distance, cross_validate=cross_validate, split=split, seed=seed
        )
        return Calibration(run.result, assessment, run)
    if image_size is None:
        raise InputError("observations need image_size=(width, height) px")
    object_points, image_points = observations  # type: ignore[misc]
    result = solve(list(object_points), list(image_points), image_size, options)
    assessment = assess(_Observed(result), board, options, distance=distance, cross_validate=False)
    if cross_validate:
        from dataclasses import replace

        from circcal.analysis.cross import cross_validate_observations

        _, cv = cross_validate_observations(
            object_points,
            image_points,
            image_size,
            options,
            full=result,
            split=split,
            seed=seed,
            distance=distance,
        )
        assessment = replace(assessment, crossval=cv)
    return Calibration(result, assessment, None)


@dataclass(frozen=True)
class _Observed:
    """What :func:`circcal.analysis.assess.assess` reads of a calibration made from observations: its result."""

    result: CalibrationResult
