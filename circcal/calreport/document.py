"""Writing the calibration report: figures (:mod:`circcal.calreport.figures`), the Jinja2 templates
``templates/calibration.html.j2`` and ``templates/calibration.md.j2`` (one context, two renderings), ``report.json``,
and overlays of the images that gave no view (:func:`circcal.detector.overlay.draw_detection`; an image that cannot
be read or drawn is listed with its reason and without one). The files are written into an empty folder the caller
gives (the command's staging folder: the caller commits all of a command's outputs together).

File names and the texts that quote them (reasons, details, messages) pass through
:func:`circcal.pathnames.display_name` (undecodable bytes as ``\\xNN``, control and bidi characters escaped), then
through each format's escaping: HTML by Jinja2's autoescape, Markdown by :func:`md_name` (a code span) and
:func:`md_text` (backslash escapes), figures by drawing names as plain text (no mathtext, no TeX; see
:mod:`circcal.calreport.figures`); ``report.json`` holds names as :func:`circcal.pathnames.path_to_json` (lossless).

The HTML is written twice: ``report.html``, self-contained (every figure embedded as a ``data:`` URI: the one file
to send), and ``index.html``, the same page linking ``figures/`` beside it as ``index.md`` does.

The page opens with the verdict (:func:`headline`): good / check / bad, coloured, with its next step, then the three
lines of numbers. The detector's dropped dots and the solve's outliers are two tables: a dropped dot has no residual.

Errors name their convention (``rms_per_point_px`` OpenCV's RMS, ``rms_per_coord_px`` mrcal's, ``mean_2d_px`` the
paper's); uncertainties are 1-sigma, worst direction, px.
"""

from __future__ import annotations

import html
import os
import re
import time
from pathlib import Path
from typing import Any

import numpy as np

from circcal.calreport import figures as F
from circcal.errors import ImageError
from circcal.pathnames import display_name, path_to_json

__all__ = [
    "write_report",
    "report_context",
    "headline",
    "md_name",
    "md_text",
    "OVERLAY_WIDTH_PX",
    "BACKDROP_WIDTH_PX",
    "TEMPLATES",
    "SELF_CONTAINED",
]

#: Overlays of failed images are scaled to this width (px) for the report (the detector's own overlay tool writes
#: full size).
OVERLAY_WIDTH_PX = 640
#: The images behind the residual vectors are scaled to this width (px): a panel is ~300 px wide.
BACKDROP_WIDTH_PX = 480
#: The templates, by output file.
TEMPLATES = {"index.html": "calibration.html.j2", "index.md": "calibration.md.j2"}
#: The self-contained page (figures embedded), rendered from the HTML template.
SELF_CONTAINED = "report.html"


def _environment():
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("circcal.calreport", "templates"),
        autoescape=jinja2.select_autoescape(enabled_extensions=("html.j2",)),
        trim_blocks=True,
        lstrip_blocks=True,
        undefined=jinja2.StrictUndefined,
    )
    env.filters.update(fmt=_fmt, esc=html.escape, md_name=md_name, md_text=md_text)
    return env


#: Characters :func:`md_text` escapes with a backslash (CommonMark escapes any ASCII punctuation): emphasis,
#: code, links and images, raw HTML and entities, GFM's table cells and strike-through, and ``$`` (math on GitHub).
_MD_SPECIAL = re.compile(r"([\\`*_\[\]<>|&~$])")


def md_text(text: Any) -> str:
    r"""Text as literal Markdown on one line, also inside a GFM table cell.

    :func:`display_name` first (no line breaks, no control characters), then a backslash before each character
    Markdown or GFM would read as markup (``\ ` * _ [ ] < > | & ~ $``).

    Parameters
    ----------
    text : object
        Any value; str() of it is used (bytes as a file name).

    Returns
    -------
    str

    Examples
    --------
    >>> md_text("a_b*c")
    'a\\_b\\*c'
    """
    return _MD_SPECIAL.sub(r"\\\1", display_name(str(text)))


