"""The interface every reference calibrator implements (:class:`ReferenceCalibrator`) and its required members.

A reference calibrator (OpenCV, mrcal, kornia, pycolmap, or a third party's plug-in) takes the *same* 2-D centres as
circcal and returns a :class:`~circcal.validators.reference_result.ReferenceResult`; subclassing
:class:`~circcal.validators.base.BaseCalibrator` is the easy way to implement it.

Conventions (those of :mod:`circcal.model`): pixel centres at integer coordinates, OpenCV point order, board points in
mm with z = 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from circcal.model import Camera
from circcal.validators.reference_result import Mode, ReferenceResult

__all__ = ["REQUIRED_MEMBERS", "missing_members", "ReferenceCalibrator"]

#: What the suite calls on a reference calibrator (the rest of :class:`ReferenceCalibrator` has defaults in
#: :class:`~circcal.validators.base.BaseCalibrator`).
REQUIRED_MEMBERS: tuple[str, ...] = ("name", "available", "calibrate_observations")


def missing_members(obj: Any) -> list[str]:
    """The members of :data:`REQUIRED_MEMBERS` that an object lacks.

    Parameters
    ----------
    obj : object
        A candidate reference calibrator (e.g. a plug-in's entry point, loaded).

    Returns
    -------
    list of str
        The missing member names; empty when ``obj`` can be used as a reference.
    """
    return [m for m in REQUIRED_MEMBERS if not hasattr(obj, m)]


@runtime_checkable
class ReferenceCalibrator(Protocol):
    """What the registry hands out.

    Third-party plug-ins implement this (subclassing :class:`~circcal.validators.base.BaseCalibrator` is the easy way) and register under the
    entry-point group ``circcal.validators``. The methods never raise: failures come back as a :class:`ReferenceResult`
    status.
    """

    name: str

    @property
    def version(self) -> str: ...

    def available(self) -> tuple[bool, str]:
        """Whether the reference can run here.

        Returns
        -------
        tuple of (bool, str)
            ``(True, "")``, or ``(False, reason)`` when the reference is not installed or cannot run.
        """

    def calibrate_observations(
        self,
        object_points: Sequence[np.ndarray],
        image_points: Sequence[np.ndarray],
        image_size: tuple[int, int],
        *,
        mode: Mode = "fair",
        initial: Camera | None = None,
    ) -> ReferenceResult:
        """Calibrate from given centres (see :meth:`BaseCalibrator.calibrate_observations`).

        Parameters
        ----------
        object_points : sequence of ndarray, shape (N_v, 3)
            Board points per view, mm, z = 0.
        image_points : sequence of ndarray, shape (N_v, 2)
            Detected centres per view, px.
        image_size : tuple of int
            (width, height) px.
        mode : {"fair", "default"}
            Estimator to run.
        initial : circcal.model.Camera, optional
            A starting camera, for references that take one.

        Returns
        -------
        ReferenceResult
            Never raises; failures are a status.
        """

    def calibrate_images(
        self,
        paths: Sequence[Any],
        board: Any,
        image_size: tuple[int, int] | None = None,
        *,
        mode: Mode = "fair",
        initial: Camera | None = None,
    ) -> ReferenceResult:
        """Detect with the reference's own detector, then calibrate.

        Parameters
        ----------
        paths : sequence of path-like
            Image files.
        board : circcal.board.Board
            The calibration target.
        image_size : tuple of int, optional
            (width, height) px; from the images when None.
        mode : {"fair", "default"}
            Estimator to run.
        initial : circcal.model.Camera, optional
            A starting camera, for references that take one.

        Returns
        -------
        ReferenceResult
            Never raises; failures are a status.
        """
