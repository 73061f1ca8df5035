"""circcal.rig.files: each rig file written, read back, and checked against its own tool where installed."""

from __future__ import annotations

import json
import subprocess

import cv2
import numpy as np
import pytest

from circcal.errors import InputError, ModelFileError
from circcal.formats.mrcal_process import mrcal_python
from circcal.model import Camera, project
from circcal.rig import RigModel
from circcal.rig.files import (
    M_PER_MM,
    essential_fundamental,
    kalibr_camchain_text,
    mrcal_cameramodel_texts,
    opencv_stereo_from_text,
    opencv_stereo_text,
    read_kalibr_camchain,
    read_mrcal_cameramodels,
    read_opencv_stereo,
    read_ros_pair,
    ros_camera_info_pair,
)
from circcal.rig.rectify import rectify_pair

A = Camera(1280, 960, 1010.0, 1005.0, 650.0, 470.0, [-0.2, 0.08, 0.001, -0.0005, -0.01])
B = Camera(640, 480, 590.0, 595.0, 330.0, 250.0, [0.1, -0.05, 0.0005, 0.0002, 0.01, 0.2, -0.04, 0.02], "rational")
C = Camera(1280, 960, 990.0, 995.0, 630.0, 490.0, [-0.15, 0.05, -0.001, 0.0008, 0.0])
F = Camera(800, 600, 300.0, 301.0, 401.0, 299.0, [0.02, -0.005, 0.001, -0.0002], "fisheye")
ROT = [[0, 0, 0], [0.02, -0.05, 0.01], [-0.1, 0.2, 0.05]]
TRA = [[0, 0, 0], [-120.0, 3.0, 2.0], [60.0, -80.0, 10.0]]


def _rig(*cams: Camera) -> RigModel:
    n = len(cams)
    return RigModel(["left", "right", "top"][:n], cams, ROT[:n], TRA[:n])


def _same(a: RigModel, b: RigModel, tol: float = 1e-9) -> None:
    assert a.n_cameras == b.n_cameras
    for ca, cb in zip(a.cameras, b.cameras):
        assert (ca.width, ca.height, ca.lens) == (cb.width, cb.height, cb.lens)
        assert np.abs(ca.intrinsics - cb.intrinsics).max() < tol
    assert np.abs(a.rvecs - b.rvecs).max() < tol
    assert np.abs(a.tvecs - b.tvecs).max() < tol * 1e3


@pytest.mark.parametrize("cams", [(A, B), (A, C), (F, F)], ids=["sizes differ", "one size", "fisheye"])
def test_opencv_stereo_round_trip(tmp_path, cams) -> None:
    rig = _rig(*cams)
    text = opencv_stereo_text(rig)
    (tmp_path / "stereo.yaml").write_text(text)
    back = read_opencv_stereo(tmp_path / "stereo.yaml")
    _same(rig, back)
    assert back.names == ("left", "right")
    # OpenCV reads every node, as the stereo_calib sample's reader would
    fs = cv2.FileStorage(str(tmp_path / "stereo.yaml"), cv2.FILE_STORAGE_READ)
    R, T = rig.pair(0, 1)
    E, Fm = essential_fundamental(rig)
    rect = rectify_pair(rig)
    for key, want in (
        ("M1", rig.cameras[0].K),
        ("M2", rig.cameras[1].K),
        ("R", R),
        ("T", T.reshape(3, 1)),
        ("E", E),
        ("F", Fm),
        ("R1", rect.R1),
        ("R2", rect.R2),
        ("P1", rect.P1),
        ("P2", rect.P2),
        ("Q", rect.Q),
    ):
        assert np.abs(fs.getNode(key).mat() - want).max() <= 1e-12 * max(1.0, np.abs(want).max()), key
    assert fs.getNode("D2").mat().size == len(rig.cameras[1].dist)
    fs.release()


