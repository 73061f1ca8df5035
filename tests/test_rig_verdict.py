"""The rig's verdict (circcal.rig.verdict): cross-validation on two halves of the instants, outlier views, coverage.

On the rig scenario "two" (a 640x480 opencv5 camera and a 512x384 rational one) projected through the true rig with
Gaussian pixel noise: the clean rig is consistent; a lens model too simple, a rig that moved between the halves, a
half of one camera's images shifted, and one noisy view are each named."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from circcal.analysis.compare import pixel_grid
from circcal.analysis.diff import model_diff
from circcal.fixtures.rig import rig_observations, rig_scenario, rig_variant_observations
from circcal.model import Camera
from circcal.rig import RigModel, calibrate_rig_points
from circcal.rig.verdict import (
    POSE_LIMIT,
    camera_coverage,
    cross_validate_rig,
    pose_check,
    rig_verdict,
    rotation_free_stdev,
    shared_coverage,
    split_instants,
    view_outliers,
)
from circcal.solver import CalibrationOptions

NOISE_PX = 0.02
OPTIONS = {"left": CalibrationOptions(), "right": CalibrationOptions(lens="rational")}


@pytest.fixture(scope="module")
def scenario():
    return rig_scenario("two")


def _sizes(sc):
    return {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}


def _halves(obs):
    return split_instants({n: list(per) for n, per in obs.items()})


@pytest.fixture(scope="module")
def clean(scenario):
    obs = rig_observations(scenario, NOISE_PX, seed=2)
    cal = calibrate_rig_points(obs, _sizes(scenario), OPTIONS)
    return cal, rig_verdict(cal, OPTIONS)


def test_split_instants_halves_every_camera():
    inst = {"a": [f"{k:02d}" for k in range(12)], "b": [f"{k:02d}" for k in range(3, 12)], "c": ["00", "05", "07"]}
    h0, h1 = split_instants(inst)
    assert not set(h0) & set(h1) and set(h0) | set(h1) == set(inst["a"])
    for per in inst.values():
        assert abs(len(set(per) & set(h0)) - len(set(per) & set(h1))) <= 1, per
    assert h0 == sorted(h0) and h1 == sorted(h1)


def test_clean_rig_is_consistent(clean):
    cal, v = clean
    assert v.verdict == "consistent", v.lines()
    assert v.cross.status == "ok" and v.cross.verdict == "consistent"
    assert set(v.cross.projections) == {"left", "right"} and [p.camera for p in v.cross.poses] == ["right"]
    assert all(d.consistent for d in v.cross.projections.values())
    assert v.cross.poses[0].mahalanobis < POSE_LIMIT
    assert not v.outliers
    assert v.lines()[0].startswith("verdict: consistent")
    # the halves are disjoint, each calibrated on its own instants only
    h0, h1 = v.cross.halves
    assert not set(h0) & set(h1) and set(h0) | set(h1) == set(cal.board_poses)
    for half, r in zip((h0, h1), v.cross.rigs):
        assert set(r.board_poses) == set(half)
    d = v.to_dict()
    assert d["verdict"] == "consistent" and d["cross_validation"]["poses"][0]["camera"] == "right"


def test_lens_model_too_simple_is_a_model_problem(scenario):
    """The rational camera fitted as opencv5 with k2 and k3 held: the halves' projections of that camera disagree."""
    opts = {"left": CalibrationOptions(), "right": CalibrationOptions.from_flags(fix_k2=True, fix_k3=True)}
    cal = calibrate_rig_points(rig_observations(scenario, NOISE_PX, seed=2), _sizes(scenario), opts)
    v = rig_verdict(cal, opts)
    assert v.verdict == "model-or-data-problem"
    assert not v.cross.projections["right"].consistent
    text = "\n".join(v.lines())
    assert "camera right: the halves' projections differ" in text and "lens model too simple" in text


