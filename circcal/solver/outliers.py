"""Outlier rejection: points (and whole views) that the model cannot explain are left out and the solve repeated
until nothing more is left out; every rejection is kept with its residual and reason.

The rule (:class:`OutlierRule`), per round, after a solve:

1. **Views.** A view whose typical point is itself an outlier (its robust residual scale, 1.4826 x the median
   absolute residual coordinate, above ``k`` times the noise level of the views, the median of the views' RMS per
   coordinate) is dropped, the worst such view first: a mislabelled or foreign view. Checked first, because such a
   view inflates the overall RMS and would hide the points' outliers (masking).
2. **Points.** A point whose residual exceeds ``k`` sigma in x or in y is dropped (mrcal's per-coordinate test),
   ``sigma = max(the solve's noise estimate sqrt(SSR / (2N - n)), sigma_floor_px)``. A view that has lost more than
   ``max_view_loss`` of its points, or is left with fewer than :data:`~circcal.observations.MIN_POINTS_PER_VIEW`, is
   dropped whole.

``k`` defaults to 5: mrcal's threshold for "new outliers found" (mrcal.c ``markOutliers``: k1 = 5 sigma, with sigma the
RMS per coordinate of the inliers). circcal does not take mrcal's second step (once any point passes 5 sigma, mark
every point past k0 = 4 sigma too): that sweep is what rejected 12 of 686 good points on noiseless renders, whose
residuals are tiny, systematic and not Gaussian. ``sigma_floor_px`` plays the part of mrcal 2.2's
``observed_pixel_uncertainty`` floor: below 0.05 px per coordinate nobody's centres are noise-limited on real
photographs (print, JPEG, lens), so a residual under 5 x 0.05 = 0.25 px is never called an outlier however small the
others are. On every rendered fixture and both real sets in ../shared/data/realdata the rule rejects nothing
(tested), so their results are unchanged.
"""

from __future__ import annotations

import enum
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, TypeVar

import numpy as np

from circcal.errors import CalibrationError, InputError
from circcal.observations import MIN_POINTS_PER_VIEW, check_observations

if TYPE_CHECKING:  # annotations only
    from circcal.model import Camera

__all__ = [
    "OutlierReason",
    "OutlierRule",
    "Rejected",
    "Rejections",
    "reject_outliers",
    "DEFAULT_K",
    "SIGMA_FLOOR_PX",
    "MAX_VIEW_LOSS",
    "MAX_ROUNDS",
    "MAD_TO_SIGMA",
]

#: Threshold in standard deviations: mrcal's (mrcal.c markOutliers, k1 = 5).
DEFAULT_K = 5.0
#: The least per-coordinate noise (px) the test assumes (see the module: mrcal 2.2's observed_pixel_uncertainty
#: floor); real photographs' centres are not better than this.
SIGMA_FLOOR_PX = 0.05
#: A view that loses more than this share of its points is dropped whole ("most of its points").
MAX_VIEW_LOSS = 0.5
#: Rounds of reject-and-resolve at most (each round drops a view or every point past the threshold; real sets
#: settle in 1-3).
MAX_ROUNDS = 25
#: Median absolute deviation -> standard deviation for a Gaussian.
MAD_TO_SIGMA = 1.4826


class OutlierReason(str, enum.Enum):
    """Why an observation was left out (the values are what model.json carries; :data:`OUTLIER_TEXT` in words).

    Attributes
    ----------
    POINT : str
        ``"outlier-point"``.
    VIEW : str
        ``"outlier-view"``.
    BAD_DOT : str
        ``"bad-dot"``.
    """

    POINT = "outlier-point"
    VIEW = "outlier-view"
    BAD_DOT = "bad-dot"


#: Each :class:`OutlierReason` in words (the README's list of codes is these).
OUTLIER_TEXT: dict[OutlierReason, str] = {
    OutlierReason.POINT: "the point's residual exceeds k sigma in x or y",
    OutlierReason.VIEW: "the view's typical residual is an outlier, or it lost most of its points",
    OutlierReason.BAD_DOT: "the detector could tell the dot is bad (its ellipse fit, area or shape), before any solve",
}


