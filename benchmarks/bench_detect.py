"""Detector timing: circcal ``detect`` against ``cv2.findCirclesGrid`` on the same images (benchmarks/timing.py:
alternated, at least 9 repeats, median [min-max], threads pinned and stated).

``run() -> dict`` (part of ``make bench``; alone: ``python -m benchmarks.run bench_detect``):

* ``paper``: 1920x1080 renders of the paper's 7x7 board: the first call in a fresh process (numba's compile or
  cache load), apart; OpenCV at its default pool (what a user gets; circcal's OpenCV calls use it too); circcal's
  peak Python-heap memory per image (tracemalloc sees numpy's buffers, not OpenCV's or numba's).
* ``resolutions``: the paper's views at 640x480, 1920x1080, 4000x3000 and 8000x6000 (the paper's camera scaled to
  the size), clean and in the ``paper`` scenario's normal and weak light, one thread each: per-image times and the
  per-round ratio circcal / findCirclesGrid, and how many views each found. Bars (issue 17): <= 0.8x at 640x480 and
  1920x1080, < 1.0x at 4000x3000 and 8000x6000. Weak light at 640x480 and 1920x1080 also against findCirclesGrid
  with its blob detector's ``minThreshold`` lowered so that it finds the boards (:data:`WEAK_MIN_THRESHOLD`).
* ``small_dots``: a 7x7 board of small dots (8 px across at 1920x1080, 6 px at 4000x3000), whose dots the shrunk
  segmentation cannot resolve, against the paper's views at the same size: the finer path's time over the normal
  path's (bar: <= 3x).
* ``variants``: the same as ``resolutions`` on the clutter and partial-view fixtures (OpenCV finds no partial view;
  it is timed all the same), each with how many views each detector found.
* ``scaling``: 1920x1080 images of n random dark dots (n = 10 ... 2,000, no board): circcal's whole detection and
  its grid search alone (recognition on the candidates of the first segmentation) against findCirclesGrid, with
  the growth exponents fitted over n >= 100 (time ~ n^e). findCirclesGrid grows about cubically (7 s at 1,000
  dots, 33 s at 2,000 measured): it is timed once per n up to :data:`OPENCV_MAX_DOTS`.
* ``hostile``: the images the issue named: 1,500 random dots and a 45 x 45 dot lattice (before: past 90 s).
* ``default_malloc``: the clean ``resolutions`` pairs at 640x480 and 1920x1080 again, in a child process under
  glibc's default malloc settings (what a user's process has; the rest of ``make bench`` runs under
  :data:`~benchmarks.timing.MALLOC_ENV`). A tool whose large buffers fault in anew on every call is slower there
  (circcal's guided filter was: 16.1 against 10.9 ms per 640x480 image), so this figure is the one a user sees.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import cv2
import numpy as np

from benchmarks.timing import MALLOC_ENV, MIN_REPEATS, alternate, pinned, ratio, summary

SCALING_DOTS = (10, 30, 100, 300, 1000, 2000)
"""Dots per scaling image."""
OPENCV_MAX_DOTS = 1000
"""findCirclesGrid is timed up to this many dots (once: 7 s at 1,000, 33 s at 2,000; cubic)."""
EXPONENT_FROM = 100
"""The growth exponent is fitted over images of at least this many dots (below, the per-image baseline of
segmentation dominates)."""
SCALING_REPEATS = MIN_REPEATS
VARIANTS = (
    ("wide", "clutter"),
    ("distractors", "clutter"),
    ("partial", "out-of-frame"),
    ("partial", "occlusion"),
    ("markers", "clean"),
    ("occluded", "hand"),
)
"""(scenario, variant) timed beside the paper images: clutter, and partial views (the markers set's last 8 views
are its corner views)."""
VARIANT_VIEWS = 6
"""Views per variant timed (the corner views of ``markers`` are its last ones: they are taken from the end)."""


RESOLUTIONS = ((640, 480), (1920, 1080), (4000, 3000), (8000, 6000))
"""Frame sizes of the ``resolutions`` benchmark."""
LIGHT = ("clean", "normal", "weak")
"""Light of the ``resolutions`` benchmark (``normal``, ``weak``: the paper scenario's perturbations)."""
VIEWS_AT = {(640, 480): 4, (1920, 1080): 4, (4000, 3000): 2, (8000, 6000): 1}
"""Views per size (findCirclesGrid takes ~1-3 s on an 8000x6000 frame: 9 repeats of 3 lights)."""
SUPERSAMPLE_AT = {(4000, 3000): 2, (8000, 6000): 2}
WEAK_TUNED_AT = ((640, 480), (1920, 1080))
WEAK_MIN_THRESHOLD = 10.0
"""findCirclesGrid's default blob detector thresholds from grey level 50 up, above the whole dark range of the weak-light
views (their board's white is ~70 of 255), so it finds none and its time is the time it takes to give up. Beside it,
where the bar is timed: the same call with the detector's ``minThreshold`` at this level, which finds them (the same
result as circcal's, timed alike)."""
"""The renderer's supersampling where 6 would take minutes (edges a little less exact: no matter for timing)."""


def _paper_views(n: int = 4, size: tuple[int, int] = (1920, 1080), light: str = "clean"):
    from circcal.fixtures.frames import paper_views
    from circcal.fixtures.scenarios import SCENARIOS

    steps = [] if light == "clean" else SCENARIOS["paper"].variants[light]
    return paper_views(*size, n, steps, supersample=SUPERSAMPLE_AT.get(size, 6))


def _flags(board) -> int:
    return cv2.CALIB_CB_ASYMMETRIC_GRID if board.layout == "asymmetric" else cv2.CALIB_CB_SYMMETRIC_GRID


def _pair(imgs, board, det, repeats: int = MIN_REPEATS, blob_detector=None) -> dict:
    """Alternated per-image timings of circcal and findCirclesGrid over ``imgs`` (each round: every image once by
    each), the ratio per round, and how many images each found. ``blob_detector``: findCirclesGrid's (its default
    SimpleBlobDetector when ``None``)."""
    found = {"circcal": 0, "opencv": 0}
    extra = {} if blob_detector is None else {"blobDetector": blob_detector}

    def ours():
        return [det.detect(im, board) for im in imgs]

    def theirs():
        return [cv2.findCirclesGrid(im, board.pattern_size, flags=_flags(board), **extra) for im in imgs]

    found["circcal"] = sum(d.found for d in ours())
    found["opencv"] = sum(bool(ok) for ok, _ in theirs())
    t = alternate({"circcal": ours, "opencv": theirs}, repeats=repeats)
    n = len(imgs)
    return {
        "circcal_s_per_image": summary([x / n for x in t["circcal"]]),
        "opencv_s_per_image": summary([x / n for x in t["opencv"]]),
        "ratio_circcal_over_opencv": ratio(t["circcal"], t["opencv"]),
        "found": found,
        "images": n,
    }


def _paper(det) -> dict:
    imgs, board = _paper_views()
    t0 = time.perf_counter()
    det.detect(imgs[0], board)  # first call: numba's compile (or cache load), imports, tables
    first_call = time.perf_counter() - t0
    out: dict = {
        "image": "1920x1080 uint8, 7x7 symmetric grid (paper setup), clean",
        "views": len(imgs),
        "circcal_first_call_s": first_call,
    }
    default = cv2.getNumThreads()
    cv2.setNumThreads(-1)
    try:
        out["opencv_default_threads"] = cv2.getNumThreads()
        out["default_threads"] = _pair(imgs, board, det)
    finally:
        cv2.setNumThreads(default)
    tracemalloc.start()
    det.detect(imgs[0], board)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    out["circcal_peak_python_memory_mb"] = peak / 2**20
    return out


def _resolutions(det) -> dict:
    out: dict = {
        "bar": "one thread: circcal <= 0.8x findCirclesGrid at 640x480 and 1920x1080, < 1.0x at 4000x3000 "
        "and 8000x6000 (ratio medians)"
    }
    with pinned(1) as threads:
        out["threads"] = threads
        for size in RESOLUTIONS:
            for light in LIGHT:
                imgs, board = _paper_views(VIEWS_AT[size], size, light)
                out[f"{size[0]}x{size[1]} {light}"] = _pair(imgs, board, det)
                if light == "weak" and size in WEAK_TUNED_AT:
                    params = cv2.SimpleBlobDetector_Params()
                    params.minThreshold = WEAK_MIN_THRESHOLD
                    out[f"{size[0]}x{size[1]} weak, OpenCV minThreshold {WEAK_MIN_THRESHOLD:g}"] = _pair(
                        imgs, board, det, blob_detector=cv2.SimpleBlobDetector_create(params)
                    )
                del imgs
    return out


def _small_dots(det) -> dict:
    from circcal.board import Board
    from circcal.fixtures.frames import embedded_board

    board = Board(7, 7, 10.0, 5.0)
    out: dict = {"bar": "the small dots' path <= 3x the normal path (ratio median)"}
    with pinned(1) as threads:
        out["threads"] = threads
        for size, dot_px in (((1920, 1080), 8.0), ((4000, 3000), 6.0)):
            small, _ = embedded_board(board, *size, dot_px / 2, (0.45 * size[0], 0.55 * size[1]))
            normal, _ = _paper_views(1, size, "normal")
            found = [bool(det.detect(small, board).found), bool(det.detect(normal[0], board).found)]
            t = alternate(
                {
                    "small": lambda: det.detect(small, board),  # noqa: B023 - timed in this iteration
                    "normal": lambda: det.detect(normal[0], board),  # noqa: B023
                }
            )
            out[f"{size[0]}x{size[1]}"] = {
                "small_dots_px": dot_px,
                "small_s": summary(t["small"]),
                "normal_s": summary(t["normal"]),
                "ratio_small_over_normal": ratio(t["small"], t["normal"]),
                "found_small_normal": found,
            }
    return out


def _variants(det) -> dict:
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth

    out = {}
    with pinned(1):
        for name, variant in VARIANTS:
            tr = load_truth(fixture_dir(name, variant))
            views = tr.views[-VARIANT_VIEWS:]
            imgs = [cv2.imread(str(v.image), cv2.IMREAD_UNCHANGED) for v in views]
            out[f"{name}-{variant}"] = _pair(imgs, tr.board, det)
    return out


def _dots(n: int, seed: int, size: tuple[int, int] = (1080, 1920)) -> np.ndarray:
    """(H, W) uint8: ``n`` dark anti-aliased dots of radius 4-9 px at random on a bright ground."""
    from circcal.fixtures.fuzz import _fine, _pt

    rng = np.random.default_rng(seed)
    h, w = size

    def draw(c, S):
        for _ in range(n):
            cv2.circle(c, _pt(rng.uniform(0, w), rng.uniform(0, h), S), int(rng.uniform(4, 9) * S), 255, -1)

    return np.clip(np.rint(_fine(draw, h, w, 0.85, 0.1) * 255), 0, 255).astype(np.uint8)


def _lattice(rows: int, cols: int, pitch_px: float, size: tuple[int, int] = (1080, 1920)) -> np.ndarray:
    """(H, W) uint8: a ``rows`` x ``cols`` lattice of dark dots (radius a quarter of the pitch), slightly rotated."""
    from circcal.fixtures.fuzz import _fine, _pt

    h, w = size
    a = np.deg2rad(7.0)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])

    def draw(c, S):
        for i in range(rows):
            for j in range(cols):
                p = R @ (np.array([j - (cols - 1) / 2, i - (rows - 1) / 2]) * pitch_px) + [w / 2, h / 2]
                cv2.circle(c, _pt(*p, S), int(0.25 * pitch_px * S), 255, -1)

    return np.clip(np.rint(_fine(draw, h, w, 0.85, 0.1) * 255), 0, 255).astype(np.uint8)


