"""The curvature correction of half-level edge points: on a blurred curved edge the half-level contour lies inside
the true edge (by ~ sigma_t^2 / (2 rho) for a radius of curvature rho much larger than the blur sigma_t), and this
module says by how much.

The model is exact for a disk blurred by a Gaussian (:func:`_half_level_radius`), applied locally with the
ellipse's osculating circle; the shift is tabulated once (:func:`_shift_table`) and interpolated. The table is
computed with scipy.special (~0.14 s to import, a fifth of a one-image ``circcal detect``) only where no stored copy
of it exists: ``make setup`` stores it beside the detector's compiled kernels (:func:`store_table`, run by
:func:`circcal.detector.kernels.build.build`), named after a hash of this module's source, so an edited model is computed
afresh until the next build.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from circcal.detector.kernels.jit import njit

__all__ = ["shift_at", "store_table"]

U_TABLE = np.geomspace(1.2, 60.0, 400)
"""Radii of curvature (in units of the blur sigma) the shift is tabulated at: from just above where a blurred disk
still reaches half darkness (sqrt(2 ln 2) = 1.18) to 60, where the asymptote 1 / (2 u) is within 1e-6 sigma of the
model (beyond: the asymptote). 400 geometric steps: linear interpolation within 1e-5 sigma where the correction is
fully applied (u >= 2.5)."""
BISECTION_STEPS = 60
"""Halvings of the search interval for the half-level radius (to double precision for u up to the table's end)."""
MODEL_FROM_U = 1.5
"""Below this radius of curvature (in blur sigmas) the osculating-circle model fails (the curvature changes within
the blur: the tight ends of thin ellipses) and no correction is applied ..."""
MODEL_FULL_U = 2.5
"""... above this one the full correction; linear in between."""


def _half_level_radius(u: np.ndarray) -> np.ndarray:
    """For a dark disk of radius ``u`` (in units of the Gaussian blur sigma), the radius ``v`` where the blurred
    image reaches the half level: P(|X + v| <= u) = 1/2 for X ~ N(0, I_2), i.e. ``chndtr(u^2, 2, v^2) = 1/2``.
    NaN where the blurred disk never reaches half darkness (u < sqrt(2 ln 2))."""
    from scipy.special import chndtr

    u = np.asarray(u, dtype=np.float64)
    lo = np.zeros_like(u)
    hi = u.copy()
    for _ in range(BISECTION_STEPS):  # bisection; the dark fraction decreases with v
        mid = 0.5 * (lo + hi)
        darker = chndtr(u * u, 2.0, mid * mid) > 0.5
        lo = np.where(darker, mid, lo)
        hi = np.where(darker, hi, mid)
    v = 0.5 * (lo + hi)
    return np.where(u > np.sqrt(2.0 * np.log(2.0)) + 1e-9, v, np.nan)


def _computed_table() -> np.ndarray:
    """(len(U_TABLE),) the shift ``u - v(u)`` (in blur sigmas) from the half-level contour of a blurred disk of radius
    u to its edge, at :data:`U_TABLE`, computed (scipy.special)."""
    return U_TABLE - _half_level_radius(U_TABLE)


def _stored_path(directory: Path | None = None) -> Path:
    """Where :func:`store_table` keeps the table: the compiled kernels' folder, named after this module's source."""
    from circcal.detector.kernels import jit

    return (jit.AOT_DIR if directory is None else directory) / f"curvature-table_{jit._module_key(__name__)}.npy"


def store_table(directory: Path | None = None) -> Path:
    """Compute the curvature shift table and store it (``.npy``) where :func:`_shift_table` looks for it.

    Older tables (of other sources) in that folder are removed. The file is written beside and then renamed, so a
    reader never sees half a file.

    Parameters
    ----------
    directory : pathlib.Path or None
        The folder to store it in; None: the compiled kernels' folder (``circcal.detector.kernels.jit.AOT_DIR``).

    Returns
    -------
    pathlib.Path
        The stored table, ``curvature-table_<hash of this module's source>.npy``.

    Raises
    ------
    OSError
        The folder cannot be created or written.

    Examples
    --------
    >>> store_table(Path("/tmp/kernels"))  # doctest: +SKIP
    PosixPath('/tmp/kernels/curvature-table_....npy')
    """
    path = _stored_path(directory)
    path.parent.mkdir(parents=True, exist_ok=True)
    for old in path.parent.glob("curvature-table_*.npy"):
        if old != path:
            old.unlink()
    tmp = path.with_suffix(".tmp.npy")
    np.save(tmp, _computed_table())
    tmp.replace(path)  # a reader never sees half a file
    return path


@functools.lru_cache(maxsize=1)
def _shift_table() -> np.ndarray:
    """(len(U_TABLE),) read-only: the shift ``u - v(u)`` (in blur sigmas) from the half-level contour of a blurred
    disk of radius u to its edge, at :data:`U_TABLE`: the stored copy of the current source's table where there is
    one (:func:`store_table`; the same values to the bit), else computed once, on first use."""
    table = None
    try:
        stored = np.load(_stored_path(), allow_pickle=False)
        if stored.shape == U_TABLE.shape and stored.dtype == np.float64:
            table = stored
    except (OSError, ValueError, EOFError):  # none stored (a wheel install), or not readable
        pass
    if table is None:
        table = _computed_table()
    table.flags.writeable = False
    return table


@njit(cache=True, nogil=True, inline="always")
def shift_at(a, b, cos_t, sin_t, sigma_t, u_table, table):
    """The outward shift from the half-level contour to the true edge at one point of a blurred ellipse.

    The edge is modelled locally by its osculating circle blurred by a Gaussian of ``sigma_t``, faded out where that
    model fails (:data:`MODEL_FROM_U`, :data:`MODEL_FULL_U`). ``table`` is interpolated as ``np.interp(u, u_table,
    table, left=table[0])``, the asymptote ``1 / (2 u)`` beyond it, ``u`` being the radius of curvature in blur
    sigmas. Compiled, called per point by the edge kernels (:mod:`circcal.detector.measure.edges`); the arithmetic of
    the vectorised numpy expressions it replaced, in their order (the same values to the bit, tested).

    Parameters
    ----------
    a, b : float
        The ellipse's semi-axes, px.
    cos_t, sin_t : float
        Cosine and sine of the point's parameter t: the point is ``(a cos t, b sin t)`` in the ellipse's frame.
    sigma_t : float
        The blur scale, px.
    u_table : numpy.ndarray
        (T,) float64 increasing: :data:`U_TABLE`, radii of curvature in blur sigmas.
    table : numpy.ndarray
        (T,) float64: :func:`_shift_table` at ``u_table``, shifts in blur sigmas.

    Returns
    -------
    shift : float
        px, the modelled outward shift (after the fade); NaN where the radius of curvature is NaN.
    unmodelled : float
        px, the part of the modelled shift the fade leaves out: the size of the error an edge point may carry there
        (the tight ends of thin ellipses: up to ~0.5 px).
    """
    q = (a * sin_t) ** 2 + (b * cos_t) ** 2
    rho = q * np.sqrt(q) / (a * b)  # radius of curvature
    u = rho / sigma_t
    n = u_table.shape[0]
    if u > u_table[n - 1]:
        s = 0.5 / max(u, 1e-9)
    elif u < u_table[0]:
        s = table[0]
    elif u == u_table[n - 1]:
        s = table[n - 1]
    elif np.isnan(u):
        s = u
    else:  # np.interp's slope and sum: u_table[j] <= u < u_table[j + 1]
        lo, hi = 0, n - 1
        while hi - lo > 1:
            mid = (lo + hi) >> 1
            if u_table[mid] <= u:
                lo = mid
            else:
                hi = mid
        slope = (table[lo + 1] - table[lo]) / (u_table[lo + 1] - u_table[lo])
        s = slope * (u - u_table[lo]) + table[lo]
    fade = min(max((u - MODEL_FROM_U) / (MODEL_FULL_U - MODEL_FROM_U), 0.0), 1.0)
    if np.isnan(u):  # (min and max would not pass NaN on)
        fade = u
    return sigma_t * s * fade, sigma_t * s * (1.0 - fade)
