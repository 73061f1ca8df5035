"""A study summary's figures, drawn with matplotlib's object API (``matplotlib.figure.Figure``, no pyplot and so no
global state: safe in workers, threads and tests).

* ``ratio.png``: empirical spread / mean stated sigma per cell and parameter, with its interval (1 = honest);
* ``bias.png``: mean error / mean stated sigma per cell and parameter, with its interval (0 = unbiased);
* ``pass_rate.png``: the truth-check pass rate per cell with Wilson's interval, beside what an honest estimator gets.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from circcal import atomic
from circcal.study.cells import TABLE_PARAMS, CellSummary

__all__ = ["draw_figures"]

#: Inches per cell row and the fixed part of a figure's height; the width fits the labels of a typical study.
ROW_IN, BASE_IN, WIDTH_IN = 0.32, 1.4, 9.0
DPI = 110


def _save(fig, path: Path) -> Path:
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    atomic.write_bytes(path, buf.getvalue())
    return path


def _per_param(
    cells: Sequence[CellSummary], value: str, interval: str, ref: float, xlabel: str, title: str, path: Path
) -> Path:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(WIDTH_IN, BASE_IN + ROW_IN * len(cells) * 1.2))
    ax = fig.add_subplot()
    y = np.arange(len(cells), dtype=float)
    step = 0.8 / len(TABLE_PARAMS)
    for j, p in enumerate(TABLE_PARAMS):
        v = np.array([getattr(c.params[p], value) for c in cells])
        ci = np.array([getattr(c.params[p], interval) for c in cells], dtype=float).reshape(-1, 2)
        err = np.abs(np.stack([v - ci[:, 0], ci[:, 1] - v]))
        err[~np.isfinite(err)] = 0.0
        ax.errorbar(v, y + (j - (len(TABLE_PARAMS) - 1) / 2) * step, xerr=err, fmt="o", ms=3, capsize=2, label=p)
    ax.axvline(ref, color="k", lw=0.8)
    ax.set_yticks(y, [c.label for c in cells], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel(f"{xlabel}: {title}")
    ax.legend(fontsize=7, ncols=len(TABLE_PARAMS), loc="lower center", bbox_to_anchor=(0.5, 1.06), frameon=False)
    fig.tight_layout()
    return _save(fig, path)


def _pass_rate(cells: Sequence[CellSummary], path: Path) -> Path:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(WIDTH_IN, BASE_IN + ROW_IN * len(cells)))
    ax = fig.add_subplot()
    y = np.arange(len(cells), dtype=float)
    v = np.array([c.pass_rate for c in cells])
    ci = np.array([c.pass_ci for c in cells], dtype=float).reshape(-1, 2)
    err = np.abs(np.stack([v - ci[:, 0], ci[:, 1] - v]))
    err[~np.isfinite(err)] = 0.0
    ax.errorbar(v, y, xerr=err, fmt="o", ms=4, capsize=2, label="measured")
    ax.plot([c.pass_expected for c in cells], y, "k|", ms=10, label="honest estimator")
    ax.set_yticks(y, [c.label for c in cells], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(max(0.0, float(np.nanmin(ci[:, 0])) - 0.05) if np.isfinite(ci).any() else 0.0, 1.005)
    ax.set_xlabel("share of runs with fx, fy, cx, cy within 3 stated sigmas of the truth")
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return _save(fig, path)


def draw_figures(cells: Sequence[CellSummary], folder: str | Path) -> dict[str, Path]:
    """Draw the figures of cells into a folder.

    Parameters
    ----------
    cells : sequence of CellSummary
    folder : str or Path

    Returns
    -------
    dict of str to Path
        Title -> file (nothing for no cells).
    """
    cells = [c for c in cells if c.n_ok]
    if not cells:
        return {}
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return {
        "Sigma honesty (empirical / stated, 95 % interval)": _per_param(
            cells,
            "ratio",
            "ratio_ci",
            1.0,
            "empirical spread / mean stated sigma",
            "sigma honesty per cell (1 = honest)",
            folder / "ratio.png",
        ),
        "Bias in stated sigmas (95 % interval)": _per_param(
            cells,
            "bias_sigmas",
            "bias_sigmas_ci",
            0.0,
            "mean error / mean stated sigma",
            "bias per cell (0 = unbiased)",
            folder / "bias.png",
        ),
        "Truth-check pass rate (Wilson 95 % interval)": _pass_rate(cells, folder / "pass_rate.png"),
    }
