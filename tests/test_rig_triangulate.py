"""circcal.rig.triangulate: points and their covariances against truth and Monte-Carlo on synthetic rigs."""

from __future__ import annotations

import numpy as np
import pytest

from circcal.errors import InputError
from circcal.model import Camera, project
from circcal.rig import RigModel
from circcal.rig.triangulate import triangulate

PINHOLE = Camera(1280, 960, 1010.0, 1005.0, 650.0, 470.0, [-0.2, 0.08, 0.001, -0.0005, -0.01])
RATIONAL = Camera(
    1024, 768, 820.0, 818.0, 515.0, 380.0, [0.1, -0.05, 0.0005, 0.0002, 0.01, 0.2, -0.04, 0.02], "rational"
)
FISHEYE = Camera(800, 600, 300.0, 301.0, 401.0, 299.0, [0.02, -0.005, 0.001, -0.0002], "fisheye")


def _rig(cameras: list[Camera]) -> RigModel:
    poses = [
        ([0, 0, 0], [0, 0, 0]),
        ([0.01, -0.08, 0.005], [-150.0, 2.0, 1.0]),
        ([-0.02, 0.1, 0.01], [140.0, -5.0, 3.0]),
    ]
    names = ["left", "right", "third"][: len(cameras)]
    return RigModel(
        names, cameras, [p[0] for p in poses[: len(cameras)]], [p[1] for p in poses[: len(cameras)]], rms_px=0.2
    )


def _points(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-250, 250, n), rng.uniform(-180, 180, n), rng.uniform(700, 1400, n)])


def _observe(rig: RigModel, P: np.ndarray) -> dict[str, np.ndarray]:
    return {n: project(P, rig.rvecs[k], rig.tvecs[k], rig.cameras[k]) for k, n in enumerate(rig.names)}


def _state_size(rig: RigModel) -> int:
    return sum(len(c.intrinsics) for c in rig.cameras) + 6 * (rig.n_cameras - 1)


def _state(rig: RigModel) -> np.ndarray:
    return np.concatenate(
        [c.intrinsics for c in rig.cameras] + [np.r_[rig.rvecs[k], rig.tvecs[k]] for k in range(1, rig.n_cameras)]
    )


def _rig_from_state(rig: RigModel, theta: np.ndarray) -> RigModel:
    cams, o = [], 0
    for c in rig.cameras:
        n = len(c.intrinsics)
        cams.append(Camera.from_intrinsics(c.width, c.height, theta[o : o + n], c.lens))
        o += n
    rv, tv = [np.zeros(3)], [np.zeros(3)]
    for _ in range(1, rig.n_cameras):
        rv.append(theta[o : o + 3])
        tv.append(theta[o + 3 : o + 6])
        o += 6
    return RigModel(rig.names, cams, rv, tv)


def _calibration_covariance(rig: RigModel, seed: int = 3) -> np.ndarray:
    """A made-up calibration covariance: plausible sigmas per parameter, with random correlations."""
    sig = []
    for c in rig.cameras:
        sig += [0.4, 0.4, 0.3, 0.3] + [2e-4] * len(c.dist)
    sig += [1.5e-4, 1.5e-4, 1.5e-4, 0.15, 0.15, 0.15] * (rig.n_cameras - 1)
    s = np.array(sig)
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(len(s), len(s) + 5))
    C = A @ A.T
    d = np.sqrt(np.diag(C))
    return (C / np.outer(d, d)) * np.outer(s, s)


def _ratios(stated: np.ndarray, samples: np.ndarray) -> tuple[float, float]:
    """stated / empirical of the trace and of the largest eigenvalue."""
    emp = np.cov(samples.T)
    return (
        float(np.trace(stated) / np.trace(emp)),
        float(np.linalg.eigvalsh(stated)[-1] / np.linalg.eigvalsh(emp)[-1]),
    )


@pytest.mark.parametrize("cams", [[PINHOLE, RATIONAL], [PINHOLE, FISHEYE], [PINHOLE, RATIONAL, FISHEYE]])
def test_exact_pixels_give_the_points(cams: list[Camera]) -> None:
    rig = _rig(cams)
    P = _points(30)
    t = triangulate(rig, _observe(rig, P), pixel_sigma=0.1)
    assert np.abs(t.points - P).max() < 1e-8
    assert np.nanmax(t.rms_px) < 1e-8
    assert (t.n_views == len(cams)).all() and not t.behind.any()
    assert not t.calibration_included
    assert np.allclose(t.covariance, t.covariance_pixels)


def test_pixel_noise_covariance_matches_monte_carlo() -> None:
    rig = _rig([PINHOLE, FISHEYE])
    P = _points(6, seed=1)
    obs = _observe(rig, P)
    sigma = 0.3
    stated = triangulate(rig, obs, pixel_sigma=sigma).covariance_pixels
    S = 2000
    rng = np.random.default_rng(7)
    noisy = {n: np.tile(o, (S, 1)) + rng.normal(0.0, sigma, (S * len(P), 2)) for n, o in obs.items()}
    X = triangulate(rig, noisy, pixel_sigma=sigma).points.reshape(S, len(P), 3)
    for p in range(len(P)):
        tr, ev = _ratios(stated[p], X[:, p])
        assert 0.8 <= tr <= 1.25 and 0.8 <= ev <= 1.25, (p, tr, ev)


