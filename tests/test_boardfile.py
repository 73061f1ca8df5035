"""Issue 34: board description files (``--board FILE``): circcal's form (YAML or JSON), ROS-Industrial's target YAML,
Kalibr's circle-grid target YAML; every bad field refused in one line naming the file and the field; ``--board``
replaces the grid options on every command; ``circcal board`` writes the description beside the print."""

from __future__ import annotations

import json
import math

import pytest

from circcal.board import Board
from circcal.cli import main
from circcal.commands.board import geometry_text
from circcal.errors import InputError
from circcal.formats.boardfile import board_file_text, read_board_file

BOOFCV = """# Serialized boofcv.alg.fiducial.calib.ConfigCalibrationTarget
BoofCV.GIT_SHA: a9ab9041d1703a9c09c31999043382e870554729
boofcv.alg.fiducial.calib.ConfigCalibrationTarget:
  grid:
    numRows: 8
    shapeDistance: 2.5
    shapeSize: 1.5
    numCols: 10
  type: CIRCLE_GRID
BoofCV.Version: 0.39-SNAPSHOT
"""

CIRCCAL = """rows: 8
cols: 11
layout: symmetric        # or asymmetric
pitch_mm: 20
diameter_mm: 8
markers:
  - {row: 0, col: 0, diameter_mm: 16}
  - {row: 5, col: 7, diameter_mm: 16}
"""


def write(tmp_path, text, name="board.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_circcal_form_markers_by_row_and_col(tmp_path):
    b = read_board_file(write(tmp_path, CIRCCAL))
    assert (b.rows, b.cols, b.layout, b.pitch_mm, b.diameter_mm) == (8, 11, "symmetric", 20.0, 8.0)
    assert b.markers == (0, 5 * 11 + 7) and b.marker_diameter_mm == 16.0
    # point (row, col) is at (col * pitch, row * pitch)
    assert b.object_points()[5 * 11 + 7].tolist() == [7 * 20.0, 5 * 20.0, 0.0]


def test_json_and_yaml_read_alike_and_the_written_text_round_trips(tmp_path):
    d = {
        "rows": 5,
        "cols": 4,
        "layout": "asymmetric",
        "pitch_mm": 12.5,
        "margin_mm": 7,
        "markers": [{"row": 4, "col": 3, "diameter_mm": 11}],
    }
    b = read_board_file(write(tmp_path, json.dumps(d), "b.json"))
    assert b.layout == "asymmetric" and b.markers == (19,) and b.margin_mm == 7.0
    assert b.diameter_mm == pytest.approx(0.5 * 12.5 * math.sqrt(2))  # the --diameter default
    again = read_board_file(write(tmp_path, board_file_text(b), "again.yaml"))
    assert again == b
    odd = Board(3, 7, 1.0 / 3.0, 0.1, markers=(0, 20), marker_diameter_mm=0.2)
    assert read_board_file(write(tmp_path, board_file_text(odd), "odd.yaml")) == odd  # floats exact


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("rows: 8\ncols: 11\npitch_mm: 20\ncolour: red\n", "unknown field 'colour'"),
        ("rows: 8\ncols: 11\n", "'pitch_mm' is missing"),
        ("rows: 8.5\ncols: 11\npitch_mm: 20\n", "rows must be an integer"),
        ("rows: 8\ncols: 11\npitch_mm: -2\n", "pitch_mm must be a finite number"),
        ("rows: 8\ncols: 11\npitch_mm: 20\nlayout: hexagonal\n", "layout must be symmetric or asymmetric"),
        ("rows: 8\ncols: 11\npitch_mm: 20\ndiameter_mm: 25\n", "diameter_mm: dot diameter 25"),
        ("rows: 8\ncols: 11\npitch_mm: 20\nmarkers:\n  - {row: 8, col: 0, diameter_mm: 16}\n", "markers[0].row"),
        ("rows: 8\ncols: 11\npitch_mm: 20\nmarkers:\n  - {row: 1, col: 0}\n", "markers[0].diameter_mm is missing"),
        (
            "rows: 8\ncols: 11\npitch_mm: 20\nmarkers:\n  - {row: 1, col: 0, diameter_mm: 16}\n"
            "  - {row: 1, col: 0, diameter_mm: 16}\n",
            "markers[1] repeats markers[0]",
        ),
        (
            "rows: 8\ncols: 11\npitch_mm: 20\nmarkers:\n  - {row: 1, col: 0, diameter_mm: 16}\n"
            "  - {row: 4, col: 4, diameter_mm: 14}\n",
            "one marker diameter",
        ),
        ("rows: 8\nrows: 9\ncols: 11\npitch_mm: 20\n", "duplicate key 'rows'"),
        ("a: &x [1]\nb: *x\n", "anchor or alias"),
        ("- 1\n- 2\n", "expected a mapping"),
        ("rows: [8\n", "not valid YAML"),
        ('{"rows": 8, "rows": 9}', "duplicate key 'rows'"),
        ("target_type: 'aprilgrid'\ntagCols: 6\n", "target_type 'aprilgrid'"),
        ("target_type: circlegrid\ntargetRows: 7\ntargetCols: 6\n", "'spacingMeters' is missing"),
        (
            "target_type: circlegrid\ntargetRows: 7\ntargetCols: 6\nspacingMeters: 0.02\nasymmetricGrid: 'no'\n",
            "asymmetricGrid must be true or false",
        ),
        ("static_targets:\n- {target_name: cb, target_type: 0, target_rows: 5, target_cols: 6}\n", "no circle-grid"),
        (
            "static_targets:\n- {target_name: g, target_type: 1, target_rows: 5, target_cols: 6, circle_dia: 0.01}\n",
            "spacing is missing",
        ),
        ("target_finder: {type: CharucoGridTargetFinder, rows: 5, cols: 7}\n", "ModifiedCircleGridTargetFinder only"),
        (BOOFCV.replace("CIRCLE_GRID", "CIRCLE_HEXAGONAL"), "hexagonal grid (rows spacing * sin 60 apart)"),
        (BOOFCV.replace("CIRCLE_GRID", "CHESSBOARD"), "type 'CHESSBOARD': BoofCV's circle grids only"),
        (BOOFCV.replace("    numCols: 10\n", ""), "ConfigCalibrationTarget.grid.numCols is missing"),
        (BOOFCV.replace("shapeDistance: 2.5", "shapeDistance: -1"), "grid.shapeDistance must be a finite number"),
        (BOOFCV.replace("shapeSize: 1.5", "shapeSize: 3"), "ConfigCalibrationTarget.grid"),
    ],
)
def test_a_bad_field_is_refused_in_one_line_naming_the_file_and_the_field(tmp_path, text, words):
    p = write(tmp_path, text)
    with pytest.raises(InputError) as e:
        read_board_file(p)
    msg = str(e.value)
    assert msg.startswith(f"board file {p}: ") and words in msg and "\n" not in msg


