"""The camera model against OpenCV and against itself (round trips), over the full frame."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from circcal.fixtures.scenarios import SCENARIOS
from circcal.model import Camera, distort, distort_jacobian, distort_pixels, project, undistort, undistort_pixels
from circcal.rotation import rodrigues, rotation_angle_deg, rotation_log

#: the scenarios' pinhole cameras (cv2.projectPoints' models; the fisheye ones are tested against cv2.fisheye below)
CAMERAS = {name: s.camera for name, s in SCENARIOS.items() if s.camera.model.pinhole}
FISHEYE_SCENARIO_CAMERAS = {f"scenario-{name}": s.camera for name, s in SCENARIOS.items() if not s.camera.model.pinhole}


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
@given(
    k1=st.floats(-0.4, 0.3),
    k2=st.floats(-0.1, 0.2),
    p1=st.floats(-0.003, 0.003),
    p2=st.floats(-0.003, 0.003),
    k3=st.floats(-0.02, 0.02),
    f=st.floats(300, 6000),
    seed=st.integers(0, 2**31 - 1),
)
def test_project_matches_opencv_random(k1, k2, p1, p2, k3, f, seed):
    rng = np.random.default_rng(seed)
    cam = Camera(
        1280,
        960,
        f,
        f * rng.uniform(0.98, 1.02),
        640 + rng.normal(0, 20),
        480 + rng.normal(0, 20),
        [k1, k2, p1, p2, k3],
    )
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
@given(
    k1=st.floats(-0.3, 0.3),
    k2=st.floats(0.0, 0.2),
    p1=st.floats(-0.002, 0.002),
    p2=st.floats(-0.002, 0.002),
    seed=st.integers(0, 2**31 - 1),
)
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
        e = np.zeros(2)
        e[j] = h
        fd = (distort(x + e, dist) - distort(x - e, dist)) / (2 * h)
        assert np.max(np.abs(fd - Jx[:, :, j])) < 1e-8
    for j in range(5):
        e = np.zeros(5)
        e[j] = h
        fd = (distort(x, dist + e) - distort(x, dist - e)) / (2 * h)
        assert np.max(np.abs(fd - Jd[:, :, j])) < 1e-8


def test_rodrigues_matches_opencv_including_tiny_angles():
    rng = np.random.default_rng(2)
    for r in list(rng.normal(0, 1.0, (20, 3))) + [np.zeros(3), np.array([1e-12, -2e-12, 0.0])]:
        assert np.max(np.abs(rodrigues(r) - cv2.Rodrigues(r)[0])) < 1e-14


def test_rotation_angle_is_precise_from_zero_to_a_half_turn():
    # arccos((trace - 1) / 2), its old form, reads every angle below ~1.2e-6 deg as 0 (and 1e-6 deg as 1.2e-6):
    # too coarse for the rig's fair bounds of 1e-6 deg
    rng = np.random.default_rng(3)
    axes = rng.normal(size=(7, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    for deg in (1e-10, 1e-7, 1e-6, 3e-6, 0.5, 90.0, 179.0, 179.9999999):
        got = rotation_angle_deg(rodrigues(axes * np.radians(deg)))
        assert got.shape == (7,) and np.allclose(got, deg, rtol=1e-8, atol=0), (deg, got)


def test_rotation_log_inverts_rodrigues_at_every_angle():
    rng = np.random.default_rng(4)
    axes = rng.normal(size=(7, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    for deg in (0.0, 1e-10, 1e-6, 0.5, 90.0, 169.0, 171.0, 179.9999):  # from 170: the symmetric part's axis
        r = axes * np.radians(deg)
        got = rotation_log(rodrigues(r))
        assert got.shape == (7, 3) and np.allclose(got, r, rtol=0, atol=1e-15 + 1e-13 * np.radians(deg)), (deg, got)
    # at a half turn +-axis are one rotation: the matrix comes back
    R = rodrigues(axes * np.pi)
    assert np.max(np.abs(rodrigues(rotation_log(R)) - R)) < 1e-14
    assert rotation_log(np.broadcast_to(np.eye(3), (2, 4, 3, 3))).shape == (2, 4, 3)


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


# --- the lens models beyond opencv5 -----------------------------------------------------------------------------

from circcal.model import (  # noqa: E402
    LENS_MODELS,
    param_names,
    project_camera,
    project_camera_jacobian,
    project_jacobian,
    theta_max,
    unproject,
)
from circcal.model.fisheye import theta_distort  # noqa: E402

#: Wide-angle cameras as OpenCV users fit them (coefficients of the size calibrateCamera returns for such lenses).
LENS_CAMERAS = {
    "rational": Camera(
        1920, 1080, 900.0, 905.0, 962.3, 541.7, [2.5, 0.6, 4e-4, -6e-4, 0.01, 2.9, 1.4, 0.1], "rational"
    ),
    "thin-prism": Camera(
        1920,
        1080,
        900.0,
        905.0,
        962.3,
        541.7,
        [2.5, 0.6, 4e-4, -6e-4, 0.01, 2.9, 1.4, 0.1, 1e-3, -2e-6, -8e-4, 3e-6],
        "thin-prism",
    ),
    # a 1280x1024 fisheye whose corners see ~85 deg off axis (cv2.fisheye projects only z > 0)
    "fisheye": Camera(1280, 1024, 520.0, 521.5, 641.2, 509.8, [0.02, -0.006, 0.001, -1e-4], "fisheye"),
    # a 190-deg lens: the image circle holds rays beyond 90 deg
    "fisheye-190": Camera(1280, 1024, 310.0, 310.0, 639.5, 511.5, [-0.012, 0.003, -6e-4, 5e-5], "fisheye"),
}


def _pixel_grid(cam: Camera, n=(61, 41)) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(-0.5, cam.width - 0.5, n[0]), np.linspace(-0.5, cam.height - 0.5, n[1]))
    return np.stack([u.ravel(), v.ravel()], -1)


def _frame_board_points(cam: Camera, rvec, tvec) -> np.ndarray:
    """Board-frame points whose projections cover the whole frame (corners included), at depths 300-3000 mm."""
    rays = unproject(_pixel_grid(cam), cam)
    assert np.all(np.isfinite(rays))
    rays = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    Xc = rays * np.linspace(300.0, 3000.0, len(rays))[:, None]
    return (Xc - tvec) @ rodrigues(rvec)


@pytest.mark.parametrize("name", ["rational", "thin-prism"])
def test_pinhole_lens_models_equal_opencv_full_frame(name):
    """8- and 12-coefficient projection equals cv2.projectPoints to 1e-9 px over the whole frame."""
    cam = LENS_CAMERAS[name]
    assert len(cam.dist) == len(LENS_MODELS[name].dist_names) == {"rational": 8, "thin-prism": 12}[name]
    rvec, tvec = np.array([0.2, -0.3, 0.1]), np.array([15.0, -20.0, 40.0])
    P = _frame_board_points(cam, rvec, tvec)
    ours = project(P, rvec, tvec, cam)
    ref = cv2.projectPoints(P, rvec, tvec, cam.K, cam.dist)[0][:, 0]
    assert np.max(np.abs(ours - ref)) <= 1e-9
    assert np.max(np.abs(ours - _pixel_grid(cam))) <= 1e-9  # and the grid came back
    assert ours[:, 0].min() < 0 and ours[:, 0].max() > cam.width - 1


def test_fisheye_equals_cv2_fisheye_full_frame():
    cam = LENS_CAMERAS["fisheye"]
    rvec, tvec = np.array([0.2, -0.3, 0.1]), np.array([15.0, -20.0, 40.0])
    P = _frame_board_points(cam, rvec, tvec)
    Xc = P @ rodrigues(rvec).T + tvec
    theta = np.degrees(np.arctan2(np.hypot(Xc[:, 0], Xc[:, 1]), Xc[:, 2]))
    assert 80 < theta.max() < 90  # the frame's corners, all in front
    ours = project(P, rvec, tvec, cam)
    ref = cv2.fisheye.projectPoints(P[:, None, :], rvec, tvec, cam.K, cam.dist)[0][:, 0]
    assert np.max(np.abs(ours - ref)) <= 1e-9
    assert np.max(np.abs(ours - _pixel_grid(cam))) <= 1e-9
    # on the optical axis too (cv2's special case r < 1e-8)
    on_axis = np.array([[0.0, 0.0, 500.0], [1e-9, -1e-9, 500.0]])
    ref = cv2.fisheye.projectPoints(on_axis[:, None, :], np.zeros(3), np.zeros(3), cam.K, cam.dist)[0][:, 0]
    assert np.max(np.abs(project_camera(on_axis, cam) - ref)) <= 1e-9


@pytest.mark.parametrize("name", sorted(LENS_CAMERAS) + sorted(FISHEYE_SCENARIO_CAMERAS))
def test_unproject_round_trips_every_pixel(name):
    """pixel -> ray -> pixel to 1e-9 px over a dense grid of the whole image, edges and corners included (the
    fixtures' fisheye scenarios too)."""
    cam = LENS_CAMERAS.get(name) or FISHEYE_SCENARIO_CAMERAS[name]
    uv = _pixel_grid(cam, (193, 111))
    rays = unproject(uv, cam)
    assert np.all(np.isfinite(rays))
    assert np.max(np.abs(project_camera(rays, cam) - uv)) <= 1e-9
    if not cam.model.pinhole:
        assert np.allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-14, rtol=0)