def test_e_and_f_are_stereo_calibrates() -> None:
    """cv2.stereoCalibrate with the intrinsics fixed, on exact projections of a board, returns R, T, E, F."""
    rig = _rig(A, C)
    grid = np.array([[x * 20.0, y * 20.0, 0.0] for y in range(7) for x in range(9)])
    obj, q1, q2 = [], [], []
    rng = np.random.default_rng(0)
    for _ in range(6):
        rv = rng.normal(0, 0.2, 3) + [np.pi, 0, 0]
        tv = np.array([-80.0, -60.0, 700.0]) + rng.normal(0, 30, 3)
        X0 = grid @ cv2.Rodrigues(rv)[0].T + tv  # board in the rig frame
        obj.append(grid.astype(np.float32))
        q1.append(project(X0, rig.rvecs[0], rig.tvecs[0], A).astype(np.float32))
        q2.append(project(X0, rig.rvecs[1], rig.tvecs[1], C).astype(np.float32))
    out = cv2.stereoCalibrate(obj, q1, q2, A.K, A.dist, C.K, C.dist, (1280, 960), flags=cv2.CALIB_FIX_INTRINSIC)
    R_cv, T_cv, E_cv, F_cv = out[5], out[6], out[7], out[8]
    R, T = rig.pair(0, 1)
    E, Fm = essential_fundamental(rig)
    assert np.abs(R_cv - R).max() < 1e-4 and np.abs(T_cv.ravel() - T).max() < 0.05
    assert np.abs(E_cv - E).max() < 0.05 * np.abs(E).max()
    assert np.abs(F_cv - Fm).max() < 1e-3 * np.abs(Fm).max()
    # and the epipolar constraint holds on undistorted pixels
    u1 = cv2.undistortPoints(q1[0].reshape(-1, 1, 2), A.K, A.dist, P=A.K).reshape(-1, 2)
    u2 = cv2.undistortPoints(q2[0].reshape(-1, 1, 2), C.K, C.dist, P=C.K).reshape(-1, 2)
    h1, h2 = np.c_[u1, np.ones(len(u1))], np.c_[u2, np.ones(len(u2))]
    lines = h1 @ Fm.T
    dist = np.abs(np.sum(h2 * lines, axis=1)) / np.linalg.norm(lines[:, :2], axis=1)
    assert dist.max() < 1e-3


