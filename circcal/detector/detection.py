"""What the detector says about one image: :class:`Detection`, and the machine-readable :class:`Reason` an image
was not used (beside the human text; nothing parses the text)."""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = ["Reason", "Detection", "Rejection"]


class Reason(str, enum.Enum):
    """Why an image gave no grid. The values are what detections.json and model.json carry (``reason_code``)."""

    #: the path does not exist (or is not a file)
    FILE_NOT_FOUND = "file-not-found"
    #: the file is not an image a decoder can read, or it is corrupt
    UNREADABLE = "unreadable"
    #: the image decoded but cannot be used (too small, NaN/inf, unsupported channels or type)
    BAD_IMAGE = "bad-image"
    #: fewer dark, dot-like blobs than the board has dots
    TOO_FEW_CANDIDATES = "too-few-candidates"
    #: enough candidates, but no arrangement of them is the board's grid
    GRID_NOT_RECOGNISED = "grid-not-recognised"
    #: a dot of the grid gives too few sub-pixel edge points, or no ellipse fits them
    DOT_UNMEASURABLE = "dot-unmeasurable"
    #: the projective centre correction found no consistent board homography
    CENTRE_CORRECTION_FAILED = "centre-correction-failed"
    #: the image's size differs from the camera model's (or from the other images of a calibration)
    WRONG_IMAGE_SIZE = "wrong-image-size"
    #: the same file (or a file with identical content) was given before: counted once, or the views it adds
    #: would shrink the stated uncertainty without adding information
    DUPLICATE = "duplicate"


@dataclass
class Detection:
    """Result of :func:`circcal.detector.detect` on one image.

    ``found``: whether the whole grid was found; ``centres``: (rows*cols, 2) float64 px, images of the circle
    centres in OpenCV's object-point order (``None`` when not found); ``reason``: ``None`` when found, else why not,
    in words; ``code``: the same as a :class:`Reason`. For re-correction and overlays: ``edge_points`` (list of
    (M_k, 2) px sub-pixel boundary points per dot, in board order, in the *distorted* image as observed),
    ``conics`` ((N, 3, 3) ellipses fitted to them, in the undistorted image when a camera was given),
    ``ellipse_centres`` ((N, 2) px, the uncorrected ellipse centres, distorted image), ``homography`` (board mm ->
    undistorted image px), ``candidates`` ((K, 2) px all candidate dots), ``image_size`` (W, H), ``segmentation``
    (which threshold, at which scale, found the candidates).
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

    def __post_init__(self) -> None:
        if self.found == (self.code is not None):
            raise ValueError(f"a detection has a reason code exactly when it was not found (found={self.found}, "
                             f"code={self.code})")


class Rejection(NamedTuple):
    """An image left out of a calibration: its path, why (:class:`Reason`) and the detector's words."""

    path: str
    code: Reason
    reason: str
