"""circcal.rig.rectify: OpenCV's stereoRectify outputs, its algorithm for cameras OpenCV cannot pair, maps, overlay."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from circcal.errors import ImageError, InputError
from circcal.model import Camera, project, unproject
from circcal.rig import RigModel
from circcal.rig.rectify import (
    Rectification,
    _rectify_own,
    rectification_maps,
    rectified_overlay,
    rectify_pair,
    write_rectified_overlay,
)

LEFT = Camera(1280, 960, 1010.0, 1005.0, 650.0, 470.0, [-0.2, 0.08, 0.001, -0.0005, -0.01])
RIGHT = Camera(1280, 960, 990.0, 995.0, 630.0, 490.0, [-0.15, 0.05, -0.001, 0.0008, 0.0])
SMALL = Camera(640, 480, 590.0, 595.0, 330.0, 250.0, [0.1, -0.05, 0.0005, 0.0002, 0.01, 0.2, -0.04, 0.02], "rational")
FISH = Camera(1280, 960, 420.0, 421.0, 641.0, 479.0, [0.02, -0.005, 0.001, -0.0002], "fisheye")
FISH2 = Camera(1280, 960, 410.0, 409.0, 635.0, 485.0, [0.01, -0.002, 0.0, 0.0], "fisheye")

POSE = ([0.02, -0.05, 0.01], [-120.0, 3.0, 2.0])


def _rig(a: Camera, b: Camera, pose: tuple = POSE) -> RigModel:
    return RigModel(["a", "b"], [a, b], [[0, 0, 0], pose[0]], [[0, 0, 0], pose[1]])


def _rectified(rig: RigModel, k: int, Rk: np.ndarray, Pk: np.ndarray, uv: np.ndarray) -> np.ndarray:
    X = unproject(uv, rig.cameras[k]) @ Rk.T
    return X[:, :2] / X[:, 2:] * Pk[0, 0] + Pk[:2, 2]


def _check_rectifies(rig: RigModel, rect: Rectification) -> None:
    """Points seen by both cameras land on one row (column for a vertical pair), and Q gives them back in mm."""
    rng = np.random.default_rng(0)
    P = np.column_stack([rng.uniform(-150, 150, 40), rng.uniform(-100, 100, 40), rng.uniform(900, 1800, 40)])
    q = [project(P, rig.rvecs[k], rig.tvecs[k], rig.cameras[k]) for k in (rect.i, rect.j)]
    r1 = _rectified(rig, rect.i, rect.R1, rect.P1, q[0])
    r2 = _rectified(rig, rect.j, rect.R2, rect.P2, q[1])
    axis = 0 if rect.vertical else 1
    assert np.abs(r1[:, axis] - r2[:, axis]).max() < 1e-6
    d = r1[:, 1 - axis] - r2[:, 1 - axis]
    H = np.column_stack([r1, d, np.ones(len(d))]) @ rect.Q.T
    X_rect = H[:, :3] / H[:, 3:]
    assert np.abs(X_rect - P @ rect.R1.T).max() < 1e-6 * 1800


@pytest.mark.parametrize("alpha", [-1.0, 0.0, 0.5, 1.0])
@pytest.mark.parametrize("zero_disparity", [True, False])
def test_pinhole_pair_is_opencv_and_circcal_reproduces_it(alpha: float, zero_disparity: bool) -> None:
    rig = _rig(LEFT, RIGHT)
    rect = rectify_pair(rig, alpha=alpha, zero_disparity=zero_disparity)
    assert rect.method == "cv2.stereoRectify"
    R, T = rig.pair(0, 1)
    ref = cv2.stereoRectify(
        LEFT.K, LEFT.dist, RIGHT.K, RIGHT.dist, (1280, 960), R, T.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY if zero_disparity else 0, alpha=alpha,
    )  # fmt: skip
    for got, want in zip((rect.R1, rect.R2, rect.P1, rect.P2, rect.Q), ref[:5]):
        assert np.array_equal(got, want)
    own = _rectify_own(LEFT, RIGHT, R, T, 0, 1, alpha, None, zero_disparity)
    assert np.abs(own.R1 - rect.R1).max() < 1e-12 and np.abs(own.R2 - rect.R2).max() < 1e-12
    for a, b in ((own.P1, rect.P1), (own.P2, rect.P2)):
        assert np.abs(a[:, :3] - b[:, :3]).max() < 0.05  # OpenCV's corners and grid are float32
        assert np.abs(a[:, 3] - b[:, 3]).max() <= 1e-4 * np.abs(b[:, 3]).max() + 1e-9
    assert np.abs(own.Q - rect.Q).max() < 0.05
    for a, b in ((own.roi1, rect.roi1), (own.roi2, rect.roi2)):
        assert np.abs(np.subtract(a, b)).max() <= 1
    _check_rectifies(rig, rect)
    _check_rectifies(rig, own)


@pytest.mark.parametrize("b", [SMALL, FISH], ids=["other size and lens", "pinhole with fisheye"])
@pytest.mark.parametrize("alpha", [-1.0, 0.0, 1.0])
def test_pairs_opencv_cannot_take(b: Camera, alpha: float) -> None:
    rig = _rig(LEFT, b)
    rect = rectify_pair(rig, alpha=alpha)
    assert rect.method == "circcal"
    assert rect.image_size == (max(LEFT.width, b.width), max(LEFT.height, b.height))
    assert rect.P1[1, 2] == rect.P2[1, 2]  # one row for both
    _check_rectifies(rig, rect)
    for roi in (rect.roi1, rect.roi2):
        x, y, w, h = roi
        assert w > 0 and h > 0 and x + w <= rect.image_size[0] and y + h <= rect.image_size[1]


def test_fisheye_pair_is_opencv_fisheye() -> None:
    rig = _rig(FISH, FISH2)
    rect = rectify_pair(rig, alpha=0.5)
    assert rect.method == "cv2.fisheye.stereoRectify"
    _check_rectifies(rig, rect)


def test_vertical_pair() -> None:
    pose = ([0.01, 0.02, -0.01], [2.0, -110.0, 4.0])
    for rig, method in ((_rig(LEFT, RIGHT, pose), "cv2.stereoRectify"), (_rig(LEFT, SMALL, pose), "circcal")):
        rect = rectify_pair(rig)
        assert rect.vertical and rect.method == method
        _check_rectifies(rig, rect)


@pytest.mark.parametrize("b", [RIGHT, SMALL, FISH])
def test_maps_invert_the_rectification(b: Camera) -> None:
    rig = _rig(LEFT, b)
    rect = rectify_pair(rig)
    maps = rectification_maps(rig, rect)
    w, h = rect.image_size
    for k, Rk, Pk, (mx, my) in ((0, rect.R1, rect.P1, maps[0]), (1, rect.R2, rect.P2, maps[1])):
        assert mx.shape == (h, w) and mx.dtype == np.float32
        cam = rig.cameras[k]
        ys, xs = np.mgrid[0:h:37, 0:w:41]
        src = np.column_stack([mx[ys, xs].ravel(), my[ys, xs].ravel()]).astype(np.float64)
        inside = (src[:, 0] >= 0) & (src[:, 0] <= cam.width - 1) & (src[:, 1] >= 0) & (src[:, 1] <= cam.height - 1)
        assert inside.sum() > 20
        back = _rectified(rig, k, Rk, Pk, src[inside])
        target = np.column_stack([xs.ravel(), ys.ravel()])[inside]
        assert np.abs(back - target).max() < 0.02  # float32 maps


def test_overlay(tmp_path) -> None:
    rig = _rig(LEFT, SMALL)
    rng = np.random.default_rng(1)
    a = rng.integers(0, 255, (960, 1280), dtype=np.uint8)
    b = rng.integers(0, 4095, (480, 640, 3)).astype(np.uint16)
    vis = rectified_overlay(rig, a, b, line_every=50)
    assert vis.shape == (960, 2 * 1280, 3) and vis.dtype == np.uint8
    assert (vis[::50] == (0, 255, 0)).all() and not (vis[25] == (0, 255, 0)).all()
    cv2.imwrite(str(tmp_path / "a.png"), a)
    cv2.imwrite(str(tmp_path / "b.png"), b)
    out = write_rectified_overlay(tmp_path / "sub" / "pair.png", rig, tmp_path / "a.png", tmp_path / "b.png")
    assert cv2.imread(str(out)).shape == (960, 2560, 3)
    with pytest.raises(ImageError, match="'b'"):
        rectified_overlay(rig, a, a)
    with pytest.raises(ImageError, match="no image"):
        write_rectified_overlay(tmp_path / "x.png", rig, tmp_path / "a.png", tmp_path / "missing.png")
    with pytest.raises(InputError, match="line_every"):
        rectified_overlay(rig, a, b, line_every=0)


def test_refusals() -> None:
    rig = _rig(LEFT, RIGHT)
    with pytest.raises(InputError, match="two different"):
        rectify_pair(rig, 1, 1)
    with pytest.raises(InputError, match="index"):
        rectify_pair(rig, 0, 2)
    with pytest.raises(InputError, match="alpha"):
        rectify_pair(rig, alpha=1.5)
    with pytest.raises(InputError, match="alpha"):
        rectify_pair(rig, alpha=float("nan"))
    with pytest.raises(InputError, match="size"):
        rectify_pair(rig, new_size=(0, 10))
    with pytest.raises(InputError, match="same place"):
        rectify_pair(_rig(LEFT, RIGHT, ([0.1, 0, 0], [0, 0, 0])))
