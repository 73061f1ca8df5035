"""The dots' measurement (:mod:`circcal.detector.measure`): the robust statistics, levels, edge points, curvature
shift, smoothing and the dot fit, each against the numpy, scipy or per-dot formulation it replaced; and the trust
checks (the ring shares and points, local steps, dots washed out or absent, light added over a dot)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from circcal.board import Board
from circcal.detector import Reason, detect
from circcal.fixtures.poses import pose_looking_at
from circcal.fixtures.render import render_view, to_uint
from circcal.model import Camera, project
from tests.detector.helpers import BOARD, CAM, _render


def test_row_medians_are_numpys_medians_of_the_values_left_in():
    import warnings

    from circcal.detector.measure.robust import row_medians

    rng = np.random.default_rng(4)
    vals = rng.normal(size=(7, 10))
    keep = rng.random((7, 10)) < 0.6
    keep[2] = False  # a row without values: NaN, and no warning
    keep[3] = np.arange(10) < 4  # even and odd counts
    keep[4] = np.arange(10) < 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = row_medians(np.where(keep, vals, np.nan))
    expect = [np.median(v[k]) if k.any() else np.nan for v, k in zip(vals, keep)]
    assert np.array_equal(got, expect, equal_nan=True)


def test_compiled_medians_are_numpys_on_ties_and_ordered_input():
    # the selection's partitions (three-way, drawn pivots) on the inputs that break simple quickselects: ties, all
    # equal, sorted and reverse-sorted rows, one and two values; the selection the levels kernel calls as well
    from circcal.detector.measure.robust import _median_of, row_medians

    rng = np.random.default_rng(11)
    rows = [
        rng.integers(0, 3, 500).astype(float),
        np.full(300, 2.5),
        np.arange(1001.0),
        np.arange(1000.0)[::-1],
        np.round(rng.normal(size=777), 2),
        np.array([3.0]),
        np.array([4.0, -1.0]),
        rng.normal(size=2048),
    ]
    for r in rows:
        assert row_medians(r[None])[0] == np.median(r)
        assert _median_of(r.copy(), len(r)) == np.median(r)


def test_the_band_median_is_the_median_also_where_the_sample_misses_it():
    # from BAND_SELECT_FROM values the median is selected within a band a sample bounds; inputs whose sample lies far
    # from the median (the values at the sample's positions all large) take the full selection: both numpy's median
    from circcal.detector.measure.robust import BAND_SAMPLE, BAND_SELECT_FROM, _band_median_of, _median_of

    rng = np.random.default_rng(12)
    missed = 0
    for n in (BAND_SELECT_FROM, BAND_SELECT_FROM + 1, 1000, 1401, 4096):
        for kind in range(5):
            r = [
                rng.normal(size=n),
                np.abs(rng.normal(size=n)) ** 3,
                rng.integers(0, 4, n).astype(float),
                np.sort(rng.normal(size=n)),
                rng.normal(size=n),
            ][kind]
            if kind == 4:  # the sampled positions hold the largest values: the band misses the median
                pos = ((2 * np.arange(BAND_SAMPLE) + 1) * n) // (2 * BAND_SAMPLE)
                r[pos] = 1e6 + np.arange(BAND_SAMPLE)
                missed += 1
            assert _median_of(r.copy(), n) == np.median(r)
            assert _band_median_of(r.copy(), n, (n - 1) // 2) == np.median(r)
    assert missed == 5


def test_median_and_mad_inliers_are_the_numpy_rule():
    # the compiled statistics against the numpy expressions they replaced, with ties, NaN, +-inf and empty rows
    from circcal.detector.measure.robust import MAD_TO_SIGMA, mad_inliers, median, row_medians

    rng = np.random.default_rng(7)
    for trial in range(200):
        D, M = int(rng.integers(1, 6)), int(rng.integers(1, 40))
        vals = rng.normal(size=(D, M)) * rng.choice([1e-3, 1.0, 50.0])
        if trial % 3 == 0:
            vals = np.round(vals, 1)  # ties
        special = rng.random((D, M))
        vals[special < 0.05] = np.nan
        vals[(special >= 0.05) & (special < 0.08)] = np.inf * rng.choice([-1, 1])
        mask = rng.random((D, M)) < 0.8
        mask[0] = mask[0] if trial % 4 else False  # a row without values keeps nothing
        floor = rng.random((D, M)) * 0.2
        sigmas = float(rng.choice([1.0, 4.0]))
        with np.errstate(invalid="ignore"):
            med = row_medians(np.where(mask, vals, np.nan))
            sdev = MAD_TO_SIGMA * row_medians(np.where(mask, np.abs(vals - med[:, None]), np.nan))
            expect = np.abs(vals) <= np.maximum((sigmas * sdev)[:, None], floor)
        assert np.array_equal(mad_inliers(vals, mask, floor, sigmas), expect)
        finite = vals[np.isfinite(vals)]
        if finite.size:
            assert median(finite) == np.median(finite)
    assert np.isnan(median(np.zeros(0)))


def test_shared_tables_are_computed_once_and_read_only():
    # detect_files runs images in threads: nothing global is mutated per call
    from circcal.detector.measure.curvature import _shift_table
    from circcal.detector.measure.edges import _profile_offsets

    assert _profile_offsets(2.0, 0.2) is _profile_offsets(2.0, 0.2) and _shift_table() is _shift_table()
    for table in (_profile_offsets(2.0, 0.2), _shift_table()):
        assert not table.flags.writeable


def test_the_compiled_ring_shares_are_the_numpy_rule():
    # dark_neighbourhood's shares, once numpy expressions (a median of three along each ring by np.roll, the tests'
    # means), now one compiled pass: the same values on random rings, with ties, NaN samples and no contrast
    from circcal.detector.measure.baddots import CLEARANCE_LEVEL, CLEARANCE_MIN_PX, _ring_shares

    rng = np.random.default_rng(21)
    for trial in range(40):
        D = int(rng.integers(1, 30))
        v = np.round(rng.uniform(0, 255, (D, 5, 48)), int(rng.integers(0, 3)))
        if trial % 4 == 0:
            v[rng.random(v.shape) < 0.02] = np.nan
        white, inner = rng.uniform(100, 255, D), rng.uniform(0, 150, D)
        near, far = rng.uniform(0, 5, D), rng.uniform(0, 8, D)
        a, b = np.roll(v[:, :2], 1, axis=-1), np.roll(v[:, :2], -1, axis=-1)
        ring = np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), v[:, :2])).reshape(D, -1)
        level = v[:, 2:].reshape(D, -1)
        contrast = white - inner
        dark = ring < (white - CLEARANCE_LEVEL * contrast)[:, None]
        mid = (level < (white - CLEARANCE_LEVEL * contrast)[:, None]) & (
            level > (inner + CLEARANCE_LEVEL * contrast)[:, None]
        )
        ok = contrast > 0
        want = (
            np.where(ok & (near >= CLEARANCE_MIN_PX), dark.mean(axis=1), 0.0),
            np.where(ok & (far > near), mid.mean(axis=1), 0.0),
        )
        got = np.empty(D), np.empty(D)
        _ring_shares(v, white, inner, near, far, CLEARANCE_LEVEL, CLEARANCE_MIN_PX, *got)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])


def test_the_compiled_ring_points_are_the_numpy_expression():
    from circcal.detector.measure.baddots import _COS, _SIN, _ring_points

    rng = np.random.default_rng(22)
    D, R = 37, 5
    c, axes = rng.uniform(0, 4000, (D, 2)), rng.uniform(1, 80, (D, 2))
    ang, radii = rng.uniform(-np.pi, np.pi, D), rng.uniform(0, 9, (D, R))
    cs, sn = np.cos(ang)[:, None, None], np.sin(ang)[:, None, None]
    a, b = axes[:, 0:1, None] + radii[:, :, None], axes[:, 1:2, None] + radii[:, :, None]
    want_x = (c[:, 0:1, None] + a * _COS * cs - b * _SIN * sn).reshape(D, -1).astype(np.float32)
    want_y = (c[:, 1:2, None] + a * _COS * sn + b * _SIN * cs).reshape(D, -1).astype(np.float32)
    x, y = np.empty_like(want_x), np.empty_like(want_y)
    _ring_points(c, axes, np.cos(ang), np.sin(ang), radii, _COS, _SIN, x, y)
    assert np.array_equal(x, want_x) and np.array_equal(y, want_y)


# ---- the vectorised detector against the per-dot formulation it replaced -------------------------------------


def _reference_levels(img, Q, origin, edge_px=2.0, step=1):
    """The per-dot level estimate as first written (one ROI, np.median, np.linalg.lstsq); ``step``: only the pixels
    of every step-th row and column from the ROI's corner."""
    from circcal.detector.measure.ellipse import conic_params

    c, (a, b), ang = conic_params(Q)
    h, w = img.shape
    yy, xx = np.mgrid[0:h, 0:w]
    xx, yy = xx + origin[0], yy + origin[1]
    dx, dy = xx - c[0], yy - c[1]
    u = (np.cos(ang) * dx + np.sin(ang) * dy) / a
    v = (-np.sin(ang) * dx + np.cos(ang) * dy) / b
    rho = np.sqrt(u * u + v * v)
    grid = ((xx - origin[0]) % step == 0) & ((yy - origin[1]) % step == 0)
    dark = float(np.median(img[(rho < 1.0 - edge_px / b) & grid]))
    ring = (rho > 1.0 + edge_px / b) & (rho < 1.0 + (edge_px + max(2.0, 0.5 * b)) / b) & grid
    vals = img[ring]
    keep = vals > 0.5 * (dark + np.median(vals))
    A = np.column_stack([xx[ring][keep], yy[ring][keep], np.ones(np.count_nonzero(keep))]).astype(float)
    plane, *_ = np.linalg.lstsq(A, vals[keep], rcond=None)
    res = vals[keep] - A @ plane
    ok = np.abs(res) < 4 * (1.4826 * np.median(np.abs(res)) + 1e-12)
    if np.count_nonzero(ok) >= 6 and not np.all(ok):
        plane, *_ = np.linalg.lstsq(A[ok], vals[keep][ok], rcond=None)
    return dark, plane


