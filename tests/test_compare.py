"""analysis/compare.py: parameter and projection differences, grid re-matching, centre errors."""

from __future__ import annotations

import numpy as np
import pytest

from circcal.analysis.compare import (
    centre_errors,
    match_grid_order,
    match_views,
    param_diff,
    per_coord_to_per_point,
    per_point_to_per_coord,
    pixel_grid,
    projection_diff,
)
from circcal.board import Board
from circcal.metrics import error_stats
from circcal.model import Camera, unproject
from circcal.rotation import fit_rotation, rodrigues, rotation_angle_deg

CAM = Camera(1920, 1080, 1500.0, 1502.0, 955.0, 545.0, np.array([-0.12, 0.08, 4e-4, -3e-4, -0.02]))
PINHOLE = Camera(1920, 1080, 1500.0, 1500.0, 959.5, 539.5, np.zeros(5))


def shifted(cam: Camera, **kw) -> Camera:
    d = cam.to_dict()
    d.update(kw)
    return Camera.from_dict(d)


def test_param_diff_in_sigmas():
    b = shifted(CAM, fx=1501.0, cy=544.0)
    std = {"fx": 0.5, "fy": 0.5, "cx": 0.3, "cy": 0.4, "k1": 0.0, "k2": 1e-3, "p1": 1e-5, "p2": 1e-5, "k3": 1e-2}
    d = param_diff(CAM, b, std, std)
    assert d["fx"]["diff"] == pytest.approx(1.0)
    assert d["fx"]["sigma"] == pytest.approx(0.5 * np.sqrt(2))
    assert d["fx"]["diff_sigmas"] == pytest.approx(1.0 / (0.5 * np.sqrt(2)))
    assert d["cy"]["diff_sigmas"] == pytest.approx(-1.0 / (0.4 * np.sqrt(2)))
    assert d["fy"]["diff"] == 0.0
    assert np.isnan(d["k1"]["diff_sigmas"])  # no stated sigma (0): no ratio
    assert np.isnan(param_diff(CAM, b)["fx"]["sigma"])


def test_identical_models_differ_by_nothing():
    for fit in (False, True):
        for distance in (None, 500.0):
            d = projection_diff(CAM, CAM, fit=fit, distance=distance)
            assert d["n_invalid"] == 0 and d["n"] == len(pixel_grid(CAM))
            assert d["max_px"] < 1e-9
    assert np.allclose(projection_diff(CAM, CAM, fit=True)["R"], np.eye(3), atol=1e-12)


@pytest.mark.parametrize("f,max_fit_px", [(1500.0, 0.2), (20000.0, 0.002)])
def test_principal_point_shift_is_mostly_a_rotation(f, max_fit_px):
    a = shifted(PINHOLE, fx=f, fy=f)
    b = shifted(a, cx=a.cx + 0.5)
    raw = projection_diff(a, b)
    assert raw["max_px"] == pytest.approx(0.5, abs=1e-9) and raw["rms_px"] == pytest.approx(0.5, abs=1e-9)
    fit = projection_diff(a, b, fit=True)
    # a 0.5 px shift is a rotation of ~0.5/f rad near the centre; the tan() nonlinearity leaves the rest, which
    # shrinks as the field of view narrows (0.16 px at the corners for f = 1500 px, 0.001 px for f = 20000 px)
    assert 1e-5 < fit["max_px"] < max_fit_px
    angle = np.radians(rotation_angle_deg(fit["R"]))
    assert angle == pytest.approx(0.5 / f, rel=0.15)


def test_projection_diff_against_cv2():
    """Each grid pixel of A unprojected, then projected with B by cv2.projectPoints, equals compare's numbers."""
    import cv2

    b = shifted(CAM, fx=1503.0, dist=[-0.1, 0.05, 0.0, 0.0, 0.0])
    d = projection_diff(CAM, b, gridn_width=12, distance=400.0)
    rays = unproject(d["uv"], CAM)
    P = rays / np.linalg.norm(rays, axis=1, keepdims=True) * 400.0
    q, _ = cv2.projectPoints(P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), b.K, b.dist)
    ref = np.linalg.norm(q.reshape(-1, 2) - d["uv"], axis=1)
    assert np.max(np.abs(ref - d["diff"])) < 1e-9
    assert d["max_px"] == pytest.approx(ref.max(), abs=1e-9)


def test_fit_rotation_recovers_a_rotation():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(50, 3))
    R = rodrigues(np.array([0.1, -0.2, 0.05]))
    Rf, t = fit_rotation(A, A @ R.T)
    assert np.allclose(Rf, R, atol=1e-12) and np.allclose(t, 0)
    Rf, t = fit_rotation(A, A @ R.T + [1.0, 2.0, 3.0], translation=True)
    assert np.allclose(Rf, R, atol=1e-12) and np.allclose(t, [1, 2, 3], atol=1e-12)


