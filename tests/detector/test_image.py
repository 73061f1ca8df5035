"""Images as the detector reads them (:mod:`circcal.detector.image`; issue 31 item 3): every image kind it takes is
found from its file, an unreadable file is ``unreadable``, and a PNG whose header claims 100000 x 100000 px is
refused before decoding (``image-too-large``; the limit set by ``CIRCCAL_MAX_IMAGE_PIXELS``).
"""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from circcal.detector import Reason, detect, detect_files
from circcal.detector.image import (
    MAX_IMAGE_PIXELS,
    MAX_IMAGE_PIXELS_ENV,
    ImageTooLargeError,
    max_image_pixels,
    read_image,
)
from circcal.detector.overlay import overlay_file
from circcal.errors import ImageError, InputError
from circcal.fixtures.render import to_uint
from tests.detector.helpers import BOARD, CAM, _render, huge_png, matched_errors, tiff_with_samples, write


def test_every_image_kind_the_detector_takes_is_found_from_its_file(tmp_path, view):
    g8 = to_uint(view, 8)
    g16 = to_uint(view, 16)
    kinds = {
        "u8.png": g8,
        "u16.png": g16,
        "bgr.png": cv2.cvtColor(g8, cv2.COLOR_GRAY2BGR),
        "bgra16.png": cv2.cvtColor(g16, cv2.COLOR_GRAY2BGRA),
        "f32.tiff": view.astype(np.float32),
        "f64.tiff": view.astype(np.float64),
        "i16.tiff": (g16.astype(np.int32) - 30000).astype(np.int16),
        "i32.tiff": g16.astype(np.int32) * 7 - 100000,
        "i8.tiff": (g8.astype(np.int16) - 128).astype(np.int8),
        "i16_bgr.tiff": cv2.merge([(g16 // 2).astype(np.int16)] * 3),
        "f64_bgr.tiff": cv2.merge([view.astype(np.float64)] * 3),
    }
    paths = [write(tmp_path / name, img) for name, img in kinds.items()]
    for path, img in zip(paths, kinds.values()):
        assert read_image(path).dtype == img.dtype, path.name
    dets = detect_files(paths, BOARD, progress=False, jobs=1)
    assert [d.found for d in dets] == [True] * len(paths), [(p.name, d.reason) for p, d in zip(paths, dets)]
    ref = dets[0].centres
    for path, d in zip(paths, dets):
        assert np.nanmax(np.abs(d.centres - ref)) < 0.05, path.name


def test_an_unreadable_file_is_unreadable(tmp_path, view):
    if os.geteuid() == 0:
        pytest.skip("run as root: chmod 000 does not stop reading")
    locked = write(tmp_path / "locked.png", to_uint(view, 8))
    locked.chmod(0)
    try:
        (d,) = detect_files([locked], BOARD, progress=False)
        assert d.code == Reason.UNREADABLE and "cannot read" in d.reason
        assert overlay_file(locked, d) is None
    finally:
        locked.chmod(0o600)


def test_a_huge_header_is_refused_without_decoding(tmp_path, monkeypatch):
    from circcal.detector import image

    path = huge_png(tmp_path / "huge.png")
    assert path.stat().st_size < 100

    def no_decoding(data):
        raise AssertionError("the decoder was called")

    monkeypatch.setattr(image, "_imdecode", no_decoding)
    for read in (lambda: read_image(path), lambda: image.decode_image(np.fromfile(path, np.uint8))):
        with pytest.raises(ImageTooLargeError, match="claims 10000000000 pixels") as raised:
            read()
        assert raised.value.pixels == 10**10 and raised.value.limit == MAX_IMAGE_PIXELS
        assert "not decoded" in str(raised.value) and "\n" not in str(raised.value)
        assert isinstance(raised.value, ImageError)
    (d,) = detect_files([path], BOARD, progress=False)
    assert d.code == Reason.IMAGE_TOO_LARGE and not d.found and d.image_size is None


def test_the_limit_is_set_by_the_environment(tmp_path, monkeypatch, view):
    small = write(tmp_path / "small.png", to_uint(view, 8))  # 480 x 360 = 172800 px
    monkeypatch.setenv(MAX_IMAGE_PIXELS_ENV, "100000")
    assert max_image_pixels() == 100000
    (d,) = detect_files([small], BOARD, progress=False)
    assert d.code == Reason.IMAGE_TOO_LARGE and "480 x 360 px" in d.reason and "limit of 100000" in d.reason
    monkeypatch.setenv(MAX_IMAGE_PIXELS_ENV, "172_800")
    assert detect_files([small], BOARD, progress=False)[0].found
    monkeypatch.setenv(MAX_IMAGE_PIXELS_ENV, "2e10")  # above the 100000 x 100000 claim
    assert max_image_pixels() == 2 * 10**10
    huge = huge_png(tmp_path / "huge.png")
    (d,) = detect_files([huge], BOARD, progress=False)  # the decoder (OpenCV) decides: its own limit
    assert d.code == Reason.IMAGE_TOO_LARGE and "OPENCV_IO_MAX_IMAGE_PIXELS" in d.reason, d.reason
    monkeypatch.setenv(MAX_IMAGE_PIXELS_ENV, "5000")  # a format Pillow cannot read: checked decoded
    hdr = write(tmp_path / "radiance.hdr", np.dstack([view.astype(np.float32)] * 3))
    (d,) = detect_files([hdr], BOARD, progress=False)
    assert d.code == Reason.IMAGE_TOO_LARGE and "decodes to 480 x 360 px" in d.reason, d.reason
    for bad in ("0", "-5", "lots", "1.5", "inf", "nan"):
        monkeypatch.setenv(MAX_IMAGE_PIXELS_ENV, bad)
        with pytest.raises(InputError, match=MAX_IMAGE_PIXELS_ENV) as raised:
            detect_files([small], BOARD, progress=False)  # a setting: not one image's problem
        assert not isinstance(raised.value, ImageError)
    monkeypatch.delenv(MAX_IMAGE_PIXELS_ENV)
    assert max_image_pixels() == MAX_IMAGE_PIXELS


def test_pillows_bomb_warning_is_not_left_to_the_caller(tmp_path, monkeypatch, recwarn):
    # 150 MP: above Pillow's warning threshold (~89 MP), below its error (~179 MP): the size is read, no warning
    from PIL import Image

    assert Image.MAX_IMAGE_PIXELS < 150_000_000 < 2 * Image.MAX_IMAGE_PIXELS
    monkeypatch.setenv(MAX_IMAGE_PIXELS_ENV, "100000000")
    (d,) = detect_files([huge_png(tmp_path / "wide.png", 15_000, 10_000)], BOARD, progress=False)
    assert d.code == Reason.IMAGE_TOO_LARGE and "claims 15000 x 10000 px (150 MP)" in d.reason, d.reason
    assert not [w for w in recwarn if "decompression" in str(w.message).lower()]


def test_opencvs_decoding_errors_are_messages_not_exceptions(tmp_path):
    # a 5-sample TIFF: OpenCV's decoder fails with an error of its own; said in the reason, not printed
    (d,) = detect_files([tiff_with_samples(tmp_path / "five.tiff", 5)], BOARD, progress=False)
    assert d.code == Reason.UNREADABLE and "Unsupported number of channels" in d.reason
    assert "loadsave.cpp" not in d.reason and "\n" not in d.reason


def test_uint16_and_bgr_inputs_agree():
    img, truth, *_ = _render(CAM, 12, 40)
    a = detect(to_uint(img, 16), BOARD)
    b = detect(cv2.cvtColor(to_uint(img, 8), cv2.COLOR_GRAY2BGR), BOARD)
    assert a.found and b.found
    assert matched_errors(BOARD, a.centres, truth).mean() < 0.005
    assert matched_errors(BOARD, b.centres, truth).mean() < 0.01


def test_compiled_histogram_is_numpys_bincount():
    from circcal.detector.image import histogram_u8

    rng = np.random.default_rng(4)
    img = rng.integers(0, 256, (301, 407), dtype=np.uint8)
    for a in (img, img[::3, 1::2], img[:1, :3], np.zeros((5, 0), np.uint8), np.full((64, 64), 17, np.uint8)):
        assert np.array_equal(histogram_u8(a), np.bincount(a.ravel(), minlength=256))


@pytest.mark.parametrize("dtype,top", [(np.uint8, 256), (np.uint16, 65536)])
@pytest.mark.parametrize("shape", [(1, 1), (3, 7), (360, 640)])
def test_contrast_stretch_percentiles_from_the_histogram_equal_numpys(dtype, top, shape):
    from circcal.detector.image import _counts, _histogram_percentiles, normalise_u8

    rng = np.random.default_rng(shape[0])
    img = rng.integers(0, top // 4, shape).astype(dtype) + dtype(top // 8)  # not the full range: the stretch acts
    q = (0.0, 0.5, 37.0, 99.5, 100.0)
    assert np.allclose(_histogram_percentiles(_counts(img), q), np.percentile(img, q), rtol=0, atol=1e-9)
    lo, hi = np.percentile(img, [0.5, 99.5])
    expect = np.clip((img.astype(np.float64) - lo) * (255.0 / max(hi - lo, 1e-9)), 0, 255).astype(np.uint8)
    hist = np.full(256, 3, np.int64)  # (added to, as the segmentation's counts are)
    assert np.array_equal(normalise_u8(img, hist=hist), expect)
    assert np.array_equal(hist, 3 + np.bincount(expect.ravel(), minlength=256))  # the result's counts, carried


def test_contrast_stretch_of_a_float_image_counts_its_result():
    from circcal.detector.image import normalise_u8

    img = np.random.default_rng(3).normal(0.5, 0.2, (90, 120)).astype(np.float32)
    hist = np.zeros(256, np.int64)
    out = normalise_u8(img, hist=hist)
    assert np.array_equal(hist, np.bincount(out.ravel(), minlength=256))