def _uneven_render():
    img, truth, *_ = _render(CAM, 12, 45)
    yy, xx = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    img = img * (0.6 + 0.4 * xx / img.shape[1]) + 0.02 * yy / img.shape[0]  # illumination gradient
    return img + np.random.default_rng(5).normal(0, 0.01, img.shape), truth


def test_batched_levels_equal_the_per_dot_estimate():
    from circcal.detector.measure.edges import PROFILE_HALF_MAX_PX, _pass_geometry
    from circcal.detector.measure.ellipse import conic_params_batch
    from circcal.detector.measure.levels import dot_levels_batch

    img, _ = _uneven_render()
    d = detect(img, BOARD)
    assert d.found, d.reason
    c = conic_params_batch(d.conics)[0]
    x0, y0, x1, y1 = _pass_geometry(np.ascontiguousarray(d.conics), 1.5, *img.shape, 1.0, PROFILE_HALF_MAX_PX)[5].T
    dark, plane, ok = dot_levels_batch(img, d.conics, np.stack([x0, y0, x1, y1], 1))
    assert np.all(ok)
    for k, Q in enumerate(d.conics):
        rd, rp = _reference_levels(img[y0[k] : y1[k], x0[k] : x1[k]], Q, (x0[k], y0[k]))
        assert dark[k] == pytest.approx(rd, abs=1e-12)
        # the plane at the dot's centre and its slopes
        assert plane[k] @ [*c[k], 1.0] == pytest.approx(rp @ [*c[k], 1.0], abs=1e-9)
        assert np.allclose(plane[k][:2], rp[:2], atol=1e-11)


