"""``circcal calibrate-rig --camera left=L/ --camera right='R/*.png' --grid RxC --pitch P --out rig.json``: a rig of
2..N cameras calibrated in one joint solve (:func:`circcal.rig.calibrate_rig`), its verdict
(:mod:`circcal.rig.verdict`) and its files (:mod:`circcal.rig.files`)."""

from __future__ import annotations

import argparse
import glob
import math
import re
from dataclasses import replace
from pathlib import Path

from circcal.commands.args import (
    DIAMETER_HELP,
    LENS_CHOICES,
    add_board_file_argument,
    add_fix_arguments,
    board_of_args,
    calibration_options,
    fix_holds,
    grid_hint,
    parse_grid,
    parse_length_mm,
    positive_int,
)
from circcal.commands.board import add_marker_arguments
from circcal.errors import InputError
from circcal.imagefiles import IMAGE_SUFFIXES, expand_images
from circcal.observations import MIN_VIEWS
from circcal.pathnames import display_name

#: A camera's name: it names files in --ros and --cameramodels folders (64 characters at most: with a suffix and
#: the staging file's affixes it stays well inside a file system's 255-byte names).
CAMERA_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}")
#: --out by extension.
OUT_FORMATS = {".json": "json", ".yaml": "opencv", ".yml": "opencv"}


def _camera(text: str) -> tuple[str, str]:
    """``NAME=IMAGES`` -> (name, images) (an argparse type)."""
    name, eq, images = str(text).partition("=")
    if not eq or not images:
        raise argparse.ArgumentTypeError(
            f"expected NAME=IMAGES (a folder or a quoted glob, e.g. left=shots/left or 'right=shots/right/*.png'), "
            f"got {text!r}"
        )
    if not CAMERA_NAME.fullmatch(name):
        raise argparse.ArgumentTypeError(
            f"camera name {display_name(name[:80]) + ('...' if len(name) > 80 else '')!r} must be 1-64 letters, "
            f"digits, '_', '.', '+' or '-' (it names files), starting with a letter or digit"
        )
    return name, images


def _lens(text: str) -> tuple[str | None, str]:
    """``[NAME=]MODEL`` -> (name or None, model) (an argparse type)."""
    name, eq, model = str(text).rpartition("=")
    if model not in LENS_CHOICES:
        raise argparse.ArgumentTypeError(
            f"unknown lens model {model!r} in {text!r}; expected [NAME=]MODEL with MODEL one of "
            f"{', '.join(LENS_CHOICES)}"
        )
    if eq and not name:
        raise argparse.ArgumentTypeError(f"expected NAME=MODEL or MODEL, got {text!r}")
    return (name or None), model


def _intrinsics(text: str) -> tuple[str, str]:
    """``NAME=MODEL_FILE`` -> (name, file) (an argparse type)."""
    name, eq, path = str(text).partition("=")
    if not eq or not name or not path:
        raise argparse.ArgumentTypeError(f"expected NAME=MODEL_FILE (e.g. left=left.yaml), got {text!r}")
    return name, path


