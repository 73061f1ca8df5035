"""The solver for every lens model against OpenCV on identical observations: cv2.calibrateCamera with
CALIB_RATIONAL_MODEL / CALIB_THIN_PRISM_MODEL and cv2.fisheye.calibrate (CALIB_RECOMPUTE_EXTRINSIC | CALIB_FIX_SKEW),
the fisheye start, and the uncertainty of each model."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from circcal.board import Board
from circcal.fixtures.poses import off_axis_observations
from circcal.model import Camera, param_names, project, project_camera, unproject
from circcal.solver import CalibrationOptions, calibrate
from circcal.solver.fisheye_start import fisheye_start

BOARD = Board(9, 9, 20.0, 8.0)
CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 1000, 1e-15)
#: a wide lens OpenCV users fit with the rational model (about 125 deg across the diagonal)
RATIONAL = Camera(1920, 1080, 900.0, 905.0, 962.3, 541.7, [0.27, 0.01, 2e-4, -3e-4, 5e-4, 0.6, 0.02, 0.001], "rational")
THIN_PRISM = Camera(
    1920,
    1080,
    900.0,
    905.0,
    962.3,
    541.7,
    [0.27, 0.01, 2e-4, -3e-4, 5e-4, 0.6, 0.02, 0.001, 1e-3, -2e-5, -8e-4, 3e-5],
    "thin-prism",
)
FISHEYE = Camera(1280, 1024, 520.0, 521.5, 641.2, 509.8, [0.02, -0.006, 0.001, -1e-4], "fisheye")
#: a 190-deg lens: boards up to 95 deg off axis
FISHEYE_190 = Camera(1280, 1024, 310.0, 310.0, 639.5, 511.5, [-0.012, 0.003, -6e-4, 5e-5], "fisheye")


def views(cam: Camera, n: int, seed: int, max_theta_deg: float, distance=(250.0, 600.0), noise=0.05):
    """``n`` views of BOARD through ``cam`` (:func:`circcal.fixtures.poses.off_axis_observations`)."""
    return off_axis_observations(cam, BOARD, n, seed, max_theta_deg, distance, noise)


def projection_difference(a: Camera, b: Camera, uv: np.ndarray) -> float:
    """Max |pixel difference| when ``b`` projects the rays ``a`` gives pixels ``uv`` (N, 2)."""
    return float(np.max(np.abs(project_camera(unproject(uv, a), b) - uv)))


def frame_grid(cam: Camera) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(0, cam.width - 1, 40), np.linspace(0, cam.height - 1, 24))
    return np.column_stack([u.ravel(), v.ravel()])


def opencv_pinhole(obj, img, cam: Camera, flags: int):
    out = cv2.calibrateCameraExtended(
        [o.astype(np.float32) for o in obj],
        [p.astype(np.float32) for p in img],
        (cam.width, cam.height),
        None,
        None,
        flags=flags,
        criteria=CRIT,
    )
    rms, K, d, std = out[0], out[1], np.ravel(out[2]), np.ravel(out[5])
    n = len(cam.dist)
    ref = Camera(cam.width, cam.height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], d[:n], cam.lens)
    return ref, rms, std[: 4 + n]


@pytest.mark.parametrize(
    "truth,flags",
    [
        (RATIONAL, cv2.CALIB_RATIONAL_MODEL),
        (THIN_PRISM, cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL),
    ],
    ids=["rational", "thin-prism"],
)
def test_pinhole_models_equal_opencv_on_identical_points(truth, flags, cv2_single_thread):
    """Same observations -> the same camera as cv2.calibrateCamera to 1e-6 px over every observed pixel, the same
    RMS and standard deviations (1 %), here over the whole frame too. Both models are nearly degenerate in (k1, k2,
    k3) against (k4, k5, k6) (a numerator root can cancel a denominator root): on some view sets (e.g. 20 views
    within 55 deg, seeds 1-2) the minimum is so flat that both solvers stop 1e-6 px apart and their covariances
    differ; 30 views up to 70 deg off axis (seed 3) fix it well."""
    obj, img = views(truth, 30, 3, 70)
    ref, ref_rms, ref_std = opencv_pinhole(obj, img, truth, flags)
    res = calibrate(obj, img, (truth.width, truth.height), CalibrationOptions(lens=truth.lens))
    assert res.converged and res.camera.lens == truth.lens
    assert res.errors["rms_per_point_px"] == pytest.approx(ref_rms, rel=1e-9)
    assert projection_difference(res.camera, ref, np.concatenate(img)) <= 1e-6
    assert projection_difference(res.camera, ref, frame_grid(truth)) <= 1e-6
    std = np.array([res.std[k] for k in param_names(truth.lens)])
    np.testing.assert_allclose(std, ref_std, rtol=0.01)


@pytest.mark.parametrize("truth", [FISHEYE], ids=["fisheye"])
def test_fisheye_equals_cv2_fisheye_calibrate(truth, cv2_single_thread):
    """Boards up to 75 deg off axis: circcal's fisheye solve equals cv2.fisheye.calibrate (RECOMPUTE_EXTRINSIC,
    FIX_SKEW) to 1e-6 px over the whole frame, and lies within a few sigmas of the truth."""
    obj, img = views(truth, 20, 2, 75, distance=(150.0, 400.0))
    flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW
    rms, K, D, _, _ = cv2.fisheye.calibrate(
        [o[None] for o in obj],
        [p[None] for p in img],
        (truth.width, truth.height),
        None,
        None,
        flags=flags,
        criteria=CRIT,
    )
    ref = Camera(truth.width, truth.height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], np.ravel(D), "fisheye")
    res = calibrate(obj, img, (truth.width, truth.height), CalibrationOptions(lens="fisheye"))
    assert res.converged and res.camera.lens == "fisheye"
    assert res.errors["rms_per_point_px"] == pytest.approx(rms, rel=1e-9)
    assert projection_difference(res.camera, ref, frame_grid(truth)) <= 1e-6
    err = np.abs(res.camera.intrinsics - truth.intrinsics)
    std = np.array([res.std[k] for k in param_names("fisheye")])
    assert np.all(err < 5 * std), err / std


def test_fisheye_start_and_solve_beyond_90_degrees():
    """A 190-deg lens with boards 95 deg off axis (cv2.fisheye cannot take them: it projects only z > 0): the
    equidistant start's focal length is within 10 % of the truth, and the noiseless solve recovers the camera to
    1e-6 px over its whole image."""
    obj, img = views(FISHEYE_190, 16, 3, 95, distance=(120.0, 300.0), noise=0.0)
    Xc_z = []
    cam0, rv, tv = fisheye_start(obj, img, (FISHEYE_190.width, FISHEYE_190.height))
    assert cam0.fy == pytest.approx(FISHEYE_190.fy, rel=0.1)
    res = calibrate(obj, img, (FISHEYE_190.width, FISHEYE_190.height), CalibrationOptions(lens="fisheye"))
    for o, r, t in zip(obj, res.rvecs, res.tvecs):
        Xc_z.append((o @ Rotation.from_rotvec(r).as_matrix().T + t)[:, 2])
    assert np.min(np.concatenate(Xc_z)) < 0  # some board points lie behind the camera
    grid = frame_grid(FISHEYE_190)
    grid = grid[np.all(np.isfinite(unproject(grid, FISHEYE_190)), axis=1)]
    assert projection_difference(FISHEYE_190, res.camera, grid) <= 1e-6


@pytest.mark.parametrize("truth,max_theta", [(FISHEYE, 75)], ids=["fisheye"])
def test_projection_uncertainty_matches_resolves(truth, max_theta):
    """The projection uncertainty is generic in the Jacobian (the pinhole models' covariance equals OpenCV's in
    test_pinhole_models_equal_opencv_on_identical_points; the rational model's re-solves are too often degenerate
    for a Monte-Carlo check): for the fisheye its prediction
    (worst-direction 1-sigma, at infinity, for 0.3 px of noise) matches the scatter of 24 re-solves with fresh
    noise (mean-frames reprojection, the quantity it describes) within 0.6-1.6x at the centre, mid-field and the
    observed edge."""
    from circcal.solver.uncertainty import mean_frames_reprojection, projection_covariance

    sigma = 0.3
    obj, clean = views(truth, 30, 3, max_theta, distance=(150.0, 500.0), noise=0.0)
    rng = np.random.default_rng(11)
    size = (truth.width, truth.height)
    # the solve of the noiseless observations (the truth): every re-solve scatters about it
    base = calibrate(obj, clean, size, CalibrationOptions(lens=truth.lens))
    allp = np.concatenate(clean)
    c = np.array([truth.cx, truth.cy])
    far = allp[np.argmax(np.linalg.norm(allp - c, axis=1))]
    uv = np.array([c, c + 0.5 * (far - c), c + 0.9 * (far - c)])
    pred = projection_covariance(base.camera, base.rvecs, base.tvecs, base.covariance, uv, sigma_px=sigma)
    d = []
    for _ in range(24):
        r = calibrate(obj, [p + rng.normal(0, sigma, p.shape) for p in clean], size, initial=base.camera)
        d.append(mean_frames_reprojection(base.camera, base.rvecs, base.tvecs, r.camera, r.rvecs, r.tvecs, uv) - uv)
    d = np.array(d)  # (24, 3, 2)
    emp = np.einsum("kni,knj->nij", d, d) / len(d)
    ratio = np.sqrt(np.linalg.eigvalsh(emp)[:, -1] / np.linalg.eigvalsh(pred)[:, -1])
    assert np.all((0.6 < ratio) & (ratio < 1.6)), ratio


@pytest.mark.parametrize(
    "truth,n,seed,max_theta,distance",
    [
        (RATIONAL, 30, 3, 70, (250.0, 600.0)),
        (THIN_PRISM, 30, 3, 70, (250.0, 600.0)),
        (FISHEYE, 20, 2, 75, (150.0, 400.0)),
    ],
    ids=["rational", "thin-prism", "fisheye"],
)
def test_opencv_reference_fits_every_lens(truth, n, seed, max_theta, distance):
    """The OpenCV reference adapter (validators/opencv.py) with ``lens=``: the matching OpenCV call reaches
    circcal's solve on the same float32 observations to 1e-6 px over the frame, with the standard deviations of
    calibrateCameraExtended (1 %) or none (cv2.fisheye gives none, said in the note)."""
    from circcal.validators import registry

    obj, img = views(truth, n, seed, max_theta, distance=distance)
    ref = registry.get_for_lens("opencv", truth.lens).calibrate_observations(obj, img, (truth.width, truth.height))
    assert ref.status == "ok", ref.message
    assert ref.camera.lens == truth.lens
    res = calibrate(obj, img, (truth.width, truth.height), CalibrationOptions(lens=truth.lens))
    assert projection_difference(res.camera, ref.camera, frame_grid(truth)) <= 1e-6
    if truth.lens == "fisheye":
        assert ref.std is None and "no standard deviations" in ref.extra["note"]
    else:
        names = param_names(truth.lens)
        np.testing.assert_allclose([ref.std[k] for k in names], [res.std[k] for k in names], rtol=0.01)
    # started from circcal's answer (CALIB_USE_INTRINSIC_GUESS), OpenCV stays there
    again = registry.get_for_lens("opencv", truth.lens).calibrate_observations(
        obj, img, (truth.width, truth.height), initial=res.camera
    )
    assert again.status == "ok" and projection_difference(res.camera, again.camera, frame_grid(truth)) <= 1e-6


def test_lens_choices_of_the_cli_are_the_models():
    from circcal.commands.args import LENS_CHOICES
    from circcal.model import LENS_MODELS

    assert tuple(LENS_CHOICES) == tuple(LENS_MODELS)


def test_cli_refuses_a_fisheye_cameramodel_before_the_work(tmp_path, capsys):
    from circcal.cli import main

    code = main(
        [
            "calibrate",
            str(tmp_path / "a.png"),
            "--grid",
            "7x7",
            "--pitch",
            "10mm",
            "--lens",
            "fisheye",
            "--out",
            str(tmp_path / "x.cameramodel"),
            "--no-progress",
        ]
    )
    assert code == 2 and "no equidistant" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # argparse's own usage error
        main(["calibrate", str(tmp_path / "a.png"), "--grid", "7x7", "--pitch", "10mm", "--lens", "kb8"])
    assert exc.value.code == 2


@pytest.fixture(scope="module")
def rational_images(tmp_path_factory):
    """9 exact renders (800x600) of a 7x9 board through a wide rational lens, boards up to 50 deg off axis."""
    from circcal.fixtures.render import render_view, to_uint

    cam = Camera(800, 600, 380.0, 381.0, 401.2, 299.7, [0.2, 0.01, 2e-4, -3e-4, 5e-4, 0.5, 0.01, 0.001], "rational")
    board = Board(7, 9, 15.0, 8.0)
    rng = np.random.default_rng(5)
    o = board.object_points()
    c = o.mean(axis=0)
    out, poses = tmp_path_factory.mktemp("rational"), []
    while len(poses) < 9:
        th = np.radians(rng.uniform(0, 50)) if poses else 0.0
        ph = rng.uniform(-np.pi, np.pi)
        d = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
        x = np.cross([0.0, 1.0, 0.0], d)
        x /= np.linalg.norm(x)
        ax = rng.normal(size=3)
        R = (
            np.column_stack([x, np.cross(d, x), d])
            @ Rotation.from_rotvec(ax / np.linalg.norm(ax) * np.radians(rng.uniform(15, 40))).as_matrix()
        )
        t = rng.uniform(220, 330) * d - R @ c
        rv = Rotation.from_rotvec(Rotation.from_matrix(R).as_rotvec()).as_rotvec()
        p = project(o, rv, t, cam)
        if np.all(p >= 15) and np.all(p[:, 0] <= cam.width - 16) and np.all(p[:, 1] <= cam.height - 16):
            poses.append((rv, t))
    paths = []
    for i, (rv, t) in enumerate(poses):
        paths.append(out / f"view{i:02d}.png")
        cv2.imwrite(str(paths[-1]), to_uint(render_view(cam, board, rv, t)))
    return cam, board, poses, paths


def test_pipeline_recorrects_through_the_rational_model(rational_images, tmp_path, capsys):
    """circcal calibrate --lens rational on exact renders of a wide rational lens: the re-corrected centres lie
    within 0.005 px RMS of the truth, fx within 0.05 px, the centres settle; model.json says the lens. The
    5-coefficient model on the same images leaves twice the residual (measured 0.0057 against 0.0027 px RMS per
    point: these views reach 50 deg, where the two models still nearly agree)."""
    import json

    from circcal.cli import main
    from circcal.pipeline import calibrate_images

    cam, board, poses, paths = rational_images
    out = tmp_path / "model.json"
    code = main(
        [
            "calibrate",
            *map(str, paths),
            "--grid",
            "7x9",
            "--pitch",
            "15mm",
            "--diameter",
            "8mm",
            "--lens",
            "rational",
            "--out",
            str(out),
            "--no-progress",
            "--jobs",
            "1",
        ]
    )
    assert code == 0
    doc = json.loads(out.read_text())
    assert doc["camera"]["lens"] == "rational" and len(doc["camera"]["dist"]) == 8
    assert doc["parameter_order"] == list(param_names("rational"))
    fitted = Camera.from_dict(doc["camera"])
    assert abs(fitted.fx - cam.fx) < 0.05 and abs(fitted.fy - cam.fy) < 0.05
    assert doc["recorrection_rounds"][-1]["max_centre_shift_px"] < 1e-4
    assert "rational" in capsys.readouterr().out
    cal = calibrate_images(paths, board, CalibrationOptions(lens="rational"), progress=False, jobs=1)
    truth = [project(board.object_points(), rv, t, cam) for rv, t in poses]
    err = np.concatenate([c - t for c, t in zip(cal.centres, truth)])
    assert np.sqrt(np.nanmean(np.sum(err**2, axis=1))) <= 0.005
    plain = calibrate_images(paths, board, progress=False, jobs=1)
    assert plain.result.errors["rms_per_point_px"] > 1.5 * cal.result.errors["rms_per_point_px"]


def test_fixing_a_coefficient_the_lens_lacks_is_bad_input():
    from circcal.errors import InputError

    obj, img = views(FISHEYE, 6, 2, 60, distance=(150.0, 400.0))
    with pytest.raises(InputError, match="no p1, p2"):
        calibrate(
            obj,
            img,
            (FISHEYE.width, FISHEYE.height),
            CalibrationOptions.from_flags(lens="fisheye", fix_tangential=True),
        )
    res = calibrate(
        obj, img, (FISHEYE.width, FISHEYE.height), CalibrationOptions.from_flags(lens="fisheye", fix_k3=True)
    )
    assert res.camera.dist[2] == 0.0 and res.std["k3"] == 0.0 and "k3" in res.fixed


def test_opencv_fisheye_beyond_90_degrees_is_unsupported_with_the_reason():
    """cv2.fisheye works on the z = 1 plane: boards reaching past 90 deg (the 190-deg lens) make its calibrate fail
    an assertion; the reference reports that as unsupported, saying why, while circcal's solve takes them."""
    from circcal.validators import registry

    obj, img = views(FISHEYE_190, 16, 3, 95, distance=(120.0, 300.0))
    ref = registry.get_for_lens("opencv", "fisheye").calibrate_observations(obj, img, (1280, 1024))
    assert ref.status == "unsupported" and "90 deg" in ref.message
    res = calibrate(obj, img, (1280, 1024), CalibrationOptions(lens="fisheye"))
    assert res.converged and res.errors["rms_per_coord_px"] < 0.1


