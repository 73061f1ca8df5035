"""The published comparison report: circcal against OpenCV, mrcal, kornia, pycolmap and a checkerboard, on rendered
fixtures with ground truth and on real photographs.

One module per part: :mod:`~circcal.report.config` (what a run covers), the studies (:mod:`~circcal.report.paper`,
:mod:`~circcal.report.checkerboard`, :mod:`~circcal.report.bias`, :mod:`~circcal.report.realdata` with
:mod:`~circcal.report.heldout`), :mod:`~circcal.report.environment`, :mod:`~circcal.report.figures`, the document
(:mod:`~circcal.report.document` from :mod:`~circcal.report.prose`, :mod:`~circcal.report.tables`,
:mod:`~circcal.report.notes`), :mod:`~circcal.report.render` (Markdown and HTML through Jinja2 templates) and
:mod:`~circcal.report.publish` (:func:`compute`, :func:`write_report`, :func:`generate`; not named
generate.py, so that ``circcal.report.generate`` means one thing, the function).

Error conventions (every key names its own): ``mean_2d_px`` = mean of the 2-D error norm (the paper's eq. 22 and its
tables), ``rms_per_point_px`` = OpenCV's RMS, ``rms_per_coord_px`` = mrcal's. "vs truth" = RMS over a pixel grid of
the projection difference between the true camera and the calibrated one, the implied rotation fitted
(:func:`circcal.analysis.compare.projection_diff`); "centre error" = detected centres against the exact
projections of the true centres (:func:`circcal.analysis.compare.centre_errors`).
"""

from circcal.report.config import FULL, QUICK, ReportConfig
from circcal.report.publish import compute, generate, write_report

__all__ = ["FULL", "QUICK", "ReportConfig", "compute", "generate", "write_report"]
