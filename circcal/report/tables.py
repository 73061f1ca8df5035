"""The report's tables, built from the results (the JSON tree report.json holds); cells are text, "-" where a value
is missing. Errors in px, lengths in mm."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from circcal.formatting import fmt_number
from circcal.model import PARAM_NAMES, Camera
from circcal.report.blocks import Table
from circcal.report.config import PAPER_PUBLISHED
from circcal.report.results import all_conditions, calibrator_keys, dig, paper_conditions, realdata_sets

__all__ = [
    "REALDATA_ROWS",
    "bias_table",
    "condition_table",
    "parameter_table",
    "realdata_table",
    "study_tables",
    "timings_table",
]

#: The computed rows of the real-data table: key in a real-data set's results -> label.
REALDATA_ROWS = (
    ("circcal", "circcal"),
    ("opencv", "OpenCV (baseline centres)"),
    ("circcal_refined", "circcal, board refined"),
    ("opencv_refined", "OpenCV centres (circcal's order), board refined"),
)


def _cell(row: dict | None, metric: Callable[[dict], Any], spec: str) -> str:
    """A calibrator's value in one condition: the number, its status where it did not run, "-" where absent."""
    if row is None:
        return "-"
    return fmt_number(metric(row), spec) if row["status"] == "ok" else row["status"]


def condition_table(
    results: dict[str, Any], metric: Callable[[dict], Any], *, spec: str = ".4f", published: bool = False
) -> Table:
    """One row per calibrator, one column per condition: ``metric(row)`` formatted with ``spec``.

    The checkerboard comes last, the paper's Table 7 after it with ``published``.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).
    metric : callable
        Row dict -> value (None or NaN: "-").
    spec : str
        Format spec.
    published : bool
        Add the paper's published numbers.

    Returns
    -------
    Table
    """
    conds = all_conditions(results)
    paper = [results["paper"][c]["rows"] for c in paper_conditions(results)]
    rows = []
    for key in calibrator_keys(results):
        first = next(r[key] for r in paper if key in r)
        det = f"{first['detector']} (own detector)" if first["observations"] == "own" else "circcal's centres"
        cells = [_cell(dig(results, "paper", c, "rows", key), metric, spec) for c in conds]
        rows.append((first["label"], det, *cells))
    cbs = results["checkerboard"]
    if cbs:
        first = cbs[next(c for c in conds if c in cbs)]
        rows.append(
            (
                first["label"],
                first.get("detector") or "findChessboardCorners",
                *(_cell(cbs.get(c), metric, spec) for c in conds),
            )
        )
    if published:
        for kind in ("circles", "checkerboard"):
            rows.append(
                (
                    f"Chen et al. 2023, Table 7 ({kind})",
                    "published",
                    *(fmt_number(PAPER_PUBLISHED[kind].get(c), ".4f") for c in conds),
                )
            )
    return Table(("calibrator", "detector / observations", *conds), tuple(rows))


def bias_table(results: dict[str, Any]) -> Table:
    """Mean and max centre error (px) per (tilt, dot diameter) of the bias study.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    Table
    """
    b = results["bias"]
    m, x = b["mean_2d_px"], b["max_2d_px"]
    rows = []
    for i, t in enumerate(b["tilts_deg"]):
        for j, d in enumerate(b["diameters_px"]):
            rows.append(
                (
                    f"{t:g}",
                    f"{d:g}",
                    *(fmt_number(m[k][i][j]) for k in ("circcal", "circcal_nomodel", "opencv", "perfect_centroid")),
                    fmt_number(x["circcal"][i][j]),
                    fmt_number(x["opencv"][i][j]),
                )
            )
    return Table(
        (
            "tilt [deg]",
            "dot [px]",
            "circcal (model)",
            "circcal (no model)",
            "OpenCV blob",
            "perfect centroid",
            "circcal max",
            "OpenCV max",
        ),
        tuple(rows),
    )


def parameter_table(results: dict[str, Any], condition: str) -> Table:
    """The true parameters beside each calibrator's, +- its stated standard deviation.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).
    condition : str
        The illumination condition.

    Returns
    -------
    Table
    """
    pc = results["paper"][condition]
    cols = [
        ("circcal", pc["rows"].get("circcal")),
        ("OpenCV circles", pc["rows"].get("opencv-pipeline")),
        ("mrcal [default]", pc["rows"].get("mrcal-default")),
        ("OpenCV checkerboard", results["checkerboard"].get(condition)),
    ]
    cols = [(n, r) for n, r in cols if r is not None and r.get("camera")]
    truth = Camera.from_dict(results["fixtures"]["paper"]["camera"]).intrinsics
    models = [(Camera.from_dict(r["camera"]).intrinsics, r.get("std") or {}) for _, r in cols]
    rows = []
    for k, p in enumerate(PARAM_NAMES):
        cells = [
            f"{fmt_number(v[k], '.6g')} +- {fmt_number(std[p], '.2g')}"
            if std.get(p) is not None
            else fmt_number(v[k], ".6g")
            for v, std in models
        ]
        rows.append((p, fmt_number(truth[k], ".6g"), *cells))
    return Table(("param", "truth", *(n for n, _ in cols)), tuple(rows))


def _board_text(bd: dict[str, Any]) -> str:
    if not bd:
        return "-"
    return (
        f"{bd.get('rows')}x{bd.get('cols')} {bd.get('layout')}, {fmt_number(bd.get('pitch_mm'), 'g')} mm pitch, "
        f"{fmt_number(bd.get('diameter_mm'), 'g')} mm dots"
    )


