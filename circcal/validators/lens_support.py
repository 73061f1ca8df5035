"""Which lens models a reference calibrator fits (:func:`lens_support`) and the default (:data:`DEFAULT_LENSES`)."""

from __future__ import annotations

from typing import Any

__all__ = ["DEFAULT_LENSES", "lens_support"]

#: The lens models (:data:`circcal.model.LENS_MODELS` names) a reference fits when it does not say: OpenCV's five
#: coefficients. A reference that fits more lists them in its ``lenses`` attribute and takes ``lens=`` in its
#: constructor (``registry.get(name, lens="rational")``); for the others it may say why in ``unsupported_lenses``.
DEFAULT_LENSES: tuple[str, ...] = ("opencv5",)


def lens_support(cal: Any, lens: str) -> tuple[bool, str]:
    """Whether a reference fits a lens model, and why not when it does not.

    A reference without a ``lenses`` attribute fits :data:`DEFAULT_LENSES` only.

    Parameters
    ----------
    cal : ReferenceCalibrator
        Any reference, plug-ins included.
    lens : str
        A :data:`circcal.model.LENS_MODELS` name.

    Returns
    -------
    ok : bool
        True when ``lens`` is one of the reference's ``lenses``.
    why : str
        "" when ok; else the reference's own words from ``unsupported_lenses``, or a generic reason.
    """
    lenses = tuple(getattr(cal, "lenses", DEFAULT_LENSES))
    if lens in lenses:
        return True, ""
    why = dict(getattr(cal, "unsupported_lenses", {}) or {}).get(lens)
    name = getattr(cal, "name", type(cal).__name__)
    return False, why or f"{name} fits the lens models {', '.join(lenses)} only, not {lens!r}"
