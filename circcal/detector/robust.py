"""Robust statistics the detector shares: row medians of masked data and the MAD -> sigma factor."""
from __future__ import annotations

import numpy as np

__all__ = ["MAD_TO_SIGMA", "row_medians"]

MAD_TO_SIGMA = 1.4826
"""Standard deviation of a normal distribution per unit of its median absolute deviation (1 / Phi^-1(3/4))."""


def row_medians(values: np.ndarray) -> np.ndarray:
    """(D,) ``np.nanmedian`` of each row of ``values`` (D, P), NaN marking the entries left out (the mean of the two
    middle values for an even count); NaN for a row without values. Rows without values are never passed to numpy,
    so no all-NaN warning is raised (a warning filter would be process-wide state, and images run in threads)."""
    values = np.asarray(values, np.float64).reshape(len(values), -1)
    out = np.full(len(values), np.nan)
    rows = ~np.all(np.isnan(values), axis=1)
    if np.any(rows):
        out[rows] = np.nanmedian(values[rows], axis=1)
    return out