def test_strided_levels_are_those_of_every_second_row_and_column():
    """stride 2 (a steering pass's levels): the dots of minor semi-axis >= 8 px take the levels of the pixels of
    every second row and column of their box, the smaller ones of every pixel (against the reference on those
    pixels); they agree with the full levels to the noise of a quarter of the pixels."""
    from circcal.detector.measure.edges import PROFILE_HALF_MAX_PX, _pass_geometry
    from circcal.detector.measure.ellipse import conic_params_batch
    from circcal.detector.measure.levels import STRIDE_MIN_MINOR_PX, dot_levels_from_params

    img, _ = _uneven_render()
    d = detect(img, BOARD)
    params = conic_params_batch(d.conics)
    c, axes = params[0], params[1]
    x0, y0, x1, y1 = _pass_geometry(np.ascontiguousarray(d.conics), 1.5, *img.shape, 1.0, PROFILE_HALF_MAX_PX)[5].T
    boxes = np.stack([x0, y0, x1, y1], 1)
    dark, plane, ok = dot_levels_from_params(img, *params, boxes, 2)
    dark1, plane1, _ = dot_levels_from_params(img, *params, boxes)
    big = axes[:, 1] >= STRIDE_MIN_MINOR_PX
    assert np.all(ok) and 0 < big.sum() < len(big)  # (both kinds of dot on this render)
    for k, Q in enumerate(d.conics):
        rd, rp = _reference_levels(img[y0[k] : y1[k], x0[k] : x1[k]], Q, (x0[k], y0[k]), step=2 if big[k] else 1)
        assert dark[k] == pytest.approx(rd, abs=1e-12)
        assert plane[k] @ [*c[k], 1.0] == pytest.approx(rp @ [*c[k], 1.0], abs=1e-9)
        assert np.allclose(plane[k][:2], rp[:2], atol=1e-11)
    assert np.array_equal(dark[~big], dark1[~big]) and np.array_equal(plane[~big], plane1[~big])
    bright = np.einsum("kj,kj->k", plane, np.column_stack([c, np.ones(len(c))]))
    bright1 = np.einsum("kj,kj->k", plane1, np.column_stack([c, np.ones(len(c))]))
    assert np.abs(bright - bright1)[big].max() < 0.01 and np.abs(dark - dark1)[big].max() < 0.01  # (noise 0.01)


