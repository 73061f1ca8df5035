"""Images as the detector takes them: an image file read as stored (its header's size checked against
:func:`max_image_pixels` before decoding), grey conversion, and the contrast stretch to uint8 that the thresholds
work on.

Arrays are (H, W) grey or (H, W, 3|4) BGR(A), of dtype uint8, uint16 or float (OpenCV's layout).
"""

from __future__ import annotations

import io
import os
import re
import sys
import tempfile
import threading
import warnings
from pathlib import Path

import cv2
import numpy as np

from circcal.detector.kernels.jit import njit
from circcal.errors import ImageError, InputError

__all__ = [
    "exif_orientation_note",
    "MAX_IMAGE_PIXELS",
    "MAX_IMAGE_PIXELS_ENV",
    "ImageTooLargeError",
    "as_gray",
    "decode_image",
    "header_size",
    "histogram_u8",
    "max_image_pixels",
    "normalise_u8",
    "read_image",
    "read_image_messages",
    "stretch_percentiles",
]

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
MAX_IMAGE_PIXELS = 2**28
"""Image files whose header claims more pixels than this (268 MP) are refused before decoding
(:class:`ImageTooLargeError`), unless :data:`MAX_IMAGE_PIXELS_ENV` says otherwise. A 74-byte PNG can claim 10^10
pixels: the decoder would allocate them (or OpenCV refuses them with an exception of its own, beyond its 2^30).
2^28 leaves room for the largest camera sensors sold (~150-200 MP, pixel-shift composites ~400 MP need the
variable) while bounding what one image costs: 256 MiB as 8-bit grey, 2 GiB as 16-bit BGRA, and the detector's
working copies (a few times the grey image) a few GiB at most."""
MAX_IMAGE_PIXELS_ENV = "CIRCCAL_MAX_IMAGE_PIXELS"
"""The environment variable that replaces :data:`MAX_IMAGE_PIXELS` (a positive whole number of pixels, e.g.
``500000000`` or ``5e8``); read at each image, so it can be changed while the process runs."""


DECODER_NOISE = re.compile(
    r"^(libpng (warning|error)|Corrupt JPEG data|Premature end of JPEG|Invalid SOS|"
    r"\[ ?(WARN|ERROR) ?:.*(grfmt_|imgcodecs|loadsave|imdecode)|Warning: unknown JFIF|"
    r"libtiff|TIFFRead)"
)
"""Lines the image decoders (libpng, libjpeg, libtiff, OpenCV's codec layer: its warnings and errors, with the
``>`` lines that continue them) print on stderr about a corrupt or odd file: caught while decoding and handed to the
caller (a detection's reason or notes), never left on the console. Anything else written to stderr meanwhile is
passed on untouched."""
_DECODE_LOCK = threading.Lock()
"""Decoding swaps the process's stderr (file descriptor 2) for a buffer: one decode at a time (detection itself
runs in parallel; decoding is a few ms of it)."""
_HEADER_LOCK = threading.Lock()
"""Reading a header silences Pillow's DecompressionBombWarning through the process-wide warning filters: one header
at a time, so that concurrent readers restore the filters they found."""
OPENCV_LOG = re.compile(r"^\[ ?(WARN|ERROR|INFO) ?:[^\]]*\]\s*global\s+\S+\s+\S+\s+")
"""The prefix of OpenCV's log lines (``[ WARN:0@0.08] global grfmt_tiff.cpp:123 TIFF_Warning``), cut off the
messages handed on."""


class ImageTooLargeError(ImageError):
    """An image of more pixels than :func:`max_image_pixels`: not decoded.

    The size is claimed by its file's header, or OpenCV's decoder refused it for its size. An
    :class:`~circcal.errors.ImageError` (so an :class:`~circcal.errors.InputError`).

    Parameters
    ----------
    message : str
        One line: what was claimed, the limit, how to raise it.
    pixels : int or None
        The number of pixels claimed (``None`` where only the decoder knew it).
    limit : int
        The limit it exceeds, pixels.

    Attributes
    ----------
    pixels : int or None
        The number of pixels claimed (``None`` where only the decoder knew it).
    limit : int
        The limit it exceeds, pixels.
    """

    def __init__(self, message: str, pixels: int | None, limit: int):
        super().__init__(message)
        self.pixels = pixels
        self.limit = limit


