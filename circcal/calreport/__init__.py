"""The report of one calibration of a user's own photographs (``circcal calibrate ... --report DIR``): a
self-contained folder with ``index.html`` and ``index.md`` (the same content; figures as PNG files beside them) and
``report.json`` (every number). It opens with a three-line verdict: the reprojection error in the three conventions,
the cross-validation verdict and the worst projection uncertainty. See :func:`circcal.calreport.document.write_report`.

Separate from :mod:`circcal.report` (the published comparison report of the rendered fixtures and references)."""

from circcal.calreport.document import write_report

__all__ = ["write_report"]