@pytest.mark.parametrize("name", ["fisheye", "fisheye-190"])
def test_fisheye_round_trips_over_its_whole_field(name):
    """Rays at every angle up to the lens's one-to-one limit (theta_max, here pi or the fold) -> pixels -> the same
    rays, and pixels -> rays -> pixels, to 1e-9 px; beyond 90 deg included; past the fold NaN."""
    cam = LENS_CAMERAS[name]
    tmax = theta_max(cam.dist)
    theta, phi = np.meshgrid(np.linspace(0.0, tmax * (1 - 1e-6), 400), np.linspace(-np.pi, np.pi, 73))
    theta, phi = theta.ravel(), phi.ravel()
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    uv = project_camera(rays, cam)
    back = unproject(uv, cam)
    assert np.all(np.isfinite(back))
    assert np.max(np.abs(project_camera(back, cam) - uv)) <= 1e-9
    # the same rays: the angle between them, times the pixels per radian there (d theta_d / d theta f), <= 1e-9 px
    ang = np.linalg.norm(np.cross(back, rays), axis=1)
    px_per_rad = cam.fx * theta_distort(theta, cam.dist, True)[1]
    assert np.max(ang * px_per_rad) <= 1e-9
    assert theta.max() > np.radians(95)
    # the 190-deg lens: a pixel on the image circle at 95 deg gives a ray behind the camera
    if name == "fisheye-190":
        assert np.any(back[:, 2] < -0.05)


