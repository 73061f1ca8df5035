"""Batched solves of observations runs through kornia's vectorised Levenberg-Marquardt
(:meth:`circcal.validators.kornia.KorniaCalibrator.calibrate_batch`): one task's runs (the same views, many noise
draws) as one batch, on CUDA when present and asked for (``device: auto``), on CPU otherwise.

Each result equals circcal's solver on the same points to 1e-6 px (max projection difference over the imager,
tested on CPU in tests/test_study_batched.py); the CUDA path runs the same torch code on another device and is
untested here (no GPU on the development machines).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from circcal.validators.base import ReferenceResult

__all__ = ["KORNIA", "resolve_device", "solve_batch"]

KORNIA = "kornia"


def resolve_device(device: str) -> str:
    """ "auto" -> "cuda" when torch sees a GPU, else "cpu"; "cpu" and "cuda" unchanged."""
    if device != "auto":
        return device
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


def solve_batch(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[Sequence[np.ndarray]],
    image_size: tuple[int, int],
    *,
    device: str = "auto",
    mode: str = "fair",
) -> list[ReferenceResult]:
    """One kornia batch: ``object_points`` per view (N_v, 3) mm shared by every problem, ``image_points`` one list
    of per-view (N_v, 2) px arrays per problem, ``image_size`` (width, height). Returns one
    :class:`~circcal.validators.base.ReferenceResult` per problem (``time_s``: the batch's time / its size;
    ``extra["device"]``, ``extra["batch_size"]``); never raises."""
    from circcal.validators.kornia import KorniaCalibrator

    cal = KorniaCalibrator(device=resolve_device(device))
    problems = [
        {"object_points": list(object_points), "image_points": list(img), "image_size": tuple(image_size)}
        for img in image_points
    ]
    return cal.calibrate_batch(problems, mode=mode)