def test_opencv_stereo_refusals(tmp_path) -> None:
    text = opencv_stereo_text(_rig(A, B))
    with pytest.raises(ModelFileError, match="image_width2"):
        opencv_stereo_from_text(text.replace("image_width2", "other"))
    bad = cv2.FileStorage(".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    for k, v in (("M1", A.K), ("D1", A.dist[None]), ("M2", A.K), ("D2", A.dist[None]), ("R", 2 * np.eye(3))):
        bad.write(k, v)
    bad.write("T", np.zeros((3, 1)))
    for k in ("image_width1", "image_width2"):
        bad.write(k, 1280)
    for k in ("image_height1", "image_height2"):
        bad.write(k, 960)
    with pytest.raises(ModelFileError, match="not a rotation"):
        opencv_stereo_from_text(bad.releaseAndGetString())
    with pytest.raises(InputError, match="no such file"):
        read_opencv_stereo(tmp_path / "none.yaml")
    (tmp_path / "junk.yaml").write_text("%YAML:1.0\nM1: [1, 2\n")
    with pytest.raises(ModelFileError, match="junk.yaml"):
        read_opencv_stereo(tmp_path / "junk.yaml")


@pytest.mark.parametrize("cams", [(A, B), (A, C), (F, F)], ids=["sizes differ", "one size", "fisheye"])
def test_ros_pair_round_trip(cams) -> None:
    rig = _rig(*cams)
    left, right = ros_camera_info_pair(rig)
    rect = rectify_pair(rig)
    import yaml

    dr = yaml.safe_load(right)
    P = np.array(dr["projection_matrix"]["data"]).reshape(3, 4)
    assert np.allclose(P[:, :3], rect.P2[:, :3]) and np.allclose(P[:, 3], rect.P2[:, 3] * M_PER_MM)
    baseline_m = -P[0, 3] / P[0, 0]  # stereo_image_proc's baseline, metres
    assert baseline_m == pytest.approx(rig.baseline_mm() * M_PER_MM, rel=0.05)
    assert np.allclose(np.array(dr["rectification_matrix"]["data"]).reshape(3, 3), rect.R2)
    _same(rig, read_ros_pair(left, right))
    with pytest.raises(ModelFileError, match="rectification_matrix"):
        read_ros_pair(left.replace("rectification_matrix", "x_matrix"), right)


def test_ros_refuses_thin_prism() -> None:
    tp = Camera(640, 480, 500.0, 500.0, 320.0, 240.0, [0.0] * 8 + [0.001, 0.0, 0.0, 0.0], "thin-prism")
    with pytest.raises(InputError, match="thin-prism"):
        ros_camera_info_pair(_rig(A, tp))


def test_mrcal_round_trip_and_reference() -> None:
    rig = _rig(A, B, C)
    texts = mrcal_cameramodel_texts(rig)
    assert list(texts) == list(rig.names)
    _same(rig, read_mrcal_cameramodels(texts))
    # another reference: the rig comes back relative to the first file given
    back = read_mrcal_cameramodels({n: texts[n] for n in ("right", "left", "top")})
    assert back.names == ("right", "left", "top")
    R, T = rig.pair(1, 2)
    assert np.allclose(back.pose(2)[0], R) and np.allclose(back.tvecs[2], T)
    with pytest.raises(InputError, match="fisheye"):
        mrcal_cameramodel_texts(_rig(A, F))


@pytest.mark.skipif(mrcal_python()[0] is None, reason="mrcal not installed")
def test_mrcal_reads_the_files(tmp_path) -> None:
    rig = _rig(A, B, C)
    paths = []
    for name, text in mrcal_cameramodel_texts(rig).items():
        p = tmp_path / f"{name}.cameramodel"
        p.write_text(text)
        paths.append(str(p))
    script = (
        "import json, sys, mrcal\n"
        "out = []\n"
        "for p in sys.argv[1:]:\n"
        "    m = mrcal.cameramodel(p)\n"
        "    out.append({'rt': m.extrinsics_rt_fromref().tolist(), 'intrinsics': m.intrinsics()[1].tolist(),\n"
        "                'lensmodel': m.intrinsics()[0], 'size': m.imagersize().tolist()})\n"
        "print(json.dumps(out))\n"
    )
    res = subprocess.run([mrcal_python()[0], "-c", script, *paths], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    got = json.loads(res.stdout)
    for k, g in enumerate(got):
        assert np.allclose(g["rt"][:3], rig.rvecs[k], atol=1e-12)
        assert np.allclose(np.array(g["rt"][3:]) / M_PER_MM, rig.tvecs[k], atol=1e-9)
        assert np.allclose(g["intrinsics"], rig.cameras[k].intrinsics)
        assert g["size"] == [rig.cameras[k].width, rig.cameras[k].height]


def test_kalibr_round_trip() -> None:
    A4 = Camera(1280, 960, 1010.0, 1005.0, 650.0, 470.0, [-0.2, 0.08, 0.001, -0.0005, 0.0])
    rig = _rig(A4, C, F)
    text = kalibr_camchain_text(rig)
    import yaml

    d = yaml.safe_load(text)
    assert list(d) == ["cam0", "cam1", "cam2"]
    assert d["cam1"]["distortion_model"] == "radtan" and d["cam2"]["distortion_model"] == "equidistant"
    T = np.array(d["cam2"]["T_cn_cnm1"])
    R, t = rig.pair(1, 2)
    assert np.allclose(T[:3, :3], R) and np.allclose(T[:3, 3], t * M_PER_MM) and "T_cn_cnm1" not in d["cam0"]
    back = read_kalibr_camchain(text)
    assert back.names == ("cam0", "cam1", "cam2")
    _same(rig, back)


def test_kalibr_refusals() -> None:
    with pytest.raises(InputError, match="k3 = -0.01"):
        kalibr_camchain_text(_rig(A, C))
    with pytest.raises(InputError, match="k4"):
        kalibr_camchain_text(_rig(C, B))
    A4 = Camera(1280, 960, 1010.0, 1005.0, 650.0, 470.0, [-0.2, 0.08, 0.001, -0.0005, 0.0])
    text = kalibr_camchain_text(_rig(A4, C))
    with pytest.raises(ModelFileError, match="omni"):
        read_kalibr_camchain(text.replace("camera_model: pinhole", "camera_model: omni", 1))
    with pytest.raises(ModelFileError, match="T_cn_cnm1"):
        read_kalibr_camchain(text.replace("T_cn_cnm1", "T_other"))
    with pytest.raises(ModelFileError, match="cam0"):
        read_kalibr_camchain("cam1: {}\n")