def test_a_rig_that_moved_between_the_halves_is_named(scenario):
    """The right camera turned by 0.3 deg for the instants of the second half: its pose disagrees."""
    obs = rig_observations(scenario, NOISE_PX, seed=3)
    _, h1 = _halves(obs)
    rv = scenario.rig.rvecs.copy()
    rv[1] += [0.0, np.radians(0.3), 0.0]
    moved = dataclasses.replace(
        scenario, rig=RigModel(scenario.rig.names, scenario.rig.cameras, rv, scenario.rig.tvecs)
    )
    other = rig_observations(moved, NOISE_PX, seed=3)
    for v in h1:
        if v in obs["right"] and v in other["right"]:
            obs["right"][v] = other["right"][v]
    cal = calibrate_rig_points(obs, _sizes(scenario), OPTIONS)
    verdict = rig_verdict(cal, OPTIONS)
    assert verdict.verdict == "model-or-data-problem"
    (pose,) = verdict.cross.poses
    assert not pose.consistent and pose.mahalanobis > 1.5 * POSE_LIMIT and 0.2 < pose.rotation_deg < 0.45
    assert "the cameras moved against each other" in "\n".join(verdict.lines())


def test_a_zoomed_half_is_a_data_problem(scenario):
    """The right camera's points of one half scaled by 0.5% about its principal point (the zoom or focus changed
    during the capture): the halves' projections of that camera disagree."""
    obs = rig_observations(scenario, NOISE_PX, seed=3)
    _, h1 = _halves(obs)
    cam = scenario.rig.cameras[1]
    c = np.array([cam.cx, cam.cy])
    for v in h1:
        if v in obs["right"]:
            P, q = obs["right"][v]
            obs["right"][v] = (P, c + 1.005 * (q - c))
    cal = calibrate_rig_points(obs, _sizes(scenario), OPTIONS)
    v = rig_verdict(cal, OPTIONS)
    assert v.verdict == "model-or-data-problem" and v.cross.verdict == "model-or-data-problem"
    assert not v.cross.projections["right"].consistent
    assert any(p.startswith("camera right:") for p in v.cross.problems())


def test_a_noisy_view_is_an_outlier_named(scenario):
    obs = rig_observations(scenario, NOISE_PX, seed=5)
    bad = sorted(obs["right"])[3]
    P, q = obs["right"][bad]
    obs["right"][bad] = (P, q + np.random.default_rng(1).normal(0.0, 20 * NOISE_PX, q.shape))
    cal = calibrate_rig_points(obs, _sizes(scenario), OPTIONS)
    outliers = view_outliers(cal)
    assert [(o.camera, o.instant) for o in outliers] == [("right", bad)]
    assert outliers[0].ratio > 3
    v = rig_verdict(cal, OPTIONS, cross_validate=False)
    assert v.verdict == "model-or-data-problem" and v.cross is None
    assert f"right {bad}: RMS per point" in "\n".join(v.lines())


def test_too_few_instants_and_skipped(scenario, clean):
    obs = rig_observations(scenario, NOISE_PX, seed=6)
    keep = sorted(set(obs["left"]) & set(obs["right"]))[:5]
    few = {n: {v: per[v] for v in keep} for n, per in obs.items()}
    simple = CalibrationOptions()  # (the rational model is not determined by 5 views of the right camera alone)
    cal = calibrate_rig_points(few, _sizes(scenario), simple)
    cv = cross_validate_rig(cal, simple)
    assert cv.status == "too-few-instants" and cv.verdict is None and "5 instants" in cv.message
    v = rig_verdict(cal, simple)
    assert v.verdict == "not-checked" and v.lines()[0].startswith("verdict: not cross-validated: not done")
    skipped = rig_verdict(clean[0], OPTIONS, cross_validate=False)
    assert skipped.verdict == "not-checked" and "--no-cross-validate" in skipped.lines()[0]


