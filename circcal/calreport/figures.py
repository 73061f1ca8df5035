"""The calibration report's figures, each a :class:`matplotlib.figure.Figure` of its own (no pyplot: no global figure
manager, no backend chosen for the process; ``Figure.savefig`` renders with the Agg canvas), drawn under
:data:`STYLE` through ``matplotlib.rc_context`` so the process's rcParams stay as they were, and written atomically as
PNG without a software stamp (byte-stable).

Legibility rules: panels that compare like quantities share one colour (or arrow) scale and say so; legends sit
outside the data (below or beside the axes); every axis is labelled with its unit; images keep their aspect and
their pixel convention (y down, integer coordinates at pixel centres).

Names (image files) are drawn as plain text: :func:`name_label` makes them printable
(:func:`circcal.pathnames.display_name`: undecodable bytes as ``\\xNN``, which FreeType could not draw, control
characters escaped) and short, and they are drawn with :data:`PLAIN_TEXT` (no mathtext: ``price$0_$x.png`` would be
parsed as math and fail; no TeX, whatever the user's matplotlibrc says).
"""

from __future__ import annotations

import io
import math
import textwrap
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from circcal import atomic
from circcal.pathnames import display_name

__all__ = [
    "STYLE",
    "PLAIN_TEXT",
    "NAME_CHARS",
    "name_label",
    "save_png",
    "fig_diff",
    "fig_uncertainty",
    "fig_coverage",
    "fig_view_bars",
    "fig_residual_vectors",
    "fig_histogram",
    "fig_correlation",
    "fig_crossval",
    "fig_board_shape",
    "text_problems",
]

#: rcParams every figure is drawn under.
STYLE = {"figure.dpi": 100, "savefig.dpi": 110, "font.size": 9, "axes.titlesize": 10, "svg.hashsalt": "circcal"}
#: Residual-vector panels per row.
VECTOR_COLUMNS = 4
#: A residual arrow is drawn this many image widths long for the largest residual of the set (one scale for every
#: panel, stated in a key arrow).
ARROW_SHARE = 0.12
#: The images behind the residual vectors are drawn this opaque (dimmed, so that the arrows stay readable).
IMAGE_ALPHA = 0.35
#: Texts may overlap or leave the figure by this much (px at the saved resolution) before :func:`text_problems`
#: reports them (anti-aliasing and rounding of the extents).
TEXT_SLACK_PX = 1.0
#: Colour map for magnitudes (perceptually uniform, readable in grey).
CMAP = "viridis"
#: Text properties of every name drawn: literal text (no mathtext, no TeX).
PLAIN_TEXT = {"parse_math": False, "usetex": False}
#: A name drawn in a figure is shortened to this many characters (the middle replaced by an ellipsis); the tables
#: give it in full.
NAME_CHARS = 32


def name_label(name: str, limit: int = NAME_CHARS) -> str:
    """A file name as a figure label, printable and short.

    :func:`~circcal.pathnames.display_name`, and if longer than ``limit`` characters its start and end (where image
    series keep their numbers and extensions) around an ellipsis. Draw it with :data:`PLAIN_TEXT`.

    Parameters
    ----------
    name : str
        The file name.
    limit : int
        Longest label, characters.

    Returns
    -------
    str
    """
    s = display_name(name)
    if len(s) <= limit:
        return s
    head = (limit - 1) // 2
    return s[:head] + "\u2026" + s[len(s) - (limit - 1 - head) :]


def _figure(width_in: float, height_in: float) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), layout="constrained")


def save_png(fig: Any, path: str | Path) -> Path:
    """Write a figure as PNG atomically (folders made); no software stamp.

    A character of a name that the font lacks (an emoji) is drawn as a box without a warning: the report's tables give
    it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : str or Path

    Returns
    -------
    Path
        ``path``.
    """
    import matplotlib

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    with matplotlib.rc_context(STYLE), warnings.catch_warnings():
        warnings.filterwarnings("ignore", r"Glyph \d+ .*missing from font", UserWarning)
        fig.savefig(buf, format="png", metadata={"Software": None})
    atomic.write_bytes(path, buf.getvalue())
    return path


