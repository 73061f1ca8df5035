"""Perturbations keep the geometric truth; scenarios are deterministic, cached and self-describing."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from circcal.board import Board
from circcal.fixtures.cache import fixture_dir, render_fixture
from circcal.fixtures.perturb import KINDS, apply_perturbations, validate
from circcal.fixtures.poses import pose_looking_at
from circcal.fixtures.render import Levels, render_coverage
from circcal.fixtures.scenarios import SCENARIOS, get_scenario
from circcal.fixtures.truth import load_truth
from circcal.model import Camera, project

CAM = Camera(320, 240, 300.0, 300.0, 159.5, 119.5, [0, 0, 0, 0, 0])
ONE_DOT = Board(2, 2, 30.0, 10.0, margin_mm=20.0)


@pytest.fixture(scope="module")
def single():
    """A 2x2 board seen head-on: linear image, board mask, exact dark-weighted centroid of dot 0."""
    rvec, tvec = pose_looking_at(CAM, ONE_DOT, distance_mm=150.0)
    bc, dc = render_coverage(CAM, ONE_DOT, rvec, tvec)
    lv = Levels()
    img = lv.background + bc * (lv.board - lv.background) - dc * (lv.board - lv.dark)
    return img, bc > 0.5, project(ONE_DOT.object_points(), rvec, tvec, CAM)


def _dark_centroid(img: np.ndarray, centre: np.ndarray, r: int, white: float) -> np.ndarray:
    u0, v0 = np.rint(centre).astype(int)
    w = np.clip(white - img[v0 - r : v0 + r + 1, u0 - r : u0 + r + 1], 0, None)
    vv, uu = np.mgrid[v0 - r : v0 + r + 1, u0 - r : u0 + r + 1]
    return np.array([(w * uu).sum() / w.sum(), (w * vv).sum() / w.sum()])


@pytest.mark.parametrize(
    "step",
    [
        {"kind": "gaussian_blur", "sigma_px": 2.0},
        {"kind": "defocus", "radius_px": 3.5},
        {"kind": "motion_blur", "length_px": 7.0, "angle_deg": 33.0},
    ],
)
def test_blur_does_not_move_dots(single, step):
    """Centred symmetric PSFs keep the dark-weighted centroid of a dot (to 1e-9 px in float before quantisation)."""
    img, mask, centres = single
    from circcal.fixtures import perturb

    kernel_img = {
        "gaussian_blur": lambda: cv2.GaussianBlur(img, (0, 0), step["sigma_px"]),
        "defocus": lambda: cv2.filter2D(img, -1, perturb._disk_kernel(step["radius_px"])),
        "motion_blur": lambda: cv2.filter2D(img, -1, perturb._motion_kernel(step["length_px"], step["angle_deg"])),
    }
    blurred = kernel_img[step["kind"]]()
    before = _dark_centroid(img, centres[0], 18, 0.9)
    after = _dark_centroid(blurred, centres[0], 18, 0.9)
    assert np.max(np.abs(after - before)) < 1e-9
    assert np.max(np.abs(blurred - img)) > 0.1  # and the blur really happened


def test_every_kind_applies_and_is_seeded(single):
    img, mask, _ = single
    all_steps = [
        {"kind": "clutter", "n": 3, "radius_px": (3, 6)},
        {"kind": "uneven"},
        {"kind": "vignetting"},
        {"kind": "strong", "gain": 1.2},
        {"kind": "weak"},
        {"kind": "gaussian_blur", "sigma_px": 1.0},
        {"kind": "defocus", "radius_px": 1.5},
        {"kind": "motion_blur", "length_px": 3.0},
        {"kind": "noise", "sigma": 0.01, "full_well": 1000},
        {"kind": "occlusion", "fraction": 0.2, "side": "left"},
    ]
    scene = [
        {"kind": "bar", "width_frac": 0.05},
        {"kind": "hand", "side": "right", "size_frac": 0.2},
        {"kind": "second_board", "rows": 2, "cols": 2, "pitch_px": 8.0, "diameter_px": 4.0},
        {"kind": "logo", "n": 5, "radius_px": 6.0, "dot_px": 3.0},
    ]
    assert {s["kind"] for s in all_steps + scene} | {"jpeg"} == set(KINDS)
    a, occ, jpg = apply_perturbations(img, all_steps, 5, board_mask=mask)
    b, _, _ = apply_perturbations(img, all_steps, 5, board_mask=mask)
    c, _, _ = apply_perturbations(img, all_steps, 6, board_mask=mask)
    assert a.dtype == np.uint8 and np.array_equal(a, b) and not np.array_equal(a, c) and jpg is None
    assert occ is not None and occ[:, 0].all() and not occ[:, -1].any()
    for step in scene:  # each scene object is drawn, seeded; occluders say what they hide
        one, occ1, _ = apply_perturbations(img, [step], 3, board_mask=mask)
        assert np.array_equal(one, apply_perturbations(img, [step], 3, board_mask=mask)[0])
        changed = one != apply_perturbations(img, [], 3)[0]
        assert changed.any()
        if step["kind"] in ("bar", "hand"):
            assert occ1 is not None and (occ1 & mask).any() and not (changed & ~occ1).any()
        else:  # drawn off the board
            assert occ1 is None and not (changed & mask).any()
    j, _, jpg = apply_perturbations(img, [{"kind": "jpeg", "quality": 60}], 0)
    assert jpg[:2] == b"\xff\xd8" and np.array_equal(cv2.imdecode(np.frombuffer(jpg, np.uint8), 0), j)
    s16, _, _ = apply_perturbations(img, [], 0, bits=16)
    assert s16.dtype == np.uint16


def test_clutter_stays_off_the_board(single):
    img, mask, _ = single
    out, _, _ = apply_perturbations(
        img, [{"kind": "clutter", "n": 6, "radius_px": (3, 8), "level": 0.0}], 1, board_mask=mask
    )
    clean = apply_perturbations(img, [], 1)[0]
    changed = out != clean
    assert changed.any() and not (changed & mask).any()


def test_strong_clips_and_weak_compresses(single):
    img, mask, _ = single
    strong = apply_perturbations(img, [{"kind": "strong", "gain": 1.6}], 0)[0]
    weak = apply_perturbations(img, [{"kind": "weak", "contrast": 0.2, "offset": 0.05}], 0)[0]
    assert strong[mask].max() == 255 and (strong == 255).sum() > 0.5 * mask.sum()
    assert int(weak.max()) - int(weak.min()) <= round(0.2 * 0.8 * 255) + 1


def test_unknown_perturbation_is_refused():
    with pytest.raises(ValueError, match="unknown perturbation 'fog'.*known: clutter"):
        validate([{"kind": "fog"}])


def test_unknown_scenario_lists_the_catalogue():
    with pytest.raises(ValueError, match="unknown scenario 'nope'; known scenarios: paper, "):
        get_scenario("nope")
    with pytest.raises(ValueError, match="has no variant 'sunny'"):
        fixture_dir("paper", "sunny")


def test_catalogue_has_the_required_sets():
    need = {"paper", "wide", "tilted-large-dots", "asymmetric", "small-noisy"}
    assert need <= set(SCENARIOS)
    p = SCENARIOS["paper"]
    assert (p.board.rows, p.board.cols, p.board.diameter_mm, p.board.pitch_mm) == (7, 7, 5.0, 10.0)
    assert (p.camera.width, p.camera.height, p.n_views) == (1920, 1080, 14) and abs(p.camera.fx - 4900) < 50
    assert list(p.variants) == ["normal", "uneven", "strong", "weak"]
    assert SCENARIOS["asymmetric"].board.layout == "asymmetric" and SCENARIOS["asymmetric"].board.pattern_size == (
        4,
        11,
    )
    assert SCENARIOS["wide"].camera.dist[0] == pytest.approx(-0.3)


def test_truth_file_is_exact_and_complete(tmp_path):
    """A rendered set: truth.json schema, centres = exact projections, images on disk, deterministic pixels."""
    sc = SCENARIOS["small-noisy"]
    dirs = render_fixture(sc, tmp_path / "a", ["noisy"], progress=False)
    truth = json.loads((dirs["noisy"] / "truth.json").read_text())
    assert set(truth["camera"]) == {"width", "height", "fx", "fy", "cx", "cy", "dist"}
    assert {"rows", "cols", "pitch_mm", "diameter_mm", "layout"} <= set(truth["board"])
    assert len(truth["views"]) == sc.n_views
    t = load_truth(dirs["noisy"])
    for v in t.views:
        assert v.image.exists()
        assert np.max(np.abs(project(t.board.object_points(), v.rvec, v.tvec, t.camera) - v.centres)) == 0.0
        assert v.visible.all()
        img = cv2.imread(str(v.image), cv2.IMREAD_UNCHANGED)
        assert img.shape == (t.camera.height, t.camera.width) and img.dtype == np.uint8
    again = render_fixture(sc, tmp_path / "b", ["noisy"], progress=False)
    for f in ("view_00.png", "view_07.png"):
        assert (dirs["noisy"] / f).read_bytes() == (again["noisy"] / f).read_bytes()


def test_partial_scenario_marks_hidden_points():
    t = load_truth(fixture_dir("partial", "occlusion"))
    hidden = sum(int((~v.visible).sum()) for v in t.views)
    assert 0 < hidden < sum(len(v.visible) for v in t.views)


def test_marker_scenarios_keep_the_printed_pattern():
    # the patterns are written into the scenarios (a printed board keeps its pattern): they are circcal's own
    from circcal.markers import PATTERN_MARKER_SCALE, marker_pattern

    for name in ("partial", "markers", "occluded", "distractors"):
        b = SCENARIOS[name].board
        assert b.markers == marker_pattern(b.rows, b.cols, b.layout), name
        assert b.marker_diameter_mm == pytest.approx(PATTERN_MARKER_SCALE * b.diameter_mm)
    o = SCENARIOS["origin"].board
    assert o.markers == ((o.rows - 1) * o.cols,) and o.marker_diameter_mm == 2 * o.diameter_mm


def test_corner_views_are_partly_out_of_frame():
    from circcal.fixtures.poses import out_of_frame_share

    sc = SCENARIOS["markers"]
    poses = sc.poses()
    assert len(poses) == sc.n_views + sc.corner_views and sc.view_kind(sc.n_views) == "corner"
    shares = [out_of_frame_share(sc.camera, sc.board, *p) for p in poses]
    assert all(s == 0.0 for s in shares[: sc.n_views])
    # the drawn share, to the sampling of the measure (1/24 of a side)
    assert all(sc.corner_out[0] - 0.01 <= s <= sc.corner_out[1] + 0.01 for s in shares[sc.n_views :]), shares
    t = load_truth(fixture_dir("markers", "clean"))
    assert [v.kind for v in t.views] == ["full"] * sc.n_views + ["corner"] * sc.corner_views
    assert all(not v.visible.all() for v in t.views[sc.n_views :])


def test_fixture_cache_hits(tmp_path, monkeypatch):
    monkeypatch.setenv("CIRCCAL_CACHE", str(tmp_path))
    d = fixture_dir("small-noisy", "noisy")
    stamp = (d / "truth.json").stat().st_mtime_ns
    assert fixture_dir("small-noisy", "noisy") == d
    assert fixture_dir("small-noisy", "very-noisy").exists()  # rendered with the first call (shared geometry)
    assert (d / "truth.json").stat().st_mtime_ns == stamp
    assert d.name.startswith("small-noisy-noisy-") and d.parent == tmp_path / "fixtures"


def test_cli_render(tmp_path, monkeypatch, capsys):
    from circcal.cli import main

    monkeypatch.setenv("CIRCCAL_CACHE", str(tmp_path / "cache"))
    assert main(["render", "small-noisy", "--variant", "noisy", "--out", str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "truth.json").exists() and (tmp_path / "out" / "view_13.png").exists()
    assert main(["render", "bogus", "--out", str(tmp_path / "x")]) == 2
    assert "known scenarios: paper" in capsys.readouterr().err
    assert main(["render", "--list"]) == 0


def test_lens_model_scenarios():
    """fisheye: a ~170 deg equidistant lens, boards out to 64 deg (centre) / 80 deg (farthest dot), every dot in
    frame and in front; rational-wide: a lens OpenCV's 5 coefficients cannot fit (0.13 px RMS on exact
    projections of its views) and the rational model can (float32 rounding)."""
    from circcal.rotation import rodrigues

    fe = SCENARIOS["fisheye"]
    assert fe.camera.lens == "fisheye" and set(fe.variants) == {"clean", "perturbed"}
    centre_deg, far_deg = [], []
    for rvec, tvec in fe.poses():
        P = fe.board.object_points() @ rodrigues(rvec).T + tvec
        deg = np.degrees(np.arctan2(np.hypot(P[:, 0], P[:, 1]), P[:, 2]))
        c = P.mean(axis=0)
        centre_deg.append(np.degrees(np.arctan2(np.hypot(c[0], c[1]), c[2])))
        far_deg.append(deg.max())
        q = project(fe.board.object_points(), rvec, tvec, fe.camera)
        assert np.all(q >= 0) and np.all(q[:, 0] <= fe.camera.width - 1) and np.all(q[:, 1] <= fe.camera.height - 1)
    assert 60.0 < max(centre_deg) < 70.0 and 78.0 < max(far_deg) < 85.0
    # the lens sees ~170 deg across the image's width
    from circcal.model import unproject

    edge = unproject(np.array([[0.0, fe.camera.cy], [fe.camera.width - 1.0, fe.camera.cy]]), fe.camera)
    across = np.degrees(np.arccos(np.clip(edge[0] @ edge[1], -1, 1)))
    assert 160.0 < across < 180.0

    rw = SCENARIOS["rational-wide"]
    assert rw.camera.lens == "rational" and set(rw.variants) == {"clean", "perturbed"}
    obj = [rw.board.object_points().astype(np.float32)] * len(rw.poses())
    img = [project(rw.board.object_points(), rv, tv, rw.camera).astype(np.float32) for rv, tv in rw.poses()]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    rms5 = cv2.calibrateCamera(obj, img, (rw.camera.width, rw.camera.height), None, None, criteria=crit)[0]
    rms8 = cv2.calibrateCamera(
        obj, img, (rw.camera.width, rw.camera.height), None, None, flags=cv2.CALIB_RATIONAL_MODEL, criteria=crit
    )[0]
    assert rms5 > 0.1 and rms8 < 1e-3


def test_truth_json_names_the_lens(tmp_path):
    """truth.json carries the lens of a camera other than opencv5, and load_truth reads it back."""
    sc = SCENARIOS["fisheye"]
    import dataclasses

    one = dataclasses.replace(sc, n_views=1)
    dirs = render_fixture(one, tmp_path, ["clean"], progress=False)
    truth = json.loads((dirs["clean"] / "truth.json").read_text())
    assert truth["camera"]["lens"] == "fisheye" and len(truth["camera"]["dist"]) == 4
    t = load_truth(dirs["clean"])
    assert t.camera.lens == "fisheye" and np.array_equal(t.camera.intrinsics, sc.camera.intrinsics)
    v = t.views[0]
    assert np.max(np.abs(project(t.board.object_points(), v.rvec, v.tvec, t.camera) - v.centres)) == 0.0