def max_image_pixels() -> int:
    """The most pixels an image file may claim, read from the environment at each call.

    The environment variable :data:`MAX_IMAGE_PIXELS_ENV` when set (a positive whole number; ``5e8`` and
    ``500_000_000`` are accepted), else :data:`MAX_IMAGE_PIXELS`.

    Returns
    -------
    int
        pixels (W x H).

    Raises
    ------
    InputError
        The variable is set to something else (one line naming it).

    Examples
    --------
    >>> max_image_pixels()  # doctest: +SKIP
    268435456
    """
    raw = os.environ.get(MAX_IMAGE_PIXELS_ENV, "").strip()
    if not raw:
        return MAX_IMAGE_PIXELS
    text = raw.replace("_", "")
    try:
        value = int(text) if text.isdigit() else float(text)
    except ValueError:
        value = 0
    if not (np.isfinite(value) and value >= 1 and value == int(value)):
        raise InputError(
            f"environment variable {MAX_IMAGE_PIXELS_ENV}={raw!r}: expected a positive whole number "
            f"of pixels (the default is {MAX_IMAGE_PIXELS})"
        )
    return int(value)


def _too_large(claimed: str, pixels: int | None, limit: int) -> ImageTooLargeError:
    """The error for an image whose header claims ``claimed`` (words), ``pixels`` in all, beyond ``limit``."""
    return ImageTooLargeError(
        f"image too large: {claimed}, more than the limit of {limit} pixels ({_mp(limit)}; not "
        f"decoded: to take it, set the environment variable {MAX_IMAGE_PIXELS_ENV} to a larger "
        "number of pixels)",
        pixels,
        limit,
    )


def _mp(pixels: int) -> str:
    """``pixels`` in megapixels, as words."""
    return f"{pixels / 1e6:,.{0 if pixels >= 1e7 else 1}f} MP"


def _check_header(source: Path | io.BytesIO, limit: int) -> None:
    """Raises :class:`ImageTooLargeError` when the image file ``source`` (a path, or its bytes) claims more than
    ``limit`` pixels in its header (:func:`_header_pixels`)."""
    claimed = _header_pixels(source)
    if claimed is not None and claimed[0] > limit:
        raise _too_large(claimed[1], claimed[0], limit)


def header_size(source: Path | io.BytesIO) -> tuple[int, int] | None:
    """The size an image file claims in its header, read by Pillow without decoding it.

    Parameters
    ----------
    source : Path or io.BytesIO
        The file, or its bytes.

    Returns
    -------
    (int, int) or None
        (width, height) px; None where Pillow cannot tell (no Pillow, a format it does not know, a header it cannot
        parse, a file it cannot open, a size beyond twice its own limit): the decoder decides.
    """
    try:
        return _pillow_size(source)
    except _DecompressionBomb:
        return None


class _DecompressionBomb(Exception):
    """Pillow refused a header's size as beyond twice its own limit; the message is Pillow's."""


def _pillow_size(source: Path | io.BytesIO) -> tuple[int, int] | None:
    """:func:`header_size`, raising :class:`_DecompressionBomb` where Pillow refuses the size (its message holds the
    pixel count)."""
    try:
        from PIL import Image  # (imported here: start-up does not pay for it)
    except ImportError:  # Pillow comes with matplotlib; without it the decoder decides
        return None
    with _HEADER_LOCK, warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        try:
            with Image.open(source) as im:
                return int(im.size[0]), int(im.size[1])
        except Image.DecompressionBombError as exc:
            raise _DecompressionBomb(str(exc)) from None
        except Exception:  # noqa: BLE001 - any header Pillow cannot parse, whatever it raises: the decoder decides
            return None


#: EXIF orientation (tag 0x0112) -> what a viewer that applies it does to the stored pixels.
EXIF_TURNS = {
    2: "mirror it left-right",
    3: "turn it 180 deg",
    4: "mirror it top-bottom",
    5: "mirror and turn it 90 deg",
    6: "turn it 90 deg clockwise",
    7: "mirror and turn it 90 deg",
    8: "turn it 90 deg counter-clockwise",
}


