"""``circcal detect IMAGES... --grid RxC [--asymmetric] [--model MODEL] --json OUT [--overlay DIR]``.

Writes ``{"board": board.to_dict(), "complete": bool, "images": [{"image": path, "found": bool,
"centers": [[x, y] | null, ...] | null, "reason": null | "why not", "reason_code": null | code, "complete": bool,
"points_seen": n, "dots_dropped": {index: why}, "notes": [...]}]}``, images in the order given: a point not seen
(out of frame, occluded, a dot left out as bad) has a null centre; ``--markers`` labels partial views. The file is rewritten (atomically) as results come in, at most every few seconds and once at the end, so an
interruption or a failure loses nothing already done; ``"complete": false`` marks a partial file (images still
missing are left out). ``--grid RxC``: R rows by C columns of *points* (OpenCV patternSize (C, R)). ``--model``: a
camera in any format circcal reads (model.json, OpenCV YAML, mrcal, COLMAP, ROS) for the distortion-aware centre
correction. A failed image never stops the others and always says why.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from circcal.commands.args import DIAMETER_HELP, board_from_args, check_output, parse_grid, parse_length_mm, \
    positive_int
from circcal.commands.board import add_marker_arguments, board_with_markers

#: The partial detections.json is rewritten at most this often (s): an interruption loses at most this much work.
SAVE_EVERY_S = 2.0


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("detect", help="find circle grids and write unbiased centre projections as JSON",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("images", nargs="+", type=Path, help="image files")
    p.add_argument("--grid", required=True, type=parse_grid, help="RxC: R rows by C columns of points")
    p.add_argument("--asymmetric", action="store_true", help="OpenCV asymmetric (acircles) layout")
    p.add_argument("--pitch", type=parse_length_mm, default=10.0,
                   help="board pitch, e.g. 10mm (OpenCV squareSize; default 10 mm)")
    p.add_argument("--diameter", type=parse_length_mm, default=None, help=DIAMETER_HELP)
    add_marker_arguments(p)
    p.add_argument("--model", type=Path, default=None,
                   help="camera model (any format circcal reads) for the distortion-aware centre correction")
    p.add_argument("--json", required=True, type=Path, dest="json_out", help="output JSON file")
    p.add_argument("--overlay", type=Path, default=None, help="folder for PNG overlays to check by eye")
    p.add_argument("--quiet", "--no-progress", dest="quiet", action="store_true",
                   help="no progress bar (--no-progress, as the other commands spell it)")
    p.add_argument("--jobs", type=positive_int, default=None,
                   help="images detected at once (default: one per CPU, at most 8; results do not depend on it)")
    p.set_defaults(func=run)


def _entry(path: Path, d) -> dict:
    """One image's record: centres (null for a point not seen: out of frame, occluded, or dropped), whether the
    view shows the whole board (``complete``), the dots left out as bad (``dots_dropped``: index -> reason) and
    what else the image shows (``notes``)."""
    return {"image": str(path), "found": bool(d.found), "centers": d.centres.tolist() if d.found else None,
            "reason": d.reason, "reason_code": None if d.code is None else d.code.value,
            "complete": bool(d.complete) if d.found else None,
            "points_seen": int(d.seen.sum()) if d.found else 0,
            "dots_dropped": {str(k): r for k, r in d.dropped.items()}, "notes": list(d.notes)}


def run(args: argparse.Namespace) -> int:
    from circcal import atomic
    from circcal.detector import detect_files, read_image
    from circcal.formats import read_camera
    from circcal.jsonio import dumps

    check_output(args.json_out)
    if args.overlay is not None:
        check_output(args.overlay, folder=True)
    board = board_with_markers(args, board_from_args(args.grid, args.pitch, args.diameter, args.asymmetric))
    camera = read_camera(args.model) if args.model is not None else None
    entries: dict[int, dict] = {}
    last_save = [time.monotonic()]

    def save(complete: bool) -> None:
        doc = {"board": board.to_dict(), "complete": complete,
               "images": [entries[i] for i in sorted(entries)]}
        args.json_out.parent.mkdir(parents=True, exist_ok=True)
        atomic.write_text(args.json_out, dumps(doc, indent=1) + "\n")
        last_save[0] = time.monotonic()

    def on_result(i: int, d) -> None:
        path = Path(args.images[i])
        entries[i] = _entry(path, d)
        if args.overlay is not None and path.is_file():
            img = read_image(path)
            if img is not None:
                from circcal.detector.overlay import write_overlay

                write_overlay(Path(args.overlay) / (path.stem + "_detect.png"), img, d)
        if time.monotonic() - last_save[0] >= SAVE_EVERY_S:
            save(complete=False)

    try:
        dets = detect_files(list(args.images), board, camera, progress=not args.quiet, jobs=args.jobs,
                            on_result=on_result)
    except BaseException:
        if entries:
            save(complete=False)  # keep what is done: an interruption or a failure in a later image
        raise
    save(complete=True)
    n = sum(d.found for d in dets)
    print(f"circcal detect: grid found in {n} of {len(dets)} images -> {args.json_out}")
    for path, d in zip(args.images, dets):
        if not d.found:
            print(f"  {path}: {d.reason}")
        elif not d.complete or d.dropped:
            print(f"  {path}: {int(d.seen.sum())} of {board.n_points} points"
                  + ("" if d.complete else " (partial view)")
                  + (f", {d.n_dropped} dot(s) left out as bad" if d.dropped else ""))
        for note in d.notes:
            print(f"  {path}: {note}")
    return 0 if n == len(dets) else 1
