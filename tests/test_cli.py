"""The command line's contract: exit codes that tell bad input from a bug, one line for bad input, a traceback for a
bug."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from circcal import cli
from circcal.commit import RECORD
from circcal.errors import EXIT_BAD_INPUT, EXIT_INTERNAL_ERROR, InputError


def _with_command(monkeypatch, fn) -> None:
    """Replace the parser so that the command ``x`` runs ``fn``."""

    def build() -> argparse.ArgumentParser:
        parser = argparse.ArgumentParser(prog="circcal")
        sub = parser.add_subparsers(dest="command")
        sub.add_parser("x").set_defaults(func=fn)
        return parser

    monkeypatch.setattr(cli, "build_parser", build)


def test_bad_input_is_one_line_and_exit_2(monkeypatch, capsys):
    def bad(args):
        raise InputError("camera file model.json: fx must be a finite number, got True")

    _with_command(monkeypatch, bad)
    assert cli.main(["x"]) == EXIT_BAD_INPUT == 2
    err = capsys.readouterr().err
    assert err.strip() == "circcal x: error: camera file model.json: fx must be a finite number, got True"


def test_a_missing_file_is_bad_input(monkeypatch, capsys):
    def missing(args):
        open("/nonexistent/dir/file.json")

    _with_command(monkeypatch, missing)
    assert cli.main(["x"]) == EXIT_BAD_INPUT
    assert "/nonexistent/dir/file.json: No such file or directory" in capsys.readouterr().err


@pytest.mark.parametrize("exc", [RuntimeError("boom"), ValueError("an internal shape mismatch"), KeyError("k")])
def test_a_bug_keeps_its_traceback_and_exits_70(monkeypatch, capsys, exc):
    """A ValueError from inside circcal is a bug, not bad input: only InputError (and file errors) mean bad input."""

    def buggy(args):
        raise exc

    _with_command(monkeypatch, buggy)
    assert cli.main(["x"]) == EXIT_INTERNAL_ERROR == 70
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "in buggy" in err and "internal error" in err


def test_every_command_is_registered():
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert set(sub.choices) == set(cli.COMMANDS)


def test_outputs_are_checked_before_the_work(tmp_path, capsys):
    """An output that is a folder, or in a folder that cannot be written, is refused at once (exit 2, one line)
    instead of with a traceback after the whole calibration."""
    from circcal.cli import main

    model = tmp_path / "model.json"
    model.write_text(
        '{"camera": {"width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240, "dist": [0, 0, 0, 0, 0]}}'
    )
    out_dir = tmp_path / "adir"
    out_dir.mkdir()
    assert main(["convert", str(model), str(out_dir)]) == 2
    assert "is a folder" in capsys.readouterr().err
    assert main(["calibrate", "nonexistent.png", "--grid", "7x7", "--pitch", "10mm", "--out", str(out_dir)]) == 2
    assert "is a folder" in capsys.readouterr().err
    assert main(["convert", str(model), str(model / "inside" / "x.yaml")]) == 2  # a file where a folder must be
    assert "is not a folder" in capsys.readouterr().err
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        import os

        if os.access(locked, os.W_OK):  # running as root: permissions are not enforced
            pytest.skip("permissions are not enforced for this user (root)")
        assert main(["convert", str(model), str(locked / "x.yaml")]) == 2
        assert "not writable" in capsys.readouterr().err
    finally:
        locked.chmod(0o700)


def test_an_output_no_one_can_write_is_refused_before_the_work(tmp_path, capsys):
    """Where the permission bits do not tell (root, read-only mounts, /proc), the staging place made before the
    work in the nearest existing folder is the proof: an output under /proc is refused at once (exit 2, one line), nothing left behind.
    (Before, calibrate ran to the end and only then failed.)"""
    from circcal.cli import main

    if not Path("/proc/self").is_dir():
        pytest.skip("no /proc here (not Linux)")
    model = tmp_path / "model.json"
    model.write_text(
        '{"camera": {"width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240, "dist": [0, 0, 0, 0, 0]}}'
    )
    assert (
        main(
            [
                "calibrate",
                "nonexistent.png",
                "--grid",
                "7x7",
                "--pitch",
                "10mm",
                "--out",
                "/proc/circcal-no-such-folder/m.json",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "--out /proc/circcal-no-such-folder/m.json: nothing can be made in folder /proc" in err
    assert len(err.strip().splitlines()) == 1
    assert main(["convert", str(model), "/proc/circcal-no-such-folder/x.yaml"]) == 2
    assert "nothing can be made" in capsys.readouterr().err
    out = tmp_path / "ok.yaml"
    assert main(["convert", str(model), str(out)]) == 0 and out.is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == [RECORD, "model.json", "ok.yaml"]  # no probe file left


@pytest.mark.parametrize(
    "content, field",
    [
        (
            '{"camera": {"width": 640, "height": 480, "fx": true, "fy": 500, "cx": 320, "cy": 240, "dist": [0,0,0,0,0]}}',
            "fx",
        ),
        (
            '{"camera": {"width": 640, "height": 480, "fx": NaN, "fy": 500, "cx": 320, "cy": 240, "dist": [0,0,0,0,0]}}',
            "fx",
        ),
        (
            '{"camera": {"width": 640.5, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240, "dist": [0,0,0,0,0]}}',
            "width",
        ),
        (
            '{"camera": {"width": 640, "height": 480, "fx": 500, "fy": 500, "cx": null, "cy": 240, "dist": [0,0,0,0,0]}}',
            "cx",
        ),
        (
            '{"camera": {"width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240, "dist": [0, 0]}}',
            "dist",
        ),
        (
            '{"camera": {"width": 640, "height": 480, "fx": -5, "fy": 500, "cx": 320, "cy": 240, "dist": [0,0,0,0,0]}}',
            "focal lengths must be positive",
        ),
        ('{"views": []}', "no 'camera' block"),
        ('{"camera": ', "not valid JSON"),
    ],
)
def test_convert_refuses_bad_camera_values_and_names_file_and_field(tmp_path, capsys, content, field, earlier_output):
    """NaN, inf, booleans, null, non-integer sizes and distortion of the wrong length never pass into another file;
    the message names the file and the field; an earlier output is left as it was."""
    from circcal.cli import main

    src = tmp_path / "bad.json"
    src.write_text(content)
    out = tmp_path / "camera.yaml"
    earlier_output(out, "previous content\n")
    assert main(["convert", str(src), str(out)]) == 2
    err = capsys.readouterr().err
    assert str(src) in err and field in err
    assert out.read_text() == "previous content\n"


def test_detect_keeps_what_is_done_when_a_later_image_fails(tmp_path, monkeypatch, capsys, earlier_output):
    """A bug (or an interruption) at the third image leaves the earlier detections.json as it was and keeps the
    first two results beside it, in detections.partial-1.json, marked incomplete; the bug keeps its traceback
    (exit 70)."""
    import json

    import circcal.commands.detect as detect_cmd
    import circcal.detector.files as files
    from circcal.cli import main
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth

    truth = load_truth(fixture_dir("small-noisy"))
    paths = [str(v.image) for v in truth.views[:4]]
    real = files.detect
    calls = []

    def flaky(img, board, camera=None):
        calls.append(1)
        if len(calls) == 3:
            raise RuntimeError("a bug in the third image")
        return real(img, board, camera)

    monkeypatch.setattr(files, "detect", flaky)
    monkeypatch.setattr(detect_cmd, "SAVE_EVERY_S", 0.0)
    out = tmp_path / "detections.json"
    earlier_output(out, "earlier\n")
    b = truth.board
    code = main(
        [
            "detect",
            *paths,
            "--grid",
            f"{b.rows}x{b.cols}",
            "--pitch",
            f"{b.pitch_mm}mm",
            "--diameter",
            f"{b.diameter_mm}mm",
            "--json",
            str(out),
            "--jobs",
            "1",
            "--quiet",
        ]
    )
    err = capsys.readouterr().err
    assert code == 70 and "a bug in the third image" in err and "detections.partial-1.json" in err
    assert out.read_text() == "earlier\n"
    doc = json.loads((tmp_path / "detections.partial-1.json").read_text())
    assert doc["complete"] is False and [e["image"] for e in doc["images"]] == paths[:2]
    assert all(e["found"] for e in doc["images"])


def test_detect_reads_the_model_in_any_format(tmp_path):
    """--model takes an OpenCV YAML (or any format convert reads), not only model.json."""
    import json

    from circcal.cli import main
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth
    from circcal.formats import write_camera

    truth = load_truth(fixture_dir("small-noisy"))
    model = tmp_path / "camera.yaml"
    write_camera(model, truth.camera)
    out = tmp_path / "d.json"
    board = truth.board
    code = main(
        [
            "detect",
            str(truth.views[0].image),
            "--grid",
            f"{board.rows}x{board.cols}",
            "--pitch",
            f"{board.pitch_mm}mm",
            "--diameter",
            f"{board.diameter_mm}mm",
            "--model",
            str(model),
            "--json",
            str(out),
            "--quiet",
        ]
    )
    doc = json.loads(out.read_text())
    assert code == 0 and doc["complete"] and doc["images"][0]["found"] and doc["images"][0]["reason_code"] is None


def test_sigterm_unwinds_cleanly(monkeypatch, capsys):
    """A stop request (SIGTERM) unwinds like Ctrl-C: finally blocks run, exit 130, one line."""
    import os
    import signal

    cleaned = []

    def stopped(args):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            import time

            time.sleep(5)  # the handler raises before this returns
        finally:
            cleaned.append(True)

    _with_command(monkeypatch, stopped)
    old = signal.getsignal(signal.SIGTERM)
    try:
        assert cli.main(["x"]) == 143  # 128 + SIGTERM, as a shell reports it
    finally:
        signal.signal(signal.SIGTERM, old)
    assert cleaned == [True] and capsys.readouterr().err.strip() == "terminated"


def test_pycolmap_import_leaves_sigterm_alone():
    """pycolmap/pyceres bring glog, whose failure handler printed a native stack dump on SIGTERM (seen when a
    validate run was stopped): the adapter imports them without letting glog keep SIGTERM."""
    import subprocess
    import sys

    code = (
        "import os, signal\n"
        "from circcal.validators.pycolmap import PycolmapCalibrator\n"
        "ok, why = PycolmapCalibrator().available()\n"
        "assert ok, why\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == -signal_number("SIGTERM"), (run.returncode, run.stderr[-2000:])
    assert "stack trace" not in run.stderr and "*** SIGTERM" not in run.stderr


def signal_number(name: str) -> int:
    import signal

    return int(getattr(signal, name))


def test_a_failed_write_leaves_the_previous_file_intact(tmp_path, earlier_output):
    """A write that fails half way (disk full, quota: here a 4 KiB file-size limit, as `ulimit -f 4`) leaves the
    previous output as it was and no temporary file behind; the error is one line (exit 2)."""
    import json
    import resource
    import signal
    import subprocess
    import sys

    big = tmp_path / "model.json"
    doc = {
        "camera": {"width": 640, "height": 480, "fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0, "dist": [0.0] * 5},
        "views": [{"rvec": [0.1, 0.2, 0.3], "tvec_mm": [1.0, 2.0, 300.0]}] * 200,
    }
    big.write_text(json.dumps(doc))
    out = tmp_path / "previous.json"
    earlier_output(out, '{"previous": true}\n')

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write then fails with EFBIG instead of a kill
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))

    run = subprocess.run(
        [sys.executable, "-m", "circcal.cli", "convert", str(big), str(out)],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=limit,
    )
    assert run.returncode == 2, run.stderr
    assert "File too large" in run.stderr and "Traceback" not in run.stderr
    assert out.read_text() == '{"previous": true}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == [RECORD, "model.json", "previous.json"]


def test_warnings_are_one_readable_line(monkeypatch, capsys):
    import warnings

    def warns(args):
        warnings.warn("calibration did not converge (iteration limit 200 reached)", RuntimeWarning)
        return 0

    _with_command(monkeypatch, warns)
    assert cli.main(["x"]) == 0
    assert capsys.readouterr().err.strip() == (
        "circcal x: warning: calibration did not converge (iteration limit 200 reached)"
    )


def test_progress_bar_hidden_does_not_import_tqdm_and_shown_draws():
    """A hidden bar is a stand-in (no tqdm import: start-up); a shown one is tqdm's, drawn on stderr."""
    import subprocess
    import sys

    code = (
        "import sys\nfrom circcal.progress import progress_bar\n"
        "with progress_bar(3, 'x', 'it', False) as b:\n    b.update(); b.set_postfix_str('y')\n"
        "assert 'tqdm' not in sys.modules, 'tqdm imported for a hidden bar'\n"
        "b = progress_bar(3, 'detect', 'img', True)\nb.update(3); b.close()\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "detect" in r.stderr and "3/3" in r.stderr


def test_python_dash_m_circcal_is_the_command():
    """``python -m circcal`` runs the command (an environment whose scripts folder is not on the PATH): its help, and
    a refusal's one line and exit status 2."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "circcal", "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "calibrate-rig" in r.stdout, r.stderr
    r = subprocess.run([sys.executable, "-m", "circcal", "nosuch"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "nosuch" in r.stderr


def test_a_dropped_dot_is_named_without_a_position(realdata, tmp_path, capsys):
    # the detector drops 11 dots of one real 10x8 view (a shadow's edge touches them): the outlier list names them,
    # and says no "(nan, nan) px" for the centre they never had
    from circcal.cli import main

    folder = realdata / "boofcv_sony_hx5v_circle_regular_10x8"
    assert (
        main(
            [
                "calibrate",
                *map(str, sorted(folder.glob("image*.jpg"))),
                "--grid",
                "8x10",
                "--pitch",
                "25mm",
                "--diameter",
                "15mm",
                "--no-progress",
                "--no-cross-validate",
                "--out",
                str(tmp_path / "m.json"),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "image00005.jpg: point 34: bad-dot: detector:" in out and "(nan" not in out


@pytest.mark.parametrize(
    "argv, words",
    [
        (["calibrate", "x.png", "--grid", "7x7", "--pitch", "25"], ["--pitch", "25 what?", "25mm"]),
        (["calibrate", "x.png", "--grid", "8by10", "--pitch", "25mm"], ["--grid", "8by10"]),
        (["calibrate", "x.png", "--grid", "7x7", "--pitch", "25px"], ["--pitch", "25px"]),
        (["calibrate", "--grid", "7x7", "--pitch", "25mm"], ["images"]),
    ],
)
def test_a_bad_option_is_one_line_without_the_usage(capsys, argv, words):
    """Issue 36: `--pitch 25` without a unit was read as mm; every argument error printed ten lines of usage before
    the one line that says what is wrong."""
    from circcal.cli import main

    with pytest.raises(SystemExit) as e:
        main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and "usage:" not in err
    assert all(w in err for w in words), err


def test_a_folder_stands_for_its_images_sorted(tmp_path, capsys):
    import cv2
    import numpy as np

    from circcal.cli import main

    for name in ("b.png", "a.PNG", "notes.txt"):
        (tmp_path / "photos").mkdir(exist_ok=True)
        if name.endswith("txt"):
            (tmp_path / "photos" / name).write_text("x")
        else:
            cv2.imwrite(str(tmp_path / "photos" / name), np.full((40, 40), 200, np.uint8))
    out = tmp_path / "d.json"
    main(["detect", str(tmp_path / "photos"), "--grid", "7x7", "--json", str(out), "--quiet"])
    import json

    assert [Path(e["image"]).name for e in json.loads(out.read_text())["images"]] == ["a.PNG", "b.png"]
    assert "photos: 2 images" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["detect", str(tmp_path / "empty"), "--grid", "7x7", "--json", str(out), "--quiet"]) == 2


@pytest.mark.parametrize("command", ["", *__import__("circcal.cli", fromlist=["COMMANDS"]).COMMANDS])
def test_help_shows_no_developer_markup(command, capsys):
    """Issue 36: `circcal board --help` showed ":func:`add_marker_arguments`" (the module docstring as written)."""
    import re

    from circcal.cli import main

    with pytest.raises(SystemExit) as e:
        main([command, "--help"] if command else ["--help"])
    out = capsys.readouterr().out
    assert e.value.code == 0 and out
    assert not re.search(r":(func|data|class|mod|meth|attr|ref):`|``", out), out


def test_overlays_of_images_sharing_a_name_do_not_overwrite_each_other(tmp_path):
    """a/x.png and b/x.png give two overlays, numbered by their place among the inputs; a lone name stays plain."""
    import cv2
    import numpy as np

    from circcal.cli import main

    paths = [tmp_path / "a" / "x.png", tmp_path / "b" / "x.png", tmp_path / "b" / "y.png"]
    for p in paths:
        p.parent.mkdir(exist_ok=True)
        cv2.imwrite(str(p), np.full((40, 40), 200, np.uint8))
    out = tmp_path / "ov"
    main(["detect", *map(str, paths), "--grid", "7x7", "--json", str(tmp_path / "d.json"), "--overlay", str(out)])
    assert sorted(f.name for f in out.iterdir() if not f.name.startswith(".")) == [
        "x_0000_detect.png",
        "x_0001_detect.png",
        "y_detect.png",
    ]


def test_a_reader_that_goes_away_does_not_cost_the_model(tmp_path):
    """``circcal calibrate ... | head -1``: the console's reader closes early; the command still commits its model
    and exits as it would have (it exited 2 with "Broken pipe" before the model was written)."""
    import subprocess
    import sys

    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth

    truth = load_truth(fixture_dir("small-noisy", progress=False))
    out = tmp_path / "m.json"
    args = [str(v.image) for v in truth.views[:6]] + ["--grid", "7x9", "--pitch", "10mm", "--no-progress"]
    code = "import sys; from circcal.cli import main; sys.exit(main(sys.argv[1:]))"
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "calibrate", *args, "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()  # the reader is gone before the first line
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err.decode()
    assert out.is_file() and b"Broken pipe" not in err
