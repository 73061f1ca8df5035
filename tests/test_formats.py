"""Camera-model files: round trips for every format, OpenCV and COLMAP (pycolmap) reading ours, the COLMAP offset."""

import json
import shutil
import subprocess

import cv2
import numpy as np
import pytest

from circcal.cli import main
from circcal.formats import (
    camera_from_cameramodel,
    camera_from_colmap,
    camera_from_ros_yaml,
    camera_to_cameramodel,
    camera_to_colmap,
    camera_to_ros_yaml,
    detect_format,
    read_camera,
    write_camera,
)
from circcal.model import Camera, project

CAM = Camera(
    1920,
    1080,
    1498.123456789012,
    1500.987654321098,
    955.4321,
    545.6789,
    np.array([-0.2012345678901, 0.1023456789, 0.00123456789, -0.000567891234, -0.0234567891]),
)
CAM_NO_K3 = Camera(640, 480, 500.5, 501.25, 320.1, 239.9, np.array([0.1, -0.05, 0.001, 0.002, 0.0]))


def same(a: Camera, b: Camera, tol=0.0):
    assert (a.width, a.height) == (b.width, b.height)
    np.testing.assert_allclose(b.intrinsics, a.intrinsics, rtol=tol, atol=tol)


@pytest.mark.parametrize(
    "name", ["model.json", "cam.yaml", "cam.yml", "cam.xml", "cam.cameramodel", "cameras.txt", "camera_info.yaml"]
)
@pytest.mark.parametrize("camera", [CAM, CAM_NO_K3])
def test_round_trip(tmp_path, name, camera):
    path = tmp_path / name
    write_camera(path, camera)
    # exact for text formats written with repr(); OpenCV writes ~16 significant digits
    same(camera, read_camera(path), tol=1e-13 if name.endswith((".yaml", ".yml", ".xml")) else 0.0)


def test_format_detection(tmp_path):
    assert detect_format("a/model.json") == "json"
    assert detect_format("x.cameramodel") == "mrcal"
    assert detect_format("cameras.txt") == "colmap"
    assert detect_format("calib.yaml") == "opencv"
    assert detect_format("left_camera_info.yaml") == "ros"
    with pytest.raises(ValueError, match="cannot tell"):
        detect_format("model.bin")
    # content wins over a misleading name
    p = tmp_path / "calib.yaml"
    p.write_text(camera_to_ros_yaml(CAM))
    assert detect_format(p, p.read_text()) == "ros"
    same(CAM, read_camera(p))


def test_opencv_yaml_read_back_by_cv2(tmp_path):
    p = tmp_path / "cam.yaml"
    write_camera(p, CAM)
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    d = fs.getNode("distortion_coefficients").mat().ravel()
    w, h = int(fs.getNode("image_width").real()), int(fs.getNode("image_height").real())
    fs.release()
    np.testing.assert_allclose(K, CAM.K, rtol=1e-15)
    np.testing.assert_allclose(d, CAM.dist, rtol=1e-15)
    assert (w, h) == (1920, 1080)
    # and what cv2 projects with it is what circcal projects
    X = np.array([[10.0, -20.0, 0.0], [200.0, 100.0, 0.0]])
    rv, tv = np.array([0.2, -0.1, 0.05]), np.array([-50.0, -30.0, 600.0])
    uv_cv = cv2.projectPoints(X, rv, tv, K, d)[0].reshape(-1, 2)
    np.testing.assert_allclose(uv_cv, project(X, rv, tv, CAM), atol=1e-9)


def test_opencv_file_with_extra_zero_coefficients(tmp_path):
    p = tmp_path / "cam.yaml"
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", CAM_NO_K3.K)
    fs.write("distortion_coefficients", np.concatenate([CAM_NO_K3.dist, np.zeros(3)]).reshape(1, 8))
    fs.release()
    same(CAM_NO_K3, read_camera(p))
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", CAM_NO_K3.K)
    fs.write("distortion_coefficients", np.array([[0.1, 0.0, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0]]))
    fs.release()
    cam = read_camera(p)  # a nonzero k4: OpenCV's rational model
    assert cam.lens == "rational" and cam.dist[5] == 0.01


def test_colmap_offset_and_k3():
    text = camera_to_colmap(CAM_NO_K3)
    line = [ln for ln in text.splitlines() if not ln.startswith("#")][0].split()
    assert line[1] == "OPENCV" and len(line) == 4 + 8
    assert float(line[6]) == CAM_NO_K3.cx + 0.5 and float(line[7]) == CAM_NO_K3.cy + 0.5
    # k3 != 0: OPENCV refused, FULL_OPENCV written (auto)
    with pytest.raises(ValueError, match="no k3"):
        camera_to_colmap(CAM, model="OPENCV")
    full = [ln for ln in camera_to_colmap(CAM).splitlines() if not ln.startswith("#")][0].split()
    assert full[1] == "FULL_OPENCV" and len(full) == 4 + 12
    assert float(full[12]) == CAM.dist[4]
    same(CAM, camera_from_colmap(camera_to_colmap(CAM)), tol=1e-12)
    rational = camera_from_colmap("1 FULL_OPENCV 640 480 500 500 320 240 0 0 0 0 0 0.1 0 0")
    assert rational.lens == "rational" and rational.dist[5] == 0.1  # k4
    simple = camera_from_colmap("# c\n7 SIMPLE_RADIAL 640 480 500 320.5 240.5 -0.1\n")
    assert (simple.fx, simple.fy, simple.cx, simple.cy, simple.dist[0]) == (500, 500, 320.0, 240.0, -0.1)


