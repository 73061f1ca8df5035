"""The comparison report generator: end to end on its --quick configuration (~25 s per run on 2 cores), the published
report against what the code renders from its own report.json, and the report's prose against the constants and
results it states."""

from __future__ import annotations

import fnmatch
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from circcal.commit import RECORD
from circcal.report import QUICK, compute, config, figures, prose, realdata_prose, render, write_report
from circcal.report.capture import study_warnings
from circcal.report.document import TITLE, document
from circcal.report.figures import figure_files
from circcal.report.publish import published_results
from circcal.report.realdata import realdata_entry
from circcal.validators import checks

REPO = Path(__file__).resolve().parents[1]
PUBLISHED = REPO / "reports" / "latest"
REALDATA = config.realdata_root()


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
    """One quick run: its results and the folder it wrote, and matplotlib's and the warning filters' state before
    and after it."""
    import matplotlib

    out = tmp_path_factory.mktemp("reports")
    before = (list(warnings.filters), matplotlib.rcParams.copy())
    results = compute(QUICK, progress=False)
    folder = write_report(results, out)
    after = (list(warnings.filters), matplotlib.rcParams.copy())
    return results, folder, before, after


def _published() -> dict:
    """The published results as the document is drawn from them (report.json + timings.json)."""
    timings = json.loads((PUBLISHED / "timings.json").read_text())
    return published_results((PUBLISHED / "report.json").read_text(), timings)


def _markdown(results: dict) -> str:
    date = json.loads((PUBLISHED / "timings.json").read_text())["date"]
    return render.to_markdown(document(results, prose.header_line(results["config"]["name"], date)))


def test_files_exist_and_html_is_self_contained(quick):
    folder = quick[1]
    for name in (
        "index.md",
        "index.html",
        "report.json",
        "timings.json",
        "bias.png",
        "per_view_errors.png",
        "truth_vs_residual.png",
        "bias_grid.png",
        "heatmap_normal.png",
    ):
        assert (folder / name).is_file() and (folder / name).stat().st_size > 0, name
    html = (folder / "index.html").read_text()
    assert html.count("data:image/png;base64,") == len(list(folder.glob("*.png")))
    assert 'src="' not in html.replace('src="data:image/png;base64,', "")  # nothing linked from outside
    md = (folder / "index.md").read_text()
    assert "Chen et al. 2023, Table 7" in md and "mean 2-D" in md
    index = (folder.parent / "README.md").read_text()
    assert "latest/index.md" in index and "circcal" in index
    assert not list(folder.parent.glob(".latest-*"))  # no temporary folder left behind


def test_html_escapes_text_and_marks_code():
    """Autoescaping: text is escaped once (no markup from the results gets through), `code` becomes <code>."""
    from circcal.report.blocks import Bullets, Paragraph

    page = render.to_html([Paragraph("a <b> & `x < y`"), Bullets(("'q' \"r\"",))], {}, title="t <1>")
    assert "<p>a &lt;b&gt; &amp; <code>x &lt; y</code></p>" in page
    assert "<li>&#x27;q&#x27; &quot;r&quot;</li>" in page and "<title>t &lt;1&gt;</title>" in page


def test_numbers_finite_and_sane(quick):
    folder = quick[1]
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


def test_warnings_recorded_per_study_and_nothing_global(quick):
    """Every study has its warnings entry (a list, possibly empty); the run leaves the process's warning filters and
    matplotlib's rcParams as it found them."""
    _, folder, before, after = quick
    data = json.loads((folder / "report.json").read_text())
    assert set(data["warnings"]) == (
        {f"paper/{c}" for c in QUICK.conditions}
        | {f"checkerboard/{c}" for c in QUICK.checkerboard_conditions}
        | {"bias"}
        | {f"realdata/{n}" for n in QUICK.realdata}
    )
    for entries in data["warnings"].values():
        for w in entries:
            assert set(w) == {"category", "message", "count"} and w["count"] >= 1
    assert after[0] == before[0]
    assert after[1] == before[1]