def exif_orientation_note(source: Path) -> str | None:
    """What to tell about an image file whose EXIF orientation turns it: circcal calibrates its pixels as stored.

    ``cv2.imdecode(..., IMREAD_UNCHANGED)`` ignores the orientation tag, so every image is the sensor's frame and one
    camera model serves photographs taken upright and sideways alike; a viewer, ``cv2.imread``'s default and most
    photo tools turn such an image first, so a model used on their pixels does not fit it.

    Parameters
    ----------
    source : Path
        The image file.

    Returns
    -------
    str or None
        The note; None where the file has no orientation tag, tag 1 (as stored), or Pillow cannot read it.
    """
    try:
        from PIL import Image
    except ImportError:  # Pillow comes with matplotlib; without it nothing is said
        return None
    with _HEADER_LOCK, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            with Image.open(source) as im:
                tag = im.getexif().get(0x0112)
        except Exception:  # noqa: BLE001 - a header Pillow cannot parse, whatever it raises: nothing to say
            return None
    if tag not in EXIF_TURNS:
        return None
    return (
        f"EXIF orientation {tag} (viewers {EXIF_TURNS[tag]}) not applied: circcal uses the pixels as stored (the "
        f"sensor's frame); a model from them fits images read the same way (cv2.IMREAD_UNCHANGED), not turned ones "
        f"(cv2.imread's default)"
    )


def _header_pixels(source: Path | io.BytesIO) -> tuple[int, str] | None:
    """``(pixels, words)``: the size the image file ``source`` (a path, or its bytes) claims in its header
    (:func:`header_size`; ``words``: ``"W x H px"``, or the pixel count where Pillow refused to say more); ``None``
    where Pillow cannot tell (the decoder, or the reading of the file, decides)."""
    try:
        size = _pillow_size(source)
    except _DecompressionBomb as exc:  # beyond twice Pillow's own limit: the count is in its words
        m = re.search(r"\((\d+) pixels\)", str(exc))
        n = int(m.group(1)) if m else None
        return None if n is None else (n, f"its header claims {n} pixels ({_mp(n)})")
    if size is None:
        return None
    w, h = size
    return w * h, f"its header claims {w} x {h} px ({_mp(w * h)})"


def _opencv_message(text: str) -> str:
    """An OpenCV error or log text as one line: the source location, error code and function name left out."""
    text = OPENCV_LOG.sub("", text.strip())
    text = re.sub(r"OpenCV\([^)]*\)\s+\S+:\d+:\s+error:\s+\(-?\d+:[^)]*\)\s*", "", text)
    text = re.sub(r"\s+in function '[^']*'", "", text)
    text = re.sub(r"^imdecode_\([^)]*\):\s*", "", text)
    return " ".join(ln.strip().lstrip(">").strip() for ln in text.splitlines() if ln.strip())


def decode_image(data: np.ndarray) -> tuple[np.ndarray | None, list[str]]:
    """The image in the contents of an image file, decoded, with what the decoders print about the file caught.

    Decoded by ``cv2.imdecode(data, IMREAD_UNCHANGED)`` once its header's size is checked against
    :func:`max_image_pixels`.

    Parameters
    ----------
    data : numpy.ndarray
        (n,) uint8: the file's bytes.

    Returns
    -------
    image : numpy.ndarray or None
        (H, W) or (H, W, 3|4) as stored (8 or 16 bit, or float); ``None`` when no decoder can read it, or the decoder
        failed on it (OpenCV's exception becomes a message).
    messages : list of str
        The decoders' complaints: the stderr lines matching :data:`DECODER_NOISE` and OpenCV's error lines, one each
        (other stderr output is written on).

    Raises
    ------
    ImageTooLargeError
        The header claims more pixels than :func:`max_image_pixels` (nothing decoded); or, where Pillow cannot read
        the header, OpenCV's decoder refuses the size, or the decoded image exceeds the limit.
    InputError
        :data:`MAX_IMAGE_PIXELS_ENV` is set to something other than a positive whole number.
    """
    limit = max_image_pixels()
    _check_header(io.BytesIO(data), limit)
    return _decode_within(data, limit)


