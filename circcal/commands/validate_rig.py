"""``circcal validate-rig``: circcal's rig calibration of a rendered rig scenario against OpenCV's stereoCalibrate /
calibrateMultiview, mrcal's N-camera solve and the truth (:mod:`circcal.validators.rig_validate`); exits 1 when a
gated check fails, so it can gate CI."""

from __future__ import annotations

import argparse

from circcal.errors import InputError

#: ``--against`` names (kept here so ``--help`` does not import the validators).
AGAINST = ("opencv-stereo", "opencv-multiview", "mrcal")


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal validate-rig`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = sub.add_parser(
        "validate-rig",
        help="cross-validate circcal's rig solve against OpenCV, mrcal and the truth of a rig scenario",
        description="Calibrate a rendered rig scenario with circcal and compare the rig (rotation deg, position mm, "
        "projection px per camera) with OpenCV's stereoCalibrate (fix-intrinsic, intrinsic-guess), "
        "calibrateMultiview and mrcal, in fair mode (circcal's observations, compared with circcal's solve on "
        "exactly the reference's inputs: gated) and default mode (the reference's own start: printed), and "
        "circcal's rig with the truth in its stated sigmas. Exit status 1 when a gated check fails.",
    )
    p.add_argument("--scenario", required=True, help="rig scenario: two, chain or fisheye")
    p.add_argument(
        "--variant",
        help="variant (default noise): noise, low-noise, very-noisy, flip (observations), rendered, rendered-noise, "
        "rendered-blur, rendered-uneven, rendered-clutter (images through the detector)",
    )
    p.add_argument(
        "--against",
        action="append",
        default=None,
        help=f"reference(s): {', '.join(AGAINST)} or all (repeatable or comma-separated; default all)",
    )
    p.add_argument(
        "--mode", choices=("fair", "default", "both"), default="both", help="which modes to run (default both)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the observations' noise (default 0)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the rig validation and print its table.

    Parameters
    ----------
    args : argparse.Namespace
        The arguments :func:`add_parser`'s parser parsed.

    Returns
    -------
    int
        0 when every gated check passed, 1 otherwise.

    Raises
    ------
    InputError
        An unknown scenario, variant or reference (the CLI prints it and exits 2).
    """
    from circcal.validators.rig_validate import format_rig_table, run_rig_validation

    against: list[str] = []
    for spec in args.against or ["all"]:
        for a in (x.strip() for x in spec.split(",")):
            if a == "all":
                against += [x for x in AGAINST if x not in against]
            elif a in AGAINST:
                against += [a] if a not in against else []
            elif a:
                raise InputError(f"--against {a!r}: expected one of {', '.join(AGAINST)} or all")
    modes = ("fair", "default") if args.mode == "both" else (args.mode,)
    result = run_rig_validation(args.scenario, args.variant, against, modes, seed=args.seed)
    print(format_rig_table(result))
    if result.failures:
        print("\nverdict: failed")
        return 1
    print("\nverdict: passed")
    return 0
