"""Reprojection-error statistics in the three conventions people quote, written once.

* ``rms_per_point_px``: sqrt(sum |dq|^2 / N_points), the RMS of the 2-D error per point: what
  ``cv2.calibrateCamera`` returns (about 1.414 sigma for per-axis noise sigma).
* ``rms_per_coord_px``: sqrt(sum (dx^2 + dy^2) / (2 N_points)), the RMS per coordinate: what mrcal reports (~sigma).
* ``mean_2d_px``: mean of |dq|, the paper's eq. 22 and its tables (~1.253 sigma).

Every number circcal prints or writes names its convention in the key.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

SQRT2 = float(np.sqrt(2.0))


def error_stats(residuals: np.ndarray) -> dict[str, float]:
    """Reprojection error statistics in the three conventions.

    Parameters
    ----------
    residuals : ndarray, shape (..., 2)
        Reprojection errors, px (NaN rows are ignored).

    Returns
    -------
    dict of str to float
        ``{"n_points", "rms_per_point_px", "rms_per_coord_px", "mean_2d_px", "max_2d_px"}`` (NaN without points).

    Examples
    --------
    >>> error_stats(np.array([[3.0, 4.0]]))["rms_per_point_px"]
    5.0
    """
    r = np.asarray(residuals, dtype=np.float64).reshape(-1, 2)
    r = r[np.all(np.isfinite(r), axis=1)]
    if len(r) == 0:
        nan = float("nan")
        return {"n_points": 0, "rms_per_point_px": nan, "rms_per_coord_px": nan, "mean_2d_px": nan, "max_2d_px": nan}
    norm = np.hypot(r[:, 0], r[:, 1])
    ms = float(np.mean(norm**2))
    return {
        "n_points": int(len(r)),
        "rms_per_point_px": float(np.sqrt(ms)),
        "rms_per_coord_px": float(np.sqrt(ms / 2.0)),
        "mean_2d_px": float(np.mean(norm)),
        "max_2d_px": float(np.max(norm)),
    }


def error_stats_per_view(residuals: Sequence[np.ndarray]) -> tuple[dict[str, float], list[dict[str, float]]]:
    """:func:`error_stats` of all views' residuals together and of each view's, in one vectorised pass (a solve's
    statistics are computed once, not once per view).

    Parameters
    ----------
    residuals : sequence of ndarray, each shape (N_v, 2)
        Per view, px (NaN rows ignored).

    Returns
    -------
    overall : dict of str to float
    per_view : list of dict
        The same keys and values as :func:`error_stats` (sums in another order: equal to ~1e-15 relative).
    """
    if len(residuals) == 0:
        return error_stats(np.zeros((0, 2))), []
    views = [np.asarray(x, dtype=np.float64).reshape(-1, 2) for x in residuals]
    counts = np.array([len(x) for x in views], dtype=np.int64)
    r = np.concatenate(views)
    view = np.repeat(np.arange(len(counts)), counts)
    ok = np.all(np.isfinite(r), axis=1)
    r, view = r[ok], view[ok]
    norm = np.hypot(r[:, 0], r[:, 1])
    V = len(counts)
    n = np.bincount(view, minlength=V)
    ss = np.bincount(view, weights=norm * norm, minlength=V)
    s1 = np.bincount(view, weights=norm, minlength=V)
    mx = np.full(V, np.nan)
    seen = n > 0
    if np.any(seen):  # the rows are in view order: one reduceat over the views that kept a point
        mx[seen] = np.maximum.reduceat(norm, (np.cumsum(n) - n)[seen])
    with np.errstate(invalid="ignore", divide="ignore"):
        empty = n == 0
        ms = np.where(empty, np.nan, ss / n)
        cols = (
            n.tolist(),
            np.sqrt(ms).tolist(),
            np.sqrt(ms / 2.0).tolist(),
            np.where(empty, np.nan, s1 / n).tolist(),
            np.where(empty, np.nan, mx).tolist(),
        )
    keys = ("n_points", "rms_per_point_px", "rms_per_coord_px", "mean_2d_px", "max_2d_px")
    per_view = [dict(zip(keys, row)) for row in zip(*cols)]
    return error_stats(r), per_view


def per_point_to_per_coord(rms_per_point: float) -> float:
    """OpenCV's RMS (2-D, per point) -> mrcal's RMS (per coordinate).

    Parameters
    ----------
    rms_per_point : float
        px.

    Returns
    -------
    float
        px.
    """
    return rms_per_point / SQRT2


def per_coord_to_per_point(rms_per_coord: float) -> float:
    """mrcal's RMS (per coordinate) -> OpenCV's RMS (2-D, per point).

    Parameters
    ----------
    rms_per_coord : float
        px.

    Returns
    -------
    float
        px.
    """
    return rms_per_coord * SQRT2