def test_levels_of_dots_too_small_for_an_inside_are_their_nearest_pixels():
    """A dot whose inside (the ellipse shrunk by the edge gap) holds fewer than 3 pixels takes the median of the 3
    pixels nearest its centre (in the ellipse's own metric) as its dark level: against a direct computation, for
    float and uint8 images."""
    from circcal.detector.measure.ellipse import conic_from_params_batch
    from circcal.detector.measure.levels import DARK_MIN_PIXELS, dot_levels_batch

    rng = np.random.default_rng(11)
    img = rng.uniform(0.0, 1.0, (60, 80))
    c = np.column_stack([rng.uniform(15, 65, 8), rng.uniform(15, 45, 8)])
    axes = np.column_stack([rng.uniform(1.5, 2.5, 8), rng.uniform(1.0, 1.9, 8)])
    ang = rng.uniform(-1.5, 1.5, 8)
    Q = conic_from_params_batch(c, axes, ang)
    boxes = np.column_stack([np.floor(c - 9), np.ceil(c + 9)]).astype(int)
    for im in (img, np.rint(img * 255).astype(np.uint8)):
        dark, _, _ = dot_levels_batch(im, Q, boxes)
        for k in range(8):
            x0, y0, x1, y1 = boxes[k]
            yy, xx = np.mgrid[y0:y1, x0:x1]
            dx, dy = xx - c[k, 0], yy - c[k, 1]
            u = (np.cos(ang[k]) * dx + np.sin(ang[k]) * dy) / axes[k, 0]
            v = (-np.sin(ang[k]) * dx + np.cos(ang[k]) * dy) / axes[k, 1]
            near = np.argsort((u * u + v * v).ravel(), kind="stable")[:DARK_MIN_PIXELS]
            assert dark[k] == pytest.approx(float(np.median(im[y0:y1, x0:x1].ravel()[near])), abs=1e-12)


def _whole_profile_crossings(
    atlas, rows, org, base, nrm, S, n_iv, rank, todo, plane, halfk, off_out, at_out, rise_out, found_out
):
    """Reference for ``edges._crossings_kernel``: every sample of every profile (scipy's map_coordinates), then the
    up-crossing of the half level nearest to the boundary (ties: the lower index)."""
    from scipy import ndimage

    from circcal.detector.measure.edges import PROFILE_STEP_PX

    for d, j in zip(*np.nonzero(todo)):
        kk = np.arange(n_iv[d] + 1)
        px, py = base[d, j, 0] + S[d, kk] * nrm[d, j, 0], base[d, j, 1] + S[d, kk] * nrm[d, j, 1]
        v = ndimage.map_coordinates(
            atlas,
            [(py - org[d, 1]) + rows[d], px - org[d, 0]],
            order=3,
            mode="mirror",
            prefilter=False,
            output=np.float64,
        )
        F = v - (px * plane[d, 0] + py * plane[d, 1] + plane[d, 2]) * halfk[d]
        up = np.nonzero((F[:-1] < 0) & (F[1:] >= 0))[0]
        if len(up):
            mid = np.abs(0.5 * (S[d, up] + S[d, up + 1]))
            k = up[np.argmin(mid)]
            off_out[d, j] = S[d, k] + F[k] / (F[k] - F[k + 1]) * PROFILE_STEP_PX
            at_out[d, j] = base[d, j] + S[d, k] * nrm[d, j]
            rise_out[d, j], found_out[d, j] = F[k + 1] - F[k], True