def _decode_within(data: np.ndarray, limit: int) -> tuple[np.ndarray | None, list[str]]:
    """:func:`decode_image` of ``data`` whose header was checked against ``limit`` already."""
    img, noise = _decode(data)
    if isinstance(img, cv2.error):
        said = _opencv_message(str(img))
        if "CV_IO_MAX_IMAGE" in said:  # OpenCV's own size limits (a header Pillow cannot read, or a larger limit)
            raise ImageTooLargeError(
                f"image too large for OpenCV's decoder: the size in its header fails its check "
                f"({said}; OpenCV's limits are set by the environment variables "
                "OPENCV_IO_MAX_IMAGE_PIXELS, OPENCV_IO_MAX_IMAGE_WIDTH and "
                "OPENCV_IO_MAX_IMAGE_HEIGHT)",
                None,
                limit,
            )
        img, noise = None, [*noise, said]
    if img is not None and img.shape[0] * img.shape[1] > limit:
        n = img.shape[0] * img.shape[1]
        raise _too_large(f"it decodes to {img.shape[1]} x {img.shape[0]} px ({_mp(n)})", n, limit)
    return img, noise


def _decode(data: np.ndarray) -> tuple[np.ndarray | cv2.error | None, list[str]]:
    """``cv2.imdecode(data, IMREAD_UNCHANGED)`` (or the ``cv2.error`` it raised, returned) and the decoders'
    complaints on stderr (see :func:`decode_image`)."""
    with _DECODE_LOCK:
        try:
            sys.stderr.flush()
        except (AttributeError, ValueError, OSError):  # no usable sys.stderr (closed, replaced): decode plainly
            return _imdecode(data), []
        with tempfile.TemporaryFile() as buf:
            saved = os.dup(2)
            os.dup2(buf.fileno(), 2)
            try:
                img = _imdecode(data)
            finally:
                os.dup2(saved, 2)
                os.close(saved)
            buf.seek(0)
            text = buf.read().decode("utf-8", errors="replace")
    noise: list[str] = []
    other: list[str] = []
    last_noise = False
    for ln in (ln.strip() for ln in text.splitlines() if ln.strip()):
        if ln.startswith(">") and last_noise:  # the lines of a multi-line OpenCV error go with it
            noise[-1] = f"{noise[-1]} {ln.lstrip('>').strip()}"
        elif DECODER_NOISE.search(ln):
            noise.append(_opencv_message(ln))
            last_noise = True
        else:
            other.append(ln)
            last_noise = False
    if other:
        sys.stderr.write("\n".join(other) + "\n")
    return img, noise


def _imdecode(data: np.ndarray) -> np.ndarray | cv2.error | None:
    """``cv2.imdecode(data, IMREAD_UNCHANGED)``; the ``cv2.error`` a file can make it raise (a size it refuses, a
    corrupt stream) returned, not raised."""
    try:
        return cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        return exc


def read_image_messages(path: Path) -> tuple[np.ndarray | None, list[str]]:
    """:func:`read_image`, and what the decoder said about the file.

    Parameters
    ----------
    path : pathlib.Path
        An image file in any format OpenCV decodes (str accepted).

    Returns
    -------
    image : numpy.ndarray or None
        As :func:`read_image` returns it.
    messages : list of str
        The decoders' complaints about the file (:func:`decode_image`), one line each; empty for a clean file, and
        for a missing or empty one.

    Raises
    ------
    OSError
        The file exists but cannot be read (permissions, I/O).
    ImageTooLargeError
        Its header claims more pixels than :func:`max_image_pixels` (see :func:`decode_image`).
    InputError
        :data:`MAX_IMAGE_PIXELS_ENV` is set to something other than a positive whole number.
    """
    path = Path(path)
    if not path.is_file():
        return None, []
    limit = max_image_pixels()
    _check_header(path, limit)  # from the file: one that claims too much is refused before it is read whole
    data = np.fromfile(str(path), dtype=np.uint8)
    if data.size == 0:
        return None, []
    return _decode_within(data, limit)


