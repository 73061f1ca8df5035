"""Overlays for a person to check a detection: edge points, fitted ellipses and ordered centres with indices.

Drawn with OpenCV on a colour copy of the image (8-bit), written as PNG. Sub-pixel positions are drawn with
OpenCV's fixed-point ``shift`` so they are placed to 1/16 px. Whatever a :class:`Detection` holds (found or not, a
partial view with NaN for the points not seen, dots left out, values far outside the image) is drawn where it can
be and skipped where not: drawing never fails on a detection. :func:`overlay_file` draws the overlay of an image
file, or says ``None`` when the file gives no image.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from circcal import atomic
from circcal.detector.detection import Detection
from circcal.detector.image import as_gray, normalise_u8, read_image
from circcal.detector.measure.ellipse import conic_params
from circcal.detector.measure.ellipsefit import fit_ellipse_direct
from circcal.errors import ImageError

__all__ = ["draw_detection", "overlay_file", "write_overlay", "write_overlay_file"]

_SHIFT = 4
_S = 1 << _SHIFT
_REACH = 4.0
"""Positions further than this many image sizes outside the image are not drawn (nothing there to see, and OpenCV's
fixed-point coordinates must stay within int32)."""
_DROPPED = (150, 150, 150)
"""Colour (BGR) of the dots left out (:attr:`Detection.dropped`) where their position is known: small grey crosses."""


def _xy(a: object) -> np.ndarray:
    """``a`` as (K, 2) float64 positions (its first two columns), or (0, 2) when it is not such an array."""
    try:
        p = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError):
        return np.zeros((0, 2))
    return p[:, :2] if p.ndim == 2 and p.shape[1] >= 2 else np.zeros((0, 2))


class _Canvas:
    """The overlay being drawn: the image in colour, and which positions lie near enough to draw."""

    def __init__(self, vis: np.ndarray):
        self.vis = vis
        h, w = vis.shape[:2]
        self.scale = max(1.0, max(h, w) / 1000.0)
        self.lo = -_REACH * np.array([w, h], float)
        self.hi = (1 + _REACH) * np.array([w, h], float)

    def ok(self, p: np.ndarray) -> bool:
        """Whether the position ``p`` (2,) px is finite and near enough the image to draw."""
        return bool(np.all(np.isfinite(p)) and np.all(p > self.lo) and np.all(p < self.hi))

    def marker(self, p: np.ndarray, colour: tuple[int, int, int], kind: int, size: float) -> None:
        if self.ok(p):
            cv2.drawMarker(
                self.vis, (int(round(p[0])), int(round(p[1]))), colour, kind, max(1, int(size * self.scale)), 1
            )

    def dot(self, p: np.ndarray, colour: tuple[int, int, int]) -> None:
        if self.ok(p):
            cv2.circle(self.vis, _pt(p), int(0.6 * _S), colour, -1, cv2.LINE_AA, _SHIFT)

    def line(self, a: np.ndarray, b: np.ndarray, colour: tuple[int, int, int]) -> None:
        if self.ok(a) and self.ok(b):
            cv2.line(self.vis, _pt(a), _pt(b), colour, 1, cv2.LINE_AA, _SHIFT)

    def ellipse(self, pts: np.ndarray, colour: tuple[int, int, int]) -> None:
        """The ellipse fitted to the edge points ``pts`` (K, 2), when one fits and lies near the image."""
        if len(pts) < 5:
            return
        try:
            c, (a, b), ang = conic_params(fit_ellipse_direct(pts))
        except (ValueError, np.linalg.LinAlgError):  # no ellipse through these points
            return
        size = max(self.vis.shape[:2])
        if not (self.ok(np.asarray(c)) and np.isfinite([a, b, ang]).all() and 0 <= a < size and 0 <= b < size):
            return
        cv2.ellipse(
            self.vis,
            _pt(c),
            (int(round(a * _S)), int(round(b * _S))),
            float(np.degrees(ang)),
            0,
            360,
            colour,
            1,
            cv2.LINE_AA,
            _SHIFT,
        )

    def text(self, s: str, p: np.ndarray, colour: tuple[int, int, int], size: float) -> None:
        if self.ok(p):
            cv2.putText(
                self.vis,
                s.encode("ascii", "replace").decode(),
                (int(round(p[0])), int(round(p[1]))),
                cv2.FONT_HERSHEY_SIMPLEX,
                size * self.scale,
                colour,
                1,
                cv2.LINE_AA,
            )


def _pt(p: np.ndarray) -> tuple[int, int]:
    return int(round(p[0] * _S)), int(round(p[1] * _S))


def draw_detection(image: np.ndarray, detection: Detection) -> np.ndarray:
    """The overlay of ``detection`` on ``image``.

    Candidates: small grey tilted crosses; edge points: yellow dots; ellipses (fitted to the observed edge points):
    green; corrected centres: red crosses with their board index; a blue line joins the centres that follow each
    other in board order (so the ordering is visible), never through a point not seen; dots left out
    (:attr:`Detection.dropped`): small grey crosses where their position is known (their centre or ellipse centre
    finite), nothing where it is not. The first line of text gives a failed detection's reason, or how many points
    a partial view or dropped dots leave. Non-finite positions, and positions far outside the image, are skipped.

    Parameters
    ----------
    image : numpy.ndarray
        (H, W) grey or (H, W, 3|4) BGR(A) of any dtype :func:`~circcal.detector.image.as_gray` accepts.
    detection : Detection
        Any :class:`Detection`: found or not, complete or partial (NaN centres), with dots dropped.

    Returns
    -------
    numpy.ndarray
        (H, W, 3) uint8 BGR.

    Raises
    ------
    ImageError
        ``image`` is one :func:`~circcal.detector.image.as_gray` refuses.
    """
    cv = _Canvas(cv2.cvtColor(normalise_u8(as_gray(image)), cv2.COLOR_GRAY2BGR))
    if detection.candidates is not None:
        for c in _xy(detection.candidates):
            cv.marker(c, (160, 160, 160), cv2.MARKER_TILTED_CROSS, 6)
    for pts in detection.edge_points if detection.edge_points is not None else []:
        pts = _xy(pts)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        for p in pts:
            cv.dot(p, (0, 255, 255))
        cv.ellipse(pts, (0, 200, 0))
    cs = _xy(detection.centres)
    dropped = {int(k) for k in (detection.dropped or {}) if isinstance(k, (int, np.integer))}
    used = [k not in dropped and cv.ok(c) for k, c in enumerate(cs)]
    for k in range(len(cs) - 1):
        if used[k] and used[k + 1]:
            cv.line(cs[k], cs[k + 1], (255, 128, 0))
    for k, c in enumerate(cs):
        if used[k]:
            cv.marker(c, (0, 0, 255), cv2.MARKER_CROSS, 8)
            cv.text(str(k), c + 4 * cv.scale * np.array([1.0, -1.0]), (0, 0, 255), 0.35)
    known = _xy(detection.ellipse_centres)
    for k in sorted(dropped):
        where = next((w[k] for w in (cs, known) if 0 <= k < len(w) and cv.ok(w[k])), None)
        if where is not None:
            cv.marker(where, _DROPPED, cv2.MARKER_CROSS, 5)
    cv.text(_headline(detection, cs), np.array([10.0, 25.0 * cv.scale]), (0, 0, 255), 0.5)
    return cv.vis


def _headline(detection: Detection, cs: np.ndarray) -> str:
    """The overlay's line of text: why not found, or what a partial view or dropped dots leave ("" for a whole
    view with every dot)."""
    if not detection.found:
        code = getattr(detection.code, "value", detection.code)
        return f"NOT FOUND: {detection.reason if detection.reason is not None else code}"
    parts = []
    if len(cs):
        seen = int(np.all(np.isfinite(cs), axis=1).sum())
        if seen < len(cs):
            parts.append(f"{seen} of {len(cs)} points" + ("" if detection.complete else " (partial view)"))
    if detection.dropped:
        parts.append(f"{len(detection.dropped)} dot(s) left out (grey)")
    return "; ".join(parts)


def write_overlay(path: Path, image: np.ndarray, detection: Detection) -> Path:
    """Write :func:`draw_detection` as PNG to ``path``, atomically (parent folders created).

    Parameters
    ----------
    path : pathlib.Path
        The PNG file to write (str accepted).
    image : numpy.ndarray
        (H, W) grey or (H, W, 3|4) BGR(A) of any dtype :func:`~circcal.detector.image.as_gray` accepts.
    detection : Detection
        Any :class:`Detection` (see :func:`draw_detection`).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ImageError
        ``image`` is one :func:`~circcal.detector.image.as_gray` refuses.
    OSError
        ``path`` cannot be written.

    Examples
    --------
    >>> write_overlay(Path("overlay.png"), image, detect(image, board))  # doctest: +SKIP
    PosixPath('overlay.png')
    """
    return _write_png(Path(path), draw_detection(image, detection))


def overlay_file(path: Path, detection: Detection) -> np.ndarray | None:
    """:func:`draw_detection` of ``detection`` on the image in the file ``path``, or ``None`` (nothing drawn) when
    the file gives no image the overlay can be drawn on: missing, not a regular file, unreadable, empty, not
    decodable, too large (:func:`~circcal.detector.image.max_image_pixels`: not decoded), or an image
    :func:`~circcal.detector.image.as_gray` refuses. Never raises for what a file can cause.

    Parameters
    ----------
    path : pathlib.Path
        The image file the detection was made on (str accepted).
    detection : Detection
        Any :class:`Detection`.

    Returns
    -------
    numpy.ndarray or None
        (H, W, 3) uint8 BGR, or ``None``.

    Raises
    ------
    InputError
        Only for a setting, not a file: ``CIRCCAL_MAX_IMAGE_PIXELS`` set to something other than a whole number.
    """
    try:
        img = read_image(Path(path))
        return None if img is None else draw_detection(img, detection)
    except (OSError, ImageError):
        return None


def write_overlay_file(dest: Path, path: Path, detection: Detection) -> Path | None:
    """:func:`overlay_file` of an image file, written as PNG, atomically (parent folders created).

    Parameters
    ----------
    dest : pathlib.Path
        The PNG file to write (str accepted).
    path : pathlib.Path
        The image file the detection was made on (str accepted).
    detection : Detection
        Any :class:`Detection`.

    Returns
    -------
    Path or None
        ``dest``; or ``None``, with nothing written, when the file gives no image (see :func:`overlay_file`).

    Raises
    ------
    OSError
        ``dest`` cannot be written.
    InputError
        Only for a setting, not a file: ``CIRCCAL_MAX_IMAGE_PIXELS`` set to something other than a whole number.
    """
    vis = overlay_file(path, detection)
    return None if vis is None else _write_png(Path(dest), vis)


def _write_png(path: Path, vis: np.ndarray) -> Path:
    """``vis`` written as PNG to ``path``, atomically (parent folders created)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, png = cv2.imencode(".png", vis)
    if not ok:
        raise RuntimeError(f"OpenCV could not encode the overlay for {path}")
    atomic.write_bytes(path, png.tobytes())
    return path