def md_name(name: Any, cell: bool = False) -> str:
    r"""A file name as a Markdown code span (shown verbatim, monospace).

    :func:`display_name`, fenced by one more backtick than its longest run of backticks, padded with a space where it
    begins or ends with a backtick or a space.

    Parameters
    ----------
    name : object
        A file name (str, bytes or path).
    cell : bool
        Inside a GFM table row, where ``|`` must be written ``\|`` even in a code span (GFM removes the backslash).

    Returns
    -------
    str

    Examples
    --------
    >>> md_name("a`b.png")
    '``a`b.png``'
    """
    s = display_name(name)
    fence = "`" * (max((len(r) for r in re.findall("`+", s)), default=0) + 1)
    if s.strip(" ") and (s[0] in "` " or s[-1] in "` "):
        s = f" {s} "
    if cell:
        s = s.replace("|", "\\|")
    return f"{fence}{s}{fence}"


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return f"{v:.{digits}g}" if isinstance(v, float) else str(v)


def _overlay(path: str, detection: Any, dest: Path) -> str | None:
    """A downscaled overlay of a detection on its image, written to ``dest``; None, or why there is none (the
    image cannot be read, decoded or drawn: another process changed it, its header claims too many pixels)."""
    import cv2

    from circcal.detector.image import read_image
    from circcal.detector.overlay import draw_detection

    try:
        img = read_image(Path(path))
        if img is None:
            return "the image cannot be read or decoded"
        vis = draw_detection(img, detection)
    except (ImageError, OSError) as exc:  # what a file can cause; anything else is a bug
        return display_name(str(exc))
    if vis.shape[1] > OVERLAY_WIDTH_PX:
        s = OVERLAY_WIDTH_PX / vis.shape[1]
        vis = cv2.resize(vis, (OVERLAY_WIDTH_PX, int(round(vis.shape[0] * s))), interpolation=cv2.INTER_AREA)
    ok, png = cv2.imencode(".png", vis)
    if not ok:
        raise RuntimeError(f"cv2.imencode failed on a {vis.shape} {vis.dtype} overlay")
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_bytes(png.tobytes())
    return None


def _backdrop(path: str) -> np.ndarray | None:
    """A view's image, grey and scaled to :data:`BACKDROP_WIDTH_PX`, to draw the residuals over; None when it cannot
    be read (another process changed it)."""
    import cv2

    from circcal.detector.image import read_image

    try:
        img = read_image(Path(path))
    except (ImageError, OSError):
        return None
    if img is None:
        return None
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.shape[1] > BACKDROP_WIDTH_PX:
        s = BACKDROP_WIDTH_PX / img.shape[1]
        img = cv2.resize(img, (BACKDROP_WIDTH_PX, max(1, int(round(img.shape[0] * s)))), interpolation=cv2.INTER_AREA)
    return img