def _alpha(text: str) -> float:
    """OpenCV's free scaling: negative (its default) or within [0, 1] (an argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value) or value > 1.0:
        raise argparse.ArgumentTypeError(f"must be negative (OpenCV's default) or within 0..1, got {text!r}")
    return value


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal calibrate-rig`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = sub.add_parser(
        "calibrate-rig",
        help="calibrate a rig of 2..N cameras seeing one circle grid (stereo included)",
        description="Calibrate every camera (detection, calibration, centre re-correction), then solve every "
        "camera's intrinsics, every camera's pose in the rig (the first --camera is the reference: X_cam = R X_ref "
        "+ T, mm) and one board pose per instant jointly, re-correcting the centres under the joint model until "
        "they settle. Images of different cameras are matched by file name: the same name is the same instant "
        "(where no name is shared, the same name between each camera's own prefix and suffix: left01.png and "
        "right01.png, 0001_cam0.png and 0001_cam1.png, 0001/left.png and 0001/right.png); "
        "an instant seen by some cameras only, or partly, is used. Then the verdict: two halves of the instants "
        "calibrated apart and compared against their stated uncertainty, outlier views per camera, coverage.",
    )
    p.add_argument(
        "--camera",
        action="append",
        type=_camera,
        required=True,
        metavar="NAME=IMAGES",
        help="a camera and its images: a folder (its images, sorted) or a glob in quotes ('left/*.png'); give one "
        "--camera per camera, the reference first",
    )
    p.add_argument(
        "--grid", type=parse_grid, help="ROWSxCOLS points, e.g. 8x11 (asymmetric: 11x4), or auto: found in the images"
    )
    p.add_argument("--pitch", type=parse_length_mm, help="point spacing, e.g. 15mm (the unit of T)")
    p.add_argument("--diameter", type=parse_length_mm, help=DIAMETER_HELP)
    p.add_argument("--asymmetric", action="store_true", help="asymmetric circle grid (OpenCV acircles layout)")
    add_marker_arguments(p)
    add_board_file_argument(p)
    p.add_argument(
        "--lens",
        action="append",
        type=_lens,
        default=[],
        metavar="[NAME=]MODEL",
        help="lens model of camera NAME, or of every camera not named: "
        + "; ".join(f"{k} ({v})" for k, v in LENS_CHOICES.items())
        + " (default opencv5)",
    )
    add_fix_arguments(p, per_camera=True)
    p.add_argument(
        "--intrinsics",
        action="append",
        type=_intrinsics,
        default=[],
        metavar="NAME=MODEL_FILE",
        help="camera NAME's intrinsics from a model file (any format convert reads; its lens model is the camera's), "
        "held: only the poses are solved for it, as OpenCV's CALIB_FIX_INTRINSIC",
    )
    p.add_argument(
        "--out",
        type=Path,
        required=True,
        help="rig.json (circcal's rig model: every camera, its pose, the instants used, the covariance) or rig.yaml "
        "(OpenCV's stereo file of the first two cameras: M1 D1 M2 D2 R T E F R1 R2 P1 P2 Q, X_2 = R X_1 + T, T in "
        "the pitch's unit)",
    )
    p.add_argument("--ros", type=Path, help="folder: a ROS camera_info YAML pair of the first two cameras (metres)")
    p.add_argument("--cameramodels", type=Path, help="folder: one mrcal .cameramodel per camera, with extrinsics")
    p.add_argument(
        "--kalibr",
        type=Path,
        help="Kalibr camchain YAML (an opencv5 camera needs its k3 held, --fix-k3 NAME; or a fisheye)",
    )
    p.add_argument(
        "--rectified",
        type=Path,
        help="folder: the rectified pair of each instant the first two cameras share (their views used)",
    )
    p.add_argument("--alpha", type=_alpha, default=-1.0, help="rectification free scaling (OpenCV's alpha; default -1)")
    p.add_argument(
        "--report",
        type=Path,
        help="folder: a self-contained HTML + Markdown report (verdict, per-camera numbers, the rig in 3-D, a "
        "rectified pair)",
    )
    p.add_argument(
        "--no-cross-validate",
        dest="cross_validate",
        action="store_false",
        help="skip the cross-validation on two halves of the instants (done by default with >= 6 instants)",
    )
    p.add_argument("--jobs", type=positive_int, default=None, help="images detected at once (default: one per CPU)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _images_of(name: str, spec: str) -> list[Path]:
    """A camera's image files: a folder's images, or a glob's files, sorted; InputError naming --camera."""
    option = f"--camera {name}={spec}"
    path = Path(spec)
    if path.is_dir():  # the summary says how many were found
        found = expand_images([path], option, announce=False)
    elif glob.has_magic(spec):
        files = sorted(Path(f) for f in glob.glob(spec) if Path(f).is_file())
        if not files:
            raise InputError(f"{option}: the pattern matches no file")
        # as a folder's: the image files only (a README or a .json beside the images is not an unreadable image)
        found = [f for f in files if f.suffix.lower() in IMAGE_SUFFIXES]
        if not found:
            raise InputError(
                f"{option}: the pattern matches {len(files)} file(s), none an image ({', '.join(sorted(IMAGE_SUFFIXES))})"
            )
    elif path.is_file():
        if path.suffix.lower() not in IMAGE_SUFFIXES:
            raise InputError(f"{option}: a file that is not an image; give a folder of images or a glob in quotes")
        found = [path]
    else:
        raise InputError(f"{option}: no such folder or file (give a folder, or a glob in quotes such as 'left/*.png')")
    return found


