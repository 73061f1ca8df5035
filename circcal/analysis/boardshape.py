"""Is the board flat? Every calibration is also fitted with the other board model, and the two are weighed with
evidence: the fitted warp against its own uncertainty, the intrinsics' shift between the two models in stated
sigmas, and which model predicts views it was not fitted to better.

The warp is mrcal's 2-parameter ``calobject_warp`` (:func:`circcal.solver.problem.warp_basis`: a parabolic sag along
the board's x and y axes, zero at the edges of the board points' bounding box, the deflection at its centre in mm).
A flat calibration is refitted with the warp (``CalibrationOptions(board_warp=True)``, ``--board-warp``), a warped
one without; both second solves start from the calibration's camera and take a few iterations. A refined board
(``--refine-board``) is compared with the flat board's solution (the shift only: the refined board's solve is what
the user asked for, and its held-out folds would cost a refined solve each).

*Flat within the data's noise*: the warp's chi-square ``w^T C_w^-1 w`` (2 degrees of freedom, ``C_w`` the warped
solve's covariance of the warp) is at most :data:`FLAT_CHI2`, the level :data:`FLAT_LEVEL` of a flat board's
chi-square distribution (``exp(-chi2 / 2)`` is its p-value): a flat board is called warped once in 1000
calibrations.

*Held-out views*: the views are dealt into :func:`folds` (view i to fold i mod k, k = :data:`MAX_FOLDS` or fewer so
that every training set keeps :data:`MIN_TRAIN_VIEWS` views); each fold is predicted by both models fitted to the
other views (:func:`circcal.solver.holdout.prediction_error`: pose fitted, intrinsics held), 2 k solves started from
the full calibration's cameras. The model whose held-out RMS per coordinate is lower predicts better.

*Recommended*: the warped board where the board is not flat and the warped board predicts the held-out views better
(or, with too few views to hold any out, where the board is not flat); else the flat board. Where that is not the
model the calibration fitted, :attr:`BoardShape.add` / :attr:`BoardShape.remove` say which command-line option
changes it (the command line builds the exact command, :attr:`BoardShape.command`).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal.errors import InputError
from circcal.solver import CalibrationOptions, CalibrationResult, calibrate
from circcal.solver.holdout import prediction_error

__all__ = [
    "BoardShape",
    "HeldOut",
    "board_shape",
    "folds",
    "warp_chi2",
    "FLAT_LEVEL",
    "FLAT_CHI2",
    "MAX_FOLDS",
    "MIN_TRAIN_VIEWS",
    "SHIFT_PARAMS",
    "TRADE_OFF",
    "WARP_OPTION",
]

#: The level of the flatness test: a flat board's warp chi-square exceeds :data:`FLAT_CHI2` with this probability.
FLAT_LEVEL = 1e-3
#: The chi-square (2 dof) above which the board is not flat: ``-2 ln(FLAT_LEVEL)`` = 13.8.
FLAT_CHI2 = -2.0 * math.log(FLAT_LEVEL)
#: A refined board whose solve states a parameter's sigma this many times the flat board's says that the shape and
#: that parameter trade off (nearly fronto-parallel views let a bowed board stand in for a longer focal length).
TRADE_OFF = 3.0
#: Held-out folds at most (each costs two solves).
MAX_FOLDS = 4
#: Views every fold's training set keeps at least (fewer: no held-out comparison).
MIN_TRAIN_VIEWS = 4
#: The intrinsics whose shift between the two board models is reported.
SHIFT_PARAMS = ("fx", "fy", "cx", "cy")
#: The command-line option of the warped board.
WARP_OPTION = "--board-warp"


@dataclass(frozen=True)
class HeldOut:
    """Both board models predicting views they were not fitted to.

    Attributes
    ----------
    folds : int
        k: every view was held out once, with the others' models.
    flat_px, warped_px : float
        RMS per coordinate of the held-out views' residuals (pose fitted, intrinsics held), px, per model.
    n_points : int
        Held-out points predicted by both.
    """

    folds: int
    flat_px: float
    warped_px: float
    n_points: int

    @property
    def better(self) -> str:
        """``"warped"`` where the warped board predicts the held-out views better (strictly), else ``"flat"``."""
        return "warped" if self.warped_px < self.flat_px else "flat"

    def to_dict(self) -> dict[str, Any]:
        """The fields, JSON-ready.

        Returns
        -------
        dict
            ``folds``, ``flat_px``, ``warped_px``, ``n_points``, ``better``.
        """
        return {
            "folds": self.folds,
            "flat_px": self.flat_px,
            "warped_px": self.warped_px,
            "n_points": self.n_points,
            "better": self.better,
        }


@dataclass
class BoardShape:
    """What the board-shape check found (see the module).

    Attributes
    ----------
    fitted : str
        The board model the calibration fitted: ``"flat"``, ``"warped"`` (``--board-warp``) or ``"refined"``
        (``--refine-board``).
    warp_mm : tuple of float or None
        (w_x, w_y) mm, the warped board's warp (None: not fitted, or its solve failed).
    warp_std_mm : tuple of float or None
        Their standard deviations, mm.
    chi2 : float or None
        The warp's chi-square against its covariance (2 dof).
    flat : bool or None
        The board is flat within the data's noise (``chi2 <= FLAT_CHI2``); None: not tested.
    shift : dict of str to (float, float)
        Per intrinsic of :data:`SHIFT_PARAMS` held free: (other model's value - this calibration's, px; that in this
        calibration's stated sigmas). The other model: the warped board for a flat calibration, the flat board
        otherwise.
    held_out : HeldOut or None
        The held-out comparison (None: too few views, a refined board, or a fold's solve failed: see ``note``).
    recommended : str
        ``"flat"`` or ``"warped"`` (``"refined"`` for a refined calibration: nothing is recommended).
    add, remove : tuple of str
        Command-line options the recommended run adds to / removes from this one (both empty: keep this one).
    command : str or None
        The exact command of the recommended run (set by the command line, which knows the arguments given).
    note : str
        Why something was not measured; empty otherwise.
    seconds : float
        What the check cost, s.
    inflation : dict of str to float
        For a refined board: per intrinsic of :data:`SHIFT_PARAMS`, its stated sigma with the board refined over
        its sigma with the board flat, both per unit of pixel noise (the information each solve's geometry gives):
        how much of the focal length's (or principal point's) information the
        board's shape takes (:data:`TRADE_OFF` and above: shape and that parameter trade off).
    """

    fitted: str
    warp_mm: tuple[float, float] | None = None
    warp_std_mm: tuple[float, float] | None = None
    chi2: float | None = None
    flat: bool | None = None
    shift: dict[str, tuple[float, float]] = field(default_factory=dict)
    held_out: HeldOut | None = None
    recommended: str = "flat"
    add: tuple[str, ...] = ()
    remove: tuple[str, ...] = ()
    command: str | None = None
    note: str = ""
    seconds: float = 0.0
    inflation: dict[str, float] = field(default_factory=dict)

    @property
    def notable(self) -> bool:
        """Whether the verdict carries this check: the recommended board model is not the one fitted, the board is
        not flat, or the board was refined (its shift from the flat board's solution); a flat board that was fitted
        flat, or a check that could not run, is a detail."""
        return self.changes or self.flat is False or (self.fitted == "refined" and bool(self.shift))

    @property
    def changes(self) -> bool:
        """Whether the recommended board model is not the one the calibration fitted."""
        return bool(self.add or self.remove)

    def _shift_text(self) -> str:
        """The shift in words: each parameter's px and sigmas, largest in sigmas first."""
        items = sorted(self.shift.items(), key=lambda kv: -abs(kv[1][1]))
        return ", ".join(f"{n} {d:+.3g} px ({abs(s):.1f} sigma)" for n, (d, s) in items)

    def _trade_off_text(self) -> str:
        """The refined board's conditioning in words (empty where no parameter's sigma grew by TRADE_OFF)."""
        worst = {n: k for n, k in self.inflation.items() if k >= TRADE_OFF}
        if not worst:
            return ""
        items = ", ".join(f"{n} x{k:.1f}" for n, k in sorted(worst.items(), key=lambda kv: -kv[1]))
        return (
            f"; refining the board multiplies their stated sigmas ({items}): the board's shape and these "
            f"parameters trade off in these views (tilted views, at several distances, separate them)"
        )

    def line(self) -> str:
        """The verdict's line about the board's shape.

        Returns
        -------
        str
        """
        other = "the warped board" if self.fitted == "flat" else "the flat board"
        shift = f"; {other} moves the intrinsics by {self._shift_text()}" if self.shift else ""
        if self.fitted == "refined":
            if not self.shift:
                return f"board shape: refined (every point estimated); the flat board's solution: {self.note}"
            return (
                f"board shape: refined (every point estimated); against the flat board's solution the intrinsics "
                f"differ by {self._shift_text()} (in this calibration's stated sigmas)" + self._trade_off_text()
            )
        if self.warp_mm is None or self.warp_std_mm is None or self.chi2 is None:
            return f"board shape: not checked ({self.note})"
        (wx, wy), (sx, sy) = self.warp_mm, self.warp_std_mm
        warp = (
            f"mrcal's 2-parameter warp x {wx:+.3g} +- {sx:.2g} mm, y {wy:+.3g} +- {sy:.2g} mm (chi-square "
            f"{self.chi2:.3g}, 2 dof; flat up to {FLAT_CHI2:.1f}, the {100 * FLAT_LEVEL:g}% level)"
        )
        head = "flat within the data's noise" if self.flat else "NOT flat"
        text = f"board shape: {head}: {warp}{shift}"
        if self.shift:
            text += " (in this calibration's stated sigmas)"
        h = self.held_out
        if h is not None:
            text += (
                f"; held-out views ({h.folds} folds): warped board {h.warped_px:.4g} px, flat {h.flat_px:.4g} px RMS "
                f"per coordinate"
            )
        elif self.note:
            text += f"; held-out views: {self.note}"
        return text

    def recommendation(self) -> str | None:
        """The recommendation in one line where it changes the board model (None: keep this one).

        Returns
        -------
        str or None
        """
        if not self.changes:
            return None
        run = f": run {self.command}" if self.command else ""
        if self.recommended == "warped":
            why = (
                "it predicts the held-out views better"
                if self.held_out is not None
                else "the board is not flat (too few views to compare on held-out views)"
            )
            return f"recommended: the warped board ({WARP_OPTION}): {why}{run}"
        why = (
            "the board is flat within the data's noise"
            if self.flat
            else "the flat board predicts the held-out views as well or better"
        )
        return f"recommended: the flat board (without {WARP_OPTION}): {why}{run}"

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary.

        Returns
        -------
        dict
            The fields (``shift`` as ``{name: {"px", "sigmas"}}``), ``held_out`` as :meth:`HeldOut.to_dict`, the
            test's level and threshold.
        """
        return {
            "fitted": self.fitted,
            "warp_mm": None if self.warp_mm is None else list(self.warp_mm),
            "warp_std_mm": None if self.warp_std_mm is None else list(self.warp_std_mm),
            "chi2": self.chi2,
            "flat": self.flat,
            "flat_level": FLAT_LEVEL,
            "flat_chi2": FLAT_CHI2,
            "shift": {n: {"px": d, "sigmas": s} for n, (d, s) in self.shift.items()},
            "held_out": None if self.held_out is None else self.held_out.to_dict(),
            "recommended": self.recommended,
            "add": list(self.add),
            "remove": list(self.remove),
            "command": self.command,
            "note": self.note,
            "seconds": self.seconds,
            "sigma_inflation": dict(self.inflation),
        }


def warp_chi2(result: CalibrationResult) -> float | None:
    """The chi-square of a warped calibration's warp against its covariance, ``w^T C_w^-1 w`` (2 dof).

    Parameters
    ----------
    result : CalibrationResult
        A calibration with ``board_warp``.

    Returns
    -------
    float or None
        None without a warp or with a singular covariance.
    """
    w, C = result.board_warp, result.board_warp_cov
    if w is None or C is None or not np.all(np.isfinite(C)):
        return None
    try:
        return float(w @ np.linalg.solve(C, w))
    except np.linalg.LinAlgError:
        return None


def folds(n_views: int) -> list[list[int]]:
    """The held-out folds of ``n_views`` views: view i to fold i mod k, the most folds up to :data:`MAX_FOLDS` that
    leave every training set :data:`MIN_TRAIN_VIEWS` views.

    Parameters
    ----------
    n_views : int

    Returns
    -------
    list of list of int
        The views of each fold; empty when even two folds would leave a training set fewer than
        :data:`MIN_TRAIN_VIEWS` views (k folds need ``n_views - ceil(n_views / k) >= MIN_TRAIN_VIEWS``).
    """
    for k in range(MAX_FOLDS, 1, -1):
        if n_views - math.ceil(n_views / k) >= MIN_TRAIN_VIEWS:
            return [list(range(j, n_views, k)) for j in range(k)]
    return []


def _solve(
    obj: Sequence[np.ndarray],
    img: Sequence[np.ndarray],
    size: tuple[int, int],
    options: CalibrationOptions,
    start: CalibrationResult,
    views: Sequence[int] | None = None,
) -> CalibrationResult:
    """One solve of the check on ``views`` (None: all), from ``start``'s camera and poses; its warnings (no
    convergence) are the check's own."""
    keep = list(range(len(obj))) if views is None else list(views)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return calibrate(
            [obj[i] for i in keep],
            [img[i] for i in keep],
            size,
            options,
            initial=start.camera,
            start_poses=(start.rvecs[keep], start.tvecs[keep]),
        )


def _shift(this: CalibrationResult, other: CalibrationResult) -> dict[str, tuple[float, float]]:
    """(other - this px, in this's stated sigmas) per free intrinsic of :data:`SHIFT_PARAMS`."""
    names = this.camera.model.param_names
    out = {}
    for n in SHIFT_PARAMS:
        s = float(this.std.get(n, 0.0))
        if n in this.fixed or not (s > 0 and np.isfinite(s)):
            continue
        d = float(other.camera.intrinsics[names.index(n)] - this.camera.intrinsics[names.index(n)])
        out[n] = (d, d / s)
    return out


def _held_out(
    obj: Sequence[np.ndarray],
    img: Sequence[np.ndarray],
    size: tuple[int, int],
    flat: tuple[CalibrationOptions, CalibrationResult],
    warped: tuple[CalibrationOptions, CalibrationResult],
) -> HeldOut | str:
    """Both models predicting each fold from the other views (see the module); a string says why not."""
    parts = folds(len(obj))
    if not parts:
        return f"{len(obj)} views: too few to hold any out (each fit keeps {MIN_TRAIN_VIEWS})"
    sq = {"flat": 0.0, "warped": 0.0}
    n = 0
    for part in parts:
        rest = [i for i in range(len(obj)) if i not in part]
        models = {}
        for key, (o, start) in (("flat", flat), ("warped", warped)):
            try:
                models[key] = _solve(obj, img, size, o, start, rest)
            except InputError as exc:  # CalibrationError included: a training set too weak
                return f"a fold's {key} board gives no model ({exc})"
        for k in part:
            errs = {}
            for key, m in models.items():
                try:
                    errs[key] = prediction_error(m.board_lookup(np.asarray(obj[k], dtype=np.float64)), img[k], m.camera)
                except InputError:  # no pose for this view under a model: left out of both
                    break
            if len(errs) == 2:
                c = 2 * int(errs["flat"]["n_points"])
                for key in sq:
                    sq[key] += errs[key]["rms_per_coord_px"] ** 2 * c
                n += c
    if n == 0:
        return "no held-out view could be posed"
    return HeldOut(len(parts), math.sqrt(sq["flat"] / n), math.sqrt(sq["warped"] / n), n // 2)


def board_shape(result: CalibrationResult, options: CalibrationOptions, *, held_out: bool = True) -> BoardShape:
    """Fit the calibration's observations with the other board model and weigh the two (see the module).

    Parameters
    ----------
    result : CalibrationResult
        The calibration, with the observations it was fitted to (``object_points``, ``image_points``).
    options : CalibrationOptions
        The options it was made with (its lens and holds are kept; outlier rejection is not rerun: the observations
        are the ones it kept).
    held_out : bool
        Also compare the two models on held-out views (2 solves per fold).

    Returns
    -------
    BoardShape
    """
    t0 = time.perf_counter()
    obj, img = result.object_points, result.image_points
    if options.refine_board or result.board_points is not None:
        fitted = "refined"
    elif options.board_warp or result.board_warp is not None:
        fitted = "warped"
    else:
        fitted = "flat"
    if obj is None or img is None:
        return BoardShape(fitted, note="the calibration carries no observations", recommended=fitted)
    size = (result.camera.width, result.camera.height)
    base = options.replace(lens=result.camera.lens, outlier_rule=None, refine_board=False)
    flat_o, warp_o = base.replace(board_warp=False), base.replace(board_warp=True)
    other_o = warp_o if fitted == "flat" else flat_o
    try:
        other = _solve(obj, img, size, other_o, result)
    except InputError as exc:
        what = "warped" if fitted == "flat" else "flat"
        return BoardShape(
            fitted,
            note=f"the {what} board gives no model ({exc})",
            recommended=fitted,
            seconds=time.perf_counter() - t0,
        )
    shift = _shift(result, other)
    if fitted == "refined":
        # per unit of noise (each sigma over its solve's sigma_px): the flat board's residuals on a bowed board are
        # larger, which scales its sigmas up and would hide the conditioning
        inflation = {
            n: float((result.std[n] / result.sigma_px) / (other.std[n] / other.sigma_px))
            for n in shift
            if n in other.std and np.isfinite(other.std[n]) and other.std[n] > 0 and other.sigma_px > 0
        }
        return BoardShape(
            fitted, shift=shift, recommended=fitted, seconds=time.perf_counter() - t0, inflation=inflation
        )
    flat_r, warp_r = (result, other) if fitted == "flat" else (other, result)
    chi2 = warp_chi2(warp_r)
    std = warp_r.board_warp_std
    if chi2 is None or warp_r.board_warp is None or std is None:
        return BoardShape(
            fitted,
            shift=shift,
            note="the warp's covariance is singular",
            recommended=fitted,
            seconds=time.perf_counter() - t0,
        )
    is_flat = chi2 <= FLAT_CHI2
    ho: HeldOut | None = None
    note = ""
    if held_out:
        got = _held_out(obj, img, size, (flat_o, flat_r), (warp_o, warp_r))
        ho, note = (got, "") if isinstance(got, HeldOut) else (None, got)
    else:
        note = "not compared"
    warped_better = (ho.better == "warped") if ho is not None else True
    recommended = "warped" if (not is_flat and warped_better) else "flat"
    add: tuple[str, ...] = ()
    remove: tuple[str, ...] = ()
    if recommended != fitted:
        add, remove = ((WARP_OPTION,), ()) if recommended == "warped" else ((), (WARP_OPTION,))
    return BoardShape(
        fitted,
        warp_mm=(float(warp_r.board_warp[0]), float(warp_r.board_warp[1])),
        warp_std_mm=(float(std[0]), float(std[1])),
        chi2=chi2,
        flat=bool(is_flat),
        shift=shift,
        held_out=ho,
        recommended=recommended,
        add=add,
        remove=remove,
        note=note,
        seconds=time.perf_counter() - t0,
    )
