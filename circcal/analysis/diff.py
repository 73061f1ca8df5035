"""The projection difference between two camera models, as ``mrcal-show-projection-diff`` measures it: a grid of
pixels of model A is unprojected with A, the transformation implied between the two models' frames is fitted over
a focus region (a rotation at infinity, rotation and translation at a finite distance), and the points are projected
with B. With both models' projection uncertainties (:mod:`circcal.solver.uncertainty`) the difference is also stated
in units of their combined uncertainty, ``sigma_A + sigma_B`` per pixel: mrcal's cross-validation rule of thumb is
that two calibrations of one camera differ by about the sum of their uncertainties.

Over the whole image (the default) the fit is :func:`circcal.analysis.compare.projection_diff`'s; a focus radius
fits over the grid pixels within that radius of the image centre and measures everywhere. Differences are the 2-D
distance per grid pixel (px); pixels follow OpenCV's convention; distances are mm along each ray.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal.analysis.compare import GRID_WIDTH, pixel_grid, projection_diff
from circcal.errors import InputError
from circcal.formats import read_camera
from circcal.model import Camera, project_camera, unproject
from circcal.rotation import fit_rotation, rotation_angle_deg

__all__ = [
    "ModelDiff",
    "model_diff",
    "CONSISTENT_RATIO",
    "CONSISTENT_SHARE",
    "NOISE_FLOOR_PX",
    "noise_floor_factor",
    "region_names",
]

#: Two models agree when their difference is within this many times their combined uncertainty ...
CONSISTENT_RATIO = 2.0
#: ... over at least this share of the image (the issue's rule; mrcal's validate-uncertainty.py finds perfect-data
#: differences within ~2x of the summed uncertainties).
CONSISTENT_SHARE = 0.95
#: The least per-coordinate noise (px) a cross-validation weighs two halves' difference with: a half's stated
#: uncertainty, first order in its residual noise, is scaled up to this noise (:func:`noise_floor_factor`). Below it
#: the residuals are the detector's own error, not noise: on the clean rendered rigs (residuals 0.0027-0.0029 px)
#: the centres' error from the truth is correlated within a view, its mean over a view up to 3x what independent
#: errors would give (chain's camera c: 0.0126 px x sqrt(n) against 0.0041), so a clean render's halves disagree by
#: up to ~3x their iid uncertainty (a wide stereo pair of an 11x4 board: 2.7x, a false "model or data problem").
#: Real photographs' noise is 0.05 px or more (:data:`circcal.solver.outliers.SIGMA_FLOOR_PX`): never floored there.
NOISE_FLOOR_PX = 0.01


def noise_floor_factor(sigma_px: float) -> float:
    """By how much a stated uncertainty first order in the noise ``sigma_px`` is raised to :data:`NOISE_FLOOR_PX`.

    Parameters
    ----------
    sigma_px : float
        The residual noise per coordinate the uncertainty was scaled with, px.

    Returns
    -------
    float
        ``max(1, NOISE_FLOOR_PX / sigma_px)`` (1 where ``sigma_px`` is not a positive number: nothing to raise).
    """
    if not (np.isfinite(sigma_px) and sigma_px > 0):
        return 1.0
    return max(1.0, NOISE_FLOOR_PX / float(sigma_px))


#: The image is named in thirds each way for "where": corners, edges, centre.
_THIRDS = (
    ("top-left corner", "top edge", "top-right corner"),
    ("left edge", "centre", "right edge"),
    ("bottom-left corner", "bottom edge", "bottom-right corner"),
)


def region_names(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """The name of the third of the image each pixel lies in ("top-left corner", "left edge", "centre", ...).

    Parameters
    ----------
    uv : ndarray, shape (N, 2)
        px.
    width, height : int
        The image, px.

    Returns
    -------
    ndarray of str (object), shape (N,)

    Examples
    --------
    >>> list(region_names([[320, 240]], 640, 480))
    ['centre']
    """
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    col = np.clip((uv[:, 0] + 0.5) * 3 // width, 0, 2).astype(int)
    row = np.clip((uv[:, 1] + 0.5) * 3 // height, 0, 2).astype(int)
    return np.array([_THIRDS[r][c] for r, c in zip(row, col)], dtype=object)


@dataclass
class ModelDiff:
    """The difference of B against A over A's image.

    Attributes
    ----------
    uv : ndarray, shape (H, W, 2)
        The grid, px.
    diff : ndarray, shape (H, W)
        px.
    centre_px : float
        At the image centre, px.
    rms_px, p95_px, max_px : float
        Over the grid (finite pixels), px.
    R : ndarray, shape (3, 3)
    t : ndarray, shape (3,)
        The implied transformation (A's frame into B's: B sees A's point X at R X + t), mm.
    focus_radius_px : float or None
        None: whole image.
    distance_mm : float or None
        None: infinity.
    n_invalid : int
        Grid pixels that could not be compared.
    sigma_a, sigma_b : ndarray, shape (H, W), or None
        With uncertainties: each model's, px.
    ratio : ndarray, shape (H, W), or None
        diff / (sigma_a + sigma_b).
    share_within : float or None
        The share of the grid within :data:`CONSISTENT_RATIO` of it.
    consistent : bool or None
    where : list of (str, float)
        The image thirds where it is exceeded, worst first, with the share of their pixels.
    """

    uv: np.ndarray
    diff: np.ndarray
    centre_px: float
    rms_px: float
    p95_px: float
    max_px: float
    R: np.ndarray
    t: np.ndarray
    focus_radius_px: float | None
    distance_mm: float | None
    n_invalid: int
    sigma_a: np.ndarray | None = None
    sigma_b: np.ndarray | None = None
    ratio: np.ndarray | None = None
    share_within: float | None = None
    consistent: bool | None = None
    where: list[tuple[str, float]] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        """The numbers, JSON-ready (maps left out).

        Returns
        -------
        dict
        """
        out = {
            k: getattr(self, k)
            for k in (
                "centre_px",
                "rms_px",
                "p95_px",
                "max_px",
                "focus_radius_px",
                "distance_mm",
                "n_invalid",
                "share_within",
                "consistent",
            )
        }
        out["where"] = [{"region": r, "share_exceeding": s} for r, s in self.where]
        out["implied_rotation_deg"] = float(rotation_angle_deg(self.R))
        if self.ratio is not None:
            r = self.ratio[np.isfinite(self.ratio)]
            out["ratio_median"] = float(np.median(r)) if r.size else float("nan")
            out["ratio_max"] = float(np.max(r)) if r.size else float("nan")
        return out


def _points(uv: np.ndarray, cam: Camera, distance: float | None) -> np.ndarray:
    r = unproject(uv, cam)
    unit: np.ndarray = r / np.linalg.norm(r, axis=1, keepdims=True)
    return unit if distance is None else unit * float(distance)


def model_diff(
    a: Camera | str | os.PathLike[str],
    b: Camera | str | os.PathLike[str],
    *,
    distance: float | None = None,
    focus_radius_px: float | None = None,
    gridn_width: int = GRID_WIDTH,
    uncertainty_a: Callable[[np.ndarray], np.ndarray] | None = None,
    uncertainty_b: Callable[[np.ndarray], np.ndarray] | None = None,
) -> ModelDiff:
    """The projection difference of ``b`` against ``a`` (see the module).

    Parameters
    ----------
    a, b : Camera, or str or path
        The cameras, or model files any format :func:`circcal.formats.read_camera` reads.
    distance : float or None
        mm along each ray (None: infinity).
    focus_radius_px : float or None
        Fit the implied transformation over the grid pixels within this radius of the image centre (None: the whole
        image; 0: no fit).
    gridn_width : int
        Grid points across.
    uncertainty_a, uncertainty_b : callable or None
        Functions pixels (N, 2) -> projection standard deviation (N,) px of each model at ``distance`` (e.g.
        :func:`circcal.solver.uncertainty.result_projection_stdev`).

    Returns
    -------
    ModelDiff

    Raises
    ------
    InputError
        Models of different image sizes, or a ``distance`` that is not a positive number; an unreadable model file.
    """
    a, b = (read_camera(os.fspath(m)) if isinstance(m, (str, os.PathLike)) else m for m in (a, b))
    if (a.width, a.height) != (b.width, b.height):
        raise InputError(
            f"the models have different image sizes ({a.width}x{a.height} and {b.width}x{b.height}): "
            f"a projection difference compares one imager"
        )
    if distance is not None and not (np.isfinite(distance) and distance > 0):
        raise InputError(f"distance must be a positive number of mm, got {distance!r}")
    uv = pixel_grid(a, gridn_width)
    nx = gridn_width
    ny = len(uv) // nx
    if focus_radius_px is None:
        d = projection_diff(a, b, gridn_width=gridn_width, distance=distance, fit=True)
        diff, R, t = d["diff"], d["R"], d["t"]
    else:
        if not (np.isfinite(focus_radius_px) and focus_radius_px >= 0):
            raise InputError(f"the focus radius must be >= 0 px, got {focus_radius_px!r}")
        Pa = _points(uv, a, distance)
        R, t = np.eye(3), np.zeros(3)
        if focus_radius_px > 0:
            centre_xy = np.array([(a.width - 1) / 2, (a.height - 1) / 2])
            Pb = _points(uv, b, distance)
            focus = (
                (np.linalg.norm(uv - centre_xy, axis=1) <= focus_radius_px)
                & np.all(np.isfinite(Pa), axis=1)
                & np.all(np.isfinite(Pb), axis=1)
            )
            if focus.sum() < 3:
                raise InputError(
                    f"the focus radius {focus_radius_px:g} px holds {int(focus.sum())} grid pixels; the fit needs 3"
                )
            R, t = fit_rotation(Pa[focus], Pb[focus], translation=distance is not None)
        diff = np.linalg.norm(project_camera(Pa @ R.T + t, b) - uv, axis=1)
    centre_uv = np.array([[(a.width - 1) / 2, (a.height - 1) / 2]])
    centre = float(np.linalg.norm(project_camera(_points(centre_uv, a, distance) @ R.T + t, b) - centre_uv))
    ok = np.isfinite(diff)
    dv = diff[ok]
    out = ModelDiff(
        uv=uv.reshape(ny, nx, 2),
        diff=diff.reshape(ny, nx),
        centre_px=centre,
        rms_px=float(np.sqrt(np.mean(dv**2))) if dv.size else float("nan"),
        p95_px=float(np.percentile(dv, 95)) if dv.size else float("nan"),
        max_px=float(np.max(dv)) if dv.size else float("nan"),
        R=R,
        t=t,
        focus_radius_px=focus_radius_px,
        distance_mm=distance,
        n_invalid=int((~ok).sum()),
    )
    if uncertainty_a is not None and uncertainty_b is not None:
        sa = np.asarray(uncertainty_a(uv), dtype=np.float64)
        sb = np.asarray(uncertainty_b(uv), dtype=np.float64)
        ratio = diff / (sa + sb)
        fin = np.isfinite(ratio)
        within = ratio[fin] <= CONSISTENT_RATIO
        out.sigma_a, out.sigma_b, out.ratio = sa.reshape(ny, nx), sb.reshape(ny, nx), ratio.reshape(ny, nx)
        out.share_within = float(within.mean()) if fin.any() else float("nan")
        out.consistent = bool(fin.any() and out.share_within >= CONSISTENT_SHARE)
        names = region_names(uv[fin], a.width, a.height)
        where = []
        for name in dict.fromkeys(n for row in _THIRDS for n in row):
            m = names == name
            if m.any():
                share = float(np.mean(~within[m]))
                if share > 1.0 - CONSISTENT_SHARE:
                    where.append((name, share))
        out.where = sorted(where, key=lambda x: -x[1])
    return out
