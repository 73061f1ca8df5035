"""The detector: circle grids found in an image, with unbiased centre projections (see :mod:`circcal.detector.find`)."""
from circcal.detector.find import Detection, detect, detect_files, recorrect

__all__ = ["Detection", "detect", "detect_files", "recorrect"]