def headline(assessment: Any, n_images: int) -> dict[str, str]:
    """The verdict a user acts on: how the calibration looks and the next step.

    "bad": the lens model does not fit, or the two halves of a cross-validation disagree; "check": a rational lens
    with a pole, or nearly one, in the observed field (:mod:`circcal.solver.lensfield`), the board-shape
    check recommends the other board model (:mod:`circcal.analysis.boardshape`: the board is not flat, or a fitted
    warp is not needed), or nothing wrong was found but something is unverified or thin (no cross-validation, views
    that disagree, regions of the image without observations, half the images unusable); "good": cross-validated, the lens model fits, every ninth of
    the image observed.

    Parameters
    ----------
    assessment : circcal.analysis.assess.Assessment
    n_images : int
        The images given (the used views are the assessment's).

    Returns
    -------
    dict
        ``{"level": "good" | "check" | "bad", "text": the verdict, "next": the next step}``.
    """
    cv, fit, cov = assessment.crossval, assessment.lens_fit, assessment.coverage
    fix = getattr(assessment, "remedy", None)  # what the verdict tried (circcal.analysis.remedy)
    used = len(assessment.result.rvecs)
    if fit is not None and not fit.fits:
        m = re.search(r"try (.*?)\. ", fit.message())  # the --lens options the lens-fit message suggests
        return {
            "level": "bad",
            "text": f"the lens model {fit.lens} does not fit this lens: the residuals follow the radius",
            "next": display_name(fix.headline().removeprefix("recommended: "))
            if fix is not None and fix.target() is not None
            else f"recalibrate with {m.group(1) if m else 'another --lens'}",
        }
    if cv is not None and cv.status == "ok" and cv.verdict != "consistent":
        worst = [str(w[0]) for w in (getattr(cv.diff, "where", None) or [])[:2]]  # image thirds, worst first
        where = f" (worst: {', '.join(worst)})" if worst else ""
        return {
            "level": "bad",
            "text": f"the two halves of the views disagree beyond their uncertainty{where}",
            "next": display_name(fix.headline().removeprefix("recommended: "))
            if fix is not None
            else "look at the views flagged below (leave them out, or re-shoot them) and at the coverage; a lens "
            "model that cannot follow the lens disagrees too",
        }
    pole = assessment.lens_pole() if hasattr(assessment, "lens_pole") else None
    if pole:
        return {
            "level": "check",
            "text": "the rational lens's denominator vanishes, or nearly, inside the observed field: its k1..k6 are "
            "not determined by these views",
            "next": "recalibrate with --lens opencv5, or add views that fill the image's corners",
        }
    shape = getattr(assessment, "board_shape", None)  # whether the board is flat (circcal.analysis.boardshape)
    if shape is not None and shape.changes and not assessment.lens_in_question():
        return {
            "level": "check",
            "text": "the board is not flat: the flat board's intrinsics are biased"
            if shape.recommended == "warped"
            else "the board is flat within the data's noise: the fitted warp is not needed",
            "next": display_name(shape.recommendation().removeprefix("recommended: ")),
        }
    if cv is None or cv.status != "ok":
        return {
            "level": "check",
            "text": "fits, but unverified: a small RMS alone does not show the calibration is right",
            "next": "rerun with --cross-validate (the default, which --no-cross-validate turned off): it calibrates two "
            "halves of the views and compares them"
            if cv is None
            else f"add views: {display_name(cv.message)}",
        }
    if cv.flagged_views:
        return {
            "level": "check",
            "text": f"consistent overall, but {len(cv.flagged_views)} view(s) disagree with the others",
            "next": "check the flagged views in the table below; leave them out or re-shoot them",
        }
    if cov.warnings:
        return {
            "level": "check",
            "text": "consistent, but parts of the image hold no observations: distortion there is extrapolated",
            "next": "add views with the board in: " + "; ".join(display_name(w) for w in cov.warnings[:3]),
        }
    if n_images and used < n_images / 2:
        return {
            "level": "check",
            "text": f"consistent, from {used} of {n_images} images",
            "next": "see why the others gave no view (Images left out, below)",
        }
    return {
        "level": "good",
        "text": "consistent: the two halves of the views agree within their uncertainty, the lens model fits, "
        "every ninth of the image holds observations",
        "next": "use it; the uncertainty map shows where it is least sure",
    }


