"""The real-data section's sentences (:mod:`circcal.report.realdata`'s sets against their OpenCV baselines), with the
thresholds their wording depends on and the reasons; :mod:`circcal.report.prose` holds the others.

Errors in px, lengths in mm.
"""

from __future__ import annotations

from typing import Any

from circcal.report.prose import apart
from circcal.report.results import dig, realdata_sets

__all__ = [
    "REALDATA_PROVENANCE",
    "SHAPE_RMS_DROP",
    "SHAPE_SIGNIFICANCE",
    "TIE_REL",
    "realdata_method",
    "realdata_summary",
]

#: Two RMS values closer than this (relative) are called a tie: about the relative standard error of an RMS over the
#: few hundred residual coordinates of a real set (1/sqrt(2n): 3.7% for n = 360, 2.3% for n = 960).
TIE_REL = 0.03
#: The board refinement must at least halve the rigid RMS before the prose calls the sheet's shape the limit: a
#: shape fitted to pure noise only takes away the degrees of freedom it uses (RMS ~0.86-0.91x on these sets).
SHAPE_RMS_DROP = 0.5
#: ...and the largest deviation must exceed this many median standard deviations of a coordinate: beyond chance
#: even over the few hundred coordinates estimated (a Gaussian exceeds 5 sigma with probability ~6e-7).
SHAPE_SIGNIFICANCE = 5.0
#: Where the real photographs come from.
REALDATA_PROVENANCE = "BoofCV-Data, CC BY 4.0, Sony DSC-HX5V"


def _image_sizes(sets: list[tuple[str, dict]]) -> str:
    """The sets' image sizes (px), "640x480", distinct ones joined by "/"."""
    sizes = list(dict.fromkeys(f"{s['image_size'][0]}x{s['image_size'][1]}" for _, s in sets if s.get("image_size")))
    return "/".join(sizes) or "?"


def realdata_method(results: dict[str, Any]) -> str:
    """What the real-data section compares and how held-out prediction works.

    Parameters
    ----------
    results : dict
        The results tree (report.json's).

    Returns
    -------
    str
    """
    sets = realdata_sets(results)
    found = [(n, s) for n, s in sets if s.get("baseline")]
    flags = " and ".join(dict.fromkeys(str(dig(s, "baseline", "flags")) for _, s in found)) or "as stated"
    gauges = {len(dig(s, "circcal_refined", "board", "gauge") or []) for _, s in found}
    held = f"{gauges.pop()} points" if len(gauges) == 1 else "the gauge points"
    source = (
        f"{len(sets)} public set{'s' if len(sets) != 1 else ''} ({REALDATA_PROVENANCE}, "
        f"{_image_sizes(found)} JPEG): no ground truth, so the comparison is with OpenCV's baseline "
        f"(findCirclesGrid with the flags each baseline states, {flags}, then calibrateCamera; its centres are "
        "re-fitted here with the same OpenCV solver, which reproduces its stated RMS)."
    )
    method = (
        "Held-out prediction: for each view, calibrate on all the others (circcal: its full calibrate / "
        "re-correct loop on the remaining views), then take the held-out view's centres (circcal: re-corrected "
        "under the model that never saw that view), fit only its 6-DoF pose with solvePnP (IPPE, then "
        "Levenberg-Marquardt) holding the intrinsics, and measure the residual of the projected board points. "
        "Each detector is scored on its own centres, so a shared bias is not caught by this test either; it "
        "does measure how well the intrinsics predict a view they were not fitted to."
    )
    refined = (
        "Rows marked 'board refined' also estimate the 3-D position of every board point (the "
        "object-releasing method of Strobl & Hirzinger 2011, the same minimum as cv2.calibrateCameraRO; "
        f"`calibrate_images(refine_board=True)`), {held} held to fix the board's frame and scale: circcal on "
        "its own centres, and the same solver on the baseline's findCirclesGrid centres, each view put into "
        "circcal's point order (reversed where that matches circcal's centres better: a symmetric grid's "
        "180-degree ambiguity). Their held-out views are predicted with the refined board points of the model "
        "that never saw them."
    )
    return f"{source} {method} {refined}"


