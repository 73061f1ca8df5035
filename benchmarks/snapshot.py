"""What a detector change does to the detections, before its speed is measured: record every detection of a fixed
set of images, then compare another build's against it.

    python -m benchmarks.snapshot record before.npz      # on the old code
    python -m benchmarks.snapshot compare before.npz     # on the new code: what changed, worst first

The set (~620 images, ~40 s on one core): the paper's views at 640x480, 1920x1080 and 4000x3000 in its five lights,
boards of 6-12 px dots in 1920x1080 and 4000x3000 frames, every view of every circle-grid fixture scenario (rendered
on demand, cached), the real photographs of ``../shared/data/realdata`` where present, and 90 hostile images without
a board (:mod:`circcal.fixtures.fuzz`: the refusals and their words). Per image: found, reason
code and words, centres, segmentation, dropped dots with their words. ``compare`` lists every image whose outcome
changed (found, reason, dropped dots or their words, the set of dots seen) and the largest centre moves; it exits 1
when an outcome changed. A speed change is meant to leave all of it bit-identical; one that cannot (a different
rounding, a different start for the edge fit) says so with the moves it measured, and its accuracy against the
truth (tests/test_hard_views.py, tests/detector/test_find.py) decides.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "realdata"
REAL_SETS = (
    ("boofcv_sony_hx5v_circle_regular_10x8", dict(rows=8, cols=10, pitch_mm=25.0, diameter_mm=15.0)),
    ("boofcv_sony_hx5v_circle_asym_4x5", dict(rows=5, cols=4, pitch_mm=30.0, diameter_mm=20.0, layout="asymmetric")),
)
HOSTILE_IMAGES = 90
"""Images of :mod:`circcal.fixtures.fuzz` in the set (10 of each kind)."""


def cases() -> Iterator[tuple[str, np.ndarray, object]]:
    """``(key, image, board)`` of every image of the set, in a fixed order."""
    from benchmarks.bench_detect import _paper_views
    from circcal.board import Board
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.frames import embedded_board
    from circcal.fixtures.fuzz import fuzz_cases, fuzz_image
    from circcal.fixtures.scenarios import SCENARIOS
    from circcal.fixtures.truth import load_truth

    for size, n in (((640, 480), 4), ((1920, 1080), 4), ((4000, 3000), 2)):
        for light in ("clean", "normal", "uneven", "strong", "weak"):
            imgs, board = _paper_views(n, size, light)
            for i, im in enumerate(imgs):
                yield f"paper{size[0]}-{light}-{i}", im, board
    board = Board(7, 7, 10.0, 5.0)
    for size, dot_px in (((1920, 1080), 8.0), ((4000, 3000), 6.0), ((4000, 3000), 8.0), ((4000, 3000), 12.0)):
        im, _ = embedded_board(board, *size, dot_px / 2, (0.45 * size[0], 0.55 * size[1]))
        yield f"small{size[0]}-{dot_px:g}", im, board
    for name, sc in SCENARIOS.items():
        if sc.board.layout == "checkerboard":
            continue
        for variant in sc.variants:
            tr = load_truth(fixture_dir(name, variant))
            for v in tr.views:
                yield f"{name}-{variant}-{v.image.name}", cv2.imread(str(v.image), cv2.IMREAD_UNCHANGED), tr.board
    for folder, kw in REAL_SETS:
        for f in sorted((REALDATA / folder).glob("image*.jpg")):
            im = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
            if im is not None:
                yield f"real-{folder}-{f.name}", im, Board(**kw)
    boards = (board, Board(11, 4, 10.0, 7.0, "asymmetric"), Board(4, 5, 10.0, 5.0))
    for k, (kind, seed) in enumerate(fuzz_cases(HOSTILE_IMAGES, 1)):
        yield f"hostile-{kind}-{seed}", fuzz_image(kind, seed, boards[k % 3]), boards[k % 3]


def record() -> dict:
    """key -> ``(found, reason code, reason words, centres (N, 2) or (0, 2), segmentation, dropped items)``."""
    from circcal.detector import detect

    out = {}
    for key, im, board in cases():
        d = detect(im, board, time_budget_s=None)
        out[key] = (
            d.found,
            d.code.value if d.code is not None else "",
            d.reason or "",
            d.centres if d.found else np.zeros((0, 2)),
            d.segmentation or "",
            sorted(d.dropped.items()),
        )
    return out


def compare(base: dict, new: dict, show: int = 12) -> int:
    """Print what changed from ``base`` to ``new``; the number of images whose outcome changed."""
    changed, moves = 0, []
    for key in sorted(set(base) | set(new)):
        if key not in base or key not in new:
            print(f"only in {'new' if key in new else 'base'}: {key}")
            changed += 1
            continue
        (bf, bc, br, bx, bs, bd), (f, c, r, x, s, dr) = base[key], new[key]
        if (bf, bc, br, bd) != (f, c, r, dr) or not np.array_equal(np.isfinite(bx), np.isfinite(x)):
            print(f"CHANGED {key}: {bc or 'found'} {br} {bd} -> {c or 'found'} {r} {dr}")
            changed += 1
            continue
        if f:
            seen = np.isfinite(x[:, 0])
            moves.append((float(np.abs(x[seen] - bx[seen]).max()) if seen.any() else 0.0, key, bs, s))
    moves.sort(reverse=True)
    d = np.array([m[0] for m in moves])
    print(
        f"{len(new)} images; outcome changed on {changed}; centres bit-identical on {int(np.sum(d == 0))} of "
        f"{len(d)} found, largest move {d.max() if len(d) else 0.0:.2e} px, median {np.median(d) if len(d) else 0:.2e}"
    )
    for m, key, bs, s in moves[:show]:
        if m > 0:
            print(f"  {m:.3e} px  {key}  ({bs} -> {s})")
    return changed


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] not in ("record", "compare"):
        print(__doc__)
        return 2
    cv2.setNumThreads(1)
    t0 = time.perf_counter()
    snap = record()
    print(f"{len(snap)} images detected in {time.perf_counter() - t0:.0f} s")
    if argv[0] == "record":
        with open(argv[1], "wb") as f:  # (to the name given: np.save would append .npy to a path)
            np.save(f, np.array(snap, dtype=object), allow_pickle=True)
        return 0
    base = np.load(argv[1], allow_pickle=True).item()
    return 1 if compare(base, snap) else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