def read_image(path: Path) -> np.ndarray | None:
    """The image stored in the file ``path``, as stored.

    Parameters
    ----------
    path : pathlib.Path
        An image file in any format OpenCV decodes.

    Returns
    -------
    numpy.ndarray or None
        (H, W) grey or (H, W, 3|4) BGR(A) (``cv2.IMREAD_UNCHANGED``: 8 or 16 bit, or float for float TIFFs), or
        ``None`` when there is no such file (or it is not a regular file), it is empty, or no decoder can read it
        (corrupt, truncated, not an image). The decoders' complaints are not printed (:func:`read_image_messages`
        returns them).

    Raises
    ------
    OSError
        The file exists but cannot be read (permissions, I/O).
    ImageTooLargeError
        (an :class:`~circcal.errors.ImageError`) its header claims more pixels than :func:`max_image_pixels`: not
        decoded (see :func:`decode_image`).
    InputError
        :data:`MAX_IMAGE_PIXELS_ENV` is set to something other than a positive whole number.
    """
    return read_image_messages(path)[0]


def as_gray(image: np.ndarray) -> np.ndarray:
    """The grey image the detector works on.

    Parameters
    ----------
    image : numpy.ndarray
        (H, W), (H, W, 1) grey or (H, W, 3|4) BGR(A), of any integer or floating dtype (not bool).

    Returns
    -------
    numpy.ndarray
        (H, W) grey: uint8, uint16, float32 and float64 in their own dtype, other dtypes (signed integers, uint32,
        uint64, float16) as float32; colour converted by ``cv2.cvtColor`` (through float32 for dtypes it does not
        take).

    Raises
    ------
    ImageError
        Other shapes or dtypes, a side below :data:`MIN_IMAGE_SIDE`, NaN or inf.
    """
    img = np.asarray(image)
    if img.dtype == bool or not (np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)):
        raise ImageError(f"unsupported image dtype {img.dtype}; expected uint8, uint16 or float")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] not in (3, 4):
        raise ImageError(f"colour image must have 3 (BGR) or 4 (BGRA) channels, got {img.shape[2]}")
    if img.ndim not in (2, 3):
        raise ImageError(f"expected a (H, W) grey or (H, W, 3) BGR image, got shape {np.shape(image)}")
    if min(img.shape[:2]) < MIN_IMAGE_SIDE:
        raise ImageError(f"image too small: {img.shape[1]}x{img.shape[0]} px (each side at least {MIN_IMAGE_SIDE})")
    if not img.dtype.isnative:
        img = img.astype(img.dtype.newbyteorder("="))
    if img.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        img = img.astype(np.float32)
    if img.ndim == 3:
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        img = cv2.cvtColor(np.ascontiguousarray(img, np.float32 if img.dtype == np.float64 else img.dtype), code)
    if np.issubdtype(img.dtype, np.floating) and not np.all(np.isfinite(img)):
        raise ImageError("image contains NaN or inf")
    return img


def stretch_percentiles(n_pixels: int, tail_px: float = STRETCH_TAIL_PX) -> tuple[float, float]:
    """The percentiles of an image's grey levels that the contrast stretch maps to 0 and 255.

    :data:`STRETCH_PERCENTILES`, with at most ``tail_px`` pixels beyond either (:data:`STRETCH_TAIL_PX`).

    Parameters
    ----------
    n_pixels : int
        The image's number of pixels.
    tail_px : float
        The most pixels beyond either percentile (an image shrunk s times passes :data:`STRETCH_TAIL_PX` over s^2).

    Returns
    -------
    low, high : float
        Percentiles (0..100).

    Examples
    --------
    >>> stretch_percentiles(640 * 480)
    (0.5, 99.5)
    >>> stretch_percentiles(4000 * 3000)  # 0.5 % would be 60,000 px: 2,000 at most
    (0.016666666666666666, 99.98333333333333)
    """
    tail = min(STRETCH_PERCENTILES[0], 100.0 * max(float(tail_px), 1.0) / max(int(n_pixels), 1))
    return tail, 100.0 - tail


