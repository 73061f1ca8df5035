"""One validation run: circcal and the reference calibrators on the same work, each against ground truth and
against circcal, with the agreement checks that ``circcal validate`` gates on.

Reprojection errors are reported in all three conventions (keys name them: ``rms_per_point_px`` = OpenCV's RMS,
``rms_per_coord_px`` = mrcal's, ``mean_2d_px`` = the paper's). Projection differences are RMS / max over a 60-wide
pixel grid of the first model, with the implied rotation fitted (as ``mrcal.projection_diff``) unless a key says
``nofit``.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from circcal.analysis.compare import GRID_WIDTH, param_diff, projection_diff
from circcal.board import Board
from circcal.errors import InputError
from circcal.formatting import fmt_number
from circcal.imagefiles import image_list
from circcal.jsonio import jsonable
from circcal.model import DEFAULT_LENS, Camera, param_names
from circcal.solver import CalibrationOptions
from circcal.validators import registry
from circcal.validators.checks import (
    SOLVER_LENSBOY_PX,
    SOLVER_MRCAL_PX,
    SOLVER_PX,
    TRUTH_SIGMAS,
    Check,
    solver_agreement,
    truth_checks,
)
from circcal.validators.lens_support import lens_support
from circcal.validators.reference_result import ReferenceResult
from circcal.validators.shared import SharedObservations, share

__all__ = ["Bounds", "ValidationRun", "run_validation", "format_table", "verdict", "write_report", "VERDICTS"]

#: What a run found, for :func:`verdict`: a check failed; every check passed (at least one); results were compared
#: but none is gated (nothing failed, nothing was checked: own detectors, default mode only); nothing compared.
VERDICTS: tuple[str, ...] = ("failed", "passed", "not gated", "nothing compared")


@dataclass(frozen=True)
class Bounds:
    """Agreement bounds of a validation run.

    Parameters
    ----------
    solver : float
        A reference in ``fair`` mode on circcal's observations vs circcal's solve, max projection difference, px.
    solver_mrcal : float
        The same for mrcal (its solver stops earlier), px.
    truth_sigmas : float
        circcal's fx, fy, cx, cy within this many of their stated sigmas of the true camera.
    truth : float, optional
        If set, also bound circcal's RMS projection difference to the true camera (implied rotation fitted), px. Off
        by default: with a long lens the focal length is weakly observable (std(fx) 0.3 px at fx 4900 even from exact
        centres with 0.003 px noise), which alone moves the image edge by ~0.05 px, so a fixed px bound would test the
        fixture geometry, not the calibrator.
    solver_lensboy : float
        The same as ``solver`` for lensboy (its solver stops earlier still), px.

    Raises
    ------
    circcal.errors.InputError
        A bound that is not a finite positive number (NaN, inf, 0 or less would make its check pass or fail
        regardless of the result); ``truth`` may be None.
    """

    solver: float = SOLVER_PX
    solver_mrcal: float = SOLVER_MRCAL_PX
    truth_sigmas: float = TRUTH_SIGMAS
    truth: float | None = None
    solver_lensboy: float = SOLVER_LENSBOY_PX

    def __post_init__(self) -> None:
        for name in ("solver", "solver_mrcal", "solver_lensboy", "truth_sigmas", "truth"):
            v = getattr(self, name)
            if v is None and name == "truth":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise InputError(
                    f"the {name} bound must be a finite positive number, got {v!r} (a bound of NaN, "
                    f"inf, 0 or less would make its check pass or fail regardless of the result)"
                )


@dataclass
class ValidationRun:
    """Everything one validation run found.

    Attributes
    ----------
    source : dict
        Where the images came from (``{"images": [...]}`` or the fixture's name and variant).
    board : circcal.board.Board
    image_size : tuple of int
        (width, height) px.
    truth : circcal.model.Camera or None
        The true camera, when known.
    circcal : dict
        circcal's calibration: status, message, camera, std, errors, time_s, failed, rounds (and, when ok, n_views,
        converged, solver_camera, solver_ssr).
    references : list of ReferenceResult
        One per reference and mode.
    comparisons : list of dict
        One per calibrator row (circcal first): ``vs_truth`` and ``vs_circcal`` projection differences (px) and
        parameter differences.
    checks : list of Check
        What the run gates on.
    observations : str
        "circcal" or "own".
    shared : SharedObservations or None
        What every reference fitted (circcal's centres rounded to float32) and circcal's solver on exactly those.
    skipped : list of str
        References that were not available and were allowed to be missing (``allow_missing``), with the reason.
    lens : str
        The lens model every calibrator fitted (:data:`circcal.model.LENS_MODELS`).
    hints : list of str
        Why no truth or reference check ran, each with the command-line option that would run one (empty when one
        did).
    passed : bool
        Every check passed, and there was at least one.
    """

    source: dict[str, Any]
    board: Board
    image_size: tuple[int, int]
    truth: Camera | None
    circcal: dict[str, Any]  # status, message, camera, std, errors, time_s, failed, rounds
    references: list[ReferenceResult]
    comparisons: list[dict[str, Any]]  # one per calibrator row (circcal first)
    checks: list[Check] = field(default_factory=list)
    observations: str = "circcal"
    #: what every reference fitted (circcal's centres rounded to float32) and circcal's solver on exactly those
    shared: SharedObservations | None = None
    #: references that were not available and were allowed to be missing (``allow_missing``), with the reason
    skipped: list[str] = field(default_factory=list)
    #: the lens model every calibrator fitted (:data:`circcal.model.LENS_MODELS`)
    lens: str = "opencv5"
    #: why no truth or reference check ran, naming the command-line options that would run one
    hints: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        """Every check passed, and there was at least one."""
        return bool(self.checks) and all(c.passed for c in self.checks)

    @property
    def state(self) -> str:
        """One of :data:`VERDICTS`: "failed", "passed", "not gated" (no check, but circcal and at least one reference
        or the truth gave results the table compares) or "nothing compared"."""
        if any(not c.passed for c in self.checks):
            return "failed"
        if self.checks:
            return "passed"
        compared = self.circcal.get("status") == "ok" and (self.truth is not None or any(r.ok for r in self.references))
        return "not gated" if compared else "nothing compared"

    @property
    def images(self) -> tuple[int, int]:
        """(usable, given): the images that gave circcal a view, of those given (0, given when circcal failed)."""
        n = int(self.circcal.get("n_images", len(self.source.get("images", [])) or 0))
        return int(self.circcal.get("n_views", 0) if self.circcal.get("status") == "ok" else 0), n


def _compare(
    name: str, camera: Camera | None, std: dict | None, truth: Camera | None, circcal_cam: Camera | None
) -> dict[str, Any]:
    row: dict[str, Any] = {"name": name}
    if camera is None:
        return row
    if truth is not None:
        fit = projection_diff(truth, camera, fit=True)
        raw = projection_diff(truth, camera, fit=False)
        row["vs_truth"] = {
            "rms_px": fit["rms_px"],
            "max_px": fit["max_px"],
            "nofit_rms_px": raw["rms_px"],
            "nofit_max_px": raw["max_px"],
            "params": param_diff(truth, camera, None, std),
        }
    if circcal_cam is not None:
        raw = projection_diff(circcal_cam, camera, fit=False)
        fit = projection_diff(circcal_cam, camera, fit=True)
        row["vs_circcal"] = {
            "max_px": raw["max_px"],
            "rms_px": raw["rms_px"],
            "fit_max_px": fit["max_px"],
            "fit_rms_px": fit["rms_px"],
        }
    return row


#: What :func:`run_validation` runs each reference in: its ``fair`` mode, its ``default`` one, or both.
RUN_MODES: tuple[str, ...] = ("fair", "default", "both")
RunMode = Literal["fair", "default", "both"]
#: Whose centres the references fit: circcal's final ones, or each reference's own detector's.
OBSERVATIONS: tuple[str, ...] = ("circcal", "own")
ObservationSource = Literal["circcal", "own"]


def run_validation(
    paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    board: Board,
    options: CalibrationOptions | None = None,
    *,
    truth: Camera | None = None,
    against: Sequence[str] = ("all",),
    mode: RunMode = "both",
    observations: ObservationSource = "circcal",
    bounds: Bounds = Bounds(),
    progress: bool = True,
    source: dict[str, Any] | None = None,
    allow_missing: bool = False,
    min_images: int | float | None = None,
) -> ValidationRun:
    """Calibrate images with circcal, then with each reference, and compare.

    Never raises for a reference's failure: it becomes a row. :attr:`ValidationRun.passed` is false when a check
    fails and when nothing was checked (a gate that cannot pass vacuously); :attr:`ValidationRun.state` tells the
    two apart ("failed"; "not gated" or "nothing compared", with :attr:`ValidationRun.hints` naming the options that
    would check something). A reference that is not available fails the run: asked for by name, or, under "all", a
    built-in reference (``make setup`` installs every one), unless ``allow_missing`` (then each one missing is
    listed as skipped).

    Parameters
    ----------
    paths : str, Path, or iterable of them
        Image files, or a folder standing for its images (:func:`circcal.imagefiles.image_list`).
    board : circcal.board.Board
        The calibration target.
    options : CalibrationOptions, optional
        How circcal calibrates (:class:`~circcal.solver.options.CalibrationOptions`); default: the defaults for the
        true camera's lens model, else ``opencv5``. ``options.lens`` is the lens model circcal and every reference fit;
        a reference that does not fit it is a row with status "unsupported" and its reason (no check: nothing to
        compare). A held k3 (``"k3" in options.fixed``) is held by the references that can (opencv, kornia).
    truth : circcal.model.Camera, optional
        The true camera (a fixture's); adds the truth checks.
    against : sequence of str
        Reference names; "all" = every registered one.
    mode : {"fair", "default", "both"}
        Which estimators to run (a reference with one estimator runs once).
    observations : {"circcal", "own"}
        "circcal": every reference gets circcal's final centres; "own": a reference's own detector where it has one
        (the others report "unsupported").
    bounds : Bounds
        The agreement bounds.
    progress : bool
        Show circcal's progress.
    source : dict, optional
        Stored as :attr:`ValidationRun.source`; default ``{"images": paths}``.
    allow_missing : bool
        Let unavailable references be skipped instead of failing the run.
    min_images : int or float or None
        Fail the run (a check "images usable") when fewer images than this gave circcal a view: an int is a count
        (>= 1), a float a share of the images given (0 < share <= 1). None: no such check (the count is still
        reported).

    Returns
    -------
    ValidationRun

    Raises
    ------
    circcal.errors.InputError
        An unknown ``mode`` (:data:`RUN_MODES`), ``observations`` (:data:`OBSERVATIONS`) or reference name, a
        ``min_images`` that is neither a count >= 1 nor a share in (0, 1].

    Examples
    --------
    >>> run = run_validation(paths, board, against=["opencv"], truth=truth)  # doctest: +SKIP
    >>> run.passed  # doctest: +SKIP
    True
    """
    from circcal.pipeline import calibrate_images

    if observations not in OBSERVATIONS:
        raise InputError(f"observations must be one of {', '.join(OBSERVATIONS)}, got {observations!r}")
    if mode not in RUN_MODES:
        raise InputError(f"mode must be one of {', '.join(RUN_MODES)}, got {mode!r}")
    _check_min_images(min_images)
    names = registry.names() if "all" in against else list(dict.fromkeys(against))
    for n in names:
        if n not in registry.names():
            raise InputError(f"unknown reference calibrator {n!r}; known: {', '.join(registry.names())}, all")
    paths = image_list(paths)
    if options is None:
        options = CalibrationOptions(lens=truth.lens if truth is not None else DEFAULT_LENS)
    lens = options.lens
    fix_k3 = options.holds("k3")

    t0 = time.perf_counter()
    cc: dict[str, Any] = {"status": "ok", "message": "", "camera": None, "n_images": len(paths)}
    shared: SharedObservations | None = None
    image_size = (truth.width, truth.height) if truth is not None else None
    try:
        cal = calibrate_images(paths, board, options, progress=progress, image_size=image_size)
    except InputError as exc:
        cc.update(status="failed", message=str(exc))
    else:
        res = cal.result
        shared = share(cal, board, options)
        image_size = shared.image_size
        cc.update(
            camera=res.camera,
            std=res.std,
            errors=res.errors,
            failed=cal.failed,
            rounds=cal.rounds,
            n_views=len(cal.used),
            converged=res.converged,
            solver_camera=shared.result.camera,
            solver_ssr=shared.ssr,
        )
    cc["time_s"] = time.perf_counter() - t0
    if image_size is None:
        import cv2

        im = cv2.imread(paths[0], cv2.IMREAD_UNCHANGED)
        image_size = (im.shape[1], im.shape[0]) if im is not None else (0, 0)

    modes = ("fair", "default") if mode == "both" else (mode,)
    refs: list[ReferenceResult] = []
    for n in names:
        try:
            cal_ref = registry.get_for_lens(
                n, lens, **({"fix_k3": True} if fix_k3 and n in ("opencv", "kornia") else {})
            )
        except Exception as exc:  # a plug-in that cannot load is a row, not a crash
            refs.append(ReferenceResult(n, "?", modes[0], "failed", f"{type(exc).__name__}: {exc}"))
            continue
        supported = tuple(m for m in modes if m in getattr(cal_ref, "modes", ("fair",))) or ("fair",)
        fits, why = lens_support(cal_ref, lens)
        if not fits and getattr(cal_ref, "lens", "opencv5") != lens:  # a plug-in without the model: not called
            refs += [ReferenceResult(n, cal_ref.version, m, "unsupported", why) for m in supported]
            continue
        if observations == "own":
            for m in supported:
                refs.append(cal_ref.calibrate_images(paths, board, image_size, mode=m))
            continue
        if shared is None:
            refs.append(
                ReferenceResult(
                    n,
                    cal_ref.version if cal_ref.available()[0] else "?",
                    supported[0],
                    "failed",
                    "no observations: circcal could not calibrate these images",
                )
            )
            continue
        obj, img = shared.object_points, shared.image_points
        if hasattr(cal_ref, "calibrate_modes") and len(supported) > 1:
            refs.extend(cal_ref.calibrate_modes(obj, img, image_size, modes=supported))
        else:
            for m in supported:
                refs.append(cal_ref.calibrate_observations(obj, img, image_size, mode=m))

    circ_cam = cc["camera"]
    comparisons = [{**_compare("circcal", circ_cam, cc.get("std"), truth, None), "status": cc["status"]}]
    for r in refs:
        # on identical observations compare with circcal's solver on those same (float32-rounded) points
        ref_cam = cc.get("solver_camera") if observations == "circcal" else circ_cam
        row = _compare(r.name, r.camera, r.std, truth, ref_cam)
        row.update(status=r.status, mode=r.mode)
        comparisons.append(row)

    checks: list[Check] = []
    skipped: list[str] = []
    if cc["status"] != "ok":
        checks.append(Check("circcal calibrates", float("nan"), float("nan"), False, cc["message"]))
    elif truth is not None:
        checks += truth_checks("circcal", circ_cam, cc["std"], truth, sigmas=bounds.truth_sigmas, rms_px=bounds.truth)[
            0
        ]
    for r, row in zip(refs, comparisons[1:]):
        label = f"{r.name} [{r.mode}]"
        if r.status == "failed":
            checks.append(Check(f"{label} runs", float("nan"), float("nan"), False, r.message))
        elif r.status == "unavailable":
            if allow_missing:
                skipped.append(f"{label}: {r.message}")
            elif "all" not in against or r.name in registry.BUILTINS:  # asked for, or installed by `make setup`
                checks.append(Check(f"{label} is available", float("nan"), float("nan"), False, r.message))
        elif r.ok and observations == "circcal" and r.mode == "fair" and "vs_circcal" in row:
            b = {"mrcal": bounds.solver_mrcal, "lensboy": bounds.solver_lensboy}.get(r.name, bounds.solver)
            checks.append(solver_agreement(label, r, row["vs_circcal"]["max_px"], cc["solver_ssr"], b))
    hints = [] if checks else _nothing_checked(truth, refs, observations, modes)
    if cc["status"] == "ok" and min_images is not None:
        need = _images_needed(min_images, len(paths))
        if cc["n_views"] < need:
            checks.append(
                Check(
                    "images usable",
                    float(cc["n_views"]),
                    float(need),
                    False,
                    f"{len(paths) - cc['n_views']} of {len(paths)} images unusable (each with its reason above); --min-images "
                    f"asks for at least {need}",
                )
            )
    return ValidationRun(
        source or {"images": paths},
        board,
        image_size,
        truth,
        cc,
        refs,
        comparisons,
        checks,
        observations,
        shared,
        skipped,
        lens,
        hints,
    )


def _check_min_images(v: int | float | None) -> None:
    """``min_images`` is None, a count >= 1 or a share in (0, 1]; else :class:`InputError`."""
    if v is None:
        return
    ok = not isinstance(v, bool) and (
        (isinstance(v, int) and v >= 1) or (isinstance(v, float) and math.isfinite(v) and 0.0 < v <= 1.0)
    )
    if not ok:
        raise InputError(
            f"min_images must be a count >= 1 or a share in (0, 1] of the images given, got {v!r} "
            f"(on the command line: --min-images 4 or --min-images 50%)"
        )


def _images_needed(v: int | float, n: int) -> int:
    """The image count ``min_images`` asks for out of ``n`` given."""
    return int(v) if isinstance(v, int) else max(1, math.ceil(v * n - 1e-9))


def _nothing_checked(
    truth: Camera | None, refs: Sequence[ReferenceResult], observations: str, modes: Sequence[str]
) -> list[str]:
    """Why a run checked nothing, each reason with the command-line option that would check something."""
    out = []
    if truth is None:
        out.append(
            "no ground truth (your own --images): the truth checks need a rendered scenario (`circcal validate "
            "SCENARIO`) or --fixtures FOLDER with truth.json"
        )
    if not refs:
        out.append("no reference was asked for: --against opencv,mrcal,... (or all)")
    elif observations == "own":
        out.append(
            "--observations own: each reference fits its own detector's centres, so its camera differs from "
            "circcal's by more than the solver bound; the table compares them, nothing is gated. "
            "--observations circcal (the default) checks every reference against circcal on the same centres"
        )
    elif "fair" not in modes:
        out.append(
            "--mode default: the references' own estimators (board warp, regularisation, outlier rejection) differ "
            "from circcal's, so they are compared, not gated; --mode fair or both checks them"
        )
    elif not any(r.ok for r in refs):
        out.append("no reference gave a result (see each one's reason above)")
    return out


def verdict(run: ValidationRun) -> tuple[list[str], int]:
    """What ``circcal validate`` prints last, and its exit status.

    Parameters
    ----------
    run : ValidationRun

    Returns
    -------
    lines : list of str
        The verdict first ("all checks passed", "SOME CHECKS FAILED: ...", "nothing gated: ...", "NOTHING
        COMPARED: ..."), then the images left unusable ("N of M images unusable") and why nothing was checked.
    status : int
        0 when nothing failed and something was compared (passed or not gated); 1 when a check failed or nothing at
        all was compared.
    """
    state = run.state
    used, given = run.images
    lines = []
    if state == "failed":
        lines.append("SOME CHECKS FAILED: " + ", ".join(c.name for c in run.checks if not c.passed))
    elif state == "passed":
        lines.append(f"all checks passed ({len(run.checks)})")
    elif state == "not gated":
        lines.append("nothing gated: the results above are compared, none is checked (nothing failed)")
    else:
        lines.append("NOTHING COMPARED: no result to check circcal against")
    if given and used < given:
        lines.append(f"{given - used} of {given} images unusable (circcal used {used}; the reasons are listed above)")
    lines += [f"- {h}" for h in run.hints]
    return lines, (0 if state in ("passed", "not gated") else 1)


def format_table(run: ValidationRun) -> str:
    """The side-by-side table ``circcal validate`` prints (markdown-compatible).

    Parameters
    ----------
    run : ValidationRun

    Returns
    -------
    str
        Header lines, one row per calibrator (truth first when known), notes, circcal's parameters vs truth, and
        every check.
    """
    lines = []
    src = ", ".join(f"{k}={v}" for k, v in run.source.items() if k != "images") or f"{len(run.source['images'])} images"
    lines.append(
        f"validation: {src}; board {run.board.rows}x{run.board.cols} {run.board.layout}; "
        f"observations: {run.observations}; lens model: {run.lens}"
    )
    lines.append(
        "errors: rms/pt = OpenCV's RMS (2-D per point), rms/coord = mrcal's (per coordinate), mean2d = "
        f"the paper's mean error; projection differences over a {GRID_WIDTH}-wide pixel grid of the whole "
        "image (vs truth: implied rotation fitted; vs circcal: none)"
    )
    if run.observations == "circcal":
        lines.append(
            "references fit circcal's final centres rounded to float32 (OpenCV's input type); 'vs circcal' "
            "compares with circcal's solver on exactly those points"
        )
    lines.append("")
    head = [
        "calibrator",
        "status",
        "fx",
        "fy",
        "cx",
        "cy",
        "k1",
        "k2",
        "rms/pt",
        "rms/coord",
        "mean2d",
        "vs circcal max px",
        "vs truth rms px",
        "time s",
    ]
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|" + "---|" * len(head))
    rows: list[tuple[str, str, Camera | None, dict | None, float]] = []
    cc = run.circcal
    rows.append(("circcal", cc["status"], cc.get("camera"), cc.get("errors"), cc["time_s"]))
    for r in run.references:
        rows.append((f"{r.name} {r.version} [{r.mode}]", r.status, r.camera, r.errors, r.time_s))
    if run.truth is not None:
        rows.insert(0, ("truth", "", run.truth, None, float("nan")))
    comps = ([None] if run.truth is not None else []) + run.comparisons
    for (label, status, cam, err, t), comp in zip(rows, comps):
        err = err or {}
        vals = [label, status]
        if cam is not None:
            vals += [
                fmt_number(v, spec)
                for v, spec in (
                    (cam.fx, ".3f"),
                    (cam.fy, ".3f"),
                    (cam.cx, ".3f"),
                    (cam.cy, ".3f"),
                    (cam.dist[0], ".5f"),
                    (cam.dist[1], ".4f"),
                )
            ]
        else:
            vals += ["-"] * 6
        vals += [fmt_number(err.get(k)) for k in ("rms_per_point_px", "rms_per_coord_px", "mean_2d_px")]
        vc = (comp or {}).get("vs_circcal", {})
        vt = (comp or {}).get("vs_truth", {})
        vals += [fmt_number(vc.get("max_px"), ".2e"), fmt_number(vt.get("rms_px"), ".4f"), fmt_number(t, ".3f")]
        lines.append("| " + " | ".join(vals) + " |")
    notes = [f"- {r.name} [{r.mode}]: {r.status}: {r.message}" for r in run.references if r.status != "ok"]
    if cc["status"] != "ok":
        notes.insert(0, f"- circcal: {cc['status']}: {cc['message']}")
    for r in cc.get("failed") or []:
        notes.append(f"- image left out by circcal: {Path(r.path).name}: {r.reason}")
    for s in run.skipped:
        notes.append(f"- skipped (--allow-missing): {s}")
    if notes:
        lines += ["", *notes]
    if cc.get("std") and run.truth is not None and cc.get("camera") is not None:
        lines += [
            "",
            "circcal parameters vs truth:",
            "",
            "| param | truth | circcal | +- sigma | error / sigma |",
            "|---|---|---|---|---|",
        ]
        pd = run.comparisons[0]["vs_truth"]["params"]
        for n in param_names(run.truth.lens):
            cells = (
                fmt_number(pd[n]["a"], ".6g"),
                fmt_number(pd[n]["b"], ".6g"),
                fmt_number(cc["std"][n], ".3g"),
                fmt_number(pd[n]["diff_sigmas"], "+.2f"),
            )
            lines.append(f"| {n} | " + " | ".join(cells) + " |")
    lines += ["", "checks:"]
    if not run.checks:
        lines.append("- none (the verdict below says why)")
    for c in run.checks:
        mark = "PASS" if c.passed else "FAIL"
        bound = "" if not np.isfinite(c.bound) else f" (bound {c.bound:g})"
        lines.append(f"- {mark} {c.name}: {fmt_number(c.value, '.3g')}{bound}{(' - ' + c.note) if c.note else ''}")
    return "\n".join(lines)


def to_dict(run: ValidationRun) -> dict[str, Any]:
    """A validation run as a JSON-ready dict (what ``validation.json`` holds).

    Parameters
    ----------
    run : ValidationRun

    Returns
    -------
    dict
    """
    cc = {k: v for k, v in run.circcal.items()}
    return jsonable(
        {
            "source": run.source,
            "board": run.board.to_dict(),
            "image_size": list(run.image_size),
            "truth": run.truth,
            "observations": run.observations,
            "lens": run.lens,
            "circcal": cc,
            "references": [r.to_dict() for r in run.references],
            "comparisons": [{k: v for k, v in c.items()} for c in run.comparisons],
            "checks": [vars(c) for c in run.checks],
            "passed": run.passed,
            "verdict": run.state,
            "hints": run.hints,
        }
    )


def write_report(run: ValidationRun, out: str | Path) -> Path:
    """Write ``validation.json`` and ``validation.md`` into a folder.

    The folder is made if missing; the command stages it and commits it with its other outputs
    (:mod:`circcal.outputs`).

    Parameters
    ----------
    run : ValidationRun
    out : str or Path
        The folder.

    Returns
    -------
    Path
        ``out``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "validation.json").write_text(json.dumps(to_dict(run), indent=1))
    lines, _ = verdict(run)
    (out / "validation.md").write_text(
        "# circcal validation\n\n" + format_table(run) + "\n\nverdict:\n\n" + "\n".join(lines) + "\n"
    )
    return out
