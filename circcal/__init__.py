"""circcal: circle-grid camera calibration with unbiased circle-centre projections."""

__version__ = "0.1.0"
