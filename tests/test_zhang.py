"""Zhang's closed form: exact on noiseless distortion-free data, close with distortion, clear on degenerate views."""

import numpy as np
import pytest

from circcal.board import Board
from circcal.errors import DegenerateViewsError
from circcal.fixtures.poses import sample_poses
from circcal.model import Camera, project
from circcal.solver.zhang import homography, pose_from_homography, view_tilts_deg, zhang

BOARD = Board(7, 7, 10.0, 5.0)


def _views(camera, n=14, seed=0, noise=0.0, max_tilt=40.0):
    rng = np.random.default_rng(seed)
    poses = sample_poses(camera, BOARD, n, seed, max_tilt_deg=max_tilt)
    obj = [BOARD.object_points() for _ in poses]
    img = [project(o, r, t, camera) + rng.normal(0.0, noise, (len(o), 2)) for o, (r, t) in zip(obj, poses)]
    return obj, img, poses


def test_homography_exact_on_noiseless_points():
    cam = Camera(1280, 960, 1100.0, 1105.0, 650.0, 470.0)
    obj, img, _ = _views(cam, n=3)
    for o, p in zip(obj, img):
        H = homography(o[:, :2], p)
        q = np.column_stack([o[:, :2], np.ones(len(o))]) @ H.T
        assert np.max(np.abs(q[:, :2] / q[:, 2:] - p)) < 1e-9


def test_exact_without_distortion():
    cam = Camera(1920, 1080, 1500.0, 1502.0, 955.0, 545.0)
    obj, img, poses = _views(cam)
    z = zhang(obj, img, (1920, 1080))
    assert not z.principal_point_fixed
    np.testing.assert_allclose(
        [z.camera.fx, z.camera.fy, z.camera.cx, z.camera.cy], [1500, 1502, 955, 545], rtol=0, atol=1e-8
    )
    np.testing.assert_allclose(z.rvecs, [r for r, _ in poses], atol=1e-10)
    np.testing.assert_allclose(z.tvecs, [t for _, t in poses], atol=1e-8)


def test_pose_from_homography_recovers_pose():
    cam = Camera(1920, 1080, 1500.0, 1502.0, 955.0, 545.0)
    obj, img, poses = _views(cam, n=4, seed=3)
    for o, p, (r, t) in zip(obj, img, poses):
        rv, tv = pose_from_homography(homography(o[:, :2], p), cam.K)
        np.testing.assert_allclose(rv, r, atol=1e-10)
        np.testing.assert_allclose(tv, t, atol=1e-8)


@pytest.mark.parametrize("k1", [-0.1, -0.05, 0.05])
def test_close_with_distortion(k1):
    cam = Camera(1920, 1080, 1500.0, 1502.0, 955.0, 545.0, np.array([k1, -0.3 * k1, 0.0005, -0.0003, 0.0]))
    obj, img, _ = _views(cam)
    z = zhang(obj, img, (1920, 1080))
    assert abs(z.camera.fx / 1500.0 - 1.0) < 0.02
    assert abs(z.camera.fy / 1502.0 - 1.0) < 0.02
    # the linear radial estimate gets the sign and rough size of k1
    assert np.sign(z.camera.dist[0] + 0.0) == np.sign(k1) or abs(z.camera.dist[0]) < abs(k1)
    # without the radial rounds the closed form is much further off (what the rounds are for)
    z0 = zhang(obj, img, (1920, 1080), distortion_rounds=0)
    assert abs(z0.camera.fx / 1500.0 - 1.0) > abs(z.camera.fx / 1500.0 - 1.0)


def test_given_principal_point_and_aspect():
    cam = Camera(1920, 1080, 1500.0, 1500.0, 959.5, 539.5)
    obj, img, _ = _views(cam)
    z = zhang(obj, img, (1920, 1080), principal_point=(959.5, 539.5), aspect_ratio=1.0)
    assert z.principal_point_fixed
    assert (z.camera.cx, z.camera.cy) == pytest.approx((959.5, 539.5), abs=1e-9)
    assert z.camera.fx == pytest.approx(1500.0, abs=1e-6)
    assert z.camera.fx == pytest.approx(z.camera.fy, abs=1e-9)


def test_fronto_parallel_views_raise_and_are_named():
    cam = Camera(1920, 1080, 1500.0, 1502.0, 955.0, 545.0)
    rng = np.random.default_rng(1)
    obj, img = [], []
    for _ in range(10):
        rv = np.array([0.0, 0.0, rng.uniform(-0.3, 0.3)])  # board exactly parallel to the image plane
        tv = np.array([rng.uniform(-150, 100), rng.uniform(-80, 40), 500.0])
        obj.append(BOARD.object_points())
        img.append(project(BOARD.object_points(), rv, tv, cam) + rng.normal(0, 0.05, (49, 2)))
    with pytest.raises(DegenerateViewsError, match="not observable") as info:
        zhang(obj, img, (1920, 1080))
    assert len(info.value.views) >= 8  # the flat views are listed
    assert "tilt" in str(info.value)


def test_view_tilts():
    assert view_tilts_deg(np.array([[0.0, 0.0, 1.0], [np.radians(30), 0.0, 0.0]])) == pytest.approx([0.0, 30.0])
