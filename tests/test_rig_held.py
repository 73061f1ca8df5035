"""A rig camera whose intrinsics are given and held (``cv2.stereoCalibrate``'s ``CALIB_FIX_INTRINSIC`` workflow:
each camera calibrated alone on many views, the rig on a few shared ones) needs one shared view, not a calibration's
three (circcal/rig/held.py). On the rendered ``two`` rig (a 640x480 opencv5 camera and a 512x384 rational one) with
the rational camera's true intrinsics held and 1-2 of its 14 images, against the exact truth."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from circcal.cli import main
from circcal.errors import InputError
from circcal.fixtures.rig import rig_fixture_dir, rig_observations, rig_scenario
from circcal.formats import write_camera
from circcal.pipeline import TooFewImagesError
from circcal.rig import calibrate_rig, calibrate_rig_points
from circcal.rig.crossval import cross_validate_rig
from circcal.rig.held import LocatedImages, is_held
from circcal.rotation import rotation_angle_deg
from circcal.solver import CalibrationOptions

#: |estimate - truth| in stated sigmas for the pose of the camera (6 parameters; a bound as RIG_TRUTH_SIGMAS').
POSE_SIGMAS = 4.0


@pytest.fixture(scope="module")
def two():
    sc = rig_scenario("two")
    folder = rig_fixture_dir("two")
    images = {n: sorted(str(p) for p in (folder / n).glob("*.png")) for n in sc.rig.names}
    right = sc.rig.cameras[1]
    opts = {"left": CalibrationOptions(), "right": CalibrationOptions(lens="rational", fixed=right.model.param_names)}
    return sc, images, opts


def _pose_sigmas(res, sc) -> np.ndarray:
    """|rvec, tvec of camera 1 - truth| in its stated sigmas."""
    x = np.concatenate([res.rig.rvecs[1], res.rig.tvecs[1]])
    t = np.concatenate([sc.rig.rvecs[1], sc.rig.tvecs[1]])
    n = sum(len(c.intrinsics) for c in res.rig.cameras)
    sd = np.sqrt(np.diag(res.rig.covariance)[n : n + 6])
    return np.abs(x - t) / sd


@pytest.mark.parametrize("keep", [1, 2])
def test_a_held_camera_with_one_or_two_views_gives_the_rig(two, keep):
    sc, images, opts = two
    shared = [p for p in images["right"] if p.rsplit("/", 1)[-1] in {q.rsplit("/", 1)[-1] for q in images["left"]}]
    few = {"left": images["left"], "right": shared[:keep]}
    res = calibrate_rig(few, sc.board, opts, jobs=1, initial={"right": sc.rig.cameras[1]})
    found = res.per_camera["right"]
    assert isinstance(found, LocatedImages) and len(found.used) == keep  # searched, not calibrated alone
    assert len(res.instants["right"]) == keep
    assert np.array_equal(res.rig.cameras[1].intrinsics, sc.rig.cameras[1].intrinsics)
    (R, T), (Rt, Tt) = res.rig.pair(0, 1), sc.rig.pair(0, 1)
    # measured: 1 view 0.0017 deg, 0.020 mm; 2 views 0.0011 deg, 0.017 mm (all 14 views, held: 0.0019 deg, 0.025 mm)
    assert rotation_angle_deg(R @ Rt.T) < 0.01 and np.linalg.norm(T - Tt) < 0.06
    assert np.all(_pose_sigmas(res, sc) < POSE_SIGMAS), _pose_sigmas(res, sc)
    cv = cross_validate_rig(res, opts)
    if keep == 1:  # one view cannot be halved: said, not a failure
        assert cv.status == "too-few-instants" and "right (1)" in cv.message
    else:  # one view per half is enough for a held camera's pose
        assert cv.status == "ok" and cv.held == ["right"] and cv.verdict == "consistent", cv.message


def test_a_camera_not_held_still_needs_three_views_and_is_told_how_to_do_with_fewer(two):
    sc, images, opts = two
    few = {"left": images["left"], "right": images["right"][:2]}
    free = {**opts, "right": CalibrationOptions(lens="rational")}
    with pytest.raises(TooFewImagesError, match=r"camera 'right': the board was found in 2 of 2 .*--intrinsics right="):
        calibrate_rig(few, sc.board, free, jobs=1)


def test_a_held_camera_whose_board_is_found_nowhere_is_refused(two, tmp_path):
    sc, images, opts = two
    blank = tmp_path / "blank.png"
    import cv2

    cv2.imwrite(str(blank), np.full((384, 512), 200, np.uint8))
    with pytest.raises(TooFewImagesError, match=r"camera 'right': the board was found in none of its 1 images"):
        calibrate_rig(
            {"left": images["left"], "right": [str(blank)]}, sc.board, opts, initial={"right": sc.rig.cameras[1]}
        )


def test_a_held_camera_of_another_lens_is_refused_before_its_images(two):
    sc, images, opts = two
    with pytest.raises(InputError, match="initial: camera 'right' has lens 'rational', its options lens='opencv5'"):
        calibrate_rig(images, sc.board, {**opts, "right": CalibrationOptions()}, initial={"right": sc.rig.cameras[1]})


def test_points_api_takes_a_held_camera_with_one_view():
    sc = rig_scenario("two")
    obs = rig_observations(sc, noise_px=0.02, seed=3)
    right = sc.rig.cameras[1]
    opts = {"left": CalibrationOptions(), "right": CalibrationOptions(lens="rational", fixed=right.model.param_names)}
    assert is_held(right, opts["right"]) and not is_held(right, CalibrationOptions(lens="rational"))
    shared = next(v for v in obs["right"] if v in obs["left"])
    one = {"left": dict(obs["left"]), "right": {shared: obs["right"][shared]}}
    sizes = {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    with pytest.raises(InputError, match="at least 3"):  # not held: a calibration's three views
        calibrate_rig_points(one, sizes, {**opts, "right": CalibrationOptions(lens="rational")})
    res = calibrate_rig_points(one, sizes, opts, initial={"left": sc.rig.cameras[0], "right": right})
    assert np.all(_pose_sigmas(res, sc) < POSE_SIGMAS), _pose_sigmas(res, sc)


def test_cli_holds_a_camera_with_two_images(two, tmp_path, capsys):
    sc, images, _ = two
    right = tmp_path / "right"
    right.mkdir()
    shared = [p for p in images["right"] if p.rsplit("/", 1)[-1] in {q.rsplit("/", 1)[-1] for q in images["left"]}]
    for p in shared[:2]:
        shutil.copy(p, right)
    base = ["calibrate-rig", "--camera", f"left={rig_fixture_dir('two') / 'left'}", "--camera", f"right={right}"]
    base += ["--grid", "8x11", "--pitch", "15mm", "--lens", "right=rational", "--out", str(tmp_path / "rig.json")]
    assert main(base) == 2  # refused before any work, and told how
    err = capsys.readouterr().err
    assert "--camera right: 2 image(s)" in err and "--intrinsics right=MODEL_FILE" in err
    assert not (tmp_path / "rig.json").exists()
    write_camera(tmp_path / "right.json", sc.rig.cameras[1])
    assert main([*base, "--intrinsics", f"right={tmp_path / 'right.json'}"]) == 0
    out = capsys.readouterr().out
    assert "camera right: 512x384" in out and "2 views used" in out and "(held)" in out
    # its coverage here is not its lens's: no "extrapolated" warning of its own
    held_lines = out.split("  right: ", 1)[1].split("\n  the field", 1)[0]
    assert "intrinsics are held (given)" in held_lines and "extrapolated" not in held_lines
    assert (tmp_path / "rig.json").exists()