def test_study_warnings_counts_and_restores():
    """Warnings inside the block are recorded (each repeat counted, deduplicated by category and message), the
    filters are the same after it, and a deprecation is passed on to the caller's filters, not recorded."""
    log: dict = {}
    before = list(warnings.filters)
    with warnings.catch_warnings(record=True) as outer:
        warnings.simplefilter("always")
        with study_warnings(log, "s"):
            for _ in range(3):
                warnings.warn("calibration did not converge (x)", RuntimeWarning)
            warnings.warn("calibration did not converge (y)", RuntimeWarning)
            warnings.warn("held", UserWarning)
            warnings.warn("old API", DeprecationWarning)
    assert log["s"] == [
        {"category": "RuntimeWarning", "message": "calibration did not converge (x)", "count": 3},
        {"category": "RuntimeWarning", "message": "calibration did not converge (y)", "count": 1},
        {"category": "UserWarning", "message": "held", "count": 1},
    ]
    assert [str(w.message) for w in outer] == ["old API"]
    assert list(warnings.filters) == before
    with pytest.raises(KeyError), study_warnings(log, "t"):
        warnings.warn("before the failure", RuntimeWarning)
        raise KeyError("the study failed")
    assert log["t"][0]["message"] == "before the failure"


def test_warnings_printed_in_the_notes(quick, tmp_path):
    """A warning a study recorded appears in its section's notes, with its count."""
    results, _, _, _ = quick
    results = json.loads(json.dumps(results))
    results["warnings"]["bias"] = [
        {"category": "RuntimeWarning", "message": "calibration did not converge (m)", "count": 2}
    ]
    name = f"realdata/{QUICK.realdata[0]}"
    results["warnings"][name] = [{"category": "RuntimeWarning", "message": "did not settle", "count": 1}]
    md = (write_report(results, tmp_path) / "index.md").read_text()
    assert "- bias: RuntimeWarning: calibration did not converge (m) (2 times)" in md
    assert f"- {name}: RuntimeWarning: did not settle\n" in md


def test_bias_study_circcal_beats_blob_centroid_at_large_tilt(quick):
    results = quick[0]
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
    results = quick[0]
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
    results, folder, _, _ = quick
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
        ho["opencv_refined"]["mean_of_views"]["rms_per_point_px"], rel=0.03
    )
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
    for label, key in (
        ("circcal, board refined", "circcal_refined"),
        ("OpenCV centres (circcal's order), board refined", "opencv_refined"),
    ):
        line = next(x for x in md.splitlines() if f"| {label} |" in x)
        assert f"| {s[key]['errors']['rms_per_point_px']:.4f} |" in line, line
        assert f"| {ho[key]['mean_of_views']['mean_2d_px']:.4f} |" in line, line
    text = realdata_prose.realdata_summary("boofcv_sony_hx5v_circle_asym_4x5", s)
    assert text in md and f"{ours:.4f} px" in text and f"{theirs:.4f} px" in text
    assert "printed sheet's shape, not centre detection" in text
    assert "![realdata_board.png](realdata_board.png)" in md and (folder / "realdata_board.png").stat().st_size > 0
    assert f"board refined {ours:.4f} px" in (folder.parent / "README.md").read_text()


def test_realdata_root_override_and_missing_set(tmp_path, monkeypatch):
    """CIRCCAL_REALDATA chooses the folder; a set not found there is an entry marked missing that says where it was
    looked for, and the document says so."""
    monkeypatch.setenv(config.REALDATA_ENV, str(tmp_path))
    assert config.realdata_root() == tmp_path
    entry, times = realdata_entry("no_such_set", QUICK)
    assert times == {} and entry["circcal"]["status"] == "missing"
    assert f"{tmp_path / 'no_such_set'} not found" in entry["circcal"]["message"]
    results = _published()
    results["realdata"] = {"no_such_set": entry}
    results["config"]["realdata"] = ["no_such_set"]
    md = _markdown(results)
    assert f"no_such_set: circcal missing: {tmp_path / 'no_such_set'} not found" in md


def test_failed_write_leaves_previous_report(quick, tmp_path, monkeypatch):
    results = quick[0]
    first = write_report(results, tmp_path)
    before = {p.name: p.read_bytes() for p in first.iterdir()}
    readme = (tmp_path / "README.md").read_text()

    def boom(results, path):
        raise RuntimeError("figure failed")

    monkeypatch.setitem(figures.FIGURES, "bias.png", boom)
    with pytest.raises(RuntimeError, match="figure failed"):
        write_report(results, tmp_path)
    after = {p.name: p.read_bytes() for p in first.iterdir()}
    assert after == before
    assert (tmp_path / "README.md").read_text() == readme
    assert sorted(p.name for p in tmp_path.iterdir()) == [RECORD, "README.md", "latest"]


