"""CalibrationOptions: one frozen, checked object from the command line to the solver (issue 32)."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from circcal import cli
from circcal.board import Board
from circcal.errors import EXIT_BAD_INPUT, InputError
from circcal.fixtures.poses import sample_poses
from circcal.model import Camera, project
from circcal.solver import CalibrationOptions, calibrate
from circcal.solver.options import FLAG_HOLDS
from circcal.solver.outliers import OutlierRule

CAM = Camera(1280, 960, 1100.0, 1098.0, 650.0, 470.0, dist=(-0.2, 0.1, 0.001, -0.0005, 0.01))
SIZE = (CAM.width, CAM.height)


@pytest.fixture(scope="module")
def views():
    board = Board(7, 9, 10.0, 5.0)
    rng = np.random.default_rng(3)
    obj = [board.object_points()] * 10
    img = [
        project(obj[0], r, t, CAM) + rng.normal(0, 0.05, (len(obj[0]), 2)) for r, t in sample_poses(CAM, board, 10, 5)
    ]
    return obj, img


def test_holds_are_expanded_checked_and_ordered():
    o = CalibrationOptions(fixed=["k3", "tangential", "aspect_ratio", "cx", "k3"])
    assert o.fixed == ("aspect_ratio", "cx", "p1", "p2", "k3")
    assert CalibrationOptions(fixed="principal_point").fixed == ("cx", "cy")
    assert CalibrationOptions(lens="fisheye", fixed=("k4", "k1")).fixed == ("k1", "k4")
    assert o.holds("p2") and not o.holds("k1")
    assert hash(o) == hash(CalibrationOptions(fixed=("aspect_ratio", "cx", "p1", "p2", "k3")))


@pytest.mark.parametrize(
    "kw,words",
    [
        (dict(lens="fisheye", fixed=("tangential",)), "fixed: the fisheye lens model has no p1, p2"),
        (dict(fixed=("k9",)), "fixed: the opencv5 lens model has no k9"),
        (dict(fixed=("aspect_ratio", "fy")), "fixed: aspect_ratio"),
        (dict(fixed=3), "fixed must be parameter names"),
        (dict(fixed=(None,)), "fixed must be parameter names"),
        (dict(lens="pinhole"), "unknown lens model 'pinhole'"),
        (dict(solver="lm"), "solver must be one of schur, scipy"),
        (dict(max_iterations=0), "max_iterations"),
        (dict(max_iterations=True), "max_iterations"),
        (dict(board_gauge=(0, 1)), "board_gauge"),
        (dict(board_gauge=(0, 1, -2)), "board_gauge"),
        (dict(refine_board="yes"), "refine_board"),
        (dict(outlier_rule=5.0), "outlier_rule"),
    ],
)
def test_bad_options_are_one_line_input_errors(kw, words):
    with pytest.raises(InputError) as e:
        CalibrationOptions(**kw)
    assert words in str(e.value) and "\n" not in str(e.value)


def test_frozen_variants_are_checked_copies():
    base = CalibrationOptions(outlier_rule=OutlierRule())
    with pytest.raises(dataclasses.FrozenInstanceError):
        base.lens = "fisheye"  # type: ignore[misc]
    v = base.replace(refine_board=True)
    assert v.refine_board and not base.refine_board and v.outlier_rule is base.outlier_rule
    with pytest.raises(InputError, match="no p1, p2"):
        CalibrationOptions(fixed=("tangential",)).replace(lens="fisheye")


def test_flags_map_onto_holds():
    for flag, names in FLAG_HOLDS.items():
        assert CalibrationOptions.from_flags(**{flag: True}).fixed == tuple(
            n for n in ("aspect_ratio", "cx", "cy", "k2", "p1", "p2", "k3") if n in names
        )
    with pytest.raises(InputError, match=r"^--fix-tangential: the fisheye lens model has no p1, p2"):
        CalibrationOptions.from_flags(lens="fisheye", fix_tangential=True, spell=lambda f: "--" + f.replace("_", "-"))


def test_general_holds_in_the_solver(views):
    obj, img = views
    free = calibrate(obj, img, SIZE)
    k1 = calibrate(obj, img, SIZE, CalibrationOptions(fixed=("k1",)))
    assert k1.camera.dist[0] == 0.0 and k1.std["k1"] == 0.0 and k1.fixed == ("k1",)
    assert k1.sigma_px > 2 * free.sigma_px  # a real lens's k1 held at 0 is a worse fit
    cx = calibrate(obj, img, SIZE, CalibrationOptions(fixed=("cx",)))
    assert cx.camera.cx == (SIZE[0] - 1) / 2 and cx.std["cx"] == 0.0 and cx.std["cy"] > 0
    with pytest.raises(InputError, match="initial"):
        calibrate(obj, img, SIZE, CalibrationOptions(fixed=("fx",)))
    fx = calibrate(obj, img, SIZE, CalibrationOptions(fixed=("fx",)), initial=free.camera)
    assert fx.camera.fx == free.camera.fx and fx.std["fx"] == 0.0 and fx.std["fy"] > 0
    with pytest.raises(ValueError, match="lens"):
        calibrate(obj, img, SIZE, CalibrationOptions(lens="rational"), initial=free.camera)


def test_outlier_rule_through_the_options(views):
    obj, img = views
    bad = [p.copy() for p in img]
    bad[2][7] += 5.0
    res = calibrate(obj, bad, SIZE, CalibrationOptions(outlier_rule=OutlierRule()))
    assert [(r.view, r.point) for r in res.outliers.items] == [(2, 7)]
    assert calibrate(obj, bad, SIZE).outliers is None


def test_the_command_line_builds_one_options_object_first(tmp_path, capsys):
    from circcal.commands.args import calibration_options

    args = cli.build_parser().parse_args(
        [
            "calibrate",
            "a.png",
            "--grid",
            "4x5",
            "--pitch",
            "10mm",
            "--fix-k2",
            "--fix-k3",
            "--refine-board",
            "--outlier-k",
            "4",
        ]
    )
    o = calibration_options(args)
    assert o.fixed == ("k2", "k3") and o.refine_board and o.outlier_rule == OutlierRule(k=4.0)
    assert o.lens == "opencv5"
    # a hold the lens does not have is refused before any image is read (the images do not exist)
    missing = str(tmp_path / "none.png")
    code = cli.main(
        [
            "calibrate",
            missing,
            "--grid",
            "4x5",
            "--pitch",
            "10mm",
            "--lens",
            "fisheye",
            "--fix-tangential",
            "--out",
            str(tmp_path / "m.json"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code == EXIT_BAD_INPUT and "--fix-tangential: the fisheye lens model has no p1, p2" in err
    assert len(err.splitlines()) == 1
    code = cli.main(
        [
            "calibrate",
            missing,
            "--grid",
            "4x5",
            "--pitch",
            "10mm",
            "--no-outlier-rejection",
            "--outlier-k",
            "3",
            "--out",
            str(tmp_path / "m.json"),
        ]
    )
    assert code == EXIT_BAD_INPUT and "--outlier-k" in capsys.readouterr().err


def test_solver_and_outliers_import_no_cycle():
    """circcal.solver.outliers imports nothing of the solver that imports it (not even inside a function)."""
    src = Path(__import__("circcal.solver.outliers", fromlist=["x"]).__file__).read_text()
    names = set()
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    assert not {n for n in names if n.startswith("circcal.solver")}, names
