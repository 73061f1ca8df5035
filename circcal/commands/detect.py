"""``circcal detect IMAGES... --grid RxC [--asymmetric] [--model model.json] --json OUT [--overlay DIR]``.

Writes ``{"board": board.to_dict(), "images": [{"image": path, "found": bool, "centers": [[x, y], ...] | null,
"reason": null | "why not"}]}``. ``--grid RxC``: R rows by C columns of *points* (OpenCV patternSize (C, R)).
A failed image never stops the others and always says why.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from circcal.commands.args import DIAMETER_HELP, board_from_args, parse_grid, parse_length_mm, positive_int


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("detect", help="find circle grids and write unbiased centre projections as JSON",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("images", nargs="+", type=Path, help="image files")
    p.add_argument("--grid", required=True, type=parse_grid, help="RxC: R rows by C columns of points")
    p.add_argument("--asymmetric", action="store_true", help="OpenCV asymmetric (acircles) layout")
    p.add_argument("--pitch", type=parse_length_mm, default=10.0,
                   help="board pitch, e.g. 10mm (OpenCV squareSize; default 10 mm)")
    p.add_argument("--diameter", type=parse_length_mm, default=None, help=DIAMETER_HELP)
    p.add_argument("--model", type=Path, default=None, help="model.json with a 'camera' block (distortion-aware)")
    p.add_argument("--json", required=True, type=Path, dest="json_out", help="output JSON file")
    p.add_argument("--overlay", type=Path, default=None, help="folder for PNG overlays to check by eye")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--jobs", type=positive_int, default=None,
                   help="images detected at once (default: one per CPU, at most 8; results do not depend on it)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from circcal.detector import detect_files, read_image
    from circcal.model import Camera

    board = board_from_args(args.grid, args.pitch, args.diameter, args.asymmetric)
    camera = None
    if args.model is not None:
        data = json.loads(Path(args.model).read_text())
        if "camera" not in data:
            raise ValueError(f"{args.model} has no 'camera' block")
        camera = Camera.from_dict(data["camera"])
    dets = detect_files(list(args.images), board, camera, progress=not args.quiet, jobs=args.jobs)
    out = {"board": board.to_dict(), "images": []}
    for path, d in zip(args.images, dets):
        out["images"].append({"image": str(path), "found": bool(d.found),
                              "centers": d.centres.tolist() if d.found else None,
                              "reason": d.reason})
        if args.overlay is not None:
            img = read_image(Path(path)) if Path(path).exists() else None
            if img is not None:
                from circcal.detector.overlay import write_overlay

                write_overlay(Path(args.overlay) / (Path(path).stem + "_detect.png"), img, d)
    args.json_out.parent.mkdir(parents=True, exist_ok=True)
    args.json_out.write_text(json.dumps(out, indent=1))
    n = sum(d.found for d in dets)
    print(f"circcal detect: grid found in {n} of {len(dets)} images -> {args.json_out}")
    for path, d in zip(args.images, dets):
        if not d.found:
            print(f"  {path}: {d.reason}")
    return 0 if n == len(dets) else 1
