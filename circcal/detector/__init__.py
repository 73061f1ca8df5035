"""The detector: circle grids found in an image, with unbiased centre projections (see :mod:`circcal.detector.find`)."""
from circcal.detector.detection import Detection, Reason, Rejection
from circcal.detector.find import detect, detect_files, recorrect

__all__ = ["Detection", "Reason", "Rejection", "detect", "detect_files", "recorrect"]
