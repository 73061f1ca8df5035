"""What several of the detector's test modules share: the repository's root, the 4x5 board and the camera of the
accuracy renders, a render of that board with its true centres (:func:`_render`), detected centres' errors under the
board's symmetries (:func:`matched_errors`), and writers of image files (good and bad)."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np

from circcal.board import Board
from circcal.fixtures.poses import pose_looking_at
from circcal.fixtures.render import render_view
from circcal.model import Camera, project

REPO = Path(__file__).resolve().parents[2]

BOARD = Board(4, 5, 10.0, 5.0)


def matched_errors(board: Board, centres: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N,) |detected - true| px under the board symmetry that fits best."""
    best = None
    for s in board.symmetries():
        e = np.linalg.norm(centres - truth[s.perm], axis=1)
        if best is None or e.mean() < best.mean():
            best = e
    return best


CAM = Camera(1280, 960, 1600.0, 1600.0, 639.5, 479.5)


def _render(camera, radius_px, tilt, axis=30.0, target=(700.0, 500.0)):
    rvec, tvec = pose_looking_at(
        camera,
        BOARD,
        distance_mm=camera.fx * BOARD.radius_mm / radius_px,
        tilt_deg=tilt,
        tilt_axis_deg=axis,
        roll_deg=10.0,
        target_px=target,
    )
    return render_view(camera, BOARD, rvec, tvec), project(BOARD.object_points(), rvec, tvec, camera), rvec, tvec


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
