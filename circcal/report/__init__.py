"""The published comparison report (see :mod:`circcal.report.report`)."""
from circcal.report.report import generate

__all__ = ["generate"]
