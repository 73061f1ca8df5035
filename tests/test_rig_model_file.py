"""A rig model file (``calibrate-rig --out rig.json``) read back: every damaged or hostile value is refused in one
line naming its field, before it reaches the math (a rotation vector of 1e308 made triangulate's eigen-solver fail
with a traceback; a negative or textual ``rms_px`` gave a traceback or negative sigmas)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from circcal.errors import InputError
from circcal.fixtures.rig import rig_scenario
from circcal.rig.model import RigModel


@pytest.fixture(scope="module")
def doc() -> dict:
    rig = rig_scenario("two").rig
    n = len(rig.state_vector())
    A = np.random.default_rng(0).normal(size=(n, n))
    return RigModel(rig.names, rig.cameras, rig.rvecs, rig.tvecs, A @ A.T * 1e-6, 0.05).to_dict()


def test_a_rig_file_reads_back_as_written(doc):
    rig = RigModel.from_dict(doc)
    assert rig.rms_px == 0.05 and np.array_equal(rig.covariance, np.asarray(doc["covariance"]))


def _spoil(doc: dict, path: tuple, value) -> dict:
    d = copy.deepcopy(doc)
    at = d
    for key in path[:-1]:
        at = at[key]
    at[path[-1]] = value
    return d


@pytest.mark.parametrize(
    "path, value, words",
    [
        (("rms_px",), "abc", "rms_px must be a finite number"),
        (("rms_px",), -1.0, "rms_px must be a finite number"),
        (("rms_px",), float("nan"), "rms_px must be a finite number"),
        (("rms_px",), 0.0, "rms_px must be a positive number"),
        (("version",), 99, "version 99"),
        (("cameras", 1, "rvec"), [1e308, 1e308, 0.0], "rvec components must be within"),
        (("cameras", 1, "tvec"), [1e300, 0.0, 0.0], "tvec's within"),
        (("cameras", 1, "camera", "fx"), 1e308, "camera fx must be a finite number in"),
        (("covariance", 0, 1), 1.0, "symmetric"),
        (("covariance", 0, 0), -1.0, "non-negative diagonal"),
    ],
)
def test_a_damaged_rig_file_is_refused_naming_the_field(doc, path, value, words):
    with pytest.raises(InputError, match=words):
        RigModel.from_dict(_spoil(doc, path, value))


def test_a_correlation_beyond_one_is_refused(doc):
    d = copy.deepcopy(doc)
    C = np.asarray(d["covariance"])
    C[0, 1] = C[1, 0] = 2 * np.sqrt(C[0, 0] * C[1, 1])
    d["covariance"] = C.tolist()
    with pytest.raises(InputError, match="correlation beyond"):
        RigModel.from_dict(d)


@pytest.mark.parametrize(
    "name, text, words",
    [
        ("p.csv", "u,v\n1,2\n3,\n", "line 3: one coordinate only"),
        ("p.csv", "id,u,v\na,1,2\nb,3,4\na,5,6\n", "line 4: point id 'a' given twice \\(first on line 2\\)"),
        ("p.json", "[[1, 2], [3, null]]", "point 1: one coordinate only"),
        ("p.json", "[[1, 2], [1e308, 1e308]]", "point 1 must be a pixel within 1e\\+07 px"),
        ("p.csv", "1,2\n1e308,4\n", "line 2: a pixel within 1e\\+07 px"),
        ("p.csv", "1,2\ninf,4\n", "line 2: a pixel within"),
    ],
)
def test_a_points_file_with_half_a_point_or_an_id_twice_is_refused_by_line(tmp_path, name, text, words):
    from circcal.commands.triangulate import read_points

    (tmp_path / name).write_text(text)
    with pytest.raises(InputError, match=words):
        read_points(tmp_path / name)


def test_a_points_file_with_unseen_points_reads(tmp_path):
    from circcal.commands.triangulate import read_points

    (tmp_path / "p.csv").write_text("id,u,v\na,1,2\nb,,\nc,nan,nan\n")
    ids, px = read_points(tmp_path / "p.csv")
    assert ids == ["a", "b", "c"] and px[0] == (1.0, 2.0) and all(np.isnan(px[k]).all() for k in (1, 2))
