"""Is ``--lens auto`` worth making the default? Its cost and accuracy beside the default lens (opencv5), through the
whole pipeline (``calibrate_images``: detection, the candidates' fits and held-out checks, the re-correction loop),
on a plain lens (the 14 ``paper`` views), a wide rational lens (``rational-wide`` clean) and a fisheye (``fisheye``
clean). Timed alternately in one process at one thread (rendering not timed: cached). Accuracy: the RMS over a
grid of the image of the projection difference to the true camera (the implied rotation fitted,
:func:`circcal.analysis.diff.model_diff`), over the pixels both models project.

Issue 33: make auto the default "if the evidence supports it". The bar used here: auto the default only where it
costs at most 1.5x on the plain lens (the common case pays it on every run) and gives the true lens's accuracy on
the wide ones.
"""

from __future__ import annotations

from benchmarks.timing import alternate, pinned, ratio, summary

SETS = (("paper", "normal", 9), ("rational-wide", "clean", 9), ("fisheye", "clean", 9))
COST_BAR = 1.5


def run() -> dict:
    from circcal.analysis.diff import model_diff
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth
    from circcal.pipeline import LENS_CANDIDATES, calibrate_images
    from circcal.solver import CalibrationOptions
    from circcal.solver.outliers import OutlierRule

    out: dict = {}
    options = CalibrationOptions(outlier_rule=OutlierRule())
    for scenario, variant, repeats in SETS:
        truth = load_truth(fixture_dir(scenario, variant))
        paths = [v.image for v in truth.views]
        held: dict = {}

        def default(paths=paths, board=truth.board, held=held) -> None:
            held["default"] = calibrate_images(paths, board, options, progress=False, jobs=1)

        def auto(paths=paths, board=truth.board, held=held) -> None:
            held["auto"] = calibrate_images(
                paths, board, options, progress=False, jobs=1, lens_candidates=LENS_CANDIDATES
            )

        with pinned(1) as threads:
            t = alternate({"default": default, "auto": auto}, repeats=repeats)
        out["threads"] = threads
        out[f"{scenario}_auto_to_default_time"] = ratio(t["auto"], t["default"])
        out[f"{scenario}_default_s"] = summary(t["default"])
        out[f"{scenario}_auto_lens"] = held["auto"].result.camera.lens
        for k in ("default", "auto"):
            d = model_diff(truth.camera, held[k].result.camera)
            out[f"{scenario}_{k}_vs_truth_rms_px"] = float(d.rms_px)
    cost = out["paper_auto_to_default_time"]["median"]
    out["verdict"] = f"auto costs {cost:.2f}x the default on a plain lens (bar {COST_BAR:g}x): " + (
        "make it the default" if cost <= COST_BAR else "keep opencv5 the default; the verdict recommends the lens"
    )
    return out
