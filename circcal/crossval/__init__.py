"""Is a calibration right, without ground truth: the projection difference between two models weighed against
their uncertainty (:mod:`circcal.crossval.diff`), models read from any file with their uncertainty
(:mod:`circcal.crossval.sources`), and the cross-validation of a user's own views (:mod:`circcal.crossval.cross`:
two independent halves, leave-one-view-out)."""
from circcal.crossval.cross import (CrossValidation, ViewCheck, cross_validate, cross_validate_detections,
                                    cross_validate_observations, split_views)
from circcal.crossval.diff import ModelDiff, model_diff

__all__ = ["CrossValidation", "ViewCheck", "ModelDiff", "cross_validate", "cross_validate_detections",
           "cross_validate_observations", "model_diff", "split_views"]
