"""Which images of a rig show the same instant (circcal/rig/instants.py): the same file name, or, where no name is
shared, the same name between each camera's own prefix and suffix (OpenCV's stereo sample: left01.jpg,
right01.jpg; 0001_cam0.png, 0001_cam1.png; 0001.png, 0001.jpg)."""

from __future__ import annotations

import argparse
import shutil
import warnings

import numpy as np
import pytest

from circcal.commands.rig import _cameras
from circcal.errors import InputError
from circcal.fixtures.rig import rig_fixture_dir, rig_scenario
from circcal.rig import calibrate_rig
from circcal.rig.instants import PLAIN, camera_affixes, instant_of, rig_instants, unlinked
from circcal.rotation import rotation_angle_deg
from circcal.solver import CalibrationOptions


def _names(prefix: str, numbers) -> list[str]:
    return [f"{prefix}{k:02d}.png" for k in numbers]


def test_plain_names_come_first():
    # shared names link the cameras: nothing is stripped, even where every name has a prefix
    assert camera_affixes({"a": _names("img", range(1, 6)), "b": _names("img", range(3, 9))}) == {
        "a": PLAIN,
        "b": PLAIN,
    }


@pytest.mark.parametrize(
    ("left", "right", "expected", "shared"),
    [
        (_names("left", range(1, 13)), _names("right", range(1, 13)), (("left", ".png"), ("right", ".png")), 12),
        # 01..09: "right0" is cut back to "right"; 10, 20: their shared "0" is a digit, not part of the suffix
        (_names("left", (1, 10, 20)), _names("right", range(1, 10)), (("left", ".png"), ("right", ".png")), 1),
        ([f"cam0_{k:04d}.png" for k in range(5)], [f"cam1_{k:04d}.png" for k in range(5)],
         (("cam0_", ".png"), ("cam1_", ".png")), 5),
        ([f"{k:04d}_left.png" for k in range(5)], [f"{k:04d}_right.png" for k in range(5)],
         (("", "_left.png"), ("", "_right.png")), 5),
        ([f"{k:04d}.png" for k in range(5)], [f"{k:04d}.jpg" for k in range(3, 9)], (("", ".png"), ("", ".jpg")), 2),
        # zero padding differs: digits are read as numbers
        ([f"frame{k}.png" for k in range(1, 12)], [f"img{k:03d}.tif" for k in range(1, 12)],
         (("frame", ".png"), ("img", ".tif")), 11),
    ],
)  # fmt: skip
def test_each_cameras_prefix_and_suffix_around_the_digits_are_left_out(left, right, expected, shared):
    affix = camera_affixes({"l": left, "r": right})
    assert (affix["l"], affix["r"]) == expected
    keys = [{instant_of(p, affix[c]) for p in ps} for c, ps in (("l", left), ("r", right))]
    assert all(k.isdigit() for k in keys[0] | keys[1]) and len(keys[0] & keys[1]) == shared


def test_no_prefix_rule_where_it_would_not_link_either():
    # different numbers in each camera: neither rule links them, the names stay as they are (the command refuses)
    affix = camera_affixes({"l": _names("left", range(1, 5)), "r": _names("right", range(20, 25))})
    assert affix == {"l": PLAIN, "r": PLAIN}
    assert unlinked({"l": {"a", "b"}, "r": {"b"}, "s": {"z"}}) == ["s"]
    assert unlinked({"l": {"a"}, "r": {"b"}, "s": {"a", "b"}}) == []  # r reaches l through s


def test_a_folder_per_instant_names_the_instants(tmp_path):
    # shots/0001/left.png, shots/0001/right.png, ...: the file names repeat, the folders name the instants
    for k in range(1, 5):
        (tmp_path / f"{k:04d}").mkdir()
        for cam in ("left", "right"):
            (tmp_path / f"{k:04d}" / f"{cam}.png").write_bytes(b"")  # never read: the arguments are checked first
    found = rig_instants({c: sorted(tmp_path.glob(f"*/{c}.png")) for c in ("left", "right")})
    assert found.names["left"][0] == "0001/left.png" and found.affixes["left"] == ("", "/left.png")
    assert list(found.of["left"].values()) == list(found.of["right"].values()) == ["1", "2", "3", "4"]
    images = _cameras(_namespace(tmp_path, "*/left.png", "*/right.png"))
    assert [p.parent.name for p in images["right"]] == ["0001", "0002", "0003", "0004"]
    # one folder per camera with the same file names in sessions below it: the sessions keep them apart
    for cam in ("L", "R"):
        for sess in ("a", "b"):
            (tmp_path / cam / sess).mkdir(parents=True)
            (tmp_path / cam / sess / "01.png").write_bytes(b"")
    found = rig_instants({c: sorted((tmp_path / c).glob("*/*.png")) for c in ("L", "R")})
    assert not found.by_affix and set(found.of["L"].values()) == set(found.of["R"].values()) == {"a/01.png", "b/01.png"}
    # one camera flat, the other's images spread over folders: the paths link nothing, the file names do
    found = rig_instants({"l": ["L/001.png", "L/002.png"], "r": ["R/x/001.png", "R/y/002.png"]})
    assert list(found.of["r"].values()) == ["001.png", "002.png"] and not found.by_affix
    # two of one camera's images that show one instant under the rule that links the rig: refused, both named
    with pytest.raises(InputError, match=r"camera 'r': two images of instant '001.png' \(R/x/001.png, R/y/001.png\)"):
        rig_instants({"l": ["L/001.png", "L/002.png"], "r": ["R/x/001.png", "R/y/001.png"]})


