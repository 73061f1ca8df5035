"""Is the lens model the right one? circcal.solver.modelfit on rendered fixtures (truth known: which model made
the images) and on synthetic residuals (noise of known size, a radial pattern of known size)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from circcal.board import Board
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.truth import load_truth
from circcal.pipeline import calibrate_images
from circcal.solver import CalibrationOptions
from circcal.solver.modelfit import MIN_EFFECT_PX, chi2_survival_even, model_fit, neighbour_noise


def _calibrate(scenario: str, variant: str, lens: str):
    t = load_truth(fixture_dir(scenario, variant))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cal = calibrate_images([v.image for v in t.views], t.board, CalibrationOptions(lens=lens), progress=False)
    return cal, [str(w.message) for w in caught]


def test_neighbour_noise_measures_noise_under_a_smooth_error():
    """Per-coordinate noise 0.05 px plus a smooth field of 0.2 px (4x the noise) over the 150 mm board: the
    neighbour differences (25 mm apart, where the field changes by <= 0.05 px) see the noise, not the field."""
    rng = np.random.default_rng(1)
    obj = Board(7, 7, 25.0, 12.5).object_points()
    objs, res = [], []
    for _ in range(10):
        smooth = 0.2 * np.stack([(obj[:, 0] / 150.0) ** 2, -((obj[:, 1] / 150.0) ** 2)], axis=1)
        objs.append(obj)
        res.append(smooth + rng.normal(0.0, 0.05, (len(obj), 2)))
    assert np.std(np.concatenate(res)) > 0.06  # the field is there
    assert neighbour_noise(objs, res) == pytest.approx(0.05, rel=0.1)


@pytest.mark.parametrize(
    "scenario,variant,true_lens", [("rational-wide", "clean", "rational"), ("rational-wide", "perturbed", "rational")]
)
def test_too_simple_model_is_flagged_and_the_true_one_fits(scenario, variant, true_lens):
    """rational-wide's lens: the 5 coefficients miss it by ~0.13 px RMS; the rational model fits it to noise."""
    simple, _ = _calibrate(scenario, variant, "opencv5")
    fit = model_fit(simple.result)
    assert not fit.fits and fit.lens == "opencv5"
    assert abs(fit.radial_px[fit.worst]) > 2 * MIN_EFFECT_PX
    msg = fit.message()
    assert "does NOT fit" in msg and "--lens rational" in msg
    right, _ = _calibrate(scenario, variant, true_lens)
    fit = model_fit(right.result)
    assert fit.fits and np.max(np.abs(fit.radial_px)) < 0.005


def test_opencv5_on_a_fisheye_gives_a_model_and_says_it_does_not_fit():
    """opencv5 on the ~170 deg fisheye: its polynomial folds over inside the image. The loop keeps a model (the
    round whose camera could start the next is kept, with a warning naming why) instead of failing, and the
    verdict names the lens model."""
    cal, said = _calibrate("fisheye", "clean", "opencv5")
    assert any("re-correction" in s for s in said)
    fit = model_fit(cal.result)
    assert not fit.fits and "--lens" in fit.message() and "fisheye" in fit.message()
    right, _ = _calibrate("fisheye", "clean", "fisheye")
    assert model_fit(right.result).fits


@pytest.mark.parametrize("scenario,variant", [("paper", "normal"), ("wide", "clean"), ("asymmetric", "clean")])
def test_right_model_is_not_flagged(scenario, variant):
    cal, _ = _calibrate(scenario, variant, "opencv5")
    fit = model_fit(cal.result)
    assert fit.fits, fit.message()


@pytest.mark.parametrize("k", [2, 4, 8, 16])
def test_chi2_survival_equals_scipy(k):
    """The Poisson-sum survival function equals scipy.special.chdtrc to 1e-12 relative, from the bulk to p ~ 1e-30
    (the rule compares p with 1e-6), and is 1 at x <= 0."""
    from scipy.special import chdtrc

    for x in np.concatenate([np.linspace(0.01, 3 * k, 40), [50.0, 100.0, 150.0]]):
        want = float(chdtrc(k, x))
        assert chi2_survival_even(k, float(x)) == pytest.approx(want, rel=1e-12, abs=1e-300)
    assert chi2_survival_even(k, 0.0) == 1.0 and chi2_survival_even(k, -1.0) == 1.0


def test_chi2_survival_refuses_odd_dof():
    with pytest.raises(ValueError, match="even"):
        chi2_survival_even(3, 1.0)
