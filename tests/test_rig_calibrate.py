"""The joint rig solve on projected observations with exact truth: Jacobian, recovery within the stated sigmas, the
covariance against Monte-Carlo, a chain of three cameras, a disconnected camera, the board's symmetry across cameras
and agreement with cv2.stereoCalibrate."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest

from circcal.errors import CalibrationError, InputError
from circcal.fixtures.rig import rig_observations, rig_scenario
from circcal.model import Camera, param_names
from circcal.rig import calibrate_rig_points
from circcal.rig.problem import CameraObservations, RigProblem, free_intrinsics
from circcal.rig.solve import solve_rig
from circcal.rig.start import board_symmetries
from circcal.rotation import rotation_angle_deg
from circcal.solver import CalibrationOptions


def _state(rig) -> np.ndarray:
    """RigModel.state_vector's order (every camera's intrinsics, then every pose but the reference's)."""
    return np.concatenate(
        [c.intrinsics for c in rig.cameras] + [np.r_[rig.rvecs[i], rig.tvecs[i]] for i in range(1, rig.n_cameras)]
    )


def _solve(name: str, noise: float, seed: int, board: bool = True, obs=None):
    sc = rig_scenario(name)
    obs = rig_observations(sc, noise, seed) if obs is None else obs
    sizes = {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    opts = {n: CalibrationOptions(lens=c.lens) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    return sc, calibrate_rig_points(obs, sizes, opts, board=sc.board if board else None)


def _truth_problem(sc, obs, fixed: bool = False):
    """The RigProblem of ``obs`` and the true parameter vector."""
    index = {v: i for i, v in enumerate(sc.instants)}
    cams = sc.rig.cameras
    problem_obs, free, maps = [], [], []
    for n, cam in zip(sc.rig.names, cams):
        problem_obs.append(CameraObservations.stack([(index[v], o, p) for v, (o, p) in obs[n].items()]))
        f, m = free_intrinsics(param_names(cam.lens), param_names(cam.lens) if fixed else (), None)
        free.append(f)
        maps.append(m)
    prob = RigProblem(problem_obs, len(sc.instants), [c.intrinsics for c in cams], [c.lens for c in cams], free, maps)
    x = prob.pack([c.intrinsics for c in cams], sc.rig.rvecs, sc.rig.tvecs, sc.board_rvecs, sc.board_tvecs)
    return prob, x


def test_jacobian_matches_finite_differences():
    sc = rig_scenario("fisheye")
    obs = rig_observations(sc, 0.3, 0)
    obs = {n: dict(list(per.items())[:4]) for n, per in obs.items()}
    prob, x = _truth_problem(sc, obs)
    x = x + np.random.default_rng(1).normal(0, 1e-3, x.shape) * np.maximum(np.abs(x), 1)
    J = prob.dense_jacobian(x)
    cols = [k for k in range(prob.n) if np.any(J[:, k])]
    assert len(cols) > prob.ng  # the instants seen in these views
    for k in cols:
        h = 1e-6 * max(1.0, abs(x[k]))
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        num = (prob.residuals(xp)[0] - prob.residuals(xm)[0]) / (2 * h)
        assert np.allclose(J[:, k], num, rtol=1e-5, atol=1e-4 * np.abs(J[:, k]).max()), k
    f, (A, gi, B, D, gp) = prob.normal_equations(x)
    assert np.allclose(A, J[:, : prob.ng].T @ J[:, : prob.ng])
    assert np.allclose(gp.ravel(), J[:, prob.ng :].T @ f)


def test_weighted_observations_scale_residuals_and_jacobian_by_the_root_of_their_weights():
    sc = rig_scenario("two")
    obs = rig_observations(sc, 0.3, 0)
    obs = {n: dict(list(per.items())[:3]) for n, per in obs.items()}
    prob, x = _truth_problem(sc, obs)
    rng = np.random.default_rng(2)
    w = [rng.uniform(0.1, 2.0, len(o.X)) for o in prob.obs]
    weighted = RigProblem(
        [CameraObservations(o.X, o.uv, o.instant, wc) for o, wc in zip(prob.obs, w)],
        prob.n_views, prob.base, prob.lenses, prob.free, prob.maps,
    )  # fmt: skip
    root = np.repeat(np.sqrt(np.concatenate(w)), 2)
    x = x + rng.normal(0, 1e-4, x.shape) * np.maximum(np.abs(x), 1)
    assert np.allclose(weighted.residuals(x)[0], root * prob.residuals(x)[0], rtol=1e-13, atol=0)
    assert np.allclose(weighted.dense_jacobian(x), root[:, None] * prob.dense_jacobian(x), rtol=1e-13, atol=0)
    f, (A, gi, B, D, gp) = weighted.normal_equations(x)
    J = weighted.dense_jacobian(x)
    assert np.allclose(A, J[:, : prob.ng].T @ J[:, : prob.ng]) and np.allclose(gi, J[:, : prob.ng].T @ f)
    assert np.allclose(gp.ravel(), J[:, prob.ng :].T @ f)


@pytest.mark.parametrize("name", ["two", "fisheye"])
def test_rig_recovered_within_stated_sigmas(name):
    sc, res = _solve(name, 0.1, 7)
    assert res.converged and not res.dropped
    for n in sc.rig.names:
        assert res.rms_px[n] == pytest.approx(0.1 * np.sqrt(2), rel=0.1)
    std = res.std()
    assert np.all(np.isfinite(std)) and np.all(std > 0)
    z = (_state(res.rig) - _state(sc.rig)) / std
    # fx, fy, cx, cy of every camera and the pose (the rational model's coefficients are far from linear along the
    # nearly degenerate direction that trades its numerator for its denominator: their sigmas are first-order only)
    n0 = len(sc.rig.cameras[0].intrinsics)
    rows = [0, 1, 2, 3, n0, n0 + 1, n0 + 2, n0 + 3, *range(len(z) - 6, len(z))]
    assert np.max(np.abs(z[rows])) < 4.5, z
    # the relative pose in deg / mm
    R, T = res.rig.pair(0, 1)
    Rt, Tt = sc.rig.pair(0, 1)
    sig_rot_deg = np.degrees(np.linalg.norm(std[-6:-3]))
    assert rotation_angle_deg(R @ Rt.T) < 4 * sig_rot_deg < 0.5
    assert np.linalg.norm(T - Tt) < 4 * np.linalg.norm(std[-3:]) < 3.0
    # every instant each camera saw is used; views seen by one camera only too
    assert res.instants[sc.rig.names[0]] != res.instants[sc.rig.names[1]] or name == "fisheye"


def test_covariance_matches_monte_carlo():
    sc = rig_scenario("fisheye")
    noise, n = 0.2, 30
    sols, stated = [], []
    rng = np.random.default_rng(3)
    for _ in range(n):
        obs = rig_observations(sc, noise, int(rng.integers(1 << 31)))
        prob, x = _truth_problem(sc, obs)
        sol = solve_rig(prob, x, 100)
        assert sol.converged
        sols.append(sol.x[: prob.ng])
        stated.append(np.sqrt(np.diag(sol.covariance)))
    n0, n1 = (len(c.intrinsics) for c in sc.rig.cameras)
    rows = [0, 1, 2, 3, n0, n0 + 1, n0 + 2, n0 + 3, *range(n0 + n1, n0 + n1 + 6)]
    empirical = np.std(np.array(sols)[:, rows], axis=0, ddof=1)  # every parameter free: state rows = columns
    ratio = np.mean(stated, axis=0)[rows] / empirical
    assert 0.8 < np.median(ratio) < 1.25, ratio
    assert np.all((ratio > 0.6) & (ratio < 1.6)), ratio


def test_three_camera_chain():
    sc, res = _solve("chain", 0.1, 2)
    assert res.start.tree == [(0, 1), (1, 2)]  # c shares instants with b only
    assert not set(res.instants["a"]) & set(res.instants["c"])
    std = res.std()
    z = (_state(res.rig) - _state(sc.rig)) / std
    assert np.max(np.abs(z)) < 4.5
    R, T = res.rig.pair(0, 2)
    Rt, Tt = sc.rig.pair(0, 2)
    assert rotation_angle_deg(R @ Rt.T) < 0.2 and np.linalg.norm(T - Tt) < 3.0


def test_disconnected_camera_refused_in_words():
    sc = rig_scenario("chain")
    obs = rig_observations(sc, 0.1, 2)
    # b no longer sees the instants it shares with c
    obs["b"] = {v: p for v, p in obs["b"].items() if v not in obs["c"]}
    with pytest.raises(CalibrationError, match=r"camera\(s\) 'c' share no instant .* camera\(s\) 'a', 'b'"):
        _solve("chain", 0.1, 2, obs=obs)


@pytest.mark.parametrize(
    ("spoil", "words"),
    [
        (
            lambda o, p: (o, np.where(np.arange(len(p))[:, None] == 3, np.nan, p)),
            "view '{v}': 1 image point(s) are NaN",
        ),
        (lambda o, p: (o, p[:-1]), "view '{v}': {n} object points but {m} image points"),
        (lambda o, p: (o, np.zeros_like(p) + 100.0), "view(s) ['{v}']: their image (or board) points are collinear"),
    ],
    ids=["nan", "lengths", "coincident"],
)
def test_bad_observations_are_refused_naming_the_camera_and_instant(spoil, words):
    sc = rig_scenario("two")
    obs = rig_observations(sc, 0.1, 0)
    sizes = {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    v = sorted(obs["right"])[2]
    o, p = obs["right"][v]
    obs["right"][v] = spoil(o, p)
    expected = "camera 'right': " + words.format(v=v, n=len(o), m=len(p) - 1)
    with pytest.raises(InputError, match=re.escape(expected)):
        calibrate_rig_points(obs, sizes, CalibrationOptions(), board=sc.board)


def test_board_symmetry_flip_resolved():
    sc = rig_scenario("two")
    obs = rig_observations(sc, 0.1, 5)
    rot180 = next(s for s in board_symmetries(sc.board) if s.label == "rot180")
    flipped = [v for v in list(obs["right"])[1:8:3] if v in obs["left"]]
    assert len(flipped) >= 2
    for v in flipped:  # the other camera labelled the same board turned 180 deg (findCirclesGrid's ambiguity)
        o, p = obs["right"][v]
        obs["right"][v] = (rot180.apply(o), p)
    _, res = _solve("two", 0.1, 5, obs=obs)
    assert sorted(r["instant"] for r in res.relabelled) == sorted(flipped)
    assert {r["camera"] for r in res.relabelled} <= {"left", "right"} and not res.dropped
    R, T = res.rig.pair(0, 1)
    Rt, Tt = sc.rig.pair(0, 1)
    assert rotation_angle_deg(R @ Rt.T) < 0.2 and np.linalg.norm(T - Tt) < 2.0
    assert max(res.rms_px.values()) < 0.2
    # without the board's symmetries the flipped views cannot agree: they are dropped as inconsistent, in words
    _, plain = _solve("two", 0.1, 5, board=False, obs=obs)
    assert sorted(d["instant"] for d in plain.dropped) == sorted(flipped)
    assert all("inconsistent with the rig" in d["reason"] for d in plain.dropped)


def test_agrees_with_cv2_stereo_calibrate():
    sc = rig_scenario("two")
    obs = rig_observations(sc, 0.1, 9)
    # stereoCalibrate needs the same points in both cameras at every instant
    both = {}
    for v in obs["left"]:
        if v in obs["right"] and len(obs["left"][v][0]) == len(obs["right"][v][0]) == sc.board.n_points:
            both[v] = v
    obs = {n: {v: obs[n][v] for v in both} for n in obs}
    _, res = _solve("two", 0.1, 9, obs=obs)
    left, right = res.rig.cameras
    objs = [obs["left"][v][0].astype(np.float32) for v in both]
    left_px = [obs["left"][v][1].astype(np.float32) for v in both]
    right_px = [obs["right"][v][1].astype(np.float32) for v in both]
    flags = cv2.CALIB_FIX_INTRINSIC | cv2.CALIB_RATIONAL_MODEL
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    out = cv2.stereoCalibrate(
        objs,
        left_px,
        right_px,
        left.K,
        np.r_[left.dist, np.zeros(3)],
        right.K,
        right.dist,
        (left.width, left.height),
        flags=flags,
        criteria=crit,
    )
    R_cv, T_cv = out[5], out[6].ravel()
    R, T = res.rig.pair(0, 1)
    assert rotation_angle_deg(R @ R_cv.T) < 1e-4
    assert np.linalg.norm(T - T_cv) < 1e-3


def test_a_camera_its_own_views_cannot_determine_starts_from_a_simpler_model():
    """The `two` rig's 512x384 rational camera at 0.1 px noise, draw 10: alone, its coefficients are not determined
    (calibrate refuses, naming them); in the rig it starts from its opencv5 calibration (the extra terms 0) and the
    joint solve, whose other camera fixes the board poses, converges with a finite covariance and the rig's pose
    near the truth (measured 0.025 deg, 0.22 mm)."""
    from circcal.errors import CalibrationError
    from circcal.fixtures.rig import rig_observations, rig_scenario
    from circcal.rig import calibrate_rig_points
    from circcal.solver import CalibrationOptions, calibrate
    from circcal.validators.rig import compare_rigs

    sc = rig_scenario("two")
    names = sc.rig.names
    obs = rig_observations(sc, 0.1, 10)
    right = obs[names[1]]
    with pytest.raises(CalibrationError, match="not determined"):
        calibrate(
            [v[0] for v in right.values()],
            [v[1] for v in right.values()],
            (512, 384),
            CalibrationOptions(lens="rational"),
        )
    sizes = {n: (c.width, c.height) for n, c in zip(names, sc.rig.cameras)}
    opts = {names[0]: CalibrationOptions(), names[1]: CalibrationOptions(lens="rational")}
    cal = calibrate_rig_points(obs, sizes, opts, board=sc.board)
    assert cal.converged and cal.rig.covariance is not None and np.all(np.isfinite(cal.rig.covariance))
    a = compare_rigs(cal.rig, sc.rig)
    assert a.rotation_deg[1] < 0.1 and a.position_mm[1] < 1.0


def test_a_view_the_start_puts_behind_every_camera_is_dropped_in_words():
    # both cameras' own board poses of one shared instant turned to face away (the board behind each camera): from
    # either anchor the other camera sees it behind itself -- no finite fit under any labelling. The view is dropped
    # naming that (it used to read "land inf px"), and the rest keep the limit of the finite fits.
    from circcal.rig.start import rig_start

    sc = rig_scenario("two")
    obs = rig_observations(sc, 0.1, 0)
    names = list(sc.rig.names)
    poses = []
    for c in range(2):
        Rc, Tc = sc.rig.pose(c)
        per = {}
        for v, rv, tv in zip(sc.instants, sc.board_rvecs, sc.board_tvecs):
            if v in obs[names[c]]:
                per[v] = (Rc @ cv2.Rodrigues(rv)[0], Rc @ tv + Tc)
        poses.append(per)
    shared = [v for v in poses[0] if v in poses[1]]
    bad = shared[3]
    for c in range(2):
        R, t = poses[c][bad]
        poses[c][bad] = (R, -t)  # the board behind the camera
    views = [obs[n] for n in names]
    start = rig_start(names, list(sc.rig.cameras), poses, views, board_symmetries(sc.board))
    assert len(start.dropped) == 1
    c, v, why = start.dropped[0]
    assert v == bad and "fall behind the camera or outside its lens's field" in why
    assert (1 - c, bad) in start.labels  # the anchor keeps its own view


@pytest.mark.parametrize("name", ["chain", "fisheye"])
def test_given_intrinsics_reach_the_same_rig(name):
    """``initial=`` each camera's intrinsics (here the truth off by 1 % in focal length and 3 px in its centre, as a
    user's earlier calibration may be): board poses by pose_start, and the joint solve lands on the rig the default
    start (each camera calibrated alone) reaches, to the solver's own precision. (Not on ``two``: its rational
    camera's coefficients drift along their numerator-denominator valley, where starts 1 % apart stop at points
    whose RMS differ by 3e-4 relative, both within the gradient bound.)"""
    sc, res = _solve(name, 0.1, 5)
    obs = rig_observations(sc, 0.1, 5)
    sizes = {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    opts = {n: CalibrationOptions(lens=c.lens) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    given = {}
    for n, c in zip(sc.rig.names, sc.rig.cameras):
        p = c.intrinsics.copy()
        p[:2] *= 1.01
        p[2] += 3.0
        given[n] = Camera.from_intrinsics(c.width, c.height, p, c.lens)
    got = calibrate_rig_points(obs, sizes, opts, board=sc.board, initial=given)
    assert got.converged
    for a, b in zip(got.rig.cameras, res.rig.cameras):
        assert np.allclose(a.intrinsics, b.intrinsics, rtol=1e-8, atol=1e-10)
    for c in range(1, sc.rig.n_cameras):
        (R, T), (R0, T0) = got.rig.pose(c), res.rig.pose(c)
        assert rotation_angle_deg(R @ R0.T) < 1e-8 and np.linalg.norm(T - T0) < 1e-7
    assert got.rig.rms_px == pytest.approx(res.rig.rms_px, rel=1e-12)


def test_given_intrinsics_from_model_files(tmp_path):
    """The cameras as model files of any format circcal reads (model.json, OpenCV's YAML): the same rig as from the
    Camera objects."""
    from circcal.formats import write_camera

    sc = rig_scenario("chain")
    obs = rig_observations(sc, 0.1, 5)
    sizes = {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    files = {}
    for k, (n, c) in enumerate(zip(sc.rig.names, sc.rig.cameras)):
        files[n] = tmp_path / (f"{n}.json" if k % 2 else f"{n}.yaml")
        write_camera(files[n], c)
    by_file = calibrate_rig_points(obs, sizes, initial={n: str(p) for n, p in files.items()})
    by_camera = calibrate_rig_points(obs, sizes, initial=dict(zip(sc.rig.names, sc.rig.cameras)))
    for a, b in zip(by_file.rig.cameras, by_camera.rig.cameras):
        assert np.allclose(a.intrinsics, b.intrinsics, rtol=1e-9, atol=1e-12)
    assert by_file.rig.rms_px == pytest.approx(by_camera.rig.rms_px, rel=1e-12)


def test_given_intrinsics_of_another_rig_are_refused_in_one_line():
    sc = rig_scenario("two")
    obs = rig_observations(sc, 0.1, 5)
    sizes = {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    opts = {n: CalibrationOptions(lens=c.lens) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    (a, b), (ca, cb) = sc.rig.names, sc.rig.cameras
    for initial, words in [
        ({a: cb, b: ca}, f"camera '{a}' is 512x384, its images 640x480"),
        ({a: ca}, f"initial: cameras \\['{a}'\\], the observations' are"),
        ({a: ca, b: 3}, f"camera '{b}' must be a Camera or a model file, got int"),
        ({a: ca, b: "no/such/right.json"}, "no/such/right.json"),
        ([ca, cb], "initial must be a RigCalibration or a mapping of camera name to Camera"),
    ]:
        with pytest.raises(InputError, match=words):
            calibrate_rig_points(obs, sizes, opts, initial=initial)
    with pytest.raises(InputError, match=f"camera '{b}' has lens 'rational', its options lens='opencv5'"):
        calibrate_rig_points(obs, sizes, {a: opts[a]}, initial={a: ca, b: cb})


def test_a_solve_that_does_not_converge_says_where_it_crawls():
    """The `two` rig at 0.02 px, draw 1093 (of the Monte-Carlo study): the rational camera's k1 and k4 (numerator
    and denominator moving together) keep the joint solve crawling past 200 iterations; the warning names them and
    what to do, as the rig without covariance does (measured: k1, k4 of camera 'right')."""
    sc = rig_scenario("two")
    sizes = {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    opts = {n: CalibrationOptions(lens=c.lens) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    with pytest.warns(RuntimeWarning, match="did not converge") as caught:
        cal = calibrate_rig_points(rig_observations(sc, 0.02, 1093), sizes, opts, board=sc.board)
    assert not cal.converged
    said = " ".join(str(w.message) for w in caught if "did not converge" in str(w.message))
    assert "k1, k4 of camera 'right'" in said and "fewer lens coefficients" in said, said
