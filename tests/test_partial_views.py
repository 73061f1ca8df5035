"""Issue 13: the partial corner views pin what full views cannot. On the ``markers`` scenario (pattern-marker 7x7
board, 640x480, k1 -0.15), calibrating from its 14 full views plus its 8 corner views (15-40 % of the dot grid out
of frame) lowers the projection difference to the true camera in the image corners against the 14 full views alone;
so does trading 8 of the full views for the 8 corner views (14 views either way: the gain is not the view count).
The factors are published in reports/partial-views.md."""

from __future__ import annotations

import numpy as np
import pytest

from circcal.analysis.compare import projection_diff
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.truth import load_truth
from circcal.pipeline import calibrate_images

CORNER_SHARE = 1.0 / 3.0
"""The image corners: grid points beyond this share of the half-width and of the half-height from the centre
(the four corner ninths of the image)."""
MIN_FACTOR = 1.5
"""The corner RMS of the full views over that of full + corner views is at least this (measured 2.0 clean,
5.7 with noise; 6 full + 8 corner views against 14 full: 3.8 and 6.1)."""


def corner_rms(truth_camera, camera) -> tuple[float, float]:
    """(RMS px in the image corners, RMS px over the whole image) of the projection difference of ``camera`` to
    ``truth_camera`` (rays at infinity, implied rotation fitted as mrcal does; a 40-point-wide pixel grid)."""
    pd = projection_diff(truth_camera, camera, fit=True, gridn_width=40)
    uv, d = pd["uv"], pd["diff"]
    w, h = truth_camera.width, truth_camera.height
    corner = (np.abs(uv[:, 0] - (w - 1) / 2) > CORNER_SHARE * w) & (np.abs(uv[:, 1] - (h - 1) / 2) > CORNER_SHARE * h)
    return float(np.sqrt(np.mean(d[corner] ** 2))), float(pd["rms_px"])


@pytest.mark.parametrize("variant", ["clean", "noise"])
def test_corner_views_lower_the_corner_projection_error(variant):
    tr = load_truth(fixture_dir("markers", variant))
    full = [v.image for v in tr.views if v.kind == "full"]
    every = [v.image for v in tr.views]
    assert len(full) == 14 and len(every) == 22
    traded = full[:6] + every[14:]
    res = {}
    for name, paths in (("full", full), ("full+corner", every), ("traded", traded)):
        cal = calibrate_images(paths, tr.board, progress=False, jobs=1)
        assert len(cal.used) == len(paths), [r.reason for r in cal.failed]  # every partial view is used
        res[name] = corner_rms(tr.camera, cal.result.camera)
    factor = res["full"][0] / res["full+corner"][0]
    traded_factor = res["full"][0] / res["traded"][0]
    print(
        f"\nmarkers/{variant}: projection difference to the true camera, corners / whole image: 14 full views "
        f"{res['full'][0]:.4f} / {res['full'][1]:.4f} px, + 8 corner views {res['full+corner'][0]:.4f} / "
        f"{res['full+corner'][1]:.4f} px (corner factor {factor:.2f}x); 6 full + 8 corner views "
        f"{res['traded'][0]:.4f} / {res['traded'][1]:.4f} px (corner factor {traded_factor:.2f}x)"
    )
    assert factor >= MIN_FACTOR and traded_factor >= MIN_FACTOR