def test_deterministic(quick, tmp_path):
    """Same inputs, same numbers: a second quick run gives a byte-identical report.json, and PNGs are byte-stable."""
    folder = quick[1]
    again = write_report(compute(QUICK, progress=False), tmp_path)
    assert (again / "report.json").read_bytes() == (folder / "report.json").read_bytes()
    for name in ("bias.png", "per_view_errors.png", "heatmap_normal.png", "realdata_board.png"):
        if name == "realdata_board.png" and not REALDATA.is_dir():
            continue
        assert (again / name).read_bytes() == (folder / name).read_bytes(), name


def test_published_report_is_what_the_code_renders():
    """reports/latest/index.md, index.html and reports/README.md are exactly what the current code renders from the
    published report.json and timings.json (its date and run times): the published text cannot contradict the
    numbers or the code. Republish (`circcal report`) after changing either."""
    results = _published()
    timings = json.loads((PUBLISHED / "timings.json").read_text())
    blocks = document(results, prose.header_line(results["config"]["name"], timings["date"]))
    assert render.to_markdown(blocks) == (PUBLISHED / "index.md").read_text()
    images = {f: (PUBLISHED / f).read_bytes() for f in figure_files(results)}
    assert render.to_html(blocks, images, title=TITLE) == (PUBLISHED / "index.html").read_text()
    readme = render.readme(
        name="latest", date=timings["date"], kind=results["config"]["name"], headline=prose.headline(results)
    )
    assert readme == (PUBLISHED.parent / "README.md").read_text()
    assert sorted(p.name for p in PUBLISHED.glob("*.png")) == sorted(images)


def _set_all(tree: dict, keys: tuple[str, ...], value) -> None:
    """``tree[k][keys...] = value`` for every entry ``k`` of ``tree``."""
    for entry in tree.values():
        for k in keys[:-1]:
            entry = entry[k]
        entry[keys[-1]] = value


def _bias_camera(results: dict) -> None:
    results["bias"]["camera"].update(fx=1234.5, fy=1234.5, width=1281)
    results["bias"]["camera"]["dist"][0] = -0.125


def _bias_board(results: dict) -> None:
    results["bias"]["board"].update(rows=5, cols=6, n_points=30)


def _fixture_camera(results: dict) -> None:
    results["fixtures"]["paper"]["camera"]["fx"] = 4321.0


def _views(results: dict) -> None:
    _set_all(results["paper"], ("n_views",), 13)
    _set_all(results["checkerboard"], ("n_views",), 13)


#: (what is changed: a constant (module, name, distinctive value) or a function of the results; how many lines of
#: index.md must change ("1 + conditions": a sentence, and one line per illumination condition); what every changed
#: line must contain, and must no longer contain)
PROSE_CASES = {
    "agreement bound": ((checks, "SOLVER_PX", 3.7e-9), 1, "3.7e-9 px (opencv, kornia, pycolmap)", "1e-6 px"),
    "mrcal's bound": ((checks, "SOLVER_MRCAL_PX", 4.2e-3), 1, "4.2e-3 px (mrcal)", "1e-4 px"),
    "projection grid": ((config, "PROJECTION_GRID_WIDTH", 61), "1 + conditions", "61-wide", "60-wide"),
    "noise factor": ((prose, "MEAN_2D_PER_SIGMA", 1.9876), 1, "~1.988 sigma", "~1.253 sigma"),
    # both real sets' rigid RMS lie within 3% of OpenCV's (a tie); at 1e-4 they are told apart: 4x5 higher, 10x8 lower
    "tie rule": ((realdata_prose, "TIE_REL", 1e-4), 2, ("% higher.", "% lower."), "tie"),
    # the shape sentence stands on the 4x5 set only: on the 10x8 set circcal's refined RMS (the shadow-edge dots left
    # out) is ~20% below OpenCV's centres', no tie, so the sentence is not said there whatever the shape rule
    "shape rule, drop": (
        (realdata_prose, "SHAPE_RMS_DROP", 0.01),
        1,
        "in plane. The baseline",
        "printed sheet's shape",
    ),
    "shape rule, significance": (
        (realdata_prose, "SHAPE_SIGNIFICANCE", 100.0),
        1,
        "in plane. The baseline",
        "printed sheet's shape",
    ),
    "bias blur": (
        lambda r: r["bias"]["perturbations"][0].update(sigma_px=0.37),
        1,
        "(blur 0.37 px, 8-bit",
        "blur 0.7 px",
    ),
    "bias bits": (lambda r: r["bias"].update(bits=12), 1, "0.7 px, 12-bit, no noise", "8-bit"),
    "bias camera": (_bias_camera, 1, "camera 1281x960, f 1234.5 px, k1 -0.125, k2 0.05.", "f 1500 px"),
    "bias board": (_bias_board, 2, ("a 5x6 grid of dots", "over the 30 dots"), "49"),
    "bias distance": (lambda r: r["bias"].update(distance_mm=512.3), 1, "512 mm away", "341 mm"),
    "views": (_views, 1, "; 13 views each.", "14 views"),
    "fixture dots": (
        lambda r: r["fixtures"]["paper"]["board"].update(diameter_mm=4.25),
        1,
        "dots of 4.25 mm",
        "dots of 5 mm",
    ),
    "fixture camera": (_fixture_camera, "1 + conditions", ("fx 4321 px", "| fx | 4321 |"), "4900 px"),
    "checkerboard squares": (
        lambda r: r["fixtures"]["paper-checkerboard"]["board"].update(pitch_mm=16.5),
        1,
        "squares of 16.5 mm",
        "14 mm",
    ),
    "CPUs": (lambda r: r["environment"].update(cpu_count=7), 2, "7 CPUs", "2 CPUs"),
}


