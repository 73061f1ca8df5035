"""The report's sentences. Every number in them is formatted in from the results (the JSON tree report.json holds)
or from the constant that produced it; the thresholds the wording depends on are named here with their reasons.

Conventions: errors in px (the key or the sentence names the convention), lengths in mm, angles in degrees.
"""

from __future__ import annotations

import math
from typing import Any

from circcal.board import Board
from circcal.formatting import fmt_number, fmt_scientific
from circcal.metrics import SQRT2
from circcal.model import PARAM_NAMES
from circcal.report import config
from circcal.report.environment import VERSION_ORDER
from circcal.report.figures import gauge_counts, refined_boards
from circcal.report.results import calibrator_keys, dig, paper_conditions, realdata_sets
from circcal.validators import checks
from circcal.validators.checks import solver_bound

__all__ = [
    "MEAN_2D_PER_SIGMA",
    "RMS_POINT_PER_SIGMA",
    "apart",
    "bias_setup",
    "bias_table_intro",
    "captions",
    "conventions",
    "fair_references",
    "header_line",
    "headline",
    "machine",
    "reduced_run",
    "run_times_intro",
]

#: Mean 2-D error per unit per-axis Gaussian noise sigma (the Rayleigh mean, sqrt(pi/2)).
MEAN_2D_PER_SIGMA = math.sqrt(math.pi / 2.0)
#: RMS per point per unit per-axis noise sigma.
RMS_POINT_PER_SIGMA = SQRT2


def apart(a: float, b: float) -> float:
    """The relative difference of two numbers.

    Parameters
    ----------
    a, b : float

    Returns
    -------
    float
        |a - b| / |b|.

    Examples
    --------
    >>> apart(1.1, 1.0)  # doctest: +ELLIPSIS
    0.1000...
    """
    return abs(a - b) / abs(b)


def header_line(run_name: str, date: str) -> str:
    """The line under the title: when and by which command the report was made.

    Parameters
    ----------
    run_name : str
        The run folder's name.
    date : str
        When the numbers were computed.

    Returns
    -------
    str
    """
    quick = " --quick" if run_name == "quick" else ""
    return f"Generated {date} by `circcal report{quick}` ({run_name} run)."


def _views(results: dict[str, Any]) -> str:
    """How many views the rendered studies used: "14 views each", or per study where they differ."""
    paper = {results["paper"][c]["n_views"] for c in paper_conditions(results)}
    cb = {r["n_views"] for r in results["checkerboard"].values() if "n_views" in r}
    counts = paper | cb
    if len(counts) == 1:
        return f"{counts.pop()} views each"
    return (
        f"{'/'.join(str(n) for n in sorted(paper))} views of `paper`, "
        f"{'/'.join(str(n) for n in sorted(cb))} of `paper-checkerboard`"
    )


def conventions(results: dict[str, Any]) -> str:
    """The opening paragraph: the error conventions and the rendered fixtures.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    str
    """
    fx = results["fixtures"]
    dots, cam = Board.from_dict(fx["paper"]["board"]), fx["paper"]["camera"]
    cb = Board.from_dict(fx["paper-checkerboard"]["board"])
    return (
        "Every reprojection error names its convention: mean 2-D = mean of |residual| (the paper's eq. 22, used "
        f"in its tables, ~{MEAN_2D_PER_SIGMA:.3f} sigma for per-axis noise sigma); RMS per point = OpenCV's "
        f"calibrateCamera RMS (~{RMS_POINT_PER_SIGMA:.3f} sigma); RMS per coordinate = mrcal's (~sigma). "
        f"'vs truth' = RMS over a {config.PROJECTION_GRID_WIDTH}-wide pixel grid of the projection difference "
        "between the calibrated and the true camera (implied rotation fitted, as mrcal.projection_diff); "
        "'centre error' = detected centres (corners for the checkerboard) against the exact projections of the "
        "true ones. "
        "Rendered fixtures: the `paper` scenario (Chen et al. 2023's setup: "
        f"{dots.rows}x{dots.cols} dots of {dots.diameter_mm:g} mm at {dots.pitch_mm:g} mm pitch, "
        f"{cam['width']}x{cam['height']}, fx {cam['fx']:g} px) and `paper-checkerboard` "
        f"({cb.cols + 1}x{cb.rows + 1} squares of {cb.pitch_mm:g} mm); {_views(results)}. "
        "References marked 'circcal's centres' fit exactly circcal's final centres (rounded to float32, OpenCV's "
        "input type), so their residuals and their error against truth measure the solver, not the detector."
    )


