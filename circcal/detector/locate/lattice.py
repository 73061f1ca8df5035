"""Lattices among candidate dots: patches of dots whose neighbours form a (perspective-distorted) square lattice,
grown outwards from well-formed seeds, in time about linear in the number of candidates.

A circle grid, symmetric or asymmetric, is locally a square lattice: a symmetric grid's nearest neighbours lie along
the board's rows and columns, an asymmetric (staggered) grid's along its diagonals, at equal distances and right
angles on the board. In the image both are distorted by the local affine part of the board's projection; each dot's
own ellipse undoes it: the map ``S = diag(1/a, 1/b) R(-angle)`` built from a dot's semi-axes takes the image of a
circle back to a circle, so it takes the local lattice back to a square one (up to rotation and scale).

1. Seeds (:func:`find_seeds`, vectorised over all candidates): each candidate's nearest neighbours
   (:class:`~circcal.detector.locate.neighbours.NeighbourGrid`), de-skewed by its own ellipse; the nearest one gives the lattice step ``u``, the nearest one at 60-120 deg from it
   (in the de-skewed frame) with a length within :data:`SEED_LENGTH_RATIO` gives ``v``; the candidate is a seed when
   the 8 positions ``+-u, +-v, +-u+-v`` hold candidates within :data:`SEED_TOLERANCE` steps whose areas agree with
   its own within :data:`MAX_AREA_RATIO`. This is the local pattern every dot of the board shows (its 8
   neighbours; fewer at the board's edge) and clutter almost never does; candidates that are no seed cost one tree
   query each.
2. Growth (:func:`grow`): from a seed, breadth first: every lattice position next to a labelled dot is predicted
   from the labelled dots behind it (a projective extrapolation along a row or column when three are there, which
   is exact under perspective; linear from two; the parallelogram rule from a labelled corner), and takes the
   nearest unlabelled candidate within :data:`GROW_TOLERANCE` of the local step whose area agrees with its
   labelled neighbours'. Each candidate is labelled at most once and each labelled dot proposes 4 positions, so a
   patch of K dots costs O(K log M).
3. Patches (:func:`find_lattices`): seeds are taken best first; a candidate in a patch is never a seed again, so the
   whole search costs O(M log M) for M candidates, whatever they are (a 45x45 dot lattice or noise); patches of a
   board split by an occluder are joined when one's local homography puts the other's dots on its free lattice
   nodes (:func:`merge_patches`).

Lattice coordinates ``(a, b)`` are integers along ``u`` and ``v``; ``(u, v)`` is right-handed in the image (x right,
y down, ``u_x v_y - u_y v_x > 0``), the handedness of a board seen from its front. Pixels: OpenCV's convention.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from circcal.detector.locate.budget import Deadline
from circcal.detector.locate.neighbours import NeighbourGrid

__all__ = ["Lattice", "find_lattices", "find_seeds", "grow", "merge_patches", "GROW_TOLERANCE", "MAX_AREA_RATIO"]

NEIGHBOURS = 12
"""Nearest neighbours looked at per candidate for its lattice steps: a grid foreshortened 4x along one axis (75 deg
of tilt, the most the candidate filters keep) puts 3 steps along that axis nearer than one step along the other, so
the other axis's first neighbour is at most the 7th-9th nearest."""
SEED_TOLERANCE = 0.2
"""A seed's diagonal neighbours must lie within this share of the shorter lattice step of their predicted positions
(the homography of the seed and its axis neighbours: exact under perspective; lens distortion across two steps
moves them by a few percent)."""
SEED_AXIS_TOLERANCE = 0.35
"""A seed's axis neighbours (+-u, +-v) lie within this share of the step of where the opposite step points:
perspective makes neighbouring cells differ by up to ~20 % on a board close to the camera."""
SEED_LENGTH_RATIO = 1.6
"""The two steps of a seed, de-skewed by its ellipse, differ in length by at most this factor (equal on the board;
the ellipse of a rough contour is a few percent off, perspective changes the scale across a dot slightly)."""
SEED_ANGLE_DEG = (60.0, 120.0)
"""... and make an angle in this range (90 deg on the board)."""
GROW_TOLERANCE = 0.25
"""A predicted lattice position takes a candidate within this share of the local (shorter) lattice step: under
perspective the predictions are exact to second order, and at half a step a candidate could belong to either of
two positions."""
MAX_AREA_RATIO = 6.5
"""Dots of one patch: the area of a new dot lies within this factor of its labelled neighbours' median either way.
Perspective changes the area of neighbours by tens of percent at most; origin markers of twice the diameter have 4x
the area; a clutter blob of another size falls out."""
BRIDGE_TOLERANCE = 0.3
"""Two patches are one board when the local homography of one puts every dot of the other within this share of a
lattice step of a free node (the homography is extrapolated across the gap an occluder leaves)."""
MERGE_NEAREST = 16
"""... the local homography is fitted to this many dots of the first patch nearest to the second."""
MIN_PATCH = 4
"""Smaller patches are not kept (four dots fix a homography at the least)."""
SEED_MIN_NEIGHBOURS = 5
"""Secondary seeds (after the well-formed ones): at least this many of the 8 neighbours (a dot on a board's edge has
5), so strips of a board that an occluder cuts off still grow."""


