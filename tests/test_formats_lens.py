"""Camera files for every lens model: round trips through each format that has the model, the refusals (with the
reason) of those that lack it, and files as OpenCV, ROS and COLMAP users write them, read and projected by those
tools' own code."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from circcal.errors import InputError
from circcal.formats import (
    camera_from_colmap,
    camera_from_opencv_yaml,
    camera_from_ros_yaml,
    camera_to_cameramodel,
    camera_to_colmap,
    camera_to_ros_yaml,
    read_camera,
    write_camera,
)
from circcal.model import Camera, project, project_camera

LENS_CAMS = {
    "opencv5": Camera(
        1920,
        1080,
        1498.123456789012,
        1500.987654321098,
        955.4321,
        545.6789,
        [-0.2012345678901, 0.1023456789, 0.00123456789, -0.000567891234, -0.0234567891],
    ),
    "rational": Camera(
        1920,
        1080,
        900.123456789,
        905.987654321,
        962.3,
        541.7,
        [0.2712345678, 0.0112345, 2.1e-4, -3.3e-4, 5.5e-4, 0.6012345, 0.0212345, 0.00123],
        "rational",
    ),
    "thin-prism": Camera(
        1920,
        1080,
        900.1,
        905.2,
        962.3,
        541.7,
        [0.27, 0.01, 2e-4, -3e-4, 5e-4, 0.6, 0.02, 0.001, 1.1e-3, -2.2e-5, -8.3e-4, 3.4e-5],
        "thin-prism",
    ),
    "fisheye": Camera(
        1280, 1024, 520.123456789, 521.5, 641.2, 509.8, [0.0212345, -0.0061234, 0.0012345, -1.2345e-4], "fisheye"
    ),
}
#: file name -> the lens models its format cannot hold (and the words of the refusal)
FILES = {
    "model.json": {},
    "cam.yaml": {},
    "cam.xml": {},
    "cam.cameramodel": {"fisheye": "equidistant"},
    "cameras.txt": {"thin-prism": "no thin-prism"},
    "camera_info.yaml": {"thin-prism": "no thin-prism"},
}


@pytest.mark.parametrize("name", sorted(FILES))
@pytest.mark.parametrize("lens", sorted(LENS_CAMS))
def test_round_trip_or_refusal(tmp_path, name, lens):
    cam = LENS_CAMS[lens]
    path = tmp_path / name
    refusal = FILES[name].get(lens)
    if refusal:
        with pytest.raises(InputError, match=refusal):
            write_camera(path, cam)
        assert not path.exists()
        return
    write_camera(path, cam)
    back = read_camera(path)
    assert back.lens == lens
    # exact for text formats written with repr(); OpenCV's FileStorage writes ~16 significant digits
    tol = 1e-13 if name.endswith((".yaml", ".xml")) and name != "camera_info.yaml" else 0.0
    np.testing.assert_allclose(back.intrinsics, cam.intrinsics, rtol=tol, atol=tol)
    assert (back.width, back.height) == (cam.width, cam.height)


def _opencv_sample_fisheye_yaml(path, K, D, size) -> None:
    """A file as OpenCV's calibration sample (camera_calibration.cpp, saveCameraParams) writes it with
    ``Calibrate_UseFisheyeModel``: its flags, ``fisheye_model: 1``, the 3x3 camera matrix and the 4x1 D."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("calibration_time", "Wed 02 Dec 2026 00:00:00 UTC")
    fs.write("nr_of_frames", 20)
    fs.write("image_width", size[0])
    fs.write("image_height", size[1])
    fs.write("board_width", 9)
    fs.write("board_height", 6)
    fs.write("square_size", 20.0)
    fs.write("flags", int(cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW))
    fs.write("fisheye_model", 1)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", D.reshape(4, 1))
    fs.write("avg_reprojection_error", 0.07)
    fs.release()


def test_opencv_written_fisheye_yaml_reads_and_projects_as_cv2_fisheye(tmp_path):
    """A fisheye file written the way cv2.fisheye users write it reads as circcal's fisheye, and circcal projects
    with it what cv2.fisheye.projectPoints projects with the file's own K and D (1e-9 px); without
    ``fisheye_model`` the 4 coefficients are OpenCV's pinhole k1, k2, p1, p2, as OpenCV reads them."""
    K = np.array([[520.1, 0.0, 641.2], [0.0, 521.5, 509.8], [0.0, 0.0, 1.0]])
    D = np.array([0.021, -0.006, 0.0012, -1.2e-4])
    p = tmp_path / "out_camera_data.yml"
    _opencv_sample_fisheye_yaml(p, K, D, (1280, 1024))
    cam = read_camera(p)
    assert cam.lens == "fisheye" and np.array_equal(cam.dist, D) and np.array_equal(cam.K, K)
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    K_cv, D_cv = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat()
    fs.release()
    rng = np.random.default_rng(0)
    X = rng.uniform([-400, -400, 50], [400, 400, 600], (200, 3))
    ref = cv2.fisheye.projectPoints(X[None], np.zeros(3), np.zeros(3), K_cv, D_cv)[0][0]
    np.testing.assert_allclose(project_camera(X, cam), ref, atol=1e-9, rtol=0)
    # our own writer's file is read by OpenCV with the same keys
    write_camera(tmp_path / "ours.yaml", cam)
    fs = cv2.FileStorage(str(tmp_path / "ours.yaml"), cv2.FILE_STORAGE_READ)
    assert fs.getNode("fisheye_model").real() == 1
    np.testing.assert_array_equal(fs.getNode("distortion_coefficients").mat().ravel(), D)
    fs.release()
    plain = camera_from_opencv_yaml(
        (tmp_path / "ours.yaml").read_text().replace("fisheye_model: 1", "fisheye_model: 0")
    )
    assert plain.lens == "opencv5" and np.array_equal(plain.dist, [*D, 0.0])