@dataclass(frozen=True)
class OutlierRule:
    """The outlier rule's numbers (module docstring).

    Attributes
    ----------
    k : float
        Threshold in standard deviations (> 0).
    sigma_floor_px : float
        The least noise assumed, px (>= 0).
    max_view_loss : float
        Share of a view's points beyond which the view is dropped (in (0, 1)).
    max_rounds : int

    Raises
    ------
    InputError
        ``k``, ``sigma_floor_px`` or ``max_view_loss`` out of range (on construction).
    """

    k: float = DEFAULT_K
    sigma_floor_px: float = SIGMA_FLOOR_PX
    max_view_loss: float = MAX_VIEW_LOSS
    max_rounds: int = MAX_ROUNDS

    def __post_init__(self) -> None:
        if not (np.isfinite(self.k) and self.k > 0):
            raise InputError(f"outlier threshold k must be a positive number of sigmas, got {self.k!r}")
        if not (np.isfinite(self.sigma_floor_px) and self.sigma_floor_px >= 0):
            raise InputError(f"sigma_floor_px must be >= 0, got {self.sigma_floor_px!r}")
        if not 0 < self.max_view_loss < 1:
            raise InputError(f"max_view_loss must lie in (0, 1), got {self.max_view_loss!r}")


@dataclass
class Rejected:
    """One observation left out.

    Attributes
    ----------
    view : int
        Index of the view as given.
    point : int or None
        Index of the point among that view's points as given to the solve (for a bad dot, flagged before any solve:
        its index in the board's order); None for a whole view (``object_mm`` names the board point either way).
    object_mm : ndarray, shape (3,), or None
        The board point, mm (None for a view).
    image_px : ndarray, shape (2,), or None
        Its image point, px (None for a view).
    residual_px : ndarray, shape (2,), or float
        Observed - projected when it was left out, px (for a view: the RMS per coordinate of its points, one number).
    sigma_px : float
        The noise level the test used, px.
    round : int
        The solve after which it was left out (0 = before any solve: a bad dot).
    reason : OutlierReason
    detail : str
        In words.
    """

    view: int
    point: int | None
    object_mm: np.ndarray | None
    image_px: np.ndarray | None
    residual_px: Any
    sigma_px: float
    round: int
    reason: OutlierReason
    detail: str

    def to_dict(self) -> dict[str, Any]:
        """The model.json entry.

        Returns
        -------
        dict
            ``view``, ``reason``, ``detail``, ``round``, ``sigma_px``, ``residual_px`` and, for a point, ``point``,
            ``object_mm``, ``image_px``.
        """
        d: dict[str, Any] = {
            "view": self.view,
            "reason": self.reason.value,
            "detail": self.detail,
            "round": self.round,
            "sigma_px": self.sigma_px,
        }
        if self.point is not None:
            d.update(
                point=self.point,
                object_mm=np.asarray(self.object_mm).tolist(),
                image_px=np.asarray(self.image_px).tolist(),
            )
        d["residual_px"] = np.asarray(self.residual_px).tolist() if self.residual_px is not None else None
        return d


