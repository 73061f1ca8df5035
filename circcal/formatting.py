"""Numbers as circcal prints them (tables of validate, conformance and the reports), so a missing or non-finite
value reads "-" everywhere."""

from __future__ import annotations

import math
from typing import Any

__all__ = ["fmt_number", "fmt_scientific"]


def fmt_number(value: Any, spec: str = ".4f") -> str:
    """``value`` formatted with ``spec`` (default: 4 decimals, px in the tables); "-" for None, NaN or
    infinity; anything that is not a number as ``str``."""
    if value is None:
        return "-"
    try:
        x = float(value)
    except (TypeError, ValueError):
        return str(value)
    return format(x, spec) if math.isfinite(x) else "-"


def fmt_scientific(value: float, digits: int = 3) -> str:
    """A bound or tolerance as the prose writes it: mantissa with up to ``digits`` significant digits, unpadded
    exponent ("1e-6", "2.5e-5", "1e-4")."""
    mantissa, exponent = f"{float(value):.{digits - 1}e}".split("e")
    mantissa = mantissa.rstrip("0").rstrip(".")
    return f"{mantissa}e{int(exponent)}"
