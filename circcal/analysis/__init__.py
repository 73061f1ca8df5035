"""Is a calibration right, without ground truth: the projection difference between two models weighed against
their uncertainty (:mod:`circcal.analysis.diff`), models read from any file with their uncertainty
(:mod:`circcal.analysis.sources`), and the cross-validation of a user's own views (:mod:`circcal.analysis.cross`:
two independent halves, leave-one-view-out)."""

from circcal.analysis.cross import (
    CrossValidation,
    ViewCheck,
    cross_validate,
    cross_validate_detections,
    cross_validate_observations,
    split_views,
)
from circcal.analysis.diff import ModelDiff, model_diff

__all__ = [
    "CrossValidation",
    "ViewCheck",
    "ModelDiff",
    "cross_validate",
    "cross_validate_detections",
    "cross_validate_observations",
    "model_diff",
    "split_views",
]