def _model_cells(cam: dict[str, Any]) -> tuple[str, ...]:
    """fx, fy, cx, cy (px, 2 decimals) and k1 (4 decimals) of a camera entry."""
    return (
        *(fmt_number(cam.get(k), ".2f") for k in ("fx", "fy", "cx", "cy")),
        fmt_number((cam.get("dist") or [None])[0], ".4f"),
    )


def _baseline_row(name: str, board: str, base: dict[str, Any]) -> tuple[str, ...]:
    k = base["camera_matrix"]
    cam = {"fx": k[0][0], "fy": k[1][1], "cx": k[0][2], "cy": k[1][2], "dist": base["dist"]}
    return (
        name,
        board,
        f"OpenCV {base['opencv_version']} baseline as published",
        "stated",
        str(base.get("used") or "-"),
        "-",
        fmt_number(base["rms_per_point_px"]),
        "-",
        "-",
        "-",
        *_model_cells(cam),
    )


def realdata_table(results: dict[str, Any]) -> Table:
    """Every calibration of every real set: errors, held-out errors and the main parameters; the baseline as stated.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    Table
    """
    rows = []
    for name, s in realdata_sets(results):
        board = _board_text(s.get("board") or {})
        for who, label in REALDATA_ROWS:
            r = s.get(who) or {}
            e = r.get("errors") or {}
            ho = dig(s, "heldout", who, "mean_of_views") or {}
            rows.append(
                (
                    name,
                    board,
                    label,
                    r.get("status", "-"),
                    str(len(r.get("views") or [])),
                    *(fmt_number(e.get(k)) for k in ("mean_2d_px", "rms_per_point_px", "rms_per_coord_px")),
                    *(fmt_number(ho.get(k)) for k in ("mean_2d_px", "rms_per_point_px")),
                    *_model_cells(r.get("camera") or {}),
                )
            )
        if s.get("baseline"):
            rows.append(_baseline_row(name, board, s["baseline"]))
    return Table(
        (
            "set",
            "board",
            "calibrator",
            "status",
            "views",
            "mean 2-D",
            "RMS/point",
            "RMS/coord",
            "held-out mean 2-D",
            "held-out RMS/point",
            "fx",
            "fy",
            "cx",
            "cy",
            "k1",
        ),
        tuple(rows),
    )


def timings_table(results: dict[str, Any]) -> Table:
    """The run times (s) of this run, per part.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    Table
    """
    tm = results.get("timings") or {}
    rows = []
    for c, d in (tm.get("paper") or {}).items():
        rows += [("paper", c, k, fmt_number(v, ".2f")) for k, v in d.items()]
    rows += [
        ("checkerboard", c, "detect + calibrate", fmt_number(v, ".2f"))
        for c, v in (tm.get("checkerboard") or {}).items()
    ]
    if "bias" in tm:
        rows.append(("bias", "-", "render + detect grid", fmt_number(tm["bias"], ".2f")))
    for c, d in (tm.get("realdata") or {}).items():
        rows += [("realdata", c, k, fmt_number(v, ".2f")) for k, v in d.items()]
    if "total_compute_s" in tm:
        rows.append(("total", "-", "all computation", fmt_number(tm["total_compute_s"], ".1f")))
    return Table(("part", "condition / set", "what", "time [s]"), tuple(rows))


def _interval(value: Any, ci: Any, spec: str = ".3f") -> str:
    """``value [low, high]`` of a study summary (an interval is a pair)."""
    lo, hi = (ci or (None, None))[:2]
    return f"{fmt_number(value, spec)} [{fmt_number(lo, spec)}, {fmt_number(hi, spec)}]"


def study_tables(entry: dict[str, Any]) -> list[Table]:
    """The tables of one finished study.

    Sigma honesty (empirical spread over the mean stated sigma, 1 = honest) and bias (mean error in stated sigmas,
    0 = unbiased) of each parameter per cell with 95 % intervals, and the truth-check pass rate beside an honest
    estimator's.

    Parameters
    ----------
    entry : dict
        A :mod:`circcal.report.studies` entry.

    Returns
    -------
    list of Table
        Empty for a missing study.
    """
    from circcal.study.summary import TABLE_PARAMS

    cells = entry.get("cells") or []

    def label(c: dict[str, Any]) -> str:
        return f"{c['scenario']}/{c['variant']}/{c['calibrator']}" + (
            "" if c["lens_model"] == "opencv5" else f"/{c['lens_model']}"
        )

    head = ("cell", "ok / runs", *TABLE_PARAMS)
    ratio = tuple(
        (
            label(c),
            f"{c['n_ok']} / {c['n_runs']}",
            *(_interval(dig(c, "params", p, "ratio"), dig(c, "params", p, "ratio_ci")) for p in TABLE_PARAMS),
        )
        for c in cells
    )
    bias = tuple(
        (
            label(c),
            f"{c['n_ok']} / {c['n_runs']}",
            *(
                _interval(dig(c, "params", p, "bias_sigmas"), dig(c, "params", p, "bias_sigmas_ci"))
                for p in TABLE_PARAMS
            ),
        )
        for c in cells
    )
    passes = tuple(
        (
            label(c),
            f"{c['n_ok']} / {c['n_runs']}",
            _interval(c.get("pass_rate"), c.get("pass_ci")),
            fmt_number(c.get("pass_expected"), ".3f"),
            fmt_number(c.get("truth_rms_median_px"), ".4f"),
        )
        for c in cells
    )
    return [
        Table(head, ratio),
        Table(head, bias),
        Table(
            ("cell", "ok / runs", "truth check passed [95 %]", "honest estimator", "median RMS vs truth, px"), passes
        ),
    ]
