"""Fuzz (issues 13 and 14): seeded hostile images without the board (:mod:`circcal.fixtures.fuzz`: noise, blobs,
dense dots, stripes, checkers, leaves, dot lattices of other sizes, 15-45 x 45 lattices, shapes and text). On every
image: no exception, no grid reported found, and the image done within its time budget (never stopped by it).
Every second image is inverted (bright shapes on a dark ground), so that the search for a board of bright dots on
the inverted image (:func:`circcal.detector.find.detect`) meets the same hostility.

``make test`` runs :data:`FAST_IMAGES` of them; the full :data:`STUDY_IMAGES`-image run is a slow study (``make
study``) that writes its counts to reports/fuzz.md: the seeded images in this process, a subset at 12 MP (4000 x 3000)
through the command line ``circcal detect``, one fresh process per image, whose peak resident memory is measured, and
hostile files (:func:`circcal.fixtures.fuzz.hostile_files`: truncated and corrupt PNG and JPEG, a PNG header claiming
100000 x 100000 pixels, 5000 x 1 images, float32 TIFFs of NaN, 16-bit images, names with ``$``, spaces and bytes not
UTF-8) through the command line in batches, each batch a fresh process, so that exit codes are counted.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest

from circcal.board import Board
from circcal.detector import Reason, detect
from circcal.detector.locate.budget import DEFAULT_TIME_BUDGET_S
from circcal.fixtures.fuzz import FILE_KINDS, KINDS, fuzz_cases, fuzz_image, hostile_files

REPORT = Path(__file__).resolve().parents[1] / "reports" / "fuzz.md"
FAST_IMAGES = 270
"""Images in ``make test`` (30 of each kind; ~20 s on one core)."""
STUDY_SEEDED = 2700
"""Seeded images of the study detected in this process (300 of each kind)."""
STUDY_LARGE_PER_KIND = 2
"""12 MP images of each kind in the study (one as drawn, one inverted), each in a fresh ``circcal detect`` process."""
LARGE_SIZE = (3000, 4000)
"""(H, W) of the study's large images: 12 MP."""
STUDY_FILES = 3000 - STUDY_SEEDED - STUDY_LARGE_PER_KIND * len(KINDS)
"""Hostile files of the study (282), through ``circcal detect`` in batches of :data:`FILE_BATCH`."""
STUDY_IMAGES = STUDY_SEEDED + STUDY_LARGE_PER_KIND * len(KINDS) + STUDY_FILES
"""Images in the study: 3,000."""
FILE_BATCH = 47
MAX_PEAK_RSS_MB = 1000.0
"""The peak resident memory of one ``circcal detect`` process on one 12 MP image must stay below this (MB of
10^6 bytes; the interpreter and its libraries included)."""
_CHILD = (
    "import json, resource, sys\n"
    "from circcal.cli import main\n"
    "rc = main(sys.argv[2:])\n"
    "try:\n"
    "    hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')]\n"
    "    kb = int(hwm[0].split()[1])\n"
    "except (OSError, IndexError):\n"
    "    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
    "with open(sys.argv[1], 'w') as f:\n"
    "    json.dump({'rc': rc, 'maxrss_kb': kb}, f)\n"
    "sys.exit(rc)\n"
)
"""A fresh process: ``circcal detect`` through :func:`circcal.cli.main`, then its exit code and peak resident memory
(KiB) written to the file named first. The peak is Linux's ``VmHWM`` (the high-water mark of this program's own
memory): ``ru_maxrss`` would not do, as Linux carries the parent's resident size into it across the fork and exec
(a child of this test process, 0.7-1 GB after thousands of images, would report that much however small it is);
``ru_maxrss`` only where ``/proc`` is missing."""
BOARDS = (
    Board(7, 7, 10.0, 5.0),
    Board(11, 4, 10.0, 7.0, "asymmetric"),
    Board(3, 3, 10.0, 5.0),
    Board(4, 5, 10.0, 5.0),
    Board(10, 10, 20.0, 8.0, "symmetric", None, (90,), 16.0),
)
"""The boards looked for, in turn: the paper's 7x7, OpenCV's 4x11 acircles, a 3x3 (the smallest claim: issue 14
found 6 false grids of noise specks among ~960 images with it), a 4x5, ROS-I's 10x10 origin-marker board."""


