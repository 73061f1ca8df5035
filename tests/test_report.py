"""The comparison report generator, end to end on its --quick configuration (~25 s per run on 2 cores)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from circcal.report import report as rep

REALDATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "realdata"


def _numbers(x, path=""):
    """Every number in a JSON tree with its path."""
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _numbers(v, f"{path}/{k}")
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _numbers(v, f"{path}[{i}]")
    elif isinstance(x, (int, float)) and not isinstance(x, bool):
        yield path, x


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """One quick run: its results and the folder it wrote."""
    out = tmp_path_factory.mktemp("reports")
    results = rep.compute(rep.QUICK, progress=False)
    folder = rep.write_report(results, out)
    return results, folder


def test_files_exist_and_html_is_self_contained(quick):
    results, folder = quick
    for name in ("index.md", "index.html", "report.json", "timings.json", "bias.png", "per_view_errors.png",
                 "truth_vs_residual.png", "bias_grid.png", "heatmap_normal.png"):
        assert (folder / name).is_file() and (folder / name).stat().st_size > 0, name
    html = (folder / "index.html").read_text()
    assert html.count("data:image/png;base64,") == len(list(folder.glob("*.png")))
    assert 'src="' not in html.replace('src="data:image/png;base64,', "")  # nothing linked from outside
    md = (folder / "index.md").read_text()
    assert "Chen et al. 2023, Table 7" in md and "mean 2-D" in md
    index = (folder.parent / "README.md").read_text()
    assert "latest/index.md" in index and "circcal" in index
    assert not list(folder.parent.glob(".latest-*"))  # no temporary folder left behind


def test_numbers_finite_and_sane(quick):
    results, folder = quick
    data = json.loads((folder / "report.json").read_text())
    assert "timings" not in data
    for path, v in _numbers(data):
        assert math.isfinite(v), path
    rows = data["paper"]["normal"]["rows"]
    cc = rows["circcal"]
    assert cc["status"] == "ok"
    # rendered fixture with little noise: circcal's residual and its centre error are far below the paper's 0.1 px
    assert cc["errors"]["mean_2d_px"] < 0.05
    assert cc["centre_error"]["mean_2d_px"] < 0.02
    # the three conventions relate as they must: rms/coord = rms/point / sqrt 2, mean <= rms
    e = cc["errors"]
    assert e["rms_per_coord_px"] == pytest.approx(e["rms_per_point_px"] / math.sqrt(2), rel=1e-5)  # 6 digits kept
    assert e["mean_2d_px"] <= e["rms_per_point_px"]
    # the blob-centroid pipeline carries the perspective bias: its centres and its model are further from truth
    ocv = rows["opencv-pipeline"]
    assert ocv["status"] == "ok"
    assert ocv["centre_error"]["mean_2d_px"] > 2 * cc["centre_error"]["mean_2d_px"]
    assert ocv["vs_truth"]["rms_px"] > cc["vs_truth"]["rms_px"]
    # references fitting circcal's own centres reproduce its model (same observations, same estimator)
    for key in ("opencv-fair", "pycolmap-fair"):
        if rows.get(key, {}).get("status") == "ok":
            assert abs(rows[key]["vs_truth"]["rms_px"] - cc["vs_truth"]["rms_px"]) < 1e-3, key
    cb = data["checkerboard"]["normal"]
    assert cb["status"] == "ok" and 0 < cb["centre_error"]["mean_2d_px"] < 0.2
    assert data["paper_published"]["circles"]["weak"] == 0.1199


def test_bias_study_circcal_beats_blob_centroid_at_large_tilt(quick):
    results, _ = quick
    b = results["bias"]
    i = len(b["tilts_deg"]) - 1  # the largest tilt (60 deg)
    m = b["mean_2d_px"]
    for j, d in enumerate(b["diameters_px"]):
        assert m["circcal"][i][j] is not None and m["opencv"][i][j] is not None, (d, b["notes"])
        assert m["circcal"][i][j] < m["opencv"][i][j], d
        assert m["circcal"][i][j] < 0.02, d
    # the perfect-centroid bias grows with dot size (roughly with radius squared) and OpenCV follows it
    jl = len(b["diameters_px"]) - 1
    assert m["perfect_centroid"][i][jl] > 2 * m["perfect_centroid"][i][0]
    assert m["opencv"][i][jl] == pytest.approx(m["perfect_centroid"][i][jl], rel=0.3)


@pytest.mark.skipif(not REALDATA.is_dir(), reason="real data not found beside the repository")
def test_realdata_against_opencv_baseline(quick):
    results, _ = quick
    s = results["realdata"]["boofcv_sony_hx5v_circle_asym_4x5"]
    # OpenCV's solver on the baseline's own centres reproduces the stated RMS
    assert s["opencv"]["errors"]["rms_per_point_px"] == pytest.approx(s["baseline"]["rms_per_point_px"], abs=5e-4)
    cc = s["circcal"]
    assert cc["status"] == "ok", cc.get("message")
    assert 0.05 < cc["errors"]["rms_per_point_px"] < 0.5
    ho = s["heldout"]["circcal"]
    assert len(ho["per_view"]) == len(cc["views"])
    # predicting a view the model never saw costs more than fitting it, but not wildly more
    assert cc["errors"]["mean_2d_px"] < ho["mean_of_views"]["mean_2d_px"] < 3 * cc["errors"]["mean_2d_px"]


@pytest.mark.skipif(not REALDATA.is_dir(), reason="real data not found beside the repository")
def test_realdata_board_refined_rows(quick):
    """The board-refined rows (circcal, and OpenCV's centres in circcal's order through the same solver): the printed
    sheet's shape, not the centres, limits the rigid fit. Measured (asym 4x5): RMS per point 0.0709 / 0.0711 px
    against the stated 0.183; held-out RMS per point 0.128 / 0.128 against the rigid 0.198; the sheet deviates up to
    0.29 mm, 15x its median sigma."""
    results, folder = quick
    s = results["realdata"]["boofcv_sony_hx5v_circle_asym_4x5"]
    cr, orf = s["circcal_refined"], s["opencv_refined"]
    assert cr["status"] == "ok" and orf["status"] == "ok", (cr.get("message"), orf.get("message"))
    assert len(cr["views"]) == len(s["circcal"]["views"]) and len(orf["views"]) == len(s["opencv"]["views"])
    ours, theirs = cr["errors"]["rms_per_point_px"], orf["errors"]["rms_per_point_px"]
    assert ours < 0.5 * s["baseline"]["rms_per_point_px"]
    assert ours < 0.5 * s["circcal"]["errors"]["rms_per_point_px"]
    assert ours == pytest.approx(theirs, rel=0.03)  # same model, the two detectors' centres tie
    ho = s["heldout"]
    for refined, rigid in (("circcal_refined", "circcal"), ("opencv_refined", "opencv")):
        assert len(ho[refined]["per_view"]) == len(s[rigid]["views"])
        assert not [p for p in ho[refined]["per_view"] if "failed" in p]
        # a real shape predicts unseen views better; a shape fitted to noise would predict them worse
        assert ho[refined]["mean_of_views"]["rms_per_point_px"] < ho[rigid]["mean_of_views"]["rms_per_point_px"]
        assert ho[refined]["mean_of_views"]["mean_2d_px"] > s[refined]["errors"]["mean_2d_px"]
    assert ho["circcal_refined"]["mean_of_views"]["rms_per_point_px"] == pytest.approx(
        ho["opencv_refined"]["mean_of_views"]["rms_per_point_px"], rel=0.03)
    # an asymmetric grid has no 180-degree ambiguity: no view reversed
    assert orf["reversed"] == [] and orf["unmatched"] == []
    bd = cr["board"]
    nominal, dev, std = (np.array(bd[k]) for k in ("nominal_mm", "deviation_mm", "std_mm"))
    assert nominal.shape == dev.shape == std.shape == (20, 3)
    assert (std == 0).sum() == 7 and np.all(std[bd["gauge"][0]] == 0) and np.all(std[bd["gauge"][1]] == 0)
    assert np.max(np.abs(dev)) == pytest.approx(bd["max_abs_dev_mm"], rel=1e-5) and np.all(dev[std == 0] == 0)
    assert 5 * bd["median_std_mm"] < bd["max_abs_dev_mm"] < 3.0  # significant, and of printed-sheet size
    assert np.median(std[std > 0]) == pytest.approx(bd["median_std_mm"], rel=1e-5)
    assert orf["board_vs_circcal_max_mm"] < 0.5 * bd["max_abs_dev_mm"]  # both detectors see the same sheet
    # published: the four computed rows, the paragraph (its numbers formatted in), the board figure, the headline
    md = (folder / "index.md").read_text()
    for label, key in (("circcal, board refined", "circcal_refined"),
                       ("OpenCV centres (circcal's order), board refined", "opencv_refined")):
        line = next(x for x in md.splitlines() if f"| {label} |" in x)
        assert f"| {s[key]['errors']['rms_per_point_px']:.4f} |" in line, line
        assert f"| {ho[key]['mean_of_views']['mean_2d_px']:.4f} |" in line, line
    text = rep.realdata_summary("boofcv_sony_hx5v_circle_asym_4x5", s)
    assert text in md and f"{ours:.4f} px" in text and f"{theirs:.4f} px" in text
    assert "printed sheet's shape, not centre detection" in text
    assert "![realdata_board.png](realdata_board.png)" in md and (folder / "realdata_board.png").stat().st_size > 0
    assert f"board refined {ours:.4f} px" in (folder.parent / "README.md").read_text()


def test_failed_write_leaves_previous_report(quick, tmp_path, monkeypatch):
    results, _ = quick
    first = rep.write_report(results, tmp_path)
    before = {p.name: p.read_bytes() for p in first.iterdir()}
    readme = (tmp_path / "README.md").read_text()

    def boom(results, path):
        raise RuntimeError("figure failed")

    monkeypatch.setitem(rep.FIGURES, "bias.png", boom)
    with pytest.raises(RuntimeError, match="figure failed"):
        rep.write_report(results, tmp_path)
    after = {p.name: p.read_bytes() for p in first.iterdir()}
    assert after == before
    assert (tmp_path / "README.md").read_text() == readme
    assert sorted(p.name for p in tmp_path.iterdir()) == ["README.md", "latest"]


def test_deterministic(quick, tmp_path):
    """Same inputs, same numbers: a second quick run gives a byte-identical report.json, and PNGs are byte-stable."""
    results, folder = quick
    again = rep.write_report(rep.compute(rep.QUICK, progress=False), tmp_path)
    assert (again / "report.json").read_bytes() == (folder / "report.json").read_bytes()
    for name in ("bias.png", "per_view_errors.png", "heatmap_normal.png", "realdata_board.png"):
        if name == "realdata_board.png" and not REALDATA.is_dir():
            continue
        assert (again / name).read_bytes() == (folder / name).read_bytes(), name


def test_cli_registers_report():
    from circcal.cli import build_parser

    args = build_parser().parse_args(["report", "--quick", "--out", "x"])
    assert args.quick and args.out == Path("x") and callable(args.func)
