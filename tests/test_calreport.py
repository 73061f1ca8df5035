"""`circcal calibrate ... --report DIR`: a self-contained HTML + Markdown report (three-line verdict first, parameters
with sigmas and correlations, per-view residual bars, residual vectors, the residual histogram, coverage,
uncertainty, outliers, the cross-validation map, failed images with overlays), checked in a real headless browser
(Debian's chromium) where it is installed: every figure loads and nothing overflows the page."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from circcal.calreport import write_report
from circcal.calreport.document import md_name, md_text
from circcal.cli import main
from circcal.errors import ImageError
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.truth import load_truth
from circcal.pathnames import display_name, path_from_json

#: Window widths (px) the page must fit: a laptop and a narrow window.
WIDTHS = (1280, 800)
#: Limit for one browser run (s).
BROWSER_TIMEOUT_S = 120
#: Figures every report with cross-validation holds.
FIGURES = ("views", "vectors", "histogram", "coverage", "uncertainty", "correlation", "crossval")


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """The report of `wide`-clean plus one image without a board (a blank frame), cross-validated."""
    t = load_truth(fixture_dir("wide", "clean"))
    d = tmp_path_factory.mktemp("rep")
    blank = d / "blank.png"
    cv2.imwrite(str(blank), np.full((960, 1280), 200, np.uint8))
    folder = d / "report"
    assert (
        main(
            [
                "calibrate",
                *[str(v.image) for v in t.views],
                str(blank),
                "--grid",
                "6x8",
                "--pitch",
                "25mm",
                "--diameter",
                "12mm",
                "--no-progress",
                "--cross-validate",
                "--out",
                str(d / "m.json"),
                "--report",
                str(folder),
            ]
        )
        == 0
    )
    return folder


def test_report_holds_every_part(report):
    html = (report / "index.html").read_text()
    md = (report / "index.md").read_text()
    body = html[html.index('<div class="verdict') :]
    lines = re.findall(r"<p[^>]*>(.*?)</p>", body[: body.index("</div>")])
    assert len(lines) == 5 and lines[1].startswith("Next: ")  # the headline and its next step, then the numbers
    lines = lines[2:]
    assert "RMS per point (OpenCV)" in lines[0] and "RMS per coordinate (mrcal)" in lines[0] and "mean 2-D" in lines[0]
    assert lines[1].startswith("cross-validation: consistent")
    assert lines[2].startswith("projection uncertainty at infinity: worst")
    for name in FIGURES:
        assert f'src="figures/{name}.png"' in html and f"(figures/{name}.png)" in md
        assert (report / "figures" / f"{name}.png").stat().st_size > 5000
    # the blank frame is listed with its reason and an overlay
    assert "blank.png" in html and "too-few-candidates" in html
    assert list((report / "figures").glob("failed_*.png"))
    for name in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"):
        assert f'<td class="text">{name}</td>' in html
    doc = json.loads((report / "report.json").read_text())
    assert doc["assessment"]["cross_validation"]["verdict"] == "consistent"
    assert doc["model"]["camera"]["width"] == 1280
    # every image the Markdown names exists
    for src in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md):
        assert (report / src).is_file(), src


def _browser_check(page: Path, width: int, tmp: Path) -> dict:
    """Load ``page`` in headless chromium at ``width`` px; returns what a script saw after the load event: images
    (count, loaded), the document's scroll width and the window's."""
    probe = page.with_name(f".probe-{width}.html")
    script = (
        "<script>window.addEventListener('load', function () {"
        "var imgs = Array.from(document.images);"
        "var info = {n: imgs.length, loaded: imgs.filter(function (i) {"
        "return i.complete && i.naturalWidth > 0; }).length,"
        "scroll: document.documentElement.scrollWidth, inner: window.innerWidth,"
        "wide: Array.from(document.querySelectorAll('body *')).filter(function (e) {"
        "return e.getBoundingClientRect().right > window.innerWidth + 1; }).map(function (e) {"
        "return e.tagName; }).slice(0, 5)};"
        "document.body.setAttribute('data-check', JSON.stringify(info)); });</script>"
    )
    probe.write_text(page.read_text().replace("</body>", script + "</body>"))
    try:
        run = subprocess.run(
            [
                _chromium(),
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-background-networking",
                "--no-first-run",
                f"--user-data-dir={tmp}",
                f"--window-size={width},900",
                "--virtual-time-budget=10000",
                "--allow-file-access-from-files",
                "--dump-dom",
                probe.as_uri(),
            ],
            capture_output=True,
            text=True,
            timeout=BROWSER_TIMEOUT_S,
        )
    finally:
        probe.unlink()
    m = re.search(r'data-check="([^"]*)"', run.stdout)
    assert m, run.stderr[-2000:]
    return json.loads(m.group(1).replace("&quot;", '"'))


@pytest.mark.skipif(
    _chromium() is None,
    reason="chromium is not installed (as root: apt-get install -y chromium; `make setup` does it where it can)",
)
@pytest.mark.parametrize("width", WIDTHS)
def test_report_in_a_headless_browser(report, width, tmp_path):
    info = _browser_check(report / "index.html", width, tmp_path / "profile")
    print(f"\nchromium at {width} px: {info}")
    assert info["n"] >= len(FIGURES) + 1
    assert info["loaded"] == info["n"]
    assert info["scroll"] <= info["inner"], info
    assert info["wide"] == [], info


@pytest.mark.skipif(
    _chromium() is None,
    reason="chromium is not installed (as root: apt-get install -y chromium; `make setup` does it where it can)",
)
def test_report_html_alone_shows_every_figure(report, tmp_path):
    """report.html sent alone (copied into an empty folder) still shows every figure: they are embedded."""
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(report / "report.html", alone / "report.html")
    html = (alone / "report.html").read_text()
    srcs = re.findall(r'<img src="([^"]*)"', html)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)
    info = _browser_check(alone / "report.html", WIDTHS[0], tmp_path / "profile")
    assert info["n"] == len(srcs) >= len(FIGURES) + 1 and info["loaded"] == info["n"], info
    assert info["scroll"] <= info["inner"] and info["wide"] == [], info


def test_verdict_comes_first_coloured_with_its_next_step(report):
    html = (report / "index.html").read_text()
    body = html[html.index("<body>") :]
    first = re.search(
        r"<div class=\"verdict (good|check|bad)\" id=\"verdict\">\s*<p class=\"headline\">(.*?)</p>", body
    )
    assert first and body.index('<div class="verdict') < body.index("<h2>"), body[:600]
    assert first.group(2).startswith(first.group(1).upper() + ": ")
    assert re.search(r'<p class="next">Next: \S', body)
    md = (report / "index.md").read_text()
    assert md.splitlines()[2].startswith(f"> **{first.group(1).upper()}: ")


def test_headline_levels():
    """bad when the lens model does not fit or the halves disagree; check when unverified; good only when
    cross-validated, fitting and covered."""
    from types import SimpleNamespace as NS

    from circcal.calreport.document import headline

    fits = NS(fits=True, lens="opencv5", message=lambda: "fits")
    wrong = NS(fits=False, lens="opencv5", message=lambda: "does NOT fit: try --lens rational (a wide lens). (B.)")
    ok_cv = NS(status="ok", verdict="consistent", flagged_views=[], diff=NS(where=None), message="")
    bad_cv = NS(status="ok", verdict="model-or-data-problem", flagged_views=[], diff=NS(where=[("top-left", 0.3)]))
    cov = NS(warnings=[])
    res = NS(rvecs=[0] * 10)

    def a(cv, fit, c=cov):
        return NS(crossval=cv, lens_fit=fit, coverage=c, result=res)

    assert headline(a(ok_cv, fits), 10)["level"] == "good"
    h = headline(a(ok_cv, wrong), 10)
    assert h["level"] == "bad" and h["next"] == "recalibrate with --lens rational (a wide lens)"
    h = headline(a(bad_cv, fits), 10)
    assert h["level"] == "bad" and "top-left" in h["text"]
    assert "--cross-validate" in headline(a(None, fits), 10)["next"]
    h = headline(a(ok_cv, fits, NS(warnings=["nothing in the top-left corner"])), 10)
    assert h["level"] == "check" and "top-left" in h["next"]
    assert headline(a(ok_cv, fits), 30)["level"] == "check"  # 10 of 30 images
    poled = NS(crossval=ok_cv, lens_fit=fits, coverage=cov, result=res, lens_pole=lambda: "vanishes 20.0 deg off")
    h = headline(poled, 10)
    assert h["level"] == "check" and "--lens opencv5" in h["next"] and "denominator vanishes" in h["text"]


def test_text_problems_finds_clipped_and_overlapping_text():
    """The checker the report's figures pass can fail: a title wider than its figure, two labels on one spot."""
    from circcal.calreport import figures as F

    fig = F._figure(3.0, 2.0)
    ax = fig.add_subplot()
    ax.set_title("a title far too long to fit a figure three inches wide, clipped at both ends")
    ax.text(0.5, 0.5, "first label", transform=ax.transAxes)
    ax.text(0.52, 0.5, "second label", transform=ax.transAxes)
    probs = F.text_problems(fig)
    assert any("leaves the figure" in p for p in probs) and any("overlaps" in p for p in probs), probs
    fig = F._figure(3.0, 2.0)
    fig.add_subplot().set_title("short")
    assert F.text_problems(fig) == []


