"""Writing the calibration report: figures (:mod:`circcal.calreport.figures`), the Jinja2 templates
``templates/calibration.html.j2`` and ``templates/calibration.md.j2`` (one context, two renderings), ``report.json``,
and overlays of the images that gave no view (:func:`circcal.detector.overlay.draw_detection`). The folder is
written atomically (:func:`circcal.atomic.folder`): a failure leaves an earlier report as it was.

Errors name their convention (``rms_per_point_px`` OpenCV's RMS, ``rms_per_coord_px`` mrcal's, ``mean_2d_px`` the
paper's); uncertainties are 1-sigma, worst direction, px.
"""
from __future__ import annotations

import html
import time
from pathlib import Path
from typing import Any

import numpy as np

from circcal.calreport import figures as F

__all__ = ["write_report", "report_context", "OVERLAY_WIDTH_PX", "TEMPLATES"]

#: Overlays of failed images are scaled to this width (px) for the report (the detector's own overlay tool writes
#: full size).
OVERLAY_WIDTH_PX = 640
#: The templates, by output file.
TEMPLATES = {"index.html": "calibration.html.j2", "index.md": "calibration.md.j2"}


def _environment():
    import jinja2

    return jinja2.Environment(loader=jinja2.PackageLoader("circcal.calreport", "templates"),
                              autoescape=jinja2.select_autoescape(enabled_extensions=("html.j2",)),
                              trim_blocks=True, lstrip_blocks=True, undefined=jinja2.StrictUndefined)


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return f"{v:.{digits}g}" if isinstance(v, float) else str(v)


def _overlay(path: str, detection: Any, dest: Path) -> bool:
    """A downscaled overlay of a detection on its image; False when the image cannot be read."""
    import cv2

    from circcal.detector.overlay import draw_detection

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        return False
    vis = draw_detection(img, detection)
    if vis.shape[1] > OVERLAY_WIDTH_PX:
        s = OVERLAY_WIDTH_PX / vis.shape[1]
        vis = cv2.resize(vis, (OVERLAY_WIDTH_PX, int(round(vis.shape[0] * s))), interpolation=cv2.INTER_AREA)
    ok, png = cv2.imencode(".png", vis)
    if not ok:
        return False
    from circcal import atomic

    atomic.write_bytes(dest, png.tobytes())
    return True


