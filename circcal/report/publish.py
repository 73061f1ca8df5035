"""The whole report: :func:`compute` gathers every number (deterministic: fixed fixtures, fixed seeds, no clocks in
the numbers; run times kept apart in ``timings``); :func:`write_report` turns them into ``index.md``, a
self-contained ``index.html``, the PNG figures, ``report.json`` and ``timings.json``, written atomically (a temporary
folder beside the target, renamed into place: a failure leaves the previous report untouched); :func:`generate`
does both and updates the index ``README.md`` of the reports folder.

The document and the figures are drawn from report.json's tree as written (read back), plus the run times, so the
published text holds nothing report.json and timings.json do not.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from circcal import atomic
from circcal.jsonio import jsonable
from circcal.outputs import Outputs
from circcal.report import render
from circcal.report.bias import bias_study
from circcal.report.capture import study_warnings
from circcal.report.checkerboard import checkerboard_condition
from circcal.report.config import FULL, PAPER_PUBLISHED, QUICK, ReportConfig
from circcal.report.document import TITLE, document
from circcal.report.environment import environment
from circcal.report.figures import make_figures
from circcal.report.paper import paper_condition
from circcal.report.precision import CHECK_QUANTUM, precision_note, quantise, round_sig
from circcal.report.prose import header_line, headline
from circcal.report.realdata import realdata_entry
from circcal.report.rendered import fixture_summary
from circcal.report.studies import study_results

__all__ = ["compute", "generate", "published_results", "write_report"]


def _each(
    names: tuple[str, ...], study: Callable[[str], tuple[Any, Any]], prefix: str, log: dict, desc: str, progress: bool
) -> tuple[dict[str, Any], dict[str, Any]]:
    """``study(name)`` -> (numbers, run times) for every name, each under its own warning capture
    (``log["<prefix>/<name>"]``)."""
    from tqdm import tqdm

    out, times = {}, {}
    for name in tqdm(names, desc=f"report: {desc}", unit=desc.split()[-1], disable=not progress):
        with study_warnings(log, f"{prefix}/{name}"):
            out[name], times[name] = study(name)
    return out, times


def _trim_checks(paper: dict[str, Any]) -> None:
    """Agreement values of 1e-12..1e-6 px move between runs (threaded reductions in the solvers) and a passing
    check's note says which side of the px bound it landed: quantise them, and keep them only when a check fails."""
    for condition in paper.values():
        for ch in condition["checks"]:
            ch["value"] = quantise(ch["value"], CHECK_QUANTUM)
            if ch["passed"]:
                ch.pop("value")
                ch.pop("note")


def compute(cfg: ReportConfig = FULL, *, progress: bool = True) -> dict[str, Any]:
    """Every number of the report (JSON-ready, :data:`~circcal.report.precision.SIG_DIGITS` significant digits).

    ``result["warnings"]`` holds what each study warned (:func:`~circcal.report.capture.study_warnings`);
    ``result["timings"]`` holds run times (s) and is the only part that changes from run to run: :func:`write_report`
    keeps it out of ``report.json``.

    Parameters
    ----------
    cfg : ReportConfig
        What the run covers (:data:`~circcal.report.config.FULL` or ``QUICK``).
    progress : bool

    Returns
    -------
    dict
    """
    log: dict[str, list] = {}
    timings: dict[str, Any] = {}
    t0 = time.perf_counter()
    paper, timings["paper"] = _each(
        cfg.conditions, lambda v: paper_condition(v, cfg, progress=False), "paper", log, "paper conditions", progress
    )
    cb, timings["checkerboard"] = _each(
        cfg.checkerboard_conditions,
        lambda v: checkerboard_condition(v, cfg, progress=False),
        "checkerboard",
        log,
        "checkerboard conditions",
        progress,
    )
    with study_warnings(log, "bias"):
        bias, timings["bias"] = bias_study(cfg, progress=progress)
    real, timings["realdata"] = _each(
        cfg.realdata, lambda n: realdata_entry(n, cfg), "realdata", log, "real sets", progress
    )
    timings["total_compute_s"] = time.perf_counter() - t0
    _trim_checks(paper)
    fixtures = {s: fixture_summary(s) for s in ("paper", "paper-checkerboard")}
    numbers = round_sig(
        jsonable(
            {
                "config": asdict(cfg),
                "fixtures": fixtures,
                "paper": paper,
                "checkerboard": cb,
                "paper_published": PAPER_PUBLISHED,
                "bias": bias,
                "realdata": real,
                "studies": study_results(cfg),
                "warnings": log,
                "environment": environment(),
            }
        )
    )
    numbers["precision"] = precision_note()
    numbers["timings"] = jsonable(timings)
    return numbers