def _exponent(ns, ts) -> float:
    ns, ts = np.asarray(ns, float), np.asarray(ts, float)
    keep = ns >= EXPONENT_FROM
    return float(np.polyfit(np.log(ns[keep]), np.log(ts[keep]), 1)[0]) if keep.sum() >= 2 else float("nan")


def _scaling(det) -> dict:
    from circcal.board import Board
    from circcal.detector.image import STRETCH_TAIL_PX, normalise_u8
    from circcal.detector.locate.candidates import area_limits, find_candidates
    from circcal.detector.locate.recognise import recognise
    from circcal.detector.locate.segment import segmentations, shrink

    board = Board(7, 7, 10.0, 5.0)
    rows = []
    with pinned(1) as threads:
        for k, n in enumerate(SCALING_DOTS):
            img = _dots(n, 1000 + k)
            H, W = img.shape
            lo, hi = area_limits(board, W, H)
            s = 3
            mask = next(segmentations(normalise_u8(shrink(img, s), STRETCH_TAIL_PX / s**2)))[1]
            cands = find_candidates(mask, min_area=lo / s**2, max_area=hi / s**2, scale=s)
            t = alternate(
                {
                    "detect": lambda: det.detect(img, board),  # noqa: B023 - timed in this iteration
                    "grid_search": lambda: recognise(board, cands, (W, H)),  # noqa: B023
                },
                repeats=SCALING_REPEATS,
            )
            row = {
                "dots": n,
                "candidates": len(cands),
                "circcal_detect_s": summary(t["detect"]),
                "circcal_grid_search_s": summary(t["grid_search"]),
            }
            if n <= OPENCV_MAX_DOTS:
                t0 = time.perf_counter()
                cv2.findCirclesGrid(img, board.pattern_size, flags=cv2.CALIB_CB_SYMMETRIC_GRID)
                row["opencv_findCirclesGrid_s_once"] = time.perf_counter() - t0
            rows.append(row)
    ns = [r["dots"] for r in rows]
    cv = [(r["dots"], r["opencv_findCirclesGrid_s_once"]) for r in rows if "opencv_findCirclesGrid_s_once" in r]
    return {
        "threads": threads,
        "rows": rows,
        "exponent_circcal_detect": _exponent(ns, [r["circcal_detect_s"]["median"] for r in rows]),
        "exponent_circcal_grid_search": _exponent(ns, [r["circcal_grid_search_s"]["median"] for r in rows]),
        "exponent_opencv": _exponent([a for a, _ in cv], [b for _, b in cv]),
        "note": f"time ~ dots^exponent fitted over dots >= {EXPONENT_FROM}; findCirclesGrid timed once per "
        f"image up to {OPENCV_MAX_DOTS} dots",
    }


