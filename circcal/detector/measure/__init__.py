"""Measuring dots: the smoothed image and its crops (`smoothing`), edge levels and sub-pixel edges
(`levels`, `edges`, `curvature`), ellipse fits (`ellipse`, `robust`, `dots`), the projective and lens
correction of each centre (`centre`) and the checks of a labelled board and its dots (`trust`)."""