def _report_json(results: dict[str, Any]) -> str:
    """report.json: every number but the run times, keys sorted (the file is the same for the same numbers)."""
    return json.dumps({k: v for k, v in results.items() if k != "timings"}, indent=1, sort_keys=True) + "\n"


def published_results(report_json: str, timings: dict[str, Any]) -> dict[str, Any]:
    """The results as the document is drawn from them.

    Parameters
    ----------
    report_json : str
        report.json's text.
    timings : dict
        timings.json's ``{"date", "timings"}``.

    Returns
    -------
    dict
        report.json's tree read back, with the run times.
    """
    return {**json.loads(report_json), "timings": timings.get("timings")}


def write_report(
    results: dict[str, Any],
    out_dir: str | Path,
    *,
    name: str = "latest",
    header: str | None = None,
    date: str | None = None,
) -> Path:
    """Write ``out_dir/name/`` atomically, then update ``out_dir/README.md``.

    The folder holds index.md, index.html, the PNG figures, report.json and timings.json; it is written into a
    temporary folder beside the target and renamed into place (a failure leaves the previous report untouched).

    Parameters
    ----------
    results : dict
        :func:`compute`'s output.
    out_dir : str or Path
        The reports folder.
    name : str
        The run folder's name.
    header : str, optional
        The line under the title; default: when and by which command.
    date : str, optional
        When the numbers were computed; default now (give timings.json's to re-render a report with the current
        code).

    Returns
    -------
    Path
        ``out_dir / name``.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()) if date is None else date
    stamped = {"date": date, "timings": results.get("timings")}
    text = _report_json(results)
    published = published_results(text, stamped)
    kind = published["config"]["name"]
    header = header_line(kind, date) if header is None else header
    with Outputs() as outputs:  # the folder and the index committed together (circcal.outputs)
        tmp = outputs.folder(out_dir / name, "--out", kind="comparison-report")
        readme = outputs.file(out_dir / "README.md", "--out")
        (tmp / "report.json").write_text(text)
        (tmp / "timings.json").write_text(json.dumps(stamped, indent=1) + "\n")
        files = make_figures(published, tmp)
        blocks = document(published, header)
        (tmp / "index.md").write_text(render.to_markdown(blocks))
        images = {f: (tmp / f).read_bytes() for f in files}
        (tmp / "index.html").write_text(render.to_html(blocks, images, title=TITLE))
        atomic.write_text(readme, render.readme(name=name, date=date, kind=kind, headline=headline(published)))
        outputs.commit()
    return out_dir / name


def generate(
    out: str | Path = "reports", *, quick: bool = False, progress: bool = True, config: ReportConfig | None = None
) -> Path:
    """Compute and write the report into ``out/latest``.

    Parameters
    ----------
    out : str or Path
        The reports folder.
    quick : bool
        Use :data:`~circcal.report.config.QUICK`.
    progress : bool
    config : ReportConfig, optional
        Overrides ``quick``.

    Returns
    -------
    Path
        ``out/latest``.

    Examples
    --------
    >>> generate("reports", quick=True)  # doctest: +SKIP
    """
    return write_report(compute(config or (QUICK if quick else FULL), progress=progress), out)
