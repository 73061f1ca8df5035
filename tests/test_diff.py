"""`circcal diff A B`: the projection difference between two models in any format, the implied transformation fitted
over a focus region, RMS / p95 / max / centre, a heatmap, and the difference in units of the combined uncertainty
where both files carry one; bad input (an unreadable file, two image sizes) is a clear error that writes nothing."""

from __future__ import annotations

import json

import numpy as np
import pytest

from circcal.analysis import model_diff
from circcal.cli import main
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.truth import load_truth
from circcal.formats import write_camera
from circcal.model import Camera


@pytest.fixture(scope="module")
def halves(tmp_path_factory):
    """Two model.json files from disjoint halves of `wide`-clean (even and odd views), written by the CLI."""
    t = load_truth(fixture_dir("wide", "clean"))
    d = tmp_path_factory.mktemp("halves")
    out = []
    for k in (0, 1):
        path = d / f"half{k}.json"
        assert (
            main(
                [
                    "calibrate",
                    *[str(v.image) for v in t.views[k::2]],
                    "--grid",
                    "6x8",
                    "--pitch",
                    "25mm",
                    "--diameter",
                    "12mm",
                    "--no-progress",
                    "--out",
                    str(path),
                ]
            )
            == 0
        )
        out.append(path)
    return t, out


def test_diff_of_two_halves_with_their_uncertainty(halves, tmp_path, capsys):
    t, (a, b) = halves
    heat, js = tmp_path / "diff.png", tmp_path / "diff.json"
    assert main(["diff", str(a), str(b), "--heatmap", str(heat), "--json", str(js)]) == 0
    text = capsys.readouterr().out
    assert "uncertainty of A: circcal's, from the 6 views' observations" in text
    assert "within 2x over" in text and "consistent" in text
    doc = json.loads(js.read_text())
    assert doc["consistent"] is True and doc["share_within"] >= 0.95
    assert 0 < doc["rms_px"] <= doc["p95_px"] * 1.5 and doc["p95_px"] <= doc["max_px"]
    assert heat.stat().st_size > 10_000
    # the same numbers as the library's
    from circcal.formats import read_camera

    d = model_diff(read_camera(a), read_camera(b))
    assert doc["rms_px"] == pytest.approx(d.rms_px, rel=1e-12)


def test_a_model_against_itself_and_against_a_rotation(tmp_path, capsys):
    cam = Camera(1280, 960, 1000.0, 998.0, 641.5, 478.3, [-0.3, 0.1, 0.0006, -0.0004, -0.01])
    # the same lens looking 0.2 degrees to the side: principal point moved by f tan(0.2 deg) ~ 3.5 px
    moved = Camera(1280, 960, 1000.0, 998.0, 641.5 + 1000.0 * np.tan(np.radians(0.2)), 478.3, cam.dist)
    pa, pb = tmp_path / "a.yaml", tmp_path / "b.cameramodel"
    write_camera(pa, cam)
    write_camera(pb, moved)
    assert main(["diff", str(pa), str(pa), "--json", str(tmp_path / "same.json")]) == 0
    assert json.loads((tmp_path / "same.json").read_text())["max_px"] < 1e-9
    assert main(["diff", str(pa), str(pb), "--json", str(tmp_path / "fit.json")]) == 0
    assert main(["diff", str(pa), str(pb), "--radius", "0", "--json", str(tmp_path / "raw.json")]) == 0
    fit = json.loads((tmp_path / "fit.json").read_text())
    raw = json.loads((tmp_path / "raw.json").read_text())
    assert raw["centre_px"] == pytest.approx(1000.0 * np.tan(np.radians(0.2)), rel=1e-6)
    assert fit["rms_px"] < 0.2 * raw["rms_px"]  # the implied rotation takes most of it
    assert fit["share_within"] is None  # no uncertainty in these files
    out = capsys.readouterr().out
    assert "uncertainty of A: none" in out
    # a focus region: the fit is made near the centre, where the difference is then smallest
    assert main(["diff", str(pa), str(pb), "--radius", "200", "--json", str(tmp_path / "focus.json")]) == 0
    focus = json.loads((tmp_path / "focus.json").read_text())
    assert focus["focus_radius_px"] == 200 and focus["centre_px"] <= fit["centre_px"] + 1e-9


def test_bad_input_is_a_clear_error_and_writes_nothing(tmp_path, capsys):
    a = tmp_path / "a.json"
    write_camera(a, Camera(640, 480, 500.0, 500.0, 319.5, 239.5))
    b = tmp_path / "b.json"
    write_camera(b, Camera(1280, 960, 1000.0, 1000.0, 639.5, 479.5))
    heat, js = tmp_path / "h.png", tmp_path / "d.json"
    assert main(["diff", str(a), str(b), "--heatmap", str(heat), "--json", str(js)]) == 2
    err = capsys.readouterr().err
    assert "640x480" in err and "1280x960" in err and "one imager" in err
    bad = tmp_path / "broken.cameramodel"
    bad.write_text("{ 'lensmodel': 'LENSMODEL_OPENCV5', 'intrinsics': [1, 2,")
    assert main(["diff", str(a), str(bad), "--heatmap", str(heat), "--json", str(js)]) == 2
    assert "broken.cameramodel" in capsys.readouterr().err
    assert main(["diff", str(a), str(tmp_path / "missing.json")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert not heat.exists() and not js.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.json", "broken.cameramodel"]


def test_a_stated_uncertainty_is_raised_to_the_noise_floor_only_below_it():
    from circcal.analysis.diff import NOISE_FLOOR_PX, noise_floor_factor

    assert noise_floor_factor(NOISE_FLOOR_PX / 4) == pytest.approx(4.0)  # a clean render's 0.0025 px
    assert noise_floor_factor(NOISE_FLOOR_PX) == 1.0
    assert noise_floor_factor(0.3) == 1.0  # a photograph's noise: unchanged
    assert noise_floor_factor(float("nan")) == 1.0 and noise_floor_factor(0.0) == 1.0