def _size(path: Path) -> int:
    """A file's size in bytes; 0 where it cannot be read (the detector reports it)."""
    try:
        return path.stat().st_size
    except OSError:
        return 0


def _refuse_copies(images: dict[str, list[Path]]) -> None:
    """Refuse images of one camera whose bytes are another camera's (a folder copied for the second camera): two
    cameras never record the same bytes, and the rig would be a camera at one point with itself."""
    from circcal.pipeline import duplicates_of

    # an empty file is no image (the detector says so), not a copy of another camera's
    flat = [(name, f) for name, paths in images.items() for f in paths if _size(f) > 0]
    cross = [(j, i) for i, (j, _) in duplicates_of([str(f) for _, f in flat]).items() if flat[i][0] != flat[j][0]]
    if cross:
        (a, fa), (b, fb) = flat[cross[0][0]], flat[cross[0][1]]
        n = sum(1 for j, i in cross if (flat[j][0], flat[i][0]) == (a, b))
        raise InputError(
            f"--camera {b}: {display_name(fb)} holds the bytes of camera {a}'s {display_name(fa)} ({n} such "
            f"image(s)): each camera's images are its own (a folder copied for the other camera?)"
        )


def _cameras(args: argparse.Namespace) -> dict[str, list[Path]]:
    """Every --camera's images, checked: two cameras at least, names distinct, no file given to two cameras, images
    named once per camera, every camera linked to the reference by shared instants (:mod:`circcal.rig.instants`: the
    file names, or the names between each camera's prefix and suffix, said in a line)."""
    from circcal.rig.instants import rig_instants, unlinked

    images: dict[str, list[Path]] = {}
    for name, spec in args.camera:
        if name in images:
            raise InputError(f"--camera {name}: camera {name!r} given twice; give each camera once")
        images[name] = _images_of(name, spec)
    if len(images) < 2:
        raise InputError(f"--camera: a rig needs at least two cameras, got {len(images)}")
    found = rig_instants(images, lambda n: f"--camera {n}")  # refuses two images of one instant
    instants = {name: set(per.values()) for name, per in found.of.items()}
    owner: dict[Path, str] = {}
    for name, paths in images.items():
        for f in paths:
            other = owner.setdefault(f.resolve(), name)
            if other != name:
                raise InputError(
                    f"--camera {name}: {display_name(f)} is also given to camera {other!r}; each camera's "
                    f"images are its own (the same folder given twice?)"
                )
    _refuse_copies(images)
    alone = unlinked(instants)
    held = {n for n, _ in args.intrinsics}  # a held camera needs one view another camera shares
    few = next((n for n, paths in images.items() if len(paths) < MIN_VIEWS and n not in held), None)
    if few is not None and not alone:
        raise InputError(
            f"--camera {few}: {len(images[few])} image(s); a camera's calibration needs at least {MIN_VIEWS} views "
            f"(or hold its intrinsics, calibrated on more views, with --intrinsics {few}=MODEL_FILE: then one view "
            f"another camera shares is enough)"
        )
    if alone:
        raise InputError(
            f"--camera {alone[0]}: its images share no file name with the reference {next(iter(images))!r} or a "
            f"camera linked to it; the same file name names the same instant in every camera (or the same name "
            f"between each camera's own prefix and suffix: left01.png, right01.png)"
        )
    if found.by_affix:
        ref = next(iter(images))
        first = images[ref][0]
        print(
            "instants: no file name is shared, so each camera's own prefix and suffix are left out of its names ("
            + ", ".join(f"{n}: {display_name(p + '*' + s)!r}" for n, (p, s) in found.affixes.items())
            + f"; {display_name(found.names[ref][0])} is instant {display_name(found.of[ref][str(first)])!r})"
        )
    return images


