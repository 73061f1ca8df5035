"""Are the rig's stated sigmas honest? >= 100 re-solves of a rig (``calibrate_rig_points``: each camera's own start,
the pairwise start, the joint solve) on projected observations with Gaussian pixel noise, one seed per draw; the
stated sigma of every camera's fx, fy, cx, cy and of camera 1's pose in the rig (rvec components, rad; T, mm)
against the estimates' errors. Issue 37's bar: each ratio within 0.8-1.25x, measured two ways. ``make study``
(marker ``slow``); the table is printed (``-s``).

* pooled: the RMS over the draws of ``RigCalibration.std()`` against the spread (standard deviation) of the
  estimates -- one number for the study, dominated by the draws that state the largest sigmas;
* per draw: each draw's error from the truth in units of its own stated sigma, ``z = (estimate - truth) / sigma``;
  its stated sigma is honest when ``z`` has unit spread (the ratio printed is ``1 / std(z)``). This is what one
  user with one calibration relies on; where the stated sigma is the same in every draw the two agree.

The scenarios are ``fisheye`` (a 640x480 pinhole opencv5 camera and a fisheye) at 0.1 px and ``mixed`` (the same
with its pinhole camera at 800x600: two sizes, two lens models, partial views in one camera): on ``two`` the rational
camera's own calibration (the start of every rig solve) is refused on some draws (its k1, k2, k4, k5 trade off:
4 of 40 draws at 0.1 px, 1 of 40 at 0.02 px), so a study there measures only the draws that happen to
succeed. ``two`` is measured at 0.02 px as well, with the draws that fail counted and left out (11-14 of 100):
its pinhole camera, the rational camera's principal point and the rig pose are honest both ways; the rational
camera's fx and fy are honest per draw (1 / std(z) 0.96) but not pooled (1.8x): their stated sigma differs between
draws (0.059-0.071 px in three draws of four; above 0.1 px in 10 of 89, up to 1.9 px, where the rational
coefficients land on a flatter stretch of their valley), and the pooled RMS is those few draws'.

Why (measured 2026-12-06 over the same 100 draws): the stated sigma of ``right.fx`` rises with how far the fitted
rational denominator ``1 + k4 r^2 + k5 r^4 + k6 r^6`` grows over the observed field (the truth's: to 1.25):
0.059-0.067 px where it stays below 5 (62 draws), 0.07-0.10 at 5-50, 0.12-0.19 at 60-150, 0.34-1.9 at 200-2800.
There k1 and k4 run into the thousands, numerator and denominator nearly proportional: their constant terms no
longer count, so the lens's magnification near the axis (k1 / k4) trades with fx, and the cost still falls, slowly,
along that direction (seed 1093 continued to 2000 iterations: fx 428 px, 22 px from the truth, its cost 2.4e-4
lower). Over the 72 draws whose denominator stays below 20 the pooled ratio is 0.91 (per draw 0.90); no such
threshold can be a verdict: on OpenCV's real three-camera data the rational fits grow 14-34-fold over their wider
field (r to 1.5), as real lenses do. The first-order sigma there is honest for that draw, not for the study.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from circcal.errors import CalibrationError
from circcal.fixtures.rig import RigScenario, rig_observations, rig_scenario
from circcal.model import Camera
from circcal.rig import calibrate_rig_points
from circcal.rig.model import RigModel
from circcal.solver import CalibrationOptions

pytestmark = pytest.mark.slow

DRAWS = 100
LOW, HIGH = 0.8, 1.25
#: The ``two`` rig's rational camera's focal lengths (see the module and the xfail below).
RATIONAL_FOCAL = ("right.fx", "right.fy")


def _rows(sc) -> tuple[list[int], list[str]]:
    """The state rows compared (fx, fy, cx, cy of every camera, then camera 1's rvec and tvec) and their labels."""
    rows, labels, start = [], [], 0
    for name, cam in zip(sc.rig.names, sc.rig.cameras):
        rows += [start, start + 1, start + 2, start + 3]
        labels += [f"{name}.{p}" for p in ("fx", "fy", "cx", "cy")]
        start += len(cam.intrinsics)
    rows += list(range(start, start + 6))
    labels += [f"{sc.rig.names[1]}.{p}" for p in ("rx", "ry", "rz", "tx", "ty", "tz")]
    return rows, labels


def _study(scenario: str | RigScenario, noise_px: float, draws: int = DRAWS):
    """(labels, stated (K,), spread (K,), failed draws, estimates (D, K), truth (K,), per-draw ratio 1 / std(z) (K,))
    over ``draws`` seeds of a scenario (by name, or given)."""
    sc = rig_scenario(scenario) if isinstance(scenario, str) else scenario
    name = sc.name
    rows, labels = _rows(sc)
    sizes = {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    opts = {n: CalibrationOptions(lens=c.lens) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    est, std, failed = [], [], []
    for seed in range(draws):
        obs = rig_observations(sc, noise_px, 1000 + seed)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a camera's own start that hit its limit
                res = calibrate_rig_points(obs, sizes, opts, board=sc.board)
        except CalibrationError as exc:
            failed.append((seed, str(exc).splitlines()[0]))
            continue
        s = res.std()[rows]
        if not res.converged:
            failed.append((seed, "the joint solve did not converge"))
            continue
        if not np.all(np.isfinite(s)):
            failed.append((seed, "no covariance: the information matrix is singular"))
            continue
        est.append(res.rig.state_vector()[rows])
        std.append(s)
    est_a, std_a = np.array(est), np.array(std)
    truth = sc.rig.state_vector()[rows]
    stated = np.sqrt(np.mean(std_a**2, axis=0))
    spread = np.std(est_a, axis=0, ddof=1)
    per_draw = 1.0 / np.std((est_a - truth) / std_a, axis=0, ddof=1)
    print(f"\n{name} rig, {noise_px} px, {len(est)} of {draws} draws ({len(failed)} failed)")
    print(f"{'parameter':12s} {'stated':>10s} {'spread':>10s} {'pooled':>7s} {'per draw':>8s}")
    for lab, a, b, c in zip(labels, stated, spread, per_draw):
        print(f"{lab:12s} {a:10.3e} {b:10.3e} {a / b:7.3f} {c:8.3f}")
    return labels, stated, spread, failed, est_a, truth, per_draw


def _outside(labels: list[str], ratio: np.ndarray) -> dict[str, float]:
    """The parameters whose ratio is outside LOW..HIGH."""
    return {lab: round(float(r), 3) for lab, r in zip(labels, ratio) if not LOW <= r <= HIGH}


def test_rig_sigmas_honest_over_monte_carlo():
    labels, stated, spread, failed, est, truth, per_draw = _study("fisheye", 0.1)
    assert not failed and len(est) >= 100
    assert not _outside(labels, stated / spread), _outside(labels, stated / spread)
    assert not _outside(labels, per_draw), _outside(labels, per_draw)
    # and the estimates centre on the truth: the mean within 4 standard errors
    z = (est.mean(axis=0) - truth) / (spread / np.sqrt(len(est)))
    assert np.all(np.abs(z) < 4), dict(zip(labels, np.round(z, 2)))


def _mixed() -> RigScenario:
    """``fisheye`` with its pinhole camera at 800x600 (f 700 px: the same field): two image sizes, two lens models
    (opencv5 and fisheye), and partial views (7 of the pinhole camera's 14)."""
    base = rig_scenario("fisheye")
    pinhole = Camera(800, 600, 700.0, 700.0, 399.5, 299.5, [-0.1, 0.05, 0.0, 0.0, 0.0])
    rig = RigModel(base.rig.names, [pinhole, base.rig.cameras[1]], base.rig.rvecs, base.rig.tvecs)
    return RigScenario("mixed", rig, base.board, base.instants, base.board_rvecs, base.board_tvecs)


def test_sizes_lenses_and_partial_views_together_sigmas_honest():
    # the rig: cameras of different sizes and lens models, with partial views; measured 2026-12-05: every
    # ratio 0.84-1.12 over 100 of 100 draws (T_y 0.84, T_z 0.88, rz 1.12)
    sc = _mixed()
    sizes = {(c.width, c.height) for c in sc.rig.cameras}
    partial = sum(bool(np.isnan(uv).any()) for uv in sc.truth_points()["pinhole"].values())
    assert len(sizes) == 2 and {c.lens for c in sc.rig.cameras} == {"opencv5", "fisheye"} and partial >= 5
    labels, stated, spread, failed, est, truth, per_draw = _study(sc, 0.1)
    assert not failed and len(est) >= 100
    assert not _outside(labels, stated / spread), _outside(labels, stated / spread)
    assert not _outside(labels, per_draw), _outside(labels, per_draw)
    z = (est.mean(axis=0) - truth) / (spread / np.sqrt(len(est)))
    assert np.all(np.abs(z) < 4), dict(zip(labels, np.round(z, 2)))


@pytest.fixture(scope="module")
def two_study():
    return _study("two", 0.02)


def test_two_rig_sigmas_over_monte_carlo(two_study):
    labels, stated, spread, failed, est, _, per_draw = two_study
    # measured 11-14 of 100 lost, each said: the rational camera's own calibration refused (4), the joint solve not
    # converged or its information matrix singular (10) -- never a wrong rig without a word
    assert len(failed) <= 0.15 * DRAWS, failed
    assert all(why.startswith(("camera 'right'", "the joint solve", "no covariance")) for _, why in failed), failed
    pooled = _outside(labels, stated / spread)
    assert set(pooled) <= set(RATIONAL_FOCAL), pooled  # those two: the strict xfail below
    # per draw every parameter, the rational camera's focal lengths included (measured 2026-12-05 over 89 draws:
    # 0.92-1.14; right.fx 0.96, right.fy 0.96)
    assert not _outside(labels, per_draw), _outside(labels, per_draw)


@pytest.mark.xfail(
    strict=True,
    reason="pooled, measured on `two` at 0.02 px (89 draws): the rational camera's stated fx sigma is 0.059-0.071 "
    "px in three draws of four and above 0.1 px in 10 (up to 1.9 px; spread 0.14 px), so its RMS over the "
    "draws is 1.8x the spread; per draw it is honest (errors in units of their own sigma: spread 1.05, "
    "test_two_rig_sigmas_over_monte_carlo): the low-sigma half's errors 1.16 sigmas RMS, the high half's 0.87",
)
def test_two_rig_rational_focal_sigma_honest(two_study):
    labels, stated, spread, *_ = two_study
    ratio = dict(zip(labels, stated / spread))
    assert all(LOW <= ratio[k] <= HIGH for k in RATIONAL_FOCAL), ratio