def test_theta_max_is_the_fold():
    d = np.array([-0.05, 0.0, 0.0, 0.0])  # theta_d' = 1 - 0.15 t^2 = 0 at t = sqrt(1/0.15) > pi? no: 2.58
    assert theta_max(d) == pytest.approx(np.sqrt(1 / 0.15), rel=1e-12)
    assert theta_max(np.zeros(4)) == np.pi
    cam = Camera(800, 800, 200.0, 200.0, 400.0, 400.0, d, "fisheye")
    beyond = 200.0 * float(theta_distort(np.array(theta_max(d)), d)) * 1.01
    assert np.all(np.isnan(unproject(np.array([[400.0 + beyond, 400.0]]), cam)))


def _fd_check(f, x, J, rel=1e-7, scale_by_norm=False):
    """Central differences of ``f`` at ``x`` (n,) against ``J`` (..., n): each column to ``rel`` of its size. Steps
    1e-6 of each entry (``scale_by_norm``: of the vector's norm, for a point's coordinates)."""
    for j in range(len(x)):
        h = 1e-6 * max(1.0, float(np.linalg.norm(x)) if scale_by_norm else abs(x[j]))
        e = np.zeros_like(x)
        e[j] = h
        fd = (f(x + e) - f(x - e)) / (2 * h)
        col = J[..., j]
        scale = np.max(np.abs(col)) or np.max(np.abs(J))  # a column that is 0 (on the axis) against J's size
        assert np.max(np.abs(fd - col)) <= rel * scale, (j, np.max(np.abs(fd - col)) / scale)


@pytest.mark.parametrize("name", ["opencv5", "rational", "thin-prism", "fisheye", "fisheye-190"])
def test_analytic_jacobians_equal_finite_differences(name):
    """d uv / d intrinsics, d uv / d camera point and d uv / d pose agree with central differences to 1e-7
    relative over the frame (for the 190-deg fisheye also beyond 90 deg)."""
    cam = LENS_CAMERAS.get(name) or Camera(1280, 960, 1100.0, 1102.0, 641.0, 479.0, [-0.3, 0.12, 1e-3, -2e-3, -0.02])
    rays = unproject(_pixel_grid(cam, (9, 7)), cam)
    rng = np.random.default_rng(3)
    Xc = rays / np.linalg.norm(rays, axis=1, keepdims=True) * rng.uniform(200, 2000, (len(rays), 1))
    p = cam.intrinsics
    uv, Ji, JX = project_camera_jacobian(Xc, p, cam.lens)
    assert Ji.shape == (len(Xc), 2, 4 + len(cam.dist)) and JX.shape == (len(Xc), 2, 3)
    assert np.max(np.abs(uv - project_camera(Xc, cam))) <= 1e-9
    _fd_check(lambda q: project_camera_jacobian(Xc, q, cam.lens)[0], p, Ji)
    for i in range(len(Xc)):
        _fd_check(lambda X: project_camera_jacobian(X[None], p, cam.lens)[0][0], Xc[i], JX[i], scale_by_norm=True)
    rvec, tvec = np.array([0.1, -0.2, 0.05]), np.array([5.0, -3.0, 20.0])
    pts = (Xc - tvec) @ rodrigues(rvec)
    uv, Ji2, Jpose = project_jacobian(pts, rvec, tvec, cam)
    assert np.allclose(Ji2, Ji, rtol=1e-9, atol=1e-9)

    def by_pose(q):
        return project(pts, q[:3], q[3:], cam)

    _fd_check(by_pose, np.concatenate([rvec, tvec]), Jpose)


