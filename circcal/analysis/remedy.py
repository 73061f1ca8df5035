"""What to do when a calibration's cross-validation finds a problem: try the candidates the verdict names, on the
same halves, and say which one makes the halves agree; where none does, say where the image needs more views.

The cross-validation (:mod:`circcal.analysis.cross`) calibrates two disjoint halves of the views and weighs their
difference against their combined uncertainty. When the halves disagree, each candidate is one more pair of solves
on the same halves (:func:`circcal.analysis.cross.detections_fitter`):

* a richer lens model (:data:`RICHER_LENS`: opencv5 -> rational -> thin-prism);
* the board's shape estimated (``CalibrationOptions(refine_board=True)``, ``--refine-board``), on boards of at most
  :data:`REFINE_MAX_POINTS` points (the refined solve grows with the board's points);
* the board warped (mrcal's 2-parameter sag, ``CalibrationOptions(board_warp=True)``, ``--board-warp``: as cheap as
  a plain solve);
* the views the leave-one-view-out flagged, left out of both halves (each half keeps at least the solver's minimum).

A candidate *makes the halves agree* when their difference is within the cross-validation's bound over the share
of the image it needs (:data:`circcal.analysis.diff.CONSISTENT_SHARE`). Agreement alone can be bought with
uncertainty (a model with more parameters states more), so each candidate is also scored by what a user sees on new
views: each half's model predicting the other half's views, poses fitted and intrinsics held (RMS per coordinate).
Where a model change predicts better than no change (by more than :data:`LEAD_MARGIN`), each lens change that does
is also tried with each board model that does (a wide lens and a sagging print are wrong at once), and the one that
predicts best (the lead), if its halves do not agree alone, with each other candidate; of the trials that agree, the one that predicts
best is recommended, or one of fewer changes predicting within :data:`LEAD_MARGIN` of it. Where no model change predicts
better, the candidate that agrees and predicts better than no change is. Where none agrees, or the halves agree but views
disagree or regions hold no observations, the remedy names the regions of the image (the thirds where the halves
disagree, the empty ones, the projection uncertainty's worst), the parameters the halves differ in by more than
:data:`PARAM_SIGMAS` combined sigma, and the poses that would measure them.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal.analysis.coverage import REGIONS
from circcal.analysis.cross import INFLUENCE_SIGMAS, CrossValidation, detections_fitter, halves_diff
from circcal.analysis.diff import CONSISTENT_SHARE
from circcal.errors import InputError
from circcal.observations import MIN_VIEWS as SOLVER_MIN_VIEWS
from circcal.solver import CalibrationOptions

__all__ = ["Remedy", "Trial", "remedy", "region_of", "RICHER_LENS", "REFINE_MAX_POINTS", "PARAM_SIGMAS", "LEAD_MARGIN"]

#: The next richer lens model of each (fisheye has none: its family differs; ``--lens auto`` chooses between them).
RICHER_LENS = {"opencv5": "rational", "rational": "thin-prism"}
#: Boards with more points than this are not refined as a candidate (its solve costs minutes on a 224-dot board);
#: the remedy says so and gives the command that tries it.
REFINE_MAX_POINTS = 150
#: Without a candidate that makes the halves agree, the one that predicts the other half best is combined with each
#: other candidate when it predicts better than no change by this share.
LEAD_MARGIN = 0.05
#: A parameter the two halves differ in by more than this many combined standard deviations needs more views.
PARAM_SIGMAS = 2.0


@dataclass(frozen=True)
class Trial:
    """One candidate tried on the cross-validation's halves.

    Attributes
    ----------
    label : str
        What changed, in words (``"--lens rational"``, ``"--refine-board"``, ``"without view_03.png"``).
    options : tuple of str
        The command-line options the candidate adds (``("--lens", "rational")``; empty when views are dropped).
    drop : tuple of str
        The names of the views left out (empty unless the candidate drops views).
    share_within : float or None
        Share of the image (0..1) where the halves' difference is within the bound; None: not tried.
    rms_px : float or None
        The halves' projection difference, RMS over the image, px.
    consistent : bool
        The halves agree (``share_within`` at least the share needed).
    predict_px : float or None
        Each half's model predicting the other half's views (poses fitted, intrinsics held): RMS per coordinate, px,
        over both directions; the error a user would see on new views, which a model cannot lower by growing its
        uncertainty.
    note : str
        Why it was not tried or failed; empty otherwise.
    where : tuple of (str, float)
        The image thirds where the halves still disagree, worst first, with the share of their pixels.
    """

    label: str
    options: tuple[str, ...] = ()
    drop: tuple[str, ...] = ()
    share_within: float | None = None
    rms_px: float | None = None
    consistent: bool = False
    predict_px: float | None = None
    note: str = ""
    where: tuple[tuple[str, float], ...] = ()

    def line(self, before: float | None) -> str:
        """The trial in one line, its share against ``before`` (the halves' share without the change).

        Parameters
        ----------
        before : float or None
            Share (0..1) of the image within the bound before the change.

        Returns
        -------
        str
        """
        if self.share_within is None:
            return f"{self.label}: not tried ({self.note})"
        was = f" (was {100 * before:.1f}%)" if before is not None else ""
        return (
            f"{self.label}: halves {'agree' if self.consistent else 'still disagree'}: within the bound over "
            f"{100 * self.share_within:.1f}% of the image{was}, difference {self.rms_px:.3g} px RMS, each half "
            f"predicts the other's views to {self.predict_px:.3g} px RMS per coordinate"
        )

    def to_dict(self) -> dict[str, Any]:
        """The fields, JSON-ready.

        Returns
        -------
        dict
        """
        return {
            "label": self.label,
            "options": list(self.options),
            "drop": list(self.drop),
            "share_within": self.share_within,
            "rms_px": self.rms_px,
            "consistent": self.consistent,
            "predict_px": self.predict_px,
            "note": self.note,
            "where": [list(w) for w in self.where],
        }


@dataclass
class Remedy:
    """What the verdict recommends.

    Attributes
    ----------
    before_share : float or None
        Share (0..1) of the image where the halves agree without a change (None: no cross-validation).
    trials : list of Trial
        The candidates tried, in order.
    best : Trial or None
        The recommended candidate: the one that makes the halves agree (None: none does).
    needs : list of str
        Where none does (or nothing was tried): which regions and parameters need more views, and what poses.
    command : str or None
        The exact command to run (set by the command line, which knows the arguments given); None: not known.
    before_predict_px : float or None
        Without a change, each half's model predicting the other half's views, RMS per coordinate, px (None: nothing
        tried).
    lead : Trial or None
        Where no candidate makes the halves agree: the model change that predicts the other half best (recommended
        as the better model, with :attr:`needs` for the rest); None otherwise.
    """

    before_share: float | None
    trials: list[Trial] = field(default_factory=list)
    best: Trial | None = None
    needs: list[str] = field(default_factory=list)
    command: str | None = None
    before_predict_px: float | None = None
    lead: Trial | None = None

    def target(self) -> Trial | None:
        """The candidate whose command is recommended: :attr:`best`, else :attr:`lead`.

        Returns
        -------
        Trial or None
        """
        return self.best if self.best is not None else self.lead

    def headline(self) -> str:
        """The recommendation in one line.

        Returns
        -------
        str
        """
        if self.best is not None:
            b = self.best
            gain = ""
            if self.before_share is not None and b.share_within is not None:
                gain = f" (within the bound over {100 * b.share_within:.1f}% of the image, was {100 * self.before_share:.1f}%)"
            run = f": run {self.command}" if self.command else ""
            return f"recommended: {b.label}: it makes the two halves agree{gain}{run}"
        run = f": run {self.command}" if self.command else ""
        if self.lead is not None and self.lead.share_within is not None:
            t = self.lead
            share: float = self.lead.share_within
            return (
                f"recommended: {t.label}: each half then predicts the other's views to {t.predict_px:.3g} px RMS per "
                f"coordinate (was {self.before_predict_px:.3g}){run}; its halves still disagree beyond their "
                f"uncertainty over {100 * (1 - share):.1f}% of the image (at most "
                f"{100 * (1 - CONSISTENT_SHARE):g}% allowed): more views there (below)"
            )
        if self.needs:
            return "recommended: more views: " + self.needs[0]
        return "recommended: nothing found to change; see the cross-validation below"

    def lines(self) -> list[str]:
        """The remedy in lines: the recommendation, each trial, then what needs more views.

        Returns
        -------
        list of str
        """
        out = [self.headline()]
        if self.before_predict_px is not None:
            out.append(
                f"  without a change each half predicts the other's views to {self.before_predict_px:.3g} px RMS per "
                f"coordinate"
            )
        out += ["  tried " + t.line(self.before_share) for t in self.trials]
        rest = self.needs[1:] if (self.best is None and self.lead is None) else self.needs
        out += ["  " + n for n in rest]
        return out

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary.

        Returns
        -------
        dict
            ``before_share``, ``trials``, ``best`` (its label), ``needs``, ``command``.
        """
        return {
            "before_share": self.before_share,
            "trials": [t.to_dict() for t in self.trials],
            "best": None if self.best is None else self.best.label,
            "needs": list(self.needs),
            "command": self.command,
            "before_predict_px": self.before_predict_px,
            "lead": None if self.lead is None else self.lead.label,
        }


def region_of(u: float, v: float, width: int, height: int) -> str:
    """The ninth of the image (:data:`circcal.analysis.coverage.REGIONS`) holding pixel (u, v).

    Parameters
    ----------
    u, v : float
        px.
    width, height : int
        The image, px.

    Returns
    -------
    str
    """
    c = int(np.clip((u + 0.5) * 3 // width, 0, 2))
    r = int(np.clip((v + 0.5) * 3 // height, 0, 2))
    return REGIONS[r][c]


def _poses(region: str) -> str:
    if region == "centre":
        return "views with the board filling the centre, at several tilts"
    if "corner" in region:
        return f"views with the board in the {region}, tilted 30-45 degrees, some closer so that it fills the corner"
    return f"views with the board along the {region}, tilted toward it"


def _param_poses(names: Sequence[str]) -> str:
    hints = []
    if any(n in ("fx", "fy") for n in names):
        hints.append("views at several distances and tilts up to 45 degrees (fx, fy)")
    if any(n in ("cx", "cy") for n in names):
        hints.append("tilted views in opposite corners (cx, cy)")
    if any(n not in ("fx", "fy", "cx", "cy") for n in names):
        hints.append("closer views that reach the image's corners and edges (distortion)")
    return "; ".join(hints)


def _param_gaps(cv: CrossValidation) -> list[tuple[str, float]]:
    """The parameters the halves differ in by more than :data:`PARAM_SIGMAS` combined sigma, largest first."""
    a, b = cv.models
    if a.camera.lens != b.camera.lens:
        return []
    out = []
    for n, va, vb in zip(a.camera.model.param_names, a.camera.intrinsics, b.camera.intrinsics):
        s = float(np.hypot(a.std.get(n, 0.0), b.std.get(n, 0.0)))
        if s > 0 and np.isfinite(s):
            z = abs(float(va) - float(vb)) / s
            if z > PARAM_SIGMAS:
                out.append((n, z))
    return sorted(out, key=lambda t: -t[1])


def _needs(
    cv: CrossValidation | None, uncertainty: Any, coverage: Any, width: int, height: int, lead: Trial | None = None
) -> list[str]:
    """Which regions and parameters need more views, and the poses that would supply them (where the halves still
    disagree under ``lead``, the recommended model change, when given)."""
    regions: list[str] = []
    why: dict[str, str] = {}
    where = list(lead.where) if lead is not None else []
    if lead is None and cv is not None and cv.diff is not None and not cv.diff.consistent:
        where = list(cv.diff.where)
    for r, s in where[:3]:
        regions.append(str(r))
        why[str(r)] = f"the halves disagree over {100 * s:.0f}% of it"
    for e in coverage.empty if coverage is not None else []:
        r = e["region"]
        if r not in why:
            regions.append(r)
            why[r] = "it holds no observations"
    if uncertainty is not None and uncertainty.centre_px > 0:
        u, v = uncertainty.worst_uv[0], uncertainty.worst_uv[1]
        r = region_of(float(u), float(v), width, height)
        ratio = uncertainty.worst_px / uncertainty.centre_px
        note = f"the projection uncertainty is worst there ({uncertainty.worst_px:.3g} px, {ratio:.1f}x the centre's)"
        if r in why:
            why[r] += f"; {note}"
        elif regions or ratio > 2.0:
            regions.append(r)
            why[r] = note
    out = [f"the {r}: {why[r]}; take {_poses(r)}" for r in regions]
    if cv is None or cv.diff is None or lead is not None:
        return out
    params = _param_gaps(cv) if not cv.diff.consistent else []  # halves that agree differ by chance
    if params:
        out.append(
            "parameters the halves differ in beyond their uncertainty: "
            + ", ".join(f"{n} ({z:.1f} sigma)" for n, z in params[:6])
            + f"; take {_param_poses([n for n, _ in params])}"
        )
    for v in cv.flagged_views:
        if v.shift_sigmas > INFLUENCE_SIGMAS and v.shift_param:
            out.append(
                f"{v.name} alone decides {v.shift_param} ({v.shift_sigmas:.1f} sigma when left out): take more views "
                f"like it (its board's place and tilt), or leave it out if it is wrong"
            )
        elif v.flagged:
            out.append(f"{v.name} disagrees with the rest ({v.why}): re-shoot it or leave it out")
    return out


def remedy(
    cal: Any,
    board: Any,
    options: CalibrationOptions,
    cv: CrossValidation | None,
    *,
    uncertainty: Any = None,
    coverage: Any = None,
    distance: float | None = None,
) -> Remedy | None:
    """Try the candidates on the cross-validation's halves (see the module) and say what to do.

    Parameters
    ----------
    cal : circcal.pipeline.ImagesCalibration
        The calibration (its detections are refitted).
    board : circcal.board.Board
    options : CalibrationOptions
        The settings ``cal`` was made with.
    cv : CrossValidation or None
        Its cross-validation (None or not ``"ok"``: nothing is tried).
    uncertainty : UncertaintyMap or None
        Its projection uncertainty (:func:`circcal.analysis.assess.uncertainty_map`).
    coverage : Coverage or None
        Where its observations lie (:func:`circcal.analysis.coverage.coverage`).
    distance : float or None
        mm along each pixel's ray at which the halves are compared (None: infinity).

    Returns
    -------
    Remedy or None
        None when there is nothing to remedy: the halves agree, every view agrees with the rest and every ninth of
        the image holds observations.
    """
    res = cal.result
    w, h = res.camera.width, res.camera.height
    checked = cv if cv is not None and cv.status == "ok" and cv.diff is not None else None
    ok = checked is not None
    empty = coverage is not None and bool(coverage.empty)
    if not (checked is not None and checked.verdict != "consistent") and not empty:
        return None
    before = checked.diff.share_within if checked is not None and checked.diff is not None else None
    trials: list[Trial] = []
    best: Trial | None = None
    lead: Trial | None = None
    base = float("nan")
    if checked is not None and checked.diff is not None and not checked.diff.consistent:
        cv = checked
        base = _predict(*cv.models)
        trials = _trials(cal, board, options, cv, distance)
        lead = _lead(trials, base)
        if lead is None:  # no model change predicts better: the views are the question
            best = _choose(trials, base)
        else:
            # a lens and a board model can each be wrong at once (a wide lens on a sagging print): where a lens change
            # and a board model each predict better on their own, each such lens change with each such board
            # model; and the lead with each other candidate where it does not agree alone
            helps = [t for t in trials if _improves(t, base)]
            pairs = [(a, b) for a in helps for b in helps if _lens(a) and _board(b)]
            if not lead.consistent:
                pairs += [(lead, t) for t in trials if t is not lead]
            combos: list[Trial] = []
            for a, b in pairs:
                t = _combine(cal, board, options, cv, a, b, distance)
                if t is not None and all(set(t.options) != set(c.options) for c in combos):
                    combos.append(t)
            trials += combos
            # the simplest change among those that agree and predict within LEAD_MARGIN of the best
            best = _choose(trials if lead.consistent else combos, base)
        if best is not None or (lead is not None and lead.consistent):
            lead = None
    needs = [] if best is not None else _needs(cv if ok else None, uncertainty, coverage, w, h, lead)
    return Remedy(before, trials, best, needs, before_predict_px=base if ok and trials else None, lead=lead)


def _choose(trials: list[Trial], base: float) -> Trial | None:
    """The trial that makes the halves agree and predicts the other half best, better than no change (``base``, px);
    None: none does. A model that agrees only because its uncertainty grew predicts worse, and is not chosen. Of
    those within :data:`LEAD_MARGIN` of the best prediction, the one of fewest changes (one change before two)."""
    agree = [t for t in trials if t.consistent and t.predict_px is not None and not t.predict_px >= base]
    if not agree:
        return None
    top = min(float(t.predict_px or 0.0) for t in agree)
    near = [t for t in agree if float(t.predict_px or 0.0) <= (1.0 + LEAD_MARGIN) * top]
    return min(near, key=lambda t: (len(t.options) + len(t.drop), float(t.predict_px or 0.0), trials.index(t)))


def _improves(t: Trial, base: float) -> bool:
    """The trial predicts the other half better than no change by more than :data:`LEAD_MARGIN`."""
    return t.predict_px is not None and bool(np.isfinite(t.predict_px)) and t.predict_px < (1.0 - LEAD_MARGIN) * base


def _lens(t: Trial) -> bool:
    """A lens-model change alone."""
    return t.options[:1] == ("--lens",) and len(t.options) == 2 and not t.drop


def _board(t: Trial) -> bool:
    """A board-model change alone."""
    return t.options in (("--refine-board",), ("--board-warp",)) and not t.drop


def _lead(trials: list[Trial], base: float) -> Trial | None:
    """The tried model change that predicts the other half best, if better than no change by :data:`LEAD_MARGIN`
    (dropping views is not compared: it predicts fewer, other views)."""
    tried = [t for t in trials if t.predict_px is not None and np.isfinite(t.predict_px) and not t.drop]
    if not tried or not np.isfinite(base):
        return None
    t = min(tried, key=lambda t: float(t.predict_px or 0.0))
    return t if float(t.predict_px or 0.0) < (1.0 - LEAD_MARGIN) * base else None


def _candidates(
    board: Any, options: CalibrationOptions, lens: str, flagged: Sequence[Any]
) -> list[tuple[str, tuple[str, ...], tuple[Any, ...], CalibrationOptions | None, str]]:
    """(label, command-line options, views dropped, options or None, why not) of each candidate."""
    out: list[tuple[str, tuple[str, ...], tuple[Any, ...], CalibrationOptions | None, str]] = []
    richer = RICHER_LENS.get(lens)
    if richer is not None:
        try:
            out.append((f"--lens {richer}", ("--lens", richer), (), options.replace(lens=richer), ""))
        except InputError as exc:  # a held parameter the richer model does not have
            out.append((f"--lens {richer}", ("--lens", richer), (), None, str(exc)))
    if not options.refine_board:
        n = board.rows * board.cols
        o: CalibrationOptions | None = None
        why = ""
        if options.board_warp:  # the refined board replaces the warp: the command would hold both flags
            why = "--board-warp is on: run without it and with --refine-board to try the refined board"
        elif n > REFINE_MAX_POINTS:
            why = f"{n} board points: its solve takes minutes; run with --refine-board to try it"
        else:
            o = options.replace(refine_board=True)
        out.append(("--refine-board", ("--refine-board",), (), o, why))
        if not options.board_warp:
            out.append(("--board-warp", ("--board-warp",), (), options.replace(board_warp=True), ""))
    if flagged:
        out.append(("without " + ", ".join(v.name for v in flagged), (), tuple(flagged), options, ""))
    return out


def _trials(
    cal: Any, board: Any, options: CalibrationOptions, cv: CrossValidation, distance: float | None
) -> list[Trial]:
    out = []
    for label, opts, drop, o, why in _candidates(board, options, cal.result.camera.lens, cv.flagged_views):
        out.append(_run(cal, board, cv, label, opts, drop, o, why, distance))
    return out


def _run(
    cal: Any,
    board: Any,
    cv: CrossValidation,
    label: str,
    opts: tuple[str, ...],
    drop: tuple[Any, ...],
    o: CalibrationOptions | None,
    why: str,
    distance: float | None,
) -> Trial:
    """One candidate tried on the same halves (its Trial: agreement, difference, prediction; or why not)."""
    names = tuple(v.name for v in drop)
    if o is None:
        return Trial(label, opts, names, note=why)
    gone = {v.view for v in drop}
    halves = [[i for i in hh if i not in gone] for hh in cv.halves]
    if min(len(hh) for hh in halves) < SOLVER_MIN_VIEWS:
        return Trial(label, opts, names, note=f"a half would keep fewer than {SOLVER_MIN_VIEWS} views")
    fit = detections_fitter(cal, board, o)
    try:
        with warnings.catch_warnings():  # a candidate's own troubles (a fold, no convergence) are its trial's
            warnings.simplefilter("ignore")
            a, b = (fit(hh) for hh in halves)
    except InputError as exc:  # CalibrationError included: a half too weak for the candidate
        return Trial(label, opts, names, note=f"a half gives no model ({exc})")
    if a.covariance is None or b.covariance is None:
        return Trial(label, opts, names, note="a half's information matrix is singular")
    d = halves_diff(a, b, distance=distance)
    return Trial(
        label,
        opts,
        names,
        None if d.share_within is None else float(d.share_within),
        float(d.rms_px),
        bool(d.consistent),
        _predict(a, b),
        where=tuple((str(r), float(x)) for r, x in d.where),
    )


def _combine(
    cal: Any,
    board: Any,
    options: CalibrationOptions,
    cv: CrossValidation,
    lead: Trial,
    other: Trial,
    distance: float | None,
) -> Trial | None:
    """``lead`` and ``other`` together (None where they cannot be combined)."""
    if other.share_within is None or (lead.drop and other.drop):
        return None
    cands = {c[0]: c for c in _candidates(board, options, cal.result.camera.lens, cv.flagged_views)}
    first, second = cands[lead.label], cands[other.label]
    o = first[3] if first[3] is not None else options
    if {first[0], second[0]} == {"--refine-board", "--board-warp"}:  # two board models: not together
        return None
    if second[1] == ("--refine-board",):
        o = o.replace(refine_board=True)
    elif second[1] == ("--board-warp",):
        o = o.replace(board_warp=True)
    elif second[1]:
        o = o.replace(lens=second[1][1])
    label = f"{lead.label} {other.label}"
    return _run(cal, board, cv, label, lead.options + other.options, first[2] + second[2], o, "", distance)


def _predict(a: Any, b: Any) -> float:
    """RMS per coordinate (px) of each half's model predicting the other half's final observations."""
    from circcal.solver.holdout import prediction_error

    sq, n = 0.0, 0.0
    for m, other in ((a, b), (b, a)):
        for obj, img in zip(other.object_points or [], other.image_points or []):
            try:
                e = prediction_error(m.board_lookup(np.asarray(obj, dtype=np.float64)), img, m.camera)
            except (InputError, ValueError):  # no pose; a board point the model never saw (a partial view)
                continue
            k = 2 * e["n_points"]
            sq += e["rms_per_coord_px"] ** 2 * k
            n += k
    return float(np.sqrt(sq / n)) if n else float("nan")
