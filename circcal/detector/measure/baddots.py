"""The measured dots left out of a found grid, and why (:func:`bad_dots`).

A dot cut by the image border or by an occluder gives a biased ellipse, so it is left out of the solve (its centre
NaN, the reason counted in ``Detection.dropped``) rather than measured:

* its edge fit failed, or it touches the image border (:data:`BORDER_PX`);
* too few of its normal profiles found an edge (:data:`MIN_COVERAGE`: an occluder hides part of the rim), or the
  edge points fit no ellipse (:data:`RESIDUAL_FLOOR_PX`, :data:`RESIDUAL_SHARE`, :data:`RESIDUAL_FACTOR`: a
  straight cut);
* a dark object lies right next to its rim (:data:`CLEARANCE_PX`: the edge of an occluder, a bar), whose shade
  moves the dot's edge (:func:`dark_neighbourhood`; the rim: its ellipse, grown to the outline its lattice cell
  predicts where the fit of a thin dot falls short of its tips, :func:`_cell_outline`);
* pulled back to the board through the local lattice steps (:func:`~circcal.detector.measure.trust.local_steps`,
  second-order at the grid's edge) its ellipse, less the rounding the edge smoothing gives a thin dot
  (:data:`ROUNDING_PX`), is not round (:data:`MAX_ROUNDNESS`: every printed dot is a circle), or its area over the
  local lattice cell is unlike its neighbours' (:data:`SIZE_LIMITS`: a dot shrunk by a cut or a shadow; markers are
  compared with markers).

A wide lens thins and stretches the dots across one view; those rules follow it (measured on random views through a
fisheye and a wide rational lens: :data:`ROUNDING_PX`; tests/test_wide_dots_kept.py).

Whether the dots together are the board: :mod:`circcal.detector.measure.trust`. Pixels: OpenCV's convention.
"""

from __future__ import annotations

import cv2
import numpy as np

from circcal.board import Board
from circcal.detector.kernels.jit import njit
from circcal.detector.measure.ellipse import conic_params_batch, perimeter, sampson_at
from circcal.detector.measure.robust import MAD_TO_SIGMA, median, row_medians
from circcal.detector.measure.trust import local_steps

__all__ = ["bad_dots", "clearance_level", "dark_neighbourhood"]

KERNEL_IMPORTS = ("circcal.detector.measure.ellipse",)
"""Kernel modules whose kernels this module's kernels call (:mod:`circcal.detector.kernels.jit`)."""