def test_missing_or_oversized_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_board_file(tmp_path / "nope.yaml")


def test_boofcv_target_config_read_with_its_unit_stated(tmp_path):
    # the file BoofCV writes for its circle-grid target (../shared/data/realdata/boofcv_sony_hx5v_circle_regular_10x8)
    with pytest.warns(RuntimeWarning, match="BoofCV's target file states no unit: its lengths are read as mm"):
        b = read_board_file(write(tmp_path, BOOFCV))
    assert (b.rows, b.cols, b.layout, b.pitch_mm, b.diameter_mm, b.markers) == (8, 10, "symmetric", 2.5, 1.5, ())


def test_kalibr_circlegrid_in_metres(tmp_path):
    text = "target_type: 'circlegrid'\ntargetCols: 6\ntargetRows: 7\nspacingMeters: 0.02\nasymmetricGrid: False\n"
    b = read_board_file(write(tmp_path, text))
    assert (b.rows, b.cols, b.layout, b.pitch_mm, b.diameter_mm, b.markers) == (7, 6, "symmetric", 20.0, 10.0, ())
    b = read_board_file(write(tmp_path, text.replace("False", "True")))
    assert b.layout == "asymmetric" and b.pitch_mm == 20.0  # Kalibr's (2c + r % 2) s: OpenCV's squareSize


def test_ros_industrial_targets_modified_circle_grid(tmp_path):
    points = "\n".join(
        f"      - pnt: [{c * 0.02:.4f}, {(9 - r) * 0.02:.4f}, 0.0]" for r in range(10) for c in range(10)
    )
    text = (
        "---\n\nstatic_targets:\n-\n     target_name: modified_circle_10x10\n     target_type: 2\n"
        "     circle_dia:  0.0125\n     target_frame: target_frame\n     transform_interface: ros_lti\n"
        f"     target_rows: 10\n     target_cols: 10\n     num_points: 100\n     points:\n{points}\n"
    )
    b = read_board_file(write(tmp_path, text))  # spacing from the points
    assert (b.rows, b.cols, b.pitch_mm, b.diameter_mm) == (10, 10, pytest.approx(20.0), 12.5)
    # the big dot at the bottom-left origin: 2x would leave 1.25 mm to its neighbours, so 1.5x
    assert b.markers == (90,) and b.marker_diameter_mm == 18.75
    plain = text.replace("target_type: 2", "target_type: 1").replace("     points:", "     spacing: 0.02\n     pts:")
    b = read_board_file(write(tmp_path, plain.split("     pts:")[0]))
    assert b.markers == () and b.pitch_mm == 20.0
    bad = text.replace("[0.0200, 0.1800", "[0.0270, 0.1800")
    with pytest.raises(InputError, match=r"static_targets\[0\]\.points: the points are not"):
        read_board_file(write(tmp_path, bad))