def run_fuzz(n: int, seed: int) -> dict:
    """Detect each board of :data:`BOARDS` in turn in the first ``n`` fuzz images of ``seed``; the tally per kind
    (images, found, reason codes, detection times) and the images found (kind, seed, board)."""
    per: dict[str, dict] = defaultdict(lambda: {"images": 0, "found": 0, "codes": Counter(), "times": []})
    found = []
    for k, (kind, s) in enumerate(fuzz_cases(n, seed)):
        board = BOARDS[k % len(BOARDS)]
        img = fuzz_image(kind, s, board)
        if k % 2:
            img = img.max() - img
        t0 = time.perf_counter()
        d = detect(img, board)
        dt = time.perf_counter() - t0
        row = per[kind]
        row["images"] += 1
        row["times"].append(dt)
        row["codes"][d.code.value if d.code is not None else "found"] += 1
        if d.found:
            row["found"] += 1
            found.append((kind, s, f"{board.rows}x{board.cols} {board.layout}"))
    return {"per_kind": dict(per), "found": found}


def _check(tally: dict) -> None:
    per = tally["per_kind"]
    assert sorted(per) == sorted(KINDS)
    assert tally["found"] == [], f"grids reported in images without one: {tally['found']}"
    budget = [kind for kind, row in per.items() if row["codes"].get(Reason.TIME_BUDGET.value)]
    assert budget == [], f"images stopped by the time budget: {budget}"
    slowest = max(max(row["times"]) for row in per.values())
    assert slowest < DEFAULT_TIME_BUDGET_S


def _table(tally: dict) -> list[str]:
    lines = ["| kind | images | found | median s | max s | reasons (code: images) |", "|---|---|---|---|---|---|"]
    for kind in KINDS:
        row = tally["per_kind"][kind]
        codes = ", ".join(f"{c}: {n}" for c, n in sorted(row["codes"].items()))
        lines.append(
            f"| {kind} | {row['images']} | {row['found']} | {np.median(row['times']):.3f} | "
            f"{max(row['times']):.3f} | {codes} |"
        )
    return lines


def test_fuzz_seeded_no_crash_no_false_grid_within_budget():
    tally = run_fuzz(FAST_IMAGES, seed=1)
    print("\n" + "\n".join(_table(tally)))
    _check(tally)


def _cli(tmp: Path, files: list[bytes], tag: str, board_args: list[str]) -> dict:
    """``circcal detect`` on ``files`` (bytes paths) in a fresh process: its exit code (as the shell sees it), peak
    resident memory (MB), wall time (s) and the JSON's image entries (``None`` when it wrote none)."""
    out, stat = tmp / f"{tag}.json", tmp / f"{tag}.stat"
    argv = [
        sys.executable,
        "-c",
        _CHILD,
        str(stat),
        "detect",
        *files,
        *board_args,
        "--json",
        str(out),
        "--quiet",
        "--jobs",
        "1",
    ]
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, timeout=600)
    wall = time.perf_counter() - t0
    peak = json.loads(stat.read_text())["maxrss_kb"] * 1024 / 1e6 if stat.exists() else float("nan")
    images = json.loads(out.read_text())["images"] if out.exists() else None
    return {
        "rc": proc.returncode,
        "peak_mb": peak,
        "wall": wall,
        "images": images,
        "stderr": proc.stderr.decode(errors="backslashreplace")[-2000:],
    }


def run_large(tmp: Path) -> list[dict]:
    """Each kind at 12 MP (:data:`LARGE_SIZE`), as drawn and inverted, written as PNG and detected by ``circcal
    detect`` (7x7 board) in a fresh process each: kind, exit code, peak memory, wall time, reason code, found."""
    import cv2

    rows = []
    for k, kind in enumerate(KINDS):
        img = fuzz_image(kind, 31_000 + k, None, LARGE_SIZE)
        for inv in range(STUDY_LARGE_PER_KIND):
            path = tmp / f"large {kind} {inv}.png"
            cv2.imwrite(str(path), img.max() - img if inv % 2 else img)
            got = _cli(tmp, [os.fsencode(path)], f"large-{kind}-{inv}", ["--grid", "7x7"])
            entry = (got["images"] or [{}])[0]
            rows.append(
                {
                    "kind": kind,
                    "rc": got["rc"],
                    "peak_mb": got["peak_mb"],
                    "wall": got["wall"],
                    "code": entry.get("reason_code") or ("found" if entry.get("found") else "none"),
                    "found": bool(entry.get("found")),
                    "stderr": got["stderr"],
                }
            )
            path.unlink()
    return rows


