"""The rig end to end on rendered images with exact truth (fixture "two": a 640x480 opencv5 camera and a 512x384
rational one, instants seen by one camera only): detection, per-camera calibration, the joint solve and the
re-correction loop."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from circcal.errors import InputError
from circcal.fixtures.rig import rig_fixture_dir, rig_scenario
from circcal.model import project
from circcal.rig import calibrate_rig
from circcal.rotation import rodrigues, rotation_angle_deg
from circcal.solver import CalibrationOptions


@pytest.fixture(scope="module")
def rendered():
    sc = rig_scenario("two")
    folder = rig_fixture_dir("two")
    images = {n: sorted(str(p) for p in (folder / n).glob("*.png")) for n in sc.rig.names}
    opts = {"left": CalibrationOptions(), "right": CalibrationOptions(lens="rational")}
    return sc, images, calibrate_rig(images, sc.board, opts, jobs=1)


def test_rendered_rig_recovered(rendered):
    sc, images, res = rendered
    assert len(images["left"]) != len(images["right"])  # some instants are seen by one camera only
    assert set(res.instants["left"]) ^ set(res.instants["right"])
    assert not res.dropped and res.rounds[-1]["max_centre_shift_px"] < 1e-4
    R, T = res.rig.pair(0, 1)
    Rt, Tt = sc.rig.pair(0, 1)
    rot_err_deg = rotation_angle_deg(R @ Rt.T)
    assert rot_err_deg < 0.02
    assert np.linalg.norm(T - Tt) < 0.2
    for n in sc.rig.names:
        assert res.rms_px[n] < 0.02
    # each camera's projection of the board points it saw (the instants it used), against its truth
    for c, (cam, true_cam) in enumerate(zip(res.rig.cameras, sc.rig.cameras)):
        Rc, Tc = sc.rig.pose(c)
        P = sc.board.object_points()
        used = [sc.instants.index(v) for v in res.instants[sc.rig.names[c]]]
        Xc = np.concatenate([(P @ rodrigues(sc.board_rvecs[k]).T + sc.board_tvecs[k]) @ Rc.T + Tc for k in used])
        truth = project(Xc, np.zeros(3), np.zeros(3), true_cam)
        seen = (truth[:, 0] > 0) & (truth[:, 0] < cam.width) & (truth[:, 1] > 0) & (truth[:, 1] < cam.height)

        def rms(camera):
            d = project(Xc[seen], np.zeros(3), np.zeros(3), camera) - truth[seen]  # noqa: B023
            return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))

        # the 0.01 px is met by the rational camera (14 views); the opencv5 one, 11 whole views of a small
        # board in 8 bits, reaches 0.0156 px (alone: 0.0170): the joint solve must not be worse than the camera alone.
        # Bound 0.02 px (was 0.015 at 0.012 measured): since the bad-dot rules follow a wide lens (cb75498) the
        # rational camera keeps 9 thin dots at the edge of view 015 (each within 0.020 px of its truth), which the
        # joint solve shares with camera 0 through the board poses
        alone = res.per_camera[sc.rig.names[c]].result.camera
        assert rms(cam) < 0.02 and rms(cam) < 1.05 * rms(alone), (c, rms(cam), rms(alone))


def test_rendered_rig_json_round_trip(rendered):
    _, _, res = rendered
    d = res.rig.to_dict()
    assert d["format"] == "circcal-rig" and len(d["cameras"]) == 2
    assert np.allclose(d["cameras"][1]["tvec"], res.rig.tvecs[1])
    assert res.rig.covariance is not None and np.all(np.isfinite(res.rig.covariance))


def test_a_given_model_file_is_read_before_any_image(rendered, monkeypatch, tmp_path):
    import circcal.rig.calibrate as rig_calibrate

    sc, images, _ = rendered

    def no_work(*args, **kwargs):
        raise AssertionError("an image was calibrated before the model file was read")

    monkeypatch.setattr(rig_calibrate, "calibrate_images", no_work)
    with pytest.raises(InputError, match="none.yaml"):
        calibrate_rig(images, sc.board, jobs=1, initial={"right": tmp_path / "none.yaml"})


def test_one_cameras_given_intrinsics_are_held_the_others_solved(rendered):
    """calibrate_rig(initial=) with one camera of the two: the rational camera held at its truth (every parameter
    fixed, CALIB_FIX_INTRINSIC), the pinhole one refined with the rig; the rig no farther from the truth than the
    default run's bounds, the pinhole camera's intrinsics moved from its own calibration's start."""
    sc, images, default = rendered
    right = sc.rig.cameras[1]
    opts = {"left": CalibrationOptions(), "right": CalibrationOptions(lens="rational", fixed=right.model.param_names)}
    res = calibrate_rig(images, sc.board, opts, jobs=1, initial={"right": right})
    assert np.array_equal(res.rig.cameras[1].intrinsics, right.intrinsics)
    assert not np.array_equal(res.rig.cameras[0].intrinsics, res.per_camera["left"].result.camera.intrinsics)
    (R, T), (Rt, Tt) = res.rig.pair(0, 1), sc.rig.pair(0, 1)
    assert rotation_angle_deg(R @ Rt.T) < 0.02 and np.linalg.norm(T - Tt) < 0.2
    with pytest.raises(InputError, match="initial: cameras"):
        calibrate_rig(images, sc.board, opts, jobs=1, initial={"middle": right})


