"""Detection on image files (:mod:`circcal.detector.files`): one bad image file is one rejected image, with its
reason code (issue 31 item 3).

Every kind of bad file among good ones: :func:`circcal.detector.detect_files` gives one Detection per file, in
order, the good ones found, each bad one ``found=False`` with its :class:`Reason` and a message.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from circcal.detector import Reason, detect_files
from circcal.detector.image import MAX_IMAGE_PIXELS_ENV
from circcal.fixtures.render import to_uint
from tests.detector.helpers import BOARD, CAM, REPO, _render, huge_png, matched_errors, tiff_with_samples, write


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


@pytest.mark.parametrize("jobs", [1, 3])
def test_detect_files_never_raises(tmp_path, jobs):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image")
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((100, 120), 200, np.uint8))
    dets = detect_files([bad, tmp_path / "missing.png", blank], BOARD, progress=False, jobs=jobs)
    assert [d.found for d in dets] == [False, False, False]
    assert "unreadable" in dets[0].reason and "not found" in dets[1].reason
    assert "candidate dots" in dets[2].reason
    with pytest.raises(ValueError, match="jobs"):
        detect_files([blank], BOARD, progress=False, jobs=0)


@pytest.mark.parametrize("jobs", [1, 3])
def test_detect_files_gives_each_file_problem_its_reason_code(tmp_path, jobs):
    corrupt = tmp_path / "corrupt.png"
    corrupt.write_bytes(b"\x89PNG\r\n\x1a\n not really")
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    tiny = tmp_path / "tiny.png"
    cv2.imwrite(str(tiny), np.full((5, 5), 200, np.uint8))
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((100, 120), 200, np.uint8))
    paths = [corrupt, tmp_path / "missing.png", tmp_path, empty, tiny, blank]
    dets = detect_files(paths, BOARD, progress=False, jobs=jobs)
    assert [d.code for d in dets] == [
        Reason.UNREADABLE,
        Reason.FILE_NOT_FOUND,
        Reason.FILE_NOT_FOUND,
        Reason.UNREADABLE,
        Reason.BAD_IMAGE,
        Reason.TOO_FEW_CANDIDATES,
    ]
    assert not any(d.found for d in dets) and "not a file" in dets[2].reason and "too small" in dets[4].reason
    (wrong,) = detect_files([blank], BOARD, CAM, progress=False, jobs=jobs)
    assert wrong.code == Reason.WRONG_IMAGE_SIZE and "1280x960" in wrong.reason and wrong.image_size == (120, 100)


@pytest.mark.parametrize("jobs", [1, 3])
@pytest.mark.parametrize("error", [RuntimeError, ValueError])
def test_a_bug_inside_detection_propagates_out_of_detect_files(tmp_path, monkeypatch, jobs, error):
    # only what a file can cause becomes found=False; an exception from inside the detector (here a plain
    # ValueError too, which is not an ImageError) is a bug and reaches the caller with its traceback
    from circcal.detector import find

    img, *_ = _render(CAM, 12, 30)
    paths = [tmp_path / f"v{k}.png" for k in range(3)]
    for path in paths:
        cv2.imwrite(str(path), to_uint(img, 8))
    paths.insert(1, tmp_path / "missing.png")
    assert all(d.found for k, d in enumerate(detect_files(paths, BOARD, progress=False, jobs=jobs)) if k != 1)

    def broken_fit(*args, **kwargs):
        raise error("a bug in the edge fit")

    monkeypatch.setattr(find, "fit_dots", broken_fit)
    with pytest.raises(error, match="a bug in the edge fit") as raised:
        detect_files(paths, BOARD, progress=False, jobs=jobs)
    assert raised.traceback[-1].name == "broken_fit"


def test_parallel_detection_gives_the_sequential_results_in_order(tmp_path):
    paths = []
    for k, (radius, tilt) in enumerate([(12, 30), (9, 50), (20, 10), (15, 40)]):
        img, *_ = _render(CAM, radius, tilt)
        paths.append(tmp_path / f"v{k}.png")
        cv2.imwrite(str(paths[-1]), to_uint(img, 8))
    paths.insert(2, tmp_path / "missing.png")
    seq = detect_files(paths, BOARD, progress=False, jobs=1)
    par = detect_files(paths, BOARD, progress=False, jobs=4)
    assert [d.found for d in seq] == [True, True, False, True, True]
    assert [d.found for d in par] == [d.found for d in seq] and par[2].reason == seq[2].reason
    for a, b in zip(seq, par):
        assert (a.centres is None and b.centres is None) or np.array_equal(a.centres, b.centres)


def test_cli_writes_json_and_overlays(tmp_path):
    img, truth, *_ = _render(CAM, 12, 30)
    good = tmp_path / "good.png"
    cv2.imwrite(str(good), to_uint(img, 8))
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"\x00\x01")
    out = tmp_path / "det.json"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "circcal.cli",
            "detect",
            str(good),
            str(bad),
            "--grid",
            "4x5",
            "--pitch",
            "10mm",
            "--diameter",
            "5mm",
            "--json",
            str(out),
            "--overlay",
            str(tmp_path / "ov"),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert r.returncode == 1, r.stderr  # one image failed
    data = json.loads(out.read_text())
    assert data["board"]["rows"] == 4 and data["board"]["cols"] == 5
    g, b = data["images"]
    assert g["found"] and g["reason"] is None and len(g["centers"]) == 20
    assert matched_errors(BOARD, np.array(g["centers"]), truth).mean() < 0.01
    assert not b["found"] and b["centers"] is None and "unreadable" in b["reason"]
    assert (tmp_path / "ov" / "good_detect.png").exists()
    r = subprocess.run(
        [sys.executable, "-m", "circcal.cli", "detect", str(good), "--grid", "4x5", "--json", str(out), "--jobs", "0"],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert r.returncode == 2 and "--jobs" in r.stderr and "at least 1" in r.stderr
    r = subprocess.run(
        [sys.executable, "-m", "circcal.cli", "detect", str(good), "--grid", "4by5", "--json", str(out)],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert r.returncode == 2 and "--grid" in r.stderr and "ROWSxCOLS" in r.stderr


def test_an_image_turned_by_its_exif_orientation_is_read_as_stored_and_said(tmp_path):
    from PIL import Image

    # a phone's portrait photograph: the sensor's landscape pixels with an orientation tag a viewer applies
    img = to_uint(_render(CAM, 12, 30)[0])
    plain, tagged = tmp_path / "plain.jpg", tmp_path / "tagged.jpg"
    Image.fromarray(img).save(plain, quality=95)
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(img).save(tagged, quality=95, exif=exif)
    a, b = detect_files([plain, tagged], BOARD, progress=False, jobs=1)
    assert a.found and b.found and a.image_size == b.image_size == (img.shape[1], img.shape[0])  # not turned
    assert np.array_equal(a.centres, b.centres)
    assert not a.notes
    assert len(b.notes) == 1 and b.notes[0].startswith("EXIF orientation 6 (viewers turn it 90 deg clockwise)")