def run_files(tmp: Path) -> dict:
    """:data:`STUDY_FILES` hostile files through ``circcal detect`` (4x5 board) in batches: exit codes per batch,
    reason codes per file kind, files found, the peak memory of a batch."""
    folder = tmp / "files"
    folder.mkdir()
    files = hostile_files(folder, STUDY_FILES, seed=3)
    codes: dict[str, Counter] = defaultdict(Counter)
    rcs: Counter = Counter()
    found, bugs, peak = [], [], 0.0
    for b in range(0, len(files), FILE_BATCH):
        batch = files[b : b + FILE_BATCH]
        got = _cli(tmp, [p for _, p in batch], f"files-{b}", ["--grid", "4x5"])
        rcs[got["rc"]] += 1
        peak = max(peak, got["peak_mb"])
        if got["rc"] not in (0, 1, 2):
            bugs.append(got["stderr"])
        for (kind, path), entry in zip(batch, got["images"] or []):
            codes[kind][entry["reason_code"] or "found"] += 1
            if entry["found"]:
                found.append(os.fsdecode(path))
    return {
        "files": len(files),
        "batches": sum(rcs.values()),
        "rcs": rcs,
        "codes": dict(codes),
        "found": found,
        "bugs": bugs,
        "peak_mb": peak,
    }