def reduced_run(results: dict[str, Any]) -> str:
    """What a reduced run leaves out.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    str
        "" for the full run.
    """
    cfg = results["config"]
    if cfg["name"] == "full":
        return ""
    return (
        f"This is a reduced ({cfg['name']}) run: conditions {', '.join(cfg['conditions'])}, {cfg['n_views']} "
        f"views, a {len(cfg['bias_tilts_deg'])}x{len(cfg['bias_diameters_px'])} bias grid. Not the published "
        "numbers."
    )


def _camera(cam: dict[str, Any]) -> str:
    """A camera as "1280x960, f 1500 px, k1 -0.1, k2 0.05" (focal lengths apart when they differ; the distortion
    terms that are not zero)."""
    f = f"f {cam['fx']:g} px" if cam["fx"] == cam["fy"] else f"fx {cam['fx']:g} px, fy {cam['fy']:g} px"
    dist = [f"{name} {v:g}" for name, v in zip(PARAM_NAMES[4:], cam["dist"]) if v]
    return ", ".join([f"{cam['width']}x{cam['height']}", f] + dist)


def _render_terms(b: dict[str, Any]) -> str:
    """The bias renders' perturbations, e.g. "blur 0.7 px, 8-bit, no noise"."""
    kinds = [p.get("kind", "") for p in b["perturbations"]]
    terms = [
        f"blur {p['sigma_px']:g} px" if p.get("kind") == "gaussian_blur" else p.get("kind", "?")
        for p in b["perturbations"]
    ]
    terms.append(f"{b['bits']}-bit")
    if not any("noise" in k for k in kinds):
        terms.append("no noise")
    return ", ".join(terms)


def bias_setup(results: dict[str, Any]) -> str:
    """The bias study's setup paragraph.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    str
    """
    b = results["bias"]
    return (
        f"Clean renders ({_render_terms(b)}) of a {b['board']['rows']}x{b['board']['cols']} grid of dots at "
        f"{b['board']['pitch_mm']:g} mm pitch, centred on the principal point {b['distance_mm']:.0f} mm away, "
        f"tilted about an axis {b['tilt_axis_deg']:g} deg from the image x axis; camera {_camera(b['camera'])}. "
        "circcal's detector is shown given the true lens model (what calibrate_images converges to, as it "
        "re-corrects every centre under its current estimate) and without one; OpenCV's findCirclesGrid uses a "
        "SimpleBlobDetector whose area window is fitted to the dot size."
    )


def bias_table_intro(results: dict[str, Any]) -> str:
    """The line above the bias table: how many dots each error is taken over.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    str
    """
    return f"Mean (and max) centre error over the {results['bias']['board']['n_points']} dots, px:"


def _bounds(names: list[str]) -> str:
    """The agreement bound of each reference (:func:`circcal.validators.checks.solver_bound`), e.g. "1e-6 px
    (opencv, kornia) and 1e-4 px (mrcal)"; one bound for all is written once."""
    bounds: dict[float, list[str]] = {}
    for n in names:
        bounds.setdefault(solver_bound(n), []).append(n)
    if len(bounds) == 1:
        return f"{fmt_scientific(next(iter(bounds)))} px"
    return " and ".join(f"{fmt_scientific(b)} px ({', '.join(ns)})" for b, ns in bounds.items()) or "their bound"


def fair_references(results: dict[str, Any]) -> str:
    """Why the fair references are not drawn: the agreement bound they are held to, and whether every check held.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    str
    """
    names = [k.removesuffix("-fair") for k in calibrator_keys(results) if k.endswith("-fair")]
    within = _bounds(names)
    passed = all(results["paper"][c]["validation_passed"] for c in paper_conditions(results))
    verdict = (
        "every check of `circcal validate` passed in every condition"
        if passed
        else "the checks that did not pass are listed in the notes of section 1"
    )
    return (
        f"References in 'fair' mode on circcal's centres ({', '.join(names) or 'none ran'}) must reproduce "
        f"circcal's solver on the same points to within {within}, the largest projection difference over the "
        f"image ({verdict}); they are not drawn separately."
    )


def machine(results: dict[str, Any]) -> str:
    """The machine and library versions (in :data:`~circcal.report.environment.VERSION_ORDER`).

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    str
    """
    env = results["environment"]
    vers = env["versions"]
    order = [k for k in VERSION_ORDER if k in vers] + sorted(k for k in vers if k not in VERSION_ORDER)
    return (
        f"Machine: {env['platform']} ({env['machine']}), {env['cpu_count']} CPUs. Versions: "
        + ", ".join(f"{k} {vers[k]}" for k in order)
        + "."
    )


