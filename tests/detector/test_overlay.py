"""Overlays never fail (issue 33; :mod:`circcal.detector.overlay`): they are drawn for every image kind the detector
takes and every detection (a partial view with NaN centres, dots left out, values far outside the image), and
:func:`overlay_file` draws what a file gives and says ``None`` for the rest.
"""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from circcal.detector import Detection, Reason, detect, detect_files
from circcal.detector.image import as_gray, normalise_u8
from circcal.detector.overlay import draw_detection, overlay_file, write_overlay, write_overlay_file
from circcal.errors import ImageError
from circcal.fixtures.render import to_uint
from tests.detector.helpers import BOARD, huge_png, write


@pytest.fixture(scope="module")
def found(view) -> Detection:
    d = detect(to_uint(view, 8), BOARD)
    assert d.found, d.reason
    return d


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