def _options(args: argparse.Namespace, names: list[str]) -> dict:
    """One CalibrationOptions per camera: its --lens (or the one for all), the --fix-* flags it is held by
    (:func:`fix_holds`, whose notes are printed)."""
    lens_of: dict[str | None, str] = {}
    for name, model in args.lens:
        if name is not None and name not in names:
            raise InputError(f"--lens {name}={model}: no camera {name!r} (cameras: {', '.join(names)})")
        if name in lens_of:
            raise InputError(f"--lens {name or model}: given twice" + (f" for camera {name!r}" if name else ""))
        lens_of[name] = model
    lenses = {name: lens_of.get(name, lens_of.get(None, "opencv5")) for name in names}
    holds, notes = fix_holds(args, lenses)
    out = {}
    for name in names:
        lens = lenses[name]
        try:
            out[name] = calibration_options(argparse.Namespace(**{**vars(args), "lens": lens, **holds[name]}))
        except InputError as exc:
            raise InputError(f"camera {name!r} (lens {lens}): {exc}") from None
    for line in notes:
        print(f"circcal calibrate-rig: {line}")
    return out


def _given_intrinsics(args: argparse.Namespace, names: list[str], options: dict, images: dict) -> dict:
    """The cameras of --intrinsics (read before the work, errors naming the file; each checked against its camera's
    first image's size), each camera's options set to the file's lens model with every intrinsic held."""
    from circcal.detector.image import header_size
    from circcal.formats import read_camera
    from circcal.model import param_names

    named_lens = {n for n, _ in args.lens if n is not None}
    given = {}
    for name, path in args.intrinsics:
        if name not in names:
            raise InputError(f"--intrinsics {name}={path}: no camera {name!r} (cameras: {', '.join(names)})")
        if name in given:
            raise InputError(f"--intrinsics {name}: given twice")
        cam = read_camera(path)
        size = header_size(Path(images[name][0])) if images[name] else None
        if size is not None and size != (cam.width, cam.height):
            raise InputError(
                f"--intrinsics {name}={path}: a {cam.width}x{cam.height} camera, camera {name}'s images are "
                f"{size[0]}x{size[1]} ({display_name(images[name][0])})"
            )
        if name in named_lens and options[name].lens != cam.lens:
            raise InputError(
                f"--intrinsics {name}={path}: its lens model is {cam.lens}, --lens {name}={options[name].lens}"
            )
        lens = replace(options[name], lens=cam.lens, fixed=())  # the file's model, then every parameter of it held
        options[name] = replace(lens, fixed=param_names(cam.lens))
        given[name] = cam
    return given


