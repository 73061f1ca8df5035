"""``circcal calibrate-rig`` and ``circcal triangulate`` end to end on the rendered rig fixture "two" (a 640x480
opencv5 camera and a 512x384 rational one; instants seen by one camera only): the files written read back (OpenCV's
FileStorage for the stereo YAML) with the rig within bounds of the truth, every bad argument is one line and exit 2
with nothing written, and points projected through the true rig are triangulated within their stated sigmas."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from circcal.cli import main
from circcal.fixtures.rig import rig_fixture_dir, rig_scenario
from circcal.formats import write_camera
from circcal.model import project
from circcal.rig import RigModel, read_opencv_stereo
from circcal.rotation import rodrigues, rotation_angle_deg

GRID = ["--grid", "8x11", "--pitch", "15mm"]


def _run(argv: list[str]) -> int:
    """main's exit status, argparse's refusals (SystemExit) included."""
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code)


@pytest.fixture(scope="module")
def fixture_dir():
    return rig_fixture_dir("two")


@pytest.fixture(scope="module")
def run_json(fixture_dir, tmp_path_factory):
    """calibrate-rig with a folder and a glob, the lens per camera, every output but Kalibr's."""
    out = tmp_path_factory.mktemp("rig")
    argv = [
        "calibrate-rig",
        "--camera",
        f"left={fixture_dir / 'left'}",
        "--camera",
        f"right={fixture_dir / 'right'}/*.png",
        "--lens",
        "right=rational",
        *GRID,
        "--out",
        str(out / "rig.json"),
        "--ros",
        str(out / "ros"),
        "--cameramodels",
        str(out / "models"),
        "--rectified",
        str(out / "rect"),
        "--report",
        str(out / "report"),
        "--jobs",
        "1",
        "--no-progress",
    ]
    return out, argv


def test_calibrate_rig_json_end_to_end(run_json, capsys):
    out, argv = run_json
    assert main(argv) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert lines[0] == (
        "verdict: consistent: two halves of the instants give the same rig within its stated uncertainty, and no "
        "view is an outlier"
    )
    assert "RMS per point (2-D norm), OpenCV's convention" in text
    assert "camera right: 512x384" in text and "14 images found, 14 views used" in text
    assert "pose in the rig (X_right = R X_left + T): rotation" in text and "baseline" in text
    assert "the field left and right share" in text and "cross-validation (two halves" in text
    doc = json.loads((out / "rig.json").read_text())
    rig = RigModel.from_dict(doc)
    truth = rig_scenario("two").rig
    R, T = rig.pair(0, 1)
    Rt, Tt = truth.pair(0, 1)
    assert rotation_angle_deg(R @ Rt.T) < 0.02 and np.linalg.norm(T - Tt) < 0.2
    assert rig.covariance is not None and rig.covariance.shape == (len(rig.state_vector()),) * 2
    assert set(doc["instants"]) == {"left", "right"} and len(doc["instants"]["right"]) == 14
    assert set(doc["instants"]["left"]) ^ set(doc["instants"]["right"])  # instants seen by one camera only
    assert doc["verdict"]["verdict"] == "consistent" and set(doc["rms_px_per_camera"]) == {"left", "right"}
    # the other outputs: a ROS pair, one .cameramodel per camera, a rectified pair per shared instant
    assert sorted(p.name for p in (out / "ros").glob("*.yaml")) == ["left.yaml", "right.yaml"]
    assert sorted(p.name for p in (out / "models").glob("*.cameramodel")) == ["left.cameramodel", "right.cameramodel"]
    left = {p.name for p in (Path(argv[2].split("=", 1)[1])).glob("*.png")}
    right = {p.name for p in Path(argv[4].split("=", 1)[1]).parent.glob("*.png")}
    assert sorted(p.name for p in (out / "rect").glob("*.png")) == sorted(left & right)
    img = cv2.imread(str(next((out / "rect").glob("*.png"))))
    assert img is not None and img.shape[1] == 2 * 640


