"""Numbers as circcal prints them (tables of validate, conformance and the reports), so a missing or non-finite
value reads "-" everywhere."""

from __future__ import annotations

import math
from typing import Any

__all__ = ["fmt_number", "fmt_scientific"]


def fmt_number(value: Any, spec: str = ".4f") -> str:
    """A number as the tables print it.

    Parameters
    ----------
    value : Any
        A number (px, mm, a ratio), None, or anything else.
    spec : str
        A format spec (default ``.4f``: 4 decimals, px in the tables).

    Returns
    -------
    str
        ``value`` formatted with ``spec``; "-" for None, NaN or infinity; anything that is not a number as ``str``.

    Examples
    --------
    >>> fmt_number(0.123456), fmt_number(float("nan")), fmt_number(None)
    ('0.1235', '-', '-')
    """
    if value is None:
        return "-"
    try:
        x = float(value)
    except (TypeError, ValueError):
        return str(value)
    return format(x, spec) if math.isfinite(x) else "-"


def fmt_scientific(value: float, digits: int = 3) -> str:
    """A bound or tolerance as the prose writes it.

    Parameters
    ----------
    value : float
        The number.
    digits : int
        Significant digits of the mantissa at most.

    Returns
    -------
    str
        Mantissa without trailing zeros, unpadded exponent.

    Examples
    --------
    >>> fmt_scientific(1e-6), fmt_scientific(2.5e-5)
    ('1e-6', '2.5e-5')
    """
    mantissa, exponent = f"{float(value):.{digits - 1}e}".split("e")
    mantissa = mantissa.rstrip("0").rstrip(".")
    return f"{mantissa}e{int(exponent)}"