def test_nearest_first_sampling_and_batching_change_no_edge_point(monkeypatch):
    from circcal.detector.measure import edges
    from circcal.detector.measure.dots import EDGE_SIGMA, fit_dots
    from circcal.detector.measure.edges import subpixel_edge_points_batch
    from circcal.detector.measure.smoothing import SmoothedImage

    img, _ = _uneven_render()
    d = detect(img, BOARD)
    src = SmoothedImage(img, EDGE_SIGMA)
    # nearest crossings found from a few samples per profile (compiled spline) = from the whole profiles sampled by
    # scipy's map_coordinates
    p1, m1, _ = subpixel_edge_points_batch(src, d.conics)
    monkeypatch.setattr(edges, "_crossings_kernel", _whole_profile_crossings)
    p2, m2, _ = subpixel_edge_points_batch(src, d.conics)
    assert m1.sum() > 0.9 * m1.size
    assert np.array_equal(m1, m2) and np.allclose(p1[m1], p2[m2], rtol=0, atol=1e-9)
    # all dots at once = one dot at a time (each then smoothed on its own small window)
    from circcal.detector.measure.ellipse import conic_from_params, conic_params_batch

    c, axes, ang, _ = conic_params_batch(d.conics)  # a slightly wrong start
    cands = np.array([conic_from_params(c[k] + 0.3, axes[k] * 0.97, ang[k] + 0.05) for k in range(len(c))])
    P, M, Qs, err = fit_dots(img, cands)
    assert err == [None] * len(cands)
    for k in range(len(cands)):
        p_k, m_k, q_k, e_k = fit_dots(img, cands[k : k + 1])
        assert e_k == [None]
        pts, Q = p_k[0][m_k[0]], q_k[0]
        assert np.array_equal(M[k].sum(), len(pts))
        assert np.allclose(P[k][M[k]], pts, rtol=0, atol=1e-8)
        assert np.allclose(Qs[k], Q, rtol=0, atol=1e-10)


@pytest.mark.parametrize("radius_px,tilt", [(7, 0), (15, 45), (30, 60)])
def test_sparse_steering_pass_moves_no_ellipse(radius_px, tilt, monkeypatch):
    """The steering pass measures a quarter of the profiles; from starts up to 0.5 px and 5 % off, the last pass's
    ellipses are those steered by every profile (measured <= 5e-6 px on these renders), the same points kept."""
    from circcal.detector.measure import dots
    from circcal.detector.measure.ellipse import conic_from_params, conic_params_batch

    img, _, *_ = _render(CAM, radius_px, tilt)
    c, axes, ang, _ = conic_params_batch(detect(img, BOARD).conics)
    rng = np.random.default_rng(1)
    starts = np.array(
        [
            conic_from_params(c[k] + rng.uniform(-0.5, 0.5, 2), axes[k] * rng.uniform(0.95, 1.05), ang[k] + 0.05)
            for k in range(len(c))
        ]
    )
    assert dots.STEERING_SPACING_PX > dots.PROFILE_SPACING_PX
    _, M, Q, err = dots.fit_dots(img, starts)
    monkeypatch.setattr(dots, "STEERING_SPACING_PX", dots.PROFILE_SPACING_PX)
    _, M1, Q1, err1 = dots.fit_dots(img, starts)
    assert err == err1 == [None] * len(starts)
    assert np.array_equal(M.sum(axis=1), M1.sum(axis=1))
    diff = np.abs(conic_params_batch(Q)[0] - conic_params_batch(Q1)[0])
    assert diff.max() < 1e-4, diff.max()


def test_a_dot_the_steering_pass_cannot_fit_is_measured_by_the_last_pass(monkeypatch):
    """A dot left with too few steering points (as a cut or occluded dot may be) is not dropped: it keeps its
    starting ellipse and the last pass measures it, as a single pass from that start would."""
    from circcal.detector.measure import dots
    from circcal.detector.measure.edges import subpixel_edge_points_batch

    img, _, *_ = _render(CAM, 15, 30)
    starts = detect(img, BOARD).conics
    real = subpixel_edge_points_batch

    def starved(src, conics, spacing_px=dots.PROFILE_SPACING_PX, **kw):
        out = real(src, conics, spacing_px=spacing_px, **kw)
        if spacing_px == dots.STEERING_SPACING_PX:  # the steering pass: dot 0 keeps 5 points
            mask = out[1]
            mask[0, np.nonzero(mask[0])[0][5:]] = False
        return out

    monkeypatch.setattr(dots, "subpixel_edge_points_batch", starved)
    P, M, Q, err = dots.fit_dots(img, starts)
    assert err == [None] * len(starts)
    monkeypatch.setattr(dots, "FIT_PASSES", 1)
    P1, M1, Q1, err1 = dots.fit_dots(img, starts[:1])
    assert err1 == [None]
    assert M[0].sum() == M1[0].sum() > dots.MIN_EDGE_POINTS
    assert np.allclose(P[0][M[0]], P1[0][M1[0]], rtol=0, atol=1e-8) and np.allclose(Q[0], Q1[0], rtol=0, atol=1e-10)


