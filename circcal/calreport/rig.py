"""A rig calibration's report (``circcal calibrate-rig --report DIR``): one self-contained ``report.html`` beside a
Markdown ``index.md`` and the figures: the verdict first, then per camera its numbers (intrinsics with sigmas, pose
in the rig with sigmas, RMS per point in OpenCV's convention, projection uncertainty, coverage), the rig's geometry
drawn in 3-D (every camera's centre and axes, every instant's board), a rectified pair of the first two cameras with
its epipolar lines, and the cross-validation.

The command passes its console lines in: the report says what the console said, in the same words.
"""

from __future__ import annotations

import base64
import html
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from circcal import atomic
from circcal.calreport.figures import PLAIN_TEXT, STYLE, _figure, save_png
from circcal.pathnames import display_name
from circcal.rotation import rodrigues

__all__ = ["write_rig_report", "fig_rig_geometry"]


def fig_rig_geometry(cal: Any, board: Any) -> Any:
    """The rig in 3-D (the reference camera's frame, mm): each camera's centre and its x, y, z axes, each instant's
    board outline.

    Parameters
    ----------
    cal : circcal.rig.RigCalibration
    board : circcal.board.Board

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    rig = cal.rig
    with matplotlib.rc_context(STYLE):
        fig = _figure(7.0, 5.5)
        ax = fig.add_subplot(1, 1, 1, projection="3d")
        x0, y0, x1, y1 = board.extent_mm()
        corners = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0], [x0, y0, 0]], dtype=np.float64)
        pts = []
        for rv, tv in cal.board_poses.values():
            c = corners @ rodrigues(np.asarray(rv)).T + np.asarray(tv)
            ax.plot(c[:, 0], c[:, 2], -c[:, 1], color="0.6", lw=0.7)
            pts.append(c)
        span = float(np.ptp(np.concatenate(pts), axis=0).max()) if pts else 100.0
        axis_len = 0.08 * span
        for k, name in enumerate(rig.names):
            R, T = rig.pose(k)
            centre = -R.T @ T  # camera k's centre in the reference frame
            for row, colour in zip(R, ("tab:red", "tab:green", "tab:blue")):  # camera axes in the reference frame
                e = centre + axis_len * row
                ax.plot([centre[0], e[0]], [centre[2], e[2]], [-centre[1], -e[1]], color=colour, lw=1.5)
            ax.text(centre[0], centre[2], -centre[1], f" {name}", **PLAIN_TEXT)
            pts.append(centre[None, :])
        allp = np.concatenate(pts)
        mid, half = allp.mean(axis=0), 0.55 * float(np.ptp(allp, axis=0).max())
        ax.set_xlim(mid[0] - half, mid[0] + half)
        ax.set_ylim(mid[2] - half, mid[2] + half)
        ax.set_zlim(-mid[1] - half, -mid[1] + half)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("z, forward (mm)")
        ax.set_zlabel("-y, up (mm)")
        ax.set_title(
            f"the rig in {rig.names[0]}'s frame: camera axes x red, y green, z blue; boards grey", **PLAIN_TEXT
        )
    return fig


def _data_uri(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def write_rig_report(
    folder: str | os.PathLike,
    cal: Any,
    board: Any,
    lines: Sequence[str],
) -> Path:
    """Write the report into ``folder``, an existing empty folder (the command's staging folder).

    Parameters
    ----------
    folder : str or path-like
        ``report.html`` (self-contained), ``index.md``, ``geometry.png`` and, where the first two cameras share an
        instant, ``rectified.png`` are written into it.
    cal : circcal.rig.RigCalibration
    board : circcal.board.Board
    lines : sequence of str
        The console's lines (verdict, numbers, cross-validation), in order.

    Returns
    -------
    pathlib.Path
        ``folder / "report.html"``.

    Raises
    ------
    ValueError
        ``folder`` is not an existing, empty folder (a bug in the caller).
    """
    from circcal.rig.coincident import coincident_cameras
    from circcal.rig.rectify import write_rectified_overlay

    folder = Path(folder)
    if not folder.is_dir() or any(folder.iterdir()):
        raise ValueError(f"write_rig_report: {display_name(folder)} is not an existing, empty folder")
    figures = [("geometry.png", "The rig's geometry", save_png(fig_rig_geometry(cal, board), folder / "geometry.png"))]
    rig = cal.rig
    a, b = rig.names[0], rig.names[1]
    files = {n: cal.images.get(n, {}) for n in (a, b)}
    shared = [i for i in cal.instants[a] if i in cal.instants[b] and i in files[a] and i in files[b]]
    if shared and not any((c.a, c.b) == (a, b) for c in coincident_cameras(cal)):  # at one point: no rectification
        path = write_rectified_overlay(
            folder / "rectified.png", rig, Path(files[a][shared[0]]), Path(files[b][shared[0]])
        )
        figures.append(
            (
                "rectified.png",
                f"{a} and {b} rectified ({display_name(shared[0])}): a point lies on one line in both",
                path,
            )
        )
    md = ["# Rig calibration", "", "```", *[display_name(x) for x in lines], "```", ""]
    for name, title, _ in figures:
        md += [f"## {title}", "", f"![{title}]({name})", ""]
    atomic.write_text(folder / "index.md", "\n".join(md))
    body = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>Rig calibration</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}pre{white-space:pre-wrap}"
        "img{max-width:100%}</style></head><body><h1>Rig calibration</h1>",
        "<pre>" + html.escape("\n".join(display_name(x) for x in lines)) + "</pre>",
    ]
    for _, title, path in figures:
        body += [f"<h2>{html.escape(title)}</h2>", f"<img alt='{html.escape(title)}' src='{_data_uri(Path(path))}'>"]
    body.append("</body></html>")
    out = folder / "report.html"
    atomic.write_text(out, "\n".join(body))
    return out