def report_context(assessment: Any, folder: Path) -> dict[str, Any]:
    """Draw every figure into ``folder/figures`` and return the templates' context."""
    cal, res = assessment.cal, assessment.result
    cam = res.camera
    names_p = cam.model.param_names  # the lens model's (fx, fy, cx, cy, then its distortion coefficients)
    w, h = cam.width, cam.height
    figdir = folder / "figures"
    figs: dict[str, str] = {}

    def put(name: str, fig: Any) -> None:
        F.save_png(fig, figdir / f"{name}.png")
        figs[name] = f"figures/{name}.png"

    names = list(res.view_names or [f"view {i}" for i in range(len(res.rvecs))])
    pts = [np.asarray(p) for p in (res.image_points or [])]
    allpts = np.concatenate(pts) if pts else np.zeros((0, 2))
    rej = res.outliers
    kept = rej.kept_views if rej is not None else list(range(len(names)))
    rejected_xy = [np.array([r.image_px for r in rej.points_of(v)]).reshape(-1, 2) if rej is not None
                   else np.zeros((0, 2)) for v in kept]
    n_rej = [len(x) for x in rejected_xy]
    cv = assessment.crossval
    heldout = None
    if cv is not None and cv.status == "ok":
        heldout = [v.heldout_rms_per_coord_px for v in cv.views]
    put("views", F.fig_view_bars(names, [e["rms_per_coord_px"] for e in res.per_view_errors], heldout, n_rej))
    put("vectors", F.fig_residual_vectors(names, pts, res.residuals, rejected_xy, w, h))
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
        params.append({"name": n, "value": f"{v:.6f}" if abs(v) >= 1 else f"{v:.6g}",
                       "std": "held" if n in res.fixed else _fmt(res.std[n], 3),
                       "note": "= aspect x fy" if (n == "fx" and "aspect_ratio" in res.fixed) else
                       ("held" if held else "")})
    views = []
    for i, (n, e) in enumerate(zip(names, res.per_view_errors)):
        row = {"name": n, "n_points": e["n_points"], "rms_per_coord_px": _fmt(e["rms_per_coord_px"]),
               "rms_per_point_px": _fmt(e["rms_per_point_px"]), "max_2d_px": _fmt(e["max_2d_px"]),
               "rejected": n_rej[i], "heldout": "-", "shift": "-", "flag": ""}
        if heldout is not None:
            vc = cv.views[i]
            row.update(heldout=_fmt(vc.heldout_rms_per_coord_px), shift=f"{vc.shift_sigmas:.2f} ({vc.shift_param})",
                       flag=vc.why)
        views.append(row)
    outliers = []
    if rej is not None:
        gnames = assessment.cal_view_names()
        for r in rej.items:
            outliers.append({"view": gnames[r.view] if r.view < len(gnames) else f"view {r.view}",
                             "point": "whole view" if r.point is None else str(r.point),
                             "where": "-" if r.image_px is None else f"({r.image_px[0]:.1f}, {r.image_px[1]:.1f})",
                             "residual": "-" if r.residual_px is None else (
                                 f"{float(r.residual_px):.3g} RMS" if np.ndim(r.residual_px) == 0 else
                                 f"({r.residual_px[0]:+.3g}, {r.residual_px[1]:+.3g})"),
                             "reason": r.reason.value, "detail": r.detail})
    failed = []
    index = {p: i for i, p in enumerate(cal.paths)}
    for k, r in enumerate(cal.failed):
        entry = {"path": Path(r.path).name, "code": getattr(r.code, "value", str(r.code)), "reason": r.reason,
                 "overlay": None}
        i = index.get(r.path)
        d = cal.detections[i] if i is not None else None
        if d is not None and Path(r.path).is_file():
            dest = figdir / f"failed_{k:02d}.png"
            if _overlay(r.path, d, dest):
                entry["overlay"] = f"figures/{dest.name}"
        failed.append(entry)
    e = res.errors
    cvd = None
    if cv is not None:
        cvd = {"status": cv.status, "message": cv.message, "split": cv.split, "verdict": cv.verdict,
               "halves": [[names[i] for i in hh] for hh in cv.halves] if cv.status == "ok" else [],
               "flagged": [{"name": v.name, "why": v.why} for v in cv.flagged_views]}
        if cv.status == "ok":
            s = cv.diff.summary()
            cvd.update(rms=_fmt(s["rms_px"]), p95=_fmt(s["p95_px"]), max=_fmt(s["max_px"]),
                       centre=_fmt(s["centre_px"]), share=f"{100 * s['share_within']:.1f}",
                       ratio_median=_fmt(s.get("ratio_median")), where=cv.diff.where)
    u = assessment.uncertainty
    board = assessment.board
    return {
        "title": f"Calibration report: {len(res.rvecs)} views of a {board.rows}x{board.cols} {board.layout} board",
        "generated": time.strftime("%Y-%m-%d %H:%M:%S"),
        "verdict": assessment.verdict(),
        "camera": {"width": w, "height": h},
        "board": {"rows": board.rows, "cols": board.cols, "pitch_mm": board.pitch_mm, "layout": board.layout,
                  "diameter_mm": board.diameter_mm},
        "errors": {k: _fmt(e[k]) for k in ("rms_per_point_px", "rms_per_coord_px", "mean_2d_px", "max_2d_px")},
        "n_points": e["n_points"], "sigma_px": _fmt(res.sigma_px), "fixed": list(res.fixed),
        "refined_board": res.board_points is not None,
        "params": params, "views": views, "outliers": outliers,
        "outlier_rule": None if rej is None else {"k": rej.rule.k, "floor": rej.rule.sigma_floor_px,
                                                  "rounds": rej.rounds},
        "coverage": assessment.coverage, "uncertainty": u, "crossval": cvd, "failed": failed,
        "n_images": len(cal.paths), "figures": figs,
        "timings": {k: f"{v:.2f}" for k, v in assessment.timings.items()},
    }


def write_report(assessment: Any, folder: str | Path) -> Path:
    """Write the report of ``assessment`` (:class:`circcal.crossval.assess.Assessment`) into ``folder`` (replaced
    atomically). Returns the path of ``index.html``."""
    from circcal import atomic
    from circcal.jsonio import dumps

    final = Path(folder)
    env = _environment()
    env.filters["fmt"] = _fmt
    env.filters["esc"] = html.escape
    with atomic.folder(final) as tmp:
        ctx = report_context(assessment, tmp)
        for out, name in TEMPLATES.items():
            (tmp / out).write_text(env.get_template(name).render(**ctx))
        doc = {"assessment": assessment.to_dict(),
               "model": assessment.cal.to_model_json(assessment.board)}
        (tmp / "report.json").write_text(dumps(doc, indent=1) + "\n")
    return final / "index.html"
