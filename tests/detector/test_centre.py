"""Projective centre correction: pole of the vanishing line vs the truth, vs the tangent/chord construction."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from circcal.detector.measure.centre import correct_centres, pole_centre, tangent_chord_centre, vanishing_line
from circcal.detector.measure.ellipse import conic_centre, transform_conic


def _random_homography(seed: int) -> np.ndarray:
    """Board (mm) -> image (px) homography of a plausible camera view: f ~ 500-3000 px, tilt up to 70 deg."""
    import cv2

    rng = np.random.default_rng(seed)
    f = rng.uniform(500, 3000)
    K = np.array([[f, 0, rng.uniform(300, 1000)], [0, f, rng.uniform(200, 600)], [0, 0, 1]])
    tilt = np.deg2rad(rng.uniform(0, 70))
    axis = rng.normal(size=2)
    axis = np.array([*axis / np.linalg.norm(axis), 0.0])
    R = cv2.Rodrigues(axis * tilt)[0] @ cv2.Rodrigues(np.array([0, 0, rng.uniform(-np.pi, np.pi)]))[0]
    t = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(200, 800)])
    return K @ np.column_stack([R[:, 0], R[:, 1], t])


def _circle(x0, y0, r):
    return np.array([[1, 0, -x0], [0, 1, -y0], [-x0, -y0, x0 * x0 + y0 * y0 - r * r]], dtype=np.float64)


def _project(H, xy):
    p = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    return p[:, :2] / p[:, 2:]


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 10**6), st.floats(-40, 40), st.floats(-40, 40), st.floats(1.0, 15.0))
def test_pole_and_tangent_construction_agree_with_truth(seed, x0, y0, r):
    H = _random_homography(seed)
    E = transform_conic(_circle(x0, y0, r), H)
    truth = _project(H, np.array([[x0, y0]]))[0]
    line = vanishing_line(H)
    p = pole_centre(E, line)
    t = tangent_chord_centre(E, line)
    scale = np.linalg.norm(truth) + 1.0
    assert np.linalg.norm(p - truth) < 1e-9 * scale
    assert np.linalg.norm(t - p) < 1e-8 * scale


def test_affine_view_gives_the_ellipse_centre():
    H = np.array([[900.0, 40, 500], [-30, 700, 300], [0, 0, 1]])  # affine: vanishing line at infinity
    E = transform_conic(_circle(3.0, -2.0, 2.5), H)
    line = vanishing_line(H)
    assert np.allclose(pole_centre(E, line), conic_centre(E), atol=1e-9)
    assert np.allclose(tangent_chord_centre(E, line), conic_centre(E), atol=1e-8)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10**6))
def test_iterated_correction_recovers_every_centre(seed):
    H = _random_homography(seed)
    gx, gy = np.meshgrid(np.arange(7) * 10.0, np.arange(6) * 10.0)
    board = np.column_stack([gx.ravel(), gy.ravel()]) - [30, 25]
    conics = np.array([transform_conic(_circle(x, y, 3.5), H) for x, y in board])
    truth = _project(H, board)
    biased = np.array([conic_centre(E) for E in conics])
    centres, Hf = correct_centres(conics, board)
    scale = np.abs(truth).max() + 1
    assert np.max(np.linalg.norm(centres - truth, axis=1)) < 1e-7 * scale
    # the plain ellipse centres are biased (so the test above is not vacuous) unless the view is nearly affine
    lin = vanishing_line(H)
    if np.linalg.norm(lin[:2]) / abs(lin[2]) > 1e-3:
        assert np.max(np.linalg.norm(biased - truth, axis=1)) > 1e-6
    assert np.allclose(_project(Hf, board), truth, atol=1e-6 * scale)


def test_the_default_tolerance_stops_at_the_fixed_point():
    """Stopping at a last step < 1e-6 px (the default) leaves the centres within 4e-7 px of the iteration run to 1e-13
    px, on ellipses 0.02 px off a consistent view (the fixed point then is not the truth), dots 0.9 pitches across,
    tilts to 70 deg, 40 views (measured 2.0e-7; a 1e-4 px tolerance leaves 6.7e-7)."""
    worst = 0.0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        H = _random_homography(seed)
        gx, gy = np.meshgrid(np.arange(7) * 10.0, np.arange(6) * 10.0)
        board = np.column_stack([gx.ravel(), gy.ravel()]) - [30, 25]
        shifts = rng.normal(0, 0.02, (len(board), 2))
        conics = np.array(
            [
                transform_conic(
                    transform_conic(_circle(x, y, 4.5), H), np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])
                )
                for (x, y), (dx, dy) in zip(board, shifts)
            ]
        )
        c, _ = correct_centres(conics, board)
        c0, _ = correct_centres(conics, board, tol_px=1e-13, max_iter=50)
        worst = max(worst, float(np.max(np.abs(c - c0))))
    assert worst < 4e-7, worst


def test_batched_poles_equal_single_poles():
    from circcal.detector.measure.centre import pole_centres

    H = _random_homography(7)
    gx, gy = np.meshgrid(np.arange(5) * 10.0, np.arange(4) * 10.0)
    conics = np.array([transform_conic(_circle(x, y, 3.0), H) for x, y in zip(gx.ravel(), gy.ravel())])
    line = vanishing_line(H)
    direct = np.array([np.linalg.solve(E, line) for E in conics])  # the closed form E^-1 l
    direct = direct[:, :2] / direct[:, 2:]
    assert np.allclose(pole_centres(conics, line), direct, rtol=0, atol=1e-7)
    assert np.allclose(np.array([pole_centre(E, line) for E in conics]), pole_centres(conics, line), atol=1e-9)
