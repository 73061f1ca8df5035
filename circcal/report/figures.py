"""The report's figures, drawn from the results alone (the JSON tree report.json holds) into byte-stable PNGs.

Each figure is a :class:`matplotlib.figure.Figure` of its own (no pyplot: no global figure manager, no backend
chosen for the process; ``Figure.savefig`` renders with the Agg canvas), drawn under :data:`STYLE` through
``matplotlib.rc_context``, so the process's rcParams are left as they were. PNG metadata carries no software
version, so a figure's bytes change only when its content does.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from circcal.model import Camera
from circcal.report.config import PROJECTION_GRID_WIDTH
from circcal.report.results import dig, paper_conditions, realdata_sets

__all__ = [
    "BIAS_GRID_FLOOR_PX",
    "BIAS_PLOT_FLOOR_PX",
    "FIGURES",
    "STYLE",
    "fig_bias",
    "fig_bias_grid",
    "fig_heatmaps",
    "fig_per_view",
    "fig_realdata_board",
    "fig_truth_bars",
    "figure_files",
    "make_figures",
]

#: rcParams every figure is drawn under (``svg.hashsalt`` keeps SVG ids stable should a figure be saved as SVG).
STYLE = {"figure.dpi": 100, "savefig.dpi": 110, "font.size": 9, "svg.hashsalt": "circcal"}
#: The bias plot's log axis starts here: circcal's smallest errors (~5e-4 px) stay visible, exact zeros drawable.
BIAS_PLOT_FLOOR_PX = 1e-4
#: The bias grid's colour scale starts here (below every detector's error but circcal's best cells).
BIAS_GRID_FLOOR_PX = 1e-3


def _figure(width_in: float, height_in: float) -> Any:
    """A new figure of that size (inches), not registered with pyplot."""
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in))


def _save(fig: Any, path: Path) -> None:
    """PNG without a Software entry (byte-stable across matplotlib builds and runs)."""
    fig.savefig(path, format="png", metadata={"Software": None}, bbox_inches="tight")


def _value(v: Any) -> float:
    """A number of the results tree as a float (None, JSON's null, as NaN)."""
    return float("nan") if v is None else float(v)


def _grid(b: dict[str, Any], detector: str) -> np.ndarray:
    """The bias study's mean error grid (tilts x diameters, px) of one detector, NaN where it found nothing."""
    return np.array([[_value(v) for v in row] for row in b["mean_2d_px"][detector]])


def fig_per_view(results: dict, path: Path) -> None:
    """Per-view mean 2-D reprojection error, circcal vs the OpenCV circle pipeline, one panel per condition.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).
    path : Path
        The PNG to write.
    """
    conds = paper_conditions(results)
    fig = _figure(8.5, 2.3 * len(conds) + 0.4)
    axes = fig.subplots(len(conds), 1, squeeze=False)
    for ax, c in zip(axes[:, 0], conds):
        rows = results["paper"][c]["rows"]
        n = results["paper"][c]["n_views"]
        x = np.arange(n)
        for key, colour, dx in (("circcal", "tab:blue", -0.2), ("opencv-pipeline", "tab:orange", 0.2)):
            r = rows.get(key, {})
            vals = np.full(n, np.nan)
            for v, e in zip(r.get("views") or [], r.get("per_view_mean_2d_px") or []):
                vals[v] = _value(e)
            mean = dig(r, "errors", "mean_2d_px")
            ax.bar(x + dx, vals, width=0.4, color=colour, label=f"{r.get('label', key)} (mean {_value(mean):.4f} px)")
            for v in np.flatnonzero(~np.isfinite(vals)):
                ax.text(v + dx, 0, "x", ha="center", va="bottom", color=colour, fontsize=8)
        ax.set_title(f"paper fixture, {c} illumination")
        ax.set_ylabel("mean 2-D error [px]")
        ax.set_xticks(x)
        ax.set_xticklabels([f"{i}" for i in x])
        ax.legend(loc="upper right", fontsize=7)
        ax.grid(axis="y", alpha=0.3)
    axes[-1, 0].set_xlabel("view index (x = view not used)")
    fig.suptitle("Per-view reprojection error (the paper's Tables 2, 4, 6; mean of |residual|, eq. 22)")
    fig.tight_layout()
    _save(fig, path)


def fig_bias(results: dict, path: Path) -> None:
    """Centre error against tilt (largest dot size) and against dot size (largest tilt).

    Parameters
    ----------
    results : dict
        The results tree (report.json's).
    path : Path
        The PNG to write.
    """
    b = results["bias"]
    tilts, diams = np.array(b["tilts_deg"]), np.array(b["diameters_px"])
    series = (
        ("perfect_centroid", "perfect blob centroid (area centroid)", "k", "--", None),
        ("opencv", "OpenCV findCirclesGrid (SimpleBlobDetector, sized)", "tab:orange", "-", "s"),
        ("circcal_nomodel", "circcal detector, no model (perspective only)", "tab:green", ":", "^"),
        ("circcal", "circcal detector, with the lens model", "tab:blue", "-", "o"),
    )
    fig = _figure(11, 4.2)
    axes = fig.subplots(1, 2)
    for key, lab, col, ls, mk in series:
        a = np.maximum(_grid(b, key), BIAS_PLOT_FLOOR_PX)
        axes[0].plot(tilts, a[:, -1], color=col, ls=ls, marker=mk, label=lab)
        axes[1].plot(diams, a[-1, :], color=col, ls=ls, marker=mk, label=lab)
    axes[0].set_xlabel("board tilt [deg]")
    axes[0].set_title(f"vs tilt, dots {diams[-1]:g} px across")
    axes[1].set_xlabel("dot diameter at the board centre [px]")
    axes[1].set_title(f"vs dot size, tilt {tilts[-1]:g} deg")
    for ax in axes:
        ax.set_yscale("log")
        ax.set_ylabel("mean centre error vs true projection [px]")
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, loc="lower center", ncol=2, bbox_to_anchor=(0.5, -0.13))
    blur = ", ".join(f"blur {p['sigma_px']:g} px" for p in b["perturbations"] if p.get("kind") == "gaussian_blur")
    fig.suptitle(
        f"Centre bias on clean renders ({b['board']['rows']}x{b['board']['cols']} dots, "
        f"f {b['camera']['fx']:g} px, k1 {b['camera']['dist'][0]:g}; {blur}, {b['bits']}-bit; values "
        f"below {BIAS_PLOT_FLOOR_PX:g} px drawn at {BIAS_PLOT_FLOOR_PX:g})"
    )
    fig.tight_layout()
    _save(fig, path)