@dataclass
class Lattice:
    """A patch of candidates on one lattice. ``index`` (K,) candidate indices; ``ab`` (K, 2) int lattice
    coordinates (right-handed in the image, see the module docstring); ``misses`` maps a lattice position next to
    the patch (a 4-neighbour of a dot) to its predicted image position (px) where no candidate was found;
    ``seed_score``: how many of its 8 neighbours the seed had."""

    index: np.ndarray
    ab: np.ndarray
    misses: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)
    seed_score: int = 8

    def __len__(self) -> int:
        return len(self.index)


def _deskew(axes: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(M, 2, 2) maps image vector -> de-skewed vector, ``diag(1/a, 1/b) R(-angle)`` scaled by ``sqrt(a b)`` (so a
    circle's map is the identity): undoes the local affine part of the board's projection up to a rotation."""
    a = np.maximum(axes[:, 0], 1e-9)
    b = np.maximum(axes[:, 1], 1e-9)
    c, s = np.cos(angle), np.sin(angle)
    g = np.sqrt(a * b)
    S = np.empty((len(a), 2, 2))
    S[:, 0, 0] = c / a * g
    S[:, 0, 1] = s / a * g
    S[:, 1, 0] = -s / b * g
    S[:, 1, 1] = c / b * g
    return S


def _batch_homographies(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(M, 3, 3) least-squares (DLT, Hartley-normalised) homographies mapping ``src`` (K, 2) onto each ``dst[m]``
    (M, K, 2), K >= 4; rows of NaN for a degenerate ``dst``."""
    M, K = dst.shape[:2]
    mu = dst.mean(axis=1, keepdims=True)
    sc = np.sqrt(2.0) / np.maximum(np.sqrt(np.mean(np.sum((dst - mu) ** 2, axis=-1), axis=1)), 1e-12)
    q = (dst - mu) * sc[:, None, None]
    x, y = src[:, 0], src[:, 1]
    A = np.zeros((M, 2 * K, 9))
    A[:, 0::2, 0], A[:, 0::2, 1], A[:, 0::2, 2] = x, y, 1.0
    A[:, 1::2, 3], A[:, 1::2, 4], A[:, 1::2, 5] = x, y, 1.0
    A[:, 0::2, 6:8] = -q[:, :, 0:1] * src[None]
    A[:, 0::2, 8] = -q[:, :, 0]
    A[:, 1::2, 6:8] = -q[:, :, 1:2] * src[None]
    A[:, 1::2, 8] = -q[:, :, 1]
    ok = np.all(np.isfinite(A), axis=(1, 2))
    H = np.full((M, 3, 3), np.nan)
    if np.any(ok):
        _, _, vt = np.linalg.svd(A[ok])
        Hn = vt[:, -1].reshape(-1, 3, 3)
        T = np.zeros((int(ok.sum()), 3, 3))  # undo the normalisation of dst
        T[:, 0, 0] = T[:, 1, 1] = 1.0 / sc[ok]
        T[:, :2, 2] = mu[ok, 0]
        T[:, 2, 2] = 1.0
        H[ok] = T @ Hn
    return H


def find_seeds(
    points: np.ndarray, axes: np.ndarray, angle: np.ndarray, area: np.ndarray, tree: NeighbourGrid
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every candidate's local lattice (vectorised; see the module docstring).

    Parameters
    ----------
    points : numpy.ndarray
        (M, 2) float candidate centres, px.
    axes : numpy.ndarray
        (M, 2) float semi-axes (a, b), px.
    angle : numpy.ndarray
        (M,) float angle of each ``a`` from the image x axis, rad.
    area : numpy.ndarray
        (M,) float areas, px^2.
    tree : NeighbourGrid
        The neighbour grid of ``points``.

    Returns
    -------
    score : numpy.ndarray
        (M,) int how many of the 8 positions ``+u, -u, +v, -v, +u+v, -u-v, +u-v, -u+v`` hold a matching candidate.
    u, v : numpy.ndarray
        (M, 2) float the right-handed steps, px.
    neighbours : numpy.ndarray
        (M, 8) int the candidate at each position (-1 where none).
    """
    M = len(points)
    k = min(NEIGHBOURS + 1, M)
    score = np.zeros(M, np.int64)
    nbr8 = np.full((M, 8), -1, np.int64)
    u = np.zeros((M, 2))
    v = np.zeros((M, 2))
    if M < 3:
        return score, u, v, nbr8
    _, nn = tree.query(points, k=k)
    nn = nn[:, 1:]  # (M, k-1), self excluded
    d = points[nn] - points[:, None]  # (M, k-1, 2) image steps
    e = np.einsum("mij,mkj->mki", _deskew(axes, angle), d)  # de-skewed
    n = np.linalg.norm(e, axis=-1)
    iu = np.argmin(n, axis=1)
    eu = e[np.arange(M), iu]
    nu = n[np.arange(M), iu]
    cosang = np.einsum("mkj,mj->mk", e, eu) / np.maximum(n * nu[:, None], 1e-12)
    lo, hi = np.cos(np.deg2rad(SEED_ANGLE_DEG[1])), np.cos(np.deg2rad(SEED_ANGLE_DEG[0]))
    ok_v = (cosang > lo) & (cosang < hi) & (n < SEED_LENGTH_RATIO * nu[:, None]) & (n > nu[:, None] / SEED_LENGTH_RATIO)
    nv = np.where(ok_v, n, np.inf)
    iv = np.argmin(nv, axis=1)
    has_v = np.isfinite(nv[np.arange(M), iv])
    u = d[np.arange(M), iu]
    v = d[np.arange(M), iv]
    cross = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    swap = cross < 0  # right-handed: swap the two steps
    u, v = np.where(swap[:, None], v, u), np.where(swap[:, None], u, v)
    # the 4 axis neighbours: the nearest candidates to +-u, +-v (under perspective -u is not exactly minus u)
    rows = np.arange(M)
    axis = np.full((M, 4), -1, np.int64)
    axis_xy = np.zeros((M, 4, 2))
    for k, t in enumerate((u, -u, v, -v)):
        err = np.linalg.norm(d - t[:, None], axis=-1)
        j = np.argmin(err, axis=1)
        ok = (err[rows, j] < SEED_AXIS_TOLERANCE * np.linalg.norm(t, axis=1)) & has_v
        r = area[nn[rows, j]] / np.maximum(area, 1e-12)
        ok &= (r < MAX_AREA_RATIO) & (r > 1.0 / MAX_AREA_RATIO)
        axis[:, k] = np.where(ok, nn[rows, j], -1)
        axis_xy[:, k] = np.where(ok[:, None], points[nn[rows, j]], points + t)
    # the 4 diagonal neighbours, predicted by the homography of the centre and its 4 axis neighbours (exact under
    # perspective; the parallelogram rule where an axis neighbour is missing)
    src = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]], np.float64)
    diag = np.array([[1, 1], [-1, -1], [1, -1], [-1, 1]], np.float64)
    pred = points[:, None] + diag[None, :, :1] * u[:, None] + diag[None, :, 1:] * v[:, None]
    full = np.nonzero(np.all(axis >= 0, axis=1))[0]
    if len(full):
        Hs = _batch_homographies(src, np.concatenate([points[full, None], axis_xy[full]], axis=1))
        ph = np.einsum("mij,kj->mki", Hs, np.column_stack([diag, np.ones(4)]))
        with np.errstate(invalid="ignore", divide="ignore"):
            ph = ph[..., :2] / ph[..., 2:]
        good = np.all(np.isfinite(ph), axis=(1, 2))
        pred[full[good]] = ph[good]
    dist, j = tree.query(pred.reshape(-1, 2), k=1)
    dist, j = dist.reshape(M, 4), j.reshape(M, 4)
    step = np.minimum(np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1))
    ratio = area[j] / np.maximum(area[:, None], 1e-12)
    hit = (
        (dist < SEED_TOLERANCE * step[:, None])
        & (ratio < MAX_AREA_RATIO)
        & (ratio > 1.0 / MAX_AREA_RATIO)
        & (j != rows[:, None])
        & has_v[:, None]
    )
    nbr8 = np.concatenate([axis, np.where(hit, j, -1)], axis=1)
    score = np.sum(nbr8 >= 0, axis=1)
    return score, u, v, nbr8


_DIRS = ((1, 0), (-1, 0), (0, 1), (0, -1))
_CORNERS = (((1, 0), (0, 1)), ((1, 0), (0, -1)), ((-1, 0), (0, 1)), ((-1, 0), (0, -1)))


def _predict(lab: dict[tuple[int, int], tuple[float, float]], a: int, b: int) -> tuple[float, float, float] | None:
    """Predicted image position (x, y) px of lattice position ``(a, b)`` from the labelled positions ``lab``
    (position -> image point) behind it, and the local step length (px); ``None`` when no rule applies. Plain
    floats: this runs once per lattice position tried."""
    sx = sy = 0.0
    n = 0
    step = float("inf")
    get = lab.get
    for da, db in _DIRS:
        p1 = get((a - da, b - db))
        if p1 is None:
            continue
        p2 = get((a - 2 * da, b - 2 * db))
        if p2 is None:
            continue
        dx, dy = p1[0] - p2[0], p1[1] - p2[1]
        s1 = (dx * dx + dy * dy) ** 0.5
        step = min(step, s1)
        p3 = get((a - 3 * da, b - 3 * db))
        if p3 is not None and s1 > 0:
            ex, ey = p2[0] - p3[0], p2[1] - p3[1]
            s2 = (ex * ex + ey * ey) ** 0.5
            den = 3.0 * s2 - s1
            if den > 0.2 * s2:  # projective (cross-ratio) extrapolation: exact under perspective
                f = s1 * (s1 + s2) / den / s1
                sx += p1[0] + dx * f
                sy += p1[1] + dy * f
                n += 1
                continue
        sx += p1[0] + dx
        sy += p1[1] + dy
        n += 1
    for (da, db), (ea, eb) in _CORNERS:
        p1 = get((a - da, b - db))
        if p1 is None:
            continue
        p2 = get((a - ea, b - eb))
        if p2 is None:
            continue
        p3 = get((a - da - ea, b - db - eb))
        if p3 is None:
            continue
        sx += p1[0] + p2[0] - p3[0]
        sy += p1[1] + p2[1] - p3[1]
        n += 1
        step = min(
            step,
            ((p1[0] - p3[0]) ** 2 + (p1[1] - p3[1]) ** 2) ** 0.5,
            ((p2[0] - p3[0]) ** 2 + (p2[1] - p3[1]) ** 2) ** 0.5,
        )
    if n == 0:
        return None
    return sx / n, sy / n, step


def grow(
    seed: int,
    u: np.ndarray,
    v: np.ndarray,
    nbr8: np.ndarray,
    points: np.ndarray,
    area: np.ndarray,
    tree: NeighbourGrid,
    taken: np.ndarray,
    image_size: tuple[int, int],
    deadline: Deadline | None = None,
    inside: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Lattice:
    """The patch grown from candidate ``seed`` (module docstring, step 2).

    Grows in waves (every position next to the dots labelled in the last wave, predicted at once and looked up in one
    tree query).

    Parameters
    ----------
    seed : int
        Index of the seed candidate.
    u, v : numpy.ndarray
        (2,) float the seed's lattice steps, px (:func:`find_seeds`).
    nbr8 : numpy.ndarray
        (8,) int the seed's 8 neighbours (:func:`find_seeds`).
    points : numpy.ndarray
        (M, 2) float candidate centres, px.
    area : numpy.ndarray
        (M,) float candidate areas, px^2.
    tree : NeighbourGrid
        The neighbour grid of ``points``.
    taken : numpy.ndarray
        (M,) bool, candidates of other patches (not used); this patch's are marked on return (modified in place).
    image_size : tuple of int
        (W, H) px: predictions outside the image are not misses.
    deadline : Deadline or None, optional
        Checked at each wave.
    inside : callable or None, optional
        Where given, the test of which predictions (K, 2) px lie in the image instead ((K,) bool: the candidates are
        undistorted positions, :func:`~circcal.detector.locate.undistorted.inside_image`).

    Returns
    -------
    Lattice
        The patch (the seed alone and its neighbours at the least).

    Raises
    ------
    BudgetExceeded
        Past ``deadline`` (:class:`~circcal.detector.locate.budget.BudgetExceeded`).
    """
    offsets = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1), (1, -1), (-1, 1))
    pl = points.tolist()
    cand: dict[tuple[int, int], int] = {(0, 0): int(seed)}
    owner = {int(seed): (0, 0)}
    for o, j in zip(offsets, nbr8.tolist()):
        if j >= 0 and not taken[j] and j not in owner:
            cand[o] = j
            owner[j] = o
    lab = {q: (pl[i][0], pl[i][1]) for q, i in cand.items()}
    W, H = image_size
    misses: dict[tuple[int, int], tuple[float, float]] = {}
    tried: set[tuple[int, int]] = set(cand)
    fresh = list(cand)
    while fresh:
        if deadline is not None:
            deadline.check()
        wave: dict[tuple[int, int], tuple[float, float, float]] = {}
        for a, b in fresh:
            for da, db in _DIRS:
                q = (a + da, b + db)
                if q in tried or q in wave:
                    continue
                pr = _predict(lab, *q)
                if pr is not None:
                    wave[q] = pr
        fresh = []
        if not wave:
            break
        qs = list(wave)
        tried.update(qs)
        pred = np.array([wave[q][:2] for q in qs])
        if inside is None:
            within = (pred[:, 0] >= 0.0) & (pred[:, 0] <= W - 1) & (pred[:, 1] >= 0.0) & (pred[:, 1] <= H - 1)
        else:
            within = inside(pred)
        dist, jj = tree.query(pred, k=2)
        claims: dict[int, tuple[float, tuple[int, int]]] = {}
        for k, q in enumerate(qs):
            if not within[k]:
                continue
            tol = GROW_TOLERANCE * wave[q][2]
            hit = None
            for dd, j in zip(dist[k].tolist(), jj[k].tolist()):
                if dd >= tol or j >= len(pl):
                    break
                if taken[j] or j in owner:
                    continue
                ref = [
                    area[cand[n]]
                    for n in ((q[0] + 1, q[1]), (q[0] - 1, q[1]), (q[0], q[1] + 1), (q[0], q[1] - 1))
                    if n in cand
                ]
                r = area[j] / max(float(np.median(ref)), 1e-12)
                if 1.0 / MAX_AREA_RATIO < r < MAX_AREA_RATIO:
                    hit = (dd, j)
                break
            if hit is None:
                misses[q] = (float(pred[k, 0]), float(pred[k, 1]))
            elif hit[1] not in claims or hit[0] < claims[hit[1]][0]:
                if hit[1] in claims:  # two positions want one dot: the nearer wins
                    misses[claims[hit[1]][1]] = tuple(pred[qs.index(claims[hit[1]][1])])
                claims[hit[1]] = (hit[0], q)
            else:
                misses[q] = (float(pred[k, 0]), float(pred[k, 1]))
        for j, (_, q) in claims.items():
            cand[q] = j
            owner[j] = q
            lab[q] = (pl[j][0], pl[j][1])
            fresh.append(q)
    idx = np.fromiter(cand.values(), np.int64, len(cand))
    ab = np.array(list(cand.keys()), np.int64).reshape(-1, 2)
    taken[idx] = True
    return Lattice(idx, ab, {q: np.array(p) for q, p in misses.items() if q not in cand})


def _homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray | None:
    """(3, 3) least-squares homography ``src`` (K, 2) -> ``dst`` (K, 2) (``cv2.findHomography``, all points), or
    ``None`` when degenerate."""
    if len(src) < 4:
        return None
    H, _ = cv2.findHomography(src.astype(np.float64), dst.astype(np.float64), 0)
    if H is None or not np.all(np.isfinite(H)) or abs(np.linalg.det(H)) < 1e-12:
        return None
    return H


def merge_patches(patches: list[Lattice], points: np.ndarray, deadline: Deadline | None = None) -> list[Lattice]:
    """Join patches that are parts of one lattice (a board cut by an occluder).

    The largest first, each other patch taken into it when the homography of the :data:`MERGE_NEAREST` nearest dots
    of the larger (lattice -> image) puts every dot of the smaller within :data:`BRIDGE_TOLERANCE` of a free lattice
    node, in one rotation and shift of its own coordinates. Pairs of patches are tried (quadratic in their number:
    clutter of thousands of small patches), so ``deadline`` is checked every :data:`MERGE_CHECK_EVERY` tries.

    Parameters
    ----------
    patches : list of Lattice
        The patches, in any order.
    points : numpy.ndarray
        (M, 2) float candidate centres, px (the patches' ``index`` points into it).
    deadline : Deadline or None, optional
        The image's deadline.

    Returns
    -------
    list of Lattice
        The patches, largest first.

    Raises
    ------
    BudgetExceeded
        Past ``deadline`` (:class:`~circcal.detector.locate.budget.BudgetExceeded`).
    """
    patches = sorted(patches, key=len, reverse=True)
    out: list[Lattice] = []
    tries = 0
    while patches:
        big = patches.pop(0)
        changed = True
        while changed:
            changed = False
            for k, small in enumerate(patches):
                tries += 1
                if deadline is not None and tries % MERGE_CHECK_EVERY == 0:
                    deadline.check()
                joined = _join(big, small, points)
                if joined is not None:
                    big = joined
                    patches.pop(k)
                    changed = True
                    break
        out.append(big)
    return out


MERGE_CHECK_EVERY = 64
"""Tries of :func:`merge_patches` between two checks of the deadline (a try is ~0.1 ms)."""


def _join(big: Lattice, small: Lattice, points: np.ndarray) -> Lattice | None:
    """``big`` with ``small`` taken in (see :func:`merge_patches`), or ``None``."""
    sp = points[small.index]
    bp = points[big.index]
    near = np.argsort(np.linalg.norm(bp - sp.mean(axis=0), axis=1))[:MERGE_NEAREST]
    if len(np.unique(big.ab[near, 0])) < 2 or len(np.unique(big.ab[near, 1])) < 2:
        return None
    H = _homography(bp[near], big.ab[near].astype(np.float64))  # image -> lattice of `big`
    if H is None:
        return None
    q = cv2.perspectiveTransform(sp.reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)
    if not np.all(np.isfinite(q)):
        return None
    r = np.rint(q)
    if np.max(np.abs(q - r)) > BRIDGE_TOLERANCE:
        return None
    r = r.astype(np.int64)
    occupied = {tuple(x) for x in big.ab.tolist()}
    if any(tuple(x) in occupied for x in r.tolist()) or len({tuple(x) for x in r.tolist()}) != len(r):
        return None
    # the small patch's own coordinates must map onto these nodes by one rotation and shift
    from circcal.board import LATTICE_ROTATIONS

    for R in LATTICE_ROTATIONS:
        t = r - small.ab @ R.T
        if np.all(t == t[0]):
            misses = {**big.misses, **{tuple((np.array(k) @ R.T + t[0]).tolist()): p for k, p in small.misses.items()}}
            ab = np.concatenate([big.ab, r])
            occ = {tuple(x) for x in ab.tolist()}
            return Lattice(
                np.concatenate([big.index, small.index]),
                ab,
                {k: p for k, p in misses.items() if k not in occ},
                big.seed_score,
            )
    return None


def find_lattices(
    points: np.ndarray,
    axes: np.ndarray,
    angle: np.ndarray,
    area: np.ndarray,
    image_size: tuple[int, int],
    *,
    min_seed_score: int = 8,
    deadline: Deadline | None = None,
    max_patches: int | None = None,
    inside: Callable[[np.ndarray], np.ndarray] | None = None,
) -> list[Lattice]:
    """Every lattice patch among the candidates (module docstring), largest first, patches of one board joined.

    Parameters
    ----------
    points : numpy.ndarray
        (M, 2) float candidate centres, px.
    axes : numpy.ndarray
        (M, 2) float semi-axes, px.
    angle : numpy.ndarray
        (M,) float ellipse angles, rad.
    area : numpy.ndarray
        (M,) float areas, px^2.
    image_size : tuple of int
        (W, H) px.
    min_seed_score : int, optional
        Neighbours (of 8) a first seed needs (a board whose dots have fewer, e.g. 2 x C, gives its maximum);
        secondary seeds need :data:`SEED_MIN_NEIGHBOURS` (or ``min_seed_score`` when lower).
    deadline : Deadline or None, optional
        The image's deadline.
    max_patches : int or None, optional
        Stop after growing this many patches of at least :data:`MIN_PATCH` dots (None: all).
    inside : callable or None, optional
        The test of which positions lie in the image, for undistorted candidates (:func:`grow`).

    Returns
    -------
    list of Lattice
        Patches of at least :data:`MIN_PATCH` dots, largest first (empty with fewer than :data:`MIN_PATCH`
        candidates or no well-formed seed).

    Raises
    ------
    BudgetExceeded
        Past ``deadline`` (:class:`~circcal.detector.locate.budget.BudgetExceeded`).

    Examples
    --------
    >>> xy = np.array([[x, y] for y in range(5) for x in range(6)], float) * 30 + 40
    >>> M = len(xy)
    >>> [len(p) for p in find_lattices(xy, np.full((M, 2), 6.0), np.zeros(M), np.full(M, 113.0), (300, 250))]
    [30]
    """
    points = np.asarray(points, np.float64).reshape(-1, 2)
    M = len(points)
    if M < MIN_PATCH:
        return []
    tree = NeighbourGrid(points)
    score, u, v, nbr8 = find_seeds(
        points,
        np.asarray(axes, np.float64).reshape(-1, 2),
        np.asarray(angle, np.float64).reshape(-1),
        np.asarray(area, np.float64),
        tree,
    )
    if deadline is not None:
        deadline.check()
    lowest = min(min_seed_score, SEED_MIN_NEIGHBOURS)
    order = np.lexsort((np.arange(M), -score))
    order = order[score[order] >= lowest]
    taken = np.zeros(M, bool)
    patches: list[Lattice] = []
    first = True
    for s in order:
        if taken[s]:
            continue
        if first and score[s] < min_seed_score:
            break  # no well-formed seed: no board
        first = False
        lat = grow(int(s), u[s], v[s], nbr8[s], points, area, tree, taken, image_size, deadline, inside)
        lat.seed_score = int(score[s])
        if len(lat) >= MIN_PATCH:
            patches.append(lat)
            if max_patches is not None and len(patches) >= max_patches:
                break
        else:
            taken[lat.index] = True  # a few dots that form no patch are no seeds either
    return merge_patches(patches, points, deadline) if len(patches) > 1 else patches
