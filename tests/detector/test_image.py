"""One bad image file is one rejected image, with its reason code (issue 31 item 3), and overlays never fail
(issue 33).

Every kind of bad file among good ones: :func:`circcal.detector.detect_files` gives one Detection per file, in
order, the good ones found, each bad one ``found=False`` with its :class:`Reason` and a message. A PNG whose header
claims 100000 x 100000 px is refused before decoding (``image-too-large``; the limit set by
``CIRCCAL_MAX_IMAGE_PIXELS``). Overlays are drawn for every image kind the detector takes and every detection (a
partial view with NaN centres, dots left out, values far outside the image), and :func:`overlay_file` draws what a
file gives and says ``None`` for the rest.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from circcal.board import Board
from circcal.detector import Detection, Reason, detect, detect_files
from circcal.detector.image import (
    MAX_IMAGE_PIXELS,
    MAX_IMAGE_PIXELS_ENV,
    ImageTooLargeError,
    as_gray,
    max_image_pixels,
    normalise_u8,
    read_image,
)
from circcal.detector.overlay import draw_detection, overlay_file, write_overlay, write_overlay_file
from circcal.errors import ImageError, InputError
from circcal.fixtures.poses import pose_looking_at
from circcal.fixtures.render import render_view, to_uint
from circcal.model import Camera

CAM = Camera(480, 360, 600.0, 600.0, 239.5, 179.5)
BOARD = Board(4, 5, 10.0, 5.0)


@pytest.fixture(scope="module")
def view() -> np.ndarray:
    """(360, 480) float a rendered view of the 4x5 board (dots ~9 px radius), values in 0..1."""
    rvec, tvec = pose_looking_at(
        CAM,
        BOARD,
        distance_mm=CAM.fx * BOARD.radius_mm / 9.0,
        tilt_deg=25,
        tilt_axis_deg=30.0,
        roll_deg=10.0,
        target_px=(240.0, 180.0),
    )
    return render_view(CAM, BOARD, rvec, tvec)


@pytest.fixture(scope="module")
def found(view) -> Detection:
    d = detect(to_uint(view, 8), BOARD)
    assert d.found, d.reason
    return d


def huge_png(path: Path, width: int = 100_000, height: int = 100_000) -> Path:
    """A tiny PNG (1 x 1 px of data) whose header claims ``width`` x ``height``: IHDR patched, its CRC redone."""
    ok, png = cv2.imencode(".png", np.zeros((1, 1), np.uint8))
    b = bytearray(png.tobytes())
    assert ok and b[12:16] == b"IHDR"
    b[16:24] = struct.pack(">II", width, height)
    b[29:33] = struct.pack(">I", zlib.crc32(bytes(b[12:29])) & 0xFFFFFFFF)
    path.write_bytes(bytes(b))
    return path


def tiff_with_samples(path: Path, samples: int, h: int = 40, w: int = 50) -> Path:
    """An uncompressed 8-bit TIFF of ``samples`` samples per pixel (OpenCV writes only 1, 3 or 4)."""
    data = np.full((h, w, samples), 120, np.uint8).tobytes()
    tags = [(256, w), (257, h), (258, 8), (259, 1), (262, 1), (273, 0), (277, samples), (278, h), (279, len(data))]
    if samples > 1:
        tags.append((338, 0))  # extra samples: unspecified
    data_at = 8 + 2 + 12 * len(tags) + 4
    out = bytearray(b"II*\x00" + struct.pack("<IH", 8, len(tags)))
    for tag, value in tags:
        value = data_at if tag == 273 else value
        out += struct.pack("<HHII", tag, 4, 1, value)  # every value as a LONG
    path.write_bytes(bytes(out + struct.pack("<I", 0) + data))
    return path


def write(path: Path, img: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), img), path
    return path


# ---- every bad file among good ones --------------------------------------------------------------------------


@pytest.mark.parametrize("jobs", [1, 3])
def test_each_bad_file_is_one_rejected_image_with_its_code(tmp_path, view, jobs):
    g8, g16 = to_uint(view, 8), to_uint(view, 16)
    good = [
        write(tmp_path / "good8.png", g8),
        write(tmp_path / "good16.png", g16),
        write(tmp_path / "good_bgr.jpg", cv2.cvtColor(g8, cv2.COLOR_GRAY2BGR)),
        write(tmp_path / "good_f32.tiff", view.astype(np.float32)),
    ]
    ok, png = cv2.imencode(".png", g8)
    ok2, jpg = cv2.imencode(".jpg", g8)
    assert ok and ok2
    (tmp_path / "trunc.png").write_bytes(png.tobytes()[: len(png) // 2])
    (tmp_path / "trunc_head.jpg").write_bytes(jpg.tobytes()[:20])
    (tmp_path / "empty.png").write_bytes(b"")
    (tmp_path / "folder.png").mkdir()
    os.mkfifo(tmp_path / "fifo.png")
    (tmp_path / "loop_a.png").symlink_to(tmp_path / "loop_b.png")
    (tmp_path / "loop_b.png").symlink_to(tmp_path / "loop_a.png")
    (tmp_path / "dangling.png").symlink_to(tmp_path / "nothing.png")
    bad = {
        "huge.png": (huge_png(tmp_path / "huge.png"), Reason.IMAGE_TOO_LARGE, "10000000000 pixels"),
        "row.png": (write(tmp_path / "row.png", np.full((1, 5000), 100, np.uint8)), Reason.BAD_IMAGE, "5000x1"),
        "col.png": (write(tmp_path / "col.png", np.full((5000, 1), 100, np.uint8)), Reason.BAD_IMAGE, "1x5000"),
        "thin16.png": (write(tmp_path / "thin16.png", np.full((7, 300), 9, np.uint16)), Reason.BAD_IMAGE, "too small"),
        "nan.tiff": (write(tmp_path / "nan.tiff", np.full((60, 80), np.nan, np.float32)), Reason.BAD_IMAGE, "NaN"),
        "inf.tiff": (
            write(tmp_path / "inf.tiff", np.where(view > 0.5, np.inf, 0).astype(np.float32)),
            Reason.BAD_IMAGE,
            "inf",
        ),
        "five.tiff": (tiff_with_samples(tmp_path / "five.tiff", 5), Reason.UNREADABLE, "channels"),
        "trunc.png": (tmp_path / "trunc.png", Reason.UNREADABLE, "unreadable"),
        "trunc_head.jpg": (tmp_path / "trunc_head.jpg", Reason.UNREADABLE, "unreadable"),
        "empty.png": (tmp_path / "empty.png", Reason.UNREADABLE, "empty"),
        "text.png": (tmp_path / "text.png", Reason.UNREADABLE, "not an image"),
        "folder.png": (tmp_path / "folder.png", Reason.FILE_NOT_FOUND, "folder"),
        "fifo.png": (tmp_path / "fifo.png", Reason.FILE_NOT_FOUND, "fifo"),
        "loop_a.png": (tmp_path / "loop_a.png", Reason.FILE_NOT_FOUND, "symbolic link"),
        "dangling.png": (tmp_path / "dangling.png", Reason.FILE_NOT_FOUND, "symbolic link"),
        "missing.png": (tmp_path / "missing.png", Reason.FILE_NOT_FOUND, "not found"),
    }
    (tmp_path / "text.png").write_text("hello\n")
    paths, expect = [], []
    for k, (path, code, words) in enumerate(bad.values()):  # a good file between every few bad ones
        paths.append(path)
        expect.append((code, words))
        if k % 4 == 0:
            paths.append(good[(k // 4) % len(good)])
            expect.append((None, None))
    dets = detect_files(paths, BOARD, progress=False, jobs=jobs)
    assert len(dets) == len(paths)
    for path, d, (code, words) in zip(paths, dets, expect):
        assert d.code == code and d.found == (code is None), (path.name, d.code, d.reason)
        if code is not None:
            assert d.centres is None and words in d.reason and "\n" not in d.reason, (path.name, d.reason)
    assert "limit of 268435456 pixels" in dets[paths.index(bad["huge.png"][0])].reason
    assert MAX_IMAGE_PIXELS_ENV in dets[paths.index(bad["huge.png"][0])].reason


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


# ---- the size limit ------------------------------------------------------------------------------------------


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


# ---- overlays ------------------------------------------------------------------------------------------------


def _partial(found: Detection) -> Detection:
    """``found`` with points 0-2 not seen (NaN centre, no edge points), 5 and 11 dropped (NaN centre; 11's
    ellipse centre known), and only candidates far outside the image or NaN."""
    cs = found.centres.copy()
    ec = found.centres.copy()
    cs[[0, 1, 2, 5, 11]] = np.nan
    ec[[0, 1, 2, 5]] = np.nan
    edges = [np.zeros((0, 2)) if k in (0, 1, 2, 5, 11) else e for k, e in enumerate(found.edge_points)]
    cand = np.array([[1e30, -1e30], [np.nan, 3.0], [-5e9, 20.0]])
    return Detection(
        True,
        cs,
        None,
        edge_points=edges,
        ellipse_centres=ec,
        candidates=cand,
        complete=False,
        dropped={5: "cut by the image border", 11: "an edge fit that is no ellipse"},
    )


def test_overlay_of_a_partial_view_marks_dropped_dots_and_draws_no_line_to_a_missing_point(found, view):
    img = to_uint(view, 8)
    part = _partial(found)
    vis = draw_detection(img, part)
    base = cv2.cvtColor(normalise_u8(img), cv2.COLOR_GRAY2BGR)  # the image the overlay is drawn on
    assert vis.shape == base.shape and vis.dtype == np.uint8

    def drawn(p, r=2):
        x, y = int(round(p[0])), int(round(p[1]))
        return (
            np.abs(
                vis[y - r : y + r + 1, x - r : x + r + 1].astype(int) - base[y - r : y + r + 1, x - r : x + r + 1]
            ).sum()
            > 0
        )

    red = (vis[..., 2] > 200) & (vis[..., 0] < 60) & (vis[..., 1] < 60)
    for k in (3, 4, 6, 19):
        x, y = np.round(found.centres[k]).astype(int)
        assert red[y, x], k  # a red cross on each point found
    for k in (0, 1, 2, 5):
        assert not drawn(found.centres[k]), k  # nothing on a point not seen or dropped unknown
    x, y = np.round(found.centres[11]).astype(int)  # dropped, position known: grey, not red
    assert not red[y - 1 : y + 2, x - 1 : x + 2].any() and drawn(found.centres[11], 0)
    blue = (vis[..., 0] > 200) & (vis[..., 2] < 60)

    def line_at(a, b):
        x, y = np.round((found.centres[a] + found.centres[b]) / 2).astype(int)
        return blue[y - 1 : y + 2, x - 1 : x + 2].any()

    assert line_at(3, 4) and line_at(6, 7) and line_at(12, 13)
    assert not any(line_at(a, a + 1) for a in (0, 1, 2, 4, 5, 10, 11))  # no line to a point not seen or dropped
    whole = draw_detection(img, found)
    red_whole = (whole[..., 2] > 200) & (whole[..., 0] < 60) & (whole[..., 1] < 60)
    assert 0 < red[40:].sum() < red_whole[40:].sum()  # (below the line of text: "15 of 20 points ...")


@pytest.mark.parametrize(
    "make",
    [
        lambda d: Detection(False, None, "grid 4x5 not found", Reason.TOO_FEW_CANDIDATES),
        lambda d: Detection(False, None, None, Reason.BAD_IMAGE, candidates=np.array([[np.inf, 1.0], [3.0, 4.0]])),
        lambda d: Detection(
            False,
            None,
            "too few points: 2 of 20 measurable",
            Reason.TOO_FEW_POINTS,
            dropped={k: "cut by the image border" for k in range(18)},
        ),
        lambda d: Detection(
            True,
            np.full((20, 2), np.nan),
            None,
            edge_points=[np.zeros((0, 2))] * 20,
            dropped={3: "x", 99: "a key past the board", -1: "negative"},
        ),
        lambda d: Detection(True, d.centres * 1e12, None, edge_points=[e * 1e9 for e in d.edge_points]),
        lambda d: Detection(
            True,
            d.centres[:, :1],
            None,
            edge_points=[
                np.full((7, 2), np.nan),
                np.ones((3, 2)),
                np.array([[1.0, 1], [2, 2], [3, 3], [4, 4], [5, 5], [6, 6]]),
            ],
        ),
        lambda d: Detection(False, None, "ünïcode réason", Reason.GRID_NOT_RECOGNISED, candidates=np.zeros((0, 2))),
    ],
)
def test_overlay_never_raises_for_any_detection(found, view, make):
    img = to_uint(view, 8)
    vis = draw_detection(img, make(found))
    assert vis.shape == (*img.shape, 3) and vis.dtype == np.uint8


@pytest.mark.parametrize(
    "kind",
    [
        "u8",
        "u16",
        "f32",
        "f64",
        "i8",
        "i16",
        "i32",
        "u32",
        "i64",
        "f16",
        "bgr8",
        "bgra16",
        "bgr_i16",
        "bgr_f64",
        "hw1",
        "tiny",
        "flat",
        "big_endian",
    ],
)
def test_overlay_is_drawn_on_every_image_kind_the_detector_takes(found, view, kind, tmp_path):
    g8, g16 = to_uint(view, 8), to_uint(view, 16)
    img = {
        "u8": g8,
        "u16": g16,
        "f32": view.astype(np.float32),
        "f64": view,
        "i8": (g8 - 128.0).astype(np.int8),
        "i16": (g16 - 30000.0).astype(np.int16),
        "i32": g16.astype(np.int32) - 7,
        "u32": g16.astype(np.uint32),
        "i64": g16.astype(np.int64) * 10**12,
        "f16": view.astype(np.float16),
        "bgr8": cv2.cvtColor(g8, cv2.COLOR_GRAY2BGR),
        "bgra16": cv2.cvtColor(g16, cv2.COLOR_GRAY2BGRA),
        "bgr_i16": np.dstack([(g16 // 2).astype(np.int16)] * 3),
        "bgr_f64": np.dstack([view] * 3),
        "hw1": g8[:, :, None],
        "tiny": g8[:8, :8],
        "flat": np.zeros((20, 30), np.float32),
        "big_endian": g16.astype(">u2"),
    }[kind]
    gray = as_gray(img)
    assert gray.shape == img.shape[:2] and gray.dtype in (np.uint8, np.uint16, np.float32, np.float64)
    for d in (found, _partial(found), Detection(False, None, "not found", Reason.GRID_NOT_RECOGNISED)):
        vis = draw_detection(img, d)
        assert vis.shape == (*img.shape[:2], 3) and vis.dtype == np.uint8
    out = write_overlay(tmp_path / "sub" / "o.png", img, _partial(found))
    assert cv2.imread(str(out)).shape == (*img.shape[:2], 3)


@pytest.mark.parametrize(
    "img, words",
    [
        (np.zeros((5000, 1), np.uint8), "too small"),
        (np.zeros((40, 40, 2), np.uint8), "channels"),
        (np.full((40, 40), np.nan), "NaN"),
        (np.zeros((40, 40), bool), "dtype"),
        (np.zeros((40, 40), complex), "dtype"),
        (np.zeros((40, 40, 3, 2), np.uint8), "shape"),
        (np.zeros(40, np.uint8), "shape"),
        (np.zeros((0, 0, 3), np.uint8), "too small"),
    ],
)
def test_overlay_of_an_image_the_detector_refuses_raises_image_error(found, img, words):
    with pytest.raises(ImageError, match=words) as raised:
        draw_detection(img, found)
    assert "\n" not in str(raised.value)


def test_overlay_file_draws_every_file_it_can_and_none_for_the_rest(tmp_path, found, view):
    good = write(tmp_path / "good.png", to_uint(view, 16))
    part = _partial(found)
    vis = overlay_file(good, part)
    assert vis.shape == (*view.shape, 3) and vis.dtype == np.uint8
    assert np.array_equal(vis, draw_detection(to_uint(view, 16), part))
    (tmp_path / "trunc.png").write_bytes(good.read_bytes()[:100])
    (tmp_path / "empty.png").write_bytes(b"")
    (tmp_path / "folder.png").mkdir()
    os.mkfifo(tmp_path / "fifo.png")
    (tmp_path / "loop.png").symlink_to(tmp_path / "loop.png")
    no = [
        huge_png(tmp_path / "huge.png"),
        tmp_path / "trunc.png",
        tmp_path / "empty.png",
        tmp_path / "folder.png",
        tmp_path / "fifo.png",
        tmp_path / "loop.png",
        tmp_path / "missing.png",
        write(tmp_path / "row.png", np.zeros((1, 5000), np.uint8)),
        write(tmp_path / "nan.tiff", np.full((60, 80), np.nan, np.float32)),
    ]
    dets = detect_files([good, *no], BOARD, progress=False)
    assert dets[0].found and not any(d.found for d in dets[1:])
    for path, d in zip(no, dets[1:]):
        assert overlay_file(path, d) is None, path.name
        assert write_overlay_file(tmp_path / "ov" / f"{path.name}.png", path, d) is None
    assert write_overlay_file(tmp_path / "ov" / "good.png", good, dets[0]) == tmp_path / "ov" / "good.png"
    assert sorted(p.name for p in (tmp_path / "ov").iterdir()) == ["good.png"]
