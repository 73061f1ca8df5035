"""``circcal diff A B``: the projection difference between two camera models in any format circcal reads, with the
implied transformation between their frames fitted as ``mrcal-show-projection-diff`` does, and, where both files
carry an uncertainty (a circcal model.json with its views' observations, or an mrcal ``.cameramodel`` with
optimisation inputs), the difference in units of their combined uncertainty.

A is the reference: a grid of A's pixels is unprojected with A and projected with B. The exit status is 1 when both
files carry an uncertainty and the models are NOT consistent within it (a script can gate on it), 0 when they are or
when there is no uncertainty to judge by, 2 on bad input."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from circcal.commands.args import DISTANCE_HELP, int_between, parse_distance_mm

#: --gridn's largest value, the grid's points across the image: 1000 (750,000 points at 4:3) keeps the projections
#: and the uncertainty's per-point work arrays under ~1 GB; 100,000 asked for 41.9 GiB.
MAX_GRIDN = 1000


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal diff`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = sub.add_parser(
        "diff",
        help="projection difference between two camera models (implied transformation fitted)",
        description="Unproject a grid of pixels of model A, fit the transformation implied between the two models' "
        "frames over a focus region (a rotation at infinity; rotation and translation at a finite "
        "distance), project with model B and measure the 2-D difference: RMS, p95, max and at the "
        "centre. Where both models carry an uncertainty (a model.json written by `circcal calibrate`, "
        "or an mrcal .cameramodel with optimisation inputs), also the difference in units of their "
        "combined uncertainty (sigma A + sigma B; consistent when within 2x over 95% of the image). Exit "
        "status: 0 consistent, or no uncertainty to judge by; 1 NOT consistent; 2 bad input.",
    )
    p.add_argument("a", type=Path, help="model A, the reference (any format circcal reads)")
    p.add_argument("b", type=Path, help="model B, compared with A")
    p.add_argument("--distance", type=parse_distance_mm, default=None, help=DISTANCE_HELP)
    p.add_argument(
        "--radius",
        type=float,
        default=None,
        help="fit the implied transformation over the pixels within this radius of the image centre "
        "(px; default: the whole image; 0: no fit)",
    )
    p.add_argument(
        "--gridn", type=int_between(2, MAX_GRIDN), default=None, help="grid pixels across the image (default 60)"
    )
    p.add_argument("--heatmap", type=Path, default=None, help="write the difference heatmap here (PNG)")
    p.add_argument("--json", type=Path, default=None, dest="json_out", help="write the numbers here (JSON)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print (and write) the projection difference of the two camera files.

    Parameters
    ----------
    args : argparse.Namespace
        The arguments :func:`add_parser`'s parser parsed.

    Returns
    -------
    int
        The exit status: 1 when both models carry an uncertainty and are NOT consistent within it, else 0.

    Raises
    ------
    ModelFileError
        A file that cannot be read.
    InputError
        Models of different image sizes, or a bad option.
    """
    from circcal.errors import InputError
    from circcal.outputs import Outputs

    if args.radius is not None and not (args.radius >= 0 and math.isfinite(args.radius)):
        raise InputError(f"--radius must be a finite number >= 0 px, got {args.radius}")
    with Outputs(inputs=[args.a, args.b]) as outputs:
        heatmap = None if args.heatmap is None else outputs.file(args.heatmap, "--heatmap")
        json_out = None if args.json_out is None else outputs.file(args.json_out, "--json")
        code = _diff(args, heatmap, json_out)
        outputs.commit()
    for given in (args.heatmap, args.json_out):
        if given is not None:
            print(f"wrote {given}")
    return code


def _diff(args: argparse.Namespace, heatmap, json_out) -> int:
    """The comparison, written to the staged ``heatmap`` and ``json_out`` where given; the exit status (1: NOT
    consistent)."""
    from circcal import atomic
    from circcal.analysis.compare import GRID_WIDTH
    from circcal.analysis.diff import CONSISTENT_RATIO, CONSISTENT_SHARE, model_diff
    from circcal.analysis.sources import load_model
    from circcal.errors import InputError
    from circcal.jsonio import dumps

    a, b = load_model(args.a), load_model(args.b)
    ca, cb = a.camera, b.camera
    if (ca.width, ca.height) != (cb.width, cb.height):
        raise InputError(
            f"{args.a} is {ca.width}x{ca.height} but {args.b} is {cb.width}x{cb.height}: a projection "
            f"difference compares two models of one imager"
        )
    both = a.uncertainty is not None and b.uncertainty is not None
    d = model_diff(
        ca,
        cb,
        distance=args.distance,
        focus_radius_px=args.radius,
        gridn_width=args.gridn or GRID_WIDTH,
        uncertainty_a=(lambda uv: a.uncertainty(uv, args.distance)) if both else None,
        uncertainty_b=(lambda uv: b.uncertainty(uv, args.distance)) if both else None,
    )
    at = "at infinity" if args.distance is None else f"at {args.distance:g} mm"
    fit = (
        "over the whole image"
        if args.radius is None
        else ("not fitted" if args.radius == 0 else f"within {args.radius:g} px of the centre")
    )
    s = d.summary()
    print(
        f"A {args.a} (reference), B {args.b}: {ca.width}x{ca.height}, {d.diff.size} grid pixels of A {at}, "
        f"implied transformation fitted {fit} (rotation {s['implied_rotation_deg']:.4f} deg)"
    )
    print(
        f"  difference: RMS {d.rms_px:.4g} px, p95 {d.p95_px:.4g} px, max {d.max_px:.4g} px, at the centre "
        f"{d.centre_px:.4g} px" + (f" ({d.n_invalid} pixels beyond a lens's fold left out)" if d.n_invalid else "")
    )
    for m, name in ((a, "A"), (b, "B")):
        print(f"  uncertainty of {name}: " + (m.note if m.uncertainty is not None else f"none ({m.note})"))
    if both:
        print(
            f"  in units of the combined uncertainty (sigma A + sigma B): median {s['ratio_median']:.3g}, max "
            f"{s['ratio_max']:.3g}; within {CONSISTENT_RATIO:g}x over {100 * d.share_within:.1f}% of the image: "
            + (
                "consistent"
                if d.consistent
                else f"NOT consistent (< {100 * CONSISTENT_SHARE:g}%), exceeded in the "
                + ", ".join(f"{r} ({100 * x:.0f}%)" for r, x in d.where[:4])
            )
        )
    if args.heatmap is not None:
        from circcal.calreport.figures import fig_diff, save_png

        save_png(fig_diff(d, ca.width, ca.height, f"A {args.a.name} vs B {args.b.name}"), heatmap)
    if args.json_out is not None:
        doc = {
            "a": str(args.a),
            "b": str(args.b),
            "image_size": [ca.width, ca.height],
            "uncertainty_a": a.note if a.uncertainty is not None else None,
            "uncertainty_b": b.note if b.uncertainty is not None else None,
            **s,
        }
        atomic.write_text(json_out, dumps(doc, indent=2) + "\n")
    return 1 if d.consistent is False else 0
