"""Does the lens model fit? A test of a calibration's residuals for the radial pattern a too simple lens model
leaves, with the noise measured where no smooth model error can reach it.

A lens model that is too simple for the lens (opencv5 on a fisheye or on a wide lens that needs the rational model)
cannot follow the true distortion curve: after the fit, the residuals left along the radius from the principal
point have the same sign over whole rings of the image, in every view. Noise has no such pattern. The test:

1. **Noise** ``noise_px`` (per coordinate) from the differences of the residuals of neighbouring board points in
   the same view: a smooth model error is nearly the same at two points one pitch apart and cancels in their
   difference, noise does not (``var(r_i - r_j) = 2 sigma^2`` per coordinate).
2. **Radial profile**: every residual's component along the ray from the principal point (px, positive outwards),
   averaged in :data:`RADIAL_BINS` rings of equal point count; ``z_b = mean_b / (noise_px / sqrt(n_b))``.
3. **Verdict**: the model is reported not to fit when the profile is significant (``chi2 = sum z_b^2`` has a
   chance below :data:`P_VALUE` under noise alone) *and* large enough to matter: some ring's mean radial residual
   exceeds both :data:`MIN_EFFECT_PX` and :data:`MIN_EFFECT_NOISE` x the noise. (The first alone would flag
   0.001 px patterns of a huge clean data set; the second alone would flag noise.)

The rule reads residuals only, so it serves any lens model and any data (renders or photographs). What it cannot
tell apart: a radial pattern from biased centres that grows with the radius (e.g. centroids of strongly tilted
dots); the message says so. Residuals are observed - projected (px, OpenCV's pixel-centre convention).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["ModelFit", "model_fit", "neighbour_noise", "RADIAL_BINS", "P_VALUE", "MIN_EFFECT_PX", "MIN_EFFECT_NOISE"]

#: rings of equal point count over the radius from the principal point
RADIAL_BINS = 8
#: the chance under noise alone below which the radial profile is significant
P_VALUE = 1e-6
#: the least ring-mean radial residual reported as a model error (px): below it the model error is a small part of
#: any calibration's error budget (the paper's bar is 0.12 px mean 2-D)
MIN_EFFECT_PX = 0.02
#: the least ring-mean radial residual reported as a model error, in units of the measured noise
MIN_EFFECT_NOISE = 0.5


@dataclass(frozen=True)
class ModelFit:
    """Whether the lens model fits: the radial pattern of the residuals (module rule).

    Attributes
    ----------
    fits : bool
        False when the residuals hold the radial pattern of a too simple lens model.
    lens : str
        The model tested.
    noise_px : float
        Per-coordinate noise from neighbour differences, px.
    radius_px : ndarray, shape (B,)
        Each ring's mean radius, px.
    radial_px : ndarray, shape (B,)
        Its mean radial residual, px (positive: observed beyond the projection).
    z : ndarray, shape (B,)
        The same in standard errors.
    chi2 : float
        With ``p_value``.
    p_value : float
    n_points : int
    """

    fits: bool
    lens: str
    noise_px: float
    radius_px: np.ndarray
    radial_px: np.ndarray
    z: np.ndarray
    chi2: float
    p_value: float
    n_points: int

    @property
    def worst(self) -> int:
        """The ring with the largest mean radial residual."""
        return int(np.argmax(np.abs(self.radial_px)))

    def message(self) -> str:
        """The verdict in one line of words: the residuals' radial profile and, when the model does not fit, which
        ``--lens`` to try.

        Returns
        -------
        str
        """
        k = self.worst
        profile = (
            f"mean radial residual up to {self.radial_px[k]:+.3f} px at {self.radius_px[k]:.0f} px from the "
            f"principal point, {abs(self.radial_px[k]) / self.noise_px:.1f}x the noise of {self.noise_px:.3f} "
            f"px per coordinate (chi2 {self.chi2:.0f} over {len(self.z)} rings, p {self.p_value:.1g})"
        )
        if self.fits:
            return f"lens model {self.lens}: fits (no radial pattern in the residuals: {profile})"
        wider = {
            "opencv5": "--lens rational (a wide lens) or --lens fisheye (beyond ~120 deg)",
            "rational": "--lens thin-prism or --lens fisheye",
            "thin-prism": "--lens fisheye",
            "fisheye": "--lens rational",
        }.get(self.lens, "another --lens")
        return (
            f"lens model {self.lens} does NOT fit: the residuals follow the radius ({profile}); the model cannot "
            f"follow this lens's distortion: try {wider}. (Biased centres that grow toward the edge would look "
            f"alike.)"
        )

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary, with the rule in words.

        Returns
        -------
        dict
            ``fits``, ``lens``, ``noise_px_per_coord``, ``radius_px``, ``radial_residual_px``, ``z``, ``chi2``,
            ``p_value``, ``n_points``, ``rule``.
        """
        return {
            "fits": self.fits,
            "lens": self.lens,
            "noise_px_per_coord": self.noise_px,
            "radius_px": self.radius_px.tolist(),
            "radial_residual_px": self.radial_px.tolist(),
            "z": self.z.tolist(),
            "chi2": self.chi2,
            "p_value": self.p_value,
            "n_points": self.n_points,
            "rule": f"not fitting when chi2 of {RADIAL_BINS} ring means has p < {P_VALUE:g} and a ring's mean "
            f"radial residual exceeds {MIN_EFFECT_PX:g} px and {MIN_EFFECT_NOISE:g}x the noise "
            f"(noise from neighbouring points' residual differences)",
        }