def test_the_rig_report_holds_the_verdict_the_numbers_and_the_figures(run_json, capsys):
    """--report: report.html (self-contained: its figures as data URIs) and index.md carry the console's verdict and
    per-camera numbers, the rig in 3-D and a rectified pair."""
    import cv2

    out, argv = run_json
    if not (out / "report" / "report.html").exists():
        assert _run(argv) == 0
    capsys.readouterr()
    page = (out / "report" / "report.html").read_text()
    md = (out / "report" / "index.md").read_text()
    assert page.count("data:image/png;base64,") == 2 and "src='geometry.png'" not in page
    for text in (md, page):
        assert "verdict: " in text and "camera left (reference)" in text and "projection uncertainty" in text
    for name in ("geometry.png", "rectified.png"):
        img = cv2.imread(str(out / "report" / name))
        assert img is not None and img.shape[0] > 100 and f"]({name})" in md


def test_calibrate_rig_yaml_reads_back_in_opencv(fixture_dir, tmp_path, capsys):
    out = tmp_path / "stereo.yaml"
    argv = ["calibrate-rig", "--camera", f"left={fixture_dir / 'left'}", "--camera", f"right={fixture_dir / 'right'}"]
    argv += ["--lens", "right=rational", *GRID, "--out", str(out), "--no-cross-validate", "--jobs", "1"]
    assert main([*argv, "--no-progress"]) == 0
    assert capsys.readouterr().out.startswith("verdict: not cross-validated: skipped (--no-cross-validate)")
    fs = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    try:
        M1, D1, M2, D2 = (fs.getNode(k).mat() for k in ("M1", "D1", "M2", "D2"))
        R, T, P2, Q = (fs.getNode(k).mat() for k in ("R", "T", "P2", "Q"))
    finally:
        fs.release()
    truth = rig_scenario("two").rig
    Rt, Tt = truth.pair(0, 1)
    assert rotation_angle_deg(R @ Rt.T) < 0.02 and np.linalg.norm(T.ravel() - Tt) < 0.2
    assert M1.shape == M2.shape == (3, 3) and D1.size == 5 and D2.size == 8
    assert abs(M1[0, 0] - truth.cameras[0].fx) < 0.5 and abs(M2[0, 0] - truth.cameras[1].fx) < 0.5
    assert P2.shape == (3, 4) and Q.shape == (4, 4)
    rig = read_opencv_stereo(out)
    assert rig.names == ("left", "right") and np.allclose(rig.pair(0, 1)[1], T.ravel())


def _images(root: Path, names: list[str]) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    for n in names:
        (root / n).write_bytes(b"")  # never read: every argument is checked before any image is
    return root


