"""``--grid auto`` (issue 36): the grid, layout included, found from the images alone
(:mod:`circcal.detector.locate.infer`), on the real photograph sets and rendered symmetric, asymmetric and
partial-view sets; the flag that fixes a wrong ``--grid``; ``calibrate --grid auto --pitch`` end to end."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from circcal.cli import main
from circcal.commands.args import parse_grid
from circcal.detector.locate.infer import infer_grid, probe_grid_of, shape_of
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.truth import load_truth

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "realdata"
REGULAR = REAL / "boofcv_sony_hx5v_circle_regular_10x8"
ASYM = REAL / "boofcv_sony_hx5v_circle_asym_4x5"
needs_real = pytest.mark.skipif(not ASYM.is_dir() or not REGULAR.is_dir(), reason="../shared/data/realdata absent")


def test_parse_grid_auto():
    assert parse_grid("auto") == "auto" and parse_grid(" AUTO ") == "auto"
    assert parse_grid("8x10") == (8, 10)
    with pytest.raises(argparse.ArgumentTypeError):
        parse_grid("automatic")


def test_shape_of_layouts():
    sym = np.array([[i, j] for j in range(4) for i in range(6)])
    assert shape_of(sym) == (4, 6, "symmetric")
    # an asymmetric 5x4 grid, board frame (2j + i % 2, i), in patch coordinates (its diagonals)
    xy = np.array([[2 * j + i % 2, i] for i in range(5) for j in range(4)])
    ab = np.column_stack([(xy[:, 0] - xy[:, 1]) // 2, (xy[:, 0] + xy[:, 1]) // 2])
    assert shape_of(ab) == (5, 4, "asymmetric")
    assert shape_of(sym[1:])[2] is None  # one dot missing: a partial view


@needs_real
@pytest.mark.parametrize(
    "folder, grid", [(REGULAR, (8, 10, "symmetric")), (ASYM, (5, 4, "asymmetric"))], ids=["regular", "asym"]
)
def test_real_sets(folder, grid):
    rows, cols, layout, evidence = infer_grid(sorted(folder.glob("*.jpg")))
    assert (rows, cols, layout) == grid
    assert len(evidence) == len(list(folder.glob("*.jpg")))


@pytest.mark.parametrize(
    "scenario, variant", [("small-noisy", "noisy"), ("asymmetric", "noise"), ("partial", "out-of-frame")]
)
def test_rendered_sets(scenario, variant):
    folder = fixture_dir(scenario, variant)
    truth = load_truth(folder)
    rows, cols, layout, evidence = infer_grid([v.image for v in truth.views])
    assert (rows, cols, layout) == probe_grid_of(truth.board)
    if scenario == "partial":  # no view shows the whole board, yet the grid is not the partial views' smaller one
        assert not any(e.complete for e in evidence)


@needs_real
def test_wrong_flags_are_answered_with_the_flag(tmp_path, capsys):
    assert main(["detect", str(ASYM), "--grid", "5x4", "--json", str(tmp_path / "a.json"), "--quiet"]) == 1
    assert "an asymmetric grid: add --asymmetric" in capsys.readouterr().out
    argv = ["detect", str(ASYM), "--grid", "4x5", "--asymmetric", "--json", str(tmp_path / "b.json"), "--quiet"]
    assert main(argv) == 1
    assert "the grid is 5x4: --grid 5x4" in capsys.readouterr().out


@needs_real
def test_calibrate_grid_auto_end_to_end(tmp_path, capsys):
    out = tmp_path / "model.json"
    assert main(["calibrate", str(ASYM), "--grid", "auto", "--pitch", "30mm", "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "--grid auto: --grid 5x4 --asymmetric" in printed
    assert out.is_file()


def test_asymmetric_given_for_a_symmetric_grid_is_answered_with_the_flag():
    """`--grid RxC --asymmetric` on images of the symmetric RxC grid: the hint drops the flag (it named the grid the
    user had given)."""
    from dataclasses import replace

    from circcal.commands.args import grid_hint

    truth = load_truth(fixture_dir("small-noisy", "noisy"))
    assert truth.board.layout == "symmetric"
    hint = grid_hint([v.image for v in truth.views], replace(truth.board, layout="asymmetric"))
    assert hint.startswith("a symmetric grid: drop --asymmetric"), hint
