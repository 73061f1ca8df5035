"""Images as the detector takes them: an image file read as stored, grey conversion, and the contrast stretch to
uint8 that the thresholds work on.

Arrays are (H, W) grey or (H, W, 3|4) BGR(A), of dtype uint8, uint16 or float (OpenCV's layout).
"""
from __future__ import annotations

import os
import re
import sys
import tempfile
import threading
from pathlib import Path

import cv2
import numpy as np

from circcal.detector.jit import njit
from circcal.errors import ImageError

__all__ = ["as_gray", "decode_image", "histogram_u8", "normalise_u8", "read_image", "read_image_messages",
           "stretch_percentiles"]

MIN_IMAGE_SIDE = 8
"""Images with a side shorter than this (px) are refused: no dot with a measurable boundary fits."""
STRETCH_PERCENTILES = (0.5, 99.5)
"""Grey levels (percent of the pixels) stretched to 0 and 255: a few outliers at either end (specular highlights,
dead pixels, the image border) do not squeeze the board's contrast."""
STRETCH_TAIL_PX = 2000
"""... but never more than this many pixels at either end (a highlight or dead area of ~45 x 45 px): in a large frame
0.5 % of the pixels can outnumber the white of a small board (a 7x7 board of 6 px dots in a 4000x3000 frame has
~5,000 white pixels, 0.04 %), and its percentile would stretch the background's noise to the full range (measured:
masks of 850,000 noise specks, seconds per contour search)."""
FLOAT_SUBSAMPLE_STEP = 4
"""Float images larger than :data:`FLOAT_SUBSAMPLE_ABOVE` pixels take their stretch percentiles from every 4th pixel
in each direction (1/16 of the pixels; percentiles of a smooth histogram barely move)."""
FLOAT_SUBSAMPLE_ABOVE = 400_000


DECODER_NOISE = re.compile(r"^(libpng (warning|error)|Corrupt JPEG data|Premature end of JPEG|Invalid SOS|"
                           r"\[ ?WARN:.*grfmt_|\[ ?WARN:.*imgcodecs|Warning: unknown JFIF|libtiff|TIFFRead)")
"""Lines the image decoders (libpng, libjpeg, libtiff, OpenCV's codec layer) print on stderr about a corrupt or odd
file: caught while decoding and handed to the caller (a detection's reason or notes), never left on the console.
Anything else written to stderr meanwhile is passed on untouched."""
_DECODE_LOCK = threading.Lock()
"""Decoding swaps the process's stderr (file descriptor 2) for a buffer: one decode at a time (detection itself
runs in parallel; decoding is a few ms of it)."""


def decode_image(data: np.ndarray) -> tuple[np.ndarray | None, list[str]]:
    """``cv2.imdecode(data, IMREAD_UNCHANGED)`` with what the decoders print about the file caught: ``(image or
    None, messages)``, messages the lines matching :data:`DECODER_NOISE` (other stderr output is written on)."""
    with _DECODE_LOCK:
        try:
            sys.stderr.flush()
        except (AttributeError, ValueError, OSError):   # no usable sys.stderr (closed, replaced): decode plainly
            return cv2.imdecode(data, cv2.IMREAD_UNCHANGED), []
        with tempfile.TemporaryFile() as buf:
            saved = os.dup(2)
            os.dup2(buf.fileno(), 2)
            try:
                img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
            finally:
                os.dup2(saved, 2)
                os.close(saved)
            buf.seek(0)
            text = buf.read().decode("utf-8", errors="replace")
    lines = [ln for ln in text.splitlines() if ln.strip()]
    noise = [re.sub(r"^\[ ?WARN:[^\]]*\]\s*global\s+\S+\s+\S+\s+", "", ln.strip())
             for ln in lines if DECODER_NOISE.search(ln.strip())]
    other = [ln for ln in lines if not DECODER_NOISE.search(ln.strip())]
    if other:
        sys.stderr.write("\n".join(other) + "\n")
    return img, noise


def read_image_messages(path: Path) -> tuple[np.ndarray | None, list[str]]:
    """:func:`read_image` and what the decoder said about the file (:func:`decode_image`)."""
    path = Path(path)
    data = np.fromfile(str(path), dtype=np.uint8) if path.is_file() else None
    if data is None or data.size == 0:
        return None, []
    return decode_image(data)


def read_image(path: Path) -> np.ndarray | None:
    """The image stored in the file ``path`` (``cv2.IMREAD_UNCHANGED``: grey, BGR or BGRA, 8 or 16 bit), or ``None``
    when there is no such file, it is empty, or no decoder can read it. Raises ``OSError`` when the file exists but
    cannot be read (permissions, I/O). The decoders' complaints about a corrupt file are not printed
    (:func:`read_image_messages` returns them)."""
    return read_image_messages(path)[0]


def as_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3|4) BGR(A) image of dtype uint8, uint16 or float -> (H, W) grey in its own dtype (colour
    converted by ``cv2.cvtColor``; float64 colour via float32). Raises :class:`~circcal.errors.ImageError` for other
    shapes or dtypes, a side below :data:`MIN_IMAGE_SIDE`, and for NaN/inf."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3:
        if img.shape[2] not in (3, 4):
            raise ImageError(f"colour image must have 3 (BGR) or 4 (BGRA) channels, got {img.shape[2]}")
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        img = cv2.cvtColor(img.astype(np.float32) if img.dtype == np.float64 else img, code)
    if img.ndim != 2:
        raise ImageError(f"expected a (H, W) grey or (H, W, 3) BGR image, got shape {np.shape(image)}")
    if not (np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)) or img.dtype == bool:
        raise ImageError(f"unsupported image dtype {img.dtype}; expected uint8, uint16 or float")
    if min(img.shape) < MIN_IMAGE_SIDE:
        raise ImageError(f"image too small: {img.shape[1]}x{img.shape[0]}")
    if np.issubdtype(img.dtype, np.floating) and not np.all(np.isfinite(img)):
        raise ImageError("image contains NaN or inf")
    return img


