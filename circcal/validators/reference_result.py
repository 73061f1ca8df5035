"""The result a reference calibrator hands back (:class:`ReferenceResult`), its statuses and modes.

Conventions (those of :mod:`circcal.model`): poses map board to camera (``X_cam = R(rvec) X + tvec``); residuals are
``observed - projected`` in px.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from circcal.jsonio import jsonable
from circcal.model import Camera

__all__ = ["STATUSES", "MODES", "Mode", "ReferenceResult"]

STATUSES: tuple[str, ...] = ("ok", "unavailable", "unsupported", "failed")
MODES: tuple[str, ...] = ("fair", "default")
Mode = Literal["fair", "default"]


@dataclass
class ReferenceResult:
    """What one reference calibrator produced on one problem.

    Attributes
    ----------
    name, version : str
        The reference and its version.
    mode : str
        "fair" or "default" (see :data:`MODES`).
    status : str
        "ok" | "unavailable" (reference not installed) | "unsupported" (input it cannot handle, e.g. an asymmetric grid
        for mrcal) | "failed" (crash, divergence, bad input).
    message : str
        Why, when the status is not "ok".
    camera : circcal.model.Camera or None
        The calibrated camera (None unless ok).
    std : dict of str to float, or None
        Standard deviations keyed by ``circcal.model.param_names(camera.lens)`` (a fixed parameter has 0.0), or None
        when the reference offers none.
    rvecs, tvecs : ndarray, shape (V, 3), or None
        Board-to-camera poses (rad; mm).
    residuals : list of ndarray, shape (N_v, 2), or None
        Per view, observed - projected in px (NaN for points a reference dropped as outliers).
    errors : dict or None
        :func:`circcal.metrics.error_stats` of all residuals.
    time_s : float
        Wall time of the solve (s).
    object_points, image_points : list of ndarray or None
        The observations actually used, per view: (N_v, 3) mm and (N_v, 2) px.
    views : list of int or None
        Indices (into the caller's views/images) of the views used.
    extra : dict
        Reference-specific facts (fixed parameters, flags, mrcal statistics, seeds) that a report should show.

    Raises
    ------
    ValueError
        ``status`` is not one of :data:`STATUSES` (a bug in the adapter).
    """

    name: str
    version: str
    mode: str
    status: str
    message: str = ""
    camera: Camera | None = None
    std: dict[str, float] | None = None
    rvecs: np.ndarray | None = None
    tvecs: np.ndarray | None = None
    residuals: list[np.ndarray] | None = None
    errors: dict[str, float] | None = None
    time_s: float = 0.0
    object_points: list[np.ndarray] | None = None
    image_points: list[np.ndarray] | None = None
    views: list[int] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {', '.join(STATUSES)}, got {self.status!r}")

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def summary(self) -> str:
        """One line for logs and CLI tables.

        Returns
        -------
        str
            Name, version, mode and status; for an ok result the intrinsics, distortion, RMS per point (px) and time
            (s),
            otherwise the message.
        """
        head = f"{self.name} {self.version} [{self.mode}]: {self.status}"
        if not self.ok:
            return f"{head}: {self.message}"
        c = self.camera
        e = self.errors or {}
        return (
            f"{head}: fx={c.fx:.4f} fy={c.fy:.4f} cx={c.cx:.4f} cy={c.cy:.4f} "
            f"dist={np.array2string(c.dist, precision=5)} rms_per_point={e.get('rms_per_point_px', np.nan):.4f} px "
            f"({self.time_s:.3f} s)"
        )

    def to_dict(self) -> dict[str, Any]:
        """The result as a JSON-ready dict.

        Returns
        -------
        dict
            Every field but the observations; arrays as lists, residuals per view, ``extra`` made JSON-safe.
        """

        def arr(a: Any) -> Any:
            return None if a is None else np.asarray(a, dtype=float).tolist()

        return {
            "name": self.name,
            "version": self.version,
            "mode": self.mode,
            "status": self.status,
            "message": self.message,
            "camera": None if self.camera is None else self.camera.to_dict(),
            "std": self.std,
            "rvecs": arr(self.rvecs),
            "tvecs": arr(self.tvecs),
            "residuals": None if self.residuals is None else [arr(r) for r in self.residuals],
            "errors": self.errors,
            "time_s": float(self.time_s),
            "views": self.views,
            "extra": jsonable(self.extra),
        }
