"""Reference-calibrator adapters (validators/*) against cv2.calibrateCamera on identical observations.

Bars: on the same centres (14 tilted views of a 7x7 board, 0.05 px noise, float32-representable so OpenCV sees exactly
what the others see) opencv, kornia, pycolmap and mrcal "fair" reach cv2.calibrateCamera's calibration to <= 1e-6 px
(mrcal <= 1e-4 px) of projection difference over the whole imager, and, where they state standard deviations, the
same ones to 1%. mrcal "default" (board warp, regularisation, outlier rejection) is a different estimator: its
difference is measured and printed, not asserted small. Bad input gives a clear per-reference status.
"""

from __future__ import annotations

import importlib.metadata
import math

import numpy as np
import pytest
from conftest import skip_unless_available

from circcal.analysis.compare import param_diff, projection_diff
from circcal.board import Board
from circcal.model import Camera, project
from circcal.rotation import rodrigues
from circcal.validators import registry
from circcal.validators.base import BaseCalibrator, run_safely
from circcal.validators.reference_result import ReferenceResult

# kornia's import triggers torch's own deprecation notice for torch.jit.script: not ours to fix
pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.script` is deprecated:DeprecationWarning")

TRUE_CAMERA = Camera(1920, 1080, 1500.0, 1502.0, 955.0, 545.0, np.array([-0.12, 0.08, 4e-4, -3e-4, -0.02]))
BOARD = Board(7, 7, 10.0, 5.0)


def make_problem(
    seed: int = 0, n_views: int = 14, noise: float = 0.05, board: Board = BOARD, camera: Camera = TRUE_CAMERA
) -> dict:
    """Synthetic observations: ``n_views`` poses tilted up to 35 deg about x and y, board 180-260 mm away, spread
    over the image; centres projected with circcal.model.project plus Gaussian noise, rounded to float32."""
    rng = np.random.default_rng(seed)
    P = board.object_points()
    c = board.centre_mm()
    obj, img, rvecs, tvecs = [], [], [], []
    while len(obj) < n_views:
        tilt = np.deg2rad(rng.uniform(-35.0, 35.0, 2))
        r = np.array([tilt[0], tilt[1], rng.uniform(-0.3, 0.3)])
        z = rng.uniform(180.0, 260.0)
        centre = np.array([rng.uniform(-0.5, 0.5) * z * 960 / 1500, rng.uniform(-0.5, 0.5) * z * 540 / 1500, z])
        t = centre - rodrigues(r) @ c
        q = project(P, r, t, camera) + rng.normal(0.0, noise, (len(P), 2))
        if np.any((q < 0) | (q > [camera.width - 1, camera.height - 1])):
            continue  # a camera cannot observe a point outside its image (every solver refuses one)
        obj.append(P.astype(np.float32).astype(np.float64))
        img.append(q.astype(np.float32).astype(np.float64))
        rvecs.append(r)
        tvecs.append(t)
    return {
        "object_points": obj,
        "image_points": img,
        "image_size": (camera.width, camera.height),
        "rvecs": np.array(rvecs),
        "tvecs": np.array(tvecs),
    }


def cv2_calibrate(problem: dict, *, fix_k3: bool = False) -> tuple[Camera, dict]:
    """cv2.calibrateCameraExtended directly (not through the adapter): the yardstick."""
    import cv2

    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    n_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # multi-threaded, OpenCV's answer varies run to run by ~2e-7 px
    try:
        out = cv2.calibrateCameraExtended(
            [o.astype(np.float32).reshape(-1, 1, 3) for o in problem["object_points"]],
            [p.astype(np.float32).reshape(-1, 1, 2) for p in problem["image_points"]],
            problem["image_size"],
            None,
            None,
            flags=flags,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-16),
        )
    finally:
        cv2.setNumThreads(n_threads)
    _, K, d, _, _, std, _, _ = out
    w, h = problem["image_size"]
    cam = Camera(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2], np.asarray(d).reshape(-1)[:5])
    names = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
    return cam, {n: float(s) for n, s in zip(names, np.asarray(std).reshape(-1))}


@pytest.fixture(scope="module")
def problem() -> dict:
    return make_problem(0)


@pytest.fixture(scope="module")
def cv_ref(problem):
    return {False: cv2_calibrate(problem), True: cv2_calibrate(problem, fix_k3=True)}


@pytest.fixture(scope="module")
def mrcal_results(problem):
    from circcal.validators.mrcal import MrcalCalibrator

    cal = MrcalCalibrator()
    skip_unless_available(cal)
    return {
        r.mode: r
        for r in cal.calibrate_modes(
            problem["object_points"], problem["image_points"], problem["image_size"], modes=("fair", "default")
        )
    }


# name, factory kwargs, fix_k3 of the cv2 yardstick, projection tolerance px
CASES = [
    ("opencv", {}, False, 1e-6),
    ("opencv", {"fix_k3": True}, True, 1e-6),
    ("kornia", {}, False, 1e-6),
    ("kornia", {"fix_k3": True}, True, 1e-6),
    ("pycolmap", {"model": "FULL_OPENCV"}, False, 1e-6),
    ("pycolmap", {"model": "OPENCV"}, True, 1e-6),
]


def _std_rel(std: dict, ref: dict) -> dict:
    return {k: abs(std[k] / ref[k] - 1.0) for k in ref if ref[k] > 0}


@pytest.mark.parametrize(
    "name,kwargs,fix_k3,tol",
    CASES,
    ids=["opencv", "opencv-FIX_K3", "kornia", "kornia-fix_k3", "pycolmap-FULL_OPENCV", "pycolmap-OPENCV-vs-FIX_K3"],
)
def test_same_observations_same_calibration(problem, cv_ref, name, kwargs, fix_k3, tol):
    cal = registry.get(name, **kwargs)
    skip_unless_available(cal)
    res = cal.calibrate_observations(problem["object_points"], problem["image_points"], problem["image_size"])
    assert res.status == "ok", res.message
    ref_cam, ref_std = cv_ref[fix_k3]
    d = projection_diff(ref_cam, res.camera)
    print(f"\n{name} {kwargs}: projection difference vs cv2 max {d['max_px']:.3g} px, rms {d['rms_px']:.3g} px")
    assert d["n_invalid"] == 0
    assert d["max_px"] <= tol
    # the truth is near: 0.05 px noise gives fx within a few of its ~0.46 px sigmas
    assert abs(res.camera.fx - TRUE_CAMERA.fx) < 5 * ref_std["fx"]
    assert res.errors["n_points"] == 14 * 49
    assert res.rvecs.shape == (14, 3) and len(res.residuals) == 14
    # std devs: where the reference states them, they agree with OpenCV's to 1 %
    assert res.std is not None, f"{name} should state standard deviations"
    rel = _std_rel(res.std, ref_std)
    print(f"{name}: worst std-dev relative difference vs cv2 {max(rel.values()):.2e}")
    assert max(rel.values()) < 0.01
    if fix_k3:
        assert res.camera.dist[4] == 0.0 and res.std["k3"] == 0.0
        assert "k3" in res.extra["fixed"]


def test_mrcal_fair_equals_opencv(problem, cv_ref, mrcal_results):
    res = mrcal_results["fair"]
    assert res.status == "ok", res.message
    assert res.version and res.version != "unavailable"
    d = projection_diff(cv_ref[False][0], res.camera)
    print(f"\nmrcal {res.version} fair: projection difference vs cv2 max {d['max_px']:.3g} px, rms {d['rms_px']:.3g}")
    assert d["max_px"] <= 1e-4
    # mrcal's own residuals equal ours (same flat-board model): the pose conversion is right
    assert res.extra["max_abs_residual_diff_vs_mrcal_px"] < 1e-6
    # RMS conventions: mrcal's per-coordinate RMS equals ours per coordinate
    assert res.errors["rms_per_coord_px"] == pytest.approx(res.extra["rms_per_coord_px_mrcal"], rel=1e-6)
    assert res.errors["rms_per_point_px"] == pytest.approx(math.sqrt(2) * res.extra["rms_per_coord_px_mrcal"], rel=1e-6)
    assert np.max(np.abs(res.tvecs - problem["tvecs"])) < 2.0  # mm, against the true poses


def test_mrcal_default_measured(cv_ref, mrcal_results):
    res = mrcal_results["default"]
    assert res.status == "ok", res.message
    ref_cam, ref_std = cv_ref[False]
    raw = projection_diff(ref_cam, res.camera)
    fit = projection_diff(ref_cam, res.camera, fit=True, distance=None)
    pd = param_diff(ref_cam, res.camera, ref_std)
    print(
        f"\nmrcal default vs cv2: projection max {raw['max_px']:.3f} px rms {raw['rms_px']:.3f} px; with implied "
        f"rotation max {fit['max_px']:.3f} rms {fit['rms_px']:.3f} px; fx {pd['fx']['diff']:+.3f} px "
        f"({pd['fx']['diff_sigmas']:+.2f} sigma); warp {res.extra['calobject_warp']}; "
        f"outliers {res.extra['n_outliers']}"
    )
    # a different estimator: it solved a board warp, and its answer moved off the plain least-squares one
    assert res.extra["calobject_warp"] is not None and len(res.extra["calobject_warp"]) == 2
    assert raw["max_px"] > 1e-4
    assert np.isfinite(fit["max_px"])


def test_kornia_batch_matches_single_problems(cv_ref, problem):
    from circcal.validators.kornia import KorniaCalibrator

    cal = KorniaCalibrator()
    skip_unless_available(cal)
    p2 = make_problem(1, n_views=9, noise=0.1)
    p2["object_points"] = [o[:-3] for o in p2["object_points"]]  # fewer views and points: padding is exercised
    p2["image_points"] = [q[:-3] for q in p2["image_points"]]
    bad = dict(p2, image_points=p2["image_points"][:-1])  # mismatched: fails alone, others still solve
    out = cal.calibrate_batch([problem, p2, bad])
    assert [r.status for r in out] == ["ok", "ok", "failed"]
    assert "object-point sets" in out[2].message
    for prob, res in ((problem, out[0]), (p2, out[1])):
        ref_cam, ref_std = cv2_calibrate(prob)
        d = projection_diff(ref_cam, res.camera)
        print(f"\nkornia batch: max {d['max_px']:.3g} px vs cv2 ({len(prob['object_points'])} views)")
        assert d["max_px"] <= 1e-6
        assert max(_std_rel(res.std, ref_std).values()) < 0.01


def test_circcal_solver_equals_opencv(problem, cv_ref):
    """circcal's own solver (circcal/calibrate.py) against the same yardstick."""
    calibrate = pytest.importorskip("circcal.solver").calibrate
    res = calibrate(problem["object_points"], problem["image_points"], problem["image_size"])
    ref_cam, ref_std = cv_ref[False]
    d = projection_diff(ref_cam, res.camera)
    print(f"\ncirccal.calibrate vs cv2: max {d['max_px']:.3g} px")
    assert d["max_px"] <= 1e-6
    assert max(_std_rel(res.std, ref_std).values()) < 0.01


# ---------------------------------------------------------------------------------------------------------------------
# images: OpenCV's own detector on the real photographs (baselines in their SOURCE.txt)
# ---------------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "folder,board,n_found,rms,fx",
    [
        ("boofcv_sony_hx5v_circle_regular_10x8", Board(8, 10, 25.0, 15.0), 6, 0.4755, 456.6),
        ("boofcv_sony_hx5v_circle_asym_4x5", Board(5, 4, 30.0, 20.0, layout="asymmetric"), 9, 0.1830, 701.1),
    ],
)
def test_opencv_images_reproduce_baseline(realdata, folder, board, n_found, rms, fx):
    paths = sorted((realdata / folder).glob("*.jpg"))
    res = registry.get("opencv").calibrate_images(paths, board)
    assert res.status == "ok", res.message
    assert len(res.views) == n_found
    assert res.errors["rms_per_point_px"] == pytest.approx(rms, abs=5e-4)
    assert res.camera.fx == pytest.approx(fx, abs=0.05)
    assert res.extra["missed"] == {}


def test_mrcal_on_real_detections(realdata):
    """OpenCV's detections of the real symmetric 10x8 set: mrcal fair reaches OpenCV's calibration."""
    from circcal.validators.mrcal import MrcalCalibrator

    cal = MrcalCalibrator()
    skip_unless_available(cal)
    board = Board(8, 10, 25.0, 15.0)
    cv = registry.get("opencv")
    det = cv.detect(sorted((realdata / "boofcv_sony_hx5v_circle_regular_10x8").glob("*.jpg")), board)
    obj = [board.object_points()] * len(det["image_points"])
    ref = cv.calibrate_observations(obj, det["image_points"], det["image_size"])
    res = cal.calibrate_observations(obj, det["image_points"], det["image_size"], mode="fair")
    assert res.status == "ok", res.message
    d = projection_diff(ref.camera, res.camera)
    print(f"\nmrcal fair vs opencv on real detections: max {d['max_px']:.3g} px")
    assert d["max_px"] <= 1e-4


@pytest.mark.parametrize("name", ["mrcal", "kornia", "pycolmap"])
def test_no_detector_is_unsupported(name, tmp_path):
    res = registry.get(name).calibrate_images([tmp_path / "a.png"], BOARD)
    assert res.status in ("unsupported", "unavailable")
    if res.status == "unsupported":
        assert "detector" in res.message


# ---------------------------------------------------------------------------------------------------------------------
# bad input: a clear status per reference, the others still run
# ---------------------------------------------------------------------------------------------------------------------
def test_missing_mrcal_is_unavailable(monkeypatch, problem):
    from circcal.validators.mrcal import NOT_FOUND_MESSAGE, MrcalCalibrator

    monkeypatch.setenv("CIRCCAL_MRCAL_PYTHON", "/nonexistent")
    cal = MrcalCalibrator()
    ok, why = cal.available()
    assert not ok and NOT_FOUND_MESSAGE in why and "/nonexistent" in why
    res = cal.calibrate_observations(problem["object_points"], problem["image_points"], problem["image_size"])
    assert res.status == "unavailable"
    assert "apt-get install -y mrcal python3-mrcal" in res.message
    assert registry.all_available()["mrcal"][0] is False
    # the others are unaffected
    assert (
        registry.get("opencv")
        .calibrate_observations(problem["object_points"], problem["image_points"], problem["image_size"])
        .status
        == "ok"
    )


def test_asymmetric_grid_fitted_by_mrcal():
    """One rule for asymmetric boards across validate and convert (issue 36): mrcal fits them (its board is the
    staggered points' full lattice with the absent points unobserved), as the .cameramodel export does."""
    from circcal.validators.mrcal import MrcalCalibrator, board_lattice

    board = Board(11, 4, 10.0, 5.0, layout="asymmetric")
    p = make_problem(2, n_views=6, board=board)
    cal = MrcalCalibrator()
    skip_unless_available(cal)
    res = cal.calibrate_observations(p["object_points"], p["image_points"], p["image_size"])
    assert res.status == "ok", res.message
    # the lattice mapping itself: symmetric boards map, with the right size and pitch
    lat = board_lattice([Board(8, 10, 25.0, 15.0).object_points()])
    assert (lat["width_n"], lat["height_n"], lat["spacing"]) == (10, 8, 25.0)
    # and OpenCV handles the asymmetric set
    assert (
        registry.get("opencv").calibrate_observations(p["object_points"], p["image_points"], p["image_size"]).status
        == "ok"
    )


class _Crashing(BaseCalibrator):
    name = "crashing"

    def _calibrate(self, object_points, image_points, image_size, *, mode, initial):
        raise ZeroDivisionError("boom inside the reference")


class _Diverging(BaseCalibrator):
    name = "diverging"

    def _calibrate(self, object_points, image_points, image_size, *, mode, initial):
        cam = Camera(*image_size, 1e6, 1e6, 0.0, 0.0, np.array([50.0, 0, 0, 0, 0]))
        v = len(object_points)
        return self.finish(
            mode, cam, np.zeros((v, 3)), np.tile([0, 0, 100.0], (v, 1)), object_points, image_points, 0.0
        )


class _Missing(BaseCalibrator):
    name = "missing"

    def _available(self):
        return False, "not installed: pip install missing-ref"


def test_crash_divergence_and_missing_each_get_a_status(problem):
    args = (problem["object_points"], problem["image_points"], problem["image_size"])
    crash = _Crashing().calibrate_observations(*args)
    assert crash.status == "failed" and "ZeroDivisionError: boom inside the reference" in crash.message
    div = _Diverging().calibrate_observations(*args)
    assert div.status == "failed" and div.message.startswith("diverged")
    miss = _Missing().calibrate_observations(*args)
    assert miss.status == "unavailable" and "pip install missing-ref" in miss.message
    # run_safely itself never lets an exception through
    r = run_safely(lambda: 1 / 0, name="x")
    assert r.status == "failed" and "ZeroDivisionError" in r.message
    assert run_safely(lambda: None, name="x", mode="bogus").status == "failed"


def test_bad_input_reported_by_every_reference(problem):
    obj = problem["object_points"]
    img = problem["image_points"][:-1]  # one view short
    for name in ["opencv", "kornia", "pycolmap"]:
        res = registry.get(name).calibrate_observations(obj, img, problem["image_size"])
        assert res.status in ("failed", "unavailable")
        if res.status == "failed":
            assert "14 object-point sets but 13 image-point sets" in res.message
    nan_img = [q.copy() for q in problem["image_points"]]
    nan_img[3][5] = np.nan
    res = registry.get("opencv").calibrate_observations(obj, nan_img, problem["image_size"])
    assert res.status == "failed" and "view 3" in res.message and "non-finite" in res.message
    res = registry.get("opencv").calibrate_observations(
        obj, problem["image_points"], problem["image_size"], mode="nonsense"
    )
    assert res.status == "failed" and "unknown mode" in res.message


# ---------------------------------------------------------------------------------------------------------------------
# registry: built-ins and entry-point plug-ins
# ---------------------------------------------------------------------------------------------------------------------
class _EP:
    def __init__(self, name, obj):
        self.name, self.value, self._obj = name, f"tests:{name}", obj

    def load(self):
        return self._obj


def test_registry_builtins_and_plugins(monkeypatch, problem):
    real = importlib.metadata.entry_points

    def fake(**kw):
        if kw.get("group") == registry.ENTRY_POINT_GROUP:
            return [_EP("crashing", _Crashing), _EP("opencv", _Crashing)]
        return real(**kw)

    monkeypatch.setattr(importlib.metadata, "entry_points", fake)
    assert registry.names()[:4] == ["opencv", "mrcal", "kornia", "pycolmap"]
    assert "crashing" in registry.names()
    assert "opencv" in registry.problems()  # a plug-in cannot shadow a built-in
    assert type(registry.get("opencv")).__name__ == "OpenCVCalibrator"
    with pytest.raises(KeyError, match="unknown reference calibrator 'nope'"):
        registry.get("nope")
    # run every reference on the same problem: the crashing plug-in fails, the others are unaffected
    results = {
        n: registry.get(n).calibrate_observations(
            problem["object_points"][:5], problem["image_points"][:5], problem["image_size"]
        )
        for n in ["opencv", "crashing"]
    }
    assert results["crashing"].status == "failed" and results["opencv"].status == "ok"
    avail = registry.all_available()
    assert avail["opencv"] == (True, "") and avail["crashing"][0] is True
    assert isinstance(results["opencv"], ReferenceResult)
    assert results["opencv"].to_dict()["camera"]["fx"] == pytest.approx(results["opencv"].camera.fx)


def test_a_reference_that_stops_short_passes_only_above_circcals_cost():
    """lensboy (checks.STOPS_SHORT) beyond 1e-6 px but within its own bound passes only with its cost at or above
    circcal's (it stopped short of the minimum, the note says by how much); below circcal's it fails (circcal missed
    the minimum); within 1e-6 px the costs are not consulted; any other reference within its bound passes as before."""
    from circcal.validators.checks import SOLVER_LENSBOY_PX, solver_agreement

    def ref(name: str, ssr: float) -> ReferenceResult:
        return ReferenceResult(name, "1", "fair", "ok", residuals=[np.full((50, 2), np.sqrt(ssr / 100.0))])

    base = 0.5
    short = solver_agreement("lensboy", ref("lensboy", base * (1 + 3e-7)), 3e-3, base, SOLVER_LENSBOY_PX)
    assert short.passed and "stopped short of the minimum" in short.note and "3e-07" in short.note
    lower = solver_agreement("lensboy", ref("lensboy", base * (1 - 3e-7)), 3e-3, base, SOLVER_LENSBOY_PX)
    assert not lower.passed and "circcal missed the minimum" in lower.note
    assert solver_agreement("lensboy", ref("lensboy", base * (1 - 3e-7)), 5e-7, base, SOLVER_LENSBOY_PX).passed
    assert not solver_agreement("lensboy", ref("lensboy", base * (1 + 3e-7)), 2e-2, base, SOLVER_LENSBOY_PX).passed
    assert solver_agreement("other", ref("other", base * (1 - 3e-7)), 3e-3, base, 1e-2).passed


def test_pycolmap_leaves_out_single_view_points_and_equals_circcal_on_the_rest():
    """COLMAP's bundle adjustment takes no single-view track: a board point seen in one view only is left out (and
    reported), the rest is solved; circcal's solver on exactly that subset reaches the same camera (<= 1e-6 px, the
    identical-observations bar)."""
    from circcal.solver import calibrate

    cal = registry.get("pycolmap")
    skip_unless_available(cal)
    p = make_problem(5)
    obj = [o.copy() for o in p["object_points"]]
    img = [q.copy() for q in p["image_points"]]
    for v in range(1, len(obj)):  # board point 3 stays in view 0 only, point 10 in view 2 only
        drop = [3] if v == 2 else [3, 10]
        keep = np.ones(len(obj[v]), bool)
        keep[drop] = False
        obj[v], img[v] = obj[v][keep], img[v][keep]
    keep0 = np.ones(len(obj[0]), bool)
    keep0[10] = False
    obj[0], img[0] = obj[0][keep0], img[0][keep0]
    res = cal.calibrate_observations(obj, img, p["image_size"])
    assert res.status == "ok", res.message
    assert res.extra["left_out"] == {0: [3], 2: [9]} and "seen in one view" in res.extra["note"]  # (2 lacks 3)
    assert np.array_equal(obj[0][3], p["object_points"][0][3]) and np.array_equal(obj[2][9], p["object_points"][2][10])
    sub_o = [np.delete(o, res.extra["left_out"].get(v, []), axis=0) for v, o in enumerate(obj)]
    sub_i = [np.delete(q, res.extra["left_out"].get(v, []), axis=0) for v, q in enumerate(img)]
    ours = calibrate(sub_o, sub_i, p["image_size"])
    assert projection_diff(ours.camera, res.camera)["max_px"] <= 1e-6