@pytest.mark.parametrize("case", list(PROSE_CASES))
def test_prose_numbers_come_from_constants_and_results(case, monkeypatch):
    """Each number the prose states changes with the constant or result it comes from, and nowhere else: render the
    published results, change one source to a distinctive value, render again; exactly the expected lines change,
    each now holds the new value and none the old one."""
    change, n_lines, new, old = PROSE_CASES[case]
    results = _published()
    before = _markdown(results).splitlines()
    if callable(change):
        change(results)
    else:
        module, name, value = change
        monkeypatch.setattr(module, name, value)
    after = _markdown(results).splitlines()
    assert len(after) == len(before)
    changed = [b for a, b in zip(before, after) if a != b]
    if n_lines == "1 + conditions":
        n_lines = 1 + len(results["config"]["conditions"])
    assert len(changed) == n_lines, changed
    for line in changed:
        assert any(s in line for s in ((new,) if isinstance(new, str) else new)), line
        assert old not in line, line
    for s in (new,) if isinstance(new, str) else new:
        assert any(s in line for line in changed), s


def test_templates_ship_as_package_data():
    """Every template loads through importlib.resources and is covered by pyproject.toml's package-data for
    circcal.report (so the wheel carries it)."""
    import tomllib  # Python 3.11+

    patterns = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"][
        "circcal.report"
    ]
    folder = REPO / "circcal" / "report" / render.TEMPLATES
    names = sorted(p.name for p in folder.iterdir())
    assert names == ["readme.md.j2", "report.html.j2", "report.md.j2"]
    for name in names:
        assert any(fnmatch.fnmatch(f"{render.TEMPLATES}/{name}", pat) for pat in patterns), name
        assert render.template_source(name) == (folder / name).read_text()


def test_cli_registers_report():
    from circcal.cli import build_parser

    args = build_parser().parse_args(["report", "--quick", "--out", "x"])
    assert args.quick and args.out == Path("x") and callable(args.func)


def test_study_section_shows_the_finished_studies(quick):
    """The report's studies section holds each finished study's cells as summary.json has them (the quick run reads
    the committed reports/studies), with the study's figures; a study that has not been run is named missing."""
    from circcal.report.config import studies_root

    results, folder, _, _ = quick
    assert set(results["studies"]) == set(QUICK.studies)
    md = (folder / "index.md").read_text()
    assert "## 8. Studies at scale (`circcal study`)" in md
    for name, entry in results["studies"].items():
        summary = studies_root() / name / "summary.json"
        if not summary.is_file():
            assert entry["status"] == "missing" and f"Study `{name}`" in md
            continue
        cells = json.loads(summary.read_text())
        assert entry["status"] == "ok" and len(entry["cells"]) == len(cells)
        first = cells[0]
        ratio = first["params"]["fx"]["ratio"]
        label = f"{first['scenario']}/{first['variant']}/{first['calibrator']}"
        section = md.split(f"### Study `{name}`")[1].split("### Study")[0]
        line = next(ln for ln in section.splitlines() if ln.startswith(f"| {label} |"))
        assert f"{ratio:.3f}" in line  # the sigma-honesty table's first row, fx column
        for kind in ("ratio", "bias", "pass_rate"):
            assert (folder / f"study_{name}_{kind}.png").is_file()
