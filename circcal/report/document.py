"""The report as blocks (:mod:`circcal.report.blocks`), built from the results alone: the JSON tree report.json
holds, plus the run times. The same blocks become index.md and index.html (:mod:`circcal.report.render`)."""

from __future__ import annotations

from typing import Any

from circcal.report import prose, realdata_prose
from circcal.report.blocks import Block, Bullets, Heading, Image, Paragraph
from circcal.report.figures import figure_files
from circcal.report.notes import bias_notes, paper_notes, realdata_notes
from circcal.report.results import dig, paper_conditions, realdata_sets
from circcal.report.tables import (
    bias_table,
    condition_table,
    parameter_table,
    realdata_table,
    study_tables,
    timings_table,
)

__all__ = ["document"]

TITLE = "circcal comparison report"


def _paper_section(results: dict[str, Any], caption: dict[str, str]) -> list[Block]:
    out: list[Block] = [
        Heading(2, "1. The paper's Table 7 on rendered fixtures"),
        Heading(3, "Mean reprojection error, mean 2-D (the paper's convention), px"),
        condition_table(results, lambda r: dig(r, "errors", "mean_2d_px"), published=True),
        Paragraph(
            "The paper's own numbers come from real photographs of its boards, ours from renders of the same "
            "geometry: compare orders of magnitude and rankings, not digits. Our renders carry little noise, "
            "so the residual mostly shows the detector's bias that the model could not absorb."
        ),
        Heading(3, "OpenCV's RMS per point, px"),
        condition_table(results, lambda r: dig(r, "errors", "rms_per_point_px")),
        Heading(3, "Against ground truth: RMS projection difference to the true camera, px (rotation fitted)"),
        condition_table(results, lambda r: dig(r, "vs_truth", "rms_px")),
        Heading(3, "Against ground truth: max projection difference to the true camera, px (rotation fitted)"),
        condition_table(results, lambda r: dig(r, "vs_truth", "max_px")),
        Heading(3, "Against ground truth: detector centre error, mean 2-D, px"),
        condition_table(results, lambda r: dig(r, "centre_error", "mean_2d_px")),
        Image("truth_vs_residual.png", caption["truth_vs_residual.png"]),
    ]
    notes = paper_notes(results)
    if notes:
        out += [
            Paragraph(
                "Notes (failures, notes from the references, left-out views, agreement checks of "
                "`circcal validate` that did not pass, warnings raised):"
            ),
            Bullets(tuple(notes)),
        ]
    return out


def _bias_section(results: dict[str, Any], caption: dict[str, str]) -> list[Block]:
    out: list[Block] = [
        Heading(2, "3. Centre bias against tilt and dot size"),
        Paragraph(prose.bias_setup(results)),
        Image("bias.png", caption["bias.png"]),
        Paragraph(prose.bias_table_intro(results)),
        bias_table(results),
        Image("bias_grid.png", caption["bias_grid.png"]),
    ]
    notes = bias_notes(results)
    return out + ([Bullets(tuple(notes))] if notes else [])


def _realdata_section(results: dict[str, Any], caption: dict[str, str]) -> list[Block]:
    out: list[Block] = [
        Heading(2, "6. Real photographs"),
        Paragraph(realdata_prose.realdata_method(results)),
        realdata_table(results),
    ]
    notes = realdata_notes(results)
    if notes:
        out.append(Bullets(tuple(notes)))
    out += [Paragraph(t) for t in (realdata_prose.realdata_summary(n, s) for n, s in realdata_sets(results)) if t]
    if "realdata_board.png" in caption:
        out.append(Image("realdata_board.png", caption["realdata_board.png"]))
    return out


def _studies_section(results: dict[str, Any], caption: dict[str, str]) -> list[Block]:
    studies = results.get("studies") or {}
    if not studies:
        return []
    out: list[Block] = [Heading(2, "8. Studies at scale (`circcal study`)"), Paragraph(prose.studies_intro(results))]
    for name, entry in studies.items():
        out.append(Heading(3, f"Study `{name}`"))
        if entry.get("status") != "ok":
            out.append(Paragraph(f"Not included: {entry.get('message', entry.get('status'))}."))
            continue
        ratio, bias, passes = study_tables(entry)
        out += [
            Paragraph(prose.study_summary(entry)),
            Paragraph("Sigma honesty: empirical spread / mean stated sigma (1 = honest; [95 % interval])."),
            ratio,
            Paragraph("Bias: mean error in stated sigmas (0 = unbiased; [95 % interval])."),
            bias,
            Paragraph("Truth check (fx, fy, cx, cy within the stated sigmas of the truth) per cell:"),
            passes,
        ]
        out += [Image(f, caption[f]) for f in caption if f.startswith(f"study_{name}_")]
    return out


def document(results: dict[str, Any], header: str) -> list[Block]:
    """Every block of the report, in order.

    Parameters
    ----------
    results : dict
        report.json's tree with ``timings`` (run times, s) added.
    header : str
        The line under the title (:func:`circcal.report.prose.header_line`).

    Returns
    -------
    list of Block
    """
    caption = prose.captions(results, figure_files(results))
    conds = paper_conditions(results)
    out: list[Block] = [Heading(1, TITLE), Paragraph(header), Paragraph(prose.conventions(results))]
    if prose.reduced_run(results):
        out.append(Paragraph(prose.reduced_run(results)))
    out += _paper_section(results, caption)
    out += [
        Heading(2, "2. Per-view errors (the paper's Tables 2, 4, 6)"),
        Image("per_view_errors.png", caption["per_view_errors.png"]),
    ]
    out += _bias_section(results, caption)
    out += [
        Heading(2, "4. Where each model is wrong: projection difference to the truth"),
        Paragraph(prose.fair_references(results)),
    ]
    out += [Image(f"heatmap_{c}.png", caption[f"heatmap_{c}.png"]) for c in conds]
    out.append(Heading(2, "5. Parameters (+- one stated standard deviation)"))
    for c in conds:
        out += [Heading(3, f"{c} illumination"), parameter_table(results, c)]
    out += _realdata_section(results, caption)
    out += [
        Heading(2, "7. Run times and environment"),
        Paragraph(prose.machine(results)),
        Paragraph(prose.run_times_intro(results)),
        timings_table(results),
    ]
    out += _studies_section(results, caption)
    return out
