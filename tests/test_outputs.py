"""Outputs never destroy what circcal did not write (issue 31, cases 1, 2, 7 and 9): :mod:`circcal.outputs` and the
commands that plan their outputs through it. Every refusal happens before the work: the tests make the work itself
fail loudly if it is reached."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from circcal.commit import MARKER, RECORD, recover, sha256_file
from circcal.errors import InputError
from circcal.outputs import Outputs, check_folder_output


def _png(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.full((48, 64), 200, np.uint8))
    return path


@pytest.fixture
def no_work(monkeypatch):
    """Detection and calibration fail the test if reached: the refusal must come first."""
    # imported before anything is patched: a module first imported under the patch would keep the patched function
    # for good (analysis.calibration binds calibrate_images at import; monkeypatch would then "restore" the patch)
    import circcal.analysis.calibration as calibration
    import circcal.detector.files as files
    import circcal.pipeline as pipeline

    def reached(*a, **k):
        raise AssertionError("the work started before the outputs were checked")

    monkeypatch.setattr(pipeline, "calibrate_images", reached)
    monkeypatch.setattr(calibration, "calibrate_images", reached)
    monkeypatch.setattr(files, "detect_files", reached)
    import circcal.detector as det

    monkeypatch.setattr(det, "detect_files", reached)


def _cli(args, capsys):
    from circcal.cli import main

    code = main([str(a) for a in args])
    return code, capsys.readouterr().err


CAL = ["--grid", "7x7", "--pitch", "10mm", "--no-progress"]


def test_report_into_a_folder_with_a_users_file_is_refused(tmp_path, capsys, no_work, monkeypatch):
    """Case 1: `--report docs` where docs/ holds thesis.txt: exit 2 naming the folder, thesis.txt intact."""
    monkeypatch.chdir(tmp_path)
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "thesis.txt").write_text("x\n")
    imgs = [_png(tmp_path / "P" / f"v{i}.png") for i in range(3)]
    code, err = _cli(["calibrate", *imgs, *CAL, "--report", "docs", "--out", "m.json"], capsys)
    assert code == 2 and "--report docs" in err and "thesis.txt" in err and err.count("\n") == 1
    assert (docs / "thesis.txt").read_text() == "x\n" and not (tmp_path / "m.json").exists()


def test_report_into_the_photos_folder_is_refused(tmp_path, capsys, no_work, monkeypatch):
    """Case 1: `--report photos` where photos/ holds the inputs: refused, every photograph kept."""
    monkeypatch.chdir(tmp_path)
    imgs = [_png(tmp_path / "photos" / f"v{i}.png") for i in range(3)]
    before = {p: p.read_bytes() for p in imgs}
    code, err = _cli(["calibrate", *imgs, *CAL, "--report", "photos", "--out", "m.json"], capsys)
    assert code == 2 and "photos" in err and "input" in err
    assert {p: p.read_bytes() for p in imgs} == before


def test_validate_report_into_a_foreign_folder_is_refused(tmp_path, capsys, monkeypatch):
    import circcal.commands.validate as val

    monkeypatch.setattr(val, "_run", lambda *a, **k: (_ for _ in ()).throw(AssertionError("work reached")))
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "keep.md").write_text("mine")
    code, err = _cli(["validate", "--report", tmp_path / "notes", "--no-progress"], capsys)
    assert code == 2 and "keep.md" in err and (tmp_path / "notes" / "keep.md").read_text() == "mine"


def test_report_dot_is_refused(tmp_path, capsys, no_work, monkeypatch):
    """Case 9: `--report .` (even an empty working folder: swapping it would pull the folder from under the
    shell) is exit 2 before the work."""
    empty = tmp_path / "empty"
    empty.mkdir()
    img = _png(tmp_path / "v.png")
    monkeypatch.chdir(empty)
    code, err = _cli(["calibrate", img, img, img, *CAL, "--report", ".", "--out", tmp_path / "m.json"], capsys)
    assert code == 2 and "working folder" in err


def test_an_output_that_is_an_input_is_refused(tmp_path, capsys, no_work):
    """Case 2: `detect photos/*.png --json photos/view_13.png`: exit 2, the photograph unchanged; the same through
    a hard link."""
    imgs = [_png(tmp_path / "photos" / f"view_{i}.png") for i in range(3)]
    before = imgs[2].read_bytes()
    code, err = _cli(["detect", *imgs, "--grid", "7x7", "--json", imgs[2]], capsys)
    assert code == 2 and "input" in err and imgs[2].read_bytes() == before
    os.link(imgs[1], tmp_path / "alias.png")
    code, err = _cli(["detect", *imgs, "--grid", "7x7", "--json", tmp_path / "alias.png"], capsys)
    assert code == 2 and "input" in err and imgs[1].read_bytes() == (tmp_path / "alias.png").read_bytes()


@pytest.mark.parametrize("device", ["/dev/null", "/dev/full"])
def test_a_device_is_never_an_output(tmp_path, capsys, no_work, device):
    """Case 2: `--json /dev/full` (as root) replaced the device node by a regular file."""
    if not Path(device).exists():
        pytest.skip(f"{device} does not exist here")
    mode = os.stat(device).st_mode
    img = _png(tmp_path / "v.png")
    code, err = _cli(["detect", img, "--grid", "7x7", "--json", device], capsys)
    assert code == 2 and "device" in err and os.stat(device).st_mode == mode


def test_a_fifo_and_a_folder_are_not_file_outputs(tmp_path, capsys, no_work):
    img = _png(tmp_path / "v.png")
    os.mkfifo(tmp_path / "fifo")
    code, err = _cli(["detect", img, "--grid", "7x7", "--json", tmp_path / "fifo"], capsys)
    assert code == 2 and "fifo" in err
    (tmp_path / "d").mkdir()
    code, err = _cli(["convert", tmp_path / "nothere.json", tmp_path / "d", "--to", "json"], capsys)
    assert code == 2 and "folder" in err


def test_a_symlinked_output_is_written_through(tmp_path, capsys):
    """Case 2: an output path that is a symlink: the link stays, its target gets the new content."""
    from circcal.formats import write_camera
    from circcal.model import Camera

    src = tmp_path / "in.json"
    write_camera(
        src,
        Camera.from_dict(
            {"width": 640, "height": 480, "fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0, "dist": [0.0] * 5}
        ),
    )
    target = tmp_path / "real" / "cam.yaml"
    target.parent.mkdir()
    target.write_text("")  # an empty file may be replaced (a script's mktemp); a user's file may not (below)
    link = tmp_path / "cam.yaml"
    link.symlink_to(target)
    code, err = _cli(["convert", src, link], capsys)
    assert code == 0, err
    assert link.is_symlink() and "opencv-matrix" in target.read_text()
    # recorded beside the target: the next run may replace it
    assert json.loads((target.parent / RECORD).read_text())["files"] == {"cam.yaml": sha256_file(target)}
    code, err = _cli(["convert", src, link], capsys)
    assert code == 0, err


def test_a_file_output_replaces_only_what_circcal_wrote_unchanged(tmp_path, capsys):
    from circcal.formats import write_camera
    from circcal.model import Camera

    src = tmp_path / "in.json"
    cam = {"width": 640, "height": 480, "fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0, "dist": [0.0] * 5}
    write_camera(src, Camera.from_dict(cam))
    mine = tmp_path / "notes.yaml"
    mine.write_bytes(b"my own notes\n")
    code, err = _cli(["convert", src, mine], capsys)
    assert code == 2 and err.count("\n") == 1 and "circcal did not write" in err and "notes.yaml" in err
    assert mine.read_bytes() == b"my own notes\n" and not (tmp_path / RECORD).exists()
    out = tmp_path / "cam.yaml"
    assert _cli(["convert", src, out], capsys)[0] == 0
    first = out.read_bytes()
    assert _cli(["convert", src, out], capsys)[0] == 0  # circcal's own, unchanged: replaced
    assert out.read_bytes() == first
    out.write_bytes(first + b"# my edit\n")  # changed since: the user's now
    code, err = _cli(["convert", src, out], capsys)
    assert code == 2 and "changed since" in err and out.read_bytes().endswith(b"# my edit\n")
    # a record that lists another file's hash, or no record at all, protects the same way
    (tmp_path / RECORD).unlink()
    out.write_bytes(first)
    assert _cli(["convert", src, out], capsys)[0] == 2 and out.read_bytes() == first


def test_a_killed_commit_is_recorded_by_recover(tmp_path, monkeypatch):
    import circcal.outputs as outputs_mod

    def killed(outputs, commit_id):  # the process dies after the journal, before any rename (no clean-up runs)
        raise SystemExit("killed")

    monkeypatch.setattr(outputs_mod, "_apply", killed)
    out = Outputs()
    out.file(tmp_path / "m.json", "--out").write_text("one")
    with pytest.raises(SystemExit):
        out.commit()
    monkeypatch.undo()
    assert not (tmp_path / "m.json").exists()
    assert recover(tmp_path) == [tmp_path / "m.json"]
    assert json.loads((tmp_path / RECORD).read_text())["files"] == {"m.json": sha256_file(tmp_path / "m.json")}


def test_a_symlink_to_an_input_is_refused(tmp_path, capsys, no_work):
    img = _png(tmp_path / "v.png")
    (tmp_path / "out.json").symlink_to(img)
    code, err = _cli(["detect", img, "--grid", "7x7", "--json", tmp_path / "out.json"], capsys)
    assert code == 2 and "input" in err and (tmp_path / "out.json").is_symlink()


@pytest.mark.parametrize(
    "args, word",
    [
        (["--split", "random", "--seed", "-5"], "--seed"),
    ],
)
def test_options_are_checked_before_the_work(tmp_path, capsys, no_work, args, word):
    """Case 9: `--seed -5` crashed (exit 70) after the whole calibration."""
    img = _png(tmp_path / "v.png")
    with pytest.raises(SystemExit) as e:
        _cli(["calibrate", img, *CAL, "--cross-validate", *args, "--out", tmp_path / "m.json"], capsys)
    assert e.value.code == 2 and word in capsys.readouterr().err


def test_diff_gridn_is_bounded(tmp_path, capsys):
    """Case 9: `diff A B --gridn 100000` asked for 41.9 GiB."""
    with pytest.raises(SystemExit) as e:
        _cli(["diff", tmp_path / "a.json", tmp_path / "b.json", "--gridn", "100000"], capsys)
    assert e.value.code == 2 and "--gridn" in capsys.readouterr().err


# the Outputs object itself --------------------------------------------------------------------------------------
def _write_folder(folder: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(text)


def test_commit_replaces_an_earlier_circcal_folder_and_file(tmp_path):
    for text in ("one", "two"):
        with Outputs() as out:
            f = out.file(tmp_path / "m.json", "--out")
            d = out.folder(tmp_path / "rep", "--report", kind="report")
            f.write_text(text)
            _write_folder(d, {"index.html": text, "figures/a.png": text})
            out.commit()
        assert (tmp_path / "m.json").read_text() == text
        assert (tmp_path / "rep" / "figures" / "a.png").read_text() == text
        assert json.loads((tmp_path / "rep" / MARKER).read_text())["circcal"] == "report"
    assert sorted(p.name for p in tmp_path.iterdir()) == [RECORD, "m.json", "rep"]  # nothing staged is left


def test_a_circcal_folder_changed_by_the_user_is_not_replaced(tmp_path):
    with Outputs() as out:
        _write_folder(out.folder(tmp_path / "rep", "--report", kind="report"), {"index.md": "x"})
        out.commit()
    (tmp_path / "rep" / "index.md").write_text("my notes")
    with pytest.raises(InputError, match="index.md was changed"):
        check_folder_output(tmp_path / "rep", "report", "--report")
    (tmp_path / "rep" / "index.md").write_text("x")
    (tmp_path / "rep" / "mine.txt").write_text("y")
    with pytest.raises(InputError, match="mine.txt"):
        Outputs().folder(tmp_path / "rep", "--report", kind="report")
    with pytest.raises(InputError, match="not a 'overlays' folder"):
        (tmp_path / "rep" / "mine.txt").unlink()
        check_folder_output(tmp_path / "rep", "overlays", "--overlay")


def test_a_failure_before_the_commit_leaves_everything_as_it_was(tmp_path):
    with Outputs() as out:  # an earlier run's
        out.file(tmp_path / "m.json", "--out").write_text("old")
        out.commit()
    with pytest.raises(RuntimeError):
        with Outputs() as out:
            out.file(tmp_path / "m.json", "--out").write_text("new")
            out.folder(tmp_path / "rep", "--report", kind="report")
            raise RuntimeError("a bug in the work")
    assert (tmp_path / "m.json").read_text() == "old" and sorted(os.listdir(tmp_path)) == [RECORD, "m.json"]


def test_outputs_that_overlap_are_refused(tmp_path):
    out = Outputs()
    out.folder(tmp_path / "rep", "--report", kind="report")
    with pytest.raises(InputError, match="overlap"):
        out.file(tmp_path / "rep" / "m.json", "--out")
    out.discard()


@pytest.mark.parametrize("crash_at", [1, 2, 3, 4])
@pytest.mark.parametrize("exchange", [True, False])
def test_a_commit_killed_between_renames_is_finished_by_the_next_run(tmp_path, monkeypatch, crash_at, exchange):
    """A process killed at any rename of the commit (simulated: the rename raises SystemExit and nothing after it
    runs) leaves each output old or new; the next run's planning (:func:`recover`) makes them all new."""
    import circcal.commit as O

    with Outputs() as out:
        out.file(tmp_path / "m.json", "--out").write_text("old")
        _write_folder(out.folder(tmp_path / "rep", "--report", kind="report"), {"i.html": "old"})
        out.commit()
    calls = []
    real_rename = O._rename

    def dying_rename(a, b):
        calls.append(b)
        if len(calls) == crash_at:
            raise SystemExit("killed")
        real_rename(a, b)

    monkeypatch.setattr(O, "_rename", dying_rename)
    if not exchange:
        monkeypatch.setattr(O, "_exchange", lambda a, b: False)
    out = Outputs()
    out.file(tmp_path / "m.json", "--out").write_text("new")
    _write_folder(out.folder(tmp_path / "rep", "--report", kind="report"), {"i.html": "new"})
    try:
        out.commit()
    except SystemExit:
        pass
    else:
        assert len(calls) < crash_at  # fewer renames than the crash point: the commit finished
    monkeypatch.setattr(O, "_rename", real_rename)
    model = (tmp_path / "m.json").read_text()
    report = (tmp_path / "rep" / "i.html").read_text() if (tmp_path / "rep").exists() else None
    assert model in ("old", "new") and report in ("old", "new", None)
    recover(tmp_path)
    assert (tmp_path / "m.json").read_text() == "new" and (tmp_path / "rep" / "i.html").read_text() == "new"
    leftovers = [p.name for p in tmp_path.iterdir() if p.name not in ("m.json", "rep", RECORD)]
    assert leftovers == [], leftovers
    assert json.loads((tmp_path / RECORD).read_text())["files"] == {"m.json": sha256_file(tmp_path / "m.json")}