BORDER_PX = 1.0
"""A dot with an edge point within this many px of the image's outer pixel centres is cut by the border."""
MIN_COVERAGE = 0.7
"""At least this share of a dot's normal profiles (one per px of its perimeter) must give an edge point: >= 0.9 of
them do on renders (blur, noise, JPEG, weak light), >= 0.84 on the real 640x480 JPEGs (measured); an occluder over
a third of the rim leaves less (smaller cuts are caught by the residual and the shape)."""
RESIDUAL_FLOOR_PX = 0.2
"""The edge points' RMS (Sampson) distance from their ellipse may be up to this many px (dots seen at 55-70 deg of
tilt, 3 px across their minor axis, measure up to 0.14 px on clean renders), ..."""
RESIDUAL_SHARE = 0.01
"""... or this share of the ellipse's minor semi-axis (the ellipse model of a distorted circle errs more on large
dots), ..."""
RESIDUAL_FACTOR = 5.0
"""... or this many times the grid's median RMS (the image's own edge noise), whichever is largest. Measured on
renders (clean, noisy, blurred, JPEG, weak light) and the real 640x480 JPEGs: RMS <= 0.16 px, <= 3x the median of
its view; a 32 px dot with a grey occluder over a tenth of its rim: 0.9 px."""
MAX_ROUNDNESS = 1.2
"""Pulled back to the board by the local lattice steps, a dot's ellipse has an axis ratio of at most this plus
:data:`ROUNDNESS_PX` over its minor semi-axis (1 for a circle; central differences over two pitches err by a few
percent under perspective and distortion, <= 1.12 measured on dots of 5 px and more; the ellipse of a noisy 2 px
dot errs by ~0.15 more; a dot with a fifth cut away: ~1.3)."""
ROUNDNESS_PX = 0.6
ROUNDING_PX = 2.0
"""The edge smoothing (:data:`~circcal.detector.measure.dots.EDGE_SIGMA`) and the optics' blur round a thin dot's
fitted ellipse in the image: its tips, narrower than the smoothing, fade, and the fit comes out shorter and wider
than the dot (a dot 5.2 x 1.7 px in semi-axes, 75 deg off a fisheye's axis and tilted 65 deg, fits 3.2 x 2.0), its
centre still within 0.02 px. So the roundness is that of the fitted ellipse ``E`` less the most favourable
isotropic rounding ``beta I``, ``0 <= beta <= ROUNDING_PX**2`` px^2 (``E - beta I`` pulled back to the board): an
ellipse rounder in the image than its lattice cell (the same axes) passes, one elongated another way (a cut, motion
blur) does not. Measured on 250 random views through a fisheye and a wide rational lens (dots of 1-40 px, tilts up
to 72 deg): the good dots (within 0.02 px of the truth) needed beta <= 5.4 px^2, and with 4 px^2 all but those
whose one-sided lattice steps erred passed (:func:`~circcal.detector.measure.trust.local_steps`, ``edge_order``);
on a dot of 10 px the rounding changes the axis ratio by 2 % at most."""
ROUNDING_STEPS = 16
"""``beta`` is tried at this many equal steps of that range (and 0)."""
SIZE_LIMITS = (0.75, 1.33)
"""A dot's area over its local lattice cell, divided by the median of the grid's dots of its kind (markers with
markers), lies in this range widened by :data:`SIZE_PX` over its minor semi-axis: perspective and blur change it by
<= 12 % on dots of 5 px and more (measured), the noise of a 2 px dot's ellipse by tens of percent; a cut or
occluded dot is smaller (a dot larger than its neighbours on a board without declared markers is a marker the user
did not declare: kept)."""
SIZE_PX = 1.0
CLEARANCE_PX = 3.5
"""A dark object (an occluder's edge, a bar) within this many px of a dot's rim darkens the outer half of its edge
profiles (the edge smoothing of 1.5 px and the optics' blur reach ~3 sigma) and moves its edge: the ring around the
rim is sampled at half and at the whole of this (or of half the gap to the nearest dot, when narrower) ..."""
CLEARANCE_LEVEL = 0.3
"""... and a sample counts as dark when it lies this share of the dot's contrast (ring median - dot centre) below
the ring's median (the noise of the weak-light renders is ~5 % of their contrast) ..."""
TEXTURE_SIGMAS = 4.0
"""... or this many times the view's texture (:func:`clearance_level`), when that is more: the grain of a matte
plate at 10 % of a low-contrast print's contrast darkened 3-6 of the 96 samples of a quarter of its dots'
rings, none of them biased by it (renders of :mod:`circcal.fixtures.texture`); sensor noise on printed boards
stays under the fixed level (its sigma, at most ~7 % of the contrast, times 4)."""
CLEARANCE_SHARE = 0.035
"""... and the dot is left out when more than this share of the ring's samples are dark (3 of the 96: an occluder
next to the rim darkens an arc, and one touching 4 % of the ring of a 37 px marker moved it by 0.2 px; noise at
6 sigma darkens none; the rim of a close neighbour under 60 deg of tilt touches 2)."""
LEVEL_RING_PX = (2.0, 2.0, 0.5)
"""The dot's white level is a plane fitted to the pixels from 2 px to 2 + max(2 px, half its minor semi-axis) px
outside its rim (:mod:`circcal.detector.measure.levels`), dark pixels (neighbouring dots, a dark occluder) left out; a grey
occluder there (neither white nor dark) is kept and tilts the plane: a 37 px marker with one 4 px below its rim
moved by 0.2 px."""
GREY_SHARE = 0.05
"""A dot is left out when more than this share of the samples on that ring are grey (between the dot's dark and the
board's white by :data:`CLEARANCE_LEVEL` of the contrast either way): the rim of a neighbouring dot crossing the
ring gives a few such samples, an occluder an arc of them."""
UNEVEN_SHARE = 0.04
"""A dot is left out when the grey level inside it changes across its minor semi-axis by more than this share of its
contrast (:func:`_uneven_inside`) and by more than :data:`UNEVEN_VIEW_FACTOR` times the view's median. Light added
over a dot (a specular reflection's flank, a shadow's edge) moves its edge points on one side: a glare spot's
neighbours measured 0.04-0.13 of their contrast and moved by 0.1-0.3 px; the fixtures' clear dots measure <= 0.033
(0.000-0.002 on exact renders), the real photographs' dots mostly <= 0.04."""
UNEVEN_VIEW_FACTOR = 5.0
"""... (noise alone gives every dot of a view a gradient of a few noise sigmas over the contrast: the weak-light and
very noisy fixtures' dots measure up to 2.6x their view's median, 0.14 at most)."""
EDGE_RING_PX = 2.0
"""... and its contrast measured against the samples this far outside its rim (past the blurred edge; a close
neighbour's dark covers less than half of them)."""
GRADIENT_MIN_SAMPLES = 24
"""The white's plane around a dot (:func:`_inside_gradients`) is fitted to at least this many bright samples of the
96 on its two rings (a quarter: the neighbouring dots of a dense grid darken the rest), else taken as flat."""
PLANE_MISFIT = 0.05
"""... and the gradient the edge model follows is only taken off where that plane explains the bright samples to
this share of the contrast (RMS): a shadow's edge across the dot is a step that no plane follows (the real 10x8
set's hand shadow: 0.04-0.07; the median dot there 0.015), smooth light is a plane to a few thousandths (renders
under a spotlight: <= 0.005)."""
INSIDE_RING_SHARE = 0.5
"""The dot's inside is sampled on its ellipse shrunk by this share of the minor semi-axis (half-way to the centre:
clear of the blurred rim)."""
CLEARANCE_MIN_PX = 2.0
"""The clearance rings are only sampled when the nearer one lies at least half this far (px) outside the rim: nearer,
bilinear samples of the dot's own anti-aliased edge read dark (a dot of a 70 deg-tilted asymmetric grid 2 px from its
neighbour was dropped so), and a dot that close to its neighbours leaves no room for an occluder anyway."""
CLEARANCE_ANGLES = 48
"""Samples per ring (one per 7.5 deg; the tables _COS, _SIN below)."""