def run_times_intro(results: dict[str, Any]) -> str:
    """What the run-time table's rows cover.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    str
    """
    return (
        "Run times (wall clock, this run; they vary between runs and are not part of report.json). 'circcal' is "
        "the whole `circcal calibrate` (detection, calibration, re-correction rounds) with its default of "
        "detecting images in parallel threads (one per CPU, as `circcal.detector.detect_files` chooses; "
        f"{results['environment']['cpu_count']} CPUs here); 'opencv-pipeline' is findCirclesGrid + "
        "calibrateCamera one image at a time; the 'fair' rows are solves on circcal's centres. `make bench` "
        "compares the detectors one thread each:"
    )


def _board_caption(results: dict[str, Any]) -> str:
    """The real-board figure's caption, with the gauge read from the refined boards."""
    counts = {gauge_counts(s["circcal_refined"]["board"]) for _, s in refined_boards(results)}
    if len(counts) == 1:
        ((full, z_only),) = counts
        held = f"the {full + z_only} gauge points (held at their nominal positions: {full} in x, y, z, {z_only} in z"
    else:
        held = "the gauge points (held at their nominal positions, some in x, y, z, some in z only"
    return (
        "The board points as circcal estimates them on each real set (board refined), against the nominal board: "
        "colour = out-of-plane deviation dz, arrows = in-plane deviation (dx, dy), exaggerated by the factor in "
        f"the legend. Deviations are in the frame fixed by {held}; the default choice, the first point, the one "
        "farthest from it and the one farthest from their line): another choice of gauge changes the picture by "
        "a rigid motion and scale, not the shape. The median sigma is over the estimated coordinates."
    )


def captions(results: dict[str, Any], files: list[str]) -> dict[str, str]:
    """The caption of each figure file drawn for this run.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).
    files : list of str
        The figure files (:func:`circcal.report.figures.figure_files`).

    Returns
    -------
    dict of str to str
        File name -> caption.
    """
    out = {
        "truth_vs_residual.png": "A low residual does not prove the bias is gone: left, the residual each calibrator "
        "reports; right, its error against the true camera on the same images.",
        "per_view_errors.png": "Per-view mean 2-D reprojection error of circcal and the OpenCV circle pipeline "
        "(findCirclesGrid + calibrateCamera), one panel per illumination condition.",
        "bias.png": "Centre error of each detector against the exact projection of the true circle centre on clean "
        "renders. The dashed line is what a perfect blob detector reports (the exact area centroid of "
        "the projected, distorted dot): the bias that no amount of image quality removes from "
        "centroid-based detectors.",
        "bias_grid.png": "Mean centre error over the whole tilt x dot-size grid (numbers in px).",
    }
    for c in paper_conditions(results):
        out[f"heatmap_{c}.png"] = (
            f"Where each model is wrong ({c}): the 2-D difference between projecting through the calibrated and the "
            f"true camera, over a {config.PROJECTION_GRID_WIDTH}-wide grid of the image, with the implied rotation "
            "fitted (mrcal's projection_diff idea). Each panel has its own colour scale."
        )
    if "realdata_board.png" in files:
        out["realdata_board.png"] = _board_caption(results)
    study_captions = {
        "ratio": "empirical spread / mean stated sigma per cell and parameter with its 95 % interval (1 = honest)",
        "bias": "mean error / mean stated sigma per cell and parameter with its 95 % interval (0 = unbiased)",
        "pass_rate": f"share of runs whose fx, fy, cx, cy all lie within {checks.TRUTH_SIGMAS:g} stated "
        "sigmas of the truth, with Wilson's 95 % interval, beside an honest estimator's",
    }
    for f in files:
        for name in results.get("studies") or {}:
            for kind, text in study_captions.items():
                if f == f"study_{name}_{kind}.png":
                    out[f] = f"Study `{name}`: {text}."
    return {f: out.get(f, "") for f in files}


def studies_intro(results: dict[str, Any]) -> str:
    """What the studies section shows, and where its numbers come from.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    str
    """
    return (
        "Monte-Carlo studies run by `circcal study` (scenarios x variants x seeds x calibrators on a Dask "
        "cluster; one Parquet row per run, resumable) and summarised per cell (one scenario, variant, "
        "calibrator and lens model over its seeds): whether the stated standard deviations are honest (the "
        "empirical spread of the estimates over their mean stated sigma), whether the estimates are biased "
        f"(mean error in stated sigmas), and how often the truth check (fx, fy, cx, cy within "
        f"{checks.TRUTH_SIGMAS:g} stated sigmas) passes. Each study's rows and its own summary are in "
        "`reports/studies/<name>/`; the numbers below are its summary.json as the study wrote it."
    )


