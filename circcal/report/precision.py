"""How many digits report.json keeps, and why: every number is rounded to :data:`SIG_DIGITS` significant digits and
the agreement checks' values to :data:`CHECK_QUANTUM` px, so that run-to-run jitter of the reference calibrators
does not change the published numbers."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["CHECK_QUANTUM", "SIG_DIGITS", "precision_note", "quantise", "round_sig"]

#: Significant digits of every float in report.json: enough for every comparison the report makes, coarse enough
#: that run-to-run jitter of the references (pycolmap's Ceres solve differs ~1e-11 relative between runs; its
#: agreement with circcal, ~2e-8 px, by percent) does not change the published numbers.
SIG_DIGITS = 6
#: Agreement-check values (px) are rounded to this: values of 1e-12..1e-6 px move between runs (threaded
#: reductions in the solvers) at about this level; they are kept only for checks that fail.
CHECK_QUANTUM = 1e-7


def quantise(value: Any, quantum: float) -> Any:
    """A finite float rounded to a multiple of a quantum; anything else unchanged.

    Parameters
    ----------
    value : object
    quantum : float
        The step (e.g. :data:`CHECK_QUANTUM` px).

    Returns
    -------
    object

    Examples
    --------
    >>> quantise(0.123456, 0.01)
    0.12
    """
    if isinstance(value, (float, np.floating)) and np.isfinite(value):
        return float(np.round(float(value) / quantum) * quantum)
    return value


def round_sig(tree: Any, sig: int = SIG_DIGITS) -> Any:
    """A JSON tree with every float rounded to a number of significant digits.

    Parameters
    ----------
    tree : object
        Dicts, lists and scalars.
    sig : int
        Significant digits.

    Returns
    -------
    object
        A tree of the same shape.

    Examples
    --------
    >>> round_sig({"a": [3.14159, 2]}, 3)
    {'a': [3.14, 2]}
    """
    if isinstance(tree, dict):
        return {k: round_sig(v, sig) for k, v in tree.items()}
    if isinstance(tree, list):
        return [round_sig(v, sig) for v in tree]
    if isinstance(tree, float):
        return float(f"{tree:.{sig}g}")
    return tree


def precision_note() -> str:
    """The sentence report.json carries about its own precision.

    Returns
    -------
    str
    """
    return (
        f"floats rounded to {SIG_DIGITS} significant digits; agreement-check values to {CHECK_QUANTUM:g} px and "
        f"kept only for failed checks (they move between runs at that level)"
    )
