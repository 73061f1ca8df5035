"""The camera model against OpenCV and against itself (round trips), over the full frame."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from circcal.rotation import rodrigues
from circcal.model import (Camera, distort, distort_jacobian, project, undistort, undistort_pixels,
                           distort_pixels)
from circcal.fixtures.scenarios import SCENARIOS

CAMERAS = {name: s.camera for name, s in SCENARIOS.items()}


def _full_frame_points(cam: Camera, rvec, tvec, n=41):
    """Board-frame points whose projections cover the whole image, corners included."""
    u, v = np.meshgrid(np.linspace(-0.5, cam.width - 0.5, n), np.linspace(-0.5, cam.height - 0.5, n))
    xn = undistort(np.stack([(u.ravel() - cam.cx) / cam.fx, (v.ravel() - cam.cy) / cam.fy], -1), cam.dist)
    depth = np.linspace(300.0, 3000.0, xn.shape[0])
    Xc = np.column_stack([xn * depth[:, None], depth])
    R = rodrigues(rvec)
    return (Xc - tvec) @ R  # back into the board frame


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_project_equals_opencv_full_frame(name):
    cam = CAMERAS[name]
    rvec, tvec = np.array([0.2, -0.3, 0.1]), np.array([15.0, -20.0, 40.0])
    P = _full_frame_points(cam, rvec, tvec)
    ours = project(P, rvec, tvec, cam)
    ref = cv2.projectPoints(P, rvec, tvec, cam.K, cam.dist)[0][:, 0]
    assert np.max(np.abs(ours - ref)) <= 1e-9
    # the points really span the frame, corners included
    assert ours[:, 0].min() < 0 and ours[:, 0].max() > cam.width - 1
    assert ours[:, 1].min() < 0 and ours[:, 1].max() > cam.height - 1


@settings(max_examples=60, deadline=None)
@given(k1=st.floats(-0.4, 0.3), k2=st.floats(-0.1, 0.2), p1=st.floats(-0.003, 0.003), p2=st.floats(-0.003, 0.003),
       k3=st.floats(-0.02, 0.02), f=st.floats(300, 6000), seed=st.integers(0, 2**31 - 1))
def test_project_matches_opencv_random(k1, k2, p1, p2, k3, f, seed):
    rng = np.random.default_rng(seed)
    cam = Camera(1280, 960, f, f * rng.uniform(0.98, 1.02), 640 + rng.normal(0, 20), 480 + rng.normal(0, 20),
                 [k1, k2, p1, p2, k3])
    P = rng.uniform([-200, -200, 0], [200, 200, 0], (200, 3))
    rvec = rng.normal(0, 0.4, 3)
    tvec = np.array([0, 0, 600.0]) + rng.normal(0, 10, 3)  # normalised coordinates within about +-0.5
    ref = cv2.projectPoints(P, rvec, tvec, cam.K, cam.dist)[0][:, 0]
    assert np.max(np.abs(project(P, rvec, tvec, cam) - ref)) <= 1e-9


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_undistort_everywhere_in_image(name):
    """distort(undistort(uv)) == uv to 1e-10 px over a dense grid covering the whole image, edges included."""
    cam = CAMERAS[name]
    u, v = np.meshgrid(np.linspace(-0.5, cam.width - 0.5, 193), np.linspace(-0.5, cam.height - 0.5, 111))
    uv = np.stack([u.ravel(), v.ravel()], -1)
    ideal = undistort_pixels(uv, cam)
    assert np.all(np.isfinite(ideal))
    assert np.max(np.abs(distort_pixels(ideal, cam) - uv)) <= 1e-10


@settings(max_examples=60, deadline=None)
@given(k1=st.floats(-0.3, 0.3), k2=st.floats(0.0, 0.2), p1=st.floats(-0.002, 0.002), p2=st.floats(-0.002, 0.002),
       seed=st.integers(0, 2**31 - 1))
def test_round_trip_undistort_distort(k1, k2, p1, p2, seed):
    """undistort(distort(x)) == x to <= 1e-9 px (f = 1000) inside a 90-degree field of view."""
    dist = np.array([k1, k2, p1, p2, 0.0])
    x = np.random.default_rng(seed).uniform(-0.6, 0.6, (500, 2))
    back = undistort(distort(x, dist), dist)
    assert np.max(np.abs(back - x)) * 1000.0 <= 1e-9


def test_undistort_reports_fold_as_nan():
    """Barrel distortion with no k2 folds over beyond r = 1/sqrt(3|k1|): no inverse there, NaN, not a wrong value."""
    dist = np.array([-0.3, 0.0, 0.0, 0.0, 0.0])
    xd = np.array([[0.2, 0.1], [1.2, 0.0]])
    x = undistort(xd, dist)
    assert np.all(np.isfinite(x[0])) and np.max(np.abs(distort(x[:1], dist) - xd[:1])) < 1e-14
    assert np.all(np.isnan(x[1]))


def test_distort_jacobian_matches_finite_differences():
    rng = np.random.default_rng(1)
    x = rng.uniform(-0.5, 0.5, (20, 2))
    dist = np.array([-0.2, 0.05, 0.001, -0.002, 0.01])
    xd, Jx, Jd = distort_jacobian(x, dist)
    assert np.allclose(xd, distort(x, dist), atol=0, rtol=1e-15)
    h = 1e-7
    for j in range(2):
        e = np.zeros(2); e[j] = h
        fd = (distort(x + e, dist) - distort(x - e, dist)) / (2 * h)
        assert np.max(np.abs(fd - Jx[:, :, j])) < 1e-8
    for j in range(5):
        e = np.zeros(5); e[j] = h
        fd = (distort(x, dist + e) - distort(x, dist - e)) / (2 * h)
        assert np.max(np.abs(fd - Jd[:, :, j])) < 1e-8


def test_rodrigues_matches_opencv_including_tiny_angles():
    rng = np.random.default_rng(2)
    for r in list(rng.normal(0, 1.0, (20, 3))) + [np.zeros(3), np.array([1e-12, -2e-12, 0.0])]:
        assert np.max(np.abs(rodrigues(r) - cv2.Rodrigues(r)[0])) < 1e-14


def test_camera_block_round_trip_and_errors():
    cam = CAMERAS["paper"]
    assert Camera.from_dict(cam.to_dict()).to_dict() == cam.to_dict()
    assert np.array_equal(Camera.from_intrinsics(cam.width, cam.height, cam.intrinsics).intrinsics, cam.intrinsics)
    with pytest.raises(ValueError, match="lacks fx"):
        Camera.from_dict({k: v for k, v in cam.to_dict().items() if k != "fx"})
    with pytest.raises(ValueError, match="5 coefficients"):
        Camera(10, 10, 1, 1, 0, 0, [0, 0, 0])
    with pytest.raises(ValueError, match="positive"):
        Camera(10, 10, -1, 1, 0, 0)
