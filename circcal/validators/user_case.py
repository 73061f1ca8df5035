"""A calibrator under test (``--calibrator``) on one conformance case: the lens model and holds it declares, circcal's
solve under that same model on the same observations, and the case's checks against both and the truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from circcal.analysis.compare import projection_diff
from circcal.errors import CalibrationError
from circcal.model import Camera, param_names
from circcal.validators.base import camera_size_problem
from circcal.validators.case_matrix import Case, bounds_for, suite_truth_sigmas
from circcal.validators.case_run import Outcome
from circcal.validators.checks import SOLVER_PX, TRUTH_PARAMS, Check, solver_agreement, truth_checks
from circcal.validators.parameter_table import (
    format_parameter_table,
    largest_difference,
    parameter_table,
    stated_sigmas,
)
from circcal.validators.reference_protocol import ReferenceCalibrator
from circcal.validators.scenario_observations import Observations

#: Parameters a calibrator may not declare held: they have no default value to hold them at (a user's calibrator
#: and circcal's solve could hold them at different values).
UNHOLDABLE: tuple[str, ...] = ("fx", "fy")


def declared_model(cal: Any) -> tuple[str, tuple[str, ...]]:
    """The lens model a calibrator fits and the parameters it holds, as it declares them.

    A calibrator declares them with the attributes ``lens`` (a :data:`circcal.model.LENS_MODELS` name; default
    "opencv5") and ``fixes`` (names of :func:`circcal.model.param_names` of that lens, or ``"aspect_ratio"``,
    ``"tangential"``, ``"principal_point"``; default none), on the function or on the class. A held parameter is
    held at its default: 0 for a distortion coefficient, the image centre ((w-1)/2, (h-1)/2) for cx, cy, 1 for the
    aspect ratio (OpenCV's ``CALIB_FIX_*`` without an intrinsic guess).

    Parameters
    ----------
    cal : ReferenceCalibrator
        The calibrator (a :class:`~circcal.validators.user_calibrator.FunctionCalibrator` carries its function's
        declarations).

    Returns
    -------
    lens : str
    fixed : tuple of str
        Expanded and ordered as :class:`circcal.solver.CalibrationOptions` stores them.

    Raises
    ------
    ValueError
        An unknown lens model, a name the lens model does not have, fx or fy held, or ``fixes`` not a sequence of
        names; the message names the attribute.
    """
    from circcal.errors import InputError
    from circcal.solver import CalibrationOptions

    lens = getattr(cal, "lens", None) or "opencv5"
    fixes = getattr(cal, "fixes", ()) or ()
    if isinstance(fixes, str) or not all(isinstance(f, str) for f in fixes):
        raise ValueError(f"fixes = {fixes!r}: expected a tuple of parameter names such as ('k3',)")
    bad = [f for f in fixes if f in UNHOLDABLE]
    if bad:
        raise ValueError(f"fixes = {tuple(fixes)!r}: {bad[0]} cannot be held (it has no default value to hold it at)")
    try:
        options = CalibrationOptions(lens=str(lens), fixed=tuple(fixes))
    except InputError as exc:
        raise ValueError(f"lens = {lens!r}, fixes = {tuple(fixes)!r}: {exc}") from None
    return options.lens, options.fixed


def _held_default(name: str, camera: Camera) -> float:
    """The value a held parameter takes without an initial camera (see :func:`declared_model`)."""
    if name == "cx":
        return (camera.width - 1) / 2.0
    if name == "cy":
        return (camera.height - 1) / 2.0
    return 0.0


def model_start(camera: Camera, lens: str, fixed: Sequence[str]) -> Camera:
    """A camera in lens model ``lens`` with the held parameters at their defaults, the others from ``camera``.

    Parameters
    ----------
    camera : circcal.model.Camera
        A pinhole-family camera (its coefficients missing from ``lens`` are dropped, those ``lens`` adds are 0), or a
        fisheye with ``lens`` "fisheye".
    lens : str
        The target lens model.
    fixed : sequence of str
        Held parameters (names as :class:`circcal.solver.CalibrationOptions` takes them).

    Returns
    -------
    circcal.model.Camera
    """
    from circcal.solver import CalibrationOptions

    fixed = CalibrationOptions(lens=lens, fixed=tuple(fixed)).fixed
    values = dict(zip(param_names(camera.lens), camera.intrinsics))
    p = {n: float(values.get(n, 0.0)) for n in param_names(lens)}
    for n in fixed:
        if n in p:
            p[n] = _held_default(n, camera)
    if "aspect_ratio" in fixed:
        p["fx"] = p["fy"] = (p["fx"] + p["fy"]) / 2.0
    return Camera.from_intrinsics(camera.width, camera.height, np.array(list(p.values())), lens=lens)


def unrepresentable(truth: Camera, lens: str, fixed: Sequence[str]) -> str:
    """Why a lens model with held parameters cannot represent the true camera ("" when it can).

    Parameters
    ----------
    truth : circcal.model.Camera
        The true camera of a scenario.
    lens : str
        The model fitted.
    fixed : sequence of str
        Its held parameters (:func:`declared_model`).

    Returns
    -------
    str
        One line: a lens of the other family (fisheye / pinhole), a true coefficient the model lacks that is not 0, or
        a held parameter whose true value is not the value it is held at.
    """
    from circcal.model import lens_model
    from circcal.solver import CalibrationOptions

    if lens_model(lens).pinhole != truth.model.pinhole:
        return f"the true lens is {truth.lens}; the {lens} model cannot represent it"
    fixed = CalibrationOptions(lens=lens, fixed=tuple(fixed)).fixed
    names = param_names(lens)
    true = dict(zip(param_names(truth.lens), truth.intrinsics))
    extra = [f"{n} = {v:g}" for n, v in true.items() if n not in names and v != 0.0]
    if extra:
        return f"the true {truth.lens} lens has {', '.join(extra)}, which the {lens} model lacks"
    for n in fixed:
        if n in names:
            held, v = _held_default(n, truth), float(true.get(n, 0.0))
            if abs(v - held) > 1e-9 * max(1.0, abs(held)):
                return f"the true {n} is {v:g}; the calibrator holds it at {held:g}"
    if "aspect_ratio" in fixed and true["fx"] != true["fy"]:
        return f"the true fx / fy is {true['fx'] / true['fy']:.6g}; the calibrator holds it at 1"
    return ""


def restricted_solve(
    obs: Observations, lens: str, fixed: Sequence[str], left_out: dict | None = None
) -> tuple[Camera, dict[str, float], float]:
    """circcal's solver on a case's shared observations with a calibrator's declared model.

    Started from circcal's solve converted to that model (:func:`model_start`); the solve of the scenario's own model
    without holds is the observations' own (no second solve). Cached per process.

    Parameters
    ----------
    obs : Observations
        An ok observation set.
    lens : str
        The lens model.
    fixed : sequence of str
        The held parameters.
    left_out : dict, optional
        View (int or its str) -> indices of points the calibrator left out.

    Returns
    -------
    camera : circcal.model.Camera
    std : dict of str to float
        Its standard deviations (0 for a held parameter).
    ssr : float
        Its sum of squared residuals, px^2.
    """
    from circcal.solver import CalibrationOptions, calibrate
    from circcal.validators.shared import ssr

    fixed = CalibrationOptions(lens=lens, fixed=tuple(fixed)).fixed
    if lens == obs.lens and not fixed and not left_out:
        return obs.solver_camera, dict(obs.solver_std or {}), obs.solver_ssr
    key = (lens, fixed, repr(sorted((str(k), list(v)) for k, v in (left_out or {}).items())))
    cache = obs.__dict__.setdefault("_restricted", {})  # per observation set (obs is cached per session)
    if key not in cache:
        keep = []
        for v, o in enumerate(obs.object_points):
            m = np.ones(len(o), bool)
            m[list((left_out or {}).get(v, (left_out or {}).get(str(v), [])))] = False
            keep.append(m)
        res = calibrate(
            [o[m] for o, m in zip(obs.object_points, keep)],
            [q[m] for q, m in zip(obs.image_points, keep)],
            obs.image_size,
            CalibrationOptions(lens=lens, fixed=fixed),
            initial=model_start(obs.solver_camera, lens, fixed),
        )
        cache[key] = (res.camera, dict(res.std), ssr(res.residuals))
    return cache[key]


def run_user_case(
    case: Case,
    obs: Observations,
    calibrator: ReferenceCalibrator,
    *,
    solver_px: float | None = None,
    allow_unavailable: bool = False,
) -> Outcome:
    """A calibrator under test (``--calibrator``) on circcal's observations of a case's scenario-variant.

    It is compared with circcal's solver under the same model (:func:`declared_model`, :func:`restricted_solve`) and
    with the truth. Statuses: "checked" (its checks asserted), "unsupported" (the declared model cannot represent the
    true camera, :func:`unrepresentable`, or the calibrator raised ``NotImplementedError``: ``skip_reason`` says
    why), "unavailable" (``available()`` said no: a failed check unless ``allow_unavailable``, then a skip), "skip"
    (circcal has no observations). An exception of the calibrator is a failed check whose note holds the traceback.
    ``params`` holds :func:`parameter_table`.

    Parameters
    ----------
    case : Case
        A user case.
    obs : Observations
        :func:`~circcal.validators.scenario_observations.observe`'s result for its scenario-variant.
    calibrator : ReferenceCalibrator
        The calibrator.
    solver_px : float, optional
        The agreement bound with circcal's solver, px (default :data:`~circcal.validators.checks.SOLVER_PX`; ``inf``: measured only).
    allow_unavailable : bool
        An unavailable calibrator is skipped instead of failed.

    Returns
    -------
    Outcome
    """
    out = Outcome(case, "checked")
    name = getattr(calibrator, "name", case.reference)
    try:
        ok, why = calibrator.available()
    except Exception as exc:  # noqa: BLE001  (the user's code: reported, with its traceback)
        import traceback

        ok, why = False, f"available() raised {type(exc).__name__}: {exc}\n{traceback.format_exc()}"
    if not ok:
        out.status = "unavailable"
        if allow_unavailable:
            out.skip_reason = f"{name} unavailable (allowed by --allow-unavailable): {why}"
        else:
            out.checks.append(
                Check(f"{name} is available", 0.0, 1.0, False, f"{why} (--allow-unavailable skips such cases)")
            )
        return out
    if not obs.ok:
        out.status = "skip"
        out.skip_reason = f"no observations: circcal did not calibrate {case.scenario}-{case.variant}"
        return out
    lens, fixed = declared_model(calibrator)
    why = unrepresentable(obs.truth, lens, fixed)
    if why:
        out.status, out.skip_reason = "unsupported", f"{name} ({_model_words(lens, fixed)}): {why}"
        return out
    # copies: a calibrator that changes its arguments in place must not change the observations the next one gets
    res = calibrator.calibrate_observations(
        [o.copy() for o in obs.object_points], [p.copy() for p in obs.image_points], obs.image_size, mode=case.mode
    )
    out.result = res
    out.measured["time_s"] = float(res.time_s)
    label = f"{res.name} {res.version} [{_model_words(lens, fixed)}]"
    if res.status == "unsupported":
        out.status, out.skip_reason = "unsupported", f"{label} says: {res.message}"
        return out
    if res.status == "unavailable":
        out.status = "unavailable"
        if allow_unavailable:
            out.skip_reason = f"{label} unavailable (allowed by --allow-unavailable): {res.message}"
        else:
            out.checks.append(Check(f"{label} is available", 0.0, 1.0, False, res.message))
        return out
    note = f"status {res.status}: {res.message}"
    if res.status == "failed" and (res.extra or {}).get("traceback"):
        note += "\n" + str(res.extra["traceback"]).rstrip()
    out.checks.append(Check(f"{label} runs", float(res.ok), 1.0, res.ok, note))
    if not res.ok:
        out.status = "failed"
        return out
    problem = _result_problem(res, lens, fixed, obs.image_size)
    if problem:
        out.status = "failed"
        out.checks.append(Check(f"{label} returns a usable result", 0.0, 1.0, False, problem))
        return out
    left_out = (res.extra or {}).get("left_out") or {}
    try:
        circ_cam, circ_std, circ_ssr = restricted_solve(obs, lens, fixed, left_out)
    except CalibrationError as exc:  # these observations do not determine the declared model: nothing to compare with
        out.status = "unsupported"
        out.skip_reason = (
            f"circcal's solve under the same model ({_model_words(lens, fixed)}), which {label} is compared with, "
            f"fails on these observations: {exc}"
        )
        return out
    res_fitted = res
    if left_out:
        from dataclasses import replace

        keep = {int(k): set(v) for k, v in left_out.items()}
        res_fitted = replace(
            res,
            residuals=None
            if res.residuals is None
            else [np.delete(r, sorted(keep.get(i, ())), axis=0) for i, r in enumerate(res.residuals)],
        )
        out.notes.append(f"{label} left out {sum(map(len, left_out.values()))} observations; compared on the rest")
    std, from_circcal, std_notes = stated_sigmas(res.std, lens, fixed, circ_std)
    out.notes += std_notes
    table = parameter_table(res.camera, std, circ_cam, circ_std, obs.truth)
    out.params = table
    vs = projection_diff(circ_cam, res.camera, fit=False)
    out.measured["vs_circcal_max_px"] = vs["max_px"]
    if "mean_2d_px" in (res.errors or {}):
        out.measured["mean_2d_px"] = float(res.errors["mean_2d_px"])
    circ_truth = [n for n in TRUTH_PARAMS if n in from_circcal]
    std_note = f"; circcal's on the same observations and model for {', '.join(circ_truth)}" if circ_truth else ""
    found, measured = truth_checks(
        res.name,
        res.camera,
        std,
        obs.truth,
        sigmas=suite_truth_sigmas(),
        rms_px=bounds_for(case.scenario).truth_px_for(case.variant),
        std_note=std_note,
    )
    out.measured.update(measured)
    out.checks += found
    bound = SOLVER_PX if solver_px is None else solver_px
    if np.isfinite(bound):
        check = solver_agreement(label, res_fitted, vs["max_px"], circ_ssr, bound)
        check.name = f"{label} vs circcal's solve ({_model_words(lens, fixed)}) on identical observations: max px"
        check.note = "; ".join(x for x in (largest_difference(table), f"RMS {vs['rms_px']:.3g} px", check.note) if x)
        out.checks.append(check)
    out.notes += format_parameter_table(table)
    return out


def _result_problem(res: Any, lens: str, fixed: Sequence[str], image_size: tuple[int, int]) -> str:
    """What makes an "ok" result of a calibrator under test unusable, in one line ("" when nothing): a camera of
    another lens model or image size, or a ``std`` that is not a dict of finite numbers >= 0."""
    if not isinstance(res.camera, Camera):
        return f"the returned camera is a {type(res.camera).__name__}; expected circcal.model.Camera"
    if res.camera.lens != lens:
        return f"it returned a {res.camera.lens} camera; it declares lens = {lens!r}"
    problem = camera_size_problem(res.camera, image_size)
    if problem:
        return problem
    try:
        stated_sigmas(res.std, lens, fixed, None)
    except ValueError as exc:
        return str(exc)
    return ""


def _model_words(lens: str, fixed: Sequence[str]) -> str:
    return lens + (f", {', '.join(fixed)} held" if fixed else "")
