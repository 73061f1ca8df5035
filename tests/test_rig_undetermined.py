"""A rig whose information is singular in some directions only (a rational camera whose coefficients trade off): the
parameters independent of those directions keep their marginal covariance (circcal.rig.solve.determined_covariance,
circcal.rig.undetermined.determined_rig_covariance), NaN only for the others; a regular rig is unchanged."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from circcal.commands.rig import summary_lines
from circcal.fixtures.rig import RigScenario, _board_poses, rig_observations, rig_scenario
from circcal.model import Camera
from circcal.rig import RigModel, calibrate_rig_points
from circcal.solver import CalibrationOptions


def test_the_marginal_covariance_of_an_exactly_singular_information():
    """Parameters a and b enter only as a + b (and one column is scaled 1e3, as px beside unitless coefficients):
    a and b are NaN, every other parameter's covariance is the one of the problem with a + b as one parameter."""
    from circcal.rig.solve import marginal_covariance

    rng = np.random.default_rng(4)
    Jr = rng.normal(size=(40, 5)) * np.array([1.0, 1e3, 1.0, 0.1, 1.0])  # columns: a + b, c, d, e, f
    J = np.column_stack([Jr[:, 0], Jr[:, 0], Jr[:, 1:]])  # a, b, c, d, e, f
    sigma2 = 0.3**2
    cov = marginal_covariance(J.T @ J, sigma2)
    assert cov is not None
    assert np.all(np.isnan(cov[:2])) and np.all(np.isnan(cov[:, :2]))
    exact = sigma2 * np.linalg.inv(Jr.T @ Jr)
    np.testing.assert_allclose(cov[2:, 2:], exact[1:, 1:], rtol=1e-9)
    # regular: the plain inverse
    np.testing.assert_allclose(marginal_covariance(Jr.T @ Jr, sigma2), exact, rtol=1e-9)


#: The three-camera rig of tests/test_rig_verdict.py whose middle rational camera its views cannot determine.
CAMERAS = [
    Camera(800, 600, 768.03, 766.66, 405.22, 297.87, [-0.19, 0.0815, 4.9e-4, -1.6e-4, -0.0067]),
    Camera(1280, 960, 1149.41, 1149.41, 639.0, 482.23, [-0.0268, 0.05, 1e-4, -2e-4, 0.0, -0.0434, 0, 0], "rational"),
    Camera(1280, 960, 1043.89, 1045.52, 643.71, 480.44, [0.0102, 0.0136, 3.9e-4, 1.03e-3, 0.0194]),
]


@pytest.fixture(scope="module")
def undetermined():
    rvecs = [[0, 0, 0], [-0.0301, -0.0159, 0.0013], [0.0216, -0.1278, 0.0021]]
    tvecs = [[0, 0, 0], [-80.37, 0.85, -1.70], [-160.74, 2.61, -11.30]]
    rig = RigModel(["c0", "c1", "c2"], CAMERAS, rvecs, tvecs)
    rv, tv = _board_poses(20, 213, (350.0, 650.0), 100.0, 40.0)
    tv[:, 0] += 80.37
    board = rig_scenario("two").board
    sc = RigScenario("rational-free", rig, board, tuple(f"{k:03d}" for k in range(20)), rv, tv)
    opts = {n: CalibrationOptions(lens=c.lens) for n, c in zip(rig.names, CAMERAS)}
    with pytest.warns(RuntimeWarning):
        cal = calibrate_rig_points(
            rig_observations(sc, 0.36, 438), {n: (c.width, c.height) for n, c in zip(rig.names, CAMERAS)}, opts
        )
    return rig, cal, opts


