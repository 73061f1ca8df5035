"""How far a patch of dots is from a smooth lattice, each dot measured against its own neighbours
(:func:`local_residual`): a grid bent by a wide lens, whose rows no single homography (nor one with a quadratic
term) follows, is measured against its local step rather than one global fit.

Seen through any lens, a dot lattice is near each dot a smooth map of its lattice coordinates: a quadratic
polynomial fitted to the :data:`LOCAL_DOTS` dots nearest to a dot in lattice coordinates (the 3 x 3 block around it),
the dot itself left out, predicts it to within the third-order change of the map across two lattice steps: on the
exact projections of a 1280x1024 fisheye's 8x11 board from 3 to 84 deg off axis, 0.004 of a local step RMS at the
worst, where a homography with a quadratic term over the whole board leaves 0.1. What the local fit does not absorb
is what is not smooth: a dot off its node (a chance alignment of clutter, a misread dot) moves it by its own
displacement. Each prediction error is divided by its noise gain (the error that unit noise on every dot gives it,
``sqrt(1 + |w|^2)`` for the prediction's weights ``w``), so the RMS estimates the dots' own scatter whatever the
shape of their neighbourhood, as a global fit's residual does.

Pixels: OpenCV's convention; lattice coordinates: along the two steps of the lattice (integers for a patch, pitches
for a board).
"""

from __future__ import annotations

import numpy as np

__all__ = ["LOCAL_DOTS", "MIN_LOCAL_DOTS", "local_residual"]

LOCAL_DOTS = 8
"""Each dot is predicted from the quadratic (6 coefficients per image axis) of this many of its nearest lattice
neighbours: the ring of 8 around an inner dot, the 3 x 3 block next to a corner. More neighbours reach farther and
leave more of a fisheye's curvature (12: 0.016 of a step RMS on the renders above; 20: 0.03)."""
MIN_LOCAL_DOTS = 12
"""Patches of fewer dots are not measured locally (:func:`local_residual` returns ``None``): the neighbours of each
dot would be most of the patch, which the global fit measures already."""


RANK_TOLERANCE = 1e-6
"""A neighbourhood whose design matrix (columns scaled to unit norm) has a singular value below this leaves a term
of its quadratic free: it is fitted with the affine map."""


def _distinct(c: np.ndarray) -> np.ndarray:
    """(K,) how many distinct values each row of ``c`` (K, n) holds."""
    s = np.sort(c, axis=1)
    return 1 + np.sum(np.diff(s, axis=1) > 1e-9, axis=1)


def local_residual(coords: np.ndarray, points: np.ndarray, n: int = LOCAL_DOTS) -> float | None:
    """RMS over the dots of each one's prediction error from its ``n`` nearest lattice neighbours (module docstring).

    Each error is divided by its noise gain and by the local lattice step there: a share of a lattice step, like the
    RMS residual of a global fit over a median step.

    Parameters
    ----------
    coords : numpy.ndarray
        (K, 2) float lattice coordinates of the dots (patch integers, or board coordinates in pitches).
    points : numpy.ndarray
        (K, 2) float their image positions, px.
    n : int, optional
        Neighbours each dot is predicted from (:data:`LOCAL_DOTS`).

    Returns
    -------
    float or None
        The RMS, in lattice steps; ``None`` for fewer than :data:`MIN_LOCAL_DOTS` dots, ``inf`` when no dot has a
        usable neighbourhood.

    Examples
    --------
    >>> ab = np.array([[i, j] for j in range(4) for i in range(5)], float)
    >>> local_residual(ab, ab * 20 + 5) < 1e-12, local_residual(ab[:6], ab[:6])
    (True, None)
    """
    L = np.asarray(coords, np.float64).reshape(-1, 2)
    P = np.asarray(points, np.float64).reshape(-1, 2)
    K = len(L)
    if K < MIN_LOCAL_DOTS:
        return None
    n = min(n, K - 1)
    d2 = np.sum((L[:, None] - L[None]) ** 2, axis=-1)
    np.fill_diagonal(d2, np.inf)
    nb = np.argsort(d2, axis=1, kind="stable")[:, :n]  # ties by index: the same patch, the same neighbours
    s = L[nb] - L[:, None]  # (K, n, 2): the dot itself at the origin
    x, y = s[..., 0], s[..., 1]
    A = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)  # (K, n, 6)
    # a term the neighbours do not fix is left out (a dot beyond the end of a row has its neighbours on two
    # columns only: no square along the row; a minimum-norm fit would mix it into the prediction), and a
    # neighbourhood that fixes the quadratic in no other way is fitted with the affine map alone
    nx = _distinct(x)
    ny = _distinct(y)
    A[..., 3] *= (nx >= 3)[:, None]
    A[..., 4] *= ((nx >= 2) & (ny >= 2))[:, None]
    A[..., 5] *= (ny >= 3)[:, None]
    used = np.array([True, True, True, False, False, False]) | np.any(A != 0, axis=1)
    sv = np.linalg.svd(A / np.maximum(np.linalg.norm(A, axis=1, keepdims=True), 1e-12), compute_uv=False)
    short = np.sum(sv > RANK_TOLERANCE, axis=1) < used.sum(axis=1)
    A[short, :, 3:] = 0.0
    pinv = np.linalg.pinv(A)  # (K, 6, n): least squares (zero columns: zero coefficients)
    coef = pinv @ P[nb]  # (K, 6, 2)
    err = P - coef[:, 0]  # the value at the origin: the prediction
    gain = np.sqrt(1.0 + np.sum(pinv[:, 0] ** 2, axis=1))
    J = coef[:, 1:3].transpose(0, 2, 1)  # (K, 2, 2) px per lattice unit: columns along the two coordinates
    step = np.sqrt(np.abs(np.linalg.det(J)))
    ok = np.isfinite(step) & (step > 0) & np.all(np.isfinite(err), axis=1)
    if not np.any(ok):
        return float("inf")
    rel = np.linalg.norm(err[ok], axis=1) / (gain[ok] * step[ok])
    return float(np.sqrt(np.mean(rel**2)))