def _tie(a: float, b: float) -> bool:
    """Whether two RMS values count as equal (:data:`TIE_REL`)."""
    return apart(a, b) < TIE_REL


def _rigid(s: dict, name: str) -> str:
    """The rigid-board sentence: circcal's RMS per point against OpenCV's solver on the baseline's centres."""
    rc, ro = dig(s, "circcal", "errors", "rms_per_point_px"), dig(s, "opencv", "errors", "rms_per_point_px")
    rb = dig(s, "baseline", "rms_per_point_px")
    gap = 100 * apart(rc, ro)
    return (
        f"{name}: with a rigid board circcal's RMS per point is {rc:.4f} px and OpenCV's solver on the "
        f"baseline's centres gives {ro:.4f} px (stated: {rb:.4f} px): "
        + (
            f"the two detectors tie ({gap:.1f}% apart)."
            if _tie(rc, ro)
            else f"circcal is {gap:.1f}% {'lower' if rc < ro else 'higher'}."
        )
    )


def _refined(s: dict, held: dict[str, Any]) -> str:
    """The board-refined sentence: circcal's RMS and its held-out RMS (``held``: per key, held-out RMS per point)."""
    fc, rb = dig(s, "circcal_refined", "errors", "rms_per_point_px"), dig(s, "baseline", "rms_per_point_px")
    text = (
        f"With every board point's position estimated, circcal's RMS drops to {fc:.4f} px, "
        f"{rb / fc:.1f}x below the stated baseline"
    )
    if held["circcal"] and held["circcal_refined"]:
        better = held["circcal"] / held["circcal_refined"]
        text += (
            f", and held-out views are predicted {better:.1f}x {'better' if better > 1 else 'worse'} than with "
            f"the rigid board ({held['circcal_refined']:.4f} vs {held['circcal']:.4f} px RMS per point)"
            + ("; a shape fitted to noise would predict them worse, not better" if better > 1 else "")
        )
    return text + "."


def _same_model(s: dict, held: dict[str, Any]) -> str:
    """OpenCV's centres through the same board-refined solver, against circcal's."""
    fc, fo = (
        dig(s, "circcal_refined", "errors", "rms_per_point_px"),
        dig(s, "opencv_refined", "errors", "rms_per_point_px"),
    )
    gap = 100 * apart(fc, fo)
    text = (
        f"The same solver on OpenCV's centres, in circcal's point order, gives {fo:.4f} px"
        + (f" (held-out {held['opencv_refined']:.4f} px)" if held["opencv_refined"] else "")
        + (
            f": with the same model the two detectors tie again ({gap:.1f}% apart"
            if _tie(fc, fo)
            else f": {gap:.1f}% {'below' if fo < fc else 'above'} circcal's (the same model, different centres"
        )
    )
    bvc = dig(s, "opencv_refined", "board_vs_circcal_max_mm")
    return text + (
        f"; the two estimated boards agree to within {bvc:.3f} mm per coordinate)." if bvc is not None else ")."
    )


def _sheet(s: dict) -> list[str]:
    """How far the estimated sheet is from the nominal board (mm), and whether its shape is what limits a rigid fit
    (:data:`TIE_REL`, :data:`SHAPE_RMS_DROP`, :data:`SHAPE_SIGNIFICANCE`)."""
    bd = dig(s, "circcal_refined", "board")
    if not bd:
        return []
    ratio = bd["max_dev_over_median_std"]
    out = [
        (
            f"The estimated sheet departs from the nominal board by up to {bd['max_abs_dev_mm']:.2f} mm in one "
            f"coordinate, {ratio:.0f}x the median standard deviation of a coordinate ({bd['median_std_mm']:.3f} mm): "
            f"up to {bd['max_abs_dz_mm']:.2f} mm out of plane and {bd['max_abs_dxy_mm']:.2f} mm in plane."
        )
    ]
    rc, ro = dig(s, "circcal", "errors", "rms_per_point_px"), dig(s, "opencv", "errors", "rms_per_point_px")
    fc, fo = (
        dig(s, "circcal_refined", "errors", "rms_per_point_px"),
        dig(s, "opencv_refined", "errors", "rms_per_point_px"),
    )
    if _tie(rc, ro) and _tie(fc, fo) and fc < SHAPE_RMS_DROP * rc and ratio > SHAPE_SIGNIFICANCE:
        out.append(
            "So the residual of a rigid calibration on this set is the printed sheet's shape, not centre "
            "detection: modelled, it leaves both detectors with the same, much smaller residual."
        )
    return out


