"""The checks that ``circcal validate`` gates on and the conformance suite asserts, written once: agreement with
circcal's solver on identical observations, and agreement with the true camera in stated sigmas.

A :class:`Check` holds a value, its bound and the verdict; the bounds' defaults, each with its reason, are
:mod:`circcal.validators.bounds`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from circcal.analysis.compare import param_diff, projection_diff
from circcal.model import Camera
from circcal.validators.bounds import COST_TIE_REL, SOLVER_LENSBOY_PX, SOLVER_MRCAL_PX, SOLVER_PX, TRUTH_SIGMAS
from circcal.validators.shared import ssr

__all__ = [
    "Check",
    "SOLVER_PX",
    "SOLVER_MRCAL_PX",
    "SOLVER_LENSBOY_PX",
    "TRUTH_SIGMAS",
    "COST_TIE_REL",
    "TRUTH_PARAMS",
    "STOPS_SHORT",
    "solver_bound",
    "solver_agreement",
    "truth_checks",
]

#: The parameters the truth check holds to their stated sigmas (distortion terms are correlated with each other
#: and with the focal length; their individual sigmas are not a useful bar).
TRUTH_PARAMS = ("fx", "fy", "cx", "cy")


@dataclass
class Check:
    """One verdict: a measured value against its bound.

    Attributes
    ----------
    name : str
        What was checked, with its unit.
    value : float
        The measurement (NaN for a yes/no check).
    bound : float
        The bound it is held to (NaN for a yes/no check).
    passed : bool
        The verdict.
    note : str
        What was measured beside it.
    """

    name: str
    value: float
    bound: float
    passed: bool
    note: str = ""


#: References whose own bound beyond :data:`SOLVER_PX` stands for their solver stopping short of the minimum
#: (lensboy: Ceres's function tolerance, :data:`SOLVER_LENSBOY_PX`): a difference beyond SOLVER_PX passes only with
#: their cost at or above circcal's on the same observations, the proof that they stopped short.
STOPS_SHORT: frozenset[str] = frozenset({"lensboy"})


def solver_bound(reference: str) -> float:
    """The identical-observations bound for a reference.

    Parameters
    ----------
    reference : str
        A reference name.

    Returns
    -------
    float
        Max projection difference, px: :data:`SOLVER_MRCAL_PX` for mrcal and :data:`SOLVER_LENSBOY_PX` for lensboy
        (their solvers stop earlier than the others), :data:`SOLVER_PX` otherwise.
    """
    return {"mrcal": SOLVER_MRCAL_PX, "lensboy": SOLVER_LENSBOY_PX}.get(reference, SOLVER_PX)


def solver_agreement(label: str, ref: Any, max_px: float, circcal_ssr: float, bound: float) -> Check:
    """The identical-observations check: a reference's solve against circcal's solver on the same points.

    Passes when the max projection difference ``max_px`` is within ``bound``. Beyond it the costs decide: on a flat
    problem (k3 at a long focal length) two solvers can stop 1e-6..1e-5 px apart with costs equal to ~1e-13
    relative, which double precision cannot separate, so equal costs (within :data:`COST_TIE_REL`) still pass; any
    real cost difference fails, and the note says which side missed the minimum. For a reference in
    :data:`STOPS_SHORT` a difference beyond :data:`SOLVER_PX` passes within ``bound`` only with its cost not below
    circcal's (the note gives the excess).

    Parameters
    ----------
    label : str
        The reference as the check's name shows it.
    ref : circcal.validators.reference_result.ReferenceResult
        The reference's "ok" solve (its ``residuals`` give its cost).
    max_px : float
        Max projection difference between its camera and circcal's over the imager, px.
    circcal_ssr : float
        circcal's sum of squared residuals on the same points, px^2.
    bound : float
        The bound, px (:func:`solver_bound`).

    Returns
    -------
    Check
    """
    name = f"{label} vs circcal on identical observations: max projection difference, px"
    within = bool(np.isfinite(max_px) and max_px <= bound)
    if within and (ref.name not in STOPS_SHORT or max_px <= SOLVER_PX):
        return Check(name, max_px, bound, True)
    ssr_ref = ssr(ref.residuals)
    rel = (ssr_ref - circcal_ssr) / circcal_ssr if circcal_ssr > 0 else float("nan")
    if abs(rel) <= COST_TIE_REL:
        return Check(
            name,
            max_px,
            bound,
            True,
            f"costs equal to {abs(rel):.1g} relative: both at the minimum to "
            f"double precision; the difference lies along a flat direction",
        )
    if rel < 0:
        return Check(
            name,
            max_px,
            bound,
            False,
            f"{ref.name}'s cost is lower than circcal's by {-rel:.2g} (relative): circcal missed the minimum",
        )
    if within and rel > 0:
        return Check(
            name,
            max_px,
            bound,
            True,
            f"{ref.name}'s cost is higher than circcal's by {rel:.2g} (relative): "
            f"{ref.name} stopped short of the minimum",
        )
    return Check(
        name,
        max_px,
        bound,
        False,
        f"{ref.name}'s cost is higher than circcal's by {rel:.2g} (relative): {ref.name} did not reach the minimum",
    )


def truth_checks(
    who: str,
    camera: Camera,
    std: dict[str, float] | None,
    truth: Camera,
    *,
    sigmas: float = TRUTH_SIGMAS,
    rms_px: float | None = None,
    std_note: str = "",
) -> tuple[list[Check], dict[str, float]]:
    """A camera against the true camera.

    Each of :data:`TRUTH_PARAMS` must lie within ``sigmas`` of its stated standard deviation (a missing or zero sigma
    fails), and, when ``rms_px`` is given, the RMS projection difference over the imager (implied rotation fitted,
    :func:`~circcal.analysis.compare.projection_diff`) within it.

    Parameters
    ----------
    who : str
        The solver, as the checks' names show it.
    camera : circcal.model.Camera
        The estimate.
    std : dict of str to float, or None
        Its standard deviations by parameter name (px for fx, fy, cx, cy).
    truth : circcal.model.Camera
        The true camera.
    sigmas : float
        Bound on |estimate - truth| / sigma.
    rms_px : float, optional
        Bound on the RMS projection difference, px; no such check when None.
    std_note : str
        Appended to each note after the sigma (e.g. where the sigmas came from).

    Returns
    -------
    checks : list of Check
        One per parameter, then the projection check when asked.
    measured : dict of str to float
        Every number measured, for the tables: ``fx_sigmas`` ... ``cy_sigmas`` (signed), ``truth_rms_px``,
        ``truth_max_px``.
    """
    checks, measured = [], {}
    pd = param_diff(truth, camera, None, std)
    for n in TRUTH_PARAMS:
        v = abs(pd[n]["diff_sigmas"])
        note = (
            f"{n} {pd[n]['b']:.4f} vs true {pd[n]['a']:.4f} (diff {pd[n]['diff']:+.4f}, sigma "
            f"{pd[n]['sigma']:.3g}{std_note})"
        )
        checks.append(
            Check(f"{who} {n} vs truth, in stated sigmas", v, sigmas, bool(np.isfinite(v) and v <= sigmas), note)
        )
        measured[f"{n}_sigmas"] = float(pd[n]["diff_sigmas"])
    fit = projection_diff(truth, camera, fit=True)
    measured["truth_rms_px"], measured["truth_max_px"] = fit["rms_px"], fit["max_px"]
    if rms_px is not None:
        v = fit["rms_px"]
        checks.append(
            Check(
                f"{who} vs truth: RMS projection difference (rotation fitted), px",
                v,
                rms_px,
                bool(np.isfinite(v) and v <= rms_px),
                f"max {fit['max_px']:.4f} px",
            )
        )
    return checks, measured
