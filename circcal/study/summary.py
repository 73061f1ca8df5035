"""A finished study's summary: per cell, the bias and spread of each parameter against its stated sigma, the
empirical/stated ratio with its interval, and the truth-check pass rate; as data, Markdown and figures.

A *cell* here is (kind, scenario, variant, calibrator, lens model): the rows that differ only by seed. Per
parameter (over the cell's "ok" rows): ``bias`` = mean(estimate - truth) with its t interval; ``spread`` = the
standard deviation of the estimates (ddof 1) with its chi-square interval; ``stated`` = the mean stated sigma;
``ratio`` = spread / stated, its interval that of the spread over the same ``stated`` (the stated sigmas' own
scatter between draws is a few per cent and left out); ``bias_sigmas`` = bias / stated. An honest, unbiased
calibrator has ratio 1 and bias 0 within their intervals. ``pass`` = the share of runs whose fx, fy, cx, cy all lie
within :data:`circcal.validators.checks.TRUTH_SIGMAS` stated sigmas of the truth (the conformance suite's primary
check), with Wilson's interval; ``pass_expected`` what an honest Gaussian estimator gets, taking the four as
independent. Intervals: :mod:`circcal.study.stats` (95 %).

:func:`study_section` is what a published report includes (Markdown + figure files).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from circcal import atomic
from circcal.jsonio import dumps
from circcal.model import PARAM_NAMES
from circcal.study.cells import CELL_COLUMNS, TABLE_PARAMS, CellSummary, ParamSummary
from circcal.study.figures import draw_figures
from circcal.study.stats import CONFIDENCE, mean_interval, std_interval, wilson_interval
from circcal.validators.checks import TRUTH_PARAMS, TRUTH_SIGMAS

__all__ = [
    "CELL_COLUMNS",
    "TABLE_PARAMS",
    "CellSummary",
    "ParamSummary",
    "StudySection",
    "study_section",
    "summarise",
    "summary_markdown",
    "write_summary",
]


def _honest_pass_probability(sigmas: float, n_params: int) -> float:
    """P(|z| <= sigmas) ** n_params for standard normal z: the pass rate of an honest estimator."""
    return math.erf(sigmas / math.sqrt(2.0)) ** n_params


def _param(err: np.ndarray, std: np.ndarray) -> ParamSummary:
    b, blo, bhi = mean_interval(err)
    s, slo, shi = std_interval(err)
    stated = float(np.nanmean(std)) if np.isfinite(std).any() else float("nan")
    ok = np.isfinite(stated) and stated > 0

    def per(v: float) -> float:
        return v / stated if ok else float("nan")

    return ParamSummary(
        int(np.isfinite(err).sum()),
        b,
        (blo, bhi),
        s,
        (slo, shi),
        stated,
        per(s),
        (per(slo), per(shi)),
        per(b),
        (per(blo), per(bhi)),
    )


def summarise(table: Any) -> list[CellSummary]:
    """The cells of a study table, in order of first row.

    Parameters
    ----------
    table : pyarrow.Table
        :mod:`circcal.study.rows` columns.

    Returns
    -------
    list of CellSummary
    """
    if table.num_rows == 0:
        return []
    ids = list(zip(*(table.column(c).to_pylist() for c in CELL_COLUMNS)))
    status = np.asarray(table.column("status").to_pylist())
    col = {
        n: table.column(n).to_numpy(zero_copy_only=False).astype(np.float64)
        for n in [f"err_{p}" for p in PARAM_NAMES] + [f"std_{p}" for p in PARAM_NAMES] + ["truth_rms_px", "time_s"]
    }
    order: dict[tuple, list[int]] = {}
    for i, k in enumerate(ids):
        order.setdefault(k, []).append(i)
    out = []
    for k, rows in order.items():
        idx = np.asarray(rows)
        ok = idx[status[idx] == "ok"]
        cell = CellSummary(*k, n_runs=len(idx), n_ok=len(ok))
        cell.statuses = {s: int((status[idx] == s).sum()) for s in sorted(set(status[idx]))}
        for p in PARAM_NAMES:
            cell.params[p] = _param(col[f"err_{p}"][ok], col[f"std_{p}"][ok])
        if len(ok):
            z = np.stack([np.abs(col[f"err_{p}"][ok]) / col[f"std_{p}"][ok] for p in TRUTH_PARAMS])
            passed = np.all(np.isfinite(z) & (z <= TRUTH_SIGMAS), axis=0)
            p, lo, hi = wilson_interval(int(passed.sum()), len(ok))
            cell.pass_rate, cell.pass_ci = p, (lo, hi)
            cell.pass_expected = _honest_pass_probability(TRUTH_SIGMAS, len(TRUTH_PARAMS))
            t = col["truth_rms_px"][ok]
            t = t[np.isfinite(t)]
            if t.size:
                cell.truth_rms_median_px = float(np.median(t))
                cell.truth_rms_p95_px = float(np.percentile(t, 95))
        times = col["time_s"][idx]
        if np.isfinite(times).any():
            cell.time_median_s = float(np.nanmedian(times))
        out.append(cell)
    return out


def _ci(v: float, ci: tuple[float, float], fmt: str = ".3f") -> str:
    if not np.isfinite(v):
        return "-"
    if not (np.isfinite(ci[0]) and np.isfinite(ci[1])):
        return f"{v:{fmt}}"
    return f"{v:{fmt}} [{ci[0]:{fmt}}, {ci[1]:{fmt}}]"


def summary_markdown(
    name: str, description: str, cells: list[CellSummary], *, figures: dict[str, str] | None = None, heading: str = "#"
) -> str:
    """The Markdown of a study summary.

    Parameters
    ----------
    name, description : str
    cells : list of CellSummary
    figures : dict of str to str, optional
        Title -> relative path of each figure to show.
    heading : str
        The Markdown level of the title (``"##"`` to nest it in a report).

    Returns
    -------
    str
    """
    sub = heading + "#"
    conf = f"{100 * CONFIDENCE:.0f} %"
    n_runs, n_ok = sum(c.n_runs for c in cells), sum(c.n_ok for c in cells)
    lines = [f"{heading} Study `{name}`", ""]
    if description:
        lines += [description.strip(), ""]
    lines += [
        (
            f"{n_runs} runs in {len(cells)} cells, {n_ok} calibrated (status ok). Intervals: {conf}. A cell is "
            "one scenario, variant, calibrator and lens model over its seeds."
        ),
        "",
    ]
    head = "| cell | ok / runs | " + " | ".join(TABLE_PARAMS) + " |"
    rule = "|---|---|" + "---|" * len(TABLE_PARAMS)
    lines += [
        f"{sub} Sigma honesty: empirical spread / mean stated sigma",
        "",
        "1 = the stated standard deviations are honest; below 1 they are pessimistic, above 1 optimistic.",
        "",
        head,
        rule,
    ]
    for c in cells:
        lines.append(
            f"| {c.label} | {c.n_ok} / {c.n_runs} | "
            + " | ".join(_ci(c.params[p].ratio, c.params[p].ratio_ci) for p in TABLE_PARAMS)
            + " |"
        )
    lines += [
        "",
        f"{sub} Bias: mean error / mean stated sigma",
        "",
        "0 = unbiased. The interval is that of the mean error over the seeds, in stated sigmas.",
        "",
        head,
        rule,
    ]
    for c in cells:
        lines.append(
            f"| {c.label} | {c.n_ok} / {c.n_runs} | "
            + " | ".join(_ci(c.params[p].bias_sigmas, c.params[p].bias_sigmas_ci) for p in TABLE_PARAMS)
            + " |"
        )
    lines += [
        "",
        f"{sub} Parameters: bias and spread in their own units",
        "",
        "| cell | parameter | bias | spread (std) | mean stated sigma |",
        "|---|---|---|---|---|",
    ]
    for c in cells:
        for p in TABLE_PARAMS:
            s = c.params[p]
            lines.append(
                f"| {c.label} | {p} | {_ci(s.bias, s.bias_ci, '.4g')} | {_ci(s.spread, s.spread_ci, '.4g')}"
                f" | {s.stated:.4g} |"
            )
    lines += [
        "",
        f"{sub} Truth check and projection difference to the true camera",
        "",
        (
            f"Pass: fx, fy, cx, cy all within {TRUTH_SIGMAS:g} stated sigmas of the truth (the conformance suite's "
            "check); expected: an honest Gaussian estimator, the four taken as independent. Projection difference: "
            "RMS over the imager, implied rotation fitted."
        ),
        "",
        "| cell | pass rate | expected | truth RMS median px | p95 px | median run time s | statuses |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in cells:
        st = ", ".join(f"{k} {v}" for k, v in c.statuses.items())
        lines.append(
            f"| {c.label} | {_ci(c.pass_rate, c.pass_ci)} | {c.pass_expected:.3f} | "
            f"{c.truth_rms_median_px:.4g} | {c.truth_rms_p95_px:.4g} | {c.time_median_s:.3g} | {st} |"
        )
    for title, path in (figures or {}).items():
        lines += ["", f"![{title}]({path})"]
    return "\n".join(lines) + "\n"


@dataclass
class StudySection:
    """A study's part of a report.

    Attributes
    ----------
    markdown : str
        Its figures linked relative to ``figures_dir``'s parent.
    figures : dict of str to Path
        Title -> file.
    cells : list of CellSummary
    """

    markdown: str
    figures: dict[str, Path]
    cells: list[CellSummary]


def study_section(folder: str | Path, figures_dir: str | Path | None = None, *, heading: str = "##") -> StudySection:
    """The summary of a finished study, with its figures.

    Only the rows of its current spec (``study.yaml``) count; without a spec file, every stored row.

    Parameters
    ----------
    folder : str or Path
        The study folder.
    figures_dir : str or Path, optional
        Where the figures are drawn; default ``folder/figures``. They are linked relative to its parent.
    heading : str
        The Markdown level of the title.

    Returns
    -------
    StudySection

    Raises
    ------
    circcal.errors.InputError
        A ``study.yaml`` that cannot be read or checked (:func:`circcal.study.spec.load_spec`).
    """
    folder = Path(folder)
    table, spec = _table_of(folder)
    cells = summarise(table)
    figures_dir = Path(figures_dir) if figures_dir is not None else folder / "figures"
    figs = draw_figures(cells, figures_dir)
    rel = {t: f"{figures_dir.name}/{p.name}" for t, p in figs.items()}
    md = summary_markdown(
        spec.name if spec else folder.name, spec.description if spec else "", cells, figures=rel, heading=heading
    )
    return StudySection(md, figs, cells)


def _table_of(folder: Path) -> tuple[Any, Any]:
    """The stored rows of the study in ``folder`` that belong to its spec (``study.yaml``), and the spec."""
    import pyarrow as pa

    from circcal.study.engine import study_keys
    from circcal.study.spec import load_spec
    from circcal.study.store import RowStore

    table = RowStore(folder).read()
    spec_file = folder / "study.yaml"
    if not spec_file.exists():
        return table, None
    spec = load_spec(spec_file)
    keys = study_keys(spec)
    mask = pa.array([k in keys for k in table.column("key").to_pylist()], type=pa.bool_())
    return table.filter(mask), spec


def write_summary(folder: str | Path) -> Path:
    """Write ``summary.md``, ``summary.json`` and ``figures/*.png`` into a study folder.

    Parameters
    ----------
    folder : str or Path

    Returns
    -------
    Path
        summary.md.

    Raises
    ------
    circcal.errors.InputError
        As :func:`study_section`.
    """
    folder = Path(folder)
    section = study_section(folder, heading="#")
    atomic.write_text(folder / "summary.md", section.markdown)
    atomic.write_text(folder / "summary.json", dumps([asdict(c) for c in section.cells], indent=1))
    return folder / "summary.md"
