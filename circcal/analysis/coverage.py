"""Where in the image a calibration's observations lie, and where it has none.

The map counts the observed points per cell of a grid of :data:`CELLS_ACROSS` square-ish cells across the image.
The warning rule: the image is split in thirds each way into nine regions (four corners, four edges, the centre);
a region holding fewer than :data:`MIN_POINTS_PER_REGION` observed points gets a warning, because the lens model there
is not measured but extrapolated from elsewhere (distortion grows fastest toward the corners, where it is least often
observed). Pixels follow OpenCV's convention (integer coordinates are pixel centres).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Coverage", "coverage", "CELLS_ACROSS", "MIN_POINTS_PER_REGION", "REGIONS"]

#: Cells across the image in the coverage map (rows keep the cells about square).
CELLS_ACROSS = 16
#: A region (a ninth of the image) with fewer observed points than this is reported as not covered: one view of a
#: board corner there already pins the distortion down locally.
MIN_POINTS_PER_REGION = 1
#: The nine regions, row by row from the top.
REGIONS = (
    ("top-left corner", "top edge", "top-right corner"),
    ("left edge", "centre", "right edge"),
    ("bottom-left corner", "bottom edge", "bottom-right corner"),
)


@dataclass
class Coverage:
    """Where in the image the observations lie.

    Attributes
    ----------
    width, height : int
        The image, px.
    counts : ndarray of int, shape (rows, CELLS_ACROSS)
        Observed points per cell.
    region_counts : dict of str to int
        {region: points}.
    empty : list of dict
        The regions below :data:`MIN_POINTS_PER_REGION`, each with its pixel bounds.
    covered_share : float
        The share of map cells holding a point.
    warnings : list of str
        One sentence per empty region.
    """

    width: int
    height: int
    counts: np.ndarray
    region_counts: dict[str, int]
    empty: list[dict[str, Any]]
    covered_share: float
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary, with the rule in words.

        Returns
        -------
        dict
            ``cells_across``, ``counts``, ``region_counts``, ``empty_regions``, ``covered_share``, ``warnings``, ``rule``.
        """
        return {
            "cells_across": int(self.counts.shape[1]),
            "counts": self.counts.tolist(),
            "region_counts": dict(self.region_counts),
            "empty_regions": self.empty,
            "covered_share": self.covered_share,
            "warnings": list(self.warnings),
            "rule": f"each ninth of the image (thirds each way) needs at least {MIN_POINTS_PER_REGION} observed "
            f"point(s); elsewhere the lens model is extrapolated",
        }


def coverage(image_points: Sequence[np.ndarray], width: int, height: int) -> Coverage:
    """The coverage of observations over an image.

    Parameters
    ----------
    image_points : sequence of ndarray, each shape (N_v, 2)
        Per view, px (non-finite rows are left out).
    width, height : int
        The image, px.

    Returns
    -------
    Coverage
    """
    pts = (
        np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in image_points])
        if len(image_points)
        else np.zeros((0, 2))
    )
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    nx = CELLS_ACROSS
    ny = max(1, int(round(nx * height / width)))
    cx = np.clip(((pts[:, 0] + 0.5) * nx // width).astype(int), 0, nx - 1)
    cy = np.clip(((pts[:, 1] + 0.5) * ny // height).astype(int), 0, ny - 1)
    counts = np.zeros((ny, nx), dtype=int)
    np.add.at(counts, (cy, cx), 1)
    rc = np.clip(((pts[:, 0] + 0.5) * 3 // width).astype(int), 0, 2)
    rr = np.clip(((pts[:, 1] + 0.5) * 3 // height).astype(int), 0, 2)
    region_counts, empty, warnings = {}, [], []
    for r in range(3):
        for c in range(3):
            name = REGIONS[r][c]
            n = int(np.sum((rr == r) & (rc == c)))
            region_counts[name] = n
            if n < MIN_POINTS_PER_REGION:
                x0, x1 = c * width / 3 - 0.5, (c + 1) * width / 3 - 0.5
                y0, y1 = r * height / 3 - 0.5, (r + 1) * height / 3 - 0.5
                empty.append({"region": name, "x_px": [x0, x1], "y_px": [y0, y1]})
                what = (
                    "distortion there is extrapolated"
                    if name != "centre"
                    else "the principal point region is extrapolated"
                )
                # the image's edge is at -0.5 (pixel centres are integers): printed from pixel 0, not "-0"
                a, b = max(x0, 0.0), max(y0, 0.0)
                warnings.append(f"nothing in the {name} (x {a:.0f}..{x1:.0f} px, y {b:.0f}..{y1:.0f} px): {what}")
    return Coverage(width, height, counts, region_counts, empty, float(np.mean(counts > 0)), warnings)
