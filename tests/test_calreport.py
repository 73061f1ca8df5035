"""`circcal calibrate ... --report DIR`: a self-contained HTML + Markdown report (three-line verdict first, parameters
with sigmas and correlations, per-view residual bars, residual vectors, the residual histogram, coverage,
uncertainty, outliers, the cross-validation map, failed images with overlays), checked in a real headless browser
(Debian's chromium) where it is installed: every figure loads and nothing overflows the page."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from circcal.cli import main
from circcal.fixtures.scenarios import fixture_dir, load_truth

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
    assert main(["calibrate", *[str(v.image) for v in t.views], str(blank), "--grid", "6x8", "--pitch", "25mm",
                 "--diameter", "12mm", "--no-progress", "--cross-validate", "--out", str(d / "m.json"),
                 "--report", str(folder)]) == 0
    return folder


def test_report_holds_every_part(report):
    html = (report / "index.html").read_text()
    md = (report / "index.md").read_text()
    body = html[html.index('<div class="verdict"'):]
    lines = re.findall(r"<p>(.*?)</p>", body[: body.index("</div>")])
    assert len(lines) == 3
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
        assert f"<td class=\"text\">{name}</td>" in html
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
    script = ("<script>window.addEventListener('load', function () {"
              "var imgs = Array.from(document.images);"
              "var info = {n: imgs.length, loaded: imgs.filter(function (i) {"
              "return i.complete && i.naturalWidth > 0; }).length,"
              "scroll: document.documentElement.scrollWidth, inner: window.innerWidth,"
              "wide: Array.from(document.querySelectorAll('body *')).filter(function (e) {"
              "return e.getBoundingClientRect().right > window.innerWidth + 1; }).map(function (e) {"
              "return e.tagName; }).slice(0, 5)};"
              "document.body.setAttribute('data-check', JSON.stringify(info)); });</script>")
    probe.write_text(page.read_text().replace("</body>", script + "</body>"))
    try:
        run = subprocess.run([_chromium(), "--headless", "--no-sandbox", "--disable-gpu",
                              "--disable-background-networking", "--no-first-run", f"--user-data-dir={tmp}",
                              f"--window-size={width},900", "--virtual-time-budget=10000",
                              "--allow-file-access-from-files", "--dump-dom", probe.as_uri()],
                             capture_output=True, text=True,
                             timeout=BROWSER_TIMEOUT_S)
    finally:
        probe.unlink()
    m = re.search(r'data-check="([^"]*)"', run.stdout)
    assert m, run.stderr[-2000:]
    return json.loads(m.group(1).replace("&quot;", '"'))


@pytest.mark.skipif(_chromium() is None, reason="chromium is not installed (as root: apt-get install -y chromium; "
                                                "`make setup` does it where it can)")
@pytest.mark.parametrize("width", WIDTHS)
def test_report_in_a_headless_browser(report, width, tmp_path):
    info = _browser_check(report / "index.html", width, tmp_path / "profile")
    print(f"\nchromium at {width} px: {info}")
    assert info["n"] >= len(FIGURES) + 1
    assert info["loaded"] == info["n"]
    assert info["scroll"] <= info["inner"], info
    assert info["wide"] == [], info


def test_report_folder_that_is_a_file_is_refused_before_the_work(tmp_path, capsys):
    t = load_truth(fixture_dir("wide", "clean"))
    bad = tmp_path / "report"
    bad.write_text("not a folder")
    out = tmp_path / "m.json"
    assert main(["calibrate", *[str(v.image) for v in t.views[:6]], "--grid", "6x8", "--pitch", "25mm",
                 "--no-progress", "--out", str(out), "--report", str(bad)]) == 2
    assert "is a file" in capsys.readouterr().err
    assert not out.exists() and bad.read_text() == "not a folder"
