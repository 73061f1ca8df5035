"""Each rig camera's projection uncertainty (circcal.rig.uncertainty) against the spread of re-solves."""

from __future__ import annotations

import numpy as np

from circcal.analysis.diff import model_diff
from circcal.fixtures.rig import rig_observations, rig_scenario
from circcal.rig import calibrate_rig_points
from circcal.rig.uncertainty import projection_uncertainty
from circcal.solver import CalibrationOptions


def test_the_stated_projection_uncertainty_matches_the_spread_of_re_solves():
    """The `fisheye` rig (a pinhole and a fisheye) at 0.1 px noise, 16 re-solves: each camera's projection
    difference from the truth at the image centre (implied rotation fitted over the image, model_diff) against the
    stated uncertainty there. (The `two` rig's 512x384 rational camera is left out: on 1 noise draw in 16 its
    own calibration ends with a singular information matrix, the rational terms trading against each other.)"""
    sc = rig_scenario("fisheye")
    names = sc.rig.names
    sizes = {n: (c.width, c.height) for n, c in zip(names, sc.rig.cameras)}
    opts = {n: CalibrationOptions(lens=c.lens) for n, c in zip(names, sc.rig.cameras)}
    diffs = {n: [] for n in names}
    stated = {n: [] for n in names}
    for seed in range(16):
        cal = calibrate_rig_points(rig_observations(sc, 0.1, seed), sizes, opts, board=sc.board)
        unc = {u.name: u for u in projection_uncertainty(cal.rig)}
        assert set(unc) == set(names)
        for k, n in enumerate(names):
            d = model_diff(sc.rig.cameras[k], cal.rig.cameras[k])
            diffs[n].append(d.centre_px)
            stated[n].append(unc[n].centre_px)
            assert unc[n].worst_px >= unc[n].centre_px > 0
    for n in names:
        # the 2-D difference's RMS is sqrt(s1^2 + s2^2) of the two directions' sigmas, the stated one the larger
        # sigma: 1-1.41 for a right covariance. Measured over 40 draws: pinhole 1.11; fisheye 0.71 (the implied
        # rotation is fitted over other grids here and in model_diff, which weigh a fisheye's wide field
        # differently: the stated value is 1.4x conservative there); 16 draws add +-18 %
        ratio = np.sqrt(np.mean(np.square(diffs[n]))) / np.median(stated[n])
        assert 0.55 < ratio < 1.8, (n, ratio)
