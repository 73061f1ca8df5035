"""`circcal validate --against all` on the default scenario: wall time (goal <= 60 s on 2 cores) and each
calibrator's own time on the same observations, as ratios to OpenCV's."""
from __future__ import annotations

import time


def run() -> dict:
    from circcal.fixtures.scenarios import DEFAULT_SCENARIO, fixture_dir, load_truth
    from circcal.validators.validate import run_validation

    truth = load_truth(fixture_dir(DEFAULT_SCENARIO))  # rendering is not timed (cached fixture)
    t0 = time.perf_counter()
    run = run_validation([v.image for v in truth.views], truth.board, truth=truth.camera, against=["all"],
                         progress=False)
    total = time.perf_counter() - t0
    out: dict = {"validate_all_s": total, "goal_s": 60.0, "all_checks_passed": run.passed,
                 "circcal_detect_and_calibrate_s": run.circcal["time_s"]}
    cv = next((r.time_s for r in run.references if r.name == "opencv" and r.ok), None)
    for r in run.references:
        key = f"{r.name}_{r.mode}"
        out[f"{key}_s"] = r.time_s if r.ok else r.status
        if cv and r.ok:
            out[f"{key}_vs_opencv_ratio"] = r.time_s / cv
    if any(r.name == "mrcal" for r in run.references):
        out["mrcal_note"] = ("mrcal's modes run in one out-of-process worker (one interpreter start); its wall time is "
                             "split evenly between them")
    return out
