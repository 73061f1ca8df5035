"""The terminal text of conformance cases: one case's checks in full, and its line of the end-of-run summary table."""

from __future__ import annotations

import numpy as np

from circcal.formatting import fmt_number
from circcal.validators.case_run import Outcome, failed_checks
from circcal.validators.parameter_table import STD_NOTE


def format_outcome(outcome: Outcome) -> str:
    """Multi-line text of a case: every check with value and bound, measured numbers, notes.

    Parameters
    ----------
    outcome : Outcome

    Returns
    -------
    str
    """
    lines = [f"{outcome.case.id}: {outcome.status}"]
    if outcome.result is not None:
        lines.append(f"  {outcome.result.summary()}")
    for c in outcome.checks:
        bound = "" if not np.isfinite(c.bound) else f" (bound {c.bound:g})"
        lines.append(
            f"  {'PASS' if c.passed else 'FAIL'} {c.name}: {fmt_number(c.value, '.4g')}{bound}"
            f"{(' - ' + c.note) if c.note else ''}"
        )
    if outcome.measured:
        lines.append("  measured: " + ", ".join(f"{k}={fmt_number(v, '.4g')}" for k, v in outcome.measured.items()))
    lines += [f"  {n}" for n in outcome.notes]
    if outcome.skip_reason:
        lines.append(f"  skipped: {outcome.skip_reason}")
    return "\n".join(lines)


def summary_line(outcome: Outcome) -> str:
    """One line for the end-of-run table: the case, its status and its key numbers, then any note on the sigmas a
    calibrator under test stated (:func:`~circcal.validators.parameter_table.stated_sigmas`: circcal's used for
    some, unknown keys).

    Parameters
    ----------
    outcome : Outcome

    Returns
    -------
    str
    """
    m = outcome.measured
    keys = [
        ("images_used", "images used"),
        ("truth_rms_px", "vs truth rms px"),
        ("truth_rms_pred_p99_px", "(p99 predicted px"),
        ("vs_circcal_max_px", "vs circcal max px"),
        ("mean_2d_px", "mean2d px"),
        ("fx_sigmas", "fx/sigma"),
        ("cx_sigmas", "cx/sigma"),
    ]
    parts = [f"{name} {fmt_number(m[k], '.4g')}" + (")" if name.startswith("(") else "") for k, name in keys if k in m]
    if "images_used" in m:
        parts[0] += f"/{m.get('images', 0):.0f}"
    bad = failed_checks(outcome)
    head = "FAIL" if bad else outcome.status
    parts += [n for n in outcome.notes if n.startswith(STD_NOTE)]
    return f"{outcome.case.id:<44} {head:<11} " + "; ".join(parts)