def _namespace(tmp_path, left: str, right: str) -> argparse.Namespace:
    return argparse.Namespace(camera=[("left", str(tmp_path / left)), ("right", str(tmp_path / right))], intrinsics=[])


def test_the_command_says_when_it_matched_by_prefix(tmp_path, capsys):
    for name in _names("left", range(1, 4)) + _names("right", range(1, 4)):
        (tmp_path / name).write_bytes(b"")  # never read: the arguments are checked first
    images = _cameras(_namespace(tmp_path, "left*.png", "right*.png"))
    assert [p.name for p in images["right"]] == _names("right", range(1, 4))
    out = capsys.readouterr().out
    assert "own prefix and suffix are left out of its names (left: 'left*.png', right: 'right*.png'" in out
    assert "left01.png is instant '1'" in out
    for name in _names("right", range(7, 9)):  # other numbers: no rule links them
        (tmp_path / "other").mkdir(exist_ok=True)
        (tmp_path / "other" / name).write_bytes(b"")
    with pytest.raises(
        InputError, match=r"or the same name between each camera's own prefix and suffix: left01.png, right01.png"
    ):
        _cameras(_namespace(tmp_path, "left*.png", "other/right*.png"))


def test_a_rig_of_prefixed_names_calibrates_as_one_of_plain_names(tmp_path):
    # eight instants of the rendered `two` rig, renamed the way OpenCV's stereo sample names its pairs, in one folder
    sc = rig_scenario("two")
    folder = rig_fixture_dir("two")
    both = sorted(
        {p.name for p in (folder / "left").glob("*.png")} & {p.name for p in (folder / "right").glob("*.png")}
    )
    for k, name in enumerate(both[:8], start=1):
        shutil.copy(folder / "left" / name, tmp_path / f"left{k:02d}.png")
        shutil.copy(folder / "right" / name, tmp_path / f"right{k:02d}.png")
    # right's images as a generator (Path.glob, read once): the instants and the calibration both see them
    images = {"left": sorted(tmp_path.glob("left*.png")), "right": tmp_path.glob("right*.png")}
    opts = {"left": CalibrationOptions(), "right": CalibrationOptions(lens="rational")}
    with warnings.catch_warnings():  # eight views leave the rational camera's coefficients a long valley to walk
        warnings.simplefilter("ignore", RuntimeWarning)
        res = calibrate_rig(images, sc.board, opts, jobs=1)
    assert res.instants["left"] == res.instants["right"] == [str(k) for k in range(1, 9)]
    R, T = res.rig.pair(0, 1)
    Rt, Tt = sc.rig.pair(0, 1)
    assert rotation_angle_deg(R @ Rt.T) < 0.02  # measured 0.004 deg
    assert np.linalg.norm(T - Tt) < 0.1  # measured 0.025 mm
    assert res.images["right"]["3"] == str(tmp_path / "right03.png")  # each instant's image, for the outputs


def test_a_folder_per_instant_gets_its_rectified_pairs_and_report(tmp_path, capsys):
    # the outputs took each instant's pair by file name: with shots/<instant>/left.png they wrote no rectified
    # pair (and the report no rectified.png) while saying "wrote"; an unreadable image of one instant is left out
    # of them (it ended the command with an error after the work)
    from circcal.cli import main

    folder = rig_fixture_dir("two")
    both = sorted(
        {p.name for p in (folder / "left").glob("*.png")} & {p.name for p in (folder / "right").glob("*.png")}
    )
    for name in both[:8]:
        (tmp_path / "shots" / name[:-4]).mkdir(parents=True)
        for cam in ("left", "right"):
            shutil.copy(folder / cam / name, tmp_path / "shots" / name[:-4] / f"{cam}.png")
    broken = tmp_path / "shots" / both[2][:-4] / "right.png"
    broken.write_bytes(broken.read_bytes()[:2000])
    argv = ["calibrate-rig", "--camera", f"left={tmp_path}/shots/*/left.png", "--camera"]
    argv += [f"right={tmp_path}/shots/*/right.png", "--lens", "right=opencv5", "--grid", "8x11", "--pitch", "15mm"]
    argv += ["--out", str(tmp_path / "rig.json"), "--rectified", str(tmp_path / "rect"), "--report"]
    assert main([*argv, str(tmp_path / "rep"), "--no-progress", "--no-cross-validate"]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in (tmp_path / "rect").glob("*.png")) == sorted(
        f"{int(n[:-4])}.png" for n in both[:8] if n != both[2]
    )
    assert (tmp_path / "rep" / "rectified.png").is_file()