_COS = np.cos(np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False))
_SIN = np.sin(np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False))


def _rings(g: np.ndarray, centres: np.ndarray, axes: np.ndarray, angle: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(D, R, CLEARANCE_ANGLES) grey values on the ellipses grown by ``radii`` (D, R) px (bilinear, one remap)."""
    D, R = radii.shape
    x = np.empty((D, R * len(_COS)), np.float32)
    y = np.empty((D, R * len(_COS)), np.float32)
    _ring_points(
        np.ascontiguousarray(centres, np.float64),
        np.ascontiguousarray(axes, np.float64),
        np.cos(angle),
        np.sin(angle),
        np.ascontiguousarray(radii, np.float64),
        _COS,
        _SIN,
        x,
        y,
    )
    v = cv2.remap(g, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return v.reshape(D, R, -1).astype(np.float64)


@njit(cache=True, nogil=True)
def _ring_points(c, axes, cs, sn, radii, cos_a, sin_a, x, y):
    """Writes into ``x``, ``y`` (D, R A) float32 the points of :func:`_rings`: on ellipse d grown by ``radii[d, r]``
    at the angles of ``cos_a``, ``sin_a`` (A,), ``x = (cx + (a cos) cs) - (b sin) sn``, ``y = (cy + (a cos) sn) +
    (b sin) cs`` in numpy's order of the broadcast expression it replaced (the same float64 values, then rounded to
    float32)."""
    D, R = radii.shape
    A = len(cos_a)
    for d in range(D):
        for r in range(R):
            a = axes[d, 0] + radii[d, r]
            b = axes[d, 1] + radii[d, r]
            for i in range(A):
                ac, bs = a * cos_a[i], b * sin_a[i]
                x[d, r * A + i] = np.float32((c[d, 0] + ac * cs[d]) - bs * sn[d])
                y[d, r * A + i] = np.float32((c[d, 1] + ac * sn[d]) + bs * cs[d])


def dark_neighbourhood(
    gray: np.ndarray, centres: np.ndarray, axes: np.ndarray, angle: np.ndarray, outline: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per dot, the dark objects just outside its ellipse, the mid-grey around it, and how unevenly lit its inside is.

    The outer rings end half-way to the nearest dot.

    Parameters
    ----------
    gray : numpy.ndarray
        (H, W) the image.
    centres : numpy.ndarray
        (D, 2) float ellipse centres, px.
    axes : numpy.ndarray
        (D, 2) float semi-axes, px.
    angle : numpy.ndarray
        (D,) float ellipse angles, rad.
    outline : numpy.ndarray or None, optional
        (D, 2) float semi-axes (at least ``axes``) of the outline the rings outside the dot are grown from, at the
        ellipse's centre and angle (:func:`_cell_outline`); None: ``axes``.

    Returns
    -------
    shade : numpy.ndarray
        (D,) float the share of dark samples on the rings just outside its ellipse (:data:`CLEARANCE_PX`; each
        ring's samples median-filtered along it, so only dark arcs count: :func:`_ring_shares`).
    grey : numpy.ndarray
        (D,) float the share of mid-grey samples (neither the board's white nor a dot's dark) on the rings its white
        level is measured on (:data:`LEVEL_RING_PX`).
    uneven : numpy.ndarray
        (D,) float how unevenly lit its inside is: the part of :func:`_uneven_inside`'s gradient that the edge model
        does not follow (:func:`_unfollowed_inside`), a share of the contrast.
    """
    D = len(centres)
    if D == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    g = np.asarray(gray)
    if g.dtype not in (np.uint8, np.uint16, np.float32):
        g = g.astype(np.float32)
    rim = axes if outline is None else np.asarray(outline, np.float64)
    gap = np.full(D, np.inf)
    if D > 1:
        dx = centres[:, None, 0] - centres[None, :, 0]
        dy = centres[:, None, 1] - centres[None, :, 1]
        d = np.sqrt(dx * dx + dy * dy) - rim[:, None, 0] - rim[None, :, 0]  # (np.linalg.norm's values)
        np.fill_diagonal(d, np.inf)
        gap = d.min(axis=1)
    inner = cv2.remap(
        g,
        centres[:, 0:1].astype(np.float32),
        centres[:, 1:2].astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    ).astype(np.float64)[:, 0]
    near = np.minimum(CLEARANCE_PX, 0.5 * gap)
    far = np.minimum(LEVEL_RING_PX[0] + np.maximum(LEVEL_RING_PX[1], LEVEL_RING_PX[2] * rim[:, 1]), 0.5 * gap)
    start = np.minimum(LEVEL_RING_PX[0], far)
    v = _rings(g, centres, rim, angle, np.stack([0.5 * near, near, start, 0.5 * (start + far), far], 1))
    white = row_medians(v.reshape(D, -1))
    shade, grey = np.empty(D), np.empty(D)
    _ring_shares(v, white, inner, near, far, clearance_level(v, white, inner), CLEARANCE_MIN_PX, shade, grey)
    return shade, grey, _unfollowed_inside(g, centres, axes, angle)


