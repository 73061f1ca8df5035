"""The board's location (:mod:`circcal.detector.locate`): the segmentation (the guided filter and Otsu's threshold
against OpenCV's, when the filter runs, the shrunk copies and the scale the dots are searched at) and the candidate
dots' contour measures against OpenCV's."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from circcal.detector import detect
from circcal.model import Camera
from tests.detector.helpers import BOARD, _render, matched_errors


def test_the_compiled_contour_measures_are_opencvs():
    # find_candidates measures all contours in one compiled pass instead of cv2.moments, arcLength, convexHull +
    # contourArea and boundingRect per contour: the same values to the bit, on masks of specks, blobs and ellipses
    from circcal.detector.locate.candidates import _contour_measures

    rng = np.random.default_rng(3)
    checked = 0
    for trial in range(60):
        H, W = (int(v) for v in rng.integers(20, 300, 2))
        m = (rng.random((H, W)) > rng.uniform(0.3, 0.995)).astype(np.uint8) * 255
        if trial % 2:
            m = cv2.dilate(m, np.ones((int(rng.integers(1, 9)),) * 2, np.uint8))
        if trial % 3 == 0:
            m = np.zeros((H, W), np.uint8)
            for _ in range(int(rng.integers(1, 30))):
                cv2.ellipse(
                    m,
                    (int(rng.integers(0, W)), int(rng.integers(0, H))),
                    (int(rng.integers(1, 60)), int(rng.integers(1, 60))),
                    float(rng.uniform(0, 180)),
                    0,
                    360,
                    255,
                    -1,
                )
        cs = [c for c in cv2.findContours(m, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)[0] if len(c) >= 3]
        if not cs:
            continue
        counts = np.array([len(c) for c in cs], np.int64)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        out = np.empty((len(cs), 12))
        _contour_measures(
            np.ascontiguousarray(np.concatenate(cs).reshape(-1, 2), np.int64), starts, counts, 0.0, np.inf, out
        )
        for c, got in zip(cs, out.tolist()):
            mm = cv2.moments(c)
            x, y, w, h = cv2.boundingRect(c)
            assert got == [
                mm["m00"],
                mm["m10"],
                mm["m01"],
                mm["mu20"],
                mm["mu11"],
                mm["mu02"],
                cv2.arcLength(c, True),
                cv2.contourArea(cv2.convexHull(c)),
                x,
                y,
                x + w - 1,
                y + h - 1,
            ]
            checked += 1
    assert checked > 10000


def test_guided_filter_is_opencvs_to_float32_rounding():
    from circcal.detector.kernels.build import synthetic_board
    from circcal.detector.locate.segment import GUIDED_EPS, guided_filter

    board_img, _ = synthetic_board()
    noise = np.random.default_rng(0).integers(0, 256, (480, 640), dtype=np.uint8)
    for img, share in ((board_img, 1e-3), (noise, 1e-2), (np.full((40, 50), 77, np.uint8), 0.0)):
        for radius in (2, 3, 5):
            g = img.astype(np.float32) * np.float32(1.0 / 255.0)
            ref = cv2.convertScaleAbs(cv2.ximgproc.guidedFilter(g, g, radius, GUIDED_EPS), alpha=255.0)
            d = np.abs(guided_filter(img, radius, GUIDED_EPS).astype(int) - ref)
            assert d.max() <= 1 and np.count_nonzero(d) <= share * d.size


def _written_out_guided_filter(gray_u8: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """The guided filter's steps written out with OpenCV's float32 box filter and numpy's float32 arithmetic (what
    circcal ran before its compiled pass)."""
    k = (2 * radius + 1, 2 * radius + 1)

    def box(x):
        return cv2.boxFilter(x, cv2.CV_32F, k, normalize=True, borderType=cv2.BORDER_REFLECT)

    g = np.multiply(gray_u8, np.float32(1.0 / 255.0), dtype=np.float32)
    mean = box(g)
    cov = box(g * g) - mean * mean
    a = cov * (np.float32(1.0) / (cov + np.float32(eps)))
    return cv2.convertScaleAbs(box(a) * g + box(mean - a * mean), alpha=255.0)


def test_compiled_guided_filter_is_the_written_out_filter_to_the_bit():
    # one streamed pass with integer box sums against OpenCV's box filters and float32 arithmetic: the same uint8
    # image, at every radius the detector uses (2 at 640x480 ... 8 at 8000x6000's scale 2) and beyond, on boards,
    # noise, sizes smaller than the window (the reflection repeated), and a view that is not contiguous; the histogram
    # it hands over is the result's; threads share nothing (the same results from 4 at once)
    from concurrent.futures import ThreadPoolExecutor

    from circcal.detector.kernels.build import synthetic_board
    from circcal.detector.locate.segment import GUIDED_EPS, guided_filter

    rng = np.random.default_rng(2)
    board_img, _ = synthetic_board()
    images = [
        board_img,
        cv2.GaussianBlur(board_img, (0, 0), 2.0),
        board_img[::2, ::3],
        np.full((40, 50), 77, np.uint8),
        np.full((1, 9), 200, np.uint8),
    ]
    images += [
        rng.integers(0, 256, (int(rng.integers(1, 120)), int(rng.integers(1, 160))), dtype=np.uint8) for _ in range(12)
    ]
    for img in images:
        for radius in (1, 2, 3, 5, 8, 13):
            hist = np.zeros(256, np.int64)
            got = guided_filter(img, radius, GUIDED_EPS, hist)
            assert np.array_equal(got, _written_out_guided_filter(img, radius, GUIDED_EPS)), (img.shape, radius)
            assert np.array_equal(hist, np.bincount(got.ravel(), minlength=256))
    expect = [guided_filter(im, 3, GUIDED_EPS) for im in images]

    def run(k: int) -> bool:
        return all(
            np.array_equal(guided_filter(images[(k + j) % len(images)], 3, GUIDED_EPS), expect[(k + j) % len(images)])
            for j in range(40)
        )

    with ThreadPoolExecutor(4) as pool:
        assert all(pool.map(run, range(4)))


def test_otsu_threshold_from_the_histogram_is_opencvs():
    from circcal.detector.kernels.build import synthetic_board
    from circcal.detector.locate.segment import GUIDED_EPS, guided_filter, otsu_threshold

    rng = np.random.default_rng(3)
    board_img, _ = synthetic_board()
    images = [
        board_img,
        guided_filter(board_img, 2, GUIDED_EPS),
        np.full((30, 40), 9, np.uint8),
        np.where(rng.random((50, 60)) < 0.01, 255, 0).astype(np.uint8),
    ]
    images += [
        rng.integers(int(lo), 256, (int(rng.integers(1, 200)), int(rng.integers(1, 200))), dtype=np.uint8)
        for lo in rng.integers(0, 250, 20)
    ]
    images += [np.clip(rng.normal(m, s, (120, 90)), 0, 255).astype(np.uint8) for m, s in ((60, 5), (128, 40), (250, 3))]
    for img in images:
        t_cv, mask_cv = cv2.threshold(img, 0, 255, cv2.THRESH_BINARY_INV + cv2.THRESH_OTSU)
        t = otsu_threshold(np.bincount(img.ravel(), minlength=256))
        assert t == int(t_cv)
        assert np.array_equal(cv2.threshold(img, t, 255, cv2.THRESH_BINARY_INV)[1], mask_cv)
    assert otsu_threshold(np.zeros(256, np.int64)) == 0  # (no pixels: no division by their count)


def test_shrink_is_opencvs_area_resize():
    """The compiled block means of uint8 images (scales >= 3) equal ``cv2.resize(..., INTER_AREA)`` to the bit,
    ties (even block sizes) included, on noise, on a board and on sizes that are not multiples of the scale; the
    other dtypes and scale 2 are OpenCV's own call."""
    from circcal.detector.kernels.build import synthetic_board
    from circcal.detector.locate.segment import shrink

    rng = np.random.default_rng(5)
    board_img, _ = synthetic_board()
    images = [board_img, np.repeat(np.repeat(board_img, 3, axis=0), 3, axis=1)]
    images += [
        rng.integers(0, 256, (int(rng.integers(20, 500)), int(rng.integers(20, 700))), dtype=np.uint8)
        for _ in range(12)
    ]
    for img in images:
        for s in range(2, 10):
            H, W = img.shape
            if H < s or W < s:
                continue
            ref = cv2.resize(img[: H // s * s, : W // s * s], (W // s, H // s), interpolation=cv2.INTER_AREA)
            out = shrink(img, s)
            assert out.dtype == np.uint8 and out.shape == ref.shape
            assert np.array_equal(out, ref), (img.shape, s, int(np.count_nonzero(out != ref)))
    f = board_img.astype(np.float32)
    assert np.array_equal(shrink(f, 3), cv2.resize(f[:480, :639], (213, 160), interpolation=cv2.INTER_AREA))


def test_shrunk_segmentation_agrees_with_full(monkeypatch):
    from circcal.detector.locate import search

    cam = Camera(1600, 1200, 2000.0, 2000.0, 799.5, 599.5)
    img, truth, *_ = _render(cam, 14, 40, target=(850.0, 600.0))
    img = cv2.GaussianBlur(img, (0, 0), 1.0) + np.random.default_rng(2).normal(0, 0.01, img.shape)
    half = detect(img, BOARD)
    assert half.found and half.segmentation.endswith("@1/3")  # 1200 // 360
    monkeypatch.setattr(search, "segmentation_scales", lambda h, w: (1,))
    full = detect(img, BOARD)
    assert full.found and "@" not in full.segmentation
    e_half, e_full = matched_errors(BOARD, half.centres, truth), matched_errors(BOARD, full.centres, truth)
    print(
        f"\nshrunk segmentation: RMS {np.sqrt(np.mean(e_half**2)):.5f} px; full: "
        f"{np.sqrt(np.mean(e_full**2)):.5f} px; max difference {np.abs(half.centres - full.centres).max():.2e}"
    )
    # only the starting ellipses differ: the same centres to well below the noise-limited accuracy
    assert np.abs(half.centres - full.centres).max() < 2e-3
    assert np.sqrt(np.mean(e_half**2)) <= 0.01


@pytest.mark.parametrize(
    "size,radius_px,scale",
    [((1920, 1080), 7.5, "@1/2"), ((1920, 1080), 5.0, None), ((3840, 2160), 8.0, "@1/2"), ((3840, 2160), 25.0, "@1/6")],
)
def test_small_dots_go_to_the_coarsest_scale_that_resolves_them(size, radius_px, scale):
    # 1920x1080 starts at 1/3; dots of 7.5 px are 2.5 px there (too small), 3.75 px at 1/2; 5 px dots need full size.
    # 3840x2160 tries 1/6, 1/3, 1/2: 8 px dots are not found at 1/6 or 1/3.
    cam = Camera(*size, 2000.0, 2000.0, size[0] / 2 - 0.5, size[1] / 2 - 0.5)
    img, truth, *_ = _render(cam, radius_px, 20, target=(size[0] * 0.47, size[1] * 0.46))
    d = detect(img, BOARD)
    assert d.found, d.reason
    seg = d.segmentation.split("[")[0]  # "[x0:x1,y0:y1]": segmented in the board's window only
    assert seg.endswith(scale) if scale else "@" not in seg
    assert np.sqrt(np.mean(matched_errors(BOARD, d.centres, truth) ** 2)) <= 0.005


def test_guided_filter_runs_where_the_image_has_noise_and_changes_only_edges_where_not(monkeypatch):
    # the filter is skipped on an image whose noise is below GUIDED_MIN_NOISE: there it would move no flat pixel
    # across a threshold, only edge pixels, and the candidates (the edge fit's starts) stay where they were
    from circcal.detector.image import normalise_u8
    from circcal.detector.kernels.build import synthetic_board
    from circcal.detector.locate import segment
    from circcal.detector.locate.candidates import find_candidates

    board_img, _ = synthetic_board()
    clean = normalise_u8(cv2.GaussianBlur(board_img, (0, 0), 1.0))
    noisy = normalise_u8(np.clip(clean + np.random.default_rng(8).normal(0, 8.0, clean.shape), 0, 255).astype(np.uint8))
    calls = []
    real = segment.guided_filter
    monkeypatch.setattr(segment, "guided_filter", lambda *a, **k: calls.append(1) or real(*a, **k))
    s_clean, s_noisy = segment.noise_sigma_u8(clean), segment.noise_sigma_u8(noisy)
    assert s_clean <= segment.GUIDED_MIN_NOISE < s_noisy
    masks = dict(segment.segmentations(clean, s_clean))
    assert not calls and list(masks)[0] == "otsu" and "guided-otsu" not in masks
    noisy_masks = segment.segmentations(noisy, s_noisy)
    assert next(noisy_masks)[0] == "otsu" and not calls  # plain Otsu first: a board found there needs no filter
    assert next(noisy_masks)[0] == "guided-otsu" and calls
    filtered = dict(segment.segmentations(clean))  # (no noise given: always filtered)
    for name in masks:
        other = "guided-otsu" if name == "otsu" else name
        differ = masks[name] != filtered[other]
        edge = cv2.morphologyEx(filtered[other], cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
        assert not np.any(differ & ~edge), name  # flat areas: the same side of every threshold
    a = find_candidates(masks["otsu"], min_area=12.0, max_area=1e5)
    b = find_candidates(filtered["guided-otsu"], min_area=12.0, max_area=1e5)
    assert len(a) == len(b) == 30
    pa, pb = np.array([c.centre for c in a]), np.array([c.centre for c in b])
    assert np.abs(np.sort(pa, axis=0) - np.sort(pb, axis=0)).max() < 0.1


@pytest.mark.parametrize("sigma", [8.0, 16.0])
def test_plain_otsu_of_a_noisy_image_differs_from_the_filtered_one_only_on_edges(sigma):
    # why a noisy image is thresholded at Otsu's level before it is filtered: that level lies ~half the contrast
    # (here ~130 grey levels) from the dots' and the board's, many noise sigmas (4 and 8 after the stretch), so the
    # filter would change no flat pixel's side of it
    from circcal.detector.image import normalise_u8
    from circcal.detector.kernels.build import synthetic_board
    from circcal.detector.locate import segment
    from circcal.detector.locate.candidates import find_candidates

    board_img, _ = synthetic_board()
    clean = normalise_u8(cv2.GaussianBlur(board_img, (0, 0), 1.0))
    noisy = normalise_u8(
        np.clip(clean + np.random.default_rng(8).normal(0, sigma, clean.shape), 0, 255).astype(np.uint8)
    )
    noise = segment.noise_sigma_u8(noisy)
    assert noise > segment.GUIDED_MIN_NOISE
    masks = dict(segment.segmentations(noisy, noise))
    plain, filtered = masks["otsu"], masks["guided-otsu"]
    edge = cv2.morphologyEx(filtered, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
    assert not np.any((plain != filtered) & ~edge)
    a = find_candidates(plain, min_area=12.0, max_area=1e5)
    b = find_candidates(filtered, min_area=12.0, max_area=1e5)
    assert len(a) == len(b) == 30
    pa, pb = np.array([c.centre for c in a]), np.array([c.centre for c in b])
    assert np.abs(np.sort(pa, axis=0) - np.sort(pb, axis=0)).max() < 0.1
