"""Detection on image files (:mod:`circcal.detector.files`): one bad image file is one rejected image, with its
reason code (issue 31 item 3).

Every kind of bad file among good ones: :func:`circcal.detector.detect_files` gives one Detection per file, in
order, the good ones found, each bad one ``found=False`` with its :class:`Reason` and a message.
"""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from circcal.detector import Reason, detect_files
from circcal.detector.image import MAX_IMAGE_PIXELS_ENV
from circcal.fixtures.render import to_uint
from tests.detector.helpers import BOARD, huge_png, tiff_with_samples, write


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