@pytest.mark.parametrize(
    "rows,cols,label", [(7, 7, "rot90"), (7, 7, "rot270"), (7, 7, "rot180"), (8, 10, "rot180"), (8, 10, "rot0")]
)
def test_match_grid_order_undoes_rotations(rows, cols, label):
    rng = np.random.default_rng(0)
    truth = np.stack(np.meshgrid(np.arange(cols) * 30.0, np.arange(rows) * 30.0), -1).reshape(-1, 2) + 100.0
    truth = truth + rng.normal(0, 0.5, truth.shape)
    board = Board(rows, cols, 30.0, 10.0)
    perm = {s.label: s.perm for s in board.symmetries()}[label]
    # a detector that returned the grid transformed: det[perm] is in board order, i.e. det = truth[inverse(perm)]
    inv = np.argsort(perm)
    det = truth[inv] + 0.01
    got, found, rms = match_grid_order(det, truth, board)
    assert found == label
    assert np.allclose(got, truth + 0.01) and rms == pytest.approx(0.01 * np.sqrt(2))


def test_mirror_only_when_asked():
    rows = cols = 5
    board = Board(rows, cols, 30.0, 10.0)
    truth = np.stack(np.meshgrid(np.arange(cols) * 30.0, np.arange(rows) * 30.0), -1).reshape(-1, 2)
    truth = truth * [1.0, 1.3]  # break the square's diagonal symmetry
    det = truth.reshape(rows, cols, 2)[:, ::-1].reshape(-1, 2)
    _, label, rms = match_grid_order(det, truth, board)
    assert rms > 1.0  # no rotation maps a mirror image back
    got, label, rms = match_grid_order(det, truth, board, mirror=True)
    assert label == "mirror" and rms < 1e-12
    with pytest.raises(ValueError, match="expected 25 points"):
        match_grid_order(det[:-1], truth, board)


def test_match_views_puts_views_in_the_reference_order():
    """A second detector's views, some reversed (a symmetric grid's 180-degree ambiguity): reversed back where that
    matches the reference, with NaN in the reference ignored and a view without a reference kept as detected."""
    rows, cols = 8, 10
    board = Board(rows, cols, 25.0, 10.0)
    base = np.stack(np.meshgrid(np.arange(cols) * 25.0, np.arange(rows) * 25.0), -1).reshape(-1, 2) + 50.0
    rng = np.random.default_rng(2)
    ref = [base + rng.normal(0, 3.0, base.shape) for _ in range(4)]
    det = [r + 0.05 for r in ref]
    det[1], det[3] = det[1][::-1], det[3][::-1]
    ref[3] = ref[3].copy()
    ref[3][:5] = np.nan  # points the reference detector missed
    got, labels = match_views(det, ref, board)
    assert labels == ["rot0", "rot180", "rot0", "rot180"]
    for g, r in zip(got, ref):
        assert np.allclose(g[5:], r[5:] + 0.05)
    got, labels = match_views(det, [ref[0], None, ref[2], ref[3]], board)
    assert labels == ["rot0", "rot0", "rot0", "rot180"] and np.array_equal(got[1], det[1])
    with pytest.raises(ValueError, match="expected 80 points"):
        match_views([base[:-1]], [base], board)


def test_centre_errors_with_rematching():
    rng = np.random.default_rng(1)
    rows = cols = 7
    base = np.stack(np.meshgrid(np.arange(cols) * 25.0, np.arange(rows) * 25.0), -1).reshape(-1, 2) + 50.0
    truth = [base + rng.normal(0, 2.0, base.shape) for _ in range(3)]
    errs = [rng.normal(0, 0.05, base.shape) for _ in range(3)]
    detected = [t + e for t, e in zip(truth, errs)]
    detected[1] = detected[1].reshape(rows, cols, 2)[::-1, ::-1].reshape(-1, 2)  # returned rotated by 180 deg
    out = centre_errors(detected, truth, board=Board(rows, cols, 25.0, 10.0))
    assert out["matched"] == ["rot0", "rot180", "rot0"]
    expected = error_stats(np.concatenate(errs))
    for k, v in expected.items():
        assert out["overall"][k] == pytest.approx(v, rel=1e-12)
    # without re-matching the rotated view is (rightly) far off
    assert centre_errors(detected, truth)["per_view"][1]["max_2d_px"] > 10


def test_error_conventions():
    r = np.array([[0.3, 0.4], [0.0, 0.0], [-0.6, 0.8]])
    s = error_stats(r)
    assert s["rms_per_point_px"] == pytest.approx(np.sqrt((0.25 + 1.0) / 3))
    assert per_point_to_per_coord(s["rms_per_point_px"]) == pytest.approx(s["rms_per_coord_px"])
    assert per_coord_to_per_point(s["rms_per_coord_px"]) == pytest.approx(s["rms_per_point_px"])