def _drawn_texts(fig: Any, renderer: Any) -> list[tuple[str, Any]]:
    """Every text ``fig`` draws, with its window extent: visible, non-empty, and for tick labels only the ticks the
    axis draws (matplotlib keeps labels of ticks outside the view, undrawn)."""
    from matplotlib.text import Text

    ticks: dict[int, bool] = {}
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            drawn = {id(t) for t in axis._update_ticks()} if ax.axison and axis.get_visible() else set()
            for t in [*axis.get_major_ticks(), *axis.get_minor_ticks()]:
                for lab in (t.label1, t.label2):
                    ticks[id(lab)] = id(t) in drawn
    out = []
    for t in fig.findobj(Text):
        if not t.get_visible() or not t.get_text().strip() or not ticks.get(id(t), True):
            continue
        if t.axes is not None and not t.axes.get_visible():
            continue
        out.append((t.get_text(), t.get_window_extent(renderer)))
    return out


def text_problems(fig: Any) -> list[str]:
    """Texts of a figure, drawn as :func:`save_png` saves it, that leave the figure or overlap another text.

    Parameters
    ----------
    fig : matplotlib.figure.Figure

    Returns
    -------
    list of str
        One line per problem (the text, and where or what it overlaps); empty when every text is whole and apart.
    """
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    with matplotlib.rc_context(STYLE), warnings.catch_warnings():
        warnings.filterwarnings("ignore", r"Glyph \d+ .*missing from font", UserWarning)
        dpi = fig.dpi
        fig.set_dpi(matplotlib.rcParams["savefig.dpi"])
        try:
            canvas = FigureCanvasAgg(fig)
            canvas.draw()
            renderer = canvas.get_renderer()
            texts = _drawn_texts(fig, renderer)
            W, H = fig.bbox.width, fig.bbox.height
        finally:
            fig.set_dpi(dpi)
    e = TEXT_SLACK_PX
    out = []
    for label, b in texts:
        if b.x0 < -e or b.y0 < -e or b.x1 > W + e or b.y1 > H + e:
            out.append(
                f"{label!r} leaves the figure ({b.x0:.0f}..{b.x1:.0f} x {b.y0:.0f}..{b.y1:.0f} of {W:.0f}x{H:.0f} px)"
            )
    for i, (la, a) in enumerate(texts):
        for lb, b in texts[i + 1 :]:
            if min(a.x1, b.x1) - max(a.x0, b.x0) > e and min(a.y1, b.y1) - max(a.y0, b.y0) > e:
                out.append(f"{la!r} overlaps {lb!r}")
    return out


def _title(ax: Any, text: str, width_in: float) -> None:
    """A title wrapped to the axes' width (about 11 characters per inch at the style's title size)."""
    ax.set_title("\n".join(textwrap.wrap(text, max(20, int(11 * width_in)))))


