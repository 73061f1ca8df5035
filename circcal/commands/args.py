"""Argument types shared by the ``circcal`` subcommands (argparse ``type=`` callables: a bad value exits 2 with one
line naming the option and the reason)."""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path

from circcal.errors import InputError

_UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}


def parse_length_mm(text: str) -> float:
    """A length with its unit -> mm.

    Parameters
    ----------
    text : str
        A number and a unit: ``10mm``, ``1.5cm``, ``0.01m``, ``0.5in``. A bare number is refused: a board printed in
        inches read as millimetres would scale every pose and the board's shape by 25.4.

    Returns
    -------
    float
        The length in mm (> 0, finite).

    Raises
    ------
    argparse.ArgumentTypeError
        No unit, not a number, not positive.
    """
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(mm|cm|m|in|)\s*", str(text))
    if not m:
        raise argparse.ArgumentTypeError(f"not a length: {text!r} (expected e.g. 10mm, 1.5cm, 0.01m)")
    if not m.group(2):
        raise argparse.ArgumentTypeError(f"{m.group(1)} what? give the unit, e.g. {m.group(1)}mm (mm, cm, m or in)")
    value = float(m.group(1)) * _UNITS_MM[m.group(2)]
    if not (0 < value < float("inf")):
        raise argparse.ArgumentTypeError(f"length must be a finite number above 0, got {text!r}")
    return value


#: ``--distance``'s help (calibrate, diff): a length with its unit, or a bare number of mm as before.
DISTANCE_HELP = (
    "distance along each pixel's ray, a length with its unit, e.g. 2m or 500mm (a bare number is mm; default: "
    "infinity, as mrcal)"
)


def parse_distance_mm(text: str) -> float:
    """``--distance``: a length with its unit (:func:`parse_length_mm`: ``2m``, ``500mm``), or a bare number of mm
    (what the option took before it took units, kept so that existing scripts mean the same).

    Parameters
    ----------
    text : str
        ``2m``, ``1.5cm``, ``0.5in``, ``500mm`` or ``500`` (mm).

    Returns
    -------
    float
        The distance in mm (> 0, finite).

    Raises
    ------
    argparse.ArgumentTypeError
        Not a length or a number, not positive, not finite.

    Examples
    --------
    >>> parse_distance_mm("2m"), parse_distance_mm("500")
    (2000.0, 500.0)
    """
    try:
        value = float(text)
    except ValueError:
        return parse_length_mm(text)
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"distance must be a finite length above 0, got {text!r}")
    return value


def parse_grid(text: str) -> tuple[int, int] | str:
    """'7x7' -> (rows, cols): points per column x points per row (an argparse type); ``auto`` -> ``"auto"`` (the grid
    found from the images: :func:`resolve_grid`).

    Parameters
    ----------
    text : str
        ``ROWSxCOLS`` (``x``, ``X`` or ``*``), or ``auto``.

    Returns
    -------
    tuple of int or str
        (rows, cols), or ``"auto"``.

    Raises
    ------
    argparse.ArgumentTypeError
        Not ``ROWSxCOLS``.

    Examples
    --------
    >>> parse_grid("11x4")
    (11, 4)
    """
    if str(text).strip().lower() == "auto":
        return "auto"
    m = re.fullmatch(r"\s*(\d+)\s*[xX*]\s*(\d+)\s*", str(text))
    if not m:
        raise argparse.ArgumentTypeError(f"grid must be ROWSxCOLS (points), e.g. 7x7 or 11x4, or auto, got {text!r}")
    return int(m.group(1)), int(m.group(2))


