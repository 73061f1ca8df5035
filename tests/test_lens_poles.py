"""A rational lens whose numerator and denominator trade off: undistortion at its rounding floor, and the verdict on a
fit with a pole, or nearly one, in the field its views observed (circcal/solver/lensfield.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from circcal.fixtures.rig import rig_observations, rig_scenario
from circcal.model import Camera, denominator_minimum, distort, undistort
from circcal.rig import calibrate_rig_points
from circcal.rig.calibrate import lens_poles
from circcal.rig.model import RigModel
from circcal.rig.verdict import RigVerdict
from circcal.solver import CalibrationOptions
from circcal.solver.lensfield import NEAR_POLE, pole_in_field, result_pole


def _common_factor(a: float) -> np.ndarray:
    """One lens written with a common factor (1 + a r^2) in numerator and denominator: k1..k6 differ for every a,
    the lens does not (its quadratic numerator 1 - 0.2 s + 0.05 s^2 and denominator 1 + 0.1 s + 0.02 s^2, s = r^2)."""
    k1, k2, k4, k5 = -0.2, 0.05, 0.1, 0.02
    return np.array([k1 + a, k2 + a * k1, 1e-4, -2e-4, a * k2, k4 + a, k5 + a * k4, a * k5])


def test_one_lens_written_with_a_near_pole_undistorts_like_its_plain_form():
    # a < 0 puts a zero of both numerator and denominator at s = -1/a: for -2.75 and -2.77 at r 0.603 and 0.601,
    # just beyond the points (r <= 0.6), where both nearly vanish and evaluating the distortion rounds at 1e-15 to
    # 1e-14, above undistort's tolerance: points no step could improve came back NaN (13 and 34 of 1200 before)
    r = np.linspace(0.0, 0.6, 25)
    t = np.linspace(0.0, 2 * np.pi, 48, endpoint=False)
    x = np.stack([np.outer(r, np.cos(t)).ravel(), np.outer(r, np.sin(t)).ravel()], axis=1)
    xd = distort(x, _common_factor(0.0))
    for a in (30.0, 300.0, -2.0, -2.75, -2.77):
        d = _common_factor(a)
        assert np.allclose(distort(x, d), xd, atol=1e-12)  # the same lens
        back = undistort(xd, d)
        assert np.all(np.isfinite(back)), a
        assert np.max(np.abs(back - x)) < 1e-12, a


@pytest.mark.parametrize(
    ("dist", "xd"),
    [  # two fits of the `two` rig's rational camera (re-solves from 0.1 px noise) and pixels they observed
        (
            [-16.555982420209848, 72.56918414925647, 0.0003691500561366777, 0.0004462483056574139, 7.8668253863944395,
             -16.26411036900119, 67.70474346333026, 29.58609519299418],
            [[0.31090815600724414, -0.16604513041464905], [0.01103585679472224, 0.3450240222459458]],
        ),
        (
            [-10.583446857012547, 29.773899564525273, 0.00018260441254872313, 0.000767973480705351,
             3.3628480703717742, -10.291550792864038, 26.65619438099431, 12.376761995078978],
            [[-0.39668773535154356, 0.005388492807307387]],
        ),
    ],
)  # fmt: skip
def test_fitted_lenses_invert_at_their_rounding_floor(dist, xd):
    xd = np.array(xd)
    back = undistort(xd, dist)
    assert np.all(np.isfinite(back))
    assert np.max(np.abs(distort(back, dist) - xd)) < 1e-13


def test_the_denominators_minimum_over_the_field():
    assert denominator_minimum([0.1, 0.0, 0.0, 0.0, 0.0], 1.0) == (1.0, 0.0)  # opencv5: no denominator
    # 1 - 4 s + 4 s^2 = (1 - 2 s)^2: its minimum 0 at s = 1/2 inside r <= 0.8, and 1 - 0.8 * 4 + ... at the edge
    value, r = denominator_minimum([0.0, 0.0, 0.0, 0.0, 0.0, -4.0, 4.0, 0.0], 0.8)
    assert value == pytest.approx(0.0, abs=1e-15) and r == pytest.approx(np.sqrt(0.5))
    value, r = denominator_minimum([0.0, 0.0, 0.0, 0.0, 0.0, -4.0, 4.0, 0.0], 0.5)  # s <= 0.25: the edge
    assert value == pytest.approx(1.0 - 1.0 + 0.25) and r == pytest.approx(0.5)
    value, _ = denominator_minimum([0.0] * 5 + [-3.0, 0.0, 0.0], 0.7)  # 1 - 3 s crosses zero at s = 1/3
    assert value < 0


def _camera(dist) -> Camera:
    return Camera(512, 384, 450.0, 449.0, 253.1, 195.6, dist, "rational")


def test_a_pole_or_near_pole_in_the_observed_field_is_named_with_its_angle():
    points = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 1.0]])  # observed out to atan(0.6) = 31.0 deg
    through = pole_in_field(_camera([0.0] * 5 + [-3.0, 0.0, 0.0]), points)  # zero at r = 0.577: 30.0 deg
    assert through is not None and "vanishes 30.0 deg off the optical axis" in through and "out to 31.0 deg" in through
    assert "opencv5" in through
    near = pole_in_field(_camera([0.0] * 5 + [-4.0, 4.0 + 1e-2 / 0.25, 0.0]), points)  # min 0.01 at r = 0.707
    assert near is None  # beyond the observed field
    k5 = 4.0 / (1.0 - 0.5 * NEAR_POLE)  # 1 - 4 s + k5 s^2: minimum 1 - 4 / k5 = NEAR_POLE / 2 at s = 2 / k5, r 0.70
    near = pole_in_field(_camera([0.0] * 5 + [-4.0, k5, 0.0]), np.array([[0.75, 0.0, 1.0]]))
    assert near is not None and "falls to 0.025 (1 on the axis)" in near
    assert pole_in_field(_camera([0.4, -0.1, 0.0, 0.0, 0.01, 0.7, -0.05, 0.02]), points) is None  # a real lens
    fisheye = Camera(640, 480, 260.0, 260.5, 322.0, 241.0, [0.02, -0.01, 0.004, -0.001], "fisheye")
    assert pole_in_field(fisheye, points) is None


class _Result:
    """What result_pole reads of a CalibrationResult."""

    def __init__(self, camera: Camera):
        self.camera = camera
        self.object_points = [np.array([[0.0, 0.0, 0.0], [60.0, 0.0, 0.0]])]
        self.rvecs = np.zeros((1, 3))
        self.tvecs = np.array([[0.0, 0.0, 100.0]])  # the second point 31.0 deg off axis


def test_a_calibrations_own_views_decide_its_field():
    assert "vanishes 30.0 deg" in result_pole(_Result(_camera([0.0] * 5 + [-3.0, 0.0, 0.0])))
    assert result_pole(_Result(_camera([0.0] * 5 + [-2.0, 0.0, 0.0]))) is None  # the zero at 35.3 deg lies beyond


def test_the_rig_verdict_names_the_camera_whose_lens_has_a_pole():
    sc = rig_scenario("two")
    sizes = {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    opts = {n: CalibrationOptions(lens=c.lens) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    cal = calibrate_rig_points(rig_observations(sc, 0.02, 0), sizes, opts, board=sc.board)
    assert lens_poles(cal) == {}  # the fit of the true lens (denominator >= 1)
    right = cal.rig.cameras[1]
    # a pole at r = 0.5 (26.6 deg): inside what the right camera observed (out to ~34 deg)
    bad = Camera.from_intrinsics(right.width, right.height, np.r_[right.intrinsics[:9], -4.0, 0.0, 0.0], "rational")
    rig = RigModel(cal.rig.names, [cal.rig.cameras[0], bad], cal.rig.rvecs, cal.rig.tvecs)
    poles = lens_poles(replace(cal, rig=rig))
    assert list(poles) == ["right"] and "vanishes 26.6 deg off the optical axis" in poles["right"]
    lines = RigVerdict("consistent", None, [], poles).lines()
    assert lines[-1].startswith("  camera 'right': the rational lens's denominator")