BAD = {
    "no '='": (["--camera", "left"], "expected NAME=IMAGES"),
    "bad name": (["--camera", "a/b=L", "--camera", "right=R"], "camera name 'a/b'"),
    "named twice": (["--camera", "left=L", "--camera", "left=R"], "camera 'left' given twice"),
    "one camera": (["--camera", "left=L"], "at least two cameras, got 1"),
    "one folder twice": (["--camera", "left=L", "--camera", "right=L"], "is also given to camera 'left'"),
    "a file in two cameras": (["--camera", "left=L", "--camera", "right=L/a.png"], "the same folder given twice?"),
    "empty folder": (["--camera", "left=L", "--camera", "right=E"], "holds no image file"),
    "a text file as the images": (
        ["--camera", "left=L", "--camera", "right=N/notes.txt"],
        "a file that is not an image",
    ),
    "a glob of no image": (["--camera", "left=L", "--camera", "right=N/*"], "matches 1 file(s), none an image"),
    "too few images": (["--camera", "left=L", "--camera", "right=L2"], "--camera right: 1 image(s); a camera's"),
    "a folder copied": (
        ["--camera", "left=L", "--camera", "right=C"],
        "C/b.png holds the bytes of camera left's L/b.png (2 such",
    ),
    "glob matches nothing": (["--camera", "left=L", "--camera", "right=R/*.jpg"], "the pattern matches no file"),
    "no such folder": (["--camera", "left=L", "--camera", "right=nowhere"], "no such folder or file"),
    "no shared name": (["--camera", "left=L", "--camera", "right=S"], "share no file name"),
    # right1.png and right01.png: one instant once each camera's prefix and suffix are left out
    "two images one instant": (["--camera", "left=P/left*", "--camera", "right=P/right*"], "two images of instant '1'"),
    "unknown lens": (["--camera", "left=L", "--camera", "right=R", "--lens", "right=pinhole"], "unknown lens model"),
    "lens of no camera": (["--camera", "left=L", "--camera", "right=R", "--lens", "up=rational"], "no camera 'up'"),
    "lens twice": (["--camera", "left=L", "--camera", "right=R", "--lens", "fisheye", "--lens", "rational"], "twice"),
    "hold not in lens": (
        ["--camera", "left=L", "--camera", "right=R", "--lens", "right=fisheye", "--fix-tangential"],
        "camera 'right' (lens fisheye): --fix-tangential",
    ),
    "out extension": (["--camera", "left=L", "--camera", "right=R", "--out", "OUT/rig.txt"], "unknown extension"),
    "fisheye cameramodels": (
        ["--camera", "left=L", "--camera", "right=R", "--lens", "right=fisheye", "--cameramodels", "OUT/m"],
        "--cameramodels: camera 'right' is fisheye",
    ),
    "kalibr extension": (
        ["--camera", "left=L", "--camera", "right=R", "--fix-k3", "--kalibr", "OUT/k.txt"],
        "--kalibr OUT/k.txt: give a .yaml file",
    ),
    "kalibr k3": (["--camera", "left=L", "--camera", "right=R", "--kalibr", "OUT/k.yaml"], "--fix-k3"),
    "alpha": (["--camera", "left=L", "--camera", "right=R", "--alpha", "2"], "--alpha"),
    "no grid": (["--camera", "left=L", "--camera", "right=R", "--no-grid"], "give --grid ROWSxCOLS"),
    "board and grid": (["--camera", "left=L", "--camera", "right=R", "--board", "B.yaml"], "--board"),
    "output is an input": (
        ["--camera", "left=L", "--camera", "right=R", "--board", "B.json", "--out", "B.json", "--no-grid"],
        "it is one of the inputs",
    ),
    "intrinsics without '='": (["--camera", "left=L", "--camera", "right=R", "--intrinsics", "M.yaml"], "NAME=MODEL"),
    "intrinsics of no camera": (
        ["--camera", "left=L", "--camera", "right=R", "--intrinsics", "up=M.yaml"],
        "--intrinsics up=M.yaml: no camera 'up'",
    ),
    "intrinsics twice": (
        ["--camera", "left=L", "--camera", "right=R", "--intrinsics", "left=M.yaml", "--intrinsics", "left=M.yaml"],
        "--intrinsics left: given twice",
    ),
    "intrinsics file missing": (
        ["--camera", "left=L", "--camera", "right=R", "--intrinsics", "left=none.yaml"],
        "none.yaml: no such file",
    ),
    "intrinsics against its lens": (
        ["--camera", "left=L", "--camera", "right=R", "--lens", "left=rational", "--intrinsics", "left=M.yaml"],
        "its lens model is opencv5, --lens left=rational",
    ),
    "output is the intrinsics": (
        ["--camera", "left=L", "--camera", "right=R", "--intrinsics", "left=M.yaml", "--out", "M.yaml"],
        "--out M.yaml: it is one of the inputs",
    ),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_arguments_are_one_line_and_write_nothing(case, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    _images(tmp_path / "L", ["a.png", "b.png", "c.png"])
    _images(tmp_path / "L2", ["a.png"])
    _images(tmp_path / "R", ["a.png", "b.png", "d.png"])
    _images(tmp_path / "S", ["x.png", "y.png"])
    (tmp_path / "N").mkdir()
    (tmp_path / "N" / "notes.txt").write_text("my notes")
    for name, data in (("a.png", b""), ("b.png", b"\x89PNG b"), ("c.png", b"\x89PNG c")):  # copies of L's (a: empty)
        (tmp_path / "C").mkdir(exist_ok=True)
        (tmp_path / "L" / name).write_bytes(data)
        (tmp_path / "C" / name).write_bytes(data)
    _images(tmp_path / "P", ["left1.png", "left2.png", "right1.png", "right01.png", "right2.png"])
    (tmp_path / "B.json").write_text('{"rows": 8, "cols": 11, "layout": "symmetric", "pitch_mm": 15}')
    (tmp_path / "E").mkdir()
    (tmp_path / "OUT").mkdir()
    (tmp_path / "B.yaml").write_text("rows: 8\ncols: 11\nlayout: symmetric\npitch_mm: 15\n")
    write_camera(tmp_path / "M.yaml", rig_scenario("two").rig.cameras[0])
    words, expected = BAD[case]
    grid = [] if "--no-grid" in words else GRID
    words = [w for w in words if w != "--no-grid"]
    if "--out" not in words:
        words += ["--out", "OUT/rig.json"]
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    code = _run(["calibrate-rig", *words, *grid, "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1, err
    assert expected in err, err
    assert sorted(str(p) for p in tmp_path.rglob("*")) == before  # nothing written, no staging left


def test_given_intrinsics_are_held_and_only_the_poses_solved(fixture_dir, tmp_path, capsys):
    """--intrinsics NAME=FILE (OpenCV's CALIB_FIX_INTRINSIC): each camera's true intrinsics given in a model file
    come back exactly, the rig's pose is solved (measured 0.0009 deg, 0.0066 mm from the truth; the default run's
    bounds are 0.02 deg, 0.2 mm), the cross-validation does not compare held intrinsics and no projection
    uncertainty is stated for them; an image size unlike the file's is refused before the work."""
    truth = rig_scenario("two").rig
    files = {}
    for name, cam in zip(truth.names, truth.cameras):
        files[name] = tmp_path / f"{name}_true.yaml"  # OpenCV's YAML: the rational lens read back from its flags
        write_camera(files[name], cam)
    cams = ["--camera", f"left={fixture_dir / 'left'}", "--camera", f"right={fixture_dir / 'right'}"]
    given = [w for n, f in files.items() for w in ("--intrinsics", f"{n}={f}")]
    out = tmp_path / "rig.json"
    assert main(["calibrate-rig", *cams, *given, *GRID, "--out", str(out), "--jobs", "1", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("verdict: consistent") and "projection of right: intrinsics held (given)" in text
    assert "consistent: every camera's projection (held, not compared: left, right) within" in text
    assert "projection uncertainty of left's intrinsics: none stated (held at the ones given)" in text
    rig = RigModel.from_dict(json.loads(out.read_text()))
    assert [c.lens for c in rig.cameras] == ["opencv5", "rational"]
    for c, t in zip(rig.cameras, truth.cameras):
        assert np.array_equal(c.intrinsics, t.intrinsics)
    (R, T), (Rt, Tt) = rig.pair(0, 1), truth.pair(0, 1)
    assert rotation_angle_deg(R @ Rt.T) < 0.005 and np.linalg.norm(T - Tt) < 0.03
    sd = np.sqrt(np.diag(rig.covariance))
    assert not np.any(sd[: len(rig.state_vector()) - 6]) and np.all(sd[-6:] > 0)  # held: only the pose has a sigma
    swapped = ["--intrinsics", f"left={files['right']}"]
    assert _run(["calibrate-rig", *cams, *swapped, *GRID, "--out", str(tmp_path / "b.json"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "a 512x384 camera, camera left's images are 640x480" in err and not (tmp_path / "b.json").exists()


def _true_pixels(instant: int):
    """Board points of one instant in the rig frame (mm) and their exact pixels in each camera of the true rig."""
    sc = rig_scenario("two")
    X0 = sc.board.object_points() @ rodrigues(sc.board_rvecs[instant]).T + sc.board_tvecs[instant]
    px = {}
    for c, name in enumerate(sc.rig.names):
        R, T = sc.rig.pose(c)
        px[name] = project(X0 @ R.T + T, np.zeros(3), np.zeros(3), sc.rig.cameras[c])
    return sc, X0, px


def _write_points(tmp_path: Path, px: dict) -> list[str]:
    """left as CSV with a header and ids (one point unseen), right as JSON."""
    left = tmp_path / "left.csv"
    with left.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["id", "u", "v"])
        for k, (u, v) in enumerate(px["left"]):
            w.writerow([f"p{k}", "" if k == 0 else repr(float(u)), "" if k == 0 else repr(float(v))])
    right = tmp_path / "right.json"
    right.write_text(json.dumps({"points": px["right"].tolist()}))
    return ["--points", f"left={left}", "--points", f"right={right}"]


def test_triangulate_true_points_within_their_sigmas(tmp_path, capsys):
    """The true rig (with a pixel noise given): noisy pixels of the true points come back within their sigmas."""
    sc, X0, px = _true_pixels(4)
    rng = np.random.default_rng(0)
    sigma = 0.1
    noisy = {n: p + rng.normal(0.0, sigma, p.shape) for n, p in px.items()}
    rig_file = tmp_path / "true_rig.json"
    rig_file.write_text(json.dumps(sc.rig.to_dict()))
    out = tmp_path / "points.json"
    argv = ["triangulate", "--rig", str(rig_file), *_write_points(tmp_path, noisy), "--pixel-sigma", str(sigma)]
    assert main([*argv, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "in the frame of left (the reference camera), mm" in text and "p0 (given by 1 camera(s): no point)" in text
    doc = json.loads(out.read_text())
    rows = doc["points"]
    assert len(rows) == len(X0) and rows[0]["x_mm"] is None and rows[1]["id"] == "p1"
    X = np.array([[r["x_mm"], r["y_mm"], r["z_mm"]] for r in rows[1:]])
    S = np.array([[r["sigma_x_mm"], r["sigma_y_mm"], r["sigma_z_mm"]] for r in rows[1:]])
    z = (X - X0[1:]) / S
    assert np.all(np.abs(z) < 4.5) and 0.6 < np.sqrt(np.mean(z**2)) < 1.5, np.sqrt(np.mean(z**2))
    assert all(r["sigma_largest_mm"] >= max(r["sigma_x_mm"], r["sigma_y_mm"], r["sigma_z_mm"]) for r in rows[1:])
    assert "behind a camera" not in text and all(r["behind"] == "" for r in rows)
    # with --out the console shows the first CONSOLE_ROWS points, the file every one
    from circcal.commands.triangulate import CONSOLE_ROWS

    assert len(rows) > CONSOLE_ROWS and f"... {len(rows) - CONSOLE_ROWS} more point(s) in {out}" in text
    assert f"\n{'p' + str(CONSOLE_ROWS - 1):>8} " in text and f"\n{'p' + str(CONSOLE_ROWS):>8} " not in text


def test_triangulate_names_points_behind_the_cameras(tmp_path, capsys):
    """right's rows reversed (a file of another point order): the points whose rays then cross behind the cameras
    are named in one line and in the output's 'behind' field."""
    sc, _, px = _true_pixels(4)
    px["right"] = px["right"][::-1]
    rig_file = tmp_path / "true_rig.json"
    rig_file.write_text(json.dumps(sc.rig.to_dict()))
    out = tmp_path / "points.json"
    argv = ["triangulate", "--rig", str(rig_file), *_write_points(tmp_path, px), "--pixel-sigma", "0.1"]
    assert main([*argv, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    rows = json.loads(out.read_text())["points"]
    flagged = [r["id"] for r in rows if r["behind"]]
    assert flagged and f"{len(flagged)} point(s) behind a camera that sees them: {flagged[0]} (behind " in text
    assert all(r["z_mm"] < 0 for r in rows if r["behind"] == "left;right")
    # rays that meet nowhere (Gauss-Newton runs off to infinity; it raised LinAlgError before): no point, said why
    assert "(given by 2 camera(s); their rays meet at no finite point in front of them" in text
    assert any(r["x_mm"] is None for r in rows)


def test_triangulate_through_the_calibrated_rig(run_json, tmp_path, capsys):
    """Exact pixels of the true points through calibrate-rig's rig.json (its covariance included): every point
    within 3 of its largest sigma (the calibration's error is common to all points); the CSV output reads back."""
    out, argv = run_json
    if not (out / "rig.json").exists():
        assert main(argv) == 0
        capsys.readouterr()
    _, X0, px = _true_pixels(4)
    pts = tmp_path / "p.csv"
    assert main(["triangulate", "--rig", str(out / "rig.json"), *_write_points(tmp_path, px), "--out", str(pts)]) == 0
    assert "and the calibration's covariance" in capsys.readouterr().out
    rows = list(csv.DictReader(pts.open()))
    assert rows[0]["x_mm"] == "" and len(rows) == len(X0)
    X = np.array([[float(r[k]) for k in ("x_mm", "y_mm", "z_mm")] for r in rows[1:]])
    largest = np.array([float(r["sigma_largest_mm"]) for r in rows[1:]])
    assert np.all(np.linalg.norm(X - X0[1:], axis=1) < 3 * largest)


def test_triangulate_bad_arguments(run_json, tmp_path, capsys):
    sc, _, px = _true_pixels(4)
    rig_file = tmp_path / "rig.json"
    rig_file.write_text(json.dumps(sc.rig.to_dict()))  # no covariance, no rms_px
    pts = _write_points(tmp_path, px)
    short = tmp_path / "short.csv"
    short.write_text("1,2\n3,4\n")
    bad_value = tmp_path / "bad.csv"
    bad_value.write_text("u,v\n1,2\n3,x\n")
    cases = [
        (["--rig", str(rig_file), *pts], "states no pixel noise (no rms_px): give --pixel-sigma"),
        (["--rig", str(rig_file), pts[0], pts[1], "--pixel-sigma", "1"], "at least two cameras, got 1"),
        (["--rig", str(rig_file), *pts, "--points", f"up={short}", "--pixel-sigma", "1"], "no camera 'up'"),
        (["--rig", str(rig_file), pts[0], pts[1], "--points", f"right={short}", "--pixel-sigma", "1"], "different"),
        (["--rig", str(rig_file), pts[0], pts[1], "--points", f"right={bad_value}", "--pixel-sigma", "1"], "line 3"),
        (["--rig", str(tmp_path / "nope.json"), *pts, "--pixel-sigma", "1"], "no such file"),
        (["--rig", str(short), *pts, "--pixel-sigma", "1"], "unknown extension"),
        (["--rig", str(rig_file), *pts, "--pixel-sigma", "1", "--out", str(tmp_path / "p.txt")], "unknown extension"),
        (["--rig", str(rig_file), *pts, "--pixel-sigma", "0"], "--pixel-sigma"),
    ]
    before = sorted(tmp_path.iterdir())
    for words, expected in cases:
        code = _run(["triangulate", *words])
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1 and expected in err, (words, err)
    assert sorted(tmp_path.iterdir()) == before


def test_help_names_the_formats(capsys):
    for command in ("calibrate-rig", "triangulate"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
    out = capsys.readouterr().out
    assert "NAME=IMAGES" in out and "X_2 = R X_1 + T" in out and "'u,v' or 'id,u,v'" in out


def test_a_pixel_a_camera_cannot_unproject_is_said_so(tmp_path, capsys):
    # p1's left pixel far beyond where the left lens folds over (opencv5 with k3 < 0): given by both cameras, no point
    sc, _, px = _true_pixels(3)
    px["left"][1] = (-3000.0, -3000.0)
    rig_file = tmp_path / "true_rig.json"
    rig_file.write_text(json.dumps(sc.rig.to_dict()))
    argv = ["triangulate", "--rig", str(rig_file), *_write_points(tmp_path, px), "--pixel-sigma", "0.1"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "p1 (given by 2 camera(s); 1 of them cannot unproject its pixel (beyond its lens's one-to-one field" in text
    assert "p0 (given by 1 camera(s): no point)" in text


def test_a_grid_that_is_not_the_boards_names_the_images_grid(fixture_dir, tmp_path, capsys):
    # --grid 7x11 on the 8x11 board: no rig, and the grid the images show, as calibrate says it; nothing written
    argv = ["calibrate-rig", "--camera", f"left={fixture_dir / 'left'}", "--camera", f"right={fixture_dir / 'right'}"]
    argv += ["--grid", "7x11", "--pitch", "15mm", "--lens", "right=rational", "--out", str(tmp_path / "rig.json")]
    assert main([*argv, "--jobs", "1", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "no rig: camera 'left': the board was found in 0 of" in err
    assert "circcal calibrate-rig: the images show --grid 8x11 (or give --grid auto)" in err
    assert list(tmp_path.iterdir()) == []


def test_one_cameras_images_given_for_both_is_named_with_what_to_do(fixture_dir, tmp_path, capsys):
    # one folder twice is refused before any work ("the same folder given twice?"), and so is a byte copy of it as
    # the other camera's (a wrong folder copied); the same images written again (other bytes, the same pixels)
    # solve to a zero baseline: the verdict says the same images were given for both cameras (each camera
    # re-corrects its own centres: equal to rounding, 3e-13 px)
    import shutil

    import cv2

    shutil.copytree(fixture_dir / "left", tmp_path / "copy")
    argv = ["calibrate-rig", "--camera", f"left={fixture_dir / 'left'}", "--camera", f"right={tmp_path / 'copy'}"]
    argv += [*GRID, "--no-cross-validate", "--jobs", "1", "--no-progress"]
    assert main([*argv, "--out", str(tmp_path / "rig.json")]) == 2
    err = capsys.readouterr().err
    assert "holds the bytes of camera left's" in err and not (tmp_path / "rig.json").exists()
    for f in (tmp_path / "copy").glob("*.png"):
        cv2.imwrite(str(f), cv2.imread(str(f), cv2.IMREAD_UNCHANGED), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    assert main([*argv, "--out", str(tmp_path / "rig.json"), "--report", str(tmp_path / "report")]) == 0
    out = capsys.readouterr().out
    assert out.startswith("verdict: a model or data problem"), out[:300]
    assert "cameras 'left' and 'right' sit at one point" in out and "the same images were given for both" in out
    assert "what to do: give each camera its own images" in out
    doc = json.loads((tmp_path / "rig.json").read_text())
    assert doc["verdict"]["coincident"][0]["same_points"] is True
    # the report has no rectified view (there is no epipolar geometry to rectify by)
    assert not (tmp_path / "report" / "rectified.png").exists() and (tmp_path / "report" / "geometry.png").exists()
    # outputs that need the rectification are refused, and nothing of the run is written
    stereo = tmp_path / "stereo"
    stereo.mkdir()
    assert main([*argv, "--out", str(stereo / "rig.yaml"), "--rectified", str(stereo / "rect")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("circcal calibrate-rig: no stereo rectification: cameras 'left'")
    assert "nothing written (--out .yaml, --rectified need it" in err[0] and list(stereo.iterdir()) == []


def test_calibrate_rig_shows_progress_after_detection(fixture_dir, tmp_path, capsys):
    """Beyond the detector's bars: the joint solve's re-correction rounds and the cross-validation's halves (with
    200 images they took ~9 s without a word)."""
    cams = ["--camera", f"left={fixture_dir / 'left'}", "--camera", f"right={fixture_dir / 'right'}"]
    assert main(["calibrate-rig", *cams, "--lens", "right=rational", *GRID, "--out", str(tmp_path / "r.json")]) == 0
    err = capsys.readouterr().err
    assert "rig joint solve: 100%" in err and "rig cross-validation: 100%" in err, err[-500:]


def test_the_shared_field_of_every_pair_that_shares_an_instant():
    """The chain rig (c shares the board with b only): the field a-b and b-c share is reported, a-c's is not (it
    was the first two cameras' only)."""
    from circcal.commands.rig import summary_lines
    from circcal.fixtures.rig import rig_observations
    from circcal.rig import calibrate_rig_points
    from circcal.solver import CalibrationOptions

    sc = rig_scenario("chain")
    sizes = {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    cal = calibrate_rig_points(rig_observations(sc, 0.05, 0), sizes, CalibrationOptions(), board=sc.board)
    text = "\n".join(summary_lines(cal, {n: [] for n in sc.rig.names}))
    assert "the field a and b share" in text and "the field b and c share" in text
    assert "the field a and c share" not in text


def test_triangulate_refuses_points_files_without_points(tmp_path, capsys):
    rig_file = tmp_path / "rig.json"
    rig_file.write_text(json.dumps(rig_scenario("two").rig.to_dict()))
    (tmp_path / "l.csv").write_text("u,v\n")
    (tmp_path / "r.json").write_text("[]")
    argv = ["triangulate", "--rig", str(rig_file), "--points", f"left={tmp_path / 'l.csv'}"]
    argv += ["--points", f"right={tmp_path / 'r.json'}", "--pixel-sigma", "0.1"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--points: the files hold no points" in err[0], err


def test_triangulate_warns_when_the_points_are_noisier_than_the_sigma_assumed(tmp_path, capsys):
    """A rig whose own noise is 0.0024 px (its RMS per point 0.0034 px) and points of 0.2 px noise: one line on stderr
    naming --pixel-sigma and the points' noise, estimated within 20% of 0.2; none with --pixel-sigma 0.2, none for
    points at the rig's own noise."""
    import dataclasses

    sc, _, px = _true_pixels(4)
    rig_file = tmp_path / "rig.json"
    rig_file.write_text(json.dumps(dataclasses.replace(sc.rig, rms_px=0.0034).to_dict()))
    rng = np.random.default_rng(1)
    for noise, given, warned in ((0.2, [], True), (0.2, ["--pixel-sigma", "0.2"], False), (0.0024, [], False)):
        noisy = {n: p + rng.normal(0.0, noise, p.shape) for n, p in px.items()}
        folder = tmp_path / f"{noise}-{len(given)}"
        folder.mkdir()
        assert main(["triangulate", "--rig", str(rig_file), *_write_points(folder, noisy), *given]) == 0
        err = capsys.readouterr().err.strip().splitlines()
        if not warned:
            assert err == [], err
            continue
        assert len(err) == 1 and "--pixel-sigma" in err[0] and "0.0024 px assumed (the rig's own" in err[0], err
        stated = float(re.search(r"reproject with ([\d.]+) px of noise per coordinate", err[0]).group(1))
        assert 0.8 * noise < stated < 1.2 * noise, stated