def _real_report(folder: Path, args: list[str], problems: dict) -> Path:
    """``circcal calibrate ARGS --report folder/report``, collecting :func:`text_problems` of every figure saved."""
    from circcal.calreport import document
    from circcal.calreport import figures as F

    real = F.save_png

    def save(fig, path):
        problems[Path(path).stem] = F.text_problems(fig)
        return real(fig, path)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(document.F, "save_png", save)
        out = folder / "report"
        assert main(["calibrate", *args, "--no-progress", "--out", str(folder / "m.json"), "--report", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def real_reports(realdata, tmp_path_factory):
    """Reports of both real sets: the 10x8 one cross-validated (held-out bars, "N out" labels, the detector's
    dropped dots), the asymmetric one with --refine-board (the board's shape); {name: (folder, text problems)}."""
    out = {}
    reg = realdata / "boofcv_sony_hx5v_circle_regular_10x8"
    asym = realdata / "boofcv_sony_hx5v_circle_asym_4x5"
    for name, imgs, extra in (
        ("regular", sorted(reg.glob("image*.jpg")), ["--grid", "10x8", "--pitch", "30mm", "--cross-validate"]),
        (
            "asym",
            sorted(asym.glob("image*.jpg")),
            ["--grid", "5x4", "--pitch", "30mm", "--asymmetric", "--refine-board", "--no-cross-validate"],
        ),
    ):
        problems: dict = {}
        d = tmp_path_factory.mktemp(name)
        folder = _real_report(d, [*map(str, imgs), "--diameter", "20mm", *extra], problems)
        out[name] = (folder, problems)
    return out


def test_real_reports_figure_text_is_whole_and_apart(real_reports):
    for name, (_folder, problems) in real_reports.items():
        assert {"views", "vectors", "histogram", "coverage", "correlation"} <= set(problems), (name, problems)
        bad = {fig: p for fig, p in problems.items() if p}
        assert not bad, (name, bad)
    assert "crossval" in real_reports["regular"][1] and "board" in real_reports["asym"][1]


def test_detector_drops_have_their_own_table(real_reports):
    folder, _ = real_reports["regular"]
    html = (folder / "index.html").read_text()
    md = (folder / "index.md").read_text()
    assert "nan" not in html.lower().replace("nanmax", "")
    drops = html[html.index("Dots the detector left out") : html.index("Residual beyond")]
    rows = re.findall(r"<tr><td class=\"text\">(image\d+\.jpg)</td>", drops)
    assert len(rows) >= 10, drops[:2000]  # image00005's dots under a hand's shadow, and more
    assert "a dark object touches it" in drops or "uneven" in drops
    beyond = html[html.index("Residual beyond") : html.index("<h2>Coverage</h2>")]
    assert "bad-dot" not in beyond and "(nan" not in beyond
    assert "### Dots the detector left out" in md and "(nan, nan)" not in md


def test_refined_board_is_drawn(real_reports):
    folder, _ = real_reports["asym"]
    html = (folder / "index.html").read_text()
    assert "<h2>Board shape</h2>" in html and 'src="figures/board.png"' in html
    assert (folder / "figures" / "board.png").stat().st_size > 5000
    assert "![the board's estimated shape](figures/board.png)" in (folder / "index.md").read_text()


def test_report_folder_that_is_a_file_is_refused_before_the_work(tmp_path, capsys):
    t = load_truth(fixture_dir("wide", "clean"))
    bad = tmp_path / "report"
    bad.write_text("not a folder")
    out = tmp_path / "m.json"
    assert (
        main(
            [
                "calibrate",
                *[str(v.image) for v in t.views[:6]],
                "--grid",
                "6x8",
                "--pitch",
                "25mm",
                "--no-progress",
                "--out",
                str(out),
                "--report",
                str(bad),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "--report" in err and str(bad) in err and "file" in err
    assert not out.exists() and bad.read_text() == "not a folder"


#: Hostile file names for `wide`-clean's 12 views (bytes: POSIX names; a name is at most 255 bytes).
HOSTILE = [
    b"price$0_$x.png",
    b"a|b.png",
    b"new\nline.png",
    b"caf\xe9_00.png",
    b"<script>.png",
    b"L" * 240 + b"_05.png",
    "\U0001f600\U0001f3af \U0001f469\u200d\U0001f52c.png".encode(),
    "\u202egnp.exe_07.png".encode(),
    b"tick`s``_08.png",
    b"esc\x1b[31m_09.png",
    b"bytes:x_10.png",
    b"plain_11.png",
]
#: Two frames without a board: one listed with an overlay, one whose image cannot be read again for its overlay.
BLANKS = [b"<b>blank|$1$<i>\xff.png", b"unreadable.png"]


@pytest.fixture(scope="module")
def hostile(tmp_path_factory):
    """The calibration (cross-validated, outlier rejection on) of `wide`-clean's views linked under hostile names,
    plus two blank frames; (assessment, paths as given)."""
    from circcal.analysis.assess import assess
    from circcal.pipeline import calibrate_images
    from circcal.solver import CalibrationOptions
    from circcal.solver.outliers import OutlierRule

    if os.name != "posix":
        pytest.skip("file names of any bytes: POSIX")
    t = load_truth(fixture_dir("wide", "clean"))
    d = os.fsencode(tmp_path_factory.mktemp("hostile"))
    paths = []
    for v, name in zip(t.views, HOSTILE):
        os.symlink(os.fsencode(v.image), os.path.join(d, name))
        paths.append(os.fsdecode(os.path.join(d, name)))
    for grey, name in zip((200, 180), BLANKS):
        with open(os.path.join(d, name), "wb") as f:
            f.write(cv2.imencode(".png", np.full((960, 1280), grey, np.uint8))[1].tobytes())
        paths.append(os.fsdecode(os.path.join(d, name)))
    options = CalibrationOptions(outlier_rule=OutlierRule())
    cal = calibrate_images(paths, t.board, options, progress=False, jobs=1)
    assert len(cal.used) == len(HOSTILE) and len(cal.failed) == len(BLANKS)
    return assess(cal, t.board, options, cross_validate=True), paths


@pytest.fixture(scope="module")
def hostile_report(hostile, tmp_path_factory):
    """The report of :func:`hostile` written into an empty folder, the second blank frame's image unreadable when
    its overlay is drawn."""
    import circcal.detector.image as image_mod

    assessment, paths = hostile
    folder = tmp_path_factory.mktemp("hostile-report")
    real = image_mod.read_image

    def read_image(path):
        if Path(path).name == "unreadable.png":
            raise ImageError(f"{display_name(path)}: header claims 100000x100000 pixels")
        return real(path)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(image_mod, "read_image", read_image)
        index = write_report(assessment, folder)
    assert index == folder / "report.html"
    return folder


def test_hostile_names_in_html(hostile_report):
    html = (hostile_report / "index.html").read_text(encoding="utf-8")
    assert "<script" not in html.lower() and "<b>blank" not in html and "<i>" not in html  # names stay text
    for shown in (
        "price$0_$x.png",
        "a|b.png",
        "new\\nline.png",
        "caf\\xe9_00.png",
        "&lt;script&gt;.png",
        "L" * 240 + "_05.png",
        "\U0001f600\U0001f3af \U0001f469\u200d\U0001f52c.png",
        "\\u202egnp.exe_07.png",
        "tick`s``_08.png",
        "esc\\x1b[31m_09.png",
        "bytes:x_10.png",
        "&lt;b&gt;blank|$1$&lt;i&gt;\\xff.png",
    ):
        assert re.search(f'<td class="name( long)?">{re.escape(shown)}</td>', html) or f"<b>{shown}</b>" in html, shown
    assert not set(html) & {"\x1b", "\u202e", "\ufffd"}
    # the blank frames: both listed with their reason; the one unreadable again has no overlay and says why
    figs = re.findall(r"<figure>(.*?)</figure>", html[html.index("Images left out") :], re.S)
    assert len(figs) == 2
    assert '<img src="figures/failed_00.png"' in figs[0] and "too-few-candidates" in figs[0]
    assert "<img" not in figs[1] and "no overlay: " in figs[1] and "header claims 100000x100000" in figs[1]
    assert (hostile_report / "figures" / "failed_00.png").is_file()
    assert not (hostile_report / "figures" / "failed_01.png").exists()
    for name in ("views", "vectors", "histogram", "coverage", "uncertainty", "correlation", "crossval"):
        assert (hostile_report / "figures" / f"{name}.png").stat().st_size > 5000


def _cells(row: str) -> list[str]:
    """A GFM table row's cells (split at the pipes no backslash escapes)."""
    assert row.startswith("| ") and row.endswith(" |"), row
    return [c.strip() for c in re.split(r"(?<!\\)\|", row[1:-1])]


def test_hostile_names_keep_markdown_table_rows_intact(hostile_report):
    md = (hostile_report / "index.md").read_text(encoding="utf-8")
    lines = md.splitlines()
    head = lines.index(next(ln for ln in lines if ln.startswith("| view | points |")))
    rows = lines[head + 2 : head + 2 + len(HOSTILE)]
    assert lines[head + 2 + len(HOSTILE)] == ""  # one line per view, then the table ends
    width = len(_cells(lines[head]))
    for row, raw in zip(rows, HOSTILE):
        cells = _cells(row)
        assert len(cells) == width, row
        assert cells[0] == md_name(display_name(raw), cell=True)
    assert rows[1].startswith("| `a\\|b.png` |") and rows[0].startswith("| `price$0_$x.png` |")
    assert rows[8].startswith("| ```tick`s``_08.png``` |")
    assert "\\n" in rows[2] and not set(md) & {"\x1b", "\u202e", "\ufffd"}
    failed = [ln for ln in lines if ln.startswith("- **")]
    assert failed[0].startswith("- **`<b>blank|$1$<i>\\xff.png`** (too-few-candidates): ")
    assert failed[1].startswith("- **`unreadable.png`**") and "(no overlay: " in failed[1]


def test_report_json_stores_hostile_names_losslessly(hostile_report, hostile):
    text = (hostile_report / "report.json").read_text(encoding="utf-8")  # strict UTF-8
    doc = json.loads(text)
    json.dumps(doc, ensure_ascii=False).encode("utf-8")  # strict: no lone surrogate in any string
    _, paths = hostile
    want = [os.fsencode(Path(p).name) for p in paths[: len(HOSTILE)]]
    got = [os.fsencode(path_from_json(v["name"])) for v in doc["model"]["views"]]
    assert got == want
    got = [os.fsencode(path_from_json(v["name"])) for v in doc["assessment"]["cross_validation"]["views"]]
    assert got == want
    assert doc["model"]["views"][3]["name"] == "bytes:caf%E9_00.png"
    assert doc["model"]["views"][10]["name"] == "bytes:bytes:x_10.png"
    failed = [os.fsencode(path_from_json(f["path"])) for f in doc["model"]["failed_images"]]
    assert failed == [os.fsencode(p) for p in paths[len(HOSTILE) :]]


def test_write_report_writes_only_into_an_empty_existing_folder(hostile, tmp_path):
    assessment, _ = hostile
    full = tmp_path / "full"
    full.mkdir()
    (full / "keep.txt").write_text("mine")
    with pytest.raises(ValueError, match="not empty"):
        write_report(assessment, full)
    assert [p.name for p in full.iterdir()] == ["keep.txt"] and (full / "keep.txt").read_text() == "mine"
    with pytest.raises(ValueError, match="not an existing folder"):
        write_report(assessment, tmp_path / "missing")
    assert not (tmp_path / "missing").exists()


@pytest.mark.parametrize(
    "text, md",
    [
        ("a|b", "a\\|b"),
        ("x `y` *z* _w_", "x \\`y\\` \\*z\\* \\_w\\_"),
        ("<script>&amp;", "\\<script\\>\\&amp;"),
        ("[l](u) ~s~ $m$", "\\[l\\](u) \\~s\\~ \\$m\\$"),
        ("a\\b", "a\\\\b"),
        ("two\nlines", "two\\\\nlines"),
    ],
)
def test_md_text_escapes_markup(text, md):
    assert md_text(text) == md


@pytest.mark.parametrize(
    "name, cell, md",
    [
        ("plain.png", False, "`plain.png`"),
        ("a|b", True, "`a\\|b`"),
        ("a|b", False, "`a|b`"),
        ("a`b``c", False, "```a`b``c```"),
        ("`x", False, "`` `x ``"),
        (" x ", False, "`  x  `"),
        ("new\nline", False, "`new\\nline`"),
    ],
)
def test_md_name_is_a_code_span(name, cell, md):
    assert md_name(name, cell=cell) == md


@pytest.mark.skipif(_chromium() is None, reason="chromium is not installed")
@pytest.mark.parametrize("width", WIDTHS)
def test_hostile_names_fit_the_page_in_a_headless_browser(hostile_report, width, tmp_path):
    """A 247-character name wraps in its cell and in the text: nothing wider than the window."""
    info = _browser_check(hostile_report / "index.html", width, tmp_path / "profile")
    assert info["loaded"] == info["n"] >= 8
    assert info["scroll"] <= info["inner"] and info["wide"] == [], info