def stretch_percentiles(n_pixels: int, tail_px: float = STRETCH_TAIL_PX) -> tuple[float, float]:
    """(low, high) percentiles stretched to 0 and 255 in an image of ``n_pixels``: :data:`STRETCH_PERCENTILES`, with
    at most ``tail_px`` pixels beyond either (:data:`STRETCH_TAIL_PX`; an image shrunk s times passes it over s^2)."""
    tail = min(STRETCH_PERCENTILES[0], 100.0 * max(float(tail_px), 1.0) / max(int(n_pixels), 1))
    return tail, 100.0 - tail


def normalise_u8(gray: np.ndarray, tail_px: float = STRETCH_TAIL_PX, hist: np.ndarray | None = None) -> np.ndarray:
    """(H, W) uint8: the range of ``gray`` (H, W) between the :func:`stretch_percentiles` stretched to 0..255 (for
    thresholding only; ``tail_px``: see there). Integer images (uint8/uint16, e.g. from :func:`as_gray`): percentiles
    of all pixels from their histogram, the stretch through a lookup table of the same formula (identical results);
    float images: percentiles of a subsample above :data:`FLOAT_SUBSAMPLE_ABOVE` pixels
    (:data:`FLOAT_SUBSAMPLE_STEP`). ``hist``: (256,) int64, if given the counts of the result's values are added to
    it (integer images: the input's histogram carried through the lookup table, no second pass over the pixels)."""
    q = stretch_percentiles(gray.size, tail_px)
    if gray.dtype in (np.uint8, np.uint16):
        counts = _counts(gray)
        lo, hi = _histogram_percentiles(counts, q)
    else:
        step = FLOAT_SUBSAMPLE_STEP
        sub = gray[::step, ::step] if gray.size > FLOAT_SUBSAMPLE_ABOVE else gray
        q = stretch_percentiles(sub.size, tail_px * sub.size / gray.size)
        lo, hi = np.percentile(sub.astype(np.float64), q)
    if hi <= lo:   # a flat image: any positive range (everything maps to 0)
        hi = lo + 1e-9
    scale = 255.0 / (hi - lo)
    if gray.dtype in (np.uint8, np.uint16):
        lut = np.clip((np.arange(np.iinfo(gray.dtype).max + 1, dtype=np.float64) - lo) * scale, 0, 255)
        lut = lut.astype(np.uint8)
        if hist is not None:
            hist += np.bincount(lut[:len(counts)], weights=counts, minlength=256).astype(np.int64)
        return cv2.LUT(gray, lut) if gray.dtype == np.uint8 else lut[gray]
    out = np.clip((gray.astype(np.float64) - lo) * scale, 0, 255).astype(np.uint8)
    if hist is not None:
        hist += histogram_u8(out)
    return out


def histogram_u8(img: np.ndarray) -> np.ndarray:
    """(256,) int64 counts of the values of ``img`` (H, W) uint8 (any strides): ``np.bincount(img.ravel(),
    minlength=256)``, in one compiled pass (:func:`_histogram_kernel`; ~4x faster than ``cv2.calcHist`` at one
    thread, and exact at any size, where calcHist counts in float32)."""
    out = np.zeros(256, np.int64)
    a = img if img.flags.c_contiguous else np.ascontiguousarray(img)
    _histogram_kernel(a.reshape(-1), out)
    return out


@njit(cache=True, nogil=True)
def _histogram_kernel(values, out):
    """Adds to ``out`` (256,) int64 the counts of ``values`` (n,) uint8: eight partial histograms (int32), filled in
    turn, so that a run of equal values (flat image areas) increments eight counters, not one, whose updates would
    wait on each other (~0.7x the time of four partial int64 histograms on a board image)."""
    part = np.zeros((8, 256), np.int32)
    count_into(values, part)
    for v in range(256):
        out[v] += np.int64(part[0, v]) + part[1, v] + part[2, v] + part[3, v] + part[4, v] + part[5, v] \
            + part[6, v] + part[7, v]


@njit(cache=True, nogil=True, inline="always")
def count_into(values, part):
    """Adds the counts of ``values`` (n,) uint8 to the eight partial histograms ``part`` (8, 256) int32, in turn
    (each partial count must stay below 2^31)."""
    n = values.shape[0]
    i = 0
    while i + 8 <= n:
        for k in range(8):
            part[k, values[i + k]] += 1
        i += 8
    while i < n:
        part[0, values[i]] += 1
        i += 1


def _counts(img: np.ndarray) -> np.ndarray:
    """(V,) int64 counts of the values 0 .. V - 1 of the integer image ``img`` (V: one past its largest value, 256
    for uint8)."""
    return histogram_u8(img) if img.dtype == np.uint8 else np.bincount(img.ravel(), minlength=1)


def _histogram_percentiles(counts: np.ndarray, q: tuple[float, ...]) -> np.ndarray:
    """``np.percentile(img, q)`` (linear interpolation between order statistics) of an integer image, from its
    histogram ``counts`` (:func:`_counts`): O(pixels), no sort."""
    cum = np.cumsum(counts)
    n = int(cum[-1])
    h = (n - 1) * np.asarray(q, np.float64) / 100.0
    k = np.floor(h).astype(np.int64)
    lo = np.searchsorted(cum, k, side="right")                          # the k-th smallest value (0-based)
    hi = np.searchsorted(cum, np.minimum(k + 1, n - 1), side="right")
    return lo + (h - k) * (hi - lo)
