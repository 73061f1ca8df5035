"""Argument types shared by the ``circcal`` subcommands (argparse ``type=`` callables: a bad value exits 2 with the
usage line and the reason)."""
from __future__ import annotations

import argparse
import math
import re
from pathlib import Path

from circcal.errors import InputError

_UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4, "": 1.0}


def parse_length_mm(text: str) -> float:
    """'10mm', '1cm', '0.01m', '0.5in' or a bare number (mm) -> mm."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(mm|cm|m|in|)\s*", str(text))
    if not m:
        raise argparse.ArgumentTypeError(f"not a length: {text!r} (expected e.g. 10mm, 1.5cm, 0.01m)")
    value = float(m.group(1)) * _UNITS_MM[m.group(2)]
    if value <= 0:
        raise argparse.ArgumentTypeError(f"length must be positive, got {text!r}")
    return value


def parse_grid(text: str) -> tuple[int, int]:
    """'7x7' -> (rows, cols): points per column x points per row."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX*]\s*(\d+)\s*", str(text))
    if not m:
        raise argparse.ArgumentTypeError(f"grid must be ROWSxCOLS (points), e.g. 7x7 or 11x4, got {text!r}")
    return int(m.group(1)), int(m.group(2))


def positive_int(text: str) -> int:
    """'4' -> 4; at least 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """'1e-6' -> 1e-06; a finite number above 0 (NaN, inf, 0 and negatives are refused: as a tolerance they would
    make a check pass or fail whatever was measured)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a finite number above 0, got {text!r}")
    return value


def nonnegative_int(text: str) -> int:
    """'5' -> 5; 0 or more (a seed: numpy's generators refuse negative seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {text!r}")
    return value


def int_between(lo: int, hi: int):
    """An argparse type: an integer within ``lo..hi`` (a size that sets memory, e.g. a grid's pixels across)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be within {lo}..{hi}, got {text!r}")
        return value

    parse.__name__ = f"integer {lo}..{hi}"
    return parse


DIAMETER_HELP = "dot diameter, e.g. 5mm (default: half the spacing of nearest dots)"


def board_from_args(grid: tuple[int, int], pitch_mm: float, diameter_mm: float | None, asymmetric: bool):
    """The :class:`circcal.board.Board` of ``--grid``, ``--pitch``, ``--diameter``, ``--asymmetric`` (one rule for
    every subcommand). Without a diameter: half the spacing of nearest dots, ``pitch / 2`` (symmetric) or
    ``pitch * sqrt(2) / 2`` (asymmetric: OpenCV's acircles layout puts nearest dots sqrt(2) pitches apart). The
    detector uses the diameter only to bound the size of candidate dots."""
    from circcal.board import Board

    layout = "asymmetric" if asymmetric else "symmetric"
    if diameter_mm is None:
        diameter_mm = 0.5 * pitch_mm * (2 ** 0.5 if asymmetric else 1.0)
    return Board(grid[0], grid[1], pitch_mm, diameter_mm, layout)


#: The lens models of ``--lens`` (:data:`circcal.model.LENS_MODELS`' names, written out so that building the parser
#: imports no numpy; tests/test_calibrate_lens.py checks they agree), each with what it is.
LENS_CHOICES: dict[str, str] = {
    "opencv5": "OpenCV's k1, k2, p1, p2, k3",
    "rational": "OpenCV's CALIB_RATIONAL_MODEL, k1-k6, p1, p2",
    "thin-prism": "OpenCV's CALIB_THIN_PRISM_MODEL, + s1-s4",
    "fisheye": "cv2.fisheye's equidistant Kannala-Brandt k1-k4",
}


def add_lens_argument(p: argparse.ArgumentParser) -> None:
    """``--lens``: the lens model a command fits (default opencv5)."""
    p.add_argument("--lens", choices=tuple(LENS_CHOICES), default="opencv5",
                   help="lens model: " + "; ".join(f"{k} ({v})" for k, v in LENS_CHOICES.items())
                   + " (default opencv5)")
