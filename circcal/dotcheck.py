"""Dots the detector can already tell are bad, before any solve: an ellipse that does not fit its own edge points
(a dot partly occluded, merged with clutter, cut by a shadow or a glare edge), or an area out of line with its grid
neighbours' (a blob that is not the printed dot).

A :class:`circcal.detector.Detection` that says which dots it dropped itself (``dropped``: board point -> reason;
those centres are NaN already, so no solve sees them) is taken at its word and its drops are listed; the dots it
kept are checked here too, from the stored edge points and the ellipses fitted to them (the model-free detection's
conics, in the image as observed):

* **fit**: the RMS geometric distance of a dot's edge points from its ellipse (first order: ``|x^T Q x| / |grad|``)
  above :data:`FIT_RATIO` times the median over the image's dots and above :data:`FIT_FLOOR_PX`;
* **area**: the ellipse's area differs from the median of its grid neighbours' by more than a factor
  :data:`AREA_RATIO`, each area taken over the area its dot is printed with (a board's markers, printed larger,
  are compared as the plain dots are: :meth:`circcal.board.Board.radii_mm`); a dot larger than that on a board
  that declares no markers is a marker the user did not declare (an orientation dot) and is kept, as the detector
  keeps it (:mod:`circcal.detector.measure.baddots`): only a smaller one is flagged there.

Measured on every rendered fixture variant (clean to defocused, motion-blurred, cluttered) and the two real sets:
the worst dot's fit residual is 8x its image's median and 0.16 px at most, neighbouring areas agree within 1.4x
(1.8x for ``small-noisy``'s 11 px dots in heavy noise); nothing is flagged there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BadDot", "bad_dots", "bad_dot_rejections", "fit_residuals", "FIT_RATIO", "FIT_FLOOR_PX", "AREA_RATIO"]

#: A dot's ellipse-fit residual must exceed this many times the image's median dot residual to be flagged ...
FIT_RATIO = 10.0
#: ... and this many px (RMS distance of its edge points from the ellipse): a sub-pixel misfit is a blurred or
#: noisy dot, not a bad one.
FIT_FLOOR_PX = 0.25
#: A dot whose ellipse area is this many times larger (or smaller) than its grid neighbours' median is flagged
#: (perspective changes neighbouring dots' areas by up to 40% on the fixtures and real sets; the small, very noisy
#: dots of ``small-noisy`` reach 1.8x at a corner with a centre still good to 0.03 px).
AREA_RATIO = 2.0


@dataclass(frozen=True)
class BadDot:
    """One dot the check finds bad.

    Attributes
    ----------
    index : int
        The dot (board order).
    value : float
        The measured fit residual (px) or area ratio.
    reason : str
        ``"fit"``, ``"area"`` or the detector's own.
    detail : str
        In words.
    """

    index: int
    value: float
    reason: str
    detail: str


def fit_residuals(edge_points: list[np.ndarray], conics: np.ndarray) -> np.ndarray:
    """RMS first-order geometric distance of each dot's edge points from its conic. All dots' points in one pass.

    Parameters
    ----------
    edge_points : list of (ndarray, shape (M_k, 2), or None)
        Each dot's edge points, px.
    conics : ndarray, shape (N, 3, 3)
        Each dot's conic.

    Returns
    -------
    ndarray, shape (N,)
        px; NaN for a dot without edge points.
    """
    n = len(edge_points)
    sizes = np.array([0 if P is None else len(P) for P in edge_points], dtype=np.int64)
    if not sizes.any():
        return np.full(n, np.nan)
    P = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in edge_points if p is not None])
    dot = np.repeat(np.arange(n), sizes)
    Q = np.asarray(conics, dtype=np.float64)[dot]  # (M, 3, 3)
    h = np.column_stack([P, np.ones(len(P))])
    Qh = np.einsum("mjk,mk->mj", Q, h)  # Q is symmetric: Q h = (h^T Q)^T
    alg = np.einsum("mj,mj->m", h, Qh)
    grad = 2.0 * np.hypot(Qh[:, 0], Qh[:, 1])
    sq = np.bincount(dot, weights=(alg / np.maximum(grad, 1e-300)) ** 2, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(sizes > 0, np.sqrt(sq / np.maximum(sizes, 1)), np.nan)


def _areas(conics: np.ndarray) -> np.ndarray:
    """(N,) px^2 ellipse areas (NaN where a conic is not an ellipse)."""
    from circcal.detector.measure.ellipse import conic_params_batch

    _, axes, _, ok = conic_params_batch(conics)
    a = np.pi * axes[:, 0] * axes[:, 1]
    return np.where(ok, a, np.nan)


def _neighbour_medians(grid: np.ndarray) -> np.ndarray:
    """(rows, cols): the median of each cell's up-to-4 grid neighbours' values in ``grid`` (rows, cols), NaN values
    (and the border) left out; NaN where none is left."""
    from circcal.detector.measure.robust import row_medians

    g = np.pad(np.asarray(grid, dtype=np.float64), 1, constant_values=np.nan)
    nb = np.stack([g[:-2, 1:-1], g[2:, 1:-1], g[1:-1, :-2], g[1:-1, 2:]], axis=-1)  # up, down, left, right
    return row_medians(nb.reshape(-1, 4)).reshape(grid.shape)


def bad_dots(detection, rows: int, cols: int, radii_mm: np.ndarray | None = None) -> list[BadDot]:
    """The dots of a found ``detection`` the detector can tell are bad (see the module).

    Parameters
    ----------
    detection : circcal.detector.Detection
        A detection of a ``rows`` x ``cols`` grid, board order.
    rows, cols : int
        The grid's size.
    radii_mm : (rows * cols,) ndarray, optional
        The printed radius of every dot (:meth:`circcal.board.Board.radii_mm`): areas are compared over the printed
        ones, and a larger dot is flagged only where the radii differ (declared markers). ``None``: all dots alike,
        larger ones flagged too.

    Returns
    -------
    list of BadDot
        In board order; [] when there are none or the detection holds no edge points.
    """
    dropped = getattr(detection, "dropped", None) or {}
    out: list[BadDot] = [BadDot(int(i), float("nan"), "detector", str(why)) for i, why in sorted(dropped.items())]
    if detection.edge_points is None or detection.conics is None:
        return out
    res = fit_residuals(detection.edge_points, detection.conics)
    res[list(dropped)] = np.nan
    if not np.isfinite(res).any():
        return out
    med = float(np.nanmedian(res))
    for k in np.flatnonzero(res > max(FIT_RATIO * med, FIT_FLOOR_PX)):
        out.append(
            BadDot(
                int(k),
                float(res[k]),
                "fit",
                f"its ellipse misses its edge points by {res[k]:.2f} px RMS "
                f"({res[k] / med:.0f}x the image's median dot)",
            )
        )
    area = _areas(detection.conics)
    if len(area) == rows * cols:
        area[list(dropped)] = np.nan
        larger_too = True
        if radii_mm is not None:
            r = np.asarray(radii_mm, dtype=np.float64).reshape(-1)
            area = area / (r * r)  # over the printed area (a common factor pi aside)
            larger_too = bool(np.ptp(r) > 0)
        ratio = area / _neighbour_medians(area.reshape(rows, cols)).ravel()
        flagged = {b.index for b in out}
        with np.errstate(invalid="ignore", divide="ignore"):
            worse = 1.0 / ratio if not larger_too else np.maximum(ratio, 1.0 / ratio)
            far = np.isfinite(ratio) & (ratio > 0) & (worse > AREA_RATIO)
        for k in np.flatnonzero(far):
            if int(k) not in flagged:
                out.append(
                    BadDot(int(k), float(ratio[k]), "area", f"its area is {ratio[k]:.2f}x its neighbours' median")
                )
    return sorted(out, key=lambda b: b.index)


def bad_dot_rejections(detections, board) -> tuple[list[list[int]], list]:
    """The bad dots of found detections, to leave out of every solve.

    Parameters
    ----------
    detections : sequence of Detection
        Found ones, one per view, board order.
    board : Board

    Returns
    -------
    exclude : list of list of int
        The indices of each view's bad dots.
    rejected : list of Rejected
        One :class:`circcal.solver.outliers.Rejected` per bad dot (round 0: before any solve; ``point`` is the dot's
        index in the board's order, the view's position among the detections given).
    """
    from circcal.solver.outliers import OutlierReason, Rejected

    board_pts = board.object_points()
    exclude: list[list[int]] = []
    items = []
    for v, d in enumerate(detections):
        bad = bad_dots(d, board.rows, board.cols, board.radii_mm())
        exclude.append([b.index for b in bad])
        for b in bad:
            items.append(
                Rejected(
                    v,
                    b.index,
                    board_pts[b.index],
                    np.asarray(d.centres[b.index], dtype=np.float64),
                    None,
                    float("nan"),
                    0,
                    OutlierReason.BAD_DOT,
                    f"{b.reason}: {b.detail}",
                )
            )
    return exclude, items
