"""`circcal validate --against all` on the default scenario, warm (in one process, after a first untimed run that
pays the imports and numba's cache load): wall time with its spread (goal <= 6 s on 2 cores), and each
calibrator's own time on the same observations as a ratio to OpenCV's (from the last run)."""

from __future__ import annotations

from benchmarks.timing import MIN_REPEATS, alternate, pinned, summary


def run(repeats: int = MIN_REPEATS) -> dict:
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.scenarios import DEFAULT_SCENARIO
    from circcal.fixtures.truth import load_truth
    from circcal.validators.validate import run_validation

    truth = load_truth(fixture_dir(DEFAULT_SCENARIO))  # rendering is not timed (cached fixture)
    held: dict = {}

    def once() -> None:
        held["run"] = run_validation(
            [v.image for v in truth.views], truth.board, truth=truth.camera, against=["all"], progress=False
        )

    with pinned(1) as threads:
        t = alternate({"validate": once}, repeats=repeats)
    run = held["run"]
    out: dict = {
        "threads": threads,
        "validate_all_warm_s": summary(t["validate"]),
        "goal_s": 6.0,
        "all_checks_passed": run.passed,
        "circcal_detect_and_calibrate_s": run.circcal["time_s"],
    }
    cv = next((r.time_s for r in run.references if r.name == "opencv" and r.ok), None)
    for r in run.references:
        key = f"{r.name}_{r.mode}"
        out[f"{key}_s"] = r.time_s if r.ok else r.status
        if cv and r.ok:
            out[f"{key}_vs_opencv_ratio"] = r.time_s / cv
    if any(r.name == "mrcal" for r in run.references):
        out["mrcal_note"] = (
            "mrcal's modes run in one out-of-process worker (one interpreter start); its wall time is "
            "split evenly between them"
        )
    return out
