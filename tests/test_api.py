"""The public API (``circcal.NAME``): every name is the function the command line calls, imported on first use, and a
calibration through it gives the camera of the truth."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import circcal
from circcal.errors import InputError


@pytest.mark.parametrize("name", sorted(circcal._API))
def test_every_public_name_is_the_clis_own_function(name):
    import importlib

    module, attribute = circcal._API[name]
    assert getattr(circcal, name) is getattr(importlib.import_module(module), attribute)
    assert name in circcal.__all__ and name in dir(circcal)
    assert getattr(circcal, name).__doc__, f"circcal.{name} has no docstring"


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'calibrat'"):
        circcal.calibrat  # noqa: B018


def test_import_circcal_loads_nothing_heavy():
    out = subprocess.run(
        [sys.executable, "-c", "import sys, circcal; print(sorted(m for m in ('numpy', 'cv2') if m in sys.modules))"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert out == "[]"


def test_calibrate_detect_save_and_load_through_the_api(tmp_path):
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth

    truth = load_truth(fixture_dir("small-noisy"))
    paths = [v.image for v in truth.views]
    run = circcal.calibrate(paths, truth.board, circcal.CalibrationOptions(), jobs=1)
    cam = run.camera
    for name in ("fx", "fy", "cx", "cy"):  # within 4 stated sigmas of the truth
        assert abs(getattr(cam, name) - getattr(truth.camera, name)) < 4 * run.std[name], name
    # the verdict and the uncertainty come with it; the images used and left out too
    assert run.verdict and "RMS" in " ".join(run.verdict) and run.uncertainty is not None
    assert len(run.residuals) == len(run.images.used) == len(paths) and not run.images.failed
    # from observations: the same model to the solver's precision
    obs = run.images.observations(truth.board)
    again = circcal.calibrate(observations=obs, board=truth.board, image_size=(cam.width, cam.height))
    assert np.allclose(again.camera.intrinsics, cam.intrinsics, rtol=1e-9, atol=1e-9) and again.verdict
    with pytest.raises(InputError, match=r"give board= \(a circcal.Board"):
        circcal.calibrate(observations=obs, image_size=(cam.width, cam.height))
    import cv2

    d = circcal.detect(cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED), truth.board)
    assert d.found and np.nanmax(np.abs(d.centres - truth.views[0].centres)) < 0.1
    circcal.save_model(tmp_path / "cam.yaml", cam)
    back = circcal.load_model(tmp_path / "cam.yaml")
    assert np.allclose(back.intrinsics, cam.intrinsics, rtol=1e-12, atol=1e-9)
    assert circcal.diff(cam, back).rms_px < 1e-6
    assert circcal.diff(tmp_path / "cam.yaml", str(tmp_path / "cam.yaml")).rms_px < 1e-9  # model files as well


def test_a_folder_stands_for_its_images_and_a_non_path_is_refused(tmp_path):
    # circcal.calibrate("photos", board) iterated the string's characters as file names, and a Path raised TypeError
    from circcal.fixtures.cache import fixture_dir
    from circcal.imagefiles import image_list

    folder = fixture_dir("small-noisy")
    pngs = sorted(str(p) for p in folder.glob("*.png"))
    assert image_list(folder) == image_list(str(folder)) == pngs and len(pngs) >= 3
    assert image_list([folder, pngs[0]]) == [*pngs, pngs[0]]  # a folder in a list too, in its place
    assert image_list(p for p in pngs[:2]) == pngs[:2]  # a generator, read once
    (tmp_path / "notes.txt").write_text("no images here")
    with pytest.raises(InputError, match=r"images: folder .* holds no image file"):
        image_list(tmp_path)
    with pytest.raises(InputError, match=r"images: expected a folder, an image file or a list of them, got 3"):
        image_list(3)  # type: ignore[arg-type]
    board = circcal.Board(8, 11, 15.0, 7.5)
    with pytest.raises(InputError, match=r"holds no image file"):
        circcal.calibrate(tmp_path, board)  # refused before any work
    with pytest.raises(InputError, match=r"camera 'right': folder .* holds no image file"):
        circcal.calibrate_rig({"left": folder, "right": tmp_path}, board)
    with pytest.raises(InputError, match=r"paths: a list of image files, one detection each, got the single path"):
        circcal.detect_files(str(folder), board)