def fig_bias_grid(results: dict, path: Path) -> None:
    """Mean centre error over the whole tilt x dot-size grid, circcal vs OpenCV vs perfect centroid.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).
    path : Path
        The PNG to write.
    """
    from matplotlib.colors import LogNorm

    b = results["bias"]
    tilts, diams = b["tilts_deg"], b["diameters_px"]
    keys = (
        ("circcal", "circcal (with model)"),
        ("opencv", "OpenCV findCirclesGrid"),
        ("perfect_centroid", "perfect blob centroid"),
    )
    fig = _figure(12, 3.6)
    axes = fig.subplots(1, 3)
    vals = [_grid(b, k) for k, _ in keys]
    top = np.nanmax([np.nanmax(v) for v in vals if np.isfinite(v).any()])
    norm = LogNorm(vmin=BIAS_GRID_FLOOR_PX, vmax=max(top, 10 * BIAS_GRID_FLOOR_PX))
    im = None
    for ax, (_, lab), v in zip(axes, keys, vals):
        im = ax.imshow(np.maximum(v, BIAS_GRID_FLOOR_PX), origin="lower", aspect="auto", norm=norm, cmap="viridis")
        for i in range(v.shape[0]):
            for j in range(v.shape[1]):
                ax.text(
                    j,
                    i,
                    "n/a" if not np.isfinite(v[i, j]) else f"{v[i, j]:.3f}",
                    ha="center",
                    va="center",
                    fontsize=6,
                    color="w",
                )
        ax.set_xticks(range(len(diams)))
        ax.set_xticklabels([f"{d:g}" for d in diams])
        ax.set_yticks(range(len(tilts)))
        ax.set_yticklabels([f"{t:g}" for t in tilts])
        ax.set_xlabel("dot diameter [px]")
        ax.set_ylabel("tilt [deg]")
        ax.set_title(lab)
    fig.colorbar(im, ax=list(axes), label="mean centre error [px]")
    _save(fig, path)


