"""The solver against OpenCV on identical observations, its uncertainty, options and degenerate input."""

import cv2
import numpy as np
import pytest

from circcal.board import Board
from circcal.errors import CalibrationError, DegenerateViewsError
from circcal.fixtures.poses import sample_poses
from circcal.model import (
    PARAM_NAMES,
    Camera,
    distort,
    normalized_to_pixel,
    pixel_to_normalized,
    project,
    project_jacobian,
    undistort,
)
from circcal.solver import CalibrationOptions, calibrate, problem
from circcal.solver.lm import EXTRAPOLATE_MAX, geometric_extension, schur_step
from circcal.solver.problem import Problem, board_model

BOARD = Board(7, 7, 10.0, 5.0)
W, H = 1920, 1080
TRUE = Camera(W, H, 1500.0, 1502.0, 955.0, 545.0, np.array([-0.2, 0.1, 0.001, -0.0005, -0.02]))
CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 1000, 1e-15)


def synthetic(camera=TRUE, n=14, seed=0, noise=0.1, max_tilt=40.0, drop=0.0):
    """float32-rounded observations (what cv2 takes), returned as float64 for circcal."""
    rng = np.random.default_rng(seed)
    poses = sample_poses(camera, BOARD, n, seed, max_tilt_deg=max_tilt)
    obj, img = [], []
    for r, t in poses:
        o = BOARD.object_points()
        p = project(o, r, t, camera) + rng.normal(0.0, noise, (len(o), 2))
        if drop:
            keep = rng.random(len(o)) >= drop
            o, p = o[keep], p[keep]
        obj.append(o.astype(np.float32).astype(np.float64))
        img.append(p.astype(np.float32).astype(np.float64))
    return obj, img, poses


def cv2_calibrate(obj, img, flags=0, K0=None, d0=None):
    out = cv2.calibrateCameraExtended(
        [o.astype(np.float32) for o in obj],
        [p.astype(np.float32) for p in img],
        (W, H),
        K0,
        d0,
        flags=flags,
        criteria=CRIT,
    )
    rms, K, d, rv, tv, std_i = out[:6]
    params = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *np.ravel(d)[:5]])
    return params, std_i.ravel()[:9], rms, np.array(rv).reshape(-1, 3), np.array(tv).reshape(-1, 3)


def max_projection_difference(a: Camera, b: Camera) -> float:
    """Max |pixel difference| when both cameras project the rays of a 40x24 grid over the whole image of ``a``."""
    u, v = np.meshgrid(np.linspace(0, W - 1, 40), np.linspace(0, H - 1, 24))
    uv = np.column_stack([u.ravel(), v.ravel()])
    xn = undistort(pixel_to_normalized(uv, a), a.dist)
    return float(
        np.max(np.abs(normalized_to_pixel(distort(xn, a.dist), a) - normalized_to_pixel(distort(xn, b.dist), b)))
    )


def test_projection_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(0, 60, (20, 2)), np.zeros(20)])
    for rv in (np.array([0.3, -0.4, 0.2]), np.array([1e-7, 0.0, 2e-7]), np.zeros(3), np.array([2.5, 1.0, 0.3])):
        tv = np.array([-30.0, -20.0, 400.0])
        _, Ji, Jp = project_jacobian(X, rv, tv, TRUE)
        e = 1e-6
        num_r = np.stack(
            [(project(X, rv + e * d, tv, TRUE) - project(X, rv - e * d, tv, TRUE)) / (2 * e) for d in np.eye(3)], -1
        )
        num_t = np.stack(
            [(project(X, rv, tv + e * d, TRUE) - project(X, rv, tv - e * d, TRUE)) / (2 * e) for d in np.eye(3)], -1
        )
        p = TRUE.intrinsics
        num_i = np.stack(
            [
                (
                    project(X, rv, tv, Camera.from_intrinsics(W, H, p + e * d))
                    - project(X, rv, tv, Camera.from_intrinsics(W, H, p - e * d))
                )
                / (2 * e)
                for d in np.eye(9)
            ],
            -1,
        )
        assert np.max(np.abs(num_r - Jp[:, :, :3])) < 1e-6 * np.max(np.abs(num_r))
        assert np.max(np.abs(num_t - Jp[:, :, 3:])) < 1e-6 * np.max(np.abs(num_t))
        assert np.max(np.abs(num_i - Ji)) < 1e-6 * np.max(np.abs(num_i))