def _integer(text: str) -> int:
    """``int(text)``, refused in argparse's words (the one parse behind every integer option)."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None


def positive_int(text: str) -> int:
    """'4' -> 4; at least 1 (an argparse type).

    Parameters
    ----------
    text : str

    Returns
    -------
    int

    Raises
    ------
    argparse.ArgumentTypeError
    """
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """'1e-6' -> 1e-06; a finite number above 0 (an argparse type).

    NaN, inf, 0 and negatives are refused: as a tolerance they would make a check pass or fail whatever was measured.

    Parameters
    ----------
    text : str

    Returns
    -------
    float

    Raises
    ------
    argparse.ArgumentTypeError
    """
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a finite number above 0, got {text!r}")
    return value


def nonnegative_int(text: str) -> int:
    """'5' -> 5; 0 or more (a seed: numpy's generators refuse negative seeds; an argparse type).

    Parameters
    ----------
    text : str

    Returns
    -------
    int

    Raises
    ------
    argparse.ArgumentTypeError
    """
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {text!r}")
    return value


def int_between(lo: int, hi: int):
    """An argparse type: an integer within ``lo..hi`` (a size that sets memory, e.g. a grid's pixels across).

    Parameters
    ----------
    lo, hi : int
        The bounds, inclusive.

    Returns
    -------
    callable, str -> int
        Raises ``argparse.ArgumentTypeError`` outside the bounds or for a non-integer.
    """

    def parse(text: str) -> int:
        value = _integer(text)
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be within {lo}..{hi}, got {text!r}")
        return value

    parse.__name__ = f"integer {lo}..{hi}"
    return parse


def resolve_grid(args: argparse.Namespace, command: str) -> None:
    """``--grid auto``: the grid found from ``args.images`` (:func:`circcal.detector.locate.infer.infer_grid`) put in
    ``args.grid`` and ``args.asymmetric``, and the ``--grid`` line it stands for printed; any other ``--grid`` is
    left as it is.

    Parameters
    ----------
    args : argparse.Namespace
        With ``grid``, ``asymmetric`` and ``images`` (the files, folders expanded); modified in place.
    command : str
        The command's name, for the printed line.

    Raises
    ------
    InputError
        No image shows a lattice of dots.
    """
    if args.grid != "auto":
        return
    from circcal.detector.locate.infer import grid_text, infer_grid

    rows, cols, layout, evidence = infer_grid(args.images)
    if rows is None:
        why = "; ".join(e.text() for e in evidence[:3])
        raise InputError(f"--grid auto: no image shows a lattice of dots ({why}); give --grid RxC")
    if args.asymmetric and layout != "asymmetric":
        raise InputError(f"--grid auto found {grid_text(rows, cols, layout)}, a symmetric grid: drop --asymmetric")
    args.grid, args.asymmetric = (rows, cols), layout == "asymmetric"
    shown = sum(e.whole and (e.rows, e.cols, e.layout) == (rows, cols, layout) for e in evidence)
    print(
        f"circcal {command}: --grid auto: {grid_text(rows, cols, layout)} (whole in {shown} of {len(evidence)} images)"
    )


def grid_hint(images: list[Path], board) -> str:
    """What the images show when the given grid was not found in them: the flag that fixes it, or ``""``.

    Parameters
    ----------
    images : list of Path
    board : circcal.board.Board
        The board of the given ``--grid`` and ``--asymmetric``.

    Returns
    -------
    str
        ``"an asymmetric grid: add --asymmetric"``, ``"a symmetric grid: drop --asymmetric"``, ``"the grid is CxR:
        --grid CxR"``, or the ``--grid`` line found;
        ``""`` when the images show that board's grid or no grid.
    """
    from circcal.detector.locate.infer import grid_text, infer_grid, probe_grid_of

    rows, cols, layout, _ = infer_grid(images)
    if rows is None or (rows, cols, layout) == probe_grid_of(board):
        return ""
    if layout == "asymmetric" and board.layout != "asymmetric" and {rows, cols} == {board.rows, board.cols}:
        return f"an asymmetric grid: add --asymmetric ({grid_text(rows, cols, layout)})"
    if layout != "asymmetric" and board.layout == "asymmetric" and {rows, cols} == {board.rows, board.cols}:
        return f"a symmetric grid: drop --asymmetric ({grid_text(rows, cols, layout)})"
    if layout == board.layout and (rows, cols) == (board.cols, board.rows):
        return f"the grid is {rows}x{cols}: --grid {rows}x{cols}"
    return f"the images show {grid_text(rows, cols, layout)} (or give --grid auto)"


DIAMETER_HELP = "dot diameter, e.g. 5mm (default: half the spacing of nearest dots)"


def board_from_args(grid: tuple[int, int], pitch_mm: float, diameter_mm: float | None, asymmetric: bool):
    """The :class:`circcal.board.Board` of ``--grid``, ``--pitch``, ``--diameter``, ``--asymmetric`` (one rule for every
    subcommand).

    Without a diameter: half the spacing of nearest dots, ``pitch / 2`` (symmetric) or ``pitch * sqrt(2) / 2``
    (asymmetric: OpenCV's acircles layout puts nearest dots sqrt(2) pitches apart). The detector uses the diameter
    only to bound the size of candidate dots.

    Parameters
    ----------
    grid : tuple of int
        (rows, cols).
    pitch_mm : float
        mm.
    diameter_mm : float or None
        mm; None: as above.
    asymmetric : bool

    Returns
    -------
    Board

    Raises
    ------
    InputError
        A board the class refuses (:class:`circcal.board.Board`).
    """
    from circcal.board import Board

    layout = "asymmetric" if asymmetric else "symmetric"
    if diameter_mm is None:
        diameter_mm = 0.5 * pitch_mm * (2**0.5 if asymmetric else 1.0)
    return Board(grid[0], grid[1], pitch_mm, diameter_mm, layout)


#: The options a board description file replaces (``--board FILE``): option -> its argparse ``dest``.
BOARD_FILE_REPLACES: dict[str, str] = {
    "--grid": "grid",
    "--pitch": "pitch",
    "--diameter": "diameter",
    "--asymmetric": "asymmetric",
    "--markers": "markers",
    "--marker-diameter": "marker_diameter",
}
BOARD_FILE_HELP = (
    "board description file, YAML or JSON (circcal's rows/cols/layout/pitch_mm/diameter_mm/markers form, "
    "ROS-Industrial's target.yaml, Kalibr's target YAML with target_type: circlegrid, or BoofCV's target config "
    "with type: CIRCLE_GRID): replaces --grid, "
    "--pitch, --diameter, --asymmetric and --markers (marker dots anywhere on the grid)"
)


def add_board_file_argument(p: argparse.ArgumentParser) -> None:
    """Add ``--board FILE`` (:data:`BOARD_FILE_HELP`; read by :func:`board_of_args`).

    Parameters
    ----------
    p : argparse.ArgumentParser
    """
    p.add_argument("--board", type=Path, default=None, metavar="FILE", help=BOARD_FILE_HELP)


def marker_args_board(args: argparse.Namespace, board):
    """``board`` with the markers the parsed ``--markers`` / ``--marker-diameter`` ask for (none when absent).

    Parameters
    ----------
    args : argparse.Namespace
    board : Board

    Returns
    -------
    Board

    Raises
    ------
    InputError
        ``--marker-diameter`` without markers, or markers the board cannot have
        (:func:`circcal.markers.with_markers`).
    """
    from circcal.markers import with_markers

    markers = getattr(args, "markers", None) or "none"
    if markers == "none":
        if getattr(args, "marker_diameter", None) is not None:
            raise InputError("--marker-diameter without --markers origin|pattern")
        return board
    return with_markers(board, markers, getattr(args, "marker_diameter", None))


def board_of_args(args: argparse.Namespace, command: str, *, default_pitch_mm: float | None = None):
    """The board a command's arguments describe: ``--board FILE``, or ``--grid`` (``auto`` resolved:
    :func:`resolve_grid`), ``--pitch``, ``--diameter``, ``--asymmetric``, ``--markers``, ``--marker-diameter``.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments; the grid options a command lacks count as not given. ``args.grid`` and
        ``args.asymmetric`` are set in place by ``--grid auto``.
    command : str
        The command's name, for messages.
    default_pitch_mm : float or None
        The pitch when ``--grid`` comes without ``--pitch`` (mm); None: ``--pitch`` is required.

    Returns
    -------
    Board

    Raises
    ------
    InputError
        One line: ``--board`` with any of :data:`BOARD_FILE_REPLACES` (naming both), neither ``--board`` nor
        ``--grid``, ``--grid`` without a needed ``--pitch``, a bad board file (naming the file and the field), or a
        board the options describe that the class refuses.
    """
    if getattr(args, "board", None) is not None:
        given = [opt for opt, dest in BOARD_FILE_REPLACES.items() if getattr(args, dest, None) not in (None, False)]
        if given:
            raise InputError(
                f"--board {args.board} and {given[0]} both given: the board file replaces "
                f"{', '.join(BOARD_FILE_REPLACES)}; give one or the other"
            )
        from circcal.formats.boardfile import read_board_file

        return read_board_file(args.board)
    if getattr(args, "grid", None) is None:
        raise InputError("give --grid ROWSxCOLS (with --pitch) or --board FILE")
    pitch = args.pitch if getattr(args, "pitch", None) is not None else default_pitch_mm
    if pitch is None:
        raise InputError("--grid needs --pitch (e.g. --pitch 10mm), or give --board FILE")
    resolve_grid(args, command)
    board = board_from_args(args.grid, pitch, getattr(args, "diameter", None), bool(getattr(args, "asymmetric", False)))
    return marker_args_board(args, board)


#: The lens models of ``--lens`` (:data:`circcal.model.LENS_MODELS`' names, written out so that building the parser
#: imports no numpy; tests/test_calibrate_lens.py checks they agree), each with what it is.
LENS_CHOICES: dict[str, str] = {
    "opencv5": "OpenCV's k1, k2, p1, p2, k3",
    "rational": "OpenCV's CALIB_RATIONAL_MODEL, k1-k6, p1, p2",
    "thin-prism": "OpenCV's CALIB_THIN_PRISM_MODEL, + s1-s4",
    "fisheye": "cv2.fisheye's equidistant Kannala-Brandt k1-k4",
}


def add_lens_argument(p: argparse.ArgumentParser, *, auto: bool = False) -> None:
    """Add ``--lens``: the lens model a command fits (default opencv5).

    Parameters
    ----------
    p : argparse.ArgumentParser
    auto : bool
        Also offer ``--lens auto`` (the model chosen from the images: :func:`circcal.pipeline.choose_lens`).
    """
    choices = {
        **LENS_CHOICES,
        **({"auto": "the one of opencv5, fisheye, rational that predicts held-out views best"} if auto else {}),
    }
    p.add_argument(
        "--lens",
        choices=tuple(choices),
        default="opencv5",
        help="lens model: " + "; ".join(f"{k} ({v})" for k, v in choices.items()) + " (default opencv5)",
    )


#: The ``--fix-*`` flags of ``circcal calibrate``: flag -> help (what each holds:
#: :data:`circcal.solver.options.FLAG_HOLDS`).
FIX_FLAGS: dict[str, str] = {
    "--fix-k2": "hold k2 at 0",
    "--fix-k3": "hold k3 at 0",
    "--fix-tangential": "hold p1, p2 at 0 (pinhole lens models)",
    "--fix-aspect-ratio": "hold fx = fy",
    "--fix-principal-point": "hold (cx, cy) at the image centre",
}


#: A rig's ``--fix-*`` flags whose parameter means another term for a fisheye (theta^4, theta^6 of cv2.fisheye's
#: Kannala-Brandt) than for a pinhole lens (r^4, r^6): given without a camera in a rig mixing the two, they hold the
#: pinhole cameras' only (:func:`fix_holds`).
FISHEYE_MEANS_OTHER = ("--fix-k2", "--fix-k3")


def add_fix_arguments(p: argparse.ArgumentParser, *, per_camera: bool = False) -> None:
    """Add the ``--fix-*`` flags (:data:`FIX_FLAGS`).

    Parameters
    ----------
    p : argparse.ArgumentParser
    per_camera : bool
        A rig's flags: each may name a camera (``--fix-k3 NAME`` or ``--fix-k3=NAME``, repeated for several) or none
        (every camera; a plain ``--fix-k2`` / ``--fix-k3`` in a rig mixing pinhole and fisheye lenses holds the
        pinhole cameras' only: :data:`FISHEYE_MEANS_OTHER`); the value is then the list of names given, ``None``
        for the plain flag.
    """
    for flag, text in FIX_FLAGS.items():
        if not per_camera:
            p.add_argument(flag, action="store_true", help=text)
            continue
        other = (
            "; without NAME in a rig mixing pinhole and fisheye lenses, the pinhole cameras' only (a fisheye's "
            f"{flag[6:]} is its theta^{2 * int(flag[-1])} term: name the camera to hold it)"
            if flag in FISHEYE_MEANS_OTHER
            else ""
        )
        p.add_argument(
            flag,
            action="append",
            nargs="?",
            const=None,
            default=[],
            metavar="NAME",
            help=f"{text}: of camera NAME (repeat for several), or without NAME of every camera{other}",
        )


def fix_holds(args: argparse.Namespace, lenses: dict[str, str]) -> tuple[dict[str, dict[str, bool]], list[str]]:
    """Which camera each ``--fix-*`` flag holds: a named camera (``--fix-k3 NAME``), or without a name every camera,
    except that where the rig mixes pinhole and fisheye lenses a plain ``--fix-k2`` / ``--fix-k3`` holds the pinhole
    cameras' only (a fisheye's k2, k3 are its theta^4, theta^6 terms: :data:`FISHEYE_MEANS_OTHER`), said in a note.

    Parameters
    ----------
    args : argparse.Namespace
        With the ``--fix-*`` flags as :func:`add_fix_arguments` (``per_camera=True``) parses them: per flag a list
        of camera names, ``None`` for the plain flag (a bool is taken as the plain flag).
    lenses : dict of str to str
        Per camera (in the rig's order) its lens model.

    Returns
    -------
    holds : dict of str to dict of str to bool
        Per camera, per flag's keyword (``fix_k3``, ...) whether it holds it.
    notes : list of str
        One line per plain flag that left a camera out, saying which and how to hold it there.

    Raises
    ------
    InputError
        One line naming the flag: a camera that is not the rig's, a camera named twice, a camera whose lens model
        has no such parameter (``--fix-tangential NAME`` of a fisheye; a plain ``--fix-tangential`` in a rig with a
        fisheye, naming the cameras that have p1, p2).
    """
    from circcal.model import lens_model
    from circcal.solver.options import ASPECT_RATIO, FLAG_HOLDS

    names = list(lenses)
    fisheye = {n for n, le in lenses.items() if le == "fisheye"}
    mixed = bool(fisheye) and len(fisheye) < len(names)
    holds: dict[str, dict[str, bool]] = {n: {} for n in names}
    notes = []
    for flag in FIX_FLAGS:
        key = flag[2:].replace("-", "_")
        given = getattr(args, key, None) or []
        given = [None] if given is True else [] if given is False else list(given)
        params = [q for q in FLAG_HOLDS[key] if q != ASPECT_RATIO]
        has = {n: all(q in lens_model(lenses[n]).param_names for q in params) for n in names}
        named = [g for g in given if g is not None]
        for g in named:
            if g not in lenses:
                raise InputError(f"{flag} {g}: no camera {g!r} (cameras: {', '.join(names)})")
            if named.count(g) > 1:
                raise InputError(f"{flag} {g}: camera {g!r} given twice")
            if not has[g]:
                raise InputError(f"{flag} {g}: the {lenses[g]} lens model has no {', '.join(params)} to hold fixed")
        on = set(named)
        if None in given:
            other = [n for n in names if mixed and flag in FISHEYE_MEANS_OTHER and n in fisheye]
            plain = [n for n in names if n not in other]
            lacking = next((n for n in plain if not has[n]), None)
            if lacking is not None:
                lens = lenses[lacking]
                have = [n for n in names if has[n]]
                raise InputError(
                    f"camera {lacking!r} (lens {lens}): {flag}: the {lens} lens model has no {', '.join(params)} to "
                    f"hold fixed"
                    + (f"; name the cameras that have them: {' '.join(f'{flag} {n}' for n in have)}" if have else "")
                )
            left = [n for n in other if n not in on]
            if left:
                notes.append(
                    f"{flag} holds {params[0]} of {', '.join(plain)} only, not of {', '.join(left)} (a fisheye's "
                    f"{params[0]} is its theta^{2 * int(params[0][1])} term, another coefficient; "
                    f"{' '.join(f'{flag} {n}' for n in left)} holds it)"
                )
            on |= set(plain)
        for n in names:
            holds[n][key] = n in on
    return holds, notes


def calibration_options(args: argparse.Namespace):
    """The one :class:`circcal.solver.options.CalibrationOptions` of a command's arguments: ``--lens``, the
    ``--fix-*`` flags, ``--refine-board``, ``--board-warp`` and the outlier rule (``--no-outlier-rejection``,
    ``--outlier-k``), each read where the command has it. Built before any work, so that its errors come first.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    CalibrationOptions

    Raises
    ------
    InputError
        One line naming the flag: a hold the lens model does not have (``--fix-tangential`` with the fisheye),
        ``--outlier-k`` with ``--no-outlier-rejection``, ``--board-warp`` with ``--refine-board``.
    """
    from circcal.solver.options import CalibrationOptions
    from circcal.solver.outliers import DEFAULT_K, OutlierRule

    no_rejection = getattr(args, "no_outlier_rejection", True)
    k = getattr(args, "outlier_k", None)
    if no_rejection and k is not None:
        raise InputError(
            "--outlier-k sets the threshold of the outlier rejection that --no-outlier-rejection turns "
            "off: give one of them"
        )
    if getattr(args, "board_warp", False) and getattr(args, "refine_board", False):
        raise InputError(
            "--board-warp and --refine-board: the refined board estimates every point, the warp is its "
            "2-parameter special case; give one of them"
        )
    flags = {f[2:].replace("-", "_"): bool(getattr(args, f[2:].replace("-", "_"), False)) for f in FIX_FLAGS}
    return CalibrationOptions.from_flags(
        **flags,
        spell=lambda name: "--" + name.replace("_", "-"),
        lens=lens if (lens := getattr(args, "lens", None)) not in (None, "auto") else "opencv5",
        refine_board=bool(getattr(args, "refine_board", False)),
        board_warp=bool(getattr(args, "board_warp", False)),
        outlier_rule=None if no_rejection else OutlierRule(k=k or DEFAULT_K),
    )


def plain(text: str) -> str:
    """A docstring as command-line help: Sphinx roles (``:func:`x` ``) and inline literals (````x````) as plain text.

    Parameters
    ----------
    text : str
        reStructuredText as the module docstrings write it.

    Returns
    -------
    str
        The same text with ``:role:`target``` reduced to its target's last name and double backquotes to single
        ones (the help a user reads shows no developer markup).

    Examples
    --------
    >>> plain("see :func:`circcal.commands.board.add_marker_arguments` and ``--grid RxC``")
    'see add_marker_arguments and `--grid RxC`'
    """
    text = re.sub(r":[a-z]+:`~?([^`<]*?<)?([^`>]*)>?`", lambda m: m.group(2).rsplit(".", 1)[-1], text)
    return text.replace("``", "`")