def _image_axes(ax: Any, width: int, height: int) -> None:
    """Axes in image coordinates: the whole imager, y down, equal aspect, labelled in px."""
    ax.set_xlim(-0.5, width - 0.5)
    ax.set_ylim(height - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")


def _extent(uv: np.ndarray) -> list[float]:
    """imshow extent of a grid (H, W, 2) whose samples sit at pixel positions (cells centred on them)."""
    x, y = uv[0, :, 0], uv[:, 0, 1]
    dx = (x[-1] - x[0]) / max(len(x) - 1, 1)
    dy = (y[-1] - y[0]) / max(len(y) - 1, 1)
    return [x[0] - dx / 2, x[-1] + dx / 2, y[-1] + dy / 2, y[0] - dy / 2]


def _heat(
    ax: Any, uv: np.ndarray, values: np.ndarray, vmax: float, label: str, fig: Any, contours: Sequence[float] = ()
) -> None:
    im = ax.imshow(values, extent=_extent(uv), origin="upper", cmap=CMAP, vmin=0.0, vmax=vmax, interpolation="nearest")
    if contours:
        levels = [c for c in contours if 0 < c < np.nanmax(values)]
        if levels:
            cs = ax.contour(uv[..., 0], uv[..., 1], values, levels=levels, colors="white", linewidths=0.8)
            ax.clabel(cs, fmt=lambda v: f"{v:g}", fontsize=7)
    fig.colorbar(im, ax=ax, label=label, shrink=0.8)


def fig_uncertainty(unc: Any, width: int, height: int, points: np.ndarray | None = None) -> Any:
    """The projection-uncertainty map, observed points as dots.

    Parameters
    ----------
    unc : circcal.analysis.assess.UncertaintyMap
        1-sigma worst-direction uncertainty over the image, px.
    width, height : int
        Image size, px.
    points : ndarray, shape (N, 2), optional
        Observed points, px.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = _figure(6.4, 6.4 * height / width + 0.6)
    ax = fig.add_subplot()
    vmax = float(np.nanmax(unc.stdev)) or 1.0
    _heat(ax, unc.uv, unc.stdev, vmax, "1-sigma uncertainty, worst direction (px)", fig, contours=_nice_levels(vmax))
    if points is not None and len(points):
        ax.plot(points[:, 0], points[:, 1], ".", ms=1.5, color="white", alpha=0.5)
    _image_axes(ax, width, height)
    at = "at infinity" if unc.distance_mm is None else f"at {unc.distance_mm:g} mm"
    _title(
        ax,
        f"Projection uncertainty {at}: worst {unc.worst_px:.3g} px, centre {unc.centre_px:.3g} px "
        f"(noise {unc.sigma_px:.3g} px per coordinate; dots: observed points)",
        5.2,
    )
    return fig


def _nice_levels(vmax: float) -> list[float]:
    """Three round contour levels below ``vmax``."""
    if not (np.isfinite(vmax) and vmax > 0):
        return []
    step = 10 ** math.floor(math.log10(vmax / 3))
    for m in (1, 2, 5, 10):
        if vmax / (m * step) <= 4:
            step *= m
            break
    return [step * k for k in (1, 2, 3) if step * k < vmax]


def fig_coverage(cov: Any, points: np.ndarray) -> Any:
    """Where the observations lie: points per map cell, every observed point, the regions without any hatched.

    Parameters
    ----------
    cov : circcal.analysis.coverage.Coverage
        The coverage map.
    points : ndarray, shape (N, 2)
        Every observed point, px.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.patches import Rectangle

    w, h = cov.width, cov.height
    fig = _figure(6.4, 6.4 * h / w + 0.6)
    ax = fig.add_subplot()
    im = ax.imshow(
        cov.counts, extent=[-0.5, w - 0.5, h - 0.5, -0.5], origin="upper", cmap="Blues", interpolation="nearest", vmin=0
    )
    fig.colorbar(im, ax=ax, label="observed points per cell", shrink=0.8)
    if len(points):
        ax.plot(points[:, 0], points[:, 1], ".", ms=1.5, color="black")
    for e in cov.empty:
        (x0, x1), (y0, y1) = e["x_px"], e["y_px"]
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, hatch="//", edgecolor="tab:red", lw=1.2))
    for k in (1, 2):
        ax.axvline(k * w / 3 - 0.5, color="0.6", lw=0.6, ls=":")
        ax.axhline(k * h / 3 - 0.5, color="0.6", lw=0.6, ls=":")
    _image_axes(ax, w, h)
    n_empty = len(cov.empty)
    _title(
        ax,
        f"Coverage: {100 * cov.covered_share:.0f}% of the cells observed; "
        + (
            f"{n_empty} ninth(s) of the image without observations (hatched red)"
            if n_empty
            else "every ninth of the image observed (dotted: the ninths)"
        ),
        5.2,
    )
    return fig


def fig_view_bars(
    names: Sequence[str], rms: Sequence[float], heldout: Sequence[float] | None, n_rejected: Sequence[int]
) -> Any:
    """Per-view RMS residual per coordinate, and each view's held-out prediction error with cross-validation.

    Parameters
    ----------
    names : sequence of str
        The views' image names.
    rms : sequence of float
        RMS residual per coordinate per view, px.
    heldout : sequence of float, optional
        Held-out prediction error per view, px.
    n_rejected : sequence of int
        Points rejected per view.

    Returns
    -------
    matplotlib.figure.Figure
    """
    n = len(names)
    width_in = max(6.4, 0.45 * n + 2)
    fig = _figure(width_in, 3.8)
    ax = fig.add_subplot()
    x = np.arange(n)
    wbar = 0.4 if heldout is not None else 0.7
    ax.bar(x - (wbar / 2 if heldout is not None else 0), rms, wbar, label="fit residual", color="tab:blue")
    tops = np.asarray(rms, dtype=np.float64)
    if heldout is not None:
        ax.bar(x + wbar / 2, heldout, wbar, label="held out (predicted by the other views)", color="tab:orange")
        tops = np.fmax(tops, np.asarray(heldout, dtype=np.float64))
    tops = np.where(np.isfinite(tops), tops, 0.0)
    top = float(np.max(tops)) if n else 1.0
    if any(n_rejected):  # "N out" above each view's bars, inside the axes: never on the tick labels
        ax.set_ylim(0, 1.18 * top if top > 0 else 1.0)
        for i, k in enumerate(n_rejected):
            if k:
                ax.annotate(
                    f"{k} out",
                    (x[i], tops[i]),
                    xytext=(0, 2),
                    textcoords="offset points",
                    ha="center",
                    va="bottom",
                    fontsize=7 if n < 20 else 6,
                    color="tab:red",
                )
    ax.set_xticks(x, [name_label(n) for n in names], rotation=45, ha="right", fontsize=7, **PLAIN_TEXT)
    ax.set_ylabel("RMS per coordinate (px)")
    _title(
        ax,
        "Residuals per view (RMS per coordinate, mrcal's convention)"
        + ("; red: points left out" if any(n_rejected) else ""),
        width_in - 1.2,
    )
    fig.legend(loc="outside lower center", ncols=2, fontsize=8, frameon=False)
    return fig