def heatmap_panels(results: dict, condition: str) -> list[tuple[dict, str]]:
    """The calibrators drawn in a condition's heatmap.

    circcal, the OpenCV circle pipeline, mrcal's default mode and the checkerboard, where each has a model.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).
    condition : str

    Returns
    -------
    list of (dict, str)
        (row, title).
    """
    rows = results["paper"][condition]["rows"]
    panels = [
        (rows.get("circcal"), "circcal"),
        (rows.get("opencv-pipeline"), "OpenCV circle pipeline"),
        (rows.get("mrcal-default"), "mrcal [default] on circcal's centres"),
        (results["checkerboard"].get(condition), "OpenCV checkerboard"),
    ]
    return [(r, t) for r, t in panels if r is not None and r.get("camera")]


def fig_heatmaps(results: dict, path: Path, condition: str) -> None:
    """Projection difference to the true camera over the image, one panel per calibrator.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).
    path : Path
        The PNG to write.
    condition : str
    """
    from circcal.analysis.compare import projection_diff

    truth = Camera.from_dict(results["fixtures"]["paper"]["camera"])
    panels = heatmap_panels(results, condition)
    fig = _figure(4.3 * len(panels), 3.1)
    axes = fig.subplots(1, len(panels), squeeze=False)
    for ax, (r, title) in zip(axes[0], panels):
        d = projection_diff(truth, Camera.from_dict(r["camera"]), gridn_width=PROJECTION_GRID_WIDTH, fit=True)
        nx = PROJECTION_GRID_WIDTH
        ny = len(d["uv"]) // nx
        u, v = d["uv"][:, 0].reshape(ny, nx), d["uv"][:, 1].reshape(ny, nx)
        cs = ax.contourf(u, v, d["diff"].reshape(ny, nx), levels=12, cmap="magma")
        ax.set_xlim(0, truth.width - 1)
        ax.set_ylim(truth.height - 1, 0)
        ax.set_aspect("equal")
        ax.set_title(f"{title}\nRMS {d['rms_px']:.3f} px, max {d['max_px']:.3f} px", fontsize=8)
        ax.set_xlabel("u [px]")
        ax.set_ylabel("v [px]")
        fig.colorbar(cs, ax=ax, label="|projection - truth| [px]", shrink=0.8)
    fig.suptitle(f"Projection difference to the true camera ({condition} illumination; implied rotation fitted)")
    fig.tight_layout()
    _save(fig, path)


def fig_truth_bars(results: dict, path: Path) -> None:
    """Residual (what calibrators report) beside error against truth (what matters), per condition.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).
    path : Path
        The PNG to write.
    """
    conds = paper_conditions(results)
    keys = [
        ("circcal", "circcal", "tab:blue"),
        ("opencv-pipeline", "OpenCV circles", "tab:orange"),
        ("mrcal-default", "mrcal [default]", "tab:purple"),
        ("checkerboard", "OpenCV checkerboard", "tab:gray"),
    ]
    fig = _figure(11, 3.6)
    axes = fig.subplots(1, 2)
    x = np.arange(len(conds))
    w = 0.8 / len(keys)
    for k, (key, lab, col) in enumerate(keys):
        res, tru = [], []
        for c in conds:
            r = (
                results["checkerboard"].get(c, {})
                if key == "checkerboard"
                else results["paper"][c]["rows"].get(key, {})
            )
            res.append(_value(dig(r, "errors", "mean_2d_px")))
            tru.append(_value(dig(r, "vs_truth", "rms_px")))
        axes[0].bar(x + (k - 1.5) * w, res, w, color=col, label=lab)
        axes[1].bar(x + (k - 1.5) * w, tru, w, color=col, label=lab)
    for ax, t, yl in (
        (axes[0], "what the calibrator reports: mean 2-D residual", "mean 2-D residual [px]"),
        (axes[1], "what matters: projection error vs the true camera", "RMS projection difference [px]"),
    ):
        ax.set_xticks(x)
        ax.set_xticklabels(conds)
        ax.set_xlabel("illumination condition")
        ax.set_ylabel(yl)
        ax.set_title(t)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    _save(fig, path)