def normalise_u8(gray: np.ndarray, tail_px: float = STRETCH_TAIL_PX, hist: np.ndarray | None = None) -> np.ndarray:
    """The grey image contrast-stretched to uint8 (for thresholding only).

    The range of ``gray`` between the :func:`stretch_percentiles` is stretched to 0..255 (clipped beyond). Integer
    images (uint8/uint16, e.g. from :func:`as_gray`): percentiles of all pixels from their histogram, the stretch
    through a lookup table of the same formula (identical results); float images: percentiles of a subsample above
    :data:`FLOAT_SUBSAMPLE_ABOVE` pixels (:data:`FLOAT_SUBSAMPLE_STEP`). A flat image maps to 0.

    Parameters
    ----------
    gray : numpy.ndarray
        (H, W) grey: uint8, uint16, float32 or float64 (as :func:`as_gray` gives it).
    tail_px : float
        See :func:`stretch_percentiles`.
    hist : numpy.ndarray or None
        (256,) int64; if given, the counts of the result's values are added to it in place (integer images: the
        input's histogram carried through the lookup table, no second pass over the pixels).

    Returns
    -------
    numpy.ndarray
        (H, W) uint8.

    Examples
    --------
    >>> normalise_u8(np.array([[10, 20], [30, 40]], np.uint8))
    array([[  0,  84],
           [170, 255]], dtype=uint8)
    """
    q = stretch_percentiles(gray.size, tail_px)
    if gray.dtype in (np.uint8, np.uint16):
        counts = _counts(gray)
        lo, hi = _histogram_percentiles(counts, q)
    else:
        step = FLOAT_SUBSAMPLE_STEP
        sub = gray[::step, ::step] if gray.size > FLOAT_SUBSAMPLE_ABOVE else gray
        q = stretch_percentiles(sub.size, tail_px * sub.size / gray.size)
        lo, hi = np.percentile(sub.astype(np.float64), q)
    if hi <= lo:  # a flat image: any positive range (everything maps to 0)
        hi = lo + 1e-9
    scale = 255.0 / (hi - lo)
    if gray.dtype in (np.uint8, np.uint16):
        lut = np.clip((np.arange(np.iinfo(gray.dtype).max + 1, dtype=np.float64) - lo) * scale, 0, 255)
        lut = lut.astype(np.uint8)
        if hist is not None:
            hist += np.bincount(lut[: len(counts)], weights=counts, minlength=256).astype(np.int64)
        return cv2.LUT(gray, lut) if gray.dtype == np.uint8 else lut[gray]
    out = np.clip((gray.astype(np.float64) - lo) * scale, 0, 255).astype(np.uint8)
    if hist is not None:
        hist += histogram_u8(out)
    return out


def histogram_u8(img: np.ndarray) -> np.ndarray:
    """The histogram of a uint8 image: ``np.bincount(img.ravel(), minlength=256)``.

    One compiled pass (:func:`_histogram_kernel`; ~4x faster than ``cv2.calcHist`` at one thread, and exact at any
    size, where calcHist counts in float32).

    Parameters
    ----------
    img : numpy.ndarray
        (H, W) uint8, any strides.

    Returns
    -------
    numpy.ndarray
        (256,) int64 counts.

    Examples
    --------
    >>> histogram_u8(np.array([[0, 1], [1, 255]], np.uint8))[[0, 1, 2, 255]]
    array([1, 2, 0, 1])
    """
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
        out[v] += (
            np.int64(part[0, v])
            + part[1, v]
            + part[2, v]
            + part[3, v]
            + part[4, v]
            + part[5, v]
            + part[6, v]
            + part[7, v]
        )


@njit(cache=True, nogil=True, inline="always")
def count_into(values, part):
    """Adds the counts of uint8 values to eight partial histograms, in turn (compiled, inlined into the kernels).

    Parameters
    ----------
    values : numpy.ndarray
        (n,) uint8.
    part : numpy.ndarray
        (8, 256) int32, added to in place; each partial count must stay below 2^31.
    """
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
    lo = np.searchsorted(cum, k, side="right")  # the k-th smallest value (0-based)
    hi = np.searchsorted(cum, np.minimum(k + 1, n - 1), side="right")
    return lo + (h - k) * (hi - lo)