def _hostile(det) -> dict:
    from circcal.board import Board

    board = Board(7, 7, 10.0, 5.0)
    out = {}
    with pinned(1):
        for name, img in (("1500 random dots", _dots(1500, 7)), ("45x45 dot lattice", _lattice(45, 45, 22.0))):
            d = det.detect(img, board)
            t = alternate({"d": lambda: det.detect(img, board)})["d"]  # noqa: B023 - timed in this iteration
            out[name] = {
                "circcal_detect_s": summary(t),
                "found": bool(d.found),
                "reason": d.reason,
                "was": "past 90 s before the bounded grid search",
            }
    return out


DEFAULT_MALLOC_SIZES = ((640, 480), (1920, 1080))
"""Frame sizes timed again under glibc's default malloc (``default_malloc``)."""


def _default_malloc_pairs() -> dict:
    """The clean ``resolutions`` pairs at :data:`DEFAULT_MALLOC_SIZES`, one thread, in this process (run by
    :func:`_default_malloc` in a child without :data:`~benchmarks.timing.MALLOC_ENV`)."""
    import circcal.detector.find as det

    out: dict = {"malloc": "glibc defaults (no MALLOC_* variables)"}
    with pinned(1) as threads:
        out["threads"] = threads
        for size in DEFAULT_MALLOC_SIZES:
            imgs, board = _paper_views(VIEWS_AT[size], size, "clean")
            out[f"{size[0]}x{size[1]} clean"] = _pair(imgs, board, det)
    return out


def _default_malloc() -> dict:
    """:func:`_default_malloc_pairs` in a fresh child process whose environment has no MALLOC_* variables."""
    env = {k: v for k, v in os.environ.items() if k not in MALLOC_ENV}
    proc = subprocess.run(
        [sys.executable, "-m", "benchmarks.bench_detect", "--default-malloc-pairs"],
        env=env,
        cwd=Path(__file__).resolve().parents[1],
        capture_output=True,
        text=True,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"the default-malloc child exited {proc.returncode}:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run() -> dict:
    import circcal.detector.find as det

    return {
        "paper": _paper(det),
        "resolutions": _resolutions(det),
        "small_dots": _small_dots(det),
        "variants": _variants(det),
        "scaling": _scaling(det),
        "hostile": _hostile(det),
        "default_malloc": _default_malloc(),
    }


if __name__ == "__main__":
    if "--default-malloc-pairs" in sys.argv:
        print(json.dumps(_default_malloc_pairs()))
    else:
        print(json.dumps(run(), indent=1))
