"""Running one conformance case and its checks: circcal's own case and a reference's, on circcal's observations of
the case's scenario-variant (:func:`~circcal.validators.scenario_observations.observe`), as an :class:`Outcome`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from circcal.analysis.compare import projection_diff
from circcal.detector import Reason
from circcal.model import Camera, param_names
from circcal.validators.case_matrix import (
    CENTRE_MAX_PX,
    CIRCCAL_UNSUPPORTED,
    EXPECTED_UNSUPPORTED,
    MAY_REJECT_ALL,
    UNSUPPORTED_LAYOUTS,
    USES_PARTIAL_VIEWS,
    Case,
    bounds_for,
    suite_truth_sigmas,
)
from circcal.validators.checks import Check, solver_agreement, solver_bound, truth_checks
from circcal.validators.lens_support import lens_support
from circcal.validators.reference_protocol import ReferenceCalibrator
from circcal.validators.reference_result import ReferenceResult
from circcal.validators.scenario_observations import Observations, solve_subset


@dataclass
class Outcome:
    """What one case found.

    Attributes
    ----------
    case : Case
        The case.
    status : str
        "checked" (every check asserted), "unsupported" (an expected refusal, asserted as such), "measured" (numbers
        printed, only that it ran asserted), "rejected" (circcal rejected every view where that is allowed), "skip"
        (``skip_reason`` says why: no observations, or a user calibrator that does not support the scenario).
    checks : list of Check
        What a test asserts.
    measured : dict of str to float
        Numbers printed, not asserted.
    notes : list of str
        Lines printed with the case.
    result : ReferenceResult or None
        The reference's result, for a reference case.
    skip_reason : str
        Why the case was skipped.
    params : dict
        A calibrator under test's :func:`~circcal.validators.parameter_table.parameter_table` (empty otherwise).
    passed : bool
        Every check passed.
    """

    case: Case
    status: str
    checks: list[Check] = field(default_factory=list)
    measured: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    result: ReferenceResult | None = None
    skip_reason: str = ""
    params: dict[str, dict[str, float]] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)


def failed_checks(outcome: Outcome) -> list[Check]:
    """The checks of a case that failed.

    Parameters
    ----------
    outcome : Outcome

    Returns
    -------
    list of Check
    """
    return [c for c in outcome.checks if not c.passed]


def _accounting(obs: Observations) -> Check:
    codes = {r.value for r in Reason} | {"used"}
    missing = [Path(p).name for p in obs.paths if obs.accounted.get(p) not in codes]
    overlap = sorted(Path(r.path).name for r in obs.failed if obs.accounted.get(r.path) == "used")
    n_used = sum(1 for v in obs.accounted.values() if v == "used")
    note = f"{n_used} used, {len(obs.accounted) - n_used} rejected with a reason, of {len(obs.paths)}"
    if missing:
        note += f"; not accounted for: {', '.join(missing)}"
    if overlap:
        note += f"; both used and rejected: {', '.join(overlap)}"
    return Check(
        "every image accounted for (used, or rejected with a reason code): images unaccounted",
        float(len(missing) + len(overlap)),
        0.0,
        not missing and not overlap,
        note,
    )


def predicted_truth_rms(
    camera: Camera, std: dict[str, float], correlation: np.ndarray | None, *, n: int = 200, seed: int = 0
) -> dict[str, float]:
    """What the stated covariance predicts for the RMS projection difference to the truth.

    ``n`` cameras drawn from N(camera, covariance) are compared with ``camera`` (rotation fitted, as in the truth
    check); draws that are not a valid camera are dropped. Printed beside the measured value, not asserted.

    Parameters
    ----------
    camera : circcal.model.Camera
        The estimate.
    std : dict of str to float
        Standard deviations by :func:`circcal.model.param_names` name (a missing one counts as 0).
    correlation : ndarray, shape (P, P), or None
        Parameter correlation matrix; None: uncorrelated.
    n : int
        Number of draws.
    seed : int
        Random seed.

    Returns
    -------
    dict of str to float
        ``{"p50", "p95", "p99"}`` in px (NaN when no draw is valid).
    """
    names = param_names(camera.lens)
    sd = np.array([float(std.get(k, 0.0) or 0.0) for k in names])
    corr = np.eye(len(names)) if correlation is None else np.nan_to_num(np.asarray(correlation, dtype=np.float64))
    cov = corr * np.outer(sd, sd)
    rng = np.random.default_rng(seed)
    draws = rng.multivariate_normal(camera.intrinsics, cov, size=n, method="eigh")
    rms = []
    for p in draws:
        try:
            other = Camera.from_intrinsics(camera.width, camera.height, p, lens=camera.lens)
        except ValueError:
            continue
        rms.append(projection_diff(camera, other, fit=True)["rms_px"])
    r = np.asarray(rms)
    r = r[np.isfinite(r)]
    if not r.size:
        return {"p50": float("nan"), "p95": float("nan"), "p99": float("nan")}
    return {f"p{q}": float(np.percentile(r, q)) for q in (50, 95, 99)}


def run_circcal_case(case: Case, obs: Observations) -> Outcome:
    """circcal's own case on its observations.

    Checks: every image accounted for; a refusal naming the cause for a scenario in :data:`CIRCCAL_UNSUPPORTED`;
    every partial view used (:data:`USES_PARTIAL_VIEWS`); fx, fy, cx, cy within :func:`suite_truth_sigmas`; the RMS
    projection difference to the truth within the scenario's ``truth_px``; the mean 2-D error within ``mean_2d_px``;
    every final centre within :data:`CENTRE_MAX_PX` of its true projection.

    Parameters
    ----------
    case : Case
        A case whose reference is ``"circcal"``.
    obs : Observations
        :func:`~circcal.validators.scenario_observations.observe`'s result for its scenario-variant.

    Returns
    -------
    Outcome
    """
    b = bounds_for(case.scenario)
    out = Outcome(case, "checked")
    out.measured["circcal_time_s"] = obs.time_s
    if case.scenario in CIRCCAL_UNSUPPORTED:
        word = CIRCCAL_UNSUPPORTED[case.scenario]
        refused = (not obs.ok) and word in obs.message.lower()
        out.status = "unsupported"
        out.checks.append(
            Check(
                f"circcal refuses a {word} with a reason naming it",
                float(refused),
                1.0,
                refused,
                " / ".join(obs.message.splitlines()[:2]).strip() if obs.message else "circcal calibrated it",
            )
        )
        return out
    out.checks.append(_accounting(obs))
    out.measured["images_used"] = float(sum(1 for v in obs.accounted.values() if v == "used"))
    out.measured["images"] = float(len(obs.paths))
    if not obs.ok:
        if (
            case.scenario in MAY_REJECT_ALL
            and obs.accounted
            and all(v != "used" for v in obs.accounted.values())
            and len(obs.accounted) == len(obs.paths)
        ):
            out.status = "rejected"
            out.notes.append(
                f"circcal rejected every view of {case.scenario}-{case.variant}, each with a reason "
                f"(allowed here); no calibration to check: {obs.message.splitlines()[0]}"
            )
            for r in obs.failed:
                out.notes.append(f"  {Path(r.path).name}: {r.code.value}: {r.reason}")
            return out
        out.checks.append(Check("circcal calibrates", float("nan"), float("nan"), False, obs.message))
        return out
    if case.scenario in USES_PARTIAL_VIEWS:
        n_used = sum(1 for v in obs.accounted.values() if v == "used")
        sizes = sorted({len(p) for p in obs.image_points or []})
        out.checks.append(
            Check(
                "circcal uses every partial view: views left out",
                float(len(obs.paths) - n_used),
                0.0,
                n_used == len(obs.paths),
                f"{n_used} of {len(obs.paths)} used, {sizes[0] if sizes else 0}-"
                f"{sizes[-1] if sizes else 0} of {obs.board.n_points} points per view",
            )
        )
    bound = b.truth_px_for(case.variant)
    checks, measured = truth_checks(
        "circcal", obs.camera, obs.std, obs.truth, sigmas=suite_truth_sigmas(), rms_px=bound
    )
    pred = predicted_truth_rms(obs.camera, obs.std, obs.correlation)
    checks[-1].note += (
        f"; the stated covariance predicts p50 {pred['p50']:.4f}, p99 {pred['p99']:.4f} px "
        f"(bound {bound:g}: {b.reason})"
    )
    out.checks += checks
    out.measured.update(measured)
    out.measured["truth_rms_pred_p99_px"] = pred["p99"]
    m2 = obs.errors["mean_2d_px"]
    out.checks.append(
        Check(
            "circcal mean 2-D reprojection error (the paper's convention), px",
            m2,
            b.mean_2d_px,
            bool(m2 <= b.mean_2d_px),
            f"rms per point {obs.errors['rms_per_point_px']:.4f} px (OpenCV's), per coordinate "
            f"{obs.errors['rms_per_coord_px']:.4f} px (mrcal's)",
        )
    )
    ce = obs.centre_errors if obs.centre_errors is not None else np.zeros(0)
    if ce.size:
        cmax = float(np.max(ce))
        out.checks.append(
            Check(
                "circcal final centres vs true projections: max, px",
                cmax,
                CENTRE_MAX_PX,
                cmax <= CENTRE_MAX_PX,
                f"RMS {float(np.sqrt(np.mean(ce**2))):.4f} px over {ce.size} points",
            )
        )
        out.measured["centre_rms_px"] = float(np.sqrt(np.mean(ce**2)))
    out.measured["mean_2d_px"] = m2
    for r in obs.failed:
        out.notes.append(f"image rejected: {Path(r.path).name}: {r.code.value}: {r.reason}")
    return out


def run_reference_case(
    case: Case, obs: Observations, calibrator: ReferenceCalibrator, *, solver_px: float | None = None
) -> Outcome:
    """A reference (or user) calibrator on circcal's observations of a case's scenario-variant.

    Availability is the caller's business (a test skips or fails); an "unavailable" result here becomes a skip
    outcome. A "default" mode case is measured, not asserted; a reference that left observations out is compared with
    circcal's solve on the same subset.

    Parameters
    ----------
    case : Case
        The case.
    obs : Observations
        :func:`~circcal.validators.scenario_observations.observe`'s result for its scenario-variant.
    calibrator : ReferenceCalibrator
        The reference, set up for ``case.lens``.
    solver_px : float, optional
        The agreement bound with circcal's solver, px; default :func:`~circcal.validators.checks.solver_bound`
        (:data:`~circcal.validators.checks.SOLVER_PX`, lensboy ``SOLVER_LENSBOY_PX``, mrcal :data:`~circcal.validators.checks.SOLVER_MRCAL_PX`); ``float('inf')`` measures
        without asserting.

    Returns
    -------
    Outcome
    """
    out = Outcome(case, "checked")
    expect = EXPECTED_UNSUPPORTED.get((case.scenario, case.reference))
    if expect is None and case.reference in UNSUPPORTED_LAYOUTS and obs.board is not None:
        expect = UNSUPPORTED_LAYOUTS[case.reference].get(obs.board.layout)
    if not obs.ok:
        out.status = "skip"
        out.skip_reason = (
            f"no observations: circcal did not calibrate {case.scenario}-{case.variant} "
            f"({obs.message.splitlines()[0] if obs.message else 'failed'})"
        )
        return out
    supported, why = lens_support(calibrator, case.lens)
    if not supported:
        return _lens_unsupported(case, obs, calibrator, why)
    res = calibrator.calibrate_observations(obs.object_points, obs.image_points, obs.image_size, mode=case.mode)
    out.result = res
    out.measured["time_s"] = float(res.time_s)
    label = f"{res.name} {res.version} [{res.mode}]"
    if expect is not None:
        ok = res.status == "unsupported" and expect in (res.message or "").lower()
        out.status = "unsupported"
        out.checks.append(
            Check(
                f"{label} reports {case.scenario} unsupported, naming '{expect}'",
                float(ok),
                1.0,
                ok,
                f"status {res.status}: {res.message}",
            )
        )
        return out
    if res.status == "unavailable":
        out.status, out.skip_reason = "skip", f"{label} unavailable: {res.message}"
        return out
    if res.status == "unsupported" and case.user:
        out.status, out.skip_reason = "skip", f"{label} does not support {case.scenario}: {res.message}"
        return out
    out.checks.append(Check(f"{label} runs", float(res.ok), 1.0, res.ok, f"status {res.status}: {res.message}"))
    if not res.ok:
        return out
    circcal_camera, circcal_ssr, res_fitted = obs.solver_camera, obs.solver_ssr, res
    left_out = res.extra.get("left_out") or {}
    if left_out:  # the reference fitted a subset of the observations: circcal's solve on that same subset
        circcal_camera, circcal_ssr, res_fitted = solve_subset(obs, res, left_out)
        n_left = sum(map(len, left_out.values()))
        out.notes.append(
            f"{label} left out {n_left} observations ({res.extra.get('note', '')}); compared with "
            "circcal's solve on the same subset"
        )
    vs_circcal = projection_diff(circcal_camera, res_fitted.camera, fit=False)
    out.measured["vs_circcal_max_px"] = vs_circcal["max_px"]
    errors = res.errors or {}
    if "mean_2d_px" in errors:
        out.measured["mean_2d_px"] = float(errors["mean_2d_px"])
    b = bounds_for(case.scenario)
    std, std_note = res.std, ""
    if not std or not all(np.isfinite(std.get(n, np.nan)) and std.get(n, 0) > 0 for n in ("fx", "fy", "cx", "cy")):
        std, std_note = obs.solver_std, "; circcal's on the same observations"
    found_checks, measured = truth_checks(
        res.name,
        res.camera,
        std,
        obs.truth,
        sigmas=suite_truth_sigmas(),
        rms_px=b.truth_px_for(case.variant),
        std_note=std_note,
    )
    out.measured.update(measured)
    if case.mode == "default":
        out.status = "measured"
        out.notes.append(f"{label} is a different estimator: its differences are measured and printed, not asserted")
        for c in found_checks:
            out.notes.append(f"  measured: {c.name}: {c.value:.4g} ({c.note})")
        return out
    out.checks += found_checks
    if solver_px is None:
        solver_px = solver_bound(case.reference)
    if np.isfinite(solver_px):
        check = solver_agreement(label, res_fitted, vs_circcal["max_px"], circcal_ssr, solver_px)
        check.note = "; ".join(x for x in (f"RMS {vs_circcal['rms_px']:.3g} px", check.note) if x)
        out.checks.append(check)
    return out


def _lens_unsupported(case: Case, obs: Observations, calibrator: ReferenceCalibrator, why: str) -> Outcome:
    """A reference on a lens model it does not fit. Set up for that lens (``calibrator.lens``), it must answer
    "unsupported" with a reason itself; otherwise (a plug-in that declares no such model) it is not called and the
    case reports ``why``. A user calibrator's case is skipped with the reason."""
    out = Outcome(case, "unsupported")
    name = getattr(calibrator, "name", case.reference)
    if case.user:
        out.status, out.skip_reason = "skip", f"{name} does not fit lens {case.lens}: {why}"
        return out
    if getattr(calibrator, "lens", None) != case.lens:
        out.checks.append(Check(f"{name} declares lens {case.lens} unsupported", 1.0, 1.0, True, why))
        return out
    res = calibrator.calibrate_observations(obs.object_points, obs.image_points, obs.image_size, mode=case.mode)
    out.result = res
    ok = res.status == "unsupported" and bool((res.message or "").strip())
    out.checks.append(
        Check(
            f"{res.name} [{res.mode}] reports lens {case.lens} unsupported with a reason",
            float(ok),
            1.0,
            ok,
            f"status {res.status}: {res.message}",
        )
    )
    return out