def _neighbour_pairs(xy: np.ndarray, chunk: int = 256) -> np.ndarray:
    """(K, 2) index pairs i < j of the points ``xy`` (N, 2) at most 1.01 x their smallest spacing apart (numpy in
    row chunks: scipy.spatial would cost a calibrate process ~1 s of import for a few hundred points a view)."""
    n = len(xy)
    if n < 2:
        return np.empty((0, 2), np.int64)
    d = np.concatenate(
        [np.linalg.norm(xy[i : i + chunk, None, :] - xy[None, :, :], axis=2) for i in range(0, n, chunk)]
    )
    d[np.tril_indices(n)] = np.inf
    i, j = np.nonzero(d <= 1.01 * d.min())
    return np.stack([i, j], axis=1)


def neighbour_noise(object_points: Sequence[np.ndarray], residuals: Sequence[np.ndarray]) -> float:
    """Per-coordinate noise from the residual differences of board neighbours in each view.

    Neighbours: pairs of a view's points at most 1.01 x the view's smallest point spacing apart. A robust scale
    (1.4826 x the median absolute difference) so that a few bad points do not set it.

    Parameters
    ----------
    object_points : sequence of ndarray
        Per view (N_v, 3) mm.
    residuals : sequence of ndarray
        Per view (N_v, 2) px.

    Returns
    -------
    float
        px; NaN with fewer than 10 pairs.
    """
    diffs = []
    for obj, res in zip(object_points, residuals):
        pairs = _neighbour_pairs(np.asarray(obj, dtype=np.float64)[:, :2])
        if len(pairs):
            diffs.append((res[pairs[:, 0]] - res[pairs[:, 1]]).ravel())
    if not diffs or sum(len(x) for x in diffs) < 20:
        return float("nan")
    x = np.concatenate(diffs)
    return float(1.4826 * np.median(np.abs(x - np.median(x))) / np.sqrt(2.0))


def chi2_survival_even(k: int, x: float) -> float:
    """P(X >= x) for X ~ chi-square with an even number of degrees of freedom.

    Exactly ``exp(-x/2) * sum_{i < k/2} (x/2)^i / i!`` (the Poisson sum; scipy.special.chdtrc gives the same, but
    importing scipy.special costs a calibrate process ~0.3 s, a third of its start-up).

    Parameters
    ----------
    k : int
        Degrees of freedom, even and positive.
    x : float

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Odd or non-positive ``k``.

    Examples
    --------
    >>> round(chi2_survival_even(2, 2.0), 6)
    0.367879
    """
    if k <= 0 or k % 2:
        raise ValueError(f"k must be a positive even number of degrees of freedom, got {k}")
    if x <= 0:
        return 1.0
    h = 0.5 * x
    return min(1.0, math.fsum(math.exp(i * math.log(h) - h - math.lgamma(i + 1)) for i in range(k // 2)))


def model_fit(result: Any) -> ModelFit | None:
    """Test a calibration's residuals for a lens model that does not fit (the module's rule).

    Parameters
    ----------
    result : CalibrationResult

    Returns
    -------
    ModelFit or None
        None when it holds too few points to tell (fewer than 4 per ring, or no neighbours for the noise).
    """
    cam = result.camera
    obs = np.concatenate(result.image_points)
    res = np.concatenate(result.residuals)
    n = len(obs)
    noise = neighbour_noise(result.object_points, result.residuals)
    if n < 4 * RADIAL_BINS or not np.isfinite(noise) or noise <= 0:
        return None
    proj = obs - res
    out = proj - np.array([cam.cx, cam.cy])
    r = np.linalg.norm(out, axis=1)
    radial = np.einsum("ij,ij->i", res, out / np.maximum(r, 1e-12)[:, None])
    order = np.argsort(r)
    rings = np.array_split(order, RADIAL_BINS)
    radius = np.array([r[k].mean() for k in rings])
    mean = np.array([radial[k].mean() for k in rings])
    z = mean / (noise / np.sqrt([len(k) for k in rings]))
    chi2 = float(np.sum(z**2))
    p = chi2_survival_even(RADIAL_BINS, chi2)
    big = np.abs(mean) > max(MIN_EFFECT_PX, MIN_EFFECT_NOISE * noise)
    return ModelFit(not (p < P_VALUE and bool(big.any())), cam.lens, noise, radius, mean, z, chi2, p, n)