def test_equals_opencv_on_identical_points(cv2_single_thread):
    obj, img, _ = synthetic(noise=0.1)
    ref, ref_std, ref_rms, _, _ = cv2_calibrate(obj, img)
    res = calibrate(obj, img, (W, H))
    assert res.converged
    assert max_projection_difference(Camera.from_intrinsics(W, H, ref), res.camera) <= 1e-6
    np.testing.assert_allclose(res.camera.intrinsics, ref, rtol=1e-6, atol=0)
    std = np.array([res.std[n] for n in PARAM_NAMES])
    np.testing.assert_allclose(std, ref_std, rtol=0.01)
    assert res.errors["rms_per_point_px"] == pytest.approx(ref_rms, rel=1e-9)
    # the estimate is near the truth within a few stated sigmas
    assert np.all(np.abs(res.camera.intrinsics - TRUE.intrinsics) < 5 * std)


@pytest.mark.parametrize("seed,k1", [(0, -0.1), (1, 0.1), (2, -0.3)])
def test_is_the_least_squares_minimum(seed, k1, cv2_single_thread):
    """circcal stops at the minimum: OpenCV's solution, polished by exact Gauss-Newton steps, lands on circcal's to
    ~1e-9 relative (OpenCV itself sometimes stops ~1e-6 relative short in a weak distortion coefficient)."""
    cam = Camera(W, H, 1500.0, 1502.0, 955.0, 545.0, np.array([k1, -0.3 * k1, 0.001, -0.0005, 0.01]))
    obj, img, _ = synthetic(cam, seed=seed, max_tilt=45.0)
    ref, _, _, rv, tv = cv2_calibrate(obj, img)
    res = calibrate(obj, img, (W, H))
    # raw OpenCV is within 1e-5 px everywhere (seed 0 here: 1.9e-6 px at the image corners, k3 3.9e-6 relative off)
    assert max_projection_difference(Camera.from_intrinsics(W, H, ref), res.camera) <= 1e-5
    np.testing.assert_allclose(res.camera.intrinsics[:4], ref[:4], rtol=1e-8)
    prob = Problem(obj, img, ref, list(range(9)), None)
    x = prob.pack(ref, rv, tv)
    for _ in range(4):
        x = x + schur_step(*prob.normal_equations(x)[1], 0.0)
    polished = prob.intrinsics(x)
    scale = np.maximum(np.abs(polished), 1e-3)
    assert np.max(np.abs(polished - res.camera.intrinsics) / scale) < 1e-9
    assert max_projection_difference(Camera.from_intrinsics(W, H, polished), res.camera) <= 1e-8