def test_smoothed_crops_are_the_exact_smoothing_to_a_millionth_of_the_range():
    """The spline samples of a crop (truncated combined filter, float32) against scipy's exact Gaussian smoothing and
    B-spline interpolation of the whole image: within 2e-6 of the grey range (measured 8e-7; the truncation of the
    combined kernel, :data:`~circcal.detector.measure.smoothing.COMBINED_TAIL`, dominates float32 rounding's ~1.5e-7)."""
    from scipy import ndimage

    from circcal.detector.measure.edges import _spline_at
    from circcal.detector.measure.smoothing import SmoothedImage

    rng = np.random.default_rng(3)
    img = (ndimage.gaussian_filter(rng.random((200, 240)), 2.0) * 1020 - 300).clip(0, 255).astype(np.uint8)
    img[60:120, 80:150] = 20  # a hard-edged dark block inside the box
    src = SmoothedImage(img, 1.5)
    atlas, rows, org = src.coefficient_atlas(src.crops_for(np.array([[70.0, 50.0, 160.0, 130.0]])))
    exact = ndimage.spline_filter(
        ndimage.gaussian_filter(img.astype(np.float64), 1.5, mode="reflect"), order=3, mode="mirror"
    )
    pts = np.column_stack([rng.uniform(70, 160, 2000), rng.uniform(50, 130, 2000)])
    mine = np.array([_spline_at(atlas, (y - org[0, 1]) + rows[0], x - org[0, 0]) for x, y in pts])
    ref = ndimage.map_coordinates(exact, [pts[:, 1], pts[:, 0]], order=3, mode="mirror", prefilter=False)
    assert np.abs(mine - ref).max() < 2e-6 * 255


def test_compiled_spline_equals_scipy_map_coordinates_including_the_mirror():
    from scipy import ndimage

    from circcal.detector.measure.edges import _spline_at

    rng = np.random.default_rng(1)
    atlas = rng.random((12, 9)).astype(np.float32)
    r = rng.uniform(-0.9, 11.9, 200)
    c = rng.uniform(-0.9, 8.9, 200)
    ref = ndimage.map_coordinates(atlas, [r, c], order=3, mode="mirror", prefilter=False, output=np.float64)
    ours = np.array([_spline_at(atlas, a, b) for a, b in zip(r, c)])
    assert np.allclose(ours, ref, rtol=0, atol=1e-12)
    assert np.isnan(_spline_at(atlas, np.nan, 1.0)) and np.isfinite(_spline_at(atlas, 1e9, -1e9))  # never out of bounds


def test_local_steps_are_the_neighbour_differences():
    # the compiled neighbour search against the differences written out (central where both neighbours are in
    # the set, one-sided at its edge, NaN without any), on symmetric and asymmetric boards, subsets, NaN centres
    from circcal.board import Board
    from circcal.detector.measure.trust import local_steps

    rng = np.random.default_rng(4)
    for layout, M in (("symmetric", np.eye(2)), ("asymmetric", np.array([[1.0, 1.0], [-1.0, 1.0]]))):
        board = Board(5, 6, 10.0, 5.0, layout=layout)
        L = board.lattice_coords()
        for _ in range(30):
            pts = np.sort(rng.choice(board.n_points, int(rng.integers(1, board.n_points + 1)), replace=False))
            c = rng.normal(size=(len(pts), 2)) * 100.0
            c[rng.random(len(pts)) < 0.1] = np.nan
            where = {tuple(L[p]): i for i, p in enumerate(pts)}
            Jp = np.full((len(pts), 2, 2), np.nan)
            for i, p in enumerate(pts):
                for s, st in enumerate(M.T.astype(int)):
                    f, r = where.get(tuple(L[p] + st)), where.get(tuple(L[p] - st))
                    if f is not None and r is not None:
                        Jp[i, :, s] = 0.5 * (c[f] - c[r])
                    elif f is not None:
                        Jp[i, :, s] = c[f] - c[i]
                    elif r is not None:
                        Jp[i, :, s] = c[i] - c[r]
            assert np.array_equal(local_steps(board, pts, c), Jp @ np.linalg.inv(M), equal_nan=True)
    assert local_steps(Board(3, 3, 10.0, 5.0), np.zeros(0, int), np.zeros((0, 2))).shape == (0, 2, 2)


