"""``circcal validate``: circcal against the reference calibrators and ground truth; exits 1 when a check fails or
nothing at all was compared, so users can gate their own CI on it. A run that compares results but has nothing to
gate (``--observations own``, ``--mode default``, own images without a reference) says so and why, naming the
options that would check something, and exits 0: nothing failed. The images circcal could not use are counted in the
verdict; ``--min-images`` fails the run below a count or share of them."""

from __future__ import annotations

import argparse
from pathlib import Path

from circcal.commands.args import (
    DIAMETER_HELP,
    LENS_CHOICES,
    add_board_file_argument,
    board_of_args,
    calibration_options,
    parse_grid,
    parse_length_mm,
    positive_float,
)
from circcal.errors import InputError
from circcal.imagefiles import expand_images
from circcal.validators.bounds import SOLVER_MRCAL_PX, SOLVER_PX, TRUTH_SIGMAS


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal validate`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = sub.add_parser(
        "validate",
        help="cross-validate circcal against mrcal, opencv, kornia, pycolmap and ground truth",
        description="Calibrate with circcal and with reference calibrators on the same images, compare every result "
        "with circcal and, for rendered fixtures, with the true camera. With no arguments: the `paper` "
        "scenario against every reference. Exit status 1 when a check fails or nothing was compared, 0 when "
        "every check passed or nothing is gated (the verdict says why), 2 on bad input. A reference that is not "
        "installed fails the run (each says how to install it); --allow-missing lists it as skipped instead.",
    )
    p.add_argument("scenario", nargs="?", help="fixture scenario (default: paper); see `circcal render --list`")
    p.add_argument("--variant", help="scenario variant (default: its first)")
    p.add_argument("--fixtures", type=Path, help="a rendered fixture folder (with truth.json)")
    p.add_argument("--images", nargs="+", type=Path, help="your own images (no ground truth)")
    p.add_argument("--grid", type=parse_grid, help="ROWSxCOLS points, with --images")
    p.add_argument("--pitch", type=parse_length_mm, help="grid pitch, e.g. 10mm, with --images")
    p.add_argument("--diameter", type=parse_length_mm, help=DIAMETER_HELP)
    p.add_argument("--asymmetric", action="store_true", help="asymmetric circle grid, with --images")
    add_board_file_argument(p)
    p.add_argument(
        "--against",
        action="append",
        default=None,
        help="reference(s): mrcal, opencv, kornia, pycolmap, a plug-in name, or all (repeatable or "
        "comma-separated; default all)",
    )
    p.add_argument(
        "--mode",
        choices=("fair", "default", "both"),
        default="both",
        help="fair = same estimator as OpenCV; default = what the reference's users get (default: both)",
    )
    p.add_argument(
        "--observations",
        choices=("circcal", "own"),
        default="circcal",
        help="circcal = every reference fits circcal's centres; own = each reference's own detector",
    )
    p.add_argument("--fix-k3", action="store_true", help="hold k3 at 0 in every calibrator that can")
    p.add_argument(
        "--lens",
        choices=tuple(LENS_CHOICES),
        default=None,
        help="lens model every calibrator fits: "
        + "; ".join(f"{k} ({v})" for k, v in LENS_CHOICES.items())
        + " (default: the fixture's true camera's, else opencv5); a reference without it is reported "
        "unsupported with the reason",
    )
    p.add_argument(
        "--solver-tol",
        type=positive_float,
        default=SOLVER_PX,
        help="max px projection difference to "
        f"circcal on identical observations (default {SOLVER_PX:g}; mrcal: {SOLVER_MRCAL_PX:g})",
    )
    p.add_argument(
        "--truth-sigmas",
        type=positive_float,
        default=TRUTH_SIGMAS,
        help="max |error| of circcal's fx, "
        f"fy, cx, cy vs the true camera, in its stated sigmas (default {TRUTH_SIGMAS:g})",
    )
    p.add_argument(
        "--truth-tol",
        type=positive_float,
        default=None,
        help="also bound circcal's RMS projection "
        "difference to the true camera (rotation fitted), px (default: not gated)",
    )
    p.add_argument(
        "--allow-missing",
        action="store_true",
        help="a reference that is not installed is listed as skipped instead of failing the run, so that a "
        "plain `pip install circcal` checks against what is installed (`make setup` installs every built-in one)",
    )
    p.add_argument(
        "--min-images",
        type=parse_min_images,
        default=DEFAULT_MIN_IMAGES,
        help="fail when fewer images than this gave circcal a view: a count (e.g. 4) or a share of the images "
        "given (e.g. 50%% or 0.5; default 50%%)",
    )
    p.add_argument("--report", type=Path, help="write validation.json and validation.md into this folder")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


#: ``--min-images`` when not given: half the images must give circcal a view.
DEFAULT_MIN_IMAGES = 0.5


def parse_min_images(text: str) -> int | float:
    """``--min-images``: a count (``4``) or a share (``50%``, ``0.5``).

    Parameters
    ----------
    text : str

    Returns
    -------
    int or float
        A count >= 1 (int) or a share in (0, 1] (float).

    Raises
    ------
    argparse.ArgumentTypeError
        Neither (the CLI prints it with the option's name and exits 2).
    """
    t = text.strip()
    try:
        if t.endswith("%"):
            share = float(t[:-1]) / 100.0
        elif t.isdigit():
            count = int(t)
            if count >= 1:
                return count
            share = float("nan")
        else:
            share = float(t)
    except ValueError:
        share = float("nan")
    if share > 0.0 and share <= 1.0:  # NaN fails both
        return share
    raise argparse.ArgumentTypeError(
        f"{text!r}: expected a count of images >= 1 (e.g. 4) or a share of them (e.g. 50% or 0.5)"
    )


def run(args: argparse.Namespace) -> int:
    """Check circcal against the reference calibrators and ground truth; print the verdicts.

    Parameters
    ----------
    args : argparse.Namespace
        The arguments :func:`add_parser`'s parser parsed.

    Returns
    -------
    int
        The exit status: 0 when every check passed or nothing is gated (the verdict says why); 1 when one failed
        or nothing was compared.

    Raises
    ------
    InputError
        A bad argument or input file (the CLI prints it and exits 2).
    """
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.scenarios import DEFAULT_SCENARIO, get_scenario
    from circcal.fixtures.truth import load_truth
    from circcal.outputs import Outputs
    from circcal.validators.validate import format_table, verdict, write_report

    options = calibration_options(args)  # --lens, --fix-k3 (its lens replaced by the truth's when --lens is not given)
    with Outputs(
        inputs=[*(args.images or []), *([args.fixtures] if args.fixtures else [])]
    ) as outputs:  # the report folder checked before the work
        report = None if not args.report else outputs.folder(args.report, "--report", kind="validation")
        against = [a.strip() for spec in (args.against or ["all"]) for a in spec.split(",") if a.strip()]
        truth_cam = None
        if args.images:
            args.images = expand_images(args.images, "--images")
            if args.scenario or args.fixtures:
                raise InputError("give a scenario, --fixtures or --images, not several")
            if args.board is None and (args.grid is None or args.pitch is None):
                raise InputError("--images needs --grid ROWSxCOLS and --pitch, or --board FILE")
            board = board_of_args(args, "validate")
            paths = sorted(args.images)
            source = {"images": [str(p) for p in paths]}
        else:
            if args.board is not None:
                raise InputError("--board describes the board of --images (a scenario or --fixtures brings its own)")
            if args.fixtures:
                folder = args.fixtures
                source = {"fixtures": str(folder)}
            else:
                sc = get_scenario(args.scenario or DEFAULT_SCENARIO)
                variant = args.variant or next(iter(sc.variants))
                folder = fixture_dir(sc.name, variant, progress=not args.no_progress)
                source = {"scenario": sc.name, "variant": variant, "version": sc.version}
            truth = load_truth(folder)
            board, truth_cam = truth.board, truth.camera
            paths = [v.image for v in truth.views]
        if args.lens is None and truth_cam is not None:
            options = options.replace(lens=truth_cam.lens)
        result = _run(args, options, paths, board, truth_cam, against, source)
        print(format_table(result))
        if report is not None:
            write_report(result, report)
        outputs.commit()
    if args.report:
        print(f"\nreport: {args.report}")
    lines, status = verdict(result)
    print("\n" + "\n".join(lines + missing_lines(result)))
    return status


def missing_lines(result) -> list[str]:
    """The verdict's lines on the references that are not installed: those that failed the run, with the two ways
    out (install them, or ``--allow-missing``), and those skipped under ``--allow-missing``.

    Parameters
    ----------
    result : ValidationRun
        The run (:func:`circcal.validators.validate.run_validation`).

    Returns
    -------
    list of str
        None, one or two lines, each starting with "- ".
    """
    suffix = " is available"
    failed = [c.name[: -len(suffix)] for c in result.checks if not c.passed and c.name.endswith(suffix)]
    skipped = [s.split(":", 1)[0] for s in result.skipped]  # "kornia [fair]: why; pip install ..."
    lines = []
    if failed:
        names = _names(failed)
        lines.append(
            f"- not installed: {names}: install {'them' if ', ' in names else 'it'} (the pip line is above; `make "
            "setup` installs every one), or add --allow-missing to check against the references that are installed"
        )
    if skipped:
        lines.append(f"- not installed, so not checked: {_names(skipped)} (each one's pip line is above)")
    return lines


def _names(labels: list[str]) -> str:
    """The references of labels such as ``lensboy [fair]``, each once, in order."""
    return ", ".join(dict.fromkeys(label.split(" [", 1)[0] for label in labels))


def _run(args: argparse.Namespace, options, paths, board, truth_cam, against, source):
    from circcal.validators.validate import Bounds, run_validation

    return run_validation(
        paths,
        board,
        options,
        truth=truth_cam,
        against=against,
        mode=args.mode,
        observations=args.observations,
        progress=not args.no_progress,
        bounds=Bounds(solver=args.solver_tol, truth_sigmas=args.truth_sigmas, truth=args.truth_tol),
        source=source,
        allow_missing=args.allow_missing,
        min_images=args.min_images,
    )
