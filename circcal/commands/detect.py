"""``circcal detect IMAGES... --grid RxC [--asymmetric] [--model MODEL] --json OUT [--overlay DIR]``.

Writes ``{"board": board.to_dict(), "complete": bool, "images": [{"image": path, "found": bool,
"centers": [[x, y] | null, ...] | null, "reason": null | "why not", "reason_code": null | code, "complete": bool,
"points_seen": n, "dots_dropped": {index: why}, "notes": [...]}]}``, images in the order given: a point not seen
(out of frame, occluded, a dot left out as bad) has a null centre; ``--markers`` labels partial views. The JSON file and the overlay folder are written together at the end
(:mod:`circcal.outputs`): an interruption or a failure leaves earlier ones as they were; the results done by then
are kept in ``NAME.partial-K.json`` beside it (``"complete": false``; images still missing are left out). ``--grid RxC``: R rows by C columns of *points* (OpenCV patternSize (C, R)). ``--model``: a
camera in any format circcal reads (model.json, OpenCV YAML, mrcal, COLMAP, ROS) for the distortion-aware centre
correction. A failed image never stops the others and always says why.

Detection needs the board's shape, not its scale: without ``--pitch`` (and without ``--board``) the board's lengths
in the JSON (``pitch_mm``, ``diameter_mm``, ``margin_mm``, and ``marker_diameter_mm`` of a marker board) are
``null``, not a made-up number; ``--diameter`` and ``--marker-diameter`` need ``--pitch``, since the detector uses
the dots' size relative to their spacing. The help a user reads is :data:`DESCRIPTION`.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import Counter
from pathlib import Path

from circcal.commands.args import (
    DIAMETER_HELP,
    add_board_file_argument,
    board_of_args,
    grid_hint,
    parse_grid,
    parse_length_mm,
    positive_int,
)
from circcal.commands.board import add_marker_arguments
from circcal.errors import InputError
from circcal.imagefiles import expand_images, require_existing

#: The scale the detector works in when ``--grid`` comes without ``--pitch`` (mm): detection needs the board's shape,
#: not its scale, and this number is not written (detections.json says ``pitch_mm: null``).
DEFAULT_PITCH_MM = 10.0
#: The staged detections.json is rewritten at most this often (s): what an interruption keeps as partial results.
SAVE_EVERY_S = 2.0


#: ``circcal detect --help``'s description: what the command does and writes, for a user.
DESCRIPTION = """\
Find the circle grid in every image and write the centre of each dot as it projects into the image (corrected for
the bias of a blob's centroid under perspective, and for the lens's distortion with --model) to one JSON file.

The JSON lists the images in the order given: for each, whether the grid was found (and if not, why, with a reason
code), the centres in pixels in OpenCV's point order (null for a dot not seen: out of frame, occluded or left out as
bad), and whether the view shows the whole board. --overlay writes a PNG per image to check by eye. The outputs are
written together at the end; an interrupted run keeps what it did in NAME.partial-K.json beside the output.