def test_opencv_fisheye_returning_negative_focal_lengths_beyond_90_degrees_is_unsupported(monkeypatch):
    """OpenCV 5.1's cv2.fisheye.calibrate no longer fails its assertion on the 190-deg lens's views: it returns
    fx = -15647 px (measured). The reference says why, as for 5.0's assertion (pip installs 5.1; ``make setup`` 5.0,
    so 5.1's return is imitated here)."""
    import cv2

    from circcal.validators import registry

    def like_51(obj, img, size, K, d, flags=0, criteria=None):
        K = np.array([[-15647.2, 0, 640], [0, -16023.4, 512], [0, 0, 1]], float)
        return 1e3, K, np.zeros((4, 1)), [np.zeros(3)] * len(obj), [np.zeros(3)] * len(obj)

    monkeypatch.setattr(cv2.fisheye, "calibrate", like_51)
    obj, img = views(FISHEYE_190, 16, 3, 95, distance=(120.0, 300.0))
    ref = registry.get_for_lens("opencv", "fisheye").calibrate_observations(obj, img, (1280, 1024))
    assert ref.status == "unsupported" and "90 deg" in ref.message and "fx = -15647.2" in ref.message
    # within 90 deg the same return is OpenCV's failure, said as such
    obj, img = views(FISHEYE, 20, 2, 75, distance=(150.0, 400.0))
    ref = registry.get_for_lens("opencv", "fisheye").calibrate_observations(obj, img, (1280, 1024))
    assert ref.status == "failed" and "fx = -15647.2" in ref.message