@pytest.mark.parametrize("lens", ["opencv5", "rational", "fisheye"])
def test_rotation_free_stdev_is_the_spread_of_model_diff(lens):
    """Intrinsics drawn from a covariance: the RMS of model_diff's difference (the implied rotation fitted) per
    pixel lies between the predicted worst-direction sigma and sqrt(2) times it (the 2-D norm of two directions)."""
    cams = {c.lens: c for name in ("two", "fisheye") for c in rig_scenario(name).rig.cameras}
    cam = cams[lens]
    rng = np.random.default_rng(0)
    p = len(cam.intrinsics)
    A = rng.normal(size=(p, p))
    scale = np.r_[[0.5] * 4, [1e-3] * (p - 4)]
    cov = (A @ A.T / p) * np.outer(scale, scale)
    uv = pixel_grid(cam, 24)
    sd = rotation_free_stdev(cam, cov, uv)
    d2 = []
    for _ in range(150):
        theta = cam.intrinsics + rng.multivariate_normal(np.zeros(p), cov)
        d2.append(model_diff(cam, Camera.from_intrinsics(cam.width, cam.height, theta, cam.lens), gridn_width=24).diff)
    ratio = np.sqrt(np.mean(np.square(d2), axis=0)).ravel() / sd
    assert np.isfinite(ratio).all()
    assert 0.85 < np.median(ratio) < 1.35 and ratio.min() > 0.75 and ratio.max() < 1.6, (ratio.min(), ratio.max())


def test_pose_check_is_the_mahalanobis_distance(clean):
    cal, _ = clean
    rig = cal.rig
    same = pose_check(rig, rig, 1)
    assert same.mahalanobis == 0 and same.rotation_deg == 0 and same.consistent
    n = len(rig.state_vector())
    i = n - 3  # tz of camera 1
    t = rig.tvecs.copy()
    t[1, 2] += 3 * np.sqrt(rig.covariance[i, i])
    moved = RigModel(rig.names, rig.cameras, rig.rvecs, t, rig.covariance, rig.rms_px)
    chk = pose_check(rig, moved, 1)
    # both rigs hold the same covariance: the difference is weighed by twice it (rvec mapped by the left Jacobian)
    expected = np.sqrt(np.linalg.inv(2 * _pose_cov(rig))[5, 5]) * 3 * np.sqrt(rig.covariance[i, i])
    assert chk.mahalanobis == pytest.approx(expected, rel=1e-6)
    assert chk.translation_mm == pytest.approx(3 * np.sqrt(rig.covariance[i, i]))


def _pose_cov(rig):
    from circcal.rotation import left_jacobian

    n = len(rig.state_vector())
    C = rig.covariance[n - 6 :, n - 6 :]
    D = np.eye(6)
    D[:3, :3] = left_jacobian(rig.rvecs[1])
    return D @ C @ D.T


def test_coverage_per_camera_and_of_the_shared_field(clean):
    cal, _ = clean
    own = camera_coverage(cal)
    a, b = shared_coverage(cal)
    assert set(own) == {"left", "right"}
    assert (own["left"].width, own["left"].height) == (640, 480) and (b.width, b.height) == (512, 384)
    # the shared field is part of each camera's own: never more cells, and strictly fewer points here (instants and
    # points one camera sees alone)
    assert (a.counts <= own["left"].counts).all() and a.counts.sum() < own["left"].counts.sum()
    assert (b.counts <= own["right"].counts).all() and b.counts.sum() < own["right"].counts.sum()
    # both cameras saw the same board points at the shared instants: as many in each image
    assert a.counts.sum() == b.counts.sum() > 0


def test_the_halves_own_warnings_are_the_checks_notes(scenario):
    # halves held to 2 Jacobian evaluations stop short: their words are notes of the check, named by the half, and
    # nothing reaches the console as if the user's rig had not converged
    import warnings

    obs = rig_observations(scenario, NOISE_PX, seed=4)
    cal = calibrate_rig_points(obs, _sizes(scenario), OPTIONS)
    short = {n: dataclasses.replace(o, max_iterations=2) for n, o in OPTIONS.items()}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cv = cross_validate_rig(cal, short)
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)]
    assert cv.notes and all(n.startswith("the half of ") for n in cv.notes), cv.notes
    assert any("did not converge" in n for n in cv.notes)
    assert cv.to_dict()["notes"] == cv.notes
    assert any(line.startswith("  (the check's own fits) the half of ") for line in cv.lines())


