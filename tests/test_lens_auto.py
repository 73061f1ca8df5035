"""``--lens auto`` and the second detection pass (issue 33): the lens model chosen from the images, checked against
the truth of rendered scenarios, and views the first detection refused found again with the first model."""

from __future__ import annotations

import numpy as np
import pytest

from circcal.detector import Detection, Reason
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.scenarios import get_scenario
from circcal.fixtures.truth import load_truth
from circcal.model import project_camera, unproject
from circcal.pipeline import LENS_CANDIDATES, calibrate_images
from circcal.solver import CalibrationOptions


def _observed_difference(cal, truth_camera) -> float:
    """The largest difference (px) between the model and the truth over the observed field: each observed centre's
    ray under the model, projected by the true camera (the same frame: both see the same board poses)."""
    uv = np.concatenate([c[np.all(np.isfinite(c), axis=1)] for c in cal.centres])
    return float(np.max(np.linalg.norm(project_camera(unproject(uv, cal.result.camera), truth_camera) - uv, axis=1)))


@pytest.mark.parametrize(
    "scenario, lens",
    [
        ("fisheye", "fisheye"),
        ("fisheye-central", "fisheye"),  # large central boards, up to 84 deg off axis (issue 33's scenario)
        ("rational-wide", "rational"),
        ("small-noisy", "opencv5"),
    ],
)
def test_lens_auto_chooses_the_lens_of_the_truth(scenario, lens):
    sc = get_scenario(scenario)
    truth = load_truth(fixture_dir(scenario, next(iter(sc.variants)), progress=False))
    paths = [v.image for v in truth.views]
    cal = calibrate_images(paths, truth.board, progress=False, jobs=1, lens_candidates=LENS_CANDIDATES)
    assert cal.lens_choice is not None and cal.lens_choice.lens == lens, cal.lens_choice.lines()
    assert cal.result.camera.lens == lens and [r["lens"] for r in cal.lens_choice.candidates] == list(LENS_CANDIDATES)
    if scenario != "small-noisy":  # the clean wide renders: the bar, 0.01 px over the observed field
        assert _observed_difference(cal, truth.camera) <= 0.01


def test_a_hold_a_candidate_lacks_leaves_it_out_with_the_reason():
    truth = load_truth(fixture_dir("small-noisy", progress=False))
    options = CalibrationOptions.from_flags(fix_tangential=True)
    cal = calibrate_images(
        [v.image for v in truth.views], truth.board, options, progress=False, jobs=1, lens_candidates=LENS_CANDIDATES
    )
    fisheye = next(r for r in cal.lens_choice.candidates if r["lens"] == "fisheye")
    assert "error" in fisheye and cal.lens_choice.lens != "fisheye"


def test_views_the_first_detection_refused_are_found_with_the_first_model(monkeypatch):
    """The second pass: a view refused without a model (as a strongly bent lattice is) and found with it joins the
    calibration, and says so."""
    import circcal.detector.files as files

    truth = load_truth(fixture_dir("small-noisy", progress=False))
    paths = [str(v.image) for v in truth.views]
    hard = {paths[2], paths[5]}
    real = files._detect_file

    def first_blind(path, board, camera):
        if str(path) in hard and camera is None:
            return Detection(False, None, "not recognised: no regular lattice of dots", Reason.GRID_NOT_RECOGNISED)
        return real(path, board, camera)

    monkeypatch.setattr(files, "_detect_file", first_blind)
    cal = calibrate_images(paths, truth.board, progress=False, jobs=1)
    assert sorted(cal.recovered) == sorted(hard) and len(cal.used) == len(paths) and not cal.failed
    off = calibrate_images(paths, truth.board, progress=False, jobs=1, second_pass=False)
    assert len(off.used) == len(paths) - 2 and {r.path for r in off.failed} == hard


def test_no_model_names_the_lens_option_to_try(tmp_path, capsys, monkeypatch):
    """An unusable start never ends in an unexplained exit 1: the message names --lens auto."""
    import circcal.analysis.calibration as calibration
    from circcal.cli import main
    from circcal.errors import CalibrationError

    def fails(*a, **k):
        raise CalibrationError("the initial camera's distortion cannot be inverted at some observed points")

    monkeypatch.setattr(calibration, "calibrate_images", fails)
    truth = load_truth(fixture_dir("small-noisy", progress=False))
    code = main(
        [
            "calibrate",
            *[str(v.image) for v in truth.views[:3]],
            "--grid",
            "7x9",
            "--pitch",
            "10mm",
            "--out",
            str(tmp_path / "m.json"),
            "--no-progress",
        ]
    )
    assert code == 1 and "--lens auto" in capsys.readouterr().err


def test_a_wrong_grid_is_named_not_the_lens(tmp_path, capsys):
    """No model because --grid is not the board's: the message gives the images' grid, not a lens to try."""
    from circcal.cli import main

    truth = load_truth(fixture_dir("small-noisy", progress=False))
    argv = ["calibrate", *[str(v.image) for v in truth.views[:4]], "--grid", "6x8", "--pitch", "10mm"]
    code = main([*argv, "--out", str(tmp_path / "m.json"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 1 and "--grid 7x9" in err and "--lens auto" not in err, err
    assert not (tmp_path / "m.json").exists()