@pytest.mark.slow
def test_fuzz_study_writes_its_counts(tmp_path):
    t0 = time.perf_counter()
    tally = run_fuzz(STUDY_SEEDED, seed=2)
    large = run_large(tmp_path)
    files = run_files(tmp_path)
    wall = time.perf_counter() - t0
    images = sum(r["images"] for r in tally["per_kind"].values())
    found = sum(r["found"] for r in tally["per_kind"].values())
    slowest = max((max(r["times"]), kind) for kind, r in tally["per_kind"].items())
    worst = max(large, key=lambda r: r["peak_mb"])
    large_rcs = Counter(r["rc"] for r in large)
    n_all = images + len(large) + files["files"]
    false_grids = found + sum(r["found"] for r in large) + len(files["found"])
    text = (
        [
            "# Fuzz: hostile images without a board",
            "",
            f"`tests/test_fuzz.py::test_fuzz_study_writes_its_counts` (`make study`), seeds 2, 31000 and 3: "
            f"**{n_all} hostile images and files, {false_grids} grids found** (false detections), "
            f"{len(files['bugs']) + sum(n for rc, n in large_rcs.items() if rc not in (0, 1, 2))} exits 70 "
            f"(a bug) or crashes; {wall:.0f} s in all on {os.cpu_count()} CPUs (one detection at a time). Default "
            f"time budget {DEFAULT_TIME_BUDGET_S:g} s per image.",
            "",
            f"## {images} seeded images, in this process",
            "",
            "Drawn by `circcal.fixtures.fuzz` (noise, blobs, dense dots, stripes, checkers, leaves, dot lattices of "
            "other sizes than the board, 15-45 x 45 lattices, shapes and text; 240x320 to 480x640 px), each searched "
            "for one of the boards in turn: 7x7, 4x11 asymmetric, 3x3, 4x5 and ROS-I's 10x10 origin-marker board; "
            "every second image inverted (bright on dark: the bright-dot search meets it too).",
            "",
            f"{found} grids found, 0 exceptions, 0 images stopped by the time budget; the slowest image took "
            f"{slowest[0]:.3f} s ({slowest[1]}).",
            "",
        ]
        + _table(tally)
        + [
            "",
            f"## {len(large)} images of 12 MP (4000 x 3000), `circcal detect` in a fresh process each",
            "",
            "Each kind at 12 MP at the same texture density (the counts of shapes scale with the area: ~70 times as "
            "many dots as at 480x360), as drawn and inverted, written as PNG, searched for the 7x7 board. Peak "
            "resident memory of the whole process (Linux's `VmHWM` at its end: the interpreter, numpy, OpenCV, numba "
            "and the decoded image included; ~300 MB of it is the interpreter and its libraries), bound asserted: "
            f"< {MAX_PEAK_RSS_MB:g} MB.",
            "",
            f"Exit codes: {', '.join(f'{rc}: {n}' for rc, n in sorted(large_rcs.items()))}; "
            f"{sum(r['found'] for r in large)} grids found; peak memory at most **{worst['peak_mb']:.0f} MB** "
            f"({worst['kind']}); median {np.median([r['peak_mb'] for r in large]):.0f} MB; slowest process "
            f"{max(r['wall'] for r in large):.1f} s (start-up and PNG decoding included).",
            "",
            "| kind | exit codes | reasons | peak MB (max) | process s (max) |",
            "|---|---|---|---|---|",
        ]
    )
    for kind in KINDS:
        rows = [r for r in large if r["kind"] == kind]
        text.append(
            f"| {kind} | {', '.join(str(r['rc']) for r in rows)} | "
            f"{', '.join(sorted({r['code'] for r in rows}))} | {max(r['peak_mb'] for r in rows):.0f} | "
            f"{max(r['wall'] for r in rows):.1f} |"
        )
    text += [
        "",
        f"## {files['files']} hostile files, `circcal detect` in {files['batches']} batches",
        "",
        "`circcal.fixtures.fuzz.hostile_files` (kinds in turn), named with `$`, spaces, quotes and bytes that "
        "are not UTF-8 (written and passed as bytes paths), searched for a 4x5 board, "
        f"{FILE_BATCH} files per fresh process. Exit codes of the batches: "
        f"{', '.join(f'{rc}: {n}' for rc, n in sorted(files['rcs'].items()))} (1: some image not found, as "
        f"expected; 70: a bug); {len(files['found'])} grids found; peak memory of a batch "
        f"{files['peak_mb']:.0f} MB.",
        "",
        "| file kind | reasons (code: files) |",
        "|---|---|",
    ]
    for kind in FILE_KINDS:
        codes = files["codes"].get(kind, Counter())
        text.append(f"| {kind} | {', '.join(f'{c}: {n}' for c, n in sorted(codes.items())) or 'none (batch failed)'} |")
    text += [
        "",
        "Reason codes: `too-few-candidates` (fewer dot-like blobs than the board needs), `grid-not-recognised` "
        "(no lattice of dots, or none regular), `grid-mismatch` (a lattice of another size: larger, smaller or "
        "transposed, said so in the message), `too-few-points` / `ambiguous-view` (a lattice that could be part "
        "of the board, too small or ambiguous to label), `irregular-grid` (a labelled lattice that failed the "
        "trust checks), `unreadable` / `bad-image` (a file that is no image, or not one the detector takes), "
        "`time-budget-exceeded` (stopped by the budget).",
        "",
    ]
    if files["bugs"] or any(r["rc"] not in (0, 1, 2) for r in large):
        text += (
            ["## Failures", "", "```"]
            + [b for b in files["bugs"]]
            + [r["stderr"] for r in large if r["rc"] not in (0, 1, 2)]
            + ["```", ""]
        )
    REPORT.write_text("\n".join(text))
    print("\n".join(text))
    _check(tally)
    assert false_grids == 0
    assert all(r["rc"] in (0, 1) for r in large), [(r["kind"], r["rc"], r["stderr"][-500:]) for r in large]
    assert all(r["peak_mb"] < MAX_PEAK_RSS_MB for r in large), [(r["kind"], r["peak_mb"]) for r in large]
    assert files["bugs"] == [], files["bugs"]
    assert set(files["rcs"]) <= {0, 1, 2}


@pytest.mark.parametrize(
    "kind, seed, board, invert",
    [
        # a staggered lattice on a card: its diagonals make a square lattice whose part spans a 7x7 board; the
        # board's unseen corners lie off the card in 3 separate gaps (the fuzz study's one false grid before)
        ("lattice", 202091, Board(7, 7, 10.0, 5.0), True),
        # a 45x45 lattice of thin dots, of which only a scattered subset passed the 12 px^2 candidate size: a 26-dot
        # patch with holes that fit one placement of the 4x11 board (found once thin dots were measured at their
        # edge); with the 6 px^2 floor more of them are candidates and the lattice shows as larger than the board
        ("big-lattice", 100028, Board(11, 4, 10.0, 7.0, "asymmetric"), False),
    ],
)
def test_a_lattice_of_another_shape_is_not_a_partial_board(kind, seed, board, invert):
    img = fuzz_image(kind, seed, board)
    if invert:
        img = img.max() - img
    d = detect(img, board)
    # refused, as a lattice whose unseen board dots lie in separate gaps, or as one larger than the board
    assert not d.found and ("separate gaps inside the image" in d.reason or "has more dots than" in d.reason), d.reason