def test_a_half_whose_board_poses_are_barely_determined_gives_a_verdict_not_a_crash(scenario):
    # `two` at 0.5 px with 40 % of every view's points dropped at random: in one half some board poses' own blocks
    # are near singular, their Schur complement has negative diagonal entries, and eigvalsh on its scaled form did
    # not converge (LinAlgError out of rig_verdict). Such a half has no covariance of its own. (Found with seed 71 at
    # 30 %; since the rig solve starts less damped from its near start, that half reaches a lower minimum, RMS
    # 0.68350 against 0.68413, whose information is regular: seed 60 at 40 % is such a half today.)
    rng = np.random.default_rng(60)
    views, _ = rig_variant_observations(scenario, "very-noisy", 1)
    thinned = {
        c: {v: (o[m], p[m]) for v, (o, p) in per.items() for m in [rng.random(len(o)) > 0.4]}
        for c, per in views.items()
    }
    cal = calibrate_rig_points(thinned, _sizes(scenario), OPTIONS)
    verdict = rig_verdict(cal, OPTIONS)
    assert verdict.cross is not None and verdict.cross.status == "ok"
    assert "is singular: its covariance is taken as the full rig's" in verdict.cross.message


def test_an_information_matrix_that_is_not_positive_definite_has_an_infinite_condition():
    from circcal.solver.covariance import normalised_information

    ok = np.array([[4.0, 1.0], [1.0, 9.0]])
    Sn, scale, cond = normalised_information(ok)
    assert np.allclose(np.diag(Sn), 1.0) and np.allclose(scale, [2.0, 3.0]) and 1.0 < cond < 2.0
    for bad in (np.array([[4.0, 1.0], [1.0, -9.0]]), np.array([[4.0, np.nan], [np.nan, 9.0]]), np.zeros((2, 2))):
        assert normalised_information(bad)[2] == np.inf


def test_a_cameras_start_says_it_is_a_start(scenario):
    # the right camera's own calibration (the rig's start) held to 3 Jacobian evaluations stops short: its warning
    # names it as the start; the joint solve (the cameras' largest limit, 200) converges and says nothing
    import warnings

    obs = rig_observations(scenario, NOISE_PX, seed=2)
    opts = {**OPTIONS, "right": dataclasses.replace(OPTIONS["right"], max_iterations=3)}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cal = calibrate_rig_points(obs, _sizes(scenario), opts)
    said = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert cal.converged and any("iteration limit 3 reached" in s for s in said), said
    assert all(s.startswith("the start of camera 'right' (calibrated alone, before the joint solve): ") for s in said)


def test_the_same_images_for_two_cameras_are_named_and_a_data_problem(scenario):
    """One camera's observations given again as a second camera (a wrong folder on the command line): the rig solves
    to a baseline of ~0 within its noise; the verdict says the same images were given twice, and what to do."""
    obs = rig_observations(scenario, NOISE_PX, seed=2)
    twice = {"left": obs["left"], "again": {v: (o.copy(), p.copy()) for v, (o, p) in obs["left"].items()}}
    size = _sizes(scenario)["left"]
    cal = calibrate_rig_points(twice, {"left": size, "again": size})
    assert np.linalg.norm(cal.rig.pair(0, 1)[1]) < 0.01  # mm, of a board ~400 mm away
    v = rig_verdict(cal, cross_validate=False)
    assert v.verdict == "model-or-data-problem" and len(v.coincident) == 1
    c = v.coincident[0]
    assert (c.a, c.b, c.same_points) == ("left", "again", True) and 300 < c.distance_mm < 600
    text = "\n".join(v.lines())
    assert "cameras 'left' and 'again' sit at one point" in text and "the same images were given for both" in text
    assert v.to_dict()["coincident"][0]["same_points"] is True


