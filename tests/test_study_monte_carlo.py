"""The Monte-Carlo studies of the solver's uncertainty (`make study`), run as the study spec studies/monte-carlo.yaml
through the study runner (embedded Dask cluster); pytest reads the finished table and asserts. These were
test_calibrate.py's test_monte_carlo_uncertainty_is_consistent and test_paper_geometry_monte_carlo, with the same
views, noise draws (numpy.random.default_rng(seed), one draw per view in order) and bounds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from circcal.study import RowStore, load_spec, run_study

REPO = Path(__file__).resolve().parents[1]
SPEC = REPO / "studies" / "monte-carlo.yaml"

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    """The finished study's rows (computed afresh: the table is what this code gives)."""
    folder = tmp_path_factory.mktemp("monte-carlo")
    run = run_study(load_spec(SPEC), folder, workers=2, progress=False)
    assert run.complete, run.errors
    rows = RowStore(folder).read().to_pylist()
    assert {r["status"] for r in rows} == {"ok"}
    return rows


def _cell(rows, cell, variant=None):
    out = [r for r in rows if r["cell"] == cell and (variant is None or r["variant"] == variant)]
    assert len(out) == 60
    return out


def test_monte_carlo_uncertainty_is_consistent(table):
    """Over 60 noise draws on fixed poses: empirical std of fx, cx (and fy, cy, k1) within 25% of the mean stated
    sigma, and the mean error within 0.5 sigma (no bias)."""
    rows = _cell(table, 0)
    for name in ("fx", "cx", "fy", "cy", "k1"):
        est = np.array([r[f"est_{name}"] for r in rows])
        mean_sigma = np.mean([r[f"std_{name}"] for r in rows])
        emp = est.std(ddof=1)
        assert 0.75 < emp / mean_sigma < 1.25, (name, emp, mean_sigma)
        assert abs(est.mean() - rows[0][f"true_{name}"]) < 0.5 * mean_sigma, name


@pytest.mark.parametrize("sigma", [0.0023, 0.0146])
def test_paper_geometry_monte_carlo(table, sigma):
    """The `paper` scenario's own 14 views, perfect centres plus Gaussian noise at the per-coordinate levels circcal's
    centres carry there (normal light 0.0023 px, weak 0.0146 px), 60 draws: the stated sigma of fx, cx is honest
    (within 25 %), and the printed distribution of the projection difference to the true camera shows what any
    unbiased calibrator gets on these views. Measured: median 0.019 px (53 % of draws <= 0.02 px) in normal light,
    0.120 px (2 %) in weak light: the issue's 0.02 px bar is a coin toss even for a perfect detector."""
    rows = _cell(table, 1, f"noise{sigma:g}px")
    diffs = np.array([r["truth_rms_px"] for r in rows])
    print(
        f"\nsigma {sigma} px: projection difference to the truth median {np.median(diffs):.4f} px, p95 "
        f"{np.percentile(diffs, 95):.4f} px, {100 * np.mean(diffs <= 0.02):.0f} % of draws <= 0.02 px"
    )
    for name in ("fx", "cx"):
        est = np.array([r[f"est_{name}"] for r in rows])
        ratio = est.std(ddof=1) / np.mean([r[f"std_{name}"] for r in rows])
        assert 0.75 < ratio < 1.25, (name, ratio)
