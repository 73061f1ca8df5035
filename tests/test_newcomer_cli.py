"""What a newcomer met first on the command line: `diff --help` showing "95%%", a diff that is NOT consistent
exiting 0 and naming its files in the reverse order, `--distance` refusing `2m`, `board --help` and `detect --help`
printing developer docstrings, and `detect` writing a made-up 10 mm pitch into detections.json."""

from __future__ import annotations

import argparse
import json
import re

import pytest

from circcal.cli import main
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.truth import load_truth
from circcal.formats import write_camera
from circcal.formats.boardfile import board_file_text
from circcal.model import Camera


def _help(command: str, capsys) -> str:
    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    return capsys.readouterr().out


def test_diff_help_says_95_percent_once(capsys):
    out = _help("diff", capsys)
    assert "95%" in out and "%%" not in out
    assert "1 NOT consistent" in out.replace("\n", " ")


@pytest.mark.parametrize(
    "command, developer",
    [
        ("board", ["one axes", "add_marker_arguments", "marker_args_board", "bbox_inches", "data limits"]),
        ("detect", ["board.to_dict", "(outputs)", '{"board"', "reason_code: null", "patternSize (C, R)"]),
    ],
)
def test_board_and_detect_help_speak_to_users(command, developer, capsys):
    out = _help(command, capsys)
    for text in developer:
        assert text not in out, text
    assert "examples:" in out and f"circcal {command} " in out.split("examples:")[1]
    assert "--board" in out.split("examples:")[1]
    assert "Exit status" in out


def test_distance_takes_a_length_with_its_unit_and_a_bare_number_as_mm():
    from circcal.commands.args import parse_distance_mm

    assert parse_distance_mm("2m") == 2000.0
    assert parse_distance_mm("1.5 cm") == 15.0
    assert parse_distance_mm("20in") == pytest.approx(508.0)
    assert parse_distance_mm("500") == 500.0  # what scripts gave before units were accepted
    for bad in ("0", "-1", "-1m", "nan", "inf", "2 furlongs", "m"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_distance_mm(bad)


def test_diff_distance_with_a_unit_on_the_command_line(tmp_path, capsys):
    cam = Camera(640, 480, 500.0, 500.0, 319.5, 239.5, [-0.1, 0.01, 0.0, 0.0, 0.0])
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    write_camera(a, cam)
    write_camera(b, Camera(640, 480, 501.0, 500.0, 319.5, 239.5, cam.dist))
    js = tmp_path / "d.json"
    assert main(["diff", str(a), str(b), "--distance", "2m", "--json", str(js)]) == 0  # no uncertainty: not judged
    assert json.loads(js.read_text())["distance_mm"] == 2000.0
    assert "at 2000 mm" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        main(["diff", str(a), str(b), "--distance", "0m"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--distance" in err and len(err.strip().splitlines()) <= 3  # argparse's usage + line


def _calibrate(scenario: str, variant: str, n: int, out, tmp_path) -> None:
    truth = load_truth(fixture_dir(scenario, variant))
    board = tmp_path / f"{scenario}.yaml"
    board.write_text(board_file_text(truth.board))
    images = [str(v.image) for v in truth.views[:n]]
    assert main(["calibrate", *images, "--board", str(board), "--no-progress", "--out", str(out)]) in (0, 1)
    assert out.exists()


def test_a_diff_that_is_not_consistent_exits_1_and_says_which_is_the_reference(tmp_path, capsys):
    """Two cameras of one image size (k1 -0.22 and -0.15), each with its uncertainty: NOT consistent, exit 1, the
    JSON written all the same; the first line names A (the reference) and B in the order given."""
    a, b = tmp_path / "a1.json", tmp_path / "a3.json"
    _calibrate("small-noisy", "noisy", 10, a, tmp_path)
    _calibrate("markers", "clean", 10, b, tmp_path)
    capsys.readouterr()
    js = tmp_path / "diff.json"
    assert main(["diff", str(a), str(b), "--json", str(js)]) == 1
    out = capsys.readouterr().out
    assert "NOT consistent" in out
    first = out.splitlines()[0]
    assert first.startswith(f"A {a} (reference), B {b}:"), first
    assert json.loads(js.read_text())["consistent"] is False
    assert main(["diff", str(a), str(a)]) == 0  # consistent with itself
    assert "within 2x over 100.0% of the image: consistent" in capsys.readouterr().out


def _small_noisy(n: int = 2):
    truth = load_truth(fixture_dir("small-noisy", "noisy"))
    return truth, [str(v.image) for v in truth.views[:n]]


def test_detect_without_pitch_writes_no_made_up_lengths(tmp_path, capsys):
    truth, images = _small_noisy()
    out = tmp_path / "d.json"
    assert main(["detect", *images, "--grid", "7x9", "--json", str(out), "--quiet"]) == 0
    board = json.loads(out.read_text())["board"]
    assert board["pitch_mm"] is None and board["diameter_mm"] is None and board["margin_mm"] is None
    assert (board["rows"], board["cols"], board["layout"]) == (7, 9, "symmetric")
    # given, the pitch (and what follows from it) is written as given
    assert main(["detect", *images, "--grid", "7x9", "--pitch", "1cm", "--json", str(out), "--quiet"]) == 0
    board = json.loads(out.read_text())["board"]
    assert board["pitch_mm"] == 10.0 and board["diameter_mm"] == 5.0 and board["margin_mm"] == 10.0


def test_detect_without_pitch_on_a_marker_board_leaves_the_marker_size_out(tmp_path):
    _, images = _small_noisy(1)
    out = tmp_path / "d.json"
    main(["detect", *images, "--grid", "7x9", "--markers", "pattern", "--json", str(out), "--quiet"])
    board = json.loads(out.read_text())["board"]
    assert board["pitch_mm"] is None and board["marker_diameter_mm"] is None and board["markers"]


@pytest.mark.parametrize("option", ["--diameter", "--marker-diameter"])
def test_detect_a_size_without_the_pitch_is_one_line_naming_both(option, tmp_path, capsys):
    _, images = _small_noisy(1)
    out = tmp_path / "d.json"
    extra = ["--markers", "pattern"] if option == "--marker-diameter" else []
    size = "8mm" if option == "--marker-diameter" else "4mm"  # sizes the board takes: only the pitch is missing
    assert main(["detect", *images, "--grid", "7x9", *extra, option, size, "--json", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and option in err and "--pitch" in err, err
    assert not out.exists()
    assert re.search(r"relative to", err)
