"""What the detector says about one image: :class:`Detection`, and the machine-readable :class:`Reason` an image
was not used (beside the human text; nothing parses the text)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

__all__ = ["REASON_TEXT", "Reason", "Detection", "Rejection"]


class Reason(str, enum.Enum):
    """Why an image gave no grid. The values are what detections.json and model.json carry (``reason_code``);
    :data:`REASON_TEXT` says each in words (the README's list is generated from it: tests/test_reasons.py)."""

    FILE_NOT_FOUND = "file-not-found"
    UNREADABLE = "unreadable"
    BAD_IMAGE = "bad-image"
    IMAGE_TOO_LARGE = "image-too-large"
    TOO_FEW_CANDIDATES = "too-few-candidates"
    GRID_NOT_RECOGNISED = "grid-not-recognised"
    GRID_MISMATCH = "grid-mismatch"
    MARKERS_INCONSISTENT = "markers-inconsistent"
    AMBIGUOUS_VIEW = "ambiguous-view"
    TOO_FEW_POINTS = "too-few-points"
    IRREGULAR_GRID = "irregular-grid"
    TIME_BUDGET = "time-budget-exceeded"
    CENTRE_CORRECTION_FAILED = "centre-correction-failed"
    WRONG_IMAGE_SIZE = "wrong-image-size"
    DUPLICATE = "duplicate"


#: Each :class:`Reason` in words (one line each; the README's list of codes is these).
REASON_TEXT: dict[Reason, str] = {
    Reason.FILE_NOT_FOUND: "the path does not exist (or is not a file)",
    Reason.UNREADABLE: "the file is not an image a decoder can read, or it is corrupt",
    Reason.BAD_IMAGE: "the image decoded but cannot be used (too small, NaN/inf, unsupported channels or type)",
    Reason.IMAGE_TOO_LARGE: "the image file claims more pixels than the limit (`CIRCCAL_MAX_IMAGE_PIXELS`, default 2^28) in its header (not decoded), or OpenCV's decoder refuses its size",
    Reason.TOO_FEW_CANDIDATES: "fewer dark, dot-like blobs than the board has dots",
    Reason.GRID_NOT_RECOGNISED: "enough candidates, but no arrangement of them is the board's grid",
    Reason.GRID_MISMATCH: "a dot lattice is there, but it is not a `--grid` board: it continues beyond it (the board has more dots), it is complete and smaller, or the transposed grid fits it (the reason says which)",
    Reason.MARKERS_INCONSISTENT: "the marker dots seen match no part of the board's marker layout",
    Reason.AMBIGUOUS_VIEW: "part of the board is seen, but which part is ambiguous (a board without markers, or no telling markers in view): rejected rather than guessed",
    Reason.TOO_FEW_POINTS: "too few dots of the board seen (or left after dropping the bad ones) for a view",
    Reason.IRREGULAR_GRID: "the dots sit on a lattice but fail the checks a board passes (regular spacing, elliptic edges, dot sizes)",
    Reason.TIME_BUDGET: "the image took longer than its time budget (dense texture, thousands of blobs)",
    Reason.CENTRE_CORRECTION_FAILED: "the projective centre correction found no consistent board homography",
    Reason.WRONG_IMAGE_SIZE: "the image's size differs from the camera model's (or from the other images of a calibration)",
    Reason.DUPLICATE: "the same file (or a file with identical content), or the same view (its dots at the same "
    "pixels within 0.05 px: a photograph re-saved, or neither board nor camera moved), was given before: counted once, "
    "since the views it adds would shrink the stated uncertainty without adding information",
}


@dataclass
class Detection:
    """The result of :func:`circcal.detector.detect` on one image.

    Attributes
    ----------
    found : bool
        Whether the board was found (whole, or a part labelled without ambiguity).
    centres : numpy.ndarray or None
        (rows*cols, 2) float64 px: the images of the circle centres in OpenCV's object-point order, NaN for points
        not seen (out of frame, occluded, or dropped as bad dots); ``None`` when not found.
    reason : str or None
        ``None`` when found, else why not, in words.
    code : Reason or None
        The same as a :class:`Reason`; ``None`` exactly when found.
    edge_points : list of numpy.ndarray or None
        For re-correction and overlays: N arrays (M_k, 2) px, each dot's sub-pixel boundary points, in board order,
        in the *distorted* image as observed; (0, 2) for a point not seen.
    conics : numpy.ndarray or None
        (N, 3, 3) ellipses fitted to them, in the undistorted image when a camera was given; NaN where not seen.
    ellipse_centres : numpy.ndarray or None
        (N, 2) px: the uncorrected ellipse centres, distorted image.
    homography : numpy.ndarray or None
        (3, 3) board mm -> undistorted image px.
    candidates : numpy.ndarray or None
        (K, 2) px: all candidate dots.
    image_size : tuple of int or None
        (W, H) px.
    segmentation : str or None
        Which threshold, at which scale, found the candidates.
    complete : bool
        The view shows the board's whole extent (every point, up to dropped dots).
    dropped : dict of int to str
        Why each dot of the board that was seen was left out (board point -> reason: cut by the image border, an
        edge fit that is no ellipse, a size or shape unlike its neighbours'), so they do not bias the solve.
    notes : list of str
        What else the image shows (another board, a larger dot grid), in words.
    seen : numpy.ndarray or None
        (N,) bool: the board points with a centre (``None`` when not found).
    n_dropped : int
        How many dots of the board were seen but left out as bad.

    Raises
    ------
    ValueError
        On construction, when ``code`` is given for a found board or missing for one not found.
    """

    found: bool
    centres: np.ndarray | None
    reason: str | None
    code: Reason | None = None
    edge_points: list[np.ndarray] | None = None
    conics: np.ndarray | None = None
    ellipse_centres: np.ndarray | None = None
    homography: np.ndarray | None = None
    candidates: np.ndarray | None = None
    image_size: tuple[int, int] | None = None
    segmentation: str | None = None
    complete: bool = True
    dropped: dict[int, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def seen(self) -> np.ndarray | None:
        """(N,) bool: the board points with a centre (``None`` when not found)."""
        return None if self.centres is None else np.all(np.isfinite(self.centres), axis=1)

    @property
    def n_dropped(self) -> int:
        """How many dots of the board were seen but left out as bad (:attr:`dropped`)."""
        return len(self.dropped)

    def __post_init__(self) -> None:
        if self.found == (self.code is not None):
            raise ValueError(
                f"a detection has a reason code exactly when it was not found (found={self.found}, code={self.code})"
            )


class Rejection(NamedTuple):
    """An image left out of a calibration: its path, why, and the detector's words.

    Attributes
    ----------
    path : str
        The image file.
    code : Reason
        Why, as a code.
    reason : str
        Why, in the detector's words.
    """

    path: str
    code: Reason
    reason: str