@dataclass
class Rejections:
    """What outlier rejection left out of one calibration.

    Attributes
    ----------
    rule : OutlierRule
    kept_views : list of int
        The given views' indices that remain, in order (view i of the result is given view ``kept_views[i]``).
    n_views, n_points : int
        How many were given.
    rounds : int
        Solves made.
    items : list of Rejected
        Every rejection.
    view_names : list of str or None
        The given views' names when the caller knows them (image files).
    dropped_views : list of Rejected
        The whole views left out (property).
    """

    rule: OutlierRule
    kept_views: list[int]
    n_views: int
    n_points: int
    rounds: int = 0
    items: list[Rejected] = field(default_factory=list)
    view_names: list[str] | None = None

    @property
    def dropped_views(self) -> list[Rejected]:
        """The whole views left out (the items whose ``point`` is None)."""
        return [r for r in self.items if r.point is None]

    def points_of(self, view: int) -> list[Rejected]:
        """The rejected points of a given view.

        Parameters
        ----------
        view : int
            Index of a given (kept) view.

        Returns
        -------
        list of Rejected
        """
        return [r for r in self.items if r.view == view and r.point is not None]

    def view_entries(self, i: int) -> list[dict[str, Any]]:
        """The model.json entries of the points left out of one of the result's views.

        Parameters
        ----------
        i : int
            Index of the view in the result (not as given).

        Returns
        -------
        list of dict
            :meth:`Rejected.to_dict` of each.
        """
        return [r.to_dict() for r in self.points_of(self.kept_views[i])]

    def kept_centres(self, centres: Sequence[np.ndarray], board_points: np.ndarray) -> list[np.ndarray]:
        """The kept views' centres with every rejected point set to NaN: exactly what the result was fitted to.

        Parameters
        ----------
        centres : sequence of ndarray, each shape (P, 2)
            One array per given view, px, in the board's point order.
        board_points : ndarray, shape (P, 3)
            That order, mm.

        Returns
        -------
        list of ndarray, each shape (P, 2)
            One per kept view, px.
        """
        index = {tuple(k): i for i, k in enumerate(np.round(board_points, 6).tolist())}
        out: list[np.ndarray] = []
        for v in self.kept_views:
            c = np.array(centres[v], dtype=np.float64)
            for r in self.points_of(v):
                c[index[tuple(np.round(np.asarray(r.object_mm, dtype=np.float64), 6).tolist())]] = np.nan
            out.append(c)
        return out

    def to_dict(self) -> dict[str, Any]:
        """The model.json ``outliers`` section.

        Returns
        -------
        dict
            ``rule`` (k, sigma_floor_px, max_view_loss), ``rounds``, ``n_views``, ``n_points``, ``kept_views``,
            ``rejected`` (:meth:`Rejected.to_dict` of each).
        """
        return {
            "rule": {
                "k": self.rule.k,
                "sigma_floor_px": self.rule.sigma_floor_px,
                "max_view_loss": self.rule.max_view_loss,
            },
            "rounds": self.rounds,
            "n_views": self.n_views,
            "n_points": self.n_points,
            "kept_views": list(self.kept_views),
            "rejected": [r.to_dict() for r in self.items],
        }


def _view_scale(r: np.ndarray) -> float:
    """Robust per-coordinate residual scale of one view (px): 1.4826 x median |residual coordinate|."""
    return float(MAD_TO_SIGMA * np.median(np.abs(r)))


class Solution(Protocol):
    """What :func:`reject_outliers` reads of a solve (a :class:`~circcal.solver.CalibrationResult`: this module does not
    import the solver): a dataclass with an ``outliers`` field and these attributes.

    Attributes
    ----------
    camera : Camera
    residuals : list of ndarray, each shape (N_v, 2)
        Observed - projected, px.
    sigma_px : float
        The per-coordinate noise estimate, px.
    """

    __dataclass_fields__: ClassVar[dict[str, Any]]

    @property
    def camera(self) -> Camera:
        """The calibrated camera."""
        ...

    @property
    def residuals(self) -> list[np.ndarray]:
        """Per view (N_v, 2) px, observed - projected."""
        ...

    @property
    def sigma_px(self) -> float:
        """The per-coordinate noise estimate, px."""
        ...


_Solved = TypeVar("_Solved", bound=Solution)

#: One solve for :func:`reject_outliers`: (object points per view, image points per view, initial camera or None)
#: -> a :class:`~circcal.solver.CalibrationResult` (:func:`circcal.solver.calibrate` with the calibration's options).
Solve = Callable[[list[np.ndarray], list[np.ndarray], "Camera | None"], Solution]