def test_calibration_covariance_matches_monte_carlo() -> None:
    base = _rig([PINHOLE, RATIONAL, FISHEYE])
    cov = _calibration_covariance(base)
    rig = RigModel(base.names, base.cameras, base.rvecs, base.tvecs, cov, base.rms_px)
    P = _points(5, seed=2)
    obs = _observe(rig, P)
    t = triangulate(rig, obs, pixel_sigma=0.0)
    assert t.calibration_included
    assert np.allclose(t.covariance, t.covariance_calibration) and np.all(t.covariance_pixels == 0)
    S = 1000
    rng = np.random.default_rng(11)
    thetas = rng.multivariate_normal(_state(rig), cov, size=S)
    X = np.stack([triangulate(_rig_from_state(rig, th), obs, pixel_sigma=0.0).points for th in thetas])
    for p in range(len(P)):
        tr, ev = _ratios(t.covariance_calibration[p], X[:, p])
        assert 0.8 <= tr <= 1.25 and 0.8 <= ev <= 1.25, (p, tr, ev)


def test_agrees_with_opencv_triangulate_points() -> None:
    """On noisy pixels of a pinhole pair, cv2.triangulatePoints (DLT on undistorted pixels) and circcal's
    reprojection-error minimum agree to well within the stated sigma."""
    import cv2

    rig = _rig([PINHOLE, RATIONAL])
    P = _points(40, seed=4)
    obs = _observe(rig, P)
    rng = np.random.default_rng(5)
    noisy = {n: o + rng.normal(0.0, 0.2, o.shape) for n, o in obs.items()}
    t = triangulate(rig, noisy, pixel_sigma=0.2)
    projs, und = [], []
    for k, n in enumerate(rig.names):
        c = rig.cameras[k]
        R, T = rig.pose(k)
        projs.append(c.K @ np.hstack([R, T[:, None]]))
        und.append(cv2.undistortPoints(noisy[n].reshape(-1, 1, 2), c.K, c.dist, P=c.K).reshape(-1, 2).T)
    H = cv2.triangulatePoints(projs[0], projs[1], und[0], und[1])
    X_cv = (H[:3] / H[3]).T
    d = np.linalg.norm(X_cv - t.points, axis=1)
    sigma = np.sqrt(np.trace(t.covariance, axis1=1, axis2=2))
    assert np.all(d < 0.25 * sigma)
    assert np.abs(t.points - P).max() > 0  # the noise moved them


def test_unseen_points_and_views() -> None:
    rig = _rig([PINHOLE, RATIONAL, FISHEYE])
    P = _points(4, seed=6)
    obs = _observe(rig, P)
    obs["right"][1] = np.nan
    obs["right"][2] = np.nan
    obs["third"][2] = np.nan
    t = triangulate(rig, obs, pixel_sigma=0.1)
    assert list(t.n_views) == [3, 2, 1, 3]
    assert np.all(np.isnan(t.points[2])) and np.all(np.isnan(t.covariance[2]))
    assert np.abs(np.delete(t.points, 2, axis=0) - np.delete(P, 2, axis=0)).max() < 1e-8
    # fewer views, more uncertainty
    assert np.trace(t.covariance[1]) > np.trace(triangulate(rig, _observe(rig, P), pixel_sigma=0.1).covariance[1])


def test_pixels_that_show_no_one_point_are_named_behind_the_cameras() -> None:
    # the rows of one camera's file swapped: right's pixels of two points far apart on the left and right of the
    # field; its rays then cross left's behind both cameras (the baseline runs along x)
    rig = _rig([PINHOLE, RATIONAL])
    P = np.array([[-240.0, 0.0, 800.0], [240.0, 0.0, 800.0], [0.0, 50.0, 1000.0]])
    obs = _observe(rig, P)
    obs["right"] = obs["right"][[1, 0, 2]]
    t = triangulate(rig, obs, pixel_sigma=0.1)
    assert t.behind.shape == (3, 2)
    assert t.behind[0].all() and not t.behind[2].any() and np.abs(t.points[2] - P[2]).max() < 1e-8
    assert t.points[0, 2] < 0  # it is kept (named, not dropped): its position is where the rays cross


def test_default_sigma_from_rms_and_refusals() -> None:
    rig = _rig([PINHOLE, RATIONAL])
    obs = _observe(rig, _points(3))
    assert triangulate(rig, obs).pixel_sigma == pytest.approx(0.2 / np.sqrt(2))
    bare = RigModel(rig.names, rig.cameras, rig.rvecs, rig.tvecs)
    with pytest.raises(InputError, match="pixel_sigma"):
        triangulate(bare, obs)
    with pytest.raises(InputError, match="no covariance"):
        triangulate(rig, obs, pixel_sigma=0.1, calibration=True)
    with pytest.raises(InputError, match="at least two"):
        triangulate(rig, {"left": obs["left"]}, pixel_sigma=0.1)
    with pytest.raises(InputError, match="no camera"):
        triangulate(rig, {"left": obs["left"], "nope": obs["right"]}, pixel_sigma=0.1)
    with pytest.raises(InputError, match="one row per point"):
        triangulate(rig, {"left": obs["left"], "right": obs["right"][:2]}, pixel_sigma=0.1)
    with pytest.raises(InputError, match="finite"):
        triangulate(rig, {"left": obs["left"] * np.inf, "right": obs["right"]}, pixel_sigma=0.1)
    with pytest.raises(InputError, match="pixel_sigma"):
        triangulate(rig, obs, pixel_sigma=-1.0)
    wrong = RigModel(rig.names, rig.cameras, rig.rvecs, rig.tvecs, np.eye(3))
    with pytest.raises(InputError, match="covariance must be"):
        triangulate(wrong, obs, pixel_sigma=0.1)
    assert _state_size(rig) == 9 + 12 + 6