def test_what_the_views_determine_keeps_its_sigma(undetermined):
    """No covariance (the rational c1's k1..k6 trade off), yet every other parameter -- c0's and c2's intrinsics,
    c1's fx..cy, p1, p2, both poses -- has a finite sigma and lies within 4.5 of it from the truth (RMS z near 1);
    only c1's k1..k6 are NaN."""
    from circcal.rig.undetermined import determined_rig_covariance

    truth, cal, opts = undetermined
    assert cal.rig.covariance is None
    cov = determined_rig_covariance(cal, opts)
    assert cov is not None and cov.shape == (len(truth.state_vector()),) * 2
    std = np.sqrt(np.diag(cov))
    labels = [f"{n}.{p}" for n, c in zip(truth.names, CAMERAS) for p in c.model.param_names]
    labels += [f"{n}.{p}" for n in truth.names[1:] for p in ("rx", "ry", "rz", "tx", "ty", "tz")]
    unknown = {lab for lab, s in zip(labels, std) if np.isnan(s)}
    assert unknown == {f"c1.k{i}" for i in range(1, 7)}, unknown
    known = ~np.isnan(std)
    z = (cal.rig.state_vector() - truth.state_vector())[known] / std[known]
    assert np.all(np.abs(z) < 4.5), dict(zip(np.array(labels)[known], z))
    assert 0.5 < np.sqrt(np.mean(z**2)) < 1.5, np.sqrt(np.mean(z**2))
    # without the holds nothing can be rebuilt: every sigma unknown, as before
    assert determined_rig_covariance(cal, None) is None


def test_the_console_states_the_determined_sigmas(undetermined):
    """summary_lines with the options: c0's and c2's rows and both poses with finite sigmas, c1's k1..k6 nan (its
    other rows stated), c1's projection uncertainty not stated, the others' stated."""
    truth, cal, opts = undetermined
    lines = summary_lines(cal, {n: [] for n in truth.names}, opts)
    sigma: dict[str, dict[str, float]] = {}
    camera = ""
    for line in lines:
        if line.startswith("camera "):
            camera = line.split()[1].rstrip(":")
        m = re.match(r"^\s+(fx|fy|cx|cy|k\d|p\d)\s+-?[\d.]+\s+(\S+)", line)
        if m:
            sigma.setdefault(camera, {})[m.group(1)] = float(m.group(2))
    assert set(sigma) == {"c0", "c1", "c2"}
    for cam in ("c0", "c2"):
        assert all(np.isfinite(v) and v > 0 for v in sigma[cam].values()), sigma[cam]
    assert {p for p, v in sigma["c1"].items() if np.isnan(v)} == {f"k{i}" for i in range(1, 7)}, sigma["c1"]
    poses = [line for line in lines if "pose in the rig" in line]
    assert len(poses) == 2 and not any("nan" in line for line in poses), poses
    text = "\n".join(lines)
    assert "projection uncertainty of c0's intrinsics at infinity: worst" in text
    assert "projection uncertainty of c1's intrinsics: none stated (its views leave some of them undetermined" in text
    assert "projection uncertainty of c2's intrinsics at infinity: worst" in text


def test_a_regular_rig_is_unchanged():
    """The clean `two` rig: the covariance rebuilt from the calibration (its own set aside) is the solve's within
    1e-12 relative, and the console's lines are the same with the options as without."""
    from circcal.rig.undetermined import determined_rig_covariance

    sc = rig_scenario("two")
    sizes = {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    opts = {"left": CalibrationOptions(fixed=("k3",)), "right": CalibrationOptions(lens="rational")}
    cal = calibrate_rig_points(rig_observations(sc, 0.02, 2), sizes, opts)
    assert cal.rig.covariance is not None
    assert determined_rig_covariance(cal, opts) is cal.rig.covariance or np.array_equal(
        determined_rig_covariance(cal, opts), cal.rig.covariance
    )
    bare = dataclasses.replace(cal, rig=dataclasses.replace(cal.rig, covariance=None))
    rebuilt = determined_rig_covariance(bare, opts)
    assert rebuilt is not None and not np.isnan(rebuilt).any()
    C = np.asarray(cal.rig.covariance)
    assert np.max(np.abs(rebuilt - C)) <= 1e-12 * np.max(np.abs(C)), np.max(np.abs(rebuilt - C)) / np.max(np.abs(C))
    assert np.all(rebuilt[np.diag(C) == 0] == 0)  # left's k3: held
    images = {n: [] for n in sc.rig.names}
    assert summary_lines(cal, images, opts) == summary_lines(cal, images)
