"""Overlays for a person to check a detection: edge points, fitted ellipses and ordered centres with indices.

Drawn with OpenCV on a colour copy of the image (8-bit), written as PNG. Sub-pixel positions are drawn with
OpenCV's fixed-point ``shift`` so they are placed to 1/16 px.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from circcal import atomic

from circcal.detector.detection import Detection
from circcal.detector.ellipse import conic_params, fit_ellipse_direct
from circcal.detector.image import as_gray, normalise_u8

__all__ = ["draw_detection", "write_overlay"]

_SHIFT = 4
_S = 1 << _SHIFT


def _pt(p: np.ndarray) -> tuple[int, int]:
    return int(round(p[0] * _S)), int(round(p[1] * _S))


def draw_detection(image: np.ndarray, detection: Detection) -> np.ndarray:
    """(H, W, 3) uint8 BGR overlay of ``detection`` on ``image`` (any dtype/channels :func:`detect` accepts).

    Candidates: small grey crosses; edge points: yellow dots; ellipses (fitted to the observed edge points): green;
    corrected centres: red crosses with their index; a line joins the centres in board order (blue) so the
    ordering is visible; a failed detection shows its reason.
    """
    vis = cv2.cvtColor(normalise_u8(as_gray(image)), cv2.COLOR_GRAY2BGR)
    scale = max(1.0, max(vis.shape[:2]) / 1000.0)
    if detection.candidates is not None:
        for c in detection.candidates:
            cv2.drawMarker(vis, (int(round(c[0])), int(round(c[1]))), (160, 160, 160), cv2.MARKER_TILTED_CROSS,
                           int(6 * scale), 1)
    if detection.edge_points is not None:
        for pts in detection.edge_points:
            for p in pts:
                cv2.circle(vis, _pt(p), int(0.6 * _S), (0, 255, 255), -1, cv2.LINE_AA, _SHIFT)
            try:
                c, (a, b), ang = conic_params(fit_ellipse_direct(pts))
                cv2.ellipse(vis, _pt(c), (int(round(a * _S)), int(round(b * _S))), float(np.degrees(ang)), 0, 360,
                            (0, 200, 0), 1, cv2.LINE_AA, _SHIFT)
            except ValueError:
                pass
    if detection.centres is not None:
        cs = detection.centres
        for a, b in zip(cs[:-1], cs[1:]):
            cv2.line(vis, _pt(a), _pt(b), (255, 128, 0), 1, cv2.LINE_AA, _SHIFT)
        for k, c in enumerate(cs):
            cv2.drawMarker(vis, (int(round(c[0])), int(round(c[1]))), (0, 0, 255), cv2.MARKER_CROSS,
                           int(8 * scale), 1)
            cv2.putText(vis, str(k), (int(round(c[0] + 4 * scale)), int(round(c[1] - 4 * scale))),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.35 * scale, (0, 0, 255), 1, cv2.LINE_AA)
    if not detection.found:
        cv2.putText(vis, f"NOT FOUND: {detection.reason}", (10, int(25 * scale)), cv2.FONT_HERSHEY_SIMPLEX,
                    0.5 * scale, (0, 0, 255), 1, cv2.LINE_AA)
    return vis


def write_overlay(path: Path, image: np.ndarray, detection: Detection) -> Path:
    """Write :func:`draw_detection` as PNG to ``path``, atomically (parent folders created). Returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, png = cv2.imencode(".png", draw_detection(image, detection))
    if not ok:
        raise RuntimeError(f"OpenCV could not encode the overlay for {path}")
    atomic.write_bytes(path, png.tobytes())
    return path
