"""``circcal board --grid RxC --pitch P --diameter D [--asymmetric] [--markers origin|pattern] --out board.svg|pdf``
(or ``--board FILE``): a circle-grid board true to scale for printing, with the geometry the calibrator needs printed
in its margin, and beside it (same name, ``.yaml``) its board description file (:mod:`circcal.formats.boardfile`)
for ``--board``; both are committed together.

The scale is exact by construction: the figure is the page (its size in inches is the paper's size in mm / 25.4),
one axes spans the whole figure without margins, and its data limits are the page in mm, so one data unit is one
millimetre on paper; the file is written without any cropping (no ``bbox_inches``), and both SVG (width and height
in pt) and PDF (page size in pt) carry the physical size. A 100 mm scale bar is printed beside the geometry: a
printer that scales ("fit to page") shows on it. Dots are circles of the board's diameters around the object
points (OpenCV's order, markers larger), on a white board of the board's margin; the board is centred on the page.

Also here: the marker options every command shares (:func:`add_marker_arguments`; the board they describe:
:func:`circcal.commands.args.marker_args_board`).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from circcal.commands.args import (
    DIAMETER_HELP,
    add_board_file_argument,
    board_of_args,
    parse_grid,
    parse_length_mm,
)

__all__ = ["PAPERS", "add_marker_arguments", "add_parser", "draw_board", "parse_paper", "run"]

MM_PER_INCH = 25.4
PAPERS: dict[str, tuple[float, float]] = {
    "a4": (210.0, 297.0),
    "a3": (297.0, 420.0),
    "a2": (420.0, 594.0),
    "letter": (215.9, 279.4),
    "tabloid": (279.4, 431.8),
}
"""Paper sizes (width, height) mm, portrait; a board wider than tall is laid out on the page turned."""
LINE_MM = 3.2
"""Line spacing of the margin text (mm); the band under the board holds the text and the scale bar."""
CHAR_MM = 1.45
"""Width of one character of the margin text (mm, DejaVu Sans at :data:`TEXT_PT`, with room): lines are wrapped to
the page."""
BAND_EXTRA_MM = 12.0
"""The band under the board: the text, plus this for the gap above it and the scale bar below it."""
PAGE_MARGIN_MM = 8.0
"""Kept free at the page's edges (printers do not print to the edge)."""
SCALE_BAR_MM = 100.0
"""Length of the printed scale bar (mm), shortened to fit narrower pages to 50 or 20 mm."""
TEXT_PT = 7.0
"""Size of the margin text (pt)."""


#: ``circcal board --help``'s description: what the command does and writes, for a user (the module docstring says
#: how the scale is kept exact).
DESCRIPTION = """\
Write a circle-grid calibration board, true to scale, as an SVG or PDF page to print, and beside it (same name,
.yaml) a board file that describes it: give that to calibrate and detect as --board FILE. Under the board the page
carries its geometry, the calibrate command line to use, and a 100 mm scale bar.

Print it at 100 % (actual size, not "fit to page"), check the scale bar and the dot spacing with a ruler or a
caliper, and mount the sheet flat on something rigid. If the printed spacing differs from --pitch, calibrate with
the measured one (pitch_mm in the .yaml, or --pitch); a sheet that is not quite flat: calibrate --refine-board.

The board is centred on the page (--paper, default a4; turned when it fits only that way), with a white margin of
one pitch around the outermost dots (--margin). Exit status: 0 written; 2 bad input or a board that does not fit."""

#: ``circcal board --help``'s examples.
EXAMPLES = """\
examples:
  circcal board --grid 7x10 --pitch 20mm --diameter 10mm --out board.pdf
  circcal board --grid 11x4 --asymmetric --pitch 15mm --paper letter --out acircles.svg
  circcal board --grid 8x11 --pitch 20mm --markers pattern --paper a3 --out board.pdf
  circcal board --board board.yaml --out board.pdf"""


