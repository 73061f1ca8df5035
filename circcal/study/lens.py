"""The lens-model axis of a study: which camera model a run calibrates.

Today one model exists, OpenCV's pinhole with 5 distortion coefficients ``[k1, k2, p1, p2, k3]``
(:class:`circcal.model.Camera`), which every calibrator fits and every fixture renders. The axis exists so that a study
spec, its run keys and its rows already carry the model: when another model is added here, old rows keep their keys
and a spec that names the new model gets rows of its own.
"""

from __future__ import annotations

from circcal.errors import InputError

__all__ = ["DEFAULT_LENS_MODEL", "LENS_MODELS", "check_lens_model"]

#: name -> what it is. ``opencv5``: OpenCV's pinhole + k1, k2, p1, p2, k3 (circcal.model's only model).
LENS_MODELS: dict[str, str] = {
    "opencv5": "OpenCV pinhole + 5 distortion coefficients [k1, k2, p1, p2, k3] (circcal.model.Camera)",
}
DEFAULT_LENS_MODEL = "opencv5"


def check_lens_model(name: str) -> str:
    """A lens model name, checked.

    Parameters
    ----------
    name : str

    Returns
    -------
    str
        ``name``.

    Raises
    ------
    circcal.errors.InputError
        An unknown model (the message lists the known ones).
    """
    if name not in LENS_MODELS:
        raise InputError(f"unknown lens model {name!r}; known: {', '.join(LENS_MODELS)}")
    return name