def test_ros_industrial_target_finder_block(tmp_path):
    text = "target_finder:\n  type: ModifiedCircleGridTargetFinder\n  rows: 10\n  cols: 12\n  spacing: 0.0254\n"
    b = read_board_file(write(tmp_path, text))
    assert (b.rows, b.cols, b.pitch_mm) == (10, 12, pytest.approx(25.4))
    assert b.markers == (9 * 12,) and b.marker_scale == 2.0


def test_board_option_replaces_the_grid_options_and_refuses_both(tmp_path, capsys):
    f = write(tmp_path, CIRCCAL)
    img = tmp_path / "x.png"
    img.write_bytes(b"")
    for extra in (["--grid", "8x11"], ["--pitch", "20mm"], ["--asymmetric"], ["--markers", "origin"]):
        assert main(["detect", str(img), "--board", str(f), *extra, "--json", str(tmp_path / "d.json")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--board" in err[0] and extra[0] in err[0] and "both given" in err[0]
    assert main(["detect", str(img), "--json", str(tmp_path / "d.json")]) == 2
    assert "--board FILE" in capsys.readouterr().err
    assert main(["calibrate", str(img), "--grid", "8x11", "--out", str(tmp_path / "m.json")]) == 2
    assert "--pitch" in capsys.readouterr().err
    bad = write(tmp_path, "rows: 8\ncols: 11\npitch_mm: 20\nmarkers: 3\n", "bad.yaml")
    assert main(["calibrate", str(img), "--board", str(bad), "--out", str(tmp_path / "m.json")]) == 2
    assert f"board file {bad}: markers must be a list" in capsys.readouterr().err


def test_board_command_writes_the_description_beside_the_print(tmp_path, capsys):
    out = tmp_path / "print" / "target.svg"
    out.parent.mkdir()
    args = ["board", "--grid", "6x8", "--pitch", "15mm", "--diameter", "6mm", "--markers", "origin"]
    assert main([*args, "--out", str(out)]) == 0
    described = out.with_suffix(".yaml")
    assert described.is_file() and out.is_file()
    b = read_board_file(described)
    assert (b.rows, b.cols, b.pitch_mm, b.diameter_mm, b.markers) == (6, 8, 15.0, 6.0, (40,))
    lines = geometry_text(b, "origin", described.name)  # the calibrate line printed under the board names the file
    assert "circcal calibrate IMAGES --board target.yaml" in lines
    # a board file in, the print and (another) description out; the same file is not rewritten
    f = write(tmp_path, CIRCCAL)
    assert main(["board", "--board", str(f), "--paper", "a3", "--out", str(tmp_path / "b2.pdf")]) == 0
    assert read_board_file(tmp_path / "b2.yaml") == read_board_file(f)
    before = f.read_text()
    assert main(["board", "--board", str(f), "--paper", "a3", "--out", str(tmp_path / "board.pdf")]) == 0
    assert f.read_text() == before and (tmp_path / "board.pdf").is_file()


def test_the_description_beside_the_print_never_replaces_a_users_file(tmp_path, capsys):
    """target.yaml beside --out target.svg is written by circcal, not named by the user: where a file circcal did not
    write stands there, nothing is written and the message says why; circcal's own earlier description is replaced."""
    out = tmp_path / "target.svg"
    mine = tmp_path / "target.yaml"
    mine.write_text("my notes\n")
    args = ["board", "--grid", "6x8", "--pitch", "15mm", "--diameter", "6mm", "--out", str(out)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "would replace a file circcal did not write" in err and str(mine) in err and "\n" not in err.strip()
    assert mine.read_text() == "my notes\n" and not out.exists()
    mine.unlink()
    assert main(args) == 0 and read_board_file(mine).rows == 6
    assert main([*args[:2], "7x8", *args[3:]]) == 0 and read_board_file(mine).rows == 7  # its own: replaced