def report_context(assessment: Any, folder: Path) -> dict[str, Any]:
    """Draw every figure into ``folder/figures`` and build the templates' context.

    Parameters
    ----------
    assessment : circcal.analysis.assess.Assessment
        The calibration and its assessment.
    folder : Path
        The report folder.

    Returns
    -------
    dict
        The context both templates render (and ``report.json`` is built from).
    """
    cal, res = assessment.cal, assessment.result
    cam = res.camera
    names_p = cam.model.param_names  # the lens model's (fx, fy, cx, cy, then its distortion coefficients)
    w, h = cam.width, cam.height
    figdir = folder / "figures"
    figs: dict[str, str] = {}

    def put(name: str, fig: Any) -> None:
        F.save_png(fig, figdir / f"{name}.png")
        figs[name] = f"figures/{name}.png"

    names = [display_name(n) for n in (res.view_names or [f"view {i}" for i in range(len(res.rvecs))])]
    pts = [np.asarray(p) for p in (res.image_points or [])]
    allpts = np.concatenate(pts) if pts else np.zeros((0, 2))
    rej = res.outliers
    kept = rej.kept_views if rej is not None else list(range(len(names)))
    rejected_xy = [
        np.array([r.image_px for r in rej.points_of(v)]).reshape(-1, 2) if rej is not None else np.zeros((0, 2))
        for v in kept
    ]
    n_rej = [len(x) for x in rejected_xy]
    cv = assessment.crossval
    heldout = None
    if cv is not None and cv.status == "ok":
        heldout = [v.heldout_rms_per_coord_px for v in cv.views]
    put("views", F.fig_view_bars(names, [e["rms_per_coord_px"] for e in res.per_view_errors], heldout, n_rej))
    view_paths = [cal.paths[i] for i in cal.used] if len(cal.used) == len(names) else [None] * len(names)
    backdrops = [_backdrop(p) if p is not None else None for p in view_paths]
    put("vectors", F.fig_residual_vectors(names, pts, res.residuals, rejected_xy, w, h, images=backdrops))
    if res.board_points is not None and res.board_nominal is not None:
        put("board", F.fig_board_shape(res.board_nominal, res.board_points, res.board_std))
    put("histogram", F.fig_histogram(np.concatenate(res.residuals), res.sigma_px))
    put("coverage", F.fig_coverage(assessment.coverage, allpts))
    if assessment.uncertainty is not None:
        put("uncertainty", F.fig_uncertainty(assessment.uncertainty, w, h, allpts))
    corr = np.asarray(res.correlation, dtype=np.float64)
    put("correlation", F.fig_correlation(corr, names_p))
    if cv is not None and cv.status == "ok":
        put("crossval", F.fig_crossval(cv, w, h))

    params = []
    for n, v in zip(names_p, cam.intrinsics):
        held = n in res.fixed or (n == "fx" and "aspect_ratio" in res.fixed)
        params.append(
            {
                "name": n,
                "value": f"{v:.6f}" if abs(v) >= 1 else f"{v:.6g}",
                "std": "held" if n in res.fixed else _fmt(res.std[n], 3),
                "note": "= aspect x fy" if (n == "fx" and "aspect_ratio" in res.fixed) else ("held" if held else ""),
            }
        )
    views = []
    for i, (n, e) in enumerate(zip(names, res.per_view_errors)):
        row = {
            "name": n,
            "n_points": e["n_points"],
            "rms_per_coord_px": _fmt(e["rms_per_coord_px"]),
            "rms_per_point_px": _fmt(e["rms_per_point_px"]),
            "max_2d_px": _fmt(e["max_2d_px"]),
            "rejected": n_rej[i],
            "heldout": "-",
            "shift": "-",
            "flag": "",
        }
        if heldout is not None:
            vc = cv.views[i]
            row.update(
                heldout=_fmt(vc.heldout_rms_per_coord_px),
                shift=f"{vc.shift_sigmas:.2f} ({vc.shift_param})",
                flag=display_name(vc.why),
            )
        views.append(row)
    outliers, dropped = [], []
    if rej is not None:
        gnames = [display_name(n) for n in assessment.cal_view_names()]
        for r in rej.items:
            view = gnames[r.view] if r.view < len(gnames) else f"view {r.view}"
            if r.reason.value == "bad-dot":  # the detector's: before any solve, no residual
                measured = r.image_px is not None and bool(np.all(np.isfinite(r.image_px)))
                reason, _, detail = display_name(r.detail).partition(": ")
                dropped.append(
                    {
                        "view": view,
                        "point": str(r.point),
                        "where": f"({r.image_px[0]:.1f}, {r.image_px[1]:.1f})" if measured else "not measured",
                        "reason": reason if detail else "bad dot",
                        "detail": detail or reason,
                    }
                )
                continue
            outliers.append(
                {
                    "view": gnames[r.view] if r.view < len(gnames) else f"view {r.view}",
                    "point": "whole view" if r.point is None else str(r.point),
                    "where": "-" if r.image_px is None else f"({r.image_px[0]:.1f}, {r.image_px[1]:.1f})",
                    "residual": "-"
                    if r.residual_px is None
                    else (
                        f"{float(r.residual_px):.3g} RMS"
                        if np.ndim(r.residual_px) == 0
                        else f"({r.residual_px[0]:+.3g}, {r.residual_px[1]:+.3g})"
                    ),
                    "reason": r.reason.value,
                    "detail": display_name(r.detail),
                }
            )
    failed = []
    index = {p: i for i, p in enumerate(cal.paths)}
    for k, r in enumerate(cal.failed):
        entry = {
            "path": display_name(Path(r.path).name),
            "code": getattr(r.code, "value", str(r.code)),
            "reason": display_name(r.reason),
            "overlay": None,
            "no_overlay": None,
        }
        i = index.get(r.path)
        d = cal.detections[i] if i is not None else None
        if d is not None and Path(r.path).is_file():
            dest = figdir / f"failed_{k:02d}.png"
            entry["no_overlay"] = _overlay(r.path, d, dest)
            if entry["no_overlay"] is None:
                entry["overlay"] = f"figures/{dest.name}"
        failed.append(entry)
    e = res.errors
    cvd = None
    if cv is not None:
        cvd = {
            "status": cv.status,
            "message": display_name(cv.message),
            "split": cv.split,
            "verdict": cv.verdict,
            "halves": [[names[i] for i in hh] for hh in cv.halves] if cv.status == "ok" else [],
            "flagged": [{"name": display_name(v.name), "why": display_name(v.why)} for v in cv.flagged_views],
        }
        if cv.status == "ok":
            s = cv.diff.summary()
            cvd.update(
                rms=_fmt(s["rms_px"]),
                p95=_fmt(s["p95_px"]),
                max=_fmt(s["max_px"]),
                centre=_fmt(s["centre_px"]),
                share=f"{100 * s['share_within']:.1f}",
                ratio_median=_fmt(s.get("ratio_median")),
                where=cv.diff.where,
            )
    u = assessment.uncertainty
    board = assessment.board
    resid = np.concatenate([np.asarray(r, dtype=np.float64).ravel() for r in res.residuals] or [np.zeros(0)])
    resid = resid[np.isfinite(resid)]  # mrcal's noise estimate: the fitted residuals' standard deviation
    mrcal_factor = float(np.std(resid) / res.sigma_px) if resid.size and res.sigma_px > 0 else None
    return {
        "title": f"Calibration report: {len(res.rvecs)} views of a {board.rows}x{board.cols} {board.layout} board",
        "generated": time.strftime("%Y-%m-%d %H:%M:%S"),
        "verdict": [display_name(line) for line in assessment.verdict()],
        "camera": {"width": w, "height": h},
        "board": {
            "rows": board.rows,
            "cols": board.cols,
            "pitch_mm": board.pitch_mm,
            "layout": board.layout,
            "diameter_mm": board.diameter_mm,
        },
        "errors": {k: _fmt(e[k]) for k in ("rms_per_point_px", "rms_per_coord_px", "mean_2d_px", "max_2d_px")},
        "n_points": e["n_points"],
        "sigma_px": _fmt(res.sigma_px),
        "fixed": list(res.fixed),
        "refined_board": res.board_points is not None,
        "params": params,
        "views": views,
        "outliers": outliers,
        "dropped": dropped,
        "headline": headline(assessment, len(cal.paths)),
        "outlier_rule": None
        if rej is None
        else {"k": rej.rule.k, "floor": rej.rule.sigma_floor_px, "rounds": rej.rounds},
        "coverage": assessment.coverage,
        "uncertainty": u,
        "mrcal": None
        if mrcal_factor is None
        else {"factor": _fmt(mrcal_factor, 3), "n": 2 * int(resid.size // 2), "dof": _dof(res)},
        "crossval": cvd,
        "remedy": [display_name(line) for line in assessment.remedy.lines()] if assessment.remedy else None,
        "board_shape": None
        if getattr(assessment, "board_shape", None) is None
        else display_name(assessment.board_shape.line()),
        "failed": failed,
        "n_images": len(cal.paths),
        "figures": figs,
        "timings": {k: f"{v:.2f}" for k, v in assessment.timings.items()},
    }


def _dof(res: Any) -> int:
    """The free parameters of a solve: intrinsics not held and 6 per view (the board's shape not counted)."""
    return len([n for n in res.camera.model.param_names if n not in res.fixed]) + 6 * len(res.rvecs)


#: A lone surrogate: a byte of a file name that is not UTF-8 (os.fsdecode), or a broken string.
_SURROGATE = re.compile("[\ud800-\udfff]")


def _report_json(x: Any, names: bool, key: str = "") -> Any:
    """``x`` (plain JSON data) with, where ``names``, every ``name``/``path`` string as
    :func:`~circcal.pathnames.path_to_json` (lossless), and every other string that holds a lone surrogate (a
    message quoting a name of undecodable bytes) as :func:`~circcal.pathnames.display_name`: no lone surrogate
    reaches ``json.dumps``. (``names=False`` for data whose names are stored already, model.json's.)"""
    if isinstance(x, dict):
        return {k: _report_json(v, names, str(k)) for k, v in x.items()}
    if isinstance(x, list):
        return [_report_json(v, names, key) for v in x]
    if isinstance(x, str):
        if names and key in ("name", "path") and x:
            return path_to_json(x)
        return display_name(x) if _SURROGATE.search(x) else x
    return x


def _data_uri(path: Path) -> str:
    """A PNG file as a ``data:`` URI."""
    import base64

    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def write_report(assessment: Any, folder: str | os.PathLike) -> Path:
    """Write the report of ``assessment`` into ``folder``, an existing empty folder (the command's staging folder).

    Parameters
    ----------
    assessment : circcal.analysis.assess.Assessment
        The calibration and its assessment.
    folder : str or path-like
        An existing, empty folder: ``report.html`` (self-contained), ``index.html``, ``index.md``, ``report.json``
        and ``figures/`` are written into it; nothing is deleted or replaced. Committing the folder to its final place (together with the command's
        other outputs) is the caller's job.

    Returns
    -------
    pathlib.Path
        ``folder / "report.html"``, the self-contained page.

    Raises
    ------
    ValueError
        When ``folder`` is not an existing, empty folder (a bug in the caller: a command stages an empty one).
    """
    from circcal.jsonio import dumps, jsonable

    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"write_report: {display_name(folder)} is not an existing folder")
    if any(folder.iterdir()):
        raise ValueError(
            f"write_report: {display_name(folder)} is not empty (the report goes into an empty staging folder)"
        )
    env = _environment()
    ctx = report_context(assessment, folder)
    doc = {
        "assessment": _report_json(jsonable(assessment.to_dict()), names=True),
        "model": _report_json(jsonable(assessment.cal.to_model_json(assessment.board)), names=False),
    }
    for out, name in TEMPLATES.items():
        (folder / out).write_text(env.get_template(name).render(**ctx), encoding="utf-8")
    embedded = {k: _data_uri(folder / v) for k, v in ctx["figures"].items()}
    failed = [{**f, "overlay": _data_uri(folder / f["overlay"]) if f["overlay"] else None} for f in ctx["failed"]]
    page = env.get_template(TEMPLATES["index.html"]).render(**{**ctx, "figures": embedded, "failed": failed})
    (folder / SELF_CONTAINED).write_text(page, encoding="utf-8")
    (folder / "report.json").write_text(dumps(doc, indent=1) + "\n", encoding="utf-8")
    return folder / SELF_CONTAINED