def clearance_level(v: np.ndarray, white: np.ndarray, inner: np.ndarray) -> float:
    """The share of a dot's contrast by which a ring sample must lie below the white to count as dark in this view.

    (And above the dot's dark to count as grey.) :data:`CLEARANCE_LEVEL`, or :data:`TEXTURE_SIGMAS` times the view's
    texture where that is more: the median over the dots of the robust sigma (MAD) of the samples on the level rings
    about their white, over the contrast ``white - inner``. A printed board on paper under little noise keeps the
    fixed level; the grain and mottling of a matte plate under a low-contrast print (a few dark samples on every dot's
    ring) raise it, so that only an object darker than the board's own texture counts.

    Parameters
    ----------
    v : numpy.ndarray
        (D, 5, A) float ring samples, grey levels; rings 2-4 are the level rings (the board around each dot,
        half-way to its neighbours at most).
    white : numpy.ndarray
        (D,) float each dot's white level.
    inner : numpy.ndarray
        (D,) float each dot's dark level.

    Returns
    -------
    float
        The level, a share of the contrast (at least :data:`CLEARANCE_LEVEL`).
    """
    D = len(white)
    contrast = white - inner
    ok = contrast > 0
    if D == 0 or not np.any(ok):
        return CLEARANCE_LEVEL
    dev = np.abs(v[:, 2:].reshape(D, -1) - white[:, None])
    sigma = MAD_TO_SIGMA * row_medians(np.ascontiguousarray(dev[ok])) / contrast[ok]
    return float(max(CLEARANCE_LEVEL, TEXTURE_SIGMAS * median(sigma)))