def _baseline_order(s: dict) -> str:
    """Whether the baseline's findCirclesGrid centres come in circcal's point order."""
    rev = dig(s, "opencv_refined", "reversed") or []
    n = len(dig(s, "opencv", "views") or [])
    flags = dig(s, "baseline", "flags") or "its flags"
    own = dig(s, "opencv_refined", "own_order", "errors", "rms_per_point_px")
    if not rev:
        return "The baseline's centres come in circcal's point order in every view" + (
            " (an asymmetric grid has no 180-degree ambiguity)." if dig(s, "board", "layout") == "asymmetric" else "."
        )
    if len(rev) == n:
        return (
            f"The baseline's findCirclesGrid centres ({flags}) come in the reverse of circcal's point order in "
            f"all {n} views: a consistent relabelling of the board"
            + (f", harmless (refined in their own order: {own:.4f} px)." if own is not None else ".")
        )
    return (
        f"The baseline's findCirclesGrid centres ({flags}) are reversed against circcal's point order in "
        f"{len(rev)} of {n} views" + (f"; refined in that order: {own:.4f} px." if own is not None else ".")
    )


def _adapter_order(s: dict) -> list[str]:
    """What the OpenCV adapter's plain-then-clustering findCirclesGrid does to a symmetric grid's point order."""
    fg = s.get("findcirclesgrid_order")
    if not fg or not fg.get("views"):
        return []
    k, m = len(fg["reversed"]), len(fg["views"])
    ncl = sum("clustering" in h for h in fg["how"])
    o1 = dig(fg, "refined_own_order", "errors", "rms_per_point_px")
    o2 = dig(fg, "refined_circcal_order", "errors", "rms_per_point_px")
    text = (
        f"findCirclesGrid as circcal's OpenCV adapter runs it (plain, CALIB_CB_CLUSTERING only where that fails: "
        f"{ncl} of {m} views) "
    )
    if 0 < k < m:
        text += (
            f"reverses {k} of {m} views against circcal's order: the 180-degree ambiguity resolved differently "
            "per image. A rigid board hides that (each pose absorbs it); a refined board does not"
        )
        text += (
            f": {o1:.4f} px in findCirclesGrid's order against {o2:.4f} px in circcal's."
            if None not in (o1, o2)
            else "."
        )
    else:
        text += "orders all views consistently" + (" (all reversed against circcal's order)." if k else ".")
    return [text]


def realdata_summary(name: str, s: dict) -> str:
    """What the numbers of one real-data set show, in words.

    Parameters
    ----------
    name : str
        The set.
    s : dict
        Its entry of ``results["realdata"]``.

    Returns
    -------
    str
        Empty when a rigid or board-refined row is missing.
    """
    needed = (
        dig(s, "circcal", "errors", "rms_per_point_px"),
        dig(s, "opencv", "errors", "rms_per_point_px"),
        dig(s, "circcal_refined", "errors", "rms_per_point_px"),
        dig(s, "opencv_refined", "errors", "rms_per_point_px"),
        dig(s, "baseline", "rms_per_point_px"),
    )
    if None in needed:
        return ""
    held = {
        k: dig(s, "heldout", k, "mean_of_views", "rms_per_point_px")
        for k in ("circcal", "opencv", "circcal_refined", "opencv_refined")
    }
    parts = [
        _rigid(s, name),
        _refined(s, held),
        _same_model(s, held),
        *_sheet(s),
        _baseline_order(s),
        *_adapter_order(s),
    ]
    return " ".join(parts)