def test_rational_wide_recorrection_settles_within_the_default_rounds():
    """The rational model on the wide lens converges slowly (each round's centre shift ~5-10x the next): it settles
    below the pipeline's 1e-4 px within MAX_ROUNDS calibrations, without the 'did not settle' warning."""
    import warnings

    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth
    from circcal.pipeline import MAX_ROUNDS, calibrate_images

    t = load_truth(fixture_dir("rational-wide", "clean"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cal = calibrate_images([v.image for v in t.views], t.board, CalibrationOptions(lens="rational"), progress=False)
    assert not [w for w in caught if "did not settle" in str(w.message)]
    assert len(cal.rounds) <= MAX_ROUNDS and cal.rounds[-1]["max_centre_shift_px"] < 1e-4
    assert cal.rounds[1]["max_centre_shift_px"] > 1e-2  # the slow case this default is for, not a settled one


def test_a_rational_model_the_views_cannot_determine_is_named_not_blamed_on_the_focal_length():
    """A 512x384 rational camera of the `two` rig at 0.1 px noise (draw 10 of 16): the solve ends with a singular
    information matrix whose weak direction lies in k1, k2, k4, k5 (the numerator's terms against the
    denominator's), not in f: the error names the coefficients and the way out, not tilted views."""
    from circcal.errors import CalibrationError, DegenerateViewsError
    from circcal.fixtures.rig import rig_observations, rig_scenario
    from circcal.solver import CalibrationOptions, calibrate

    obs = rig_observations(rig_scenario("two"), 0.1, 10)["right"]
    with pytest.raises(CalibrationError) as e:
        calibrate(
            [v[0] for v in obs.values()], [v[1] for v in obs.values()], (512, 384), CalibrationOptions(lens="rational")
        )
    assert not isinstance(e.value, DegenerateViewsError)
    msg = str(e.value)
    assert "rational lens model's" in msg and "k4" in msg and "--lens opencv5" in msg and "\n" not in msg
    # the 5-coefficient model of the same views is determined
    res = calibrate([v[0] for v in obs.values()], [v[1] for v in obs.values()], (512, 384))
    assert abs(res.camera.fx - 450.0) < 3 * res.std["fx"] + 1.0