def add_marker_arguments(p: argparse.ArgumentParser) -> None:
    """Add ``--markers`` and ``--marker-diameter`` (the same for ``board``, ``detect`` and ``calibrate``).

    Parameters
    ----------
    p : argparse.ArgumentParser
    """
    p.add_argument(
        "--markers",
        choices=("none", "origin", "pattern"),
        default=None,
        help="marker dots on the board: origin = ROS-Industrial's modified circle grid (one dot of twice "
        "the diameter at the bottom-left), pattern = circcal's (about one dot in four 1.5x larger, "
        "every 4x4 window unique: partial views are labelled); default none",
    )
    p.add_argument(
        "--marker-diameter",
        type=parse_length_mm,
        default=None,
        help="marker dot diameter (default: 2x the dots' for origin, 1.5x for pattern)",
    )


def parse_paper(text: str) -> tuple[float, float]:
    """'a4', 'letter', ... or 'WxH' with a unit ('300x200mm', '12x9in'; mm by default) -> (width, height) mm (an
    argparse type).

    Parameters
    ----------
    text : str

    Returns
    -------
    tuple of float
        (width, height), mm.

    Raises
    ------
    argparse.ArgumentTypeError

    Examples
    --------
    >>> parse_paper("300x200mm")
    (300.0, 200.0)
    """
    t = str(text).strip().lower()
    if t in PAPERS:
        return PAPERS[t]
    m = re.fullmatch(r"([0-9]*\.?[0-9]+)\s*x\s*([0-9]*\.?[0-9]+)\s*(mm|cm|m|in|)", t)
    if not m:
        raise argparse.ArgumentTypeError(
            f"paper must be one of {', '.join(PAPERS)} or WxH with a unit (e.g. 300x200mm), got {text!r}"
        )
    unit = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": MM_PER_INCH, "": 1.0}[m.group(3)]
    w, h = float(m.group(1)) * unit, float(m.group(2)) * unit
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"paper size must be positive, got {text!r}")
    return w, h


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal board`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = sub.add_parser(
        "board",
        help="write a circle-grid board true to scale for printing (SVG or PDF)",
        description=DESCRIPTION,
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--grid", type=parse_grid, help="ROWSxCOLS points, e.g. 7x7 (asymmetric: 11x4)")
    p.add_argument(
        "--pitch",
        type=parse_length_mm,
        help="point spacing, e.g. 10mm (asymmetric: OpenCV's squareSize, half the in-row spacing)",
    )
    p.add_argument("--diameter", type=parse_length_mm, help=DIAMETER_HELP)
    p.add_argument("--asymmetric", action="store_true", help="asymmetric circle grid (OpenCV acircles layout)")
    add_marker_arguments(p)
    add_board_file_argument(p)
    p.add_argument(
        "--margin",
        type=parse_length_mm,
        default=None,
        help="white border around the outermost dots (default: one pitch)",
    )
    p.add_argument(
        "--paper",
        type=parse_paper,
        default=PAPERS["a4"],
        help=f"paper: {', '.join(PAPERS)} or WxH with a unit (default a4)",
    )
    p.add_argument("--out", type=Path, required=True, help="output file, .svg or .pdf")
    p.set_defaults(func=run)


def _wrapped(board, style: str, width_mm: float, board_file: str | None = None) -> list[str]:
    """:func:`geometry_text` wrapped to ``width_mm``."""
    import textwrap

    out: list[str] = []
    for line in geometry_text(board, style, board_file):
        out += textwrap.wrap(line, max(20, int(width_mm / CHAR_MM)), subsequent_indent="  ")
    return out


def _layout(
    board, paper: tuple[float, float], style: str, board_file: str | None = None
) -> tuple[tuple[float, float], tuple[float, float], list[str]]:
    """((page width, height) mm, board origin (x, y) mm on the page, the text lines) with the board and the text
    band centred; the page is turned when only that orientation fits. Raises :class:`~circcal.errors.InputError`
    when the board does not fit."""
    from circcal.errors import InputError

    x0, y0, x1, y1 = board.extent_mm()
    bw, bh = x1 - x0, y1 - y0
    for page in (paper, paper[::-1]):
        lines = _wrapped(board, style, page[0] - 2 * PAGE_MARGIN_MM, board_file)
        band = LINE_MM * len(lines) + BAND_EXTRA_MM
        if bw + 2 * PAGE_MARGIN_MM <= page[0] and bh + band + 2 * PAGE_MARGIN_MM <= page[1]:
            ox = 0.5 * (page[0] - bw) - x0
            oy = 0.5 * (page[1] - bh - band) - y0
            return page, (ox, oy), lines
    raise InputError(
        f"a {board.rows}x{board.cols} board of {bw:.0f} x {bh:.0f} mm (with its margin, and the "
        f"geometry under it) does not fit on a {paper[0]:.0f} x {paper[1]:.0f} mm page: use a larger "
        f"--paper or a smaller --pitch"
    )


def geometry_text(board, style: str, board_file: str | None = None) -> list[str]:
    """The lines printed under the board: what ``circcal calibrate`` needs to know, and how to print it.

    Parameters
    ----------
    board : Board
    style : str
        The ``--markers`` style (or where the markers came from).
    board_file : str or None
        The board description file written beside the print: the calibrate line gives ``--board`` with it (the
        options otherwise; markers of no ``--markers`` style can only be given by the file).

    Returns
    -------
    list of str
    """
    grid = f"{board.rows}x{board.cols}"
    flags = (
        f"--board {board_file}"
        if board_file is not None
        else f"--grid {grid} --pitch {board.pitch_mm:g}mm --diameter {board.diameter_mm:g}mm"
        + (" --asymmetric" if board.layout == "asymmetric" else "")
        + (f" --markers {style} --marker-diameter {board.marker_diameter_mm:g}mm" if board.has_markers else "")
    )
    lines = [
        f"circcal circle grid {grid} ({board.layout}): {board.rows} rows of {board.cols} dots, pitch "
        f"{board.pitch_mm:g} mm, dot diameter {board.diameter_mm:g} mm, margin {board.margin:g} mm"
    ]
    if board.has_markers:
        lines.append(
            f"markers ({style}, {board.marker_diameter_mm:g} mm dots) at points "
            f"{', '.join(str(i) for i in board.markers)} (OpenCV order: row by row from the top-left)"
        )
    lines.append(f"circcal calibrate IMAGES {flags}")
    lines.append("Print at 100 % (actual size, no 'fit to page'), then measure the scale bar; glue the sheet flat.")
    return lines


def draw_board(
    board, path: Path, *, paper: tuple[float, float] = PAPERS["a4"], style: str = "none", board_file: str | None = None
) -> Path:
    """Write ``board`` true to scale (module docstring).

    Parameters
    ----------
    board : Board
    path : Path
        .svg or .pdf.
    paper : tuple of float
        (width, height), mm.
    style : str
        The ``--markers`` style.
    board_file : str or None
        The board description file beside it (named in the printed calibrate line).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        Another suffix, or a board that does not fit the paper.
    """
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle, Rectangle

    from circcal.errors import InputError

    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in ("svg", "pdf"):
        raise InputError(f"board output must be .svg or .pdf, got {path.name!r}")
    (pw, ph), (ox, oy), lines = _layout(board, paper, style, board_file)
    fig = Figure(figsize=(pw / MM_PER_INCH, ph / MM_PER_INCH))
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_xlim(0.0, pw)
    ax.set_ylim(ph, 0.0)  # y down, as the board frame
    ax.set_axis_off()
    x0, y0, x1, y1 = board.extent_mm()
    ax.add_patch(Rectangle((ox + x0, oy + y0), x1 - x0, y1 - y0, facecolor="white", edgecolor="0.85", linewidth=0.2))
    for (x, y, _), r in zip(board.object_points(), board.radii_mm()):
        ax.add_patch(Circle((ox + x, oy + y), r, facecolor="black", edgecolor="none", linewidth=0))
    tx, ty = PAGE_MARGIN_MM, oy + y1 + 4.0
    for k, line in enumerate(lines):
        ax.text(tx, ty + LINE_MM * k, line, fontsize=TEXT_PT, va="top", ha="left", family="DejaVu Sans")
    bar = next(b for b in (SCALE_BAR_MM, 50.0, 20.0) if b + 15.0 <= pw - 2 * PAGE_MARGIN_MM)
    by = ty + LINE_MM * len(lines) + 3.0
    ax.add_patch(Rectangle((tx, by), bar, 1.0, facecolor="black", edgecolor="none"))
    for t in range(0, int(bar) + 1, 10):
        ax.add_patch(Rectangle((tx + t - 0.15, by - 1.5), 0.3, 1.5, facecolor="black", edgecolor="none"))
    ax.text(tx + bar + 2.0, by + 0.5, f"{bar:g} mm", fontsize=TEXT_PT, va="center", ha="left")
    meta = {"Date": None} if fmt == "svg" else {"CreationDate": None}
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format=fmt, metadata=meta)  # no bbox_inches: the page is the figure, 1 unit = 1 mm
    return path


def run(args: argparse.Namespace) -> int:
    """Write the board of the arguments to ``--out``.

    Parameters
    ----------
    args : argparse.Namespace
        The arguments :func:`add_parser`'s parser parsed.

    Returns
    -------
    int
        The exit status: 0.

    Raises
    ------
    InputError
        A bad argument or input file (the CLI prints it and exits 2).
    """
    import os
    from dataclasses import replace

    from circcal.errors import InputError
    from circcal.formats.boardfile import board_file_text
    from circcal.outputs import Outputs
    from circcal.pathnames import display_name

    if args.out.suffix.lower() not in (".svg", ".pdf"):
        raise InputError(f"--out {args.out}: the board is written as .svg or .pdf")
    if args.grid == "auto":
        raise InputError("--grid auto finds the grid in images; give --grid ROWSxCOLS or --board FILE")
    board = board_of_args(args, "board")
    if args.margin is not None:
        board = replace(board, margin_mm=args.margin)
    style = args.markers or ("board file" if args.board is not None else "none")
    described = args.out.with_suffix(".yaml")
    # the description beside the print, unless that is the --board file itself (unchanged by --margin)
    same = args.board is not None and os.path.realpath(described) == os.path.realpath(args.board)
    if same and args.margin is not None:
        raise InputError(f"--margin with --board {args.board}: the board file beside --out would change; edit it")
    if not same and described.exists() and not _written_by_circcal(described):
        raise InputError(
            f"--out {display_name(args.out)}: its board description {display_name(described)} would replace a file "
            f"circcal did not write; move that file, or give --out another name"
        )
    with Outputs(inputs=[args.board] if args.board is not None and not same else []) as outputs:
        if not same:
            outputs.file(described, "--out (its board description)").write_text(board_file_text(board))
        draw_board(board, outputs.file(args.out, "--out"), paper=args.paper, style=style, board_file=described.name)
        outputs.commit()
    print(f"wrote {args.out} and {described}: " + "; ".join(geometry_text(board, style, described.name)[:2]))
    return 0


def _written_by_circcal(path: Path) -> bool:
    """Whether ``path`` begins with the line every board description circcal writes begins with (a file that is not
    one, or not readable as text, is the user's)."""
    from circcal.formats.boardfile import HEADER

    try:
        with open(path, encoding="utf-8") as f:
            return f.readline().rstrip("\r\n") == HEADER
    except (OSError, UnicodeDecodeError):
        return False