Detection needs the board's shape, not its size: --pitch is optional here (the JSON then says pitch_mm: null), but
--diameter and --marker-diameter need it (the detector uses the dots' size relative to their spacing).
Exit status: 0 the grid was found in every image; 1 not in some; 2 bad input."""

#: ``circcal detect --help``'s examples.
EXAMPLES = """\
examples:
  circcal detect photos/ --grid 7x7 --json detections.json
  circcal detect photos/*.jpg --grid 11x4 --asymmetric --overlay overlays --json detections.json
  circcal detect photos/ --board board.yaml --model model.json --json detections.json"""


def add_parser(subparsers) -> None:
    """Add the ``circcal detect`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = subparsers.add_parser(
        "detect",
        help="find circle grids and write unbiased centre projections as JSON",
        description=DESCRIPTION,
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("images", nargs="+", type=Path, help="image files, or folders of them (sorted by name)")
    p.add_argument(
        "--grid", type=parse_grid, help="RxC: R rows by C columns of points; auto: found from the images (or --board)"
    )
    p.add_argument("--asymmetric", action="store_true", help="OpenCV asymmetric (acircles) layout")
    p.add_argument(
        "--pitch",
        type=parse_length_mm,
        default=None,
        help="point spacing, e.g. 10mm (OpenCV's squareSize); optional: detection needs the board's shape, not its "
        "size (the JSON then says pitch_mm: null); needed with --diameter",
    )
    p.add_argument("--diameter", type=parse_length_mm, default=None, help=DIAMETER_HELP)
    add_marker_arguments(p)
    add_board_file_argument(p)
    p.add_argument(
        "--model",
        type=Path,
        default=None,
        help="camera model (any format circcal reads) for the distortion-aware centre correction",
    )
    p.add_argument("--json", required=True, type=Path, dest="json_out", help="output JSON file")
    p.add_argument("--overlay", type=Path, default=None, help="folder for PNG overlays to check by eye")
    p.add_argument(
        "--quiet",
        "--no-progress",
        dest="quiet",
        action="store_true",
        help="no progress bar (--no-progress, as the other commands spell it)",
    )
    p.add_argument(
        "--jobs",
        type=positive_int,
        default=None,
        help="images detected at once (default: one per CPU, at most 8; results do not depend on it)",
    )
    p.set_defaults(func=run)


def _entry(path: Path, d) -> dict:
    """One image's record: centres (null for a point not seen: out of frame, occluded, or dropped), whether the
    view shows the whole board (``complete``), the dots left out as bad (``dots_dropped``: index -> reason) and
    what else the image shows (``notes``)."""
    from circcal.pathnames import path_to_json

    return {
        "image": path_to_json(path),
        "found": bool(d.found),
        "centers": d.centres.tolist() if d.found else None,
        "reason": d.reason,
        "reason_code": None if d.code is None else d.code.value,
        "complete": bool(d.complete) if d.found else None,
        "points_seen": int(d.seen.sum()) if d.found else 0,
        "dots_dropped": {str(k): r for k, r in d.dropped.items()},
        "notes": list(d.notes),
    }


def run(args: argparse.Namespace) -> int:
    """Detect the grid in every image; write the detections JSON (and the overlays).

    Parameters
    ----------
    args : argparse.Namespace
        The arguments :func:`add_parser`'s parser parsed.

    Returns
    -------
    int
        The exit status: 0 when the grid was found in every image, else 1.

    Raises
    ------
    InputError
        A bad argument or input file (the CLI prints it and exits 2).
    """
    from circcal import atomic
    from circcal.detector import detect_files
    from circcal.detector.overlay import overlay_file
    from circcal.formats import read_camera
    from circcal.jsonio import dumps
    from circcal.outputs import Outputs
    from circcal.pathnames import display_name

    scaled = args.board is not None or args.pitch is not None  # the board's lengths known, not only its shape
    if not scaled:
        relative = [o for o, v in (("--diameter", args.diameter), ("--marker-diameter", args.marker_diameter)) if v]
        if relative:
            raise InputError(
                f"{relative[0]} needs --pitch: the detector uses the dots' size relative to their spacing (e.g. "
                f"--pitch 10mm {relative[0]} 5mm), or give neither"
            )
    args.images = expand_images(args.images)  # a folder stands for its images, sorted
    board = board_of_args(args, "detect", default_pitch_mm=DEFAULT_PITCH_MM)
    board_doc = board.to_dict() if scaled else _shape_only(board)
    inputs = list(args.images) + ([args.model] if args.model is not None else [])
    inputs += [args.board] if args.board is not None else []
    with Outputs(inputs=inputs) as outputs:  # checked before the work, committed together at the end
        json_path = outputs.file(args.json_out, "--json")
        overlay_dir = None if args.overlay is None else outputs.folder(args.overlay, "--overlay", kind="overlays")
        camera = read_camera(args.model) if args.model is not None else None
        require_existing(args.images)  # a mistyped path: one line, not "grid found in 0 of 1 images"
        entries: dict[int, dict] = {}
        stems = Counter(Path(p).stem for p in args.images)
        shared_stems = {k for k, n in stems.items() if n > 1}  # counted once, not per image
        last_save = [time.monotonic()]

        def save(complete: bool) -> None:
            doc = {"board": board_doc, "complete": complete, "images": [entries[i] for i in sorted(entries)]}
            atomic.write_text(json_path, dumps(doc, indent=1) + "\n")
            last_save[0] = time.monotonic()

        def on_result(i: int, d) -> None:
            path = Path(args.images[i])
            entries[i] = _entry(path, d)
            if overlay_dir is not None:
                vis = overlay_file(path, d)
                if vis is not None:
                    import cv2

                    ok, png = cv2.imencode(".png", vis)
                    if ok:
                        atomic.write_bytes(overlay_dir / _overlay_name(path, i, shared_stems), png.tobytes())
            if time.monotonic() - last_save[0] >= SAVE_EVERY_S:
                save(complete=False)

        try:
            dets = detect_files(
                list(args.images), board, camera, progress=not args.quiet, jobs=args.jobs, on_result=on_result
            )
        except BaseException:
            if entries:  # keep what is done, beside the earlier output, which stays as it was
                save(complete=False)
                kept = outputs.keep_partial(json_path)
                print(
                    f"circcal detect: {len(entries)} of {len(args.images)} images done; kept in "
                    f"{display_name(kept)} ({display_name(args.json_out)} left as it was)",
                    file=sys.stderr,
                )
            raise
        save(complete=True)
        outputs.commit()
    n = sum(d.found for d in dets)
    print(f"circcal detect: grid found in {n} of {len(dets)} images -> {display_name(args.json_out)}")
    for path, d in zip(args.images, dets):
        name = display_name(path)
        if not d.found:
            print(f"  {name}: {d.reason}")
        elif not d.complete or d.dropped:
            print(
                f"  {name}: {int(d.seen.sum())} of {board.n_points} points"
                + ("" if d.complete else " (partial view)")
                + (f", {d.n_dropped} dot(s) left out as bad" if d.dropped else "")
            )
        for note in d.notes:
            print(f"  {name}: {note}")
    if n == 0 and (hint := grid_hint(list(args.images), board)):
        print(f"circcal detect: {hint}")
    return 0 if n == len(dets) else 1


def _shape_only(board) -> dict:
    """``board.to_dict()`` with the lengths a ``--grid`` without ``--pitch`` did not give set to None: the pitch, and
    the diameter, margin and marker diameter that follow from it (the markers' places and the layout stay)."""
    doc = board.to_dict()
    doc.update(pitch_mm=None, diameter_mm=None, margin_mm=None)
    if board.has_markers:
        doc["marker_diameter_mm"] = None
    return doc


def _overlay_name(path: Path, i: int, shared: set[str]) -> str:
    """The overlay's file name: the image's stem, numbered where inputs share it (``shared``: a/x.png, b/x.png)."""
    safe = os.fsdecode(os.fsencode(path.stem).replace(b"/", b"_"))
    return f"{safe}_{i:04d}_detect.png" if path.stem in shared else f"{safe}_detect.png"
