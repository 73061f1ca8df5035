"""Point correspondences of a planar board, checked once: the rules every solver in circcal (its own and every
reference adapter's) takes its input under.

Observations are per view: ``object_points`` (N_v, 3) board coordinates in mm with z = 0 (an (N_v, 2) array is
taken as z = 0; OpenCV's (N_v, 1, 3) is accepted), ``image_points`` (N_v, 2) px in OpenCV's convention (integer
coordinates are pixel centres; (N_v, 1, 2) accepted), and one ``image_size`` (width, height) in pixels. Views may
hold different subsets of the board's points.
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence

import numpy as np

from circcal.errors import CalibrationError, InputError

__all__ = [
    "MIN_VIEWS",
    "MIN_POINTS_PER_VIEW",
    "PLANAR_TOL",
    "BOARD_KEY_DECIMALS",
    "check_image_size",
    "check_observations",
    "distinct_points",
    "SAME_VIEW_PX",
    "same_views",
]

#: Views a calibration needs at the least: Zhang's closed form needs 2 for the four intrinsics, and a third view is
#: the least that leaves the distortion and the poses any redundancy (10-20 well-tilted views are what a good
#: calibration uses).
MIN_VIEWS = 3
#: Points a view needs at the least: a pose has 6 parameters and a board homography 8, so with fewer than 6 points a
#: view adds (almost) nothing to the intrinsics beyond its own pose.
MIN_POINTS_PER_VIEW = 6
#: Board points must lie on z = 0 to this fraction of the board's extent (a planar target; the solver's closed-form
#: start assumes it). 1e-9 leaves room for float rounding of board coordinates only.
PLANAR_TOL = 1e-9


def check_image_size(image_size: object) -> tuple[int, int]:
    """``(width, height)`` as two positive integers (numpy integers and integral floats accepted; booleans, NaN and
    fractions refused).

    Parameters
    ----------
    image_size : object
        (width, height), px.

    Returns
    -------
    tuple of int

    Raises
    ------
    InputError
        Saying what was given.

    Examples
    --------
    >>> check_image_size((640.0, 480))
    (640, 480)
    """
    try:
        w, h = image_size  # type: ignore[misc]
    except (TypeError, ValueError):
        raise InputError(f"image_size must be (width, height) in pixels, got {image_size!r}") from None
    out = []
    for v in (w, h):
        if (
            isinstance(v, (bool, np.bool_))
            or not isinstance(v, numbers.Real)
            or not np.isfinite(float(v))
            or float(v) != int(v)
            or int(v) <= 0
        ):
            raise InputError(f"image_size must be (width, height) as positive integers, got {image_size!r}")
        out.append(int(v))
    return out[0], out[1]


def check_observations(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: object,
    *,
    min_views: int = MIN_VIEWS,
    view_names: Sequence[str] | None = None,
) -> tuple[list[np.ndarray], list[np.ndarray], tuple[int, int]]:
    """Check and normalise observations.

    Refused: a different number of object- and image-point views, fewer than ``min_views`` views, a view whose two
    arrays differ in length or shape, fewer than :data:`MIN_POINTS_PER_VIEW` points, NaN/inf, image points outside
    the image (pixel centres run 0..W-1, so the image spans -0.5..W-0.5), board points off the plane z = 0.

    Parameters
    ----------
    object_points : sequence of ndarray, each shape (N_v, 3)
        mm (OpenCV's (N_v, 1, 3) accepted).
    image_points : sequence of ndarray, each shape (N_v, 2)
        px (OpenCV's (N_v, 1, 2) accepted).
    image_size : object
        (width, height), px (:func:`check_image_size`).
    min_views : int
    view_names : sequence of str, optional
        Each view's name for the messages (a rig's instants); default its index (``view 3``).

    Returns
    -------
    object_points : list of ndarray, each shape (N_v, 3)
        float64 copies, mm.
    image_points : list of ndarray, each shape (N_v, 2)
        float64 copies, px.
    image_size : tuple of int
        ``(width, height)``.

    Raises
    ------
    CalibrationError
        (an ``InputError``) naming the view and what is wrong.
    InputError
        A malformed ``image_size``.
    """
    w, h = check_image_size(image_size)
    if len(object_points) != len(image_points):
        raise CalibrationError(
            f"got {len(object_points)} object-point sets but {len(image_points)} image-point "
            f"sets; expected one of each per view"
        )

    def label(v: int) -> str:
        return f"view {v}" if view_names is None else f"view {view_names[v]!r}"

    obj, img = [], []
    for v, (o, p) in enumerate(zip(object_points, image_points)):
        o = np.asarray(o, dtype=np.float64)
        p = np.asarray(p, dtype=np.float64)
        if o.ndim == 3 and o.shape[1] == 1:  # OpenCV's (N, 1, 3)
            o = o[:, 0]
        if p.ndim == 3 and p.shape[1] == 1:
            p = p[:, 0]
        if o.ndim == 2 and o.shape[1] == 2:
            o = np.concatenate([o, np.zeros((len(o), 1))], axis=1)
        if o.ndim != 2 or o.shape[1] != 3:
            raise CalibrationError(f"{label(v)}: object points must be (N, 3) mm, got shape {o.shape}")
        if p.ndim != 2 or p.shape[1] != 2:
            raise CalibrationError(f"{label(v)}: image points must be (N, 2) px, got shape {p.shape}")
        if len(o) != len(p):
            raise CalibrationError(f"{label(v)}: {len(o)} object points but {len(p)} image points")
        obj.append(o)
        img.append(p)
    if not _all_valid(obj, img, w, h):  # one vectorised pass; the per-view rules only to name what is wrong
        for v, (o, p) in enumerate(zip(obj, img)):
            _check_view(label(v), o, p, w, h)
    if len(obj) < min_views:
        raise CalibrationError(
            f"{len(obj)} usable view(s); calibration needs at least {min_views} views of the "
            f"board (10-20 well-tilted views recommended)"
        )
    return obj, img, (w, h)


def _all_valid(obj: list[np.ndarray], img: list[np.ndarray], w: int, h: int) -> bool:
    """Whether every view passes :func:`_check_view`, checked over all views at once."""
    counts = np.array([len(o) for o in obj])
    if len(obj) == 0 or np.any(counts < MIN_POINTS_PER_VIEW):
        return len(obj) == 0
    obj_all, P = np.concatenate(obj), np.concatenate(img)
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(obj_all))):
        return False
    if not np.all((P[:, 0] >= -0.5) & (P[:, 0] <= w - 0.5) & (P[:, 1] >= -0.5) & (P[:, 1] <= h - 0.5)):
        return False
    scale = np.maximum(1.0, np.maximum.reduceat(np.abs(obj_all[:, :2]).max(axis=1), np.cumsum(counts) - counts))
    return bool(np.all(np.abs(obj_all[:, 2]) <= PLANAR_TOL * np.repeat(scale, counts)))


def _check_view(label: str, o: np.ndarray, p: np.ndarray, w: int, h: int) -> None:
    """The value rules for the view named ``label`` (``o`` (N, 3) mm, ``p`` (N, 2) px): raises naming what is wrong."""
    bad = np.flatnonzero(~np.all(np.isfinite(p), axis=1))
    if bad.size:
        raise CalibrationError(
            f"{label}: {bad.size} image point(s) are NaN/inf (non-finite; indices {bad[:10].tolist()}"
            f"{'...' if bad.size > 10 else ''}); pass only the detected points with their object points"
        )
    if not np.all(np.isfinite(o)):
        raise CalibrationError(f"{label}: object points contain NaN/inf (non-finite)")
    if len(o) < MIN_POINTS_PER_VIEW:
        raise CalibrationError(
            f"{label}: {len(o)} points; a view needs at least {MIN_POINTS_PER_VIEW} (a pose "
            f"has 6 parameters and the homography 8). Remove the view or detect more points"
        )
    out = np.flatnonzero((p[:, 0] < -0.5) | (p[:, 0] > w - 0.5) | (p[:, 1] < -0.5) | (p[:, 1] > h - 0.5))
    if out.size:
        raise CalibrationError(
            f"{label}: {out.size} image point(s) lie outside the {w}x{h} image (first: index {out[0]} at "
            f"({p[out[0], 0]:.1f}, {p[out[0], 1]:.1f}) px; pixel centres run 0..{w - 1} x 0..{h - 1}): wrong "
            f"image_size or a bad detection"
        )
    scale = max(1.0, float(np.max(np.abs(o[:, :2]))))
    if np.max(np.abs(o[:, 2])) > PLANAR_TOL * scale:
        raise CalibrationError(
            f"{label}: object points must lie on the board plane z = 0 (a planar target), "
            f"got |z| up to {np.max(np.abs(o[:, 2])):.3g} mm"
        )


#: Board points are the same point when their coordinates agree to this many decimals (mm): 1e-6 mm, far below any
#: board's pitch and far above float64 rounding of the same nominal coordinates.
BOARD_KEY_DECIMALS = 6


def distinct_points(object_points: Sequence[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """The distinct board points across views (views may observe different subsets), identified by their coordinates to
    :data:`BOARD_KEY_DECIMALS`.

    Parameters
    ----------
    object_points : sequence of ndarray, each shape (N_v, 3)
        Per view, mm.

    Returns
    -------
    points : ndarray, shape (P, 3)
        mm, in order of first appearance.
    index : list of ndarray of int64, each shape (N_v,)
        Per view, the index of each observed point in ``points``.
    """
    sizes = [len(o) for o in object_points]
    X = np.concatenate([np.asarray(o, dtype=np.float64).reshape(-1, 3) for o in object_points])
    _, first, inverse = np.unique(np.round(X, BOARD_KEY_DECIMALS), axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    index = rank[np.asarray(inverse).ravel()].astype(np.int64)
    return X[first[order]].copy(), np.split(index, np.cumsum(sizes)[:-1])


#: Two views whose centres of the same board points lie within this RMS (2-D norm, px) of each other are one view:
#: a photograph re-saved or re-encoded (measured on a real 640x480 view: JPEG quality 97 0.0025 px, 50 0.0085 px;
#: pixels identical 0), or a second shot with neither board nor camera moved (sensor noise of 2 grey levels: 0.0025
#: px). A camera moved by 0.3 px already puts them 0.33 px apart, distinct views of a set tens of px.
SAME_VIEW_PX = 0.05
#: ... over at least this share of the points either view saw.
SAME_VIEW_SHARE = 0.8


def same_views(centres: Sequence[np.ndarray]) -> dict[int, tuple[int, float]]:
    """The views that repeat an earlier one: the same board points at the same pixels (:data:`SAME_VIEW_PX`).

    Such a view adds nothing of the board's geometry; given as a view of its own it would shrink the stated
    uncertainty (and a cross-validation's halves would each hold one of the two).

    Parameters
    ----------
    centres : sequence of ndarray, each shape (P, 2)
        Per view every board point's centre in board order, px; NaN where the view did not see the point.

    Returns
    -------
    dict of int to (int, float)
        ``{i: (j, rms)}``: view ``i`` repeats the earlier view ``j`` (the first it repeats), their centres ``rms``
        px apart (2-D norm, RMS over the points both saw).

    Examples
    --------
    >>> a = np.array([[10.0, 20.0], [30.0, 20.0], [10.0, 40.0]])
    >>> {i: (j, round(r, 4)) for i, (j, r) in same_views([a, a + 5.0, a + 0.001]).items()}
    {2: (0, 0.0014)}
    """
    cs = [np.asarray(c, dtype=np.float64).reshape(-1, 2) for c in centres]
    seen = [np.all(np.isfinite(c), axis=1) for c in cs]
    out: dict[int, tuple[int, float]] = {}
    for i in range(len(cs)):
        for j in range(i):
            if j in out or len(cs[j]) != len(cs[i]):
                continue
            both = seen[i] & seen[j]
            k = int(both.sum())
            if k < 3 or k < SAME_VIEW_SHARE * max(int(seen[i].sum()), int(seen[j].sum())):
                continue
            rms = float(np.sqrt(np.mean(np.sum((cs[i][both] - cs[j][both]) ** 2, axis=1))))
            if rms <= SAME_VIEW_PX:
                out[i] = (j, rms)
                break
    return out