def test_colmap_projection_with_pycolmap():
    """pycolmap's own projection with the written parameters equals circcal's projection + 0.5 px."""
    pycolmap = pytest.importorskip("pycolmap")
    for cam in (CAM_NO_K3, CAM):
        line = [ln for ln in camera_to_colmap(cam).splitlines() if not ln.startswith("#")][0].split()
        c = pycolmap.Camera.create_from_model_name(1, line[1], 1000.0, cam.width, cam.height)
        c.params = np.array([float(v) for v in line[4:]])
        Xc = np.array([[0.1, -0.05, 1.0], [-0.3, 0.2, 1.0], [0.25, 0.15, 1.0]])
        uv_colmap = np.asarray(c.img_from_cam(Xc))[:, :2]
        uv_ours = project(Xc, np.zeros(3), np.zeros(3), cam)
        np.testing.assert_allclose(uv_colmap - uv_ours, 0.5, atol=1e-9)


def test_mrcal_cameramodel_literal():
    text = camera_to_cameramodel(CAM)
    assert "LENSMODEL_OPENCV5" in text
    same(CAM, camera_from_cameramodel(text))
    pinhole = "{'lensmodel': 'LENSMODEL_PINHOLE', 'intrinsics': [500., 501., 320., 240.], 'imagersize': [640, 480]}"
    c = camera_from_cameramodel("# comment\n" + pinhole)
    assert (c.fx, c.cy) == (500.0, 240.0) and not np.any(c.dist)
    with pytest.raises(ValueError, match="no exact circcal equivalent"):
        camera_from_cameramodel(pinhole.replace("PINHOLE", "SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_fov_x_deg=100"))


@pytest.mark.skipif(shutil.which("python3") is None, reason="no system python")
def test_mrcal_reads_our_cameramodel(tmp_path):
    """If Debian's mrcal is installed, mrcal.project with our file equals circcal's projection."""
    probe = subprocess.run(["/usr/bin/python3", "-c", "import mrcal"], capture_output=True)
    if probe.returncode != 0:
        pytest.skip("mrcal not importable by /usr/bin/python3")
    p = tmp_path / "cam.cameramodel"
    write_camera(p, CAM)
    code = (
        "import mrcal, numpy as np, sys; m = mrcal.cameramodel(sys.argv[1]); "
        "print(' '.join(repr(float(v)) for v in mrcal.project(np.array([[0.1, -0.05, 1.0], [-0.3, 0.2, 1.0]]), "
        "*m.intrinsics()).ravel()))"
    )
    out = subprocess.run(["/usr/bin/python3", "-c", code, str(p)], capture_output=True, text=True, check=True)
    uv = np.array([float(v) for v in out.stdout.split()]).reshape(-1, 2)
    Xc = np.array([[0.1, -0.05, 1.0], [-0.3, 0.2, 1.0]])
    np.testing.assert_allclose(uv, project(Xc, np.zeros(3), np.zeros(3), CAM), atol=1e-9)


def test_ros_message_layout():
    text = """header:
  seq: 0
  frame_id: cam
height: 480
width: 640
distortion_model: "plumb_bob"
D: [0.1, -0.05, 0.001,
    0.002, 0.0]
K:
- 500.5
- 0.0
- 320.1
- 0.0
- 501.25
- 239.9
- 0.0
- 0.0
- 1.0
R: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]  # identity
P: [500.5, 0.0, 320.1, 0.0, 0.0, 501.25, 239.9, 0.0, 0.0, 0.0, 1.0, 0.0]
"""
    same(CAM_NO_K3, camera_from_ros_yaml(text))
    written = camera_to_ros_yaml(CAM, name="left")
    assert "distortion_model: plumb_bob" in written and "projection_matrix" in written
    with pytest.raises(ValueError, match="equidistant"):
        camera_from_ros_yaml(written.replace("plumb_bob", "equidistant"))


def test_model_json_keeps_result(tmp_path):
    model = {
        "format": "circcal-model",
        "camera": CAM.to_dict(),
        "std": {"fx": 0.5},
        "errors": {"rms_per_point_px": 0.1},
    }
    p = tmp_path / "model.json"
    write_camera(p, CAM, document=model)
    assert json.loads(p.read_text())["std"]["fx"] == 0.5
    same(CAM, read_camera(p))


def test_convert_cli(tmp_path, capsys):
    src = tmp_path / "model.json"
    write_camera(src, CAM)
    for out in ("cam.yaml", "cam.cameramodel", "cameras.txt", "left_camera_info.yaml", "back.json"):
        assert main(["convert", str(src), str(tmp_path / out)]) == 0
        same(CAM, read_camera(tmp_path / out), tol=1e-13)
    assert main(["convert", str(src), str(tmp_path / "c2.txt"), "--colmap-model", "OPENCV"]) == 2
    assert "no k3" in capsys.readouterr().err
    assert main(["convert", str(tmp_path / "missing.json"), str(tmp_path / "x.yaml")]) == 2