def study_summary(entry: dict[str, Any]) -> str:
    """One study's description and run counts.

    Parameters
    ----------
    entry : dict
        A :mod:`circcal.report.studies` entry.

    Returns
    -------
    str
    """
    cells = entry.get("cells") or []
    n_runs = sum(c.get("n_runs", 0) for c in cells)
    n_ok = sum(c.get("n_ok", 0) for c in cells)
    text = entry.get("description") or ""
    return (f"{text.rstrip('.')}. " if text else "") + (
        f"{n_runs} runs in {len(cells)} cells, {n_ok} calibrated (status ok)."
    )


def _headline_condition(results: dict[str, Any], c: str) -> str:
    """One condition's headline: circcal's residual and error vs truth beside OpenCV's and the checkerboard's."""
    rows = results["paper"][c]["rows"]
    cc, oc = rows.get("circcal", {}), rows.get("opencv-pipeline", {})
    text = (
        f"{c}: circcal mean 2-D residual {fmt_number(dig(cc, 'errors', 'mean_2d_px'))} px, error vs truth "
        f"{fmt_number(dig(cc, 'vs_truth', 'rms_px'))} px (OpenCV circles "
        f"{fmt_number(dig(oc, 'errors', 'mean_2d_px'))} / {fmt_number(dig(oc, 'vs_truth', 'rms_px'))} px"
    )
    cb = results["checkerboard"].get(c)
    if cb:
        text += (
            f", checkerboard {fmt_number(dig(cb, 'errors', 'mean_2d_px'))} / "
            f"{fmt_number(dig(cb, 'vs_truth', 'rms_px'))} px"
        )
    return text + ")"


def _headline_bias(b: dict[str, Any]) -> list[str]:
    """The bias study's headline at its largest tilt and dot size (none when the grid is empty)."""
    try:
        i, j = len(b["tilts_deg"]) - 1, len(b["diameters_px"]) - 1
        m = b["mean_2d_px"]
        return [
            (
                f"bias at {b['tilts_deg'][i]:g} deg tilt, {b['diameters_px'][j]:g} px dots: circcal "
                f"{fmt_number(m['circcal'][i][j])} px vs OpenCV {fmt_number(m['opencv'][i][j])} px "
                f"(perfect centroid {fmt_number(m['perfect_centroid'][i][j])} px)"
            )
        ]
    except (IndexError, KeyError, TypeError):
        return []


def _headline_set(name: str, s: dict[str, Any]) -> str:
    """One real set's headline: RMS rigid and refined, held-out mean 2-D error."""
    cc = s.get("circcal") or {}
    if cc.get("status") != "ok":
        return f"{name}: circcal {cc.get('status')}: {cc.get('message')}"
    text = (
        f"{name}: circcal RMS {fmt_number(dig(cc, 'errors', 'rms_per_point_px'))} px vs OpenCV baseline "
        f"{fmt_number(dig(s, 'baseline', 'rms_per_point_px'))} px"
    )
    if dig(s, "circcal_refined", "status") == "ok":
        text += (
            f", board refined {fmt_number(dig(s, 'circcal_refined', 'errors', 'rms_per_point_px'))} px "
            f"(OpenCV's centres refined {fmt_number(dig(s, 'opencv_refined', 'errors', 'rms_per_point_px'))} px)"
        )
    text += (
        f"; held-out mean 2-D {fmt_number(dig(s, 'heldout', 'circcal', 'mean_of_views', 'mean_2d_px'))} vs "
        f"{fmt_number(dig(s, 'heldout', 'opencv', 'mean_of_views', 'mean_2d_px'))} px"
    )
    if dig(s, "heldout", "circcal_refined"):
        text += f", board refined {fmt_number(dig(s, 'heldout', 'circcal_refined', 'mean_of_views', 'mean_2d_px'))} px"
    return text


def headline(results: dict[str, Any]) -> str:
    """One paragraph with the headline numbers (for the index reports/README.md).

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    str
    """
    parts = [_headline_condition(results, c) for c in paper_conditions(results)]
    parts += _headline_bias(results["bias"])
    parts += [_headline_set(n, s) for n, s in realdata_sets(results)]
    return "; ".join(parts) + "."
