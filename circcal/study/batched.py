"""Batched solves of observations runs through kornia's vectorised Levenberg-Marquardt
(:meth:`circcal.validators.kornia.KorniaCalibrator.calibrate_batch`): one task's runs (the same views, many noise
draws) as one batch, on CUDA when present and asked for (``device: auto``), on CPU otherwise.

Each result equals circcal's solver on the same points to 1e-6 px (tested on CPU in tests/test_study_batched.py;
the CUDA path is the same torch code on another device, see docs/studies.md).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from circcal.validators.reference_result import ReferenceResult

__all__ = ["KORNIA", "resolve_device", "solve_batch"]

KORNIA = "kornia"


def resolve_device(device: str) -> str:
    """The torch device of a study's ``device`` field.

    Parameters
    ----------
    device : {"auto", "cpu", "cuda"}

    Returns
    -------
    str
        "auto" -> "cuda" when torch sees a GPU, else "cpu"; "cpu" and "cuda" unchanged.
    """
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
    """One kornia batch; never raises.

    Parameters
    ----------
    object_points : sequence of ndarray, shape (N_v, 3)
        Board points per view, mm, shared by every problem.
    image_points : sequence of sequence of ndarray, shape (N_v, 2)
        One list of per-view centres (px) per problem.
    image_size : tuple of int
        (width, height) px.
    device : {"auto", "cpu", "cuda"}
        See :func:`resolve_device`.
    mode : str
        "fair".

    Returns
    -------
    list of ReferenceResult
        One per problem; ``time_s`` is the batch's time / its size; ``extra["device"]``, ``extra["batch_size"]``.
    """
    from circcal.validators.kornia import KorniaCalibrator

    cal = KorniaCalibrator(device=resolve_device(device))
    problems = [
        {"object_points": list(object_points), "image_points": list(img), "image_size": tuple(image_size)}
        for img in image_points
    ]
    return cal.calibrate_batch(problems, mode=mode)
