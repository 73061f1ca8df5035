"""The sigma calibrate-rig states for a camera's rotation in the rig (console and report share the line): that of the
rotation error about its worst axis and about each axis, not of the angle alone. On a camera rolled 90 deg the angle
is known some ten times better than the axis: the angle's sigma alone understated the error ~10x."""

from __future__ import annotations

import dataclasses
import re

import cv2
import numpy as np

from circcal.commands.rig import summary_lines
from circcal.fixtures.rig import rig_observations, rig_scenario
from circcal.rig import RigModel, calibrate_rig_points
from circcal.rotation import rodrigues, rotation_log
from circcal.solver import CalibrationOptions

DRAWS = 30
NOISE_PX = 0.05


def _rolled():
    """The `fisheye` rig with its fisheye turned 90 deg about its own optical axis."""
    sc = rig_scenario("fisheye")
    Rz = rodrigues(np.array([0.0, 0.0, np.pi / 2]))
    R, T = sc.rig.pose(1)
    rig = RigModel(
        list(sc.rig.names), list(sc.rig.cameras), [np.zeros(3), cv2.Rodrigues(Rz @ R)[0].ravel()], [np.zeros(3), Rz @ T]
    )
    return dataclasses.replace(sc, rig=rig)


def test_the_stated_rotation_sigma_matches_the_rotation_error():
    """30 noise draws: the rotation error against the truth about each axis over the stated per-axis sigma has an
    RMS within 0.5-1.5 (0.84, 0.82, 0.64 here; 0.94, 0.90, 0.81 over 100 draws; over the angle's sigma alone ~6 for
    x and y), the worst-axis sigma bounds every draw's error components within 4.5 of it, and the line states the
    angle, 90 deg."""
    sc = _rolled()
    names = list(sc.rig.names)
    sizes = {n: (c.width, c.height) for n, c in zip(names, sc.rig.cameras)}
    opts = {"pinhole": CalibrationOptions(), "fish": CalibrationOptions(lens="fisheye")}
    z_axes, z_worst = [], []
    for seed in range(DRAWS):
        cal = calibrate_rig_points(rig_observations(sc, NOISE_PX, seed), sizes, opts)
        text = "\n".join(summary_lines(cal, {n: [] for n in names}))
        first = re.search(r"rotation ([\d.]+)(?: deg)? \+- ([\d.e-]+) deg", text)
        assert first is not None, text
        assert abs(float(first.group(1)) - 90.0) < 0.5
        err = np.degrees(rotation_log(cal.rig.pose(1)[0] @ sc.rig.pose(1)[0].T))  # in fish's frame
        z_worst.append(np.max(np.abs(err)) / float(first.group(2)))
        axes = re.search(r"about fish's x, y, z: ([\d.e-]+), ([\d.e-]+), ([\d.e-]+) deg", text)
        z_axes.append(None if axes is None else err / np.array([float(axes.group(k)) for k in (1, 2, 3)]))
    assert max(z_worst) < 4.5, max(z_worst)
    assert all(z is not None for z in z_axes), text
    rms = np.sqrt(np.mean(np.square(z_axes), axis=0))
    assert np.all((rms > 0.5) & (rms < 1.5)), rms
