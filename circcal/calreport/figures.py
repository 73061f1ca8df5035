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
]

#: rcParams every figure is drawn under.
STYLE = {"figure.dpi": 100, "savefig.dpi": 110, "font.size": 9, "axes.titlesize": 10, "svg.hashsalt": "circcal"}
#: Residual-vector panels per row.
VECTOR_COLUMNS = 4
#: A residual arrow is drawn this many image widths long for the largest residual of the set (one scale for every
#: panel, stated in a key arrow).
ARROW_SHARE = 0.12
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
    fig = _figure(max(6.4, 0.45 * n + 2), 3.4)
    ax = fig.add_subplot()
    x = np.arange(n)
    wbar = 0.4 if heldout is not None else 0.7
    ax.bar(x - (wbar / 2 if heldout is not None else 0), rms, wbar, label="fit residual", color="tab:blue")
    if heldout is not None:
        ax.bar(x + wbar / 2, heldout, wbar, label="held out (predicted by the other views)", color="tab:orange")
    for i, k in enumerate(n_rejected):
        if k:
            ax.annotate(
                f"{k} out",
                (x[i], 0),
                xytext=(0, -24),
                textcoords="offset points",
                ha="center",
                fontsize=7,
                color="tab:red",
            )
    ax.set_xticks(x, [name_label(n) for n in names], rotation=45, ha="right", fontsize=7, **PLAIN_TEXT)
    ax.set_ylabel("RMS per coordinate (px)")
    ax.set_title("Residuals per view (RMS per coordinate, mrcal's convention)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    return fig


def fig_residual_vectors(
    names: Sequence[str],
    points: Sequence[np.ndarray],
    residuals: Sequence[np.ndarray],
    rejected: Sequence[np.ndarray],
    width: int,
    height: int,
) -> Any:
    """One panel per view: each point's residual (observed - projected) as an arrow.

    One arrow scale for every panel (key arrow in the first); rejected points as red crosses.

    Parameters
    ----------
    names : sequence of str
        The views' image names.
    points : sequence of ndarray, shape (N_v, 2)
        Observed points per view, px.
    residuals : sequence of ndarray, shape (N_v, 2)
        Residuals per view, px.
    rejected : sequence of ndarray, shape (N_v,)
        bool, rejected points per view.
    width, height : int
        Image size, px.

    Returns
    -------
    matplotlib.figure.Figure
    """
    n = len(names)
    cols = min(VECTOR_COLUMNS, n)
    rows = int(math.ceil(n / cols))
    pw = 2.6
    fig = _figure(pw * cols + 0.4, pw * height / width * rows + 0.9)
    axes = fig.subplots(rows, cols, squeeze=False)
    big = max([float(np.max(np.linalg.norm(r, axis=1))) for r in residuals if len(r)] + [1e-12])
    scale = big / (ARROW_SHARE * width)  # px of residual per px of arrow
    for k, ax in enumerate(axes.ravel()):
        if k >= n:
            ax.set_axis_off()
            continue
        p, r = np.asarray(points[k]), np.asarray(residuals[k])
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
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(name_label(names[k]), fontsize=8, **PLAIN_TEXT)
        if k == 0:
            first = ax.collections[0]
    key = float(f"{big:.1g}")
    fig.suptitle(
        f"Residual vectors over each image (one arrow scale for all panels; largest {big:.3g} px; red x: "
        f"left out as outliers)",
        fontsize=9,
    )
    fig.supxlabel(f"key: the arrow on the right is {key:g} px of residual", fontsize=8)
    axes.ravel()[0].quiverkey(
        first, 0.78, 0.012, key, f"{key:g} px", labelpos="E", coordinates="figure", fontproperties={"size": 8}
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
