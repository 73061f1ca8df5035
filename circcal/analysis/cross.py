"""Cross-validation of a calibration on the user's own images, the way mrcal validates one: split the views into two
disjoint halves, calibrate each with the same settings, and weigh the projection difference of the two models
(:func:`circcal.analysis.diff.model_diff`, implied transformation fitted) against their combined predicted
uncertainty (:mod:`circcal.solver.uncertainty`, sigma_A + sigma_B per pixel). With a right model and unbiased data the
difference stays within about 2x of it: the verdict is **consistent** when it does over at least 95% of the image,
else a **model or data problem** (a lens model too simple, biased centres, a board that is not what was said),
with the image regions where it is exceeded.

Beside it, leave-one-view-out: each view is predicted by the model of all the others (its pose fitted, the
intrinsics held; :func:`circcal.solver.holdout.leave_one_out`), and a view is flagged when it disagrees with the
rest: its held-out prediction error is more than :data:`HELDOUT_RATIO` times the views' median, or leaving it out
moves a parameter by more than :data:`INFLUENCE_SIGMAS` of its standard deviations (the view carries information
no other view has, e.g. the only board in a corner, or it is wrong: a typical view moves them by ~1/sqrt(V) sigma).
The verdict is consistent only when the halves agree and no view is flagged: a bias common to every view (a
centroid detector on tilted dots) makes the halves agree with each other, yet shows as single views that pull the
model far beyond its stated uncertainty. The leave-one-out models refit the full model's
final observations from its camera (no re-correction of the centres: their change under a model of one view less is
~1e-3 px).

Errors name their convention (``rms_per_coord_px`` mrcal's, per coordinate). At least :data:`MIN_VIEWS` views are
needed (3 per half, the solver's minimum); with fewer the cross-validation says why and the calibration stands.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from circcal.analysis.diff import CONSISTENT_RATIO, CONSISTENT_SHARE, ModelDiff, model_diff, noise_floor_factor
from circcal.errors import InputError
from circcal.model import Camera
from circcal.observations import MIN_VIEWS as SOLVER_MIN_VIEWS
from circcal.pathnames import display_name
from circcal.solver import CalibrationOptions, CalibrationResult, calibrate, leave_one_out

#: The argument and the result of a fit :func:`noting_warnings` runs.
_A = TypeVar("_A")
_R = TypeVar("_R")

__all__ = [
    "CrossValidation",
    "ViewCheck",
    "split_views",
    "cross_validate",
    "cross_validate_observations",
    "cross_validate_detections",
    "detections_fitter",
    "halves_diff",
    "noting_warnings",
    "half_named",
    "MIN_VIEWS",
    "HELDOUT_RATIO",
    "INFLUENCE_SIGMAS",
    "SPLITS",
]

#: Two halves of at least the solver's minimum of views each.
MIN_VIEWS = 2 * SOLVER_MIN_VIEWS
#: A view whose held-out prediction error (RMS per coordinate) exceeds this many times the views' median disagrees
#: with the rest (a right model predicts every view about as well as it fits them; a view that the others' model
#: must extrapolate to reaches ~3x on the fixtures).
HELDOUT_RATIO = 5.0
#: ... or whose removal moves a parameter by more than this many of its standard deviations (the full solve's; on
#: every fixture with unbiased centres the largest move is 2.2 sigma).
INFLUENCE_SIGMAS = 3.0
#: How the views are split into halves.
SPLITS = ("alternate", "random")


def split_views(n: int, how: str = "alternate", seed: int = 0) -> tuple[list[int], list[int]]:
    """Two disjoint halves of views 0..n-1.

    Parameters
    ----------
    n : int
    how : {"alternate", "random"}
        ``"alternate"``: even, odd (both halves span the capture session); ``"random"``: a seeded permutation cut in
        two.
    seed : int

    Returns
    -------
    tuple of (list of int, list of int)

    Raises
    ------
    InputError
        An unknown ``how``.

    Examples
    --------
    >>> split_views(5)
    ([0, 2, 4], [1, 3])
    """
    if how == "alternate":
        return list(range(0, n, 2)), list(range(1, n, 2))
    if how == "random":
        perm = np.random.default_rng(seed).permutation(n)
        return sorted(int(i) for i in perm[: (n + 1) // 2]), sorted(int(i) for i in perm[(n + 1) // 2 :])
    raise InputError(f"unknown split {how!r}; expected one of {', '.join(SPLITS)}")


@dataclass
class ViewCheck:
    """Leave-one-view-out for one view.

    Attributes
    ----------
    view : int
    name : str
    heldout_rms_per_coord_px : float
        Its prediction error by the others' model, px (NaN when it failed).
    ratio : float
        That to the views' median.
    shift_sigmas : float
        The largest parameter move on leaving it out (in the full solve's standard deviations).
    shift_param : str
        Which parameter.
    flagged : bool
    why : str
    """

    view: int
    name: str
    heldout_rms_per_coord_px: float
    ratio: float
    shift_sigmas: float
    shift_param: str
    flagged: bool
    why: str

    def to_dict(self) -> dict[str, Any]:
        """The fields, JSON-ready.

        Returns
        -------
        dict
        """
        return dict(self.__dict__)


@dataclass
class CrossValidation:
    """The outcome of a cross-validation.

    Attributes
    ----------
    status : str
        ``"ok"``, ``"too-few-views"`` or ``"failed"`` (a half could not be calibrated).
    message : str
        In words.
    split : str
    seed : int
    halves : tuple of (list of int, list of int)
        The two views lists (indices of the full model's views).
    models : list of CalibrationResult
        The halves' :class:`~circcal.solver.CalibrationResult`.
    diff : ModelDiff or None
        B against A with both uncertainties.
    verdict : str or None
        ``"consistent"`` or ``"model-or-data-problem"`` (None unless ok).
    views : list of ViewCheck
        One per view.
    distance_mm : float or None
        None: infinity.
    notes : list of str
        What the halves' and the leave-one-out refits' own calibrations warned of (non-convergence, a re-correction
        stopped), each once, named by whose fit it was: the check's own trials, not the calibration above.
    flagged_views : list of ViewCheck
        The views flagged (property).
    """

    status: str
    message: str
    split: str = "alternate"
    seed: int = 0
    halves: tuple[list[int], list[int]] = ([], [])
    models: list[Any] = field(default_factory=list)
    diff: ModelDiff | None = None
    verdict: str | None = None
    views: list[ViewCheck] = field(default_factory=list)
    distance_mm: float | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def flagged_views(self) -> list[ViewCheck]:
        """The :class:`ViewCheck` of each view flagged."""
        return [v for v in self.views if v.flagged]

    def lines(self) -> list[str]:
        """The console summary.

        Returns
        -------
        list of str
        """
        out = [f"cross-validation ({self.split} halves): {self.message}"]
        for v in self.flagged_views:
            out.append(f"  view {v.name} disagrees with the rest: {v.why}")
        out += [f"  (the check's own fits) {n}" for n in self.notes]
        return out

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary.

        Returns
        -------
        dict
            ``status``, ``message``, ``split``, ``seed``, ``halves``, ``verdict``, ``distance_mm``, ``diff``
            (:meth:`ModelDiff.summary`), ``half_models`` (camera and errors), ``views``, ``notes``.
        """
        return {
            "status": self.status,
            "message": self.message,
            "split": self.split,
            "seed": self.seed,
            "halves": [list(h) for h in self.halves],
            "verdict": self.verdict,
            "distance_mm": self.distance_mm,
            "diff": None if self.diff is None else self.diff.summary(),
            "half_models": [{"camera": m.camera.to_dict(), "errors": dict(m.errors)} for m in self.models],
            "views": [v.to_dict() for v in self.views],
            "notes": list(self.notes),
        }


def _verdict(d: ModelDiff, views: list[ViewCheck]) -> tuple[str, str]:
    if d.share_within is None:
        raise ValueError("_verdict needs a ModelDiff made with both models' uncertainties")
    share = 100.0 * d.share_within
    base = (
        f"the halves differ by {d.rms_px:.3g} px RMS (p95 {d.p95_px:.3g}, max {d.max_px:.3g}, centre "
        f"{d.centre_px:.3g} px), within {CONSISTENT_RATIO:g}x their combined uncertainty over {share:.1f}% of the "
        f"image"
    )
    flagged = [v.name for v in views if v.flagged]
    if d.consistent and not flagged:
        return "consistent", (
            f"consistent: {base} (>= {100 * CONSISTENT_SHARE:g}% needed), and every view agrees with the rest"
        )
    parts = []
    if not d.consistent:
        where = ", ".join(f"{r} ({100 * s:.0f}%)" for r, s in d.where[:4]) or "spread over the image"
        parts.append(f"{base}, less than {100 * CONSISTENT_SHARE:g}%; exceeded in the {where}")
    else:
        parts.append(f"{base}")
    if flagged:
        parts.append(f"{len(flagged)} view(s) disagree with the rest ({', '.join(flagged)})")
    return "model-or-data-problem", (
        "a model or data problem: " + "; ".join(parts) + ". Likely: a lens model too "
        "simple for the lens, biased centres, or a board unlike the one given"
    )


def _leave_one_out(full: Any, names: Sequence[str], options: CalibrationOptions, notes: list[str]) -> list[ViewCheck]:
    obj, img = full.object_points, full.image_points
    size = (full.camera.width, full.camera.height)
    models: dict[int, Any] = {}

    def refit(rest: list[int]) -> CalibrationResult:
        poses = (full.rvecs[rest], full.tvecs[rest])  # the full solve's: one view less moves them little
        return calibrate(
            [obj[i] for i in rest], [img[i] for i in rest], size, options, initial=full.camera, start_poses=poses
        )

    def fit(rest: list[int]) -> CalibrationResult:
        (k,) = set(range(len(obj))) - set(rest)
        models[k] = res = noting_warnings(notes, f"the fit without {names[k]}", refit, rest)
        return res

    def held_out(k: int, res: CalibrationResult) -> tuple[np.ndarray, np.ndarray, Camera]:
        return res.board_lookup(np.asarray(obj[k], dtype=np.float64)), img[k], res.camera

    rows = leave_one_out(len(obj), fit, held_out)
    rms = np.array([r.get("rms_per_coord_px", np.nan) for r in rows], dtype=np.float64)
    med = float(np.nanmedian(rms)) if np.isfinite(rms).any() else float("nan")
    names_p = full.camera.model.param_names  # the lens model's parameters (fx, fy, cx, cy, dist...)
    std = np.array([full.std[n] for n in names_p])
    out = []
    for k, r in enumerate(rows):
        shift, which = float("nan"), ""
        if k in models:
            free = std > 0
            z = np.abs(models[k].camera.intrinsics - full.camera.intrinsics)[free] / std[free]
            j = int(np.argmax(z))
            shift, which = float(z[j]), [n for n, f in zip(names_p, free) if f][j]
        ratio = rms[k] / med if med > 0 else float("nan")
        why = []
        if "failed" in r:
            why.append(f"the other views give no model or it no pose ({r['failed']})")
        if np.isfinite(ratio) and ratio > HELDOUT_RATIO:
            why.append(
                f"predicted by the others' model to {rms[k]:.3g} px RMS per coordinate, {ratio:.1f}x the "
                f"views' median {med:.3g} px"
            )
        if np.isfinite(shift) and shift > INFLUENCE_SIGMAS:
            why.append(
                f"leaving it out moves {which} by {shift:.1f} sigma: it holds information no other view has "
                f"(e.g. the only observations in part of the image), or it is wrong"
            )
        out.append(ViewCheck(k, names[k], float(rms[k]), float(ratio), shift, which, bool(why), "; ".join(why)))
    return out


def halves_diff(a: CalibrationResult, b: CalibrationResult, *, distance: float | None = None) -> ModelDiff:
    """Two models' projection difference weighed against their combined uncertainty (the cross-validation's test),
    each raised to the noise floor (:data:`circcal.analysis.diff.NOISE_FLOOR_PX`).

    Parameters
    ----------
    a, b : CalibrationResult
        Two calibrations of disjoint views of the same camera, each with its covariance.
    distance : float or None
        mm along each pixel's ray at which they are compared (None: infinity).

    Returns
    -------
    ModelDiff
        B against A with both uncertainties (``consistent``, ``share_within``, ``where``).
    """
    from circcal.solver.uncertainty import result_projection_stdev

    fa, fb = noise_floor_factor(a.sigma_px), noise_floor_factor(b.sigma_px)
    return model_diff(
        a.camera,
        b.camera,
        distance=distance,
        uncertainty_a=lambda uv: fa * result_projection_stdev(a, uv, distance=distance),
        uncertainty_b=lambda uv: fb * result_projection_stdev(b, uv, distance=distance),
    )


def noting_warnings(notes: list[str], who: str, fit: Callable[[_A], _R], views: _A) -> _R:
    """``fit(views)`` with its RuntimeWarnings kept in ``notes`` instead of shown: a check's trial fits speak through
    the check (other warnings pass on).

    Parameters
    ----------
    notes : list of str
        Appended to: ``"who: message"``, each once.
    who : str
        Whose fit it is, in words (e.g. the half of 7 views (...)).
    fit : callable
        The fit.
    views : object
        Its argument.

    Returns
    -------
    object
        What ``fit`` returns (its exceptions pass on).
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        try:
            return fit(views)
        finally:
            for w in caught:
                if not issubclass(w.category, RuntimeWarning):
                    warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
                elif (line := f"{who}: {w.message}") not in notes:
                    notes.append(line)


def half_named(members: Sequence[str], unit: str) -> str:
    """A cross-validation's half in words, by its first members (its fits' notes say whose they are).

    Parameters
    ----------
    members : sequence of str
        The half's views or instants, by name.
    unit : str
        What they are ("views", "instants").

    Returns
    -------
    str
        E.g. ``the half of 7 views (a.png, b.png, c.png, d.png, ...)``.
    """
    shown = ", ".join(display_name(m) for m in members[:4])  # a file name with a newline prints as one line
    return f"the half of {len(members)} {unit} ({shown}{', ...' if len(members) > 4 else ''})"


def cross_validate(
    full: Any,
    fit_half: Callable[[list[int]], Any],
    options: CalibrationOptions,
    *,
    names: Sequence[str] | None = None,
    split: str = "alternate",
    seed: int = 0,
    distance: float | None = None,
) -> CrossValidation:
    """Cross-validate the calibration ``full`` (see the module).

    Parameters
    ----------
    full : CalibrationResult
        The calibration of V views.
    fit_half : callable
        ``fit_half(view indices)``: calibrates a subset of ``full``'s views with the same settings.
    options : CalibrationOptions
        The settings ``full`` was made with; the leave-one-out refits use them without outlier rejection (they
        refit ``full``'s final observations, already free of outliers).
    names : sequence of str or None
        The views' names (default ``view i``). Given, the views are halved in the order of their names (file names:
        the order of capture, usually), not in the order given: the same images give the same halves however they
        are listed.
    split : {"alternate", "random"}
        How the views are halved (:func:`split_views` over that order); ``seed`` seeds ``"random"``.
    distance : float or None
        mm along each pixel's ray at which the models are compared (None: infinity).

    Returns
    -------
    CrossValidation
    """
    n = len(full.rvecs)
    # the halves follow the views' names, not the order they were given in: the same images give the same verdict
    # however a shell or a script lists them (a folder's images come sorted by name already)
    given = list(names) if names is not None else None
    order = sorted(range(n), key=lambda i: (str(given[i]), i)) if given is not None else list(range(n))
    names = given if given is not None else [f"view {i}" for i in range(n)]
    if n < MIN_VIEWS:
        return CrossValidation(
            "too-few-views",
            f"not done: {n} views; two independent halves need at least "
            f"{MIN_VIEWS} ({SOLVER_MIN_VIEWS} each, the least a calibration takes). The "
            f"calibration above stands; take more views to check it",
            split,
            seed,
            distance_mm=distance,
        )
    h0, h1 = split_views(n, split, seed)
    halves = (sorted(order[k] for k in h0), sorted(order[k] for k in h1))
    models = []
    notes: list[str] = []
    for h in halves:
        try:
            models.append(noting_warnings(notes, half_named([names[i] for i in h], "views"), fit_half, h))
        except InputError as exc:
            return CrossValidation(
                "failed",
                f"not done: the half {[names[i] for i in h]} gives no model ({exc})",
                split,
                seed,
                halves,
                distance_mm=distance,
                notes=notes,
            )
    a, b = models
    if a.covariance is None or b.covariance is None:
        return CrossValidation(
            "failed",
            "not done: a half's information matrix is singular (no uncertainty)",
            split,
            seed,
            halves,
            models,
            distance_mm=distance,
            notes=notes,
        )
    d = halves_diff(a, b, distance=distance)
    views = _leave_one_out(full, names, options.replace(outlier_rule=None), notes)
    verdict, message = _verdict(d, views)
    return CrossValidation("ok", message, split, seed, halves, models, d, verdict, views, distance, notes)


def cross_validate_observations(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    options: CalibrationOptions = CalibrationOptions(),
    *,
    full: Any = None,
    names: Sequence[str] | None = None,
    split: str = "alternate",
    seed: int = 0,
    distance: float | None = None,
) -> tuple[Any, CrossValidation]:
    """Calibrate fixed observations with ``options`` (:func:`circcal.solver.calibrate`) and cross-validate.

    With outlier rejection the halves are drawn from the views it kept.

    Parameters
    ----------
    object_points : sequence of ndarray, each shape (N_v, 3)
        Per view, mm.
    image_points : sequence of ndarray, each shape (N_v, 2)
        Per view, px.
    image_size : tuple of int
        (width, height), px.
    options : CalibrationOptions
    full : CalibrationResult or None
        That calibration, if already made.
    names, split, seed, distance
        As :func:`cross_validate`'s.

    Returns
    -------
    full : CalibrationResult
    cv : CrossValidation

    Raises
    ------
    InputError
        As :func:`circcal.solver.calibrate` (the full calibration), or an unknown ``split``.
    """
    if full is None:
        full = calibrate(object_points, image_points, image_size, options)
    kept = full.outliers.kept_views if full.outliers is not None else list(range(len(object_points)))
    obj = [object_points[i] for i in kept]
    img = [image_points[i] for i in kept]

    def fit_half(h: list[int]) -> CalibrationResult:
        return calibrate([obj[i] for i in h], [img[i] for i in h], image_size, options)

    return full, cross_validate(
        full,
        fit_half,
        options,
        names=[(names[i] if names else f"view {i}") for i in kept],
        split=split,
        seed=seed,
        distance=distance,
    )


def cross_validate_detections(
    cal: Any,
    board: Any,
    options: CalibrationOptions = CalibrationOptions(),
    *,
    split: str = "alternate",
    seed: int = 0,
    distance: float | None = None,
) -> CrossValidation:
    """Cross-validate an :class:`circcal.pipeline.ImagesCalibration` made with ``options``.

    Each half runs through the whole loop (:func:`circcal.pipeline.calibrate_detections`: calibrate, re-correct,
    recalibrate) from its views' detections, with the same ``options``.

    Parameters
    ----------
    cal : ImagesCalibration
    board : Board
    options : CalibrationOptions
    split, seed, distance
        As :func:`cross_validate`'s.

    Returns
    -------
    CrossValidation

    Raises
    ------
    InputError
        An unknown ``split``.
    """
    full = cal.result
    fit_half = detections_fitter(cal, board, options)
    return cross_validate(full, fit_half, options, names=full.view_names, split=split, seed=seed, distance=distance)


def detections_fitter(cal: Any, board: Any, options: CalibrationOptions) -> Callable[[list[int]], CalibrationResult]:
    """A function that calibrates some of an :class:`circcal.pipeline.ImagesCalibration`'s views from their detections.

    Parameters
    ----------
    cal : ImagesCalibration
    board : Board
    options : CalibrationOptions
        How each subset is calibrated (the full model's, or a candidate's: another lens model, a refined board).

    Returns
    -------
    callable
        ``fit(view indices)`` -> :class:`~circcal.solver.CalibrationResult`: the whole loop
        (:func:`circcal.pipeline.calibrate_detections`) on those views (indices of ``cal.result``'s views); the
        detector's bad dots stay out where ``options`` rejects outliers, as in the full model.
    """
    from circcal.pipeline import calibrate_detections

    dets = [cal.detections[i] for i in cal.used]
    size = (cal.result.camera.width, cal.result.camera.height)

    def fit(h: list[int]) -> CalibrationResult:
        exclude = None
        if options.outlier_rule is not None:
            from circcal.dotcheck import bad_dot_rejections

            exclude = bad_dot_rejections([dets[i] for i in h], board)[0]
        return calibrate_detections([dets[i] for i in h], board, size, options, exclude=exclude)[0]

    return fit
