"""Comparison metrics between calibrations, written once and used by the CLI, the tests and the reports.

* :func:`param_diff`: intrinsics differences, raw and in units of the stated standard deviations.
* :func:`projection_diff`: pixel difference between two models over a grid of pixels, with or without fitting the
  implied rotation (the idea of ``mrcal.projection_diff``: raw intrinsics differences mislead because a shift of the
  principal point can be absorbed by a small rotation of every pose).
* :func:`match_grid_order`: undo the rotations (and, if asked, mirror flips) with which a detector may return a
  grid, against a reference set of centres (the board's symmetries, :meth:`circcal.board.Board.symmetries`).
* :func:`match_views`: put each view of a detector's centres into another detector's point order (the rotational
  ambiguity of a symmetric grid, resolved per image by each detector).
* :func:`centre_errors`: detected centres against true centre projections, per view and overall.
* Error-convention conversions come from :mod:`circcal.metrics` (re-exported here).

All projection and unprojection goes through :mod:`circcal.model` (pixel centres at integer coordinates).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from circcal.board import Board
from circcal.metrics import error_stats, per_coord_to_per_point, per_point_to_per_coord
from circcal.model import Camera, param_names, project_camera, unproject
from circcal.rotation import fit_rotation

__all__ = [
    "param_diff",
    "projection_diff",
    "pixel_grid",
    "match_grid_order",
    "match_views",
    "centre_errors",
    "error_stats",
    "per_point_to_per_coord",
    "per_coord_to_per_point",
]


def param_diff(
    a: Camera, b: Camera, std_a: dict[str, float] | None = None, std_b: dict[str, float] | None = None
) -> dict[str, dict[str, float]]:
    """Per-parameter difference ``b - a``.

    Parameters
    ----------
    a, b : Camera
    std_a, std_b : dict of str to float, or None
        Their stated standard deviations by parameter name.

    Returns
    -------
    dict
        ``{name: {"a", "b", "diff", "sigma", "diff_sigmas"}}`` for every parameter of the two cameras' lens model
        (:func:`circcal.model.param_names`; for two different lens models only fx, fy, cx, cy, the parameters they
        share the meaning of), where ``sigma`` combines the stated standard deviations: sqrt(std_a^2 + std_b^2) over
        those given (NaN when neither states one, or both are 0).
    """
    names = param_names(a.lens) if a.lens == b.lens else param_names(a.lens)[:4]
    va = dict(zip(param_names(a.lens), a.intrinsics))
    vb = dict(zip(param_names(b.lens), b.intrinsics))
    out: dict[str, dict[str, float]] = {}
    for n in names:
        s2 = 0.0
        given = False
        for s in (std_a, std_b):
            if s is not None and n in s and s[n] is not None and np.isfinite(s[n]):
                s2 += float(s[n]) ** 2
                given = True
        sigma = float(np.sqrt(s2)) if given and s2 > 0 else float("nan")
        d = float(vb[n] - va[n])
        out[n] = {
            "a": float(va[n]),
            "b": float(vb[n]),
            "diff": d,
            "sigma": sigma,
            "diff_sigmas": d / sigma if np.isfinite(sigma) else float("nan"),
        }
    return out


#: Pixels across the grid over which projection differences are measured (corners included; rows keep the cells
#: square): fine enough that the RMS over the grid is within ~1% of the integral over the image for smooth models.
GRID_WIDTH = 60


def pixel_grid(camera: Camera, gridn_width: int = GRID_WIDTH, gridn_height: int | None = None) -> np.ndarray:
    """Pixels spanning the whole imager, corners included (pixel centres 0..W-1, 0..H-1).

    Parameters
    ----------
    camera : Camera
    gridn_width : int
        Grid points across.
    gridn_height : int or None
        Grid points down; None: to keep the cells square.

    Returns
    -------
    ndarray, shape (gridn_height * gridn_width, 2)
        px, row by row.
    """
    w, h = camera.width, camera.height
    if gridn_height is None:
        gridn_height = max(2, int(round(gridn_width * (h - 1) / max(w - 1, 1))) + 1)
    x = np.linspace(0.0, w - 1.0, gridn_width)
    y = np.linspace(0.0, h - 1.0, gridn_height)
    u, v = np.meshgrid(x, y)
    return np.stack([u.ravel(), v.ravel()], axis=-1)


def projection_diff(
    a: Camera,
    b: Camera,
    *,
    gridn_width: int = GRID_WIDTH,
    distance: float | None = None,
    fit: bool = False,
    margin_px: float = 0.0,
) -> dict[str, Any]:
    """Pixel difference between two models over the imager of ``a``.

    A grid of pixels of ``a`` (``gridn_width`` across, corners included, ``margin_px`` in from the border) is
    unprojected with ``a``; at ``distance`` (mm along the ray) or at infinity (``None``: rays only). Without ``fit``
    the same 3-D points are projected with ``b``. With ``fit`` the rotation (plus translation at a finite distance)
    that best aligns ``b``'s unprojection of the same pixels onto ``a``'s points is applied first, as
    ``mrcal.projection_diff`` does: an implied rotation between the two models is not counted as a difference.

    Parameters
    ----------
    a, b : Camera
    gridn_width : int
    distance : float or None
        mm; None: infinity.
    fit : bool
    margin_px : float
        px in from the border.

    Returns
    -------
    dict
        ``{"rms_px", "max_px", "median_px", "n", "n_invalid", "R", "t", "diff" (N,), "uv" (N, 2)}``; the RMS is of
        the 2-D difference per grid point.
    """
    w, h = a.width, a.height
    uv = pixel_grid(a, gridn_width)
    if margin_px:
        uv = margin_px + uv * np.array([(w - 1 - 2 * margin_px) / (w - 1), (h - 1 - 2 * margin_px) / (h - 1)])
    ra = unproject(uv, a)
    if distance is None:
        Pa = ra / np.linalg.norm(ra, axis=1, keepdims=True)
    else:
        Pa = ra / np.linalg.norm(ra, axis=1, keepdims=True) * float(distance)
    R, t = np.eye(3), np.zeros(3)
    if fit:
        rb = unproject(uv, b)
        Pb = rb / np.linalg.norm(rb, axis=1, keepdims=True)
        if distance is not None:
            Pb = Pb * float(distance)
        good = np.all(np.isfinite(Pa), axis=1) & np.all(np.isfinite(Pb), axis=1)
        # R, t map a's frame into b's: b sees a's point X at R X + t
        R, t = fit_rotation(Pa[good], Pb[good], translation=distance is not None)
        # refine in pixel space would change the criterion; mrcal also fits in 3-D, so stop here
    qb = project_camera(Pa @ R.T + t, b)
    d = np.linalg.norm(qb - uv, axis=1)
    valid = np.isfinite(d)
    dv = d[valid]
    return {
        "rms_px": float(np.sqrt(np.mean(dv**2))) if dv.size else float("nan"),
        "max_px": float(np.max(dv)) if dv.size else float("nan"),
        "median_px": float(np.median(dv)) if dv.size else float("nan"),
        "n": int(valid.sum()),
        "n_invalid": int((~valid).sum()),
        "R": R,
        "t": t,
        "diff": d,
        "uv": uv,
    }


def match_grid_order(
    detected: np.ndarray, reference: np.ndarray, board: Board, *, mirror: bool = False
) -> tuple[np.ndarray, str, float]:
    """Re-order a detected grid to the order of ``reference`` (e.g. true centre projections).

    Tries the board's symmetries (:meth:`circcal.board.Board.symmetries`: rotations, and with ``mirror`` reflections
    too) and keeps the one with the smallest RMS distance.

    Parameters
    ----------
    detected, reference : ndarray, shape (N, 2)
        px for ``board``'s N points (NaN rows are left out of the distance).
    board : Board
    mirror : bool
        Try reflections too.

    Returns
    -------
    matched : ndarray, shape (N, 2)
        Re-ordered, px.
    label : str
        The symmetry's label.
    rms : float
        RMS distance, px.

    Raises
    ------
    ValueError
        Not N points each (a caller's bug).
    """
    det = np.asarray(detected, dtype=np.float64).reshape(-1, 2)
    ref = np.asarray(reference, dtype=np.float64).reshape(-1, 2)
    n = board.n_points
    if len(det) != n or len(ref) != n:
        raise ValueError(
            f"expected {n} points for a {board.rows}x{board.cols} grid, got {len(det)} detected and "
            f"{len(ref)} reference"
        )
    best: tuple[np.ndarray, str, float] | None = None
    for sym in board.symmetries(reflections=mirror):
        cand = det[sym.perm]
        d2 = np.sum((cand - ref) ** 2, axis=1)
        d2 = d2[np.isfinite(d2)]
        rms = float(np.sqrt(np.mean(d2))) if d2.size else float("inf")
        if best is None or rms < best[2]:
            best = (cand, sym.label, rms)
    if best is None:  # symmetries() always yields the identity
        raise ValueError("the board lists no symmetry, not even the identity")
    return best


def match_views(
    detected: Sequence[np.ndarray], reference: Sequence[np.ndarray | None], board: Board
) -> tuple[list[np.ndarray], list[str]]:
    """Each detected view in the point order of ``reference`` (:func:`match_grid_order` per view, rotations only).

    A symmetric grid's 180-degree ambiguity (90 degrees when square) is resolved by each detector its own way
    (findCirclesGrid numbers the real 10x8 set in opposite directions in its plain and clustering modes, so a
    plain-then-clustering fallback reverses 2 of 6 views against circcal): harmless while the board is rigid, since
    the pose absorbs it, but it mixes up points once each point's position is estimated.

    Parameters
    ----------
    detected : sequence of ndarray, each shape (N, 2)
        Per view, px of ``board``.
    reference : sequence of (ndarray, shape (N, 2), or None)
        Entries may hold NaN for points its detector missed, or be None (that view is kept as detected, label
        ``rot0``).
    board : Board

    Returns
    -------
    views : list of ndarray, each shape (N, 2)
        Re-ordered, float64.
    labels : list of str
        The symmetry's label per view, ``rot0`` where the order was kept.

    Raises
    ------
    ValueError
        Different view counts (a caller's bug).
    """
    if len(detected) != len(reference):
        raise ValueError(f"{len(detected)} detected views but {len(reference)} reference views")
    out, labels = [], []
    for d, r in zip(detected, reference):
        d = np.asarray(d, dtype=np.float64).reshape(-1, 2)
        if r is None or not np.isfinite(np.asarray(r, dtype=np.float64)).any():
            out.append(d)
            labels.append("rot0")
            continue
        matched, label, _ = match_grid_order(d, r, board)
        out.append(matched)
        labels.append(label)
    return out, labels


def centre_errors(
    detected: Sequence[np.ndarray], truth: Sequence[np.ndarray], *, board: Board | None = None, mirror: bool = False
) -> dict[str, Any]:
    """Detected centres against true centre projections.

    Parameters
    ----------
    detected, truth : sequence of ndarray, each shape (N_v, 2)
        Per view, px, same order unless ``board`` is given.
    board : Board or None
        Given: each detected view is first re-matched with :func:`match_grid_order` (over the board's symmetries).
    mirror : bool
        Reflections too, in that match.

    Returns
    -------
    dict
        ``{"overall": error_stats, "per_view": [error_stats], "errors": [(N_v, 2) detected - truth], "matched":
        [label per view]}``.

    Raises
    ------
    ValueError
        Different view counts or shapes (a caller's bug).
    """
    if len(detected) != len(truth):
        raise ValueError(f"{len(detected)} detected views but {len(truth)} truth views")
    errs, per_view, labels = [], [], []
    for d, t in zip(detected, truth):
        d = np.asarray(d, dtype=np.float64).reshape(-1, 2)
        t = np.asarray(t, dtype=np.float64).reshape(-1, 2)
        label = "given"
        if board is not None:
            d, label, _ = match_grid_order(d, t, board, mirror=mirror)
        if d.shape != t.shape:
            raise ValueError(f"detected {d.shape} and truth {t.shape} differ in shape")
        e = d - t
        errs.append(e)
        per_view.append(error_stats(e))
        labels.append(label)
    overall = error_stats(np.concatenate(errs)) if errs else error_stats(np.zeros((0, 2)))
    return {"overall": overall, "per_view": per_view, "errors": errs, "matched": labels}