def _inside_gradients(
    g: np.ndarray, centres: np.ndarray, axes: np.ndarray, angle: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The grey-level gradients of :func:`_uneven_inside` and :func:`_unfollowed_inside`: ``(inside (D, 2), outside
    (D, 2), ratio (D,), contrast (D,))``. Gradients in grey levels per px along each ellipse's major and minor
    axes: inside, from the first harmonic of the samples on the ellipse shrunk to :data:`INSIDE_RING_SHARE` of the
    minor semi-axis; outside, a plane fitted (least squares) to the bright samples (above half-way from the inside
    to the white) of the rings :data:`EDGE_RING_PX` and twice that outside the rim (a neighbouring dot's dark left
    out; 0 where fewer than :data:`GRADIENT_MIN_SAMPLES` are bright). ``ratio``: the inside's median over the
    plane's white at the centre (the edge model's dark-to-white ratio); ``contrast``: the median of the samples
    just outside the rim less that of those inside."""
    b = axes[:, 1]
    D = len(b)
    radii = np.stack([-INSIDE_RING_SHARE * b, np.full(D, EDGE_RING_PX), np.full(D, 2.0 * EDGE_RING_PX)], 1)
    rings = _rings(g, centres, axes, angle, radii)
    v = rings[:, 0]  # (D, A)
    inner = row_medians(np.ascontiguousarray(v))
    contrast = row_medians(np.ascontiguousarray(rings[:, 1])) - inner
    A = v.shape[1]
    c1 = (2.0 / A) * (v @ _COS)  # the first harmonic: a' (gx cos + gy sin) along the major axis
    s1 = (2.0 / A) * (v @ _SIN)  # ... and b' (-gx sin + gy cos) along the minor one
    g_in = np.stack(
        [
            c1 / np.maximum(axes[:, 0] - INSIDE_RING_SHARE * b, 1e-9),
            s1 / np.maximum((1.0 - INSIDE_RING_SHARE) * b, 1e-9),
        ],
        1,
    )
    out = rings[:, 1:].reshape(D, -1)  # (D, 2A)
    r = radii[:, 1:]
    X = np.concatenate([(axes[:, 0:1] + r[:, 0:1]) * _COS, (axes[:, 0:1] + r[:, 1:2]) * _COS], 1)
    Y = np.concatenate([(b[:, None] + r[:, 0:1]) * _SIN, (b[:, None] + r[:, 1:2]) * _SIN], 1)
    w = (out > (inner + 0.5 * contrast)[:, None]).astype(np.float64)
    basis = np.stack([np.ones_like(X), X, Y], 2)  # (D, 2A, 3)
    N = np.einsum("dki,dk,dkj->dij", basis, w, basis)
    rhs = np.einsum("dki,dk,dk->di", basis, w, out)
    fit = (w.sum(1) >= GRADIENT_MIN_SAMPLES) & (np.abs(np.linalg.det(N)) > 1e-9)
    plane = np.zeros((D, 3))
    if np.any(fit):
        plane[fit] = np.linalg.solve(N[fit], rhs[fit][..., None])[..., 0]
    white = np.where(fit, plane[:, 0], inner + contrast)
    res = out - np.einsum("dki,di->dk", basis, plane)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(white > 0, inner / white, 0.0)
        misfit = np.where(fit, np.sqrt(np.sum(w * res * res, 1) / np.maximum(w.sum(1), 1.0)), np.inf) / contrast
    return g_in, plane[:, 1:], ratio, contrast, misfit


def _uneven_inside(g: np.ndarray, centres: np.ndarray, axes: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(D,) how far the grey level inside each dot changes across its minor semi-axis, as a share of its contrast
    (the median of the samples just outside its rim, :data:`EDGE_RING_PX`, less that of those inside; 0 where there
    is none): the gradient from the first harmonic of the samples on the ellipse shrunk to
    :data:`INSIDE_RING_SHARE` of the minor semi-axis inside the rim (:func:`_inside_gradients`). Light added on
    top, a specular reflection, changes it as much as the white; light that multiplies the board's albedo by the
    dark's share of the white (:func:`_unfollowed_inside` leaves that out)."""
    g_in, _, _, contrast, _ = _inside_gradients(g, centres, axes, angle)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.hypot(g_in[:, 0], g_in[:, 1]) * axes[:, 1] / contrast
    return np.where(contrast > 0, out, 0.0)