def reject_outliers(
    solve: Callable[[list[np.ndarray], list[np.ndarray], Camera | None], _Solved],
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    rule: OutlierRule,
    initial: Camera | None = None,
) -> _Solved:
    """Outlier rejection by ``rule`` around a solver (see the module): solve, leave out what the rule rejects,
    re-solve from the current camera, until nothing more is rejected.

    Parameters
    ----------
    solve : callable
        ``solve(object_points, image_points, initial)``: one plain solve of the kept observations (per view (N_v, 3)
        mm and (N_v, 2) px) from ``initial`` (a Camera or None), with the calibration's options (the caller's
        :func:`circcal.solver.calibrate`: this module does not import the solver).
    object_points, image_points : sequence of ndarray
        Per view (N_v, 3) mm and (N_v, 2) px, as given to the calibration.
    image_size : tuple of int
        (width, height) px.
    rule : OutlierRule
    initial : Camera or None
        The first solve's start.

    Returns
    -------
    CalibrationResult
        The final solve (its views are the kept ones) with ``outliers`` set to :class:`Rejections`; when nothing is
        rejected it is the plain solve's. Only the final solve's warnings are issued.

    Raises
    ------
    CalibrationError
        Too few views or points remain, or the rule does not settle in ``rule.max_rounds`` rounds.
    """
    obj, img, size = check_observations(object_points, image_points, image_size)
    active = [np.ones(len(o), dtype=bool) for o in obj]
    kept = list(range(len(obj)))
    out = Rejections(rule, kept, len(obj), int(sum(len(o) for o in obj)))

    caught: list[warnings.WarningMessage] = []

    def solve_kept(start: Camera | None) -> _Solved:
        # a solve's warnings (non-convergence, large residuals) matter only for the final one: they are re-issued
        # for it alone, the intermediate solves still hold the outliers being removed
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            r = solve([obj[v][active[v]] for v in kept], [img[v][active[v]] for v in kept], start)
        caught[:] = w
        return r

    res = solve_kept(initial)
    for rnd in range(1, rule.max_rounds + 1):
        out.rounds = rnd
        resid = res.residuals  # per kept view (n_active, 2), observed - proj
        view_rms = np.array([np.sqrt(np.mean(r**2)) for r in resid])
        sigma_views = max(float(np.median(view_rms)), rule.sigma_floor_px)
        scales = np.array([_view_scale(r) for r in resid])
        bad_views = np.flatnonzero(scales > rule.k * sigma_views)
        if bad_views.size and len(kept) > 1:
            i = int(bad_views[np.argmax(scales[bad_views])])
            v = kept[i]
            out.items.append(
                Rejected(
                    v,
                    None,
                    None,
                    None,
                    float(view_rms[i]),
                    sigma_views,
                    rnd,
                    OutlierReason.VIEW,
                    f"typical residual {scales[i]:.3g} px per coordinate (robust) is more than "
                    f"{rule.k:g} x the views' noise level {sigma_views:.3g} px: a mislabelled or "
                    f"foreign view",
                )
            )
            kept.remove(v)
            res = solve_kept(res.camera)
            continue
        sigma = max(float(res.sigma_px), rule.sigma_floor_px)
        changed = False
        for i, v in enumerate(list(kept)):
            idx = np.flatnonzero(active[v])  # given indices of this view's active points
            r = resid[i]
            hit = np.flatnonzero(np.max(np.abs(r), axis=1) > rule.k * sigma)
            if not hit.size:
                continue
            changed = True
            for j in hit:
                p = int(idx[j])
                out.items.append(
                    Rejected(
                        v,
                        p,
                        obj[v][p],
                        img[v][p],
                        r[j].copy(),
                        sigma,
                        rnd,
                        OutlierReason.POINT,
                        f"residual ({r[j, 0]:+.3g}, {r[j, 1]:+.3g}) px exceeds {rule.k:g} x sigma {sigma:.3g} px",
                    )
                )
                active[v][p] = False
            left = int(active[v].sum())
            if left < (1.0 - rule.max_view_loss) * len(obj[v]) or left < MIN_POINTS_PER_VIEW:
                out.items.append(
                    Rejected(
                        v,
                        None,
                        None,
                        None,
                        float(view_rms[i]),
                        sigma,
                        rnd,
                        OutlierReason.VIEW,
                        f"lost {len(obj[v]) - left} of its {len(obj[v])} points as outliers",
                    )
                )
                kept.remove(v)
        if not changed:
            break
        if len(kept) == 0:
            raise CalibrationError("outlier rejection left no view")
        res = solve_kept(res.camera)
    else:
        raise CalibrationError(
            f"outlier rejection did not settle in {rule.max_rounds} rounds: the model cannot "
            f"explain these observations (wrong board geometry or lens model?)"
        )
    out.kept_views = list(kept)
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return replace(res, outliers=out)