def test_fisheye_jacobian_on_the_axis_is_the_limit():
    cam = LENS_CAMERAS["fisheye"]
    _, _, JX = project_camera_jacobian(np.array([[0.0, 0.0, 400.0], [1e-7, 0.0, 400.0]]), cam.intrinsics, "fisheye")
    assert np.allclose(JX[0], JX[1], rtol=0, atol=1e-9)
    assert JX[0, 0, 0] == pytest.approx(cam.fx / 400.0) and JX[0, 1, 1] == pytest.approx(cam.fy / 400.0)


def test_lens_camera_api():
    assert param_names("opencv5") == PARAM_NAMES_OPENCV5
    assert param_names("fisheye") == ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")
    assert param_names("thin-prism")[-4:] == ("s1", "s2", "s3", "s4")
    for cam in LENS_CAMERAS.values():
        d = cam.to_dict()
        assert d["lens"] == cam.lens
        back = Camera.from_dict(d)
        assert back.lens == cam.lens and np.array_equal(back.intrinsics, cam.intrinsics)
        assert np.array_equal(Camera.from_intrinsics(cam.width, cam.height, cam.intrinsics, cam.lens).dist, cam.dist)
    assert "lens" not in CAMERAS["paper"].to_dict()  # old files and content hashes unchanged
    assert Camera(10, 10, 1, 1, 0, 0, lens="fisheye").dist.shape == (4,)
    with pytest.raises(ValueError, match="unknown lens model 'kb8'"):
        Camera(10, 10, 1, 1, 0, 0, lens="kb8")
    with pytest.raises(ValueError, match="8 coefficients"):
        Camera(10, 10, 1, 1, 0, 0, np.zeros(5), "rational")
    with pytest.raises(ValueError, match="4 coefficients"):
        Camera.from_dict({**LENS_CAMERAS["fisheye"].to_dict(), "dist": [0.0] * 5})


PARAM_NAMES_OPENCV5 = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


@pytest.mark.parametrize("name", ["opencv5", "rational", "thin-prism", "fisheye", "fisheye-190"])
def test_projection_jacobian_equals_its_parts(name):
    """project_camera_jacobian (the focal lengths folded into every column) against the chain rule through the
    public parts: its pixels equal the value-only path to the bit (the solver's trial steps rely on it), its
    Jacobians distort_jacobian's / fisheye_distort_jacobian's to 1e-13 relative."""
    from circcal.model import fisheye_distort, fisheye_distort_jacobian

    cam = LENS_CAMERAS.get(name) or Camera(1280, 960, 1100.0, 1102.0, 641.0, 479.0, [-0.3, 0.12, 1e-3, -2e-3, -0.02])
    rays = unproject(_pixel_grid(cam, (23, 17)), cam)
    Xc = rays * np.random.default_rng(4).uniform(200, 2000, (len(rays), 1))
    if name.startswith("fisheye"):
        Xc[0] = [0.0, 0.0, 300.0]  # on the axis: the pinhole limit
    p, f = cam.intrinsics, cam.intrinsics[:2]
    uv, Ji, JX = project_camera_jacobian(Xc, p, cam.lens)
    if cam.model.pinhole:
        xn = Xc[:, :2] * (1.0 / Xc[:, 2])[:, None]
        value = distort(xn, cam.dist)
        xd, Jx, Jd = distort_jacobian(xn, cam.dist)
        dxn = np.zeros((len(Xc), 2, 3))
        dxn[:, 0, 0] = dxn[:, 1, 1] = 1.0 / Xc[:, 2]
        dxn[:, :, 2] = -xn / Xc[:, 2:3]
        JP = Jx @ dxn
    else:
        value = fisheye_distort(Xc, cam.dist)
        xd, JP, Jd = fisheye_distort_jacobian(Xc, cam.dist)
    assert np.array_equal(uv, value * f + p[2:4]) and np.array_equal(xd, value)
    want_i = np.concatenate([np.zeros((len(Xc), 2, 4)), Jd * f[None, :, None]], axis=2)
    want_i[:, 0, 0], want_i[:, 1, 1], want_i[:, 0, 2], want_i[:, 1, 3] = xd[:, 0], xd[:, 1], 1.0, 1.0
    for got, want in ((Ji, want_i), (JX, JP * f[None, :, None])):
        assert np.max(np.abs(got - want)) <= 1e-13 * np.max(np.abs(want))
