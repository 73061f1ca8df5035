"""``circcal calibrate IMAGES... --grid RxC --pitch 10mm --out model.json``: detect, calibrate, re-correct, report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from circcal.commands.args import (
    DIAMETER_HELP,
    DISTANCE_HELP,
    add_board_file_argument,
    add_fix_arguments,
    add_lens_argument,
    board_of_args,
    calibration_options,
    grid_hint,
    nonnegative_int,
    parse_distance_mm,
    parse_grid,
    parse_length_mm,
    positive_float,
    positive_int,
)
from circcal.commands.board import add_marker_arguments
from circcal.imagefiles import expand_images, require_existing
from circcal.pathnames import display_name


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal calibrate`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = sub.add_parser(
        "calibrate",
        help="calibrate a camera from images of a circle grid",
        description="Detect the circle grid in every image, calibrate (Zhang + Levenberg-Marquardt over fx, fy, cx, "
        "cy, the lens model's distortion coefficients (--lens; default k1, k2, p1, p2, k3) and all "
        "poses), re-correct every centre under the current model and recalibrate until the centres "
        "settle. Writes model.json (or, by extension, OpenCV .yaml, "
        "mrcal .cameramodel, COLMAP cameras.txt, ROS camera_info .yaml).",
    )
    p.add_argument("images", nargs="+", type=Path, help="image files, or folders of them (sorted by name)")
    p.add_argument(
        "--grid",
        type=parse_grid,
        help="ROWSxCOLS points, e.g. 7x7 (asymmetric: 11x4); auto: found from the images (the line used is printed)",
    )
    p.add_argument(
        "--pitch",
        type=parse_length_mm,
        help="point spacing, e.g. 10mm (asymmetric: OpenCV's squareSize, half the in-row spacing)",
    )
    p.add_argument("--diameter", type=parse_length_mm, help=DIAMETER_HELP)
    p.add_argument("--asymmetric", action="store_true", help="asymmetric circle grid (OpenCV acircles layout)")
    add_marker_arguments(p)
    add_board_file_argument(p)
    add_lens_argument(p, auto=True)
    add_fix_arguments(p)
    p.add_argument(
        "--refine-board",
        action="store_true",
        help="also estimate the 3-D position of every board point (a printed board that is not flat or "
        "not printed to scale; like cv2.calibrateCameraRO); the shape goes into model.json",
    )
    p.add_argument(
        "--board-warp",
        action="store_true",
        help="also estimate mrcal's 2-parameter board warp (calobject_warp: a sag along the board's x and y, mm); "
        "every calibration checks it and recommends it where the board is not flat and the warped board predicts "
        "held-out views better; not with --refine-board",
    )
    p.add_argument("--out", type=Path, default=Path("model.json"), help="output model file (default model.json)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--jobs",
        type=positive_int,
        default=None,
        help="images detected at once (default: one per CPU, at most 8; results do not depend on it)",
    )
    g = p.add_argument_group("is it right? (outliers, uncertainty, cross-validation, report)")
    g.add_argument(
        "--no-outlier-rejection",
        action="store_true",
        help="fit every detected centre (default: leave out the detector's bad dots and every point "
        "whose residual exceeds --outlier-k sigma, re-solving until stable; each one is listed)",
    )
    g.add_argument(
        "--outlier-k",
        type=positive_float,
        default=None,
        help="outlier threshold in standard deviations (default 5, mrcal's)",
    )
    g.add_argument(
        "--cross-validate",
        dest="cross_validate",
        action="store_true",
        default=True,
        help="the default (kept for old command lines): also calibrate two disjoint halves of the views and weigh "
        "their difference against their combined uncertainty, predict every view from the others (needs 6 views) "
        "and, where they disagree, try a richer lens model, the refined board and leaving the disagreeing views out "
        "on the same halves, and print the command that makes them agree",
    )
    g.add_argument(
        "--no-cross-validate",
        dest="cross_validate",
        action="store_false",
        help="skip the cross-validation (faster; the verdict then cannot tell a model or data problem)",
    )
    g.add_argument(
        "--split",
        choices=("alternate", "random"),
        default="alternate",
        help="how the cross-validation halves the views (default: alternate; random: seeded by --seed)",
    )
    g.add_argument("--seed", type=nonnegative_int, default=0, help="seed of --split random (default 0)")
    g.add_argument(
        "--distance",
        type=parse_distance_mm,
        default=None,
        help="where uncertainty and cross-validation are evaluated: " + DISTANCE_HELP,
    )
    g.add_argument(
        "--report",
        type=Path,
        default=None,
        help="write a self-contained HTML + Markdown report of this calibration into this folder",
    )
    p.set_defaults(func=run)
    _keep_argv(p)


def _keep_argv(p: argparse.ArgumentParser) -> None:
    """Make ``p`` keep the words it parsed as ``argv`` in its namespace: the recommended command is built from the
    arguments exactly as given (:func:`recommended_command`)."""
    parse = p.parse_known_args

    def parse_known_args(args=None, namespace=None):
        ns, extras = parse(args, namespace)
        ns.argv = list(sys.argv[1:] if args is None else args)
        return ns, extras

    p.parse_known_args = parse_known_args  # type: ignore[method-assign]


def recommended_command(
    argv: list[str] | None, given: list[Path], images: list[Path], options: tuple[str, ...], drop: tuple[str, ...]
) -> str | None:
    """The ``circcal calibrate`` command line of the arguments given with one change (the remedy's).

    Parameters
    ----------
    argv : list of str or None
        The words after ``calibrate`` as given (None: not known).
    given : list of Path
        The image arguments as given (files, folders).
    images : list of Path
        The images they stand for, in order.
    options : tuple of str
        Options to set (``("--lens", "rational")``, ``("--refine-board",)``): an option given already is replaced.
    drop : tuple of str
        Names of views to leave out (as the calibration names them: the image's name or path); the images are then
        listed one by one.

    Returns
    -------
    str or None
        A shell-quoted command line; None without ``argv``.
    """
    import shlex

    if argv is None:
        return None
    words = list(argv)
    groups: list[list[str]] = []  # each option with its values: ("--board-warp", "--lens", "rational") is two
    for w in options:
        if w.startswith("--") or not groups:
            groups.append([w])
        else:
            groups[-1].append(w)
    for opt, *values in groups:
        i = 0
        while i < len(words):
            if words[i] == opt:
                del words[i : i + 1 + len(values)]
            elif words[i].startswith(opt + "="):
                del words[i]
            else:
                i += 1
        words += [opt, *values]
    if drop:
        left = list(given)
        kept = []
        for w in words:  # the image arguments go; the images kept are listed in their place
            if Path(w) in left:
                left.remove(Path(w))
            else:
                kept.append(w)
        names = set(drop)
        keep = [
            str(p) for p in images if str(p) not in names and p.name not in names and display_name(p.name) not in names
        ]
        words = keep + kept
    return "circcal calibrate " + shlex.join(words)


def format_summary(cal, *, worst: int = 3) -> str:
    """Human-readable summary of an :class:`circcal.pipeline.ImagesCalibration` (or a CalibrationResult).

    Parameters
    ----------
    cal : ImagesCalibration or CalibrationResult
    worst : int
        How many worst views to list.

    Returns
    -------
    str
    """
    import numpy as np

    res = getattr(cal, "result", cal)
    lines = []
    vals = res.camera.intrinsics
    lines.append(
        f"camera {res.camera.width}x{res.camera.height} ({res.camera.model.description}), "
        f"{len(res.rvecs)} views, "
        f"{res.errors['n_points']} points, {res.n_iterations} iterations"
        f"{'' if res.converged else ' (NOT converged)'}"
    )
    lines.append(f"  {'parameter':>9}  {'value':>14}  {'+- 1 sigma':>12}")
    for name, v in zip(res.camera.model.param_names, vals):
        s = res.std[name]
        note = "  (fixed)" if name in res.fixed else ""
        if name == "fx" and "aspect_ratio" in res.fixed:
            note = "  (= aspect * fy)"
        lines.append(f"  {name:>9}  {v:14.6f}  {s:12.6f}{note}")
    e = res.errors
    lines.append(
        f"reprojection error: RMS per point (OpenCV) {e['rms_per_point_px']:.4f} px, RMS per coordinate "
        f"(mrcal) {e['rms_per_coord_px']:.4f} px, mean 2-D (paper eq. 22) {e['mean_2d_px']:.4f} px, "
        f"max {e['max_2d_px']:.4f} px; noise estimate sigma {res.sigma_px:.4f} px"
    )
    order = sorted(range(len(res.per_view_errors)), key=lambda i: -res.per_view_errors[i]["rms_per_point_px"])
    names = (
        [display_name(n) for n in res.view_names]
        if res.view_names
        else [f"view {i}" for i in range(len(res.per_view_errors))]
    )
    lines.append("worst views (RMS per point):")
    for i in order[:worst]:
        pv = res.per_view_errors[i]
        lines.append(
            f"  {names[i]}: {pv['rms_per_point_px']:.4f} px (max {pv['max_2d_px']:.4f} px, {pv['n_points']} points)"
        )
    if res.board_points is not None:
        d = res.board_points - res.board_nominal
        sigma = np.median(res.board_std[res.board_std > 0])
        lines.append(
            f"board shape (refined, gauge points {list(res.board_gauge)} held): largest deviation from the "
            f"nominal board x {np.max(np.abs(d[:, 0])):.3f}, y {np.max(np.abs(d[:, 1])):.3f}, "
            f"z {np.max(np.abs(d[:, 2])):.3f} mm (typical 1-sigma {sigma:.3f} mm)"
        )
    rounds = getattr(cal, "rounds", None)
    if rounds:
        lines.append(
            "re-correction rounds: "
            + ", ".join(
                f"{r['round']}: RMS/pt {r['rms_per_point_px']:.4f} px"
                + ("" if r["round"] == 0 else f", centres moved <= {r['max_centre_shift_px']:.2g} px")
                for r in rounds
            )
        )
    choice = getattr(cal, "lens_choice", None)
    if choice is not None:
        lines += choice.lines()
    recovered = getattr(cal, "recovered", None)
    if recovered:
        lines.append(
            f"second detection pass with the first model: {len(recovered)} view(s) recovered: "
            + ", ".join(display_name(Path(p).name) for p in recovered)
        )
    lines += _detection_lines(cal)
    failed = getattr(cal, "failed", None)
    if failed:
        lines.append(f"{len(failed)} image(s) left out:")
        lines += [f"  {display_name(r.path)}: {r.reason}" for r in failed]
    return "\n".join(lines)


def _detection_lines(cal) -> list[str]:
    """What the detector says about the used views: partial views (points per view), dots it left out as bad (cut
    by the image border, occluded) per view, and what else the images show (another board, a larger grid)."""
    dets, used, paths = getattr(cal, "detections", None), getattr(cal, "used", None), getattr(cal, "paths", None)
    if dets is None or used is None or paths is None:
        return []
    lines = []
    partial = [(display_name(Path(paths[i]).name), int(dets[i].seen.sum())) for i in used if not dets[i].complete]
    if partial:
        lines.append(
            f"{len(partial)} partial view(s) used (board points seen): " + ", ".join(f"{n}: {k}" for n, k in partial)
        )
    dropped = [(display_name(Path(paths[i]).name), dets[i].n_dropped) for i in used if dets[i].dropped]
    if dropped:
        lines.append(
            f"dots left out by the detector as bad (cut by the image border or an occluder, a shadow's "
            f"edge): {sum(k for _, k in dropped)} in {len(dropped)} view(s): "
            + ", ".join(f"{n}: {k}" for n, k in dropped)
        )
    for i, d in enumerate(dets):
        for note in getattr(d, "notes", None) or []:
            lines.append(f"  {display_name(Path(paths[i]).name)}: {note}")
    return lines


#: ANSI colours of the verdict's level on a terminal (none where NO_COLOR is set or the output is not a terminal).
LEVEL_COLOURS = {"good": "\033[32m", "check": "\033[33m", "bad": "\033[31m"}


def _verdict_line(assessment, n_images: int) -> str:
    """The verdict in one line, as the report's headline says it (GOOD, CHECK or BAD and why), coloured on a
    terminal."""
    import os

    from circcal.calreport.document import headline

    h = headline(assessment, n_images)
    level = h["level"].upper()
    if sys.stdout.isatty() and not os.environ.get("NO_COLOR") and h["level"] in LEVEL_COLOURS:
        level = f"{LEVEL_COLOURS[h['level']]}{level}\033[0m"
    return f"verdict: {level}: {h['text']}"


def run(args: argparse.Namespace) -> int:
    """Detect, calibrate, re-correct and write the model (and the report) of the arguments.

    Parameters
    ----------
    args : argparse.Namespace
        The arguments :func:`add_parser`'s parser parsed.

    Returns
    -------
    int
        The exit status: 0; 1 when no model could be made (said on stderr).

    Raises
    ------
    InputError
        A bad argument or input file (the CLI prints it and exits 2).
    """
    from circcal.analysis.calibration import calibrate
    from circcal.errors import InputError
    from circcal.formats import detect_format, write_camera
    from circcal.outputs import Outputs
    from circcal.pipeline import LENS_CANDIDATES
    from circcal.solver import CalibrationError

    given = list(args.images)
    args.images = expand_images(args.images)  # a folder stands for its images, sorted
    options = calibration_options(args)  # the one options object: its errors come before any work
    board = board_of_args(args, "calibrate")
    with Outputs(
        inputs=[*args.images, *([args.board] if args.board is not None else [])]
    ) as outputs:  # every output checked before the work, committed together
        model_path = outputs.file(args.out, "--out")
        report_dir = None if args.report is None else outputs.folder(args.report, "--report", kind="report")
        fmt = detect_format(args.out)
        candidates = None
        if args.lens == "auto":  # mrcal's files hold no fisheye: not a candidate for a .cameramodel
            candidates = tuple(c for c in LENS_CANDIDATES if not (fmt == "mrcal" and c == "fisheye"))
        if fmt == "mrcal" and options.lens == "fisheye" and args.lens != "auto":
            from circcal.formats.mrcal import MRCAL_UNSUPPORTED

            raise InputError(
                f"--out {args.out}: {MRCAL_UNSUPPORTED['fisheye']}; write model.json, OpenCV .yaml, "
                f"COLMAP cameras.txt or ROS camera_info instead"
            )
        require_existing(args.images)  # the last check before the work: the others' words come first
        try:
            calibration = calibrate(
                args.images,
                board,
                options,
                cross_validate=args.cross_validate,
                distance=args.distance,
                split=args.split,
                seed=args.seed,
                lens_candidates=candidates,
                progress=not args.no_progress,
                jobs=args.jobs,
            )
        except CalibrationError as exc:
            # the images' own grid first: a --grid that is not the board's is the likelier cause than the lens
            flag = grid_hint(list(args.images), board)
            hint = (
                ""
                if args.lens == "auto" or flag
                else f" (fitted with --lens {args.lens}; a wide lens: try --lens auto)"
            )
            print(f"circcal calibrate: no model: {exc}{hint}", file=sys.stderr)
            if flag:
                print(f"circcal calibrate: {flag}", file=sys.stderr)
            return 1
        cal, assessment = calibration.images, calibration.assessment
        fix = assessment.remedy
        target = None if fix is None else fix.target()
        if target is not None:
            fix.command = recommended_command(
                getattr(args, "argv", None), given, list(args.images), target.options, target.drop
            )
        shape = assessment.board_shape
        if shape is not None and shape.changes and getattr(args, "argv", None) is not None:
            words = [w for w in args.argv if w not in shape.remove]  # the board model's flag, added or removed
            shape.command = recommended_command(words, given, list(args.images), shape.add, ())
        print(_verdict_line(assessment, len(args.images)))  # the verdict first, then the numbers
        print("\n".join(assessment.verdict() + assessment.next_lines()))
        print(format_summary(cal))
        print("\n".join(assessment.details()))
        model = cal.to_model_json(board)
        if fmt == "mrcal":
            from circcal import atomic
            from circcal.formats.cameramodel_export import cameramodel_text, result_views

            text, info = cameramodel_text(cal.result.camera, result_views(cal.result))
            atomic.write_text(model_path, text)
            how = (
                "with mrcal's optimisation inputs: mrcal-show-projection-uncertainty and mrcal-show-residuals "
                "work on it"
                if info["optimization_inputs"]
                else f"without optimisation inputs: {info['why']}"
            )
        else:
            write_camera(model_path, cal.result.camera, fmt, document=model)
            how = ""
        if report_dir is not None:
            from circcal.calreport import write_report

            write_report(assessment, report_dir)
        outputs.commit()
    print(f"wrote {display_name(args.out)} ({fmt}{', ' + how if how else ''})")
    if args.report is not None:
        print(
            f"wrote the report {display_name(args.report / 'report.html')} (one self-contained file; Markdown: index.md)"
        )
    return 0