def _unfollowed_inside(g: np.ndarray, centres: np.ndarray, axes: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(D,) the part of :func:`_uneven_inside`'s gradient that the edge model does not follow, as a share of the
    contrast across the minor semi-axis: the edge model takes a dot's dark level as its dark-to-white ratio times
    the plane of the white around it (:mod:`circcal.detector.measure.edges`), so the inside's gradient less that
    ratio times the outside's (:func:`_inside_gradients`). Light that multiplies the albedo leaves ~0 whatever the
    dot's contrast (a dot printed paler, its ratio 0.4 rather than 0.1, tilts inside 4x as much under the same
    light, and is measured as well); light added on top (a reflection's flank) or a shadow's edge that the plane
    cannot follow leaves its own gradient."""
    g_in, g_out, ratio, contrast, misfit = _inside_gradients(g, centres, axes, angle)
    followed = misfit <= PLANE_MISFIT  # a plane explains the white around the dot: the edge model follows it
    r = g_in - np.where(followed, ratio, 0.0)[:, None] * g_out
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.hypot(r[:, 0], r[:, 1]) * axes[:, 1] / contrast
    return np.where(contrast > 0, out, 0.0)


@njit(cache=True, nogil=True)
def _ring_shares(v, white, inner, near, far, level_share, min_near, shade, grey):
    """Writes :func:`dark_neighbourhood`'s two shares per dot into ``shade`` and ``grey`` (D,), from the ring samples
    ``v`` (D, 5, A) (two clearance rings, three level rings), the white level ``white`` (D,), the dark level
    ``inner`` (D,) and the rings' reach ``near``, ``far`` (D,) px: the share of the clearance rings' samples, each
    the median of itself and its two neighbours along its ring (circular), darker than ``white - level_share *
    contrast``, and the share of the level rings' samples between that and ``inner +
    level_share * contrast`` (``contrast = white - inner``); 0 where there is no contrast, or where the clearance
    ring reaches less than ``min_near`` px (the level rings: no further than the clearance ring). The median of
    three keeps the arc of adjacent samples a dark object next to a rim darkens and removes a single sample darkened
    by noise (under noise of 17 % of the contrast, a sixth of a small noisy dot's, each sample is dark with p ~ 4 %,
    which alone would leave a clear dot at the share's limit). NaN samples propagate as in numpy's minimum and
    maximum; the shares are numpy's means of the tests (counts over sample counts)."""
    D, _, A = v.shape
    for d in range(D):
        contrast = white[d] - inner[d]
        hi = white[d] - level_share * contrast
        lo = inner[d] + level_share * contrast
        n_dark = 0
        for r in range(2):
            for i in range(A):
                a, b, c = v[d, r, i - 1 if i > 0 else A - 1], v[d, r, i + 1 if i + 1 < A else 0], v[d, r, i]
                n_dark += _nan_max(_nan_min(a, b), _nan_min(_nan_max(a, b), c)) < hi
        n_mid = 0
        for r in range(2, 5):
            for i in range(A):
                n_mid += (v[d, r, i] < hi) & (v[d, r, i] > lo)
        ok = contrast > 0
        shade[d] = n_dark / (2 * A) if ok and near[d] >= min_near else 0.0
        grey[d] = n_mid / (3 * A) if ok and far[d] > near[d] else 0.0


@njit(cache=True, nogil=True, inline="always")
def _nan_min(a, b):
    """``np.minimum(a, b)`` of two floats (NaN if either is)."""
    if a != a or b != b:
        return np.nan
    return a if a < b else b


@njit(cache=True, nogil=True, inline="always")
def _nan_max(a, b):
    """``np.maximum(a, b)`` of two floats (NaN if either is)."""
    if a != a or b != b:
        return np.nan
    return a if a > b else b


def bad_dots(
    board: Board,
    points: np.ndarray,
    edge_pts: np.ndarray,
    mask: np.ndarray,
    conics: np.ndarray,
    errors: list[str | None],
    image_size: tuple[int, int],
    gray: np.ndarray | None = None,
    params: tuple[np.ndarray, ...] | None = None,
) -> dict[int, str]:
    """Board point -> why, for the measured dots that are left out (module docstring).

    Parameters
    ----------
    board : Board
        The board.
    points : numpy.ndarray
        (D,) int board point of each measured dot.
    edge_pts : numpy.ndarray
        (D, M, 2) float edge points, px (from :func:`~circcal.detector.measure.dots.fit_dots`).
    mask : numpy.ndarray
        (D, M) bool, the valid edge points.
    conics : numpy.ndarray
        (D, 3, 3) float fitted conics.
    errors : list of str or None
        (D,) each dot's fit error (``None``: fitted).
    image_size : tuple of int
        (W, H) px.
    gray : numpy.ndarray or None, optional
        (H, W) the image, for the dark objects next to a dot (:func:`dark_neighbourhood`; not checked without it).
    params : tuple of numpy.ndarray or None, optional
        ``conic_params_batch(conics)`` where the caller has it (only the rows without an error are read).

    Returns
    -------
    dict of int to str
        The dots left out: board point -> reason, in words (e.g. ``"cut by the image border"``).
    """
    W, H = image_size
    out: dict[int, str] = {}
    D = len(points)
    for k, e in enumerate(errors):
        if e is not None:
            out[int(points[k])] = f"unmeasurable: {e}"
    ok = np.array([e is None for e in errors], bool)
    if not np.any(ok):
        return out
    c, axes, ang, okc = (
        params if params is not None else conic_params_batch(np.where(ok[:, None, None], conics, np.eye(3)))
    )
    ok &= okc
    for k in np.nonzero(~okc & np.array([e is None for e in errors]))[0]:
        out[int(points[k])] = "unmeasurable: no real ellipse"
    b = axes[:, 1]
    J = np.full((D, 2, 2), np.nan)
    J[ok] = local_steps(board, points[ok], c[ok], edge_order=2)
    near, coverage, rms, round_, fill = (np.empty(D, bool), np.empty(D), np.empty(D), np.empty(D), np.empty(D))
    _dot_measures(
        np.ascontiguousarray(edge_pts, np.float64),
        np.ascontiguousarray(mask, np.bool_),
        np.ascontiguousarray(conics, np.float64),
        ok,
        np.ascontiguousarray(axes, np.float64),
        np.ascontiguousarray(ang, np.float64),
        J,
        float(W),
        float(H),
        BORDER_PX,
        ROUNDING_PX**2,
        ROUNDING_STEPS,
        near,
        coverage,
        rms,
        round_,
        fill,
    )
    med_rms = median(rms[ok & np.isfinite(rms)]) if np.any(ok & np.isfinite(rms)) else 0.0
    res_limit = np.maximum.reduce(
        [np.full(D, RESIDUAL_FLOOR_PX), RESIDUAL_SHARE * b, np.full(D, RESIDUAL_FACTOR * med_rms)]
    )
    round_limit = MAX_ROUNDNESS + ROUNDNESS_PX / np.maximum(b, 1e-9)
    size_lo = SIZE_LIMITS[0] - SIZE_PX / np.maximum(b, 1e-9)
    size_hi = SIZE_LIMITS[1] + SIZE_PX / np.maximum(b, 1e-9)
    marker = board.is_marker()[points]
    typical = np.full(D, np.nan)  # the median fill of the dots of its kind (markers with markers)
    for kind in (False, True):
        sel = ok & np.isfinite(fill) & (marker == kind)
        if np.any(sel):
            typical[marker == kind] = median(fill[sel])
    rel = fill / typical
    shade = np.zeros(D)
    grey = np.zeros(D)
    uneven = np.zeros(D)
    if gray is not None and np.any(ok):
        outline = np.fmax(axes, _cell_outline(J, typical))[ok]
        shade[ok], grey[ok], uneven[ok] = dark_neighbourhood(gray, c[ok], axes[ok], ang[ok], outline=outline)
    uneven_limit = max(UNEVEN_SHARE, UNEVEN_VIEW_FACTOR * median(uneven[ok])) if np.any(ok) else UNEVEN_SHARE
    with np.errstate(invalid="ignore"):
        suspect = ok & (
            near
            | (coverage < MIN_COVERAGE)
            | (rms > res_limit)
            | (shade > CLEARANCE_SHARE)
            | (grey > GREY_SHARE)
            | (uneven > uneven_limit)
            | (round_ > round_limit)
            | (rel < size_lo)
            | ((rel > size_hi) & board.has_markers)
        )
    for k in np.nonzero(suspect)[0]:  # the words, for the few dots left out
        p = int(points[k])
        if near[k]:
            out[p] = "cut by the image border"
        elif coverage[k] < MIN_COVERAGE:
            out[p] = f"edge found on {coverage[k]:.0%} of its rim (occluded?)"
        elif rms[k] > res_limit[k]:
            out[p] = f"edge points fit no ellipse (RMS {rms[k]:.2f} px: cut or occluded?)"
        elif shade[k] > CLEARANCE_SHARE:
            out[p] = f"a dark object touches it ({shade[k]:.0%} of the ring around it: an occluder's edge?)"
        elif grey[k] > GREY_SHARE:
            out[p] = f"something grey lies around it ({grey[k]:.0%} of the ring its white level comes from)"
        elif uneven[k] > uneven_limit:
            out[p] = (
                f"the light is uneven inside it ({uneven[k]:.0%} of its contrast across it: a reflection or a "
                "shadow's edge?)"
            )
        elif np.isfinite(round_[k]) and round_[k] > round_limit[k]:
            out[p] = f"not round on the board (axis ratio {round_[k]:.2f}: cut or occluded?)"
        elif np.isfinite(rel[k]) and rel[k] < size_lo[k]:
            out[p] = f"{rel[k]:.0%} of its neighbours' size (cut or shadowed?)"
        elif np.isfinite(rel[k]) and rel[k] > size_hi[k] and board.has_markers:
            out[p] = f"{rel[k]:.0%} of the size of dots of its kind"
    return out


def _cell_outline(J: np.ndarray, fill: np.ndarray) -> np.ndarray:
    """(D, 2) the semi-axes (major, minor) px of the ellipse a dot of area ``fill`` (D,) lattice cells has in the
    local lattice ``J`` (D, 2, 2) px per pitch: ``sqrt(fill / pi)`` times ``J``'s singular values (NaN where either
    is). The clearance rings (:func:`dark_neighbourhood`) are grown from this outline where it reaches beyond the
    fitted ellipse: the fit of a thin dot falls short of its tips (:data:`ROUNDING_PX`), and rings grown from it
    alone ran through the dot's own ends (read as "a dark object touches it")."""
    f2 = np.sum(J * J, axis=(1, 2))
    det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
    disc = np.sqrt(np.maximum(f2 * f2 - 4.0 * det * det, 0.0))
    sv = np.sqrt(np.maximum(np.stack([f2 + disc, f2 - disc], 1), 0.0) / 2.0)
    with np.errstate(invalid="ignore"):
        return np.sqrt(fill / np.pi)[:, None] * sv


@njit(cache=True, nogil=True)
def _dot_measures(
    pts,
    mask,
    conics,
    ok,
    axes,
    ang,
    J,
    W,
    H,
    border_px,
    rounding_px2,
    rounding_steps,
    near,
    coverage,
    rms,
    round_,
    fill,
):
    """What :func:`bad_dots` tests of each dot ``d`` (D,), written into the last five arrays: ``near``, an edge point
    (``pts`` (D, M, 2) where ``mask``) within ``border_px`` of the image's outer pixel centres (``W``, ``H``);
    ``coverage``, its edge points per px of its ellipse's perimeter (Ramanujan's approximation, ``axes`` (D, 2)
    a, b); ``rms``, the RMS Sampson distance of its points from ``conics[d]`` (NaN without points); for the dots
    where ``ok`` and the local lattice steps ``J[d]`` (2, 2) px per pitch are finite with a non-zero determinant:
    ``round_``, the least axis ratio of its ellipse ``E`` (``ang`` rad) less ``beta I`` pulled back to the board by
    ``J^-1``, over ``beta`` in 0 and ``rounding_steps`` equal steps up to ``rounding_px2`` (px^2; while ``E - beta I``
    stays positive: :data:`ROUNDING_PX`), and ``fill``, its
    area over the lattice cell's, ``pi a b / |det J|`` (NaN elsewhere). The 2 x 2 algebra in closed form
    (numpy's LAPACK calls took ~30 us each on the few dots of a board)."""
    D, M = mask.shape
    for d in range(D):
        x0 = y0 = np.inf
        x1 = y1 = -np.inf
        n = 0
        ss = 0.0
        for i in range(M):
            if not mask[d, i]:
                continue
            x, y = pts[d, i, 0], pts[d, i, 1]
            x0, y0, x1, y1 = min(x0, x), min(y0, y), max(x1, x), max(y1, y)
            dist = sampson_at(conics[d], x, y)
            ss += dist * dist
            n += 1
        near[d] = x0 < border_px or y0 < border_px or x1 > W - 1 - border_px or y1 > H - 1 - border_px
        a, b = axes[d, 0], axes[d, 1]
        coverage[d] = n / max(np.ceil(perimeter(a, b)), 1.0)
        rms[d] = np.sqrt(ss / n) if n > 0 else np.nan
        round_[d] = np.nan
        fill[d] = np.nan
        j00, j01, j10, j11 = J[d, 0, 0], J[d, 0, 1], J[d, 1, 0], J[d, 1, 1]
        det = j00 * j11 - j01 * j10
        if not (ok[d] and np.isfinite(det) and det != 0.0):
            continue
        cs, sn = np.cos(ang[d]), np.sin(ang[d])
        a2, b2 = a * a, b * b
        e00 = cs * cs * a2 + sn * sn * b2  # E = R diag(a^2, b^2) R^T
        e01 = cs * sn * (a2 - b2)
        e11 = sn * sn * a2 + cs * cs * b2
        i00, i01, i10, i11 = j11 / det, -j01 / det, -j10 / det, j00 / det
        t00, t01 = i00 * e00 + i01 * e01, i00 * e01 + i01 * e11  # C = J^-1 E J^-T, symmetric
        t10, t11 = i10 * e00 + i11 * e01, i10 * e01 + i11 * e11
        c00 = t00 * i00 + t01 * i01
        c01 = t00 * i10 + t01 * i11
        c11 = t10 * i10 + t11 * i11
        half_tr = 0.5 * (c00 + c11)
        r = np.sqrt(0.25 * (c00 - c11) ** 2 + c01 * c01)
        w_hi, w_lo = half_tr + r, half_tr - r
        best = np.sqrt(max(w_hi, 1e-300) / max(w_lo, 1e-300))
        n00 = i00 * i00 + i01 * i01  # N = J^-1 J^-T: the image's isotropic rounding, pulled back
        n01 = i00 * i10 + i01 * i11
        n11 = i10 * i10 + i11 * i11
        for m in range(1, rounding_steps + 1):  # C - beta N, beta in (0, rounding_px2]: the least axis ratio
            beta = rounding_px2 * m / rounding_steps
            h00, h01, h11 = c00 - beta * n00, c01 - beta * n01, c11 - beta * n11
            ht = 0.5 * (h00 + h11)
            hr = np.sqrt(0.25 * (h00 - h11) ** 2 + h01 * h01)
            if ht - hr <= 0.0:
                break
            best = min(best, np.sqrt((ht + hr) / (ht - hr)))
        round_[d] = best
        fill[d] = np.pi * a * b / abs(det)