@pytest.mark.parametrize("refine,drop", [(False, 0.0), (False, 0.2), (True, 0.2)], ids=["equal", "partial", "board"])
def test_normal_equations_equal_the_whole_jacobians(refine, drop, monkeypatch):
    """The normal equations assembled chunk by chunk (several chunks, views of unequal point counts, board columns)
    equal J^T J and J^T f of the whole Jacobian, and the residual-only pass gives the Jacobian pass's residuals to
    the bit."""
    monkeypatch.setattr(problem, "EVALUATE_CHUNK", 100)
    obj, img, poses = synthetic(drop=drop)
    prob = Problem(obj, img, TRUE.intrinsics, list(range(9)), None, board_model(obj, None) if refine else None)
    assert len(prob.chunks) > 3
    rng = np.random.default_rng(1)
    x = prob.pack(TRUE.intrinsics, np.array([r for r, _ in poses]), np.array([t for _, t in poses]))
    x = x * (1.0 + 1e-4 * rng.standard_normal(x.size))
    f, Xc, Jg, Jp = prob.evaluate(x)
    fr, Xcr = prob.residuals(x)
    fn, (A, gi, B, D, gp) = prob.normal_equations(x)
    assert np.array_equal(fr, f) and np.array_equal(fn, f) and np.array_equal(Xcr, Xc)
    J = np.zeros((len(f), prob.n))
    J[:, : prob.ng] = Jg.reshape(-1, prob.ng)
    for v in range(prob.n_views):
        rows = np.repeat(prob.view == v, 2)
        J[rows, prob.ng + 6 * v : prob.ng + 6 * v + 6] = Jp.reshape(-1, 6)[rows]
    JtJ, g = J.T @ J, J.T @ f
    scale = np.max(np.abs(JtJ))
    np.testing.assert_allclose(A, JtJ[: prob.ng, : prob.ng], rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(gi, g[: prob.ng], rtol=1e-10, atol=1e-12 * np.max(np.abs(g)))
    for v in range(prob.n_views):
        p = slice(prob.ng + 6 * v, prob.ng + 6 * v + 6)
        np.testing.assert_allclose(B[v], JtJ[: prob.ng, p], rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(D[v], JtJ[p, p], rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(gp[v], g[p], rtol=0, atol=1e-12 * np.max(np.abs(g)))


def test_geometric_extension_only_continues_a_shrinking_step_in_the_same_direction():
    e = np.array([1.0, 0.0, 0.0])
    assert geometric_extension(e, 0.2 * e) == pytest.approx(1.25)  # 0.2 + 0.04 + ... = 0.2 / 0.8
    assert geometric_extension(e, 0.9 * e) == EXTRAPOLATE_MAX
    assert geometric_extension(e, 1.1 * e) == 1.0  # growing: no sequence
    assert geometric_extension(e, -0.5 * e) == 1.0  # reversed: an overshoot
    assert geometric_extension(e, np.array([0.2, 0.1, 0.0])) == 1.0  # turned by 27 deg


def test_scipy_least_squares_reaches_the_same_model():
    obj, img, _ = synthetic(noise=0.1, seed=4)
    a = calibrate(obj, img, (W, H))
    b = calibrate(obj, img, (W, H), CalibrationOptions(solver="scipy"))
    assert max_projection_difference(a.camera, b.camera) < 1e-4
    np.testing.assert_allclose(b.camera.intrinsics[:4], a.camera.intrinsics[:4], rtol=1e-6)
    assert b.errors["rms_per_point_px"] == pytest.approx(a.errors["rms_per_point_px"], rel=1e-9)


@pytest.mark.parametrize(
    "option,flag",
    [
        ("fix_k3", cv2.CALIB_FIX_K3),
        ("fix_tangential", cv2.CALIB_ZERO_TANGENT_DIST),
        ("fix_aspect_ratio", cv2.CALIB_FIX_ASPECT_RATIO),
        ("fix_principal_point", cv2.CALIB_FIX_PRINCIPAL_POINT),
    ],
)
def test_fixed_parameters_match_opencv(option, flag, cv2_single_thread):
    obj, img, _ = synthetic(noise=0.08, seed=5)
    # same start for both: the ratio / principal point held is the initial camera's
    init = Camera(W, H, 1600.0, 1600.0, (W - 1) / 2, (H - 1) / 2)
    ref, ref_std, ref_rms, _, _ = cv2_calibrate(
        obj, img, flags=flag | cv2.CALIB_USE_INTRINSIC_GUESS, K0=init.K.copy(), d0=np.zeros(5)
    )
    res = calibrate(obj, img, (W, H), CalibrationOptions.from_flags(**{option: True}), initial=init)
    assert res.converged
    assert max_projection_difference(Camera.from_intrinsics(W, H, ref), res.camera) <= 1e-6
    np.testing.assert_allclose(res.camera.intrinsics[:4], ref[:4], rtol=1e-7)
    held = {
        "fix_k3": ["k3"],
        "fix_tangential": ["p1", "p2"],
        "fix_aspect_ratio": [],
        "fix_principal_point": ["cx", "cy"],
    }[option]
    for name in held:
        i = PARAM_NAMES.index(name)
        assert res.camera.intrinsics[i] == init.intrinsics[i]
        assert res.std[name] == 0.0
        assert np.all(np.isnan(res.correlation[i, [j for j in range(9) if j != i]]))
        assert name in res.fixed
    if option == "fix_aspect_ratio":
        assert "aspect_ratio" in res.fixed
        assert res.camera.fx == pytest.approx(res.camera.fy, rel=1e-15)
        assert res.std["fx"] == pytest.approx(res.std["fy"], rel=1e-12)
        assert res.correlation[0, 1] == pytest.approx(1.0, abs=1e-9)
    free = [i for i, n in enumerate(PARAM_NAMES) if n not in held and not (option == "fix_aspect_ratio" and i == 0)]
    std = np.array([res.std[n] for n in PARAM_NAMES])
    np.testing.assert_allclose(std[free], ref_std[free], rtol=0.01)
    assert res.errors["rms_per_point_px"] == pytest.approx(ref_rms, rel=1e-8)


def test_partial_boards(cv2_single_thread):
    obj, img, _ = synthetic(noise=0.1, seed=6, drop=0.3)
    assert len({len(o) for o in obj}) > 1
    ref, ref_std, _, _, _ = cv2_calibrate(obj, img)
    res = calibrate(obj, img, (W, H))
    assert max_projection_difference(Camera.from_intrinsics(W, H, ref), res.camera) <= 1e-6
    assert [len(r) for r in res.residuals] == [len(o) for o in obj]
    np.testing.assert_allclose([res.std[n] for n in PARAM_NAMES], ref_std, rtol=0.01)


def test_noiseless_recovers_truth_and_reports_errors():
    obj, img, poses = synthetic(noise=0.0, seed=7)
    obj = [BOARD.object_points() for _ in poses]
    img = [project(o, r, t, TRUE) for o, (r, t) in zip(obj, poses)]
    res = calibrate(obj, img, (W, H))
    np.testing.assert_allclose(res.camera.intrinsics, TRUE.intrinsics, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(res.rvecs, [r for r, _ in poses], atol=1e-11)
    assert res.errors["rms_per_point_px"] < 1e-9
    assert res.sigma_px < 1e-9


def test_error_conventions_and_noise_estimate():
    sigma = 0.1
    obj, img, _ = synthetic(noise=sigma, seed=8)
    res = calibrate(obj, img, (W, H))
    e = res.errors
    assert e["n_points"] == 14 * 49
    r = np.concatenate(res.residuals)
    assert e["rms_per_point_px"] == pytest.approx(np.sqrt(np.mean(np.sum(r**2, 1))))
    assert e["rms_per_coord_px"] == pytest.approx(e["rms_per_point_px"] / np.sqrt(2))
    assert e["mean_2d_px"] == pytest.approx(np.mean(np.hypot(r[:, 0], r[:, 1])))
    # sigma estimate: SSR / (2N - n_params), n_params = 9 + 6 * 14
    assert res.n_params == 9 + 6 * 14
    assert res.sigma_px == pytest.approx(np.sqrt(np.sum(r**2) / (2 * 686 - 93)))
    assert res.sigma_px == pytest.approx(sigma, rel=0.1)
    assert len(res.per_view_errors) == 14
    # residuals are observed - projected
    np.testing.assert_allclose(
        res.residuals[0], img[0] - project(obj[0], res.rvecs[0], res.tvecs[0], res.camera), atol=1e-12
    )
    np.testing.assert_allclose(np.diag(res.correlation), 1.0)
    m = res.to_model_json()
    assert m["camera"] == res.camera.to_dict()
    assert m["errors"]["rms_per_point_px"] == e["rms_per_point_px"]
    assert len(m["views"]) == 14 and len(m["correlation"]) == 9


# ---- degenerate input ----------------------------------------------------------------------------------------------


def test_fewer_than_three_views():
    obj, img, _ = synthetic(n=2)
    with pytest.raises(CalibrationError, match="at least 3 views"):
        calibrate(obj, img, (W, H))


def test_nan_points():
    obj, img, _ = synthetic(n=5)
    img[2][7] = np.nan
    with pytest.raises(CalibrationError, match=r"view 2: 1 image point\(s\) are NaN"):
        calibrate(obj, img, (W, H))


def test_out_of_image_points():
    obj, img, _ = synthetic(n=5)
    img[3][0] = (W + 20.0, 10.0)
    with pytest.raises(CalibrationError, match="view 3: 1 image point.*outside the 1920x1080 image"):
        calibrate(obj, img, (W, H))
    obj, img, _ = synthetic(n=5)
    with pytest.raises(CalibrationError, match="outside"):
        calibrate(obj, img, (640, 480))  # wrong image size


def test_too_few_points_and_shape_errors():
    obj, img, _ = synthetic(n=5)
    obj[1], img[1] = obj[1][:4], img[1][:4]
    with pytest.raises(CalibrationError, match="view 1: 4 points"):
        calibrate(obj, img, (W, H))
    obj, img, _ = synthetic(n=5)
    with pytest.raises(ValueError, match="view 0: 49 object points but 48 image points"):
        calibrate(obj, [img[0][:48]] + img[1:], (W, H))
    obj[0] = obj[0].copy()
    obj[0][:, 2] = 1.0
    with pytest.raises(CalibrationError, match="z = 0"):
        calibrate(obj, img, (W, H))


@pytest.mark.parametrize("tilt_deg", [0.0, 0.5, 3.0])
def test_fronto_parallel_views_raise(tilt_deg):
    rng = np.random.default_rng(0)
    obj, img = [], []
    for _ in range(14):
        ax = rng.normal(size=2)
        ax /= np.linalg.norm(ax)
        rv = np.array([*(ax * np.radians(tilt_deg)), rng.uniform(-0.3, 0.3)])
        tv = np.array([rng.uniform(-150, 100), rng.uniform(-80, 40), 500.0])
        obj.append(BOARD.object_points())
        img.append(project(BOARD.object_points(), rv, tv, TRUE) + rng.normal(0, 0.05, (49, 2)))
    with pytest.raises(DegenerateViewsError, match="focal length is not observable") as info:
        calibrate(obj, img, (W, H))
    assert "tilt" in str(info.value) or "parallel" in str(info.value)
    assert len(info.value.views) >= 9


def test_inconsistent_correspondences_raise():
    rng = np.random.default_rng(1)
    img = [rng.uniform(0, 1000, (49, 2)) for _ in range(5)]
    with pytest.raises(CalibrationError):
        calibrate([BOARD.object_points()] * 5, img, (W, H))


def test_non_convergence_warns():
    obj, img, _ = synthetic(noise=0.1)
    with pytest.warns(RuntimeWarning, match="did not converge"):
        res = calibrate(obj, img, (W, H), CalibrationOptions(max_iterations=2))
    assert not res.converged


# ---- statistics ----------------------------------------------------------------------------------------------------

# The Monte-Carlo studies of the stated uncertainty (60 noise draws on fixed views, and the `paper` views at the noise
# levels circcal's centres carry) are study specs now: studies/monte-carlo.yaml, asserted by
# tests/test_study_monte_carlo.py (`make study`).


# ---- images -> model (needs the detector and the fixture renderer) -------------------------------------------------


def test_cli_calibrate_paper_fixture(tmp_path, capsys):
    """`circcal calibrate` end to end on the rendered paper setup (normal illumination): the centres settle in a few
    re-correction rounds, the paper's mean 2-D error bar (<= 0.05 px) holds, and the model lies within 4 stated
    sigmas of the true camera."""
    pytest.importorskip("circcal.detector")
    import json

    from circcal.cli import main
    from circcal.fixtures.cache import fixture_dir
    from circcal.formats import read_camera

    d = fixture_dir("paper", "normal")
    truth = json.loads((d / "truth.json").read_text())
    images = [str(d / v["image"]) for v in truth["views"]] + [str(tmp_path / "missing.png")]
    out = tmp_path / "model.json"
    rc = main(
        [
            "calibrate",
            *images,
            "--grid",
            "7x7",
            "--pitch",
            "10mm",
            "--diameter",
            "5mm",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    text = capsys.readouterr().out
    assert rc == 0
    assert "missing.png: file not found" in text and "RMS per coordinate (mrcal)" in text
    model = json.loads(out.read_text())
    assert model["errors"]["mean_2d_px"] <= 0.05
    assert len(model["views"]) == 14 and model["failed_images"][0]["reason"] == "file not found"
    rounds = model["recorrection_rounds"]
    assert 2 <= len(rounds) <= 4 and rounds[-1]["max_centre_shift_px"] < 1e-4
    cam, true = read_camera(out), truth["camera"]
    for name in ("fx", "fy", "cx", "cy"):
        assert abs(getattr(cam, name) - true[name]) < 4 * model["std"][name], name