def test_cameras_sharing_one_centre_by_design_are_noted_not_condemned(scenario, clean):
    """A beam-splitter pair (one centre, other intrinsics, turned 2 deg): noted with what it means, the verdict as
    the checks find it; a rig with a baseline (the clean `two`) has no such note."""
    from circcal.fixtures.rig import RigScenario

    left = scenario.rig.cameras[0]
    other = Camera(640, 480, 600.0, 601.0, 318.0, 242.0, [-0.05, 0.02, 0.0, 0.0, 0.0])
    rig = RigModel(["left", "split"], [left, other], [np.zeros(3), np.radians([0.0, 2.0, 0.0])], [np.zeros(3)] * 2)
    sc = RigScenario("split", rig, scenario.board, scenario.instants, scenario.board_rvecs, scenario.board_tvecs)
    obs = rig_observations(sc, NOISE_PX, seed=3)
    cal = calibrate_rig_points(obs, {"left": (640, 480), "split": (640, 480)})
    v = rig_verdict(cal)
    assert len(v.coincident) == 1 and not v.coincident[0].same_points
    assert v.verdict == "consistent", v.lines()
    assert any("a beam splitter" in line for line in v.lines())
    assert not clean[1].coincident


def test_a_rig_without_covariance_names_what_its_views_leave_free():
    """A three-camera rig whose middle 1280x960 camera is fitted with the rational model its views cannot determine
    (numerator and denominator trade off; from a sweep of random rigs, not the fixtures): no covariance, the verdict a
    model problem naming that camera's coefficients and what to do; the rig itself stays within its truth."""
    from circcal.fixtures.rig import RigScenario, _board_poses

    cams = [
        Camera(800, 600, 768.03, 766.66, 405.22, 297.87, [-0.19, 0.0815, 4.9e-4, -1.6e-4, -0.0067]),
        Camera(
            1280, 960, 1149.41, 1149.41, 639.0, 482.23, [-0.0268, 0.05, 1e-4, -2e-4, 0.0, -0.0434, 0, 0], "rational"
        ),
        Camera(1280, 960, 1043.89, 1045.52, 643.71, 480.44, [0.0102, 0.0136, 3.9e-4, 1.03e-3, 0.0194]),
    ]
    rvecs = [[0, 0, 0], [-0.0301, -0.0159, 0.0013], [0.0216, -0.1278, 0.0021]]
    tvecs = [[0, 0, 0], [-80.37, 0.85, -1.70], [-160.74, 2.61, -11.30]]
    rig = RigModel(["c0", "c1", "c2"], cams, rvecs, tvecs)
    rv, tv = _board_poses(20, 213, (350.0, 650.0), 100.0, 40.0)
    tv[:, 0] += 80.37
    board = rig_scenario("two").board
    sc = RigScenario("rational-free", rig, board, tuple(f"{k:03d}" for k in range(20)), rv, tv)
    obs = rig_observations(sc, 0.36, 438)
    opts = {n: CalibrationOptions(lens=c.lens) for n, c in zip(rig.names, cams)}
    with pytest.warns(RuntimeWarning):
        cal = calibrate_rig_points(obs, {n: (c.width, c.height) for n, c in zip(rig.names, cams)}, opts, board=board)
    assert cal.rig.covariance is None and np.all(np.isnan(cal.std()))
    assert cal.undetermined and {c for c, _ in cal.undetermined} == {"c1"}
    assert {p for _, p in cal.undetermined} <= {"k1", "k2", "k3", "k4", "k5", "k6"}
    for c in (1, 2):
        assert np.linalg.norm(cal.rig.pose(c)[1] - rig.pose(c)[1]) < 1.0  # mm
    v = rig_verdict(cal, opts, cross_validate=False)
    assert v.verdict == "model-or-data-problem" and v.undetermined == cal.undetermined
    text = "\n".join(v.lines())
    assert "no stated uncertainty: the rig's information matrix is singular" in text and "of camera 'c1' free" in text
    assert "what to do: camera(s) c1: fit a lens model with fewer coefficients (--lens c1=opencv5)" in text
    assert v.to_dict()["undetermined"] == [list(u) for u in cal.undetermined]
    # a rig with its covariance says nothing of the kind
    sc2 = rig_scenario("two")
    ok = calibrate_rig_points(rig_observations(sc2, NOISE_PX, seed=2), _sizes(sc2), OPTIONS)
    assert (
        ok.rig.covariance is not None
        and ok.undetermined == []
        and rig_verdict(ok, OPTIONS, cross_validate=False).undetermined is None
    )