def _check_formats(args: argparse.Namespace, names: list[str], options: dict) -> str:
    """--out's format, and every file format's limits checked against the cameras' lens models before the work."""
    fmt = OUT_FORMATS.get(args.out.suffix.lower())
    if fmt is None:
        raise InputError(
            f"--out {display_name(args.out)}: unknown extension {args.out.suffix!r}; give rig.json (circcal's rig "
            f"model) or rig.yaml (OpenCV's stereo file of the first two cameras)"
        )
    if args.ros is not None:
        bad = [n for n in names[:2] if options[n].lens == "thin-prism"]
        if bad:
            raise InputError(f"--ros: camera {bad[0]!r} is thin-prism; ROS camera_info has no such distortion model")
    if args.cameramodels is not None:
        from circcal.formats.mrcal import MRCAL_UNSUPPORTED

        bad = [n for n in names if options[n].lens in MRCAL_UNSUPPORTED]
        if bad:
            raise InputError(
                f"--cameramodels: camera {bad[0]!r} is {options[bad[0]].lens}: "
                f"{MRCAL_UNSUPPORTED[options[bad[0]].lens]}"
            )
    if args.kalibr is not None:
        if args.kalibr.suffix.lower() not in (".yaml", ".yml"):
            raise InputError(f"--kalibr {display_name(args.kalibr)}: give a .yaml file (Kalibr's camchain is YAML)")
        richer = [n for n in names if options[n].lens in ("rational", "thin-prism")]
        k3 = [n for n in names if options[n].lens == "opencv5" and not options[n].holds("k3")]
        if richer or k3:
            blocks = ", ".join(
                f"{n!r} ({options[n].lens}{' with k3 free' if n in k3 else ''})" for n in names if n in richer + k3
            )
            fix = [
                f"--fix-k3 {n}" if n in k3 else f"--lens {n}=opencv5 --fix-k3 {n}" for n in names if n in richer + k3
            ]
            lens = [f"--lens {n}=opencv5 in place of {options[n].lens}" for n in names if n in richer]
            many = len(richer + k3) > 1
            raise InputError(
                f"--kalibr: Kalibr's radtan model holds k1, k2, p1, p2 only, and camera{'s' if many else ''} "
                f"{blocks} {'have' if many else 'has'} more; give {' '.join(fix)} ({'; '.join([*lens, ''])}or a "
                f"fisheye: --lens NAME=fisheye, Kalibr's equidistant)"
            )
    return fmt


def run(args: argparse.Namespace) -> int:
    """Calibrate the rig of the arguments, print its verdict and numbers, write its files.

    Parameters
    ----------
    args : argparse.Namespace
        The arguments :func:`add_parser`'s parser parsed.

    Returns
    -------
    int
        The exit status: 0; 1 when no rig could be made (said on stderr).

    Raises
    ------
    InputError
        A bad argument or input file (the CLI prints it and exits 2).
    """
    import sys

    from circcal.outputs import Outputs
    from circcal.rig import calibrate_rig
    from circcal.rig.verdict import rig_verdict
    from circcal.solver import CalibrationError

    images = _cameras(args)
    names = list(images)
    options = _options(args, names)
    given = _given_intrinsics(args, names, options, images)
    fmt = _check_formats(args, names, options)
    args.images = [f for paths in images.values() for f in paths]  # --grid auto looks at every camera's images
    board = board_of_args(args, "calibrate-rig")
    inputs = [*args.images, *([args.board] if args.board is not None else []), *(p for _, p in args.intrinsics)]
    with Outputs(inputs=inputs) as outputs:  # every output checked before the work, committed together
        out = outputs.file(args.out, "--out")
        ros = None if args.ros is None else outputs.folder(args.ros, "--ros", kind="rig-ros")
        models = (
            None
            if args.cameramodels is None
            else outputs.folder(args.cameramodels, "--cameramodels", kind="rig-cameramodels")
        )
        kalibr = None if args.kalibr is None else outputs.file(args.kalibr, "--kalibr")
        rectified = (
            None if args.rectified is None else outputs.folder(args.rectified, "--rectified", kind="rig-rectified")
        )
        report = None if args.report is None else outputs.folder(args.report, "--report", kind="rig-report")
        try:
            cal = calibrate_rig(
                images, board, options, progress=not args.no_progress, jobs=args.jobs, initial=given or None
            )
        except CalibrationError as exc:
            print(f"circcal calibrate-rig: no rig: {exc}", file=sys.stderr)
            flag = grid_hint(list(args.images), board)  # a --grid that is not the board's, as for calibrate
            if flag:
                print(f"circcal calibrate-rig: {flag}", file=sys.stderr)
            return 1
        verdict = rig_verdict(cal, options, cross_validate=args.cross_validate, progress=not args.no_progress)
        lines = (
            verdict.lines()
            + summary_lines(cal, images, options)
            + ([] if verdict.cross is None else verdict.cross.lines())
        )
        print("\n".join(lines))
        # the first two cameras at one point have no epipolar geometry: their rectification would be noise
        at_one_point = [c for c in verdict.coincident if (c.a, c.b) == (names[0], names[1])]
        stereo = [f for f, on in (("--out .yaml", fmt == "opencv"), ("--ros", ros), ("--rectified", rectified)) if on]
        if at_one_point and stereo:
            print(
                f"circcal calibrate-rig: no stereo rectification: {at_one_point[0].lines()[0]}; nothing written "
                f"({', '.join(stereo)} need it: give --out RIG.json, without --ros and --rectified, for this rig)",
                file=sys.stderr,
            )
            return 1
        _write(cal, board, verdict, fmt, out, ros, models, kalibr, rectified, args.alpha)
        if report is not None:
            from circcal.calreport.rig import write_rig_report

            write_rig_report(report, cal, board, lines)
        outputs.commit()
    written = [(args.out, "OpenCV stereo YAML of " + " and ".join(names[:2]) if fmt == "opencv" else "circcal rig")]
    written += [
        (p, what)
        for p, what in (
            (args.ros, "ROS camera_info pair"),
            (args.cameramodels, "mrcal .cameramodels"),
            (args.kalibr, "Kalibr camchain"),
            (args.rectified, "rectified pairs"),
            (args.report, "report: report.html, index.md"),
        )
        if p is not None
    ]
    for p, what in written:
        print(f"wrote {display_name(p)} ({what})")
    return 0