def fig_residual_vectors(
    names: Sequence[str],
    points: Sequence[np.ndarray],
    residuals: Sequence[np.ndarray],
    rejected: Sequence[np.ndarray],
    width: int,
    height: int,
    images: Sequence[np.ndarray | None] | None = None,
) -> Any:
    """One panel per view: each point's residual (observed - projected) as an arrow over the view's image (dimmed),
    axes in image pixels.

    One arrow scale for every panel (a key arrow in the first panel's lower right); rejected points as red crosses.

    Parameters
    ----------
    names : sequence of str
        The views' image names.
    points : sequence of ndarray, shape (N_v, 2)
        Observed points per view, px.
    residuals : sequence of ndarray, shape (N_v, 2)
        Residuals per view, px.
    rejected : sequence of ndarray, shape (M_v, 2)
        The rejected points of each view, px (NaN rows, a dot the detector dropped unmeasured, are not drawn).
    width, height : int
        Image size, px.
    images : sequence of (ndarray or None), optional
        Each view's image (grey or colour, any size: drawn stretched over the whole imager, dimmed by
        :data:`IMAGE_ALPHA`); None where there is none.

    Returns
    -------
    matplotlib.figure.Figure
    """
    n = len(names)
    cols = min(VECTOR_COLUMNS, n)
    rows = int(math.ceil(n / cols))
    pw = 2.9
    fig = _figure(pw * cols + 0.6, (pw - 0.3) * height / width * rows + 0.5 * rows + 1.0)
    axes = fig.subplots(rows, cols, squeeze=False)
    big = max([float(np.max(np.linalg.norm(r, axis=1))) for r in residuals if len(r)] + [1e-12])
    scale = big / (ARROW_SHARE * width)  # px of residual per px of arrow
    for k, ax in enumerate(axes.ravel()):
        if k >= n:
            ax.set_axis_off()
            continue
        p, r = np.asarray(points[k]), np.asarray(residuals[k])
        img = images[k] if images is not None and k < len(images) else None
        if img is not None:
            ax.imshow(
                img,
                cmap="gray" if img.ndim == 2 else None,
                extent=[-0.5, width - 0.5, height - 0.5, -0.5],
                alpha=IMAGE_ALPHA,
                interpolation="antialiased",
            )
        ax.quiver(
            p[:, 0],
            p[:, 1],
            r[:, 0],
            -r[:, 1],
            angles="xy",
            scale_units="xy",
            scale=scale,
            width=0.004,
            color="tab:blue",
        )
        if len(rejected[k]):
            q = np.asarray(rejected[k])
            ax.plot(q[:, 0], q[:, 1], "x", color="tab:red", ms=5)
        ax.set_xlim(-0.5, width - 0.5)
        ax.set_ylim(height - 0.5, -0.5)
        ax.set_aspect("equal")
        ax.set_xticks([0, width // 2, width - 1])
        ax.set_yticks([0, height // 2, height - 1])
        ax.tick_params(labelsize=6, labelleft=k % cols == 0, labelbottom=k >= n - cols)
        ax.set_title(name_label(names[k]), fontsize=8, **PLAIN_TEXT)
        if k == 0:
            first = ax.collections[-1]
            first_ax = ax
    key = float(f"{big:.1g}")
    fig.suptitle(
        "\n".join(
            textwrap.wrap(
                f"Residual vectors (observed - projected) over each image, dimmed; one arrow scale for every panel, "
                f"the key arrow in the first panel is {key:g} px; largest {big:.3g} px; red x: left out",
                int(11 * (pw * cols + 0.6)),
            )
        ),
        fontsize=9,
    )
    fig.supxlabel("x (px)", fontsize=8)
    fig.supylabel("y (px)", fontsize=8)
    first_ax.quiverkey(
        first,
        0.72,
        0.1,
        key,
        f"{key:g} px",
        labelpos="N",
        coordinates="axes",
        color="black",
        fontproperties={"size": 7},
    )
    return fig


def fig_board_shape(nominal: np.ndarray, refined: np.ndarray, std: np.ndarray | None = None) -> Any:
    """The board's estimated shape (``--refine-board``): each point's departure from the nominal board.

    Colour: the out-of-plane departure (mm); arrows: the in-plane departure, exaggerated by one factor for every
    point (stated in the title and a key arrow).

    Parameters
    ----------
    nominal, refined : ndarray, shape (P, 3)
        The nominal and the estimated board points, mm (the refinement's gauge: its frame, not the nominal's).
    std : ndarray, shape (P, 3), optional
        Standard deviations of the estimate, mm (their largest out-of-plane one is stated).

    Returns
    -------
    matplotlib.figure.Figure
    """
    nominal = np.asarray(nominal, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(refined, dtype=np.float64).reshape(-1, 3) - nominal
    span = float(np.ptp(nominal[:, :2], axis=0).max()) or 1.0
    inplane = np.linalg.norm(d[:, :2], axis=1)
    big = float(np.max(inplane)) if len(d) else 0.0
    gain = float(f"{0.08 * span / big:.1g}") if big > 0 else 1.0  # the largest arrow ~8% of the board
    x0, x1 = float(nominal[:, 0].min()), float(nominal[:, 0].max())
    y0, y1 = float(nominal[:, 1].min()), float(nominal[:, 1].max())
    pad = 0.12 * span
    aspect = (y1 - y0 + 2 * pad) / (x1 - x0 + 2 * pad)
    fig = _figure(6.4, min(8.0, 5.0 * aspect + 1.4))
    ax = fig.add_subplot()
    zmax = float(np.max(np.abs(d[:, 2]))) or 1e-9
    sc = ax.scatter(
        nominal[:, 0],
        nominal[:, 1],
        c=d[:, 2],
        cmap="RdBu_r",
        vmin=-zmax,
        vmax=zmax,
        s=28,
        zorder=3,
        edgecolors="0.4",
        linewidths=0.5,
    )
    fig.colorbar(sc, ax=ax, label="out of plane, estimated - nominal (mm)", shrink=0.8)
    q = ax.quiver(
        nominal[:, 0],
        nominal[:, 1],
        d[:, 0] * gain,
        d[:, 1] * gain,
        angles="xy",
        scale_units="xy",
        scale=1.0,
        width=0.004,
        color="black",
        zorder=4,
    )
    key = float(f"{big:.1g}") if big > 0 else 0.0
    if key > 0:
        ax.quiverkey(
            q, 0.8, 0.04, key * gain, f"{key:g} mm", labelpos="N", coordinates="axes", fontproperties={"size": 7}
        )
    ax.set_xlim(x0 - pad, x1 + pad)
    ax.set_ylim(y1 + pad, y0 - pad)  # the board as its image shows it: y down
    ax.set_aspect("equal")
    ax.set_xlabel("board x (mm)")
    ax.set_ylabel("board y (mm)")
    sz = "" if std is None else f"; its largest out-of-plane sigma {float(np.max(np.asarray(std)[:, 2])):.2g} mm"
    _title(
        ax,
        f"Board shape (--refine-board): out of plane up to {zmax:.3g} mm (colour), in plane up to {big:.3g} mm "
        f"(arrows x{gain:g}){sz}",
        5.0,
    )
    return fig


def fig_histogram(residuals: np.ndarray, sigma: float) -> Any:
    """Residual coordinates (x and y pooled) against the Gaussian of the solve's noise estimate.

    Parameters
    ----------
    residuals : ndarray, shape (N, 2)
        px.
    sigma : float
        The solve's noise estimate per coordinate, px.

    Returns
    -------
    matplotlib.figure.Figure
    """
    r = np.asarray(residuals, dtype=np.float64).ravel()
    fig = _figure(6.4, 3.4)
    ax = fig.add_subplot()
    lim = max(float(np.max(np.abs(r))) if r.size else 1.0, 4 * sigma)
    bins = np.linspace(-lim, lim, 61)
    ax.hist(r, bins=bins, density=True, color="tab:blue", alpha=0.7, label=f"residuals ({r.size} coordinates)")
    x = np.linspace(-lim, lim, 400)
    ax.plot(
        x,
        np.exp(-0.5 * (x / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi)),
        color="tab:red",
        label=f"expected: Gaussian, sigma {sigma:.3g} px",
    )
    ax.set_xlabel("residual coordinate, observed - projected (px)")
    ax.set_ylabel("density (1/px)")
    ax.set_title("Residual distribution against the noise model")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    return fig


def fig_correlation(corr: np.ndarray, names: Sequence[str]) -> Any:
    """The parameters' correlation matrix (held parameters blank).

    Parameters
    ----------
    corr : ndarray, shape (P, P)
        NaN for held parameters.
    names : sequence of str
        The P parameter names.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = _figure(4.6, 3.9)
    ax = fig.add_subplot()
    im = ax.imshow(np.asarray(corr, dtype=np.float64), cmap="RdBu_r", vmin=-1, vmax=1)
    ax.set_xticks(range(len(names)), names, rotation=45, ha="right")
    ax.set_yticks(range(len(names)), names)
    for i in range(len(names)):
        for j in range(len(names)):
            v = corr[i][j]
            if v is not None and np.isfinite(v):
                ax.text(
                    j, i, f"{v:.2f}", ha="center", va="center", fontsize=6, color="white" if abs(v) > 0.6 else "black"
                )
    fig.colorbar(im, ax=ax, label="correlation", shrink=0.9)
    ax.set_title("Parameter correlations")
    return fig


def fig_diff(d: Any, width: int, height: int, title: str) -> Any:
    """A projection difference: the difference map and, with both uncertainties, the combined uncertainty.

    The combined uncertainty is drawn on the same colour scale, with the ratio and its 2x contour.

    Parameters
    ----------
    d : circcal.analysis.diff.ModelDiff
    width, height : int
        Image size, px.
    title : str
        The figure's title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    with_unc = d.ratio is not None
    panels = 3 if with_unc else 1
    pw = 4.2
    fig = _figure(pw * panels + 0.6, pw * height / width + 1.2)
    axes = fig.subplots(1, panels, squeeze=False)[0]
    vmax = float(np.nanpercentile(d.diff, 99))
    if with_unc:
        comb = d.sigma_a + d.sigma_b
        vmax = max(vmax, float(np.nanpercentile(comb, 99)))
    vmax = vmax if np.isfinite(vmax) and vmax > 0 else 1.0
    _heat(axes[0], d.uv, d.diff, vmax, "difference (px)", fig, contours=_nice_levels(vmax))
    _title(axes[0], f"Difference: RMS {d.rms_px:.3g}, p95 {d.p95_px:.3g}, max {d.max_px:.3g} px", 3.2)
    _image_axes(axes[0], width, height)
    if with_unc:
        _heat(axes[1], d.uv, comb, vmax, "sigma A + sigma B (px)", fig, contours=_nice_levels(vmax))
        _title(axes[1], "Combined uncertainty (the same colour scale)", 3.2)
        _image_axes(axes[1], width, height)
        rmax = max(3.0, float(np.nanpercentile(d.ratio, 99)))
        _heat(axes[2], d.uv, d.ratio, rmax, "difference / combined uncertainty", fig, contours=[2.0])
        _title(axes[2], f"Ratio: within 2x over {100 * d.share_within:.1f}% of the image (white: 2x)", 3.2)
        _image_axes(axes[2], width, height)
    at = "at infinity" if d.distance_mm is None else f"at {d.distance_mm:g} mm"
    fit = (
        "fitted over the whole image"
        if d.focus_radius_px is None
        else ("not fitted" if d.focus_radius_px == 0 else f"fitted within {d.focus_radius_px:g} px of the centre")
    )
    fig.suptitle(
        "\n".join(textwrap.wrap(f"{title} ({at}; implied transformation {fit})", int(11 * pw * panels))), fontsize=10
    )
    return fig


def fig_crossval(cv: Any, width: int, height: int) -> Any:
    """The cross-validation's difference map between the two halves (:func:`fig_diff`).

    Parameters
    ----------
    cv : circcal.analysis.cross.CrossValidation
    width, height : int
        Image size, px.

    Returns
    -------
    matplotlib.figure.Figure
    """
    a, b = cv.halves
    return fig_diff(
        cv.diff, width, height, f"Cross-validation: half B ({len(b)} views) against half A ({len(a)} views)"
    )
