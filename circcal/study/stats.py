"""Interval estimates for a study's summary, each at confidence ``conf`` (two-sided, default 95 %).

* :func:`mean_interval`: the mean with Student's t interval (bias of an estimator);
* :func:`std_interval`: the sample standard deviation (ddof 1) with the chi-square interval of a normal sample
  (spread of an estimator);
* :func:`wilson_interval`: a proportion with Wilson's score interval (pass rates; sound at 0 % and 100 %).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["CONFIDENCE", "mean_interval", "std_interval", "wilson_interval"]

#: The confidence of every interval in a study summary.
CONFIDENCE = 0.95

_NAN3 = (float("nan"), float("nan"), float("nan"))


def _finite(x) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64).ravel()
    return a[np.isfinite(a)]


def mean_interval(x, conf: float = CONFIDENCE) -> tuple[float, float, float]:
    """The mean with Student's t interval, of the finite values.

    Parameters
    ----------
    x : array_like
    conf : float
        Two-sided confidence.

    Returns
    -------
    tuple of float
        (mean, low, high); NaNs for fewer than 2 values.
    """
    from scipy import stats

    a = _finite(x)
    if a.size < 2:
        return (float(a.mean()), float("nan"), float("nan")) if a.size else _NAN3
    m, se = float(a.mean()), float(a.std(ddof=1) / math.sqrt(a.size))
    h = float(stats.t.ppf(0.5 + conf / 2, a.size - 1)) * se
    return m, m - h, m + h


def std_interval(x, conf: float = CONFIDENCE) -> tuple[float, float, float]:
    """The sample standard deviation (ddof 1) with the normal-theory chi-square interval, of the finite values.

    Parameters
    ----------
    x : array_like
    conf : float
        Two-sided confidence.

    Returns
    -------
    tuple of float
        (std, low, high); NaNs for fewer than 2 values.
    """
    from scipy import stats

    a = _finite(x)
    if a.size < 2:
        return _NAN3
    s, dof = float(a.std(ddof=1)), a.size - 1
    lo = s * math.sqrt(dof / float(stats.chi2.ppf(0.5 + conf / 2, dof)))
    hi = s * math.sqrt(dof / float(stats.chi2.ppf(0.5 - conf / 2, dof)))
    return s, lo, hi


def wilson_interval(k: int, n: int, conf: float = CONFIDENCE) -> tuple[float, float, float]:
    """A proportion with Wilson's score interval.

    Parameters
    ----------
    k : int
        Successes.
    n : int
        Trials.
    conf : float
        Two-sided confidence.

    Returns
    -------
    tuple of float
        (k / n, low, high); NaNs for n = 0.

    Examples
    --------
    >>> p, lo, hi = wilson_interval(10, 10)
    >>> p, round(hi, 12), lo < 1
    (1.0, 1.0, True)
    """
    from scipy import stats

    if n <= 0:
        return _NAN3
    z = float(stats.norm.ppf(0.5 + conf / 2))
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return p, max(0.0, c - h), min(1.0, c + h)