def test_a_dead_runs_staging_is_removed_and_a_live_ones_kept(tmp_path):
    """Staging places carry their process's pid: a killed run's are removed by the next plan, a live one's never."""
    dead = tmp_path / ".m.json.circcal-999999999-abc.json"
    dead.write_text("half")
    live = tmp_path / f".m.json.circcal-{os.getpid()}-xyz.json"
    live.write_text("being written")
    with Outputs() as out:
        out.file(tmp_path / "m.json", "--out").write_text("new")
        out.commit()
    assert not dead.exists() and live.exists()


def test_a_killed_runs_half_written_record_is_removed_by_the_next_record(tmp_path):
    dead = 2**22 + 12345  # above pid_max's default: no live process has it
    stale = tmp_path / f".{RECORD}.circcal-{dead}-0a0b0c0d"
    stale.write_text('{"circcal": "fi')
    with Outputs() as out:
        out.file(tmp_path / "m.json", "--out").write_text("one")
        out.commit()
    assert not stale.exists()
    assert json.loads((tmp_path / RECORD).read_text())["files"] == {"m.json": sha256_file(tmp_path / "m.json")}


def test_a_file_written_by_someone_else_during_the_work_is_left_and_the_output_goes_beside_it(tmp_path):
    out = Outputs()
    out.file(tmp_path / "m.json", "--out").write_text("circcal's")
    (tmp_path / "m.json").write_text("the user's, meanwhile")  # after planning, before the commit
    with pytest.warns(RuntimeWarning, match="m.json was written by something else during the run.*m.new-1.json"):
        out.commit()
    assert (tmp_path / "m.json").read_text() == "the user's, meanwhile"
    assert (tmp_path / "m.new-1.json").read_text() == "circcal's"
    assert json.loads((tmp_path / RECORD).read_text())["files"] == {
        "m.new-1.json": sha256_file(tmp_path / "m.new-1.json")
    }
    # circcal's own earlier output, unchanged, is replaced as before: no warning
    with Outputs() as again:
        again.file(tmp_path / "m.new-1.json", "--out").write_text("second")
        again.commit()
    assert (tmp_path / "m.new-1.json").read_text() == "second" and not (tmp_path / "m.new-2.json").exists()


def test_a_full_disk_names_the_output_not_a_staging_path(tmp_path):
    """A write that fails for space (ENOSPC; a quota) is said of the output the user gave, the staging places
    removed and nothing written; a write on an open file (no file name) names every output."""
    import errno

    mine = tmp_path / "mine.txt"
    mine.write_text("my notes")
    with pytest.raises(OSError) as caught, Outputs() as outs:
        staging = outs.file(tmp_path / "rig.json", "--out")
        outs.folder(tmp_path / "rep", "--report", kind="report")
        raise OSError(errno.ENOSPC, "No space left on device", str(staging))
    assert caught.value.filename == f"--out {tmp_path / 'rig.json'}" and "nothing written" in caught.value.strerror
    with pytest.raises(OSError) as caught, Outputs() as outs:
        outs.file(tmp_path / "rig.json", "--out")
        outs.folder(tmp_path / "rep", "--report", kind="report")
        raise OSError(errno.EDQUOT, "Disk quota exceeded")
    assert caught.value.filename == f"--out {tmp_path / 'rig.json'}, --report {tmp_path / 'rep'}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.txt"] and mine.read_text() == "my notes"