def test_a_fisheyes_far_small_dots_are_kept_and_the_rig_recovered():
    """The rendered ``fisheye`` rig: its 640x480 fisheye sees the board small, the far dots 2.9-4.4 px across. With
    the candidate floor at 12 px^2 the fisheye kept 4 of its 14 views (none shared with the pinhole camera: no rig);
    at 6 px^2 (measured: circcal/detector/locate/candidates.py) 13, the one lost with dots under 3 px."""
    from circcal.validators.rig import compare_rigs

    sc = rig_scenario("fisheye")
    folder = rig_fixture_dir("fisheye")
    images = {n: sorted(str(p) for p in (folder / n).glob("*.png")) for n in sc.rig.names}
    opts = {n: CalibrationOptions(lens=c.lens) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    res = calibrate_rig(images, sc.board, opts, jobs=1)
    assert len(res.instants["fish"]) >= 13 and len(res.instants["pinhole"]) == len(images["pinhole"])
    truth = sc.truth_points()
    for n in sc.rig.names:  # every centre used against its truth
        for v, (obj, uv) in res.observations[n].items():
            k = [int(np.flatnonzero(np.all(np.isclose(sc.board.object_points(), p), axis=1))[0]) for p in obj]
            e = uv - truth[n][v][k]
            assert np.sqrt(np.mean(e**2)) < 0.012, (n, v, np.sqrt(np.mean(e**2)))
    # the `two` rig's end-to-end bounds (test_rendered_rig_recovered); measured 0.011 deg, 0.044 mm
    a = compare_rigs(res.rig, sc.rig)
    assert a.rotation_deg[1] < 0.02 and a.position_mm[1] < 0.2, (a.rotation_deg, a.position_mm)


def test_parts_of_an_unmarked_board_are_placed_by_the_rig(tmp_path):
    """The `two` rig rendered with its partial views too (8x11 symmetric board, no markers): the detector refuses a
    part of the board it cannot place on its own (several places fit), and the rig places it where its other
    camera puts the board at that instant (measured: 5 views, left 000 002 013, right 014 016; their centres
    0.0016-0.0056 px RMS from the true projections; the rig 0.0011 deg, 0.019 mm from the truth)."""
    from circcal.fixtures.rig import render_rig
    from circcal.model import project_camera
    from circcal.validators.rig import compare_rigs

    sc = rig_scenario("two")
    render_rig(sc, tmp_path, partial=True)
    images = {n: sorted(str(p) for p in (tmp_path / n).glob("*.png")) for n in sc.rig.names}
    opts = {"left": CalibrationOptions(), "right": CalibrationOptions(lens="rational")}
    with warnings.catch_warnings():  # the rational camera's own start and its valley (test_rig_calibrate.py)
        warnings.simplefilter("ignore", RuntimeWarning)
        res = calibrate_rig(images, sc.board, opts, jobs=1)
    assert sum(len(v) for v in res.placed.values()) >= 4, res.placed
    for n, placed in res.placed.items():
        c = sc.rig.names.index(n)
        Rc, Tc = sc.rig.pose(c)
        for v in placed:
            obj, uv = res.observations[n][v]
            k = sc.instants.index(v)
            X = (obj @ rodrigues(sc.board_rvecs[k]).T + sc.board_tvecs[k]) @ Rc.T + Tc
            e = uv - project_camera(X, sc.rig.cameras[c])
            assert len(uv) < sc.board.n_points and np.sqrt(np.mean(e**2)) < 0.01, (n, v, np.sqrt(np.mean(e**2)))
    a = compare_rigs(res.rig, sc.rig)
    assert a.rotation_deg[1] < 0.02 and a.position_mm[1] < 0.2, (a.rotation_deg, a.position_mm)


def test_calibrate_rig_says_which_parts_the_rig_placed(tmp_path, capsys):
    """The console and rig.json name the placed views; the per-camera 'image left out' lines no longer list them."""
    import json

    from circcal.cli import main
    from circcal.fixtures.rig import render_rig

    render_rig(rig_scenario("two"), tmp_path / "img", partial=True)
    out = tmp_path / "rig.json"
    argv = ["calibrate-rig", "--camera", f"left={tmp_path / 'img' / 'left'}", "--camera"]
    argv += [f"right={tmp_path / 'img' / 'right'}", "--grid", "8x11", "--pitch", "15mm", "--lens", "right=rational"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert main([*argv, "--out", str(out), "--no-progress", "--no-cross-validate"]) == 0
    text = capsys.readouterr().out
    placed = json.loads(out.read_text())["placed"]
    assert placed and all(placed.values())
    for name, views in placed.items():
        assert f"placed where the other cameras put the board: {', '.join(views)}" in text
        for v in views:
            assert f"image left out: {tmp_path / 'img' / name / v}" not in text
