"""The report's notes: everything that did not go as planned, listed where it happened (failed or noted calibrators,
images left out, checks that did not pass, warnings a study raised); nothing is dropped silently."""

from __future__ import annotations

from typing import Any

from circcal.formatting import fmt_number
from circcal.report.results import dig, paper_conditions, realdata_sets
from circcal.report.tables import REALDATA_ROWS

__all__ = ["bias_notes", "paper_notes", "realdata_notes", "warning_notes"]


def warning_notes(results: dict[str, Any], prefix: str) -> list[str]:
    """The warnings recorded for every study whose key starts with a prefix.

    Parameters
    ----------
    results : dict
        The results tree.
    prefix : str
        Study key prefix.

    Returns
    -------
    list of str
        "study: Category: message (n times)".
    """
    out = []
    for study, entries in (results.get("warnings") or {}).items():
        if study == prefix or study.startswith(prefix + "/"):
            out += [
                f"{study}: {w['category']}: {w['message']}" + (f" ({w['count']} times)" if w["count"] > 1 else "")
                for w in entries
            ]
    return out


def _paper_condition_notes(c: str, pc: dict[str, Any]) -> list[str]:
    out = []
    for r in pc["rows"].values():
        if r["status"] != "ok" or r.get("message"):
            what = "note" if r["status"] == "ok" else r["status"]
            out.append(f"{c}: {r['label']}: {what}{': ' + r['message'] if r.get('message') else ''}")
    out += [f"{c}: circcal left out {name}: {why}" for name, why in pc.get("failed_images") or []]
    for ch in pc["checks"]:
        if not ch["passed"]:
            out.append(
                f"{c}: check failed: {ch['name']}: {fmt_number(ch.get('value'), '.3g')} "
                f"(bound {fmt_number(ch['bound'], 'g')}){' - ' + ch['note'] if ch.get('note') else ''}"
            )
    return out


def paper_notes(results: dict[str, Any]) -> list[str]:
    """Notes of the paper and checkerboard studies (section 1).

    Parameters
    ----------
    results : dict
        The results tree.

    Returns
    -------
    list of str
    """
    out = [n for c in paper_conditions(results) for n in _paper_condition_notes(c, results["paper"][c])]
    for c in results["config"]["checkerboard_conditions"]:
        r = results["checkerboard"].get(c)
        if r is not None and (r["status"] != "ok" or r.get("message")):
            out.append(f"{c}: checkerboard: {r['status']}{': ' + r['message'] if r.get('message') else ''}")
    return out + warning_notes(results, "paper") + warning_notes(results, "checkerboard")


def bias_notes(results: dict[str, Any]) -> list[str]:
    """Renders where a detector found no grid, and the study's warnings (section 3).

    Parameters
    ----------
    results : dict
        The results tree.

    Returns
    -------
    list of str
    """
    return list(results["bias"].get("notes") or []) + warning_notes(results, "bias")


def _model_difference(name: str, what: str, diff: dict[str, Any] | None) -> list[str]:
    """The projection difference (px, rotation fitted) between two models of one set, if measured."""
    if not diff:
        return []
    return [
        (
            f"{name}: {what}, projection difference (rotation fitted): RMS {fmt_number(diff['rms_px'])} px, max "
            f"{fmt_number(diff['max_px'])} px"
        )
    ]


def _set_notes(name: str, s: dict[str, Any]) -> list[str]:
    out = []
    for who, label in REALDATA_ROWS:
        r = s.get(who) or {}
        if r.get("status") not in (None, "ok"):
            out.append(f"{name}: {label} {r.get('status')}: {r.get('message')}")
    out += _model_difference(name, "circcal's model vs OpenCV's", dig(s, "circcal", "vs_opencv"))
    out += _model_difference(
        name, "board refined, circcal's model vs the one from OpenCV's centres", dig(s, "opencv_refined", "vs_circcal")
    )
    for who, label in REALDATA_ROWS:
        out += [
            f"{name}: held-out {label} {p['view']}: {p['failed']}"
            for p in dig(s, "heldout", who, "per_view") or []
            if "failed" in p
        ]
    out += [f"{name}: circcal left out {n}: {why}" for n, why in dig(s, "circcal", "failed") or []]
    out += [
        f"{name}: OpenCV's view {n} has no circcal view to take the point order from; kept as detected"
        for n in dig(s, "opencv_refined", "unmatched") or []
    ]
    return out


def realdata_notes(results: dict[str, Any]) -> list[str]:
    """Failures, model differences and left-out views of the real sets, and their warnings (section 6).

    Parameters
    ----------
    results : dict
        The results tree.

    Returns
    -------
    list of str
    """
    return [n for name, s in realdata_sets(results) for n in _set_notes(name, s)] + warning_notes(results, "realdata")
