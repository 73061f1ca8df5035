"""Observations checked once (circcal/observations.py): the same view given twice."""

from __future__ import annotations

import numpy as np
import pytest


def test_same_views_are_the_same_points_at_the_same_pixels():
    from circcal.observations import SAME_VIEW_PX, same_views

    rng = np.random.default_rng(0)
    a = rng.uniform(0, 600, (20, 2))
    moved = a + [0.3, 0.0]  # the camera moved by 0.3 px: another view
    noisy = a + rng.normal(0, 0.002, a.shape)  # a re-encode's or the sensor noise's change
    part = a.copy()
    part[:6] = np.nan  # 14 of 20 points: not the same view, whatever their pixels
    assert same_views([a, moved, noisy, part]) == {2: (0, pytest.approx(0.0028, abs=0.001))}
    assert 0.0028 < SAME_VIEW_PX < 0.3
    assert same_views([a, a, a]) == {1: (0, 0.0), 2: (0, 0.0)}  # each repeat named after the first view