def _write(cal, board, verdict, fmt, out, ros, models, kalibr, rectified, alpha) -> None:
    """Every output into its staging place."""
    from circcal import atomic
    from circcal.jsonio import dumps
    from circcal.rig import (
        kalibr_camchain_text,
        mrcal_cameramodel_texts,
        opencv_stereo_text,
        rectify_pair,
        ros_camera_info_pair,
        write_rectified_overlay,
    )

    rig = cal.rig
    if fmt == "opencv":
        atomic.write_text(out, opencv_stereo_text(rig, 0, 1, alpha))
    else:
        doc = rig.to_dict()
        doc.update(
            instants=cal.instants,
            rms_px_per_camera=cal.rms_px,
            sigma_px=cal.sigma_px,
            dropped=cal.dropped,
            relabelled=cal.relabelled,
            placed=cal.placed,
            board=board.to_dict(),
            verdict=verdict.to_dict(),
        )
        atomic.write_text(out, dumps(doc, indent=1) + "\n")
    rect = rectify_pair(rig, 0, 1, alpha) if ros is not None or rectified is not None else None
    if ros is not None:
        for name, text in zip(rig.names[:2], ros_camera_info_pair(rig, 0, 1, rect=rect)):
            atomic.write_text(ros / f"{name}.yaml", text)
    if models is not None:
        for name, text in mrcal_cameramodel_texts(rig).items():
            atomic.write_text(models / f"{name}.cameramodel", text)
    if kalibr is not None:
        atomic.write_text(kalibr, kalibr_camchain_text(rig))
    if rectified is not None:
        a, b = rig.names[:2]
        for v in sorted(set(cal.instants[a]) & set(cal.instants[b])):  # the views the rig used: readable images
            write_rectified_overlay(
                rectified / f"{_file_stem(v)}.png", rig, Path(cal.images[a][v]), Path(cal.images[b][v]), rect
            )


def _file_stem(instant: str) -> str:
    """A file name for an instant's output: its name without an image extension, a folder's ``/`` as ``_``."""
    flat = instant.replace("/", "_")
    return Path(flat).stem if Path(flat).suffix.lower() in IMAGE_SUFFIXES else flat


