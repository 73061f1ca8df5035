"""Studies at scale in the published report: the summaries of finished ``circcal study`` runs (the sigma honesty
and bias of each calibrator per scenario cell with 95 % intervals, the truth-check pass rates), read from each
study's ``summary.json`` (:func:`circcal.study.summary.write_summary`) so the report never reruns a study."""

from __future__ import annotations

from typing import Any

from circcal.report.config import ReportConfig, studies_root

__all__ = ["study_results", "study_cells"]


def study_results(cfg: ReportConfig) -> dict[str, dict[str, Any]]:
    """The summaries of the finished studies a report shows.

    Parameters
    ----------
    cfg : ReportConfig
        Its ``studies`` names folders under :func:`~circcal.report.config.studies_root`.

    Returns
    -------
    dict of str to dict
        Name -> ``{"status": "ok", "description", "cells": [summary.json's cells]}``, or
        ``{"status": "missing", "message"}`` where the study has not been run (or not summarised).
    """
    from circcal.jsonio import read_json
    from circcal.study.spec import load_spec

    out: dict[str, dict[str, Any]] = {}
    for name in cfg.studies:
        folder = studies_root() / name
        summary, spec = folder / "summary.json", folder / "study.yaml"
        if not summary.is_file():
            out[name] = {"status": "missing", "message": f"no finished study at {folder} (run `make study-reports`)"}
            continue
        description = load_spec(spec).description if spec.is_file() else ""
        out[name] = {"status": "ok", "description": description, "cells": read_json(summary, "study summary")}
    return out


def study_cells(entry: dict[str, Any]) -> list[Any]:
    """The cell summaries of one study entry of the results.

    Parameters
    ----------
    entry : dict
        One value of :func:`study_results`.

    Returns
    -------
    list of circcal.study.summary.CellSummary
        Empty for a missing study.
    """
    from circcal.study.summary import CellSummary

    return [CellSummary.from_dict(c) for c in entry.get("cells") or []]