@pytest.mark.parametrize("lens", ["rational", "thin-prism"])
def test_opencv_yaml_vector_projects_as_cv2(tmp_path, lens):
    """The 8- and 12-vectors written to OpenCV YAML are what cv2.projectPoints takes: same pixels (1e-9 px)."""
    cam = LENS_CAMS[lens]
    write_camera(tmp_path / "c.yaml", cam)
    fs = cv2.FileStorage(str(tmp_path / "c.yaml"), cv2.FILE_STORAGE_READ)
    K, d = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat()
    fs.release()
    assert d.size == len(cam.dist)
    X = np.array([[10.0, -20.0, 0.0], [200.0, 100.0, 0.0], [-150.0, 90.0, 0.0]])
    rv, tv = np.array([0.2, -0.1, 0.05]), np.array([-50.0, -30.0, 400.0])
    np.testing.assert_allclose(cv2.projectPoints(X, rv, tv, K, d)[0].reshape(-1, 2), project(X, rv, tv, cam), atol=1e-9)


def test_ros_distortion_models():
    """camera_info as ROS writes it: rational_polynomial (8 D) and equidistant (4 D, image_geometry's cv2.fisheye)
    read as rational and fisheye; ours name the model ROS uses."""
    for lens, model in (("opencv5", "plumb_bob"), ("rational", "rational_polynomial"), ("fisheye", "equidistant")):
        text = camera_to_ros_yaml(LENS_CAMS[lens])
        assert f"distortion_model: {model}" in text
        assert camera_from_ros_yaml(text).lens == lens
    msg = (
        "width: 1280\nheight: 1024\ndistortion_model: equidistant\nD: [0.02, -0.006, 0.001, -0.0001]\n"
        "K: [520.0, 0.0, 641.2, 0.0, 521.5, 509.8, 0.0, 0.0, 1.0]\n"
    )
    cam = camera_from_ros_yaml(msg)
    assert cam.lens == "fisheye" and cam.dist[3] == -0.0001 and cam.cx == 641.2
    with pytest.raises(ValueError, match="4 distortion coefficients"):
        camera_from_ros_yaml(msg.replace("D: [0.02, -0.006, 0.001, -0.0001]", "D: [0.02, -0.006, 0.001, 0, 0]"))
    with pytest.raises(ValueError, match="none of circcal's"):
        camera_from_ros_yaml(msg.replace("equidistant", "fov"))


def test_colmap_fisheye_and_full_opencv_project_as_pycolmap():
    """OPENCV_FISHEYE and FULL_OPENCV as written: pycolmap's own projection with those parameters equals circcal's
    + 0.5 px (COLMAP's pixel centres) to 1e-9 px; the line reads back as the same camera."""
    pycolmap = pytest.importorskip("pycolmap")
    for lens, model in (("fisheye", "OPENCV_FISHEYE"), ("rational", "FULL_OPENCV")):
        cam = LENS_CAMS[lens]
        text = camera_to_colmap(cam)
        line = [ln for ln in text.splitlines() if not ln.startswith("#")][0].split()
        assert line[1] == model
        c = pycolmap.Camera.create_from_model_name(1, model, 500.0, cam.width, cam.height)
        c.params = np.array([float(v) for v in line[4:]])
        Xc = np.array([[0.1, -0.05, 1.0], [-0.8, 0.6, 1.0], [1.5, 0.9, 1.0]])
        np.testing.assert_allclose(np.asarray(c.img_from_cam(Xc))[:, :2] - project_camera(Xc, cam), 0.5, atol=1e-9)
        assert camera_from_colmap(text).lens == lens
    with pytest.raises(InputError, match="OPENCV_FISHEYE"):
        camera_to_colmap(LENS_CAMS["fisheye"], model="OPENCV")


def test_mrcal_names():
    assert "LENSMODEL_OPENCV8" in camera_to_cameramodel(LENS_CAMS["rational"])
    assert "LENSMODEL_OPENCV12" in camera_to_cameramodel(LENS_CAMS["thin-prism"])