def summary_lines(cal, images: dict[str, list[Path]], options=None) -> list[str]:
    """The numbers of a rig calibration: per camera its images, RMS, intrinsics and pose with their sigmas, what was
    left out; then the coverage of each camera and of the field each pair of cameras shares (pairs with a shared
    instant).

    Parameters
    ----------
    cal : circcal.rig.RigCalibration
    images : dict of str to list of Path
        Per camera the images given.
    options : CalibrationOptions or dict of str to CalibrationOptions, optional
        What the joint solve held: where the rig has no covariance (its information singular), the parameters its
        views still determine get their sigma (:func:`circcal.rig.undetermined.determined_rig_covariance`), the
        others nan; without it every sigma of such a rig is nan.

    Returns
    -------
    list of str
    """
    import numpy as np

    from circcal.rig.uncertainty import projection_uncertainty
    from circcal.rig.undetermined import determined_rig_covariance
    from circcal.rig.verdict import camera_coverage, shared_coverage

    rig = cal.rig
    std = cal.std()
    cov = rig.covariance
    if cov is None and options is not None:
        cov = determined_rig_covariance(cal, options)
        if cov is not None:
            std = np.sqrt(np.maximum(np.diag(cov), 0.0))  # NaN stays NaN: undetermined
    n_intr = [len(c.intrinsics) for c in rig.cameras]
    offsets = np.concatenate([[0], np.cumsum(n_intr)])
    lines = [
        f"rig of {rig.n_cameras} cameras, {len(cal.board_poses)} instants: RMS per point (2-D norm), OpenCV's "
        f"convention, {rig.rms_px:.4f} px over every camera; noise estimate sigma {cal.sigma_px:.4f} px per "
        f"coordinate; {cal.iterations} iterations{'' if cal.converged else ' (NOT converged)'}"
    ]
    if cal.rounds:
        lines.append(
            "re-correction rounds: "
            + ", ".join(
                f"{r['round']}: RMS/pt {r['rms_px']:.4f} px"
                + ("" if r["round"] == 0 else f", centres moved <= {r['max_centre_shift_px']:.2g} px")
                for r in cal.rounds
            )
        )
    for k, (name, cam) in enumerate(zip(rig.names, rig.cameras)):
        lines.append(
            f"camera {name}{' (reference)' if k == 0 else ''}: {cam.width}x{cam.height}, {cam.model.description}; "
            f"{len(images[name])} images found, {len(cal.instants[name])} views used; RMS per point (2-D norm), "
            f"OpenCV's convention, {cal.rms_px[name]:.4f} px"
        )
        lines.append(f"  {'parameter':>9}  {'value':>14}  {'+- 1 sigma':>12}")
        s = std[offsets[k] : offsets[k + 1]]
        for pname, v, sv in zip(cam.model.param_names, cam.intrinsics, s):
            lines.append(f"  {pname:>9}  {v:14.6f}  {sv:12.6f}{'  (held)' if sv == 0 else ''}")
        if k > 0:
            lines.append("  " + _pose_text(rig, k, std[offsets[-1] + 6 * (k - 1) : offsets[-1] + 6 * k], cov))
        per = cal.per_camera.get(name)
        placed = cal.placed.get(name, [])
        placed_paths = {str(cal.images.get(name, {}).get(v)) for v in placed}
        for r in getattr(per, "failed", []) or []:
            if str(r.path) not in placed_paths:
                lines.append(f"  image left out: {display_name(r.path)}: {r.reason}")
        if placed:
            lines.append(
                f"  parts of the board its detector could not place alone, placed where the other cameras put the "
                f"board: {', '.join(display_name(v) for v in placed)}"
            )
        for d in cal.dropped:
            if d["camera"] == name:
                lines.append(f"  view dropped from the rig: {display_name(d['instant'])}: {d['reason']}")
        relabelled = [display_name(r["instant"]) for r in cal.relabelled if r["camera"] == name]
        if relabelled:
            lines.append(
                f"  views relabelled by the board's symmetry to agree with the others: {', '.join(relabelled)}"
            )
    lines += [u.text() for u in projection_uncertainty(rig, cov)]
    lines.append("coverage (each ninth of the image needs an observed point, else the lens model is extrapolated):")
    for k, (name, cover) in enumerate(camera_coverage(cal).items()):
        lines.append(f"  {name}: {100 * cover.covered_share:.0f}% of the map's cells hold a point")
        if not np.any(std[offsets[k] : offsets[k + 1]]):  # held: its lens is the given calibration's
            lines.append(
                "    its intrinsics are held (given): their coverage is that of the calibration they came from"
            )
            continue
        lines += [f"    {w}" for w in cover.warnings]
    for i in range(rig.n_cameras):  # every pair of cameras that saw the board at one instant
        for j in range(i + 1, rig.n_cameras):
            if not set(cal.instants[rig.names[i]]) & set(cal.instants[rig.names[j]]):
                continue
            a, b = shared_coverage(cal, i, j)
            ni, nj = rig.names[i], rig.names[j]
            lines.append(
                f"  the field {ni} and {nj} share (board points both saw at one instant): "
                f"{100 * a.covered_share:.0f}% of {ni}'s map cells, {100 * b.covered_share:.0f}% of {nj}'s"
            )
            lines += [f"    in {ni}: {w}" for w in a.warnings] + [f"    in {nj}: {w}" for w in b.warnings]
    return lines


