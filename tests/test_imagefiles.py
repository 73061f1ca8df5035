"""Image inputs (circcal/imagefiles.py): a folder for its images, a quoted glob for its matches, and no input at all
refused in one line (found by a newcomer test: a quoted glob and a missing path both gave "the board was found in 0
of 1 images" and exit 1, with a lens hint)."""

from __future__ import annotations

from pathlib import Path

import pytest

from circcal.cli import main
from circcal.errors import InputError
from circcal.imagefiles import expand_images, require_existing


def _touch(folder: Path, *names: str) -> list[Path]:
    out = []
    for n in names:
        (folder / n).write_bytes(b"x")
        out.append(folder / n)
    return out


def test_a_pattern_the_shell_did_not_expand_is_expanded_sorted(tmp_path):
    b, a, _ = _touch(tmp_path, "b.png", "a.png", "notes.txt")
    assert expand_images([tmp_path / "*.png"]) == [a, b]
    assert expand_images([tmp_path / "*"]) == [a, b]  # image files only, as a folder gives
    with pytest.raises(InputError, match=r"the pattern .*\*\.jpg matches no image file"):
        expand_images([tmp_path / "*.jpg"])


def test_nothing_that_exists_is_refused_and_one_missing_file_among_others_is_kept(tmp_path):
    (a,) = _touch(tmp_path, "a.png")
    with pytest.raises(InputError, match=r"images: no such file or folder: .*nope\.png \(nor 1 more given\)"):
        require_existing(expand_images([tmp_path / "nope.png", tmp_path / "nope2.png"]))
    # among files that exist, a missing one stays: the detector reports it as an image left out (issue 31)
    assert expand_images([a, tmp_path / "missing.png"]) == [a, tmp_path / "missing.png"]
    require_existing([a, tmp_path / "missing.png"])


@pytest.mark.parametrize("command", ["calibrate", "detect"])
def test_the_commands_refuse_a_path_that_is_not_there_before_any_work(tmp_path, capsys, command):
    out = ["--out", str(tmp_path / "m.json")] if command == "calibrate" else ["--json", str(tmp_path / "d.json")]
    code = main([command, str(tmp_path / "nowhere" / "*.png"), "--grid", "4x5", "--pitch", "10mm", *out])
    assert code == 2
    assert "matches no image file" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # nothing written
    # a mistyped path: refused, not "the board was found in 0 of 1 images"
    assert main([command, str(tmp_path / "nope.png"), "--grid", "4x5", "--pitch", "10mm", *out]) == 2
    assert "images: no such file or folder" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
