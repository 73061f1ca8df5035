"""The detector: circle grids found in an image, with unbiased centre projections (see :mod:`circcal.detector.find`;
files in threads: :mod:`circcal.detector.files`)."""

from circcal.detector.detection import Detection, Reason, Rejection
from circcal.detector.files import detect_files
from circcal.detector.find import detect, recorrect
from circcal.detector.image import read_image

__all__ = ["Detection", "Reason", "Rejection", "detect", "detect_files", "read_image", "recorrect"]