def _pose_text(rig, k: int, s, cov=None) -> str:
    """Camera k's pose in the rig with its sigmas (s: the standard deviations of rvec, tvec; cov: the covariance of
    ``rig.state_vector()``, default ``rig.covariance``). The rotation's sigma is that of the rotation error, the
    small rotation between the estimate and the truth (rvec's covariance through SO(3)'s left Jacobian): about its
    worst axis and about each axis of camera k's frame, not the angle's alone (a rolled camera's 90 deg is known
    to 0.0003 deg while its axis is known to 0.004 deg)."""
    import numpy as np

    from circcal.rotation import left_jacobian

    rv, tv = rig.rvecs[k], rig.tvecs[k]
    cov = rig.covariance if cov is None else cov
    angle, base = float(np.linalg.norm(rv)), float(np.linalg.norm(tv))
    sw = sb = float("nan")
    axes = np.full(3, np.nan)
    if cov is not None:
        n = sum(len(c.intrinsics) for c in rig.cameras) + 6 * (k - 1)
        C = np.asarray(cov, dtype=np.float64)[n : n + 6, n : n + 6]
        if np.all(np.isfinite(C[:3, :3])):
            J = left_jacobian(rv)
            Cr = J @ C[:3, :3] @ J.T
            sw = float(np.sqrt(max(np.linalg.eigvalsh(0.5 * (Cr + Cr.T))[-1], 0.0)))
            axes = np.sqrt(np.maximum(np.diag(Cr), 0.0))
        u = tv / base if base > 0 else np.zeros(3)
        sb = float(np.sqrt(max(u @ C[3:, 3:] @ u, 0.0))) if np.all(np.isfinite(C[3:, 3:])) else float("nan")
    # sigmas to two significant digits: a clean rig's baseline sigma (~1e-4 mm) does not round to 0
    T = ", ".join(f"{t:.3f} +- {e:.2g}" for t, e in zip(tv, s[3:]))
    ax = ", ".join(f"{np.degrees(a):.2g}" for a in axes)
    return (
        f"pose in the rig (X_{rig.names[k]} = R X_{rig.names[0]} + T): rotation {np.degrees(angle):.4f} deg +- "
        f"{np.degrees(sw):.2g} deg (1 sigma of the rotation error about its worst axis; about {rig.names[k]}'s x, "
        f"y, z: {ax} deg), baseline {base:.3f} +- {sb:.2g} mm; T = ({T}) mm"
    )
