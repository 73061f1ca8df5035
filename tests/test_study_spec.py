"""Study specs (YAML -> StudySpec, every mistake an InputError naming the field), what a seed means for a rendered
scenario, and the run keys (content hashes: stable, distinct, independent of the study's name)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from circcal.errors import InputError
from circcal.fixtures.scenarios import SCENARIOS
from circcal.study import load_spec, parse_spec
from circcal.study.plan import plan
from circcal.study.seeded import seeded_scenario

REPO = Path(__file__).resolve().parents[1]

OBS = {"kind": "observations", "scenario": "paper", "noise_px": [0.01, 0.02], "seeds": 5, "calibrators": ["circcal"]}
IMG = {
    "kind": "images",
    "scenario": "paper",
    "variants": ["normal", "weak"],
    "seeds": {"start": 3, "count": 2},
    "calibrators": ["circcal", "opencv", {"name": "opencv", "observations": "circcal"}],
}


def spec(*cells, name="t"):
    return parse_spec({"name": name, "cells": list(cells)})


@pytest.mark.parametrize("path", sorted((REPO / "studies").glob("*.yaml")), ids=lambda p: p.stem)
def test_shipped_specs_parse(path):
    s = load_spec(path)
    assert s.name == path.stem and s.n_runs > 0 and s.source


def test_axes_and_counts():
    s = spec(OBS, IMG)
    obs, img = s.cells
    assert obs.variants == ("noise0.01px", "noise0.02px") and obs.seeds == (0, 1, 2, 3, 4)
    assert img.seeds == (3, 4) and img.vary == "noise" and img.lens_models == ("opencv5",)
    assert [c.label for c in img.calibrators] == ["circcal", "opencv", "opencv-on-circcal"]
    assert s.n_runs == 2 * 5 * 1 + 2 * 2 * 3
    assert sum(len(t.runs) for t in plan(s)) == s.n_runs
    every = spec({k: v for k, v in IMG.items() if k != "variants"}).cells[0]
    assert every.variants == tuple(SCENARIOS["paper"].variants)


@pytest.mark.parametrize(
    "bad,match",
    [
        ({**OBS, "seeds": 0}, r"cells\[0\].seeds: must be at least 1"),
        ({**OBS, "seeds": [1, 1]}, "listed twice"),
        ({**OBS, "seeds": {"count": 2, "stop": 3}}, "unknown key"),
        ({**OBS, "noise_px": [0.0]}, "noise_px"),
        ({**OBS, "noise_px": "x"}, "noise_px"),
        ({**OBS, "calibrators": ["nope"]}, "unknown calibrator 'nope'"),
        ({**OBS, "calibrators": ["circcal", "circcal"]}, "listed twice"),
        ({**OBS, "calibrators": [{"name": "opencv", "mode": "best"}]}, "mode"),
        ({**OBS, "calibrators": [{"name": "opencv", "observations": "circcal"}]}, "same points"),
        ({**OBS, "lens_models": ["fisheye"]}, "unknown lens model 'fisheye'"),
        ({**OBS, "variants": ["normal"]}, "only for images cells"),
        ({**OBS, "device": "tpu"}, "device"),
        ({**OBS, "batch": 0}, "batch"),
        ({**OBS, "geometry": {"views": 3}}, "a scenario or a geometry"),
        ({**IMG, "scenario": "nope"}, "unknown scenario 'nope'"),
        ({**IMG, "variants": ["dark"]}, "no variant 'dark'"),
        ({**IMG, "vary": "poses"}, "vary"),
        ({**IMG, "noise_px": [0.1]}, "only for observations cells"),
        ({**IMG, "kind": "video"}, "kind"),
        ({**IMG, "extra": 1}, "unknown key"),
        ({**IMG, "calibrators": [{"plugin": "no_such_module_xyz:fn"}]}, "cannot import"),
    ],
)
def test_bad_cells_are_input_errors_naming_the_field(bad, match):
    with pytest.raises(InputError, match=match):
        spec(bad)


def test_bad_files(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        load_spec(tmp_path / "missing.yaml")
    (tmp_path / "bad.yaml").write_text("cells: [")
    with pytest.raises(InputError, match="not valid YAML"):
        load_spec(tmp_path / "bad.yaml")
    (tmp_path / "empty.yaml").write_text(yaml.safe_dump({"cells": []}))
    with pytest.raises(InputError, match="empty.yaml: cells"):
        load_spec(tmp_path / "empty.yaml")
    with pytest.raises(InputError, match="name"):
        parse_spec({"name": "a/b", "cells": [OBS]})


def test_a_plugin_calibrator_loads_through_the_pytest_plugins_loader():
    s = spec({**OBS, "calibrators": [{"plugin": "mine=tests/conformance/example_calibrator.py:opencv_calibrate"}]})
    (cal,) = s.cells[0].calibrators
    assert cal.name == "mine" and cal.plugin.endswith("example_calibrator.py:opencv_calibrate")


def test_a_seed_changes_noise_or_scene_and_the_scenarios_own_seed_is_the_catalogue_fixture():
    base = SCENARIOS["paper"]
    own = seeded_scenario("paper", base.seed, "noise")
    assert own.key("normal") == base.key("normal") == seeded_scenario("paper", base.seed, "scene").key("normal")
    noise, scene = seeded_scenario("paper", 7, "noise"), seeded_scenario("paper", 7, "scene")
    assert len({noise.key("normal"), scene.key("normal"), base.key("normal")}) == 3
    same = [(r.tolist(), t.tolist()) for r, t in base.poses()]
    assert [(r.tolist(), t.tolist()) for r, t in noise.poses()] == same  # noise: the scenario's own poses
    assert [(r.tolist(), t.tolist()) for r, t in scene.poses()] != same  # scene: new poses too
    with pytest.raises(ValueError):
        seeded_scenario("paper", 1, "everything")


def test_run_keys_are_stable_distinct_and_independent_of_the_study_name():
    a, b = plan(spec(OBS, IMG, name="a")), plan(spec(OBS, IMG, name="b"))
    keys_a = [r.key for t in a for r in t.runs]
    assert keys_a == [r.key for t in b for r in t.runs]
    assert len(set(keys_a)) == len(keys_a)
    other = plan(spec({**OBS, "noise_px": [0.01, 0.03]}))
    assert {r.key for t in other for r in t.runs} & set(keys_a) == {r.key for t in a[:1] for r in t.runs}
    # an observations cell is cut into tasks of `batch` seeds, an images cell into one task per seed
    obs_tasks = plan(spec({**OBS, "batch": 2}))
    assert [len(t.runs) for t in obs_tasks] == [2, 2, 1, 2, 2, 1]
    img_tasks = plan(spec(IMG))
    assert [len(t.runs) for t in img_tasks] == [6, 6] and len({t.key for t in img_tasks}) == 2