def refined_boards(results: dict) -> list[tuple[str, dict]]:
    """The real-data sets with a refined board to draw.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    list of (str, dict)
        (name, set).
    """
    return [(n, s) for n, s in realdata_sets(results) if dig(s, "circcal_refined", "board", "deviation_mm")]


def gauge_counts(board: dict[str, Any]) -> tuple[int, int]:
    """The gauge of a refined board entry, read from the zero standard deviations.

    Parameters
    ----------
    board : dict
        A refined board entry (:func:`circcal.report.realdata.board_block`).

    Returns
    -------
    full : int
        Points held in x, y and z.
    z_only : int
        Points held in z only.
    """
    std = np.array(board["std_mm"], dtype=np.float64)
    full = np.all(std == 0, axis=1)
    return int(full.sum()), int(((std[:, 2] == 0) & ~full).sum())


def _board_panel(ax: Any, fig: Any, name: str, s: dict) -> None:
    """One real set's refined board: dz as colour at each nominal point, (dx, dy) as exaggerated arrows, the gauge
    points marked."""
    from matplotlib.colors import Normalize
    from matplotlib.lines import Line2D

    bd = s["circcal_refined"]["board"]
    nom, dev, std = (np.array(bd[k], dtype=np.float64) for k in ("nominal_mm", "deviation_mm", "std_mm"))
    zmax = max(float(np.max(np.abs(dev[:, 2]))), 1e-6)
    sc = ax.scatter(
        nom[:, 0],
        nom[:, 1],
        c=dev[:, 2],
        s=110,
        cmap="RdBu_r",
        edgecolors="0.3",
        linewidths=0.4,
        norm=Normalize(-zmax, zmax),
        zorder=2,
    )
    pitch = float(s["board"]["pitch_mm"])
    dxy = float(np.max(np.linalg.norm(dev[:, :2], axis=1)))
    # arrows: the largest in-plane deviation drawn 0.8 pitch long; the key shows a round length at that scale
    gain = 0.8 * pitch / max(dxy, 1e-9)
    key = float(f"{dxy:.1g}")
    q = ax.quiver(
        nom[:, 0],
        nom[:, 1],
        dev[:, 0],
        dev[:, 1],
        angles="xy",
        scale_units="xy",
        scale=1.0 / gain,
        width=0.005,
        color="k",
        zorder=3,
    )
    ax.quiverkey(
        q, 0.62, -0.21, key, f"{key:g} mm in plane", labelpos="E", coordinates="axes", fontproperties={"size": 7}
    )
    full = np.all(std == 0, axis=1)
    zonly = (std[:, 2] == 0) & ~full
    for held, marker in ((full, "s"), (zonly, "D")):
        ax.scatter(
            nom[held, 0],
            nom[held, 1],
            s=260,
            marker=marker,
            facecolors="none",
            edgecolors="k",
            linewidths=1.2,
            zorder=4,
        )
    ax.set_aspect("equal")
    ax.invert_yaxis()
    ax.margins(0.08)
    ax.set_xlabel("board x [mm]")
    ax.set_ylabel("board y [mm]")
    ax.set_title(
        f"{name}\nlargest deviation {bd['max_abs_dev_mm']:.2f} mm (one coordinate),\n"
        f"{bd['max_dev_over_median_std']:.0f}x the median sigma of {bd['median_std_mm']:.3f} mm",
        fontsize=8,
    )
    fig.colorbar(sc, ax=ax, label="dz, out of the board plane [mm]", shrink=0.85)
    ax.legend(
        handles=[
            Line2D([], [], marker="s", ls="", mfc="none", mec="k", label="held in x, y, z (gauge)"),
            Line2D([], [], marker="D", ls="", mfc="none", mec="k", label="held in z (gauge)"),
            Line2D(
                [],
                [],
                marker=r"$\rightarrow$",
                ls="",
                color="k",
                markersize=10,
                label=f"in-plane deviation, drawn x{gain:.0f}",
            ),
        ],
        fontsize=7,
        loc="upper left",
        bbox_to_anchor=(-0.02, -0.15),
        ncol=1,
        frameon=False,
    )


