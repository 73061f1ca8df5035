"""What "is my calibration right?" costs beside a plain calibration of the same images: the 14 rendered 1920x1080
`paper` views (normal light) and the 14 `small-noisy` views (few small dots: the solve, not detection, dominates, the
hardest case for the ratio); rendering not timed: cached.

Timed alternately in one process, one thread: ``plain`` = what ``circcal calibrate`` does (detect, calibrate with
outlier rejection, re-correct, recalibrate, and the projection-uncertainty map and coverage it prints);
``cross_validation`` = ``--cross-validate`` on top (two halves through the whole loop, their uncertainties and
difference, leave-one-view-out refits); ``report`` = ``--report`` (every figure, both renderings, the failed-image
overlays, report.json). Bars (issue 34): plain + cross-validation <= 2x plain on each set; the report <= 10 s for the 14 views.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from benchmarks.timing import alternate, pinned, ratio, summary

#: The bars of the issue.
CROSSVAL_RATIO_BAR = 2.0
#: (scenario, variant) timed; the report is timed on the first.
SETS = (("paper", "normal"), ("small-noisy", "noisy"))
REPORT_BAR_S = 10.0


def run(repeats: int = 9) -> dict:
    out: dict = {}
    for k, (scenario, variant) in enumerate(SETS):
        for key, v in _run_set(scenario, variant, repeats, report=k == 0).items():
            out[key if key in ("threads",) else f"{scenario}_{key}"] = v
    return out


def _run_set(scenario: str, variant: str, repeats: int, report: bool) -> dict:
    from circcal.analysis.assess import assess
    from circcal.analysis.cross import cross_validate_detections
    from circcal.calreport import write_report
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth
    from circcal.pipeline import calibrate_images
    from circcal.solver import CalibrationOptions
    from circcal.solver.outliers import OutlierRule

    truth = load_truth(fixture_dir(scenario, variant))
    paths = [v.image for v in truth.views]
    options = CalibrationOptions(outlier_rule=OutlierRule())
    held: dict = {}

    def plain() -> None:
        cal = calibrate_images(paths, truth.board, options, progress=False, jobs=1)
        held["cal"] = cal
        held["assessment"] = assess(cal, truth.board, options)

    def crossval() -> None:
        held["cv"] = cross_validate_detections(held["cal"], truth.board, options)

    with tempfile.TemporaryDirectory() as tmp:

        def write() -> None:
            a = held["assessment"]
            a.crossval = held["cv"]
            write_report(a, Path(tempfile.mkdtemp(dir=tmp)))  # into an empty folder each time, as a command stages

        steps = {"plain": plain, "cross_validation": crossval} | ({"report": write} if report else {})
        with pinned(1) as threads:
            t = alternate(steps, repeats=repeats)
    total = [p + c for p, c in zip(t["plain"], t["cross_validation"])]
    r = ratio(total, t["plain"])
    out = {
        "threads": threads,
        "views": len(paths),
        "plain_calibrate_s": summary(t["plain"]),
        "cross_validation_s": summary(t["cross_validation"]),
        "calibrate_with_cross_validation_ratio": r,
        "cross_validation_bar": f"<= {CROSSVAL_RATIO_BAR:g}x plain: "
        f"{'met' if r['max'] <= CROSSVAL_RATIO_BAR else ('median met' if r['median'] <= CROSSVAL_RATIO_BAR else 'MISSED')}",
        "cross_validation_verdict": held["cv"].verdict,
    }
    if report:
        rep = summary(t["report"])
        out["report_s"] = rep
        out["report_bar"] = f"<= {REPORT_BAR_S:g} s for {len(paths)} views: " + (
            "met" if rep["median"] <= REPORT_BAR_S else "MISSED"
        )
    return out
