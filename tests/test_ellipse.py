"""Direct ellipse fit (Halir-Flusser) and conic conversions: exact recovery on random ellipses."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from circcal.ellipse import (algebraic_distance, conic_center, conic_from_params, conic_params, ellipse_normals,
                             fit_ellipse_direct, sample_ellipse)

ellipses = st.tuples(
    st.floats(-2000, 4000), st.floats(-2000, 4000),  # centre, px (far from the origin on purpose)
    st.floats(2.0, 400.0), st.floats(0.1, 1.0),       # a, b/a
    st.floats(-np.pi / 2 + 1e-3, np.pi / 2),          # angle
)


@settings(max_examples=60, deadline=None)
@given(ellipses, st.integers(6, 200), st.floats(0.0, 2 * np.pi))
def test_fit_recovers_exact_ellipse(e, n, t0):
    cx, cy, a, ratio, ang = e
    b = a * ratio
    Q = conic_from_params((cx, cy), (a, b), ang)
    # points on an arc covering at least half the ellipse, starting anywhere
    t = t0 + np.linspace(0, 2 * np.pi, n, endpoint=False)
    R = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    pts = np.array([cx, cy]) + np.column_stack([a * np.cos(t), b * np.sin(t)]) @ R.T
    F = fit_ellipse_direct(pts)
    c, (fa, fb), fang = conic_params(F)
    assert np.allclose(c, [cx, cy], atol=1e-7 * a)
    assert fa == pytest.approx(a, rel=1e-7)
    assert fb == pytest.approx(b, rel=1e-7)
    if ratio < 0.99:  # the angle is defined only for a non-circle
        d = (fang - ang + np.pi / 2) % np.pi - np.pi / 2
        assert abs(d) < 1e-6 / (1 - ratio)
    # points satisfy the conic (scale: unit Frobenius norm, residual relative to a^2 terms)
    assert np.max(np.abs(algebraic_distance(F, pts))) < 1e-9 * max(1.0, np.abs(F).max() * (abs(cx) + abs(cy) + a) ** 2)


@settings(max_examples=60, deadline=None)
@given(ellipses)
def test_params_roundtrip_and_sampling(e):
    cx, cy, a, ratio, ang = e
    Q = conic_from_params((cx, cy), (a, a * ratio), ang)
    assert np.allclose(conic_center(Q), [cx, cy], atol=1e-9 * (abs(cx) + abs(cy) + a))
    pts = sample_ellipse(Q, 17)
    # sampled points lie on the ellipse: (u/a)^2 + (v/b)^2 = 1 in its own frame
    d = pts - [cx, cy]
    u = d[:, 0] * np.cos(ang) + d[:, 1] * np.sin(ang)
    v = -d[:, 0] * np.sin(ang) + d[:, 1] * np.cos(ang)
    assert np.allclose((u / a) ** 2 + (v / (a * ratio)) ** 2, 1.0, atol=1e-6)
    n = ellipse_normals(Q, pts)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    assert np.all(np.sum(n * (pts - [cx, cy]), axis=1) > 0)  # outward


def test_noisy_fit_is_close_and_an_ellipse():
    rng = np.random.default_rng(0)
    Q = conic_from_params((100.0, 50.0), (20.0, 8.0), 0.3)
    pts = sample_ellipse(Q, 300) + rng.normal(0, 0.05, (300, 2))
    c, (a, b), ang = conic_params(fit_ellipse_direct(pts))
    assert np.allclose(c, [100, 50], atol=0.02)
    assert a == pytest.approx(20, abs=0.03) and b == pytest.approx(8, abs=0.03)
    assert ang == pytest.approx(0.3, abs=0.01)


def test_bad_input_is_rejected():
    with pytest.raises(ValueError, match="at least 5"):
        fit_ellipse_direct(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="NaN"):
        fit_ellipse_direct(np.full((6, 2), np.nan))
    with pytest.raises(ValueError):
        fit_ellipse_direct(np.column_stack([np.arange(10.0), 2 * np.arange(10.0)]))  # collinear