def test_edge_blur_is_the_median_slope_scale():
    # the compiled pass against numpy's expressions: sigma_t = A / (sqrt(2 pi) slope) per profile, the median of
    # the finite positive ones where a crossing was found, never below the nominal blur (that without any)
    from circcal.detector.measure.edges import PIXEL_BOX_VARIANCE, PROFILE_STEP_PX, _edge_blur

    rng = np.random.default_rng(8)
    for _ in range(50):
        D, N = int(rng.integers(1, 6)), int(rng.integers(1, 60))
        at = rng.uniform(0, 400, (D, N, 2))
        rise = rng.normal(size=(D, N)) * rng.choice([1e-6, 0.1, 10.0])
        rise[rng.random((D, N)) < 0.1] = 0.0
        plane = np.column_stack([rng.normal(size=(D, 2)) * 1e-3, rng.uniform(100, 200, D)])
        ratio, ok, sigma = rng.uniform(0, 1.2, D), rng.random((D, N)) < 0.7, float(rng.choice([0.0, 1.5]))
        with np.errstate(divide="ignore", invalid="ignore"):
            st = (
                ((at[..., 0] * plane[:, :1] + at[..., 1] * plane[:, 1:2]) + plane[:, 2:])
                * (1.0 - ratio)[:, None]
                / (np.sqrt(2.0 * np.pi) * (rise / PROFILE_STEP_PX))
            )
        use = ok & np.isfinite(st) & (st > 0)
        nominal = np.sqrt(sigma * sigma + PIXEL_BOX_VARIANCE)
        expect = [max(nominal, np.median(st[d][use[d]])) if use[d].any() else nominal for d in range(D)]
        assert np.array_equal(_edge_blur(at, rise, plane, ratio, ok, sigma), expect)


def test_compiled_curvature_shift_is_the_numpy_expression():
    # per point in the edge kernel (curvature.shift_at), numpy's vectorised expression to the bit: table
    # interpolation (np.interp, nodes hit exactly), the asymptote beyond the table, the fade, and NaN passed on;
    # the kernel's point is base + (offset + shift) * normal, here 0 + (0 + shift) * (1, 0), its slack the rest
    from circcal.detector.measure import curvature as C
    from circcal.detector.measure.edges import _edge_points_kernel

    def numpy_shift(a, b, cos_t, sin_t, sigma_t):
        table, U = C._shift_table(), C.U_TABLE
        a, b = a[:, None], b[:, None]
        q = (a * sin_t) ** 2 + (b * cos_t) ** 2
        u = q * np.sqrt(q) / (a * b) / sigma_t[:, None]
        shift = np.where(u > U[-1], 0.5 / np.maximum(u, 1e-9), np.interp(u, U, table, left=table[0]))
        fade = np.clip((u - C.MODEL_FROM_U) / (C.MODEL_FULL_U - C.MODEL_FROM_U), 0.0, 1.0)
        return sigma_t[:, None] * shift * fade, sigma_t[:, None] * shift * (1.0 - fade)

    rng = np.random.default_rng(0)
    a = rng.uniform(0.5, 80.0, 300)
    b = a * rng.uniform(0.05, 1.0, 300)
    t = rng.uniform(0.0, 2.0 * np.pi, (300, 50))
    n = len(C.U_TABLE)
    cases = [
        (a, b, np.cos(t), np.sin(t), rng.uniform(0.3, 5.0, 300)),
        (a, b, np.cos(t), np.sin(t), np.full(300, np.nan)),
        (np.ones(n), np.ones(n), np.ones((n, 1)), np.zeros((n, 1)), 1.0 / C.U_TABLE),
    ]  # u on every node
    for a_, b_, cos_t, sin_t, sigma_t in cases:
        D, N = cos_t.shape
        nrm = np.zeros((D, N, 2))
        nrm[..., 0] = 1.0
        pts, slack = np.empty((D, N, 2)), np.empty((D, N))
        _edge_points_kernel(
            np.zeros((D, N, 2)),
            nrm,
            np.zeros((D, N)),
            np.ones((D, N), bool),
            a_,
            b_,
            cos_t,
            sin_t,
            sigma_t,
            C.U_TABLE,
            C._shift_table(),
            pts,
            slack,
        )
        shift, rest = numpy_shift(a_, b_, cos_t, sin_t, sigma_t)
        assert np.array_equal(pts[..., 0], 0.0 + (0.0 + shift) * 1.0, equal_nan=True)
        assert np.array_equal(slack, rest, equal_nan=True)


def _staggered_dots(rows: int, cols: int, pitch: float = 40.0, radius: float = 9.0) -> np.ndarray:
    """(480, 640) uint8: a staggered (acircles) lattice of dark dots, anti-aliased and lightly blurred."""
    img = np.full((480, 640), 220, np.uint8)
    for i in range(rows):
        for j in range(cols):
            x, y = 100 + (2 * j + i % 2) * pitch, 80 + i * pitch
            cv2.circle(img, (int(x * 16), int(y * 16)), int(radius * 16), 30, -1, cv2.LINE_AA, 4)
    return cv2.GaussianBlur(img, (0, 0), 1.0)