def fig_realdata_board(results: dict, path: Path) -> None:
    """The refined board of each real set against the nominal one (``_board_panel`` each).

    Parameters
    ----------
    results : dict
        The results tree (report.json's).
    path : Path
        The PNG to write.
    """
    sets = refined_boards(results)
    fig = _figure(5.6 * len(sets), 4.6)
    axes = fig.subplots(1, len(sets), squeeze=False)
    for ax, (name, s) in zip(axes[0], sets):
        _board_panel(ax, fig, name, s)
    fig.suptitle(
        "Real photographs: the printed board as circcal estimates it (refine_board), against the nominal board",
        fontsize=9,
    )
    fig.tight_layout()
    _save(fig, path)


#: File name -> figure function (results, path), drawn for every run; tests may monkeypatch these.
FIGURES: dict[str, Callable[[dict, Path], None]] = {
    "truth_vs_residual.png": fig_truth_bars,
    "per_view_errors.png": fig_per_view,
    "bias.png": fig_bias,
    "bias_grid.png": fig_bias_grid,
}


def _drawers(results: dict) -> dict[str, Callable[[dict, Path], None]]:
    """Every figure of this run: :data:`FIGURES`, one heatmap per condition, the real boards where refined."""
    out = dict(FIGURES)
    for c in paper_conditions(results):
        out[f"heatmap_{c}.png"] = lambda r, p, c=c: fig_heatmaps(r, p, c)
    if refined_boards(results):
        out["realdata_board.png"] = fig_realdata_board
    for name, entry in (results.get("studies") or {}).items():
        if entry.get("status") == "ok" and entry.get("cells"):
            for kind in STUDY_FIGURES:
                out[f"study_{name}_{kind}.png"] = lambda r, p, n=name, k=kind: fig_study(r, p, n, k)
    return out


#: The figures of a study summary (:func:`circcal.study.figures.draw_figures`), by file stem.
STUDY_FIGURES = ("ratio", "bias", "pass_rate")


def fig_study(results: dict, path: Path, name: str, kind: str) -> None:
    """One figure of a finished study, drawn by the study package from the cells the results hold.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).
    path : Path
        The PNG to write.
    name : str
        The study.
    kind : str
        Which figure.
    """
    import tempfile

    from circcal.report.studies import study_cells
    from circcal.study.figures import draw_figures

    with tempfile.TemporaryDirectory() as tmp:
        files = {p.stem: p for p in draw_figures(study_cells(results["studies"][name]), tmp).values()}
        Path(path).write_bytes(files[kind].read_bytes())


def figure_files(results: dict) -> list[str]:
    """The file names of the figures this run draws (what the document shows).

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    list of str
    """
    return list(_drawers(results))


def make_figures(results: dict, folder: Path) -> list[str]:
    """Draw every figure of the run into a folder under :data:`STYLE`.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).
    folder : Path

    Returns
    -------
    list of str
        The file names.
    """
    import matplotlib

    drawers = _drawers(results)
    for name, draw in drawers.items():
        with matplotlib.rc_context(STYLE):
            draw(results, folder / name)
    return list(drawers)