def test_a_lattice_of_another_layout_is_refused_where_the_board_would_show_bare_places():
    # a staggered 5x5 lattice: its diagonals make a square lattice of 25 of the 49 places of a 7x7 board, the
    # other places (inside the image) are bare board: not the board
    img = _staggered_dots(5, 5)
    d = detect(img, Board(7, 7, 10.0, 5.0))
    assert not d.found and d.code == Reason.GRID_NOT_RECOGNISED and "bare board" in d.reason
    assert detect(img, Board(5, 5, 10.0, 5.0, layout="asymmetric")).found


@pytest.mark.parametrize("how", ["erased", "glare"])
def test_a_dot_washed_out_is_left_out_in_words_and_the_view_kept(how):
    # one dot of 49 white where it lies (glare, a dot missing from the print): within ABSENT_MAX_SHARE of the
    # labelled dots, so the lattice is still the board's; the dot is named among those left out
    from circcal.detector.measure.trust import ABSENT_MAX_SHARE

    board = Board(7, 7, 10.0, 5.0)
    cam = Camera(640, 480, 900.0, 900.0, 319.5, 239.5)
    rvec, tvec = pose_looking_at(
        cam, board, distance_mm=180.0, tilt_deg=20.0, tilt_axis_deg=30.0, roll_deg=5.0, target_px=(320.0, 240.0)
    )
    truth = project(board.object_points(), rvec, tvec, cam)
    img = render_view(cam, board, rvec, tvec)
    k = 24  # the middle dot
    r = 900.0 * board.radius_mm / 180.0 * 1.4
    yy, xx = np.mgrid[:480, :640]
    near = (xx - truth[k, 0]) ** 2 + (yy - truth[k, 1]) ** 2 < r**2
    if how == "erased":
        img[near] = img[~near].max()
    else:  # a bright specular spot over it, saturating the white
        img = np.clip(img + 2.0 * np.exp(-((xx - truth[k, 0]) ** 2 + (yy - truth[k, 1]) ** 2) / (2 * r * r)), 0, 1)
    d = detect(to_uint(img, 8), board)
    assert d.found, d.reason
    assert 1 <= ABSENT_MAX_SHARE * 48
    assert "not seen" in d.dropped[k] and np.all(np.isnan(d.centres[k]))
    e = np.linalg.norm(d.centres - truth, axis=1)
    if how == "erased":
        assert list(d.dropped) == [k] and np.nanmax(e) < 0.02  # the other 48: as on a clean render
    else:
        # the spot's light, added over its 4 axis neighbours, lights their insides unevenly (9-13 % of their
        # contrast across them; they had moved by 0.24-0.32 px): left out in words; the rest as on a clean render
        axis = [k - 7, k - 1, k + 1, k + 7]
        assert sorted(d.dropped) == sorted([k, *axis])
        assert all("uneven inside" in d.dropped[i] for i in axis)
        assert np.nanmax(e) < 0.02, np.nanmax(e)


def test_light_added_over_a_dot_is_measured_and_multiplied_light_is_not():
    # the inside of a dot, sampled half-way to its centre: its first harmonic is the gradient of its grey level.
    # Light added on top (a reflection) tilts the dark inside as much as the white around; light that multiplies
    # the albedo (the uneven light the edge model takes) tilts it only by the dark's share of the white
    from circcal.detector.measure.baddots import UNEVEN_SHARE, _uneven_inside

    yy, xx = np.mgrid[:200, :200].astype(np.float64)
    disk = np.where((xx - 100.3) ** 2 + (yy - 99.6) ** 2 < 30.0**2, 0.12, 0.85)
    ramp = (xx - 100.0) / 100.0  # -1 .. 1 across the image: 0.3 across a radius
    centre, axes, ang = np.array([[100.3, 99.6]]), np.array([[30.0, 30.0]]), np.array([0.0])
    flat = _uneven_inside(disk * 255, centre, axes, ang)[0]
    added = _uneven_inside((disk + 0.2 * ramp) * 255, centre, axes, ang)[0]  # 0.06 of the range per radius
    multiplied = _uneven_inside(disk * (1 + 0.2 * ramp) * 255, centre, axes, ang)[0]
    assert flat < 1e-3
    assert added == pytest.approx(0.06 / 0.73, rel=0.05) and added > UNEVEN_SHARE  # contrast 0.73 of the range
    assert multiplied == pytest.approx(0.12 * 0.06 / 0.73, rel=0.15) and multiplied < UNEVEN_SHARE
