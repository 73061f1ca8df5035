"""Board description files (``--board FILE``): circcal's own YAML/JSON form, ROS-Industrial's target YAML,
Kalibr's circle-grid target YAML and BoofCV's calibration-target YAML, read into one :class:`circcal.board.Board`;
:func:`board_file_text` writes circcal's form (``circcal board`` writes it beside the printable target).

circcal's form (YAML, or the same keys as JSON; unknown keys are refused by name; lengths in mm)::

    rows: 8                  # rows of points (OpenCV's patternSize is (cols, rows))
    cols: 11                 # points per row
    layout: symmetric        # or asymmetric (OpenCV's acircles; pitch_mm is then its squareSize)
    pitch_mm: 20
    diameter_mm: 8           # optional: half the nearest-dot spacing, as --diameter
    margin_mm: 20            # optional: one pitch
    markers:                 # optional: the larger dots, by row and column
      - {row: 0, col: 0, diameter_mm: 16}

Point ``(row, col)`` is point ``row * cols + col`` in OpenCV's order, at ``(col * pitch, row * pitch, 0)`` on a
symmetric grid and ``((2 col + row % 2) * pitch, row * pitch, 0)`` on an asymmetric one (:mod:`circcal.board`).
Markers may sit anywhere on the grid but share one diameter (a :class:`~circcal.board.Board` has one marker
diameter; markers of several sizes are refused in one line).

Foreign forms, read as their tools define them:

* **ROS-Industrial** ``industrial_extrinsic_cal`` targets (``static_targets:`` / ``moving_targets:``, one
  circle-grid target among them): ``target_type`` 1 (CircleGrid) or 2 (ModifiedCircleGrid: one dot of twice the
  diameter at the bottom-left origin, circcal's ``--markers origin``; 1.5x where twice would nearly touch its
  neighbours, as ROS-Industrial's older finder expects), ``target_rows`` (rows) and ``target_cols``
  (points per row; ROS-I's finder calls ``findCirclesGrid`` with ``Size(cols, rows)``), ``circle_dia`` and
  ``spacing`` in **metres**; without ``spacing``, the spacing of the listed ``points`` (``pnt: [x, y, z]``,
  metres). ROS-Industrial's newer ``industrial_calibration`` ``target_finder:`` block (``type:
  ModifiedCircleGridTargetFinder``, ``rows``, ``cols``, ``spacing`` in metres) is read too; it states no dot
  diameter, which then is half the spacing, as without ``--diameter``.
* **Kalibr** (``target_type: 'circlegrid'``): ``targetRows``, ``targetCols`` (``findCirclesGrid``'s
  ``Size(cols, rows)``), ``spacingMeters`` in **metres** (on an asymmetric grid OpenCV's squareSize: Kalibr places
  point (r, c) at ``((2c + r % 2) s, r s)``), ``asymmetricGrid`` (bool). Kalibr states no dot diameter: half the
  nearest-dot spacing. (Kalibr's symmetric points are ``(s r, s c)``, the transpose of OpenCV's frame; the dots and
  their order are the same, so the camera calibrated is the same.)
* **BoofCV** (``boofcv.alg.fiducial.calib.ConfigCalibrationTarget:`` with ``type: CIRCLE_GRID``, as BoofCV serialises
  its target config): ``grid.numRows`` (rows), ``grid.numCols`` (points per row), ``grid.shapeDistance`` (the
  centres' spacing) and ``grid.shapeSize`` (the dot diameter), in **no stated unit** (BoofCV's are "consistent
  units"): read as mm, and the reader warns that poses and distances come out in the file's unit (the intrinsics do
  not depend on it). BoofCV's ``CIRCLE_HEXAGONAL`` grid (rows ``d sin 60`` apart, an equilateral lattice) is not
  OpenCV's asymmetric grid (rows ``s`` apart) and is refused by name.

The file's size, nesting, integer digits, repeated keys and YAML anchors/aliases are bounded as for camera files
(:mod:`circcal.formats.limits`, :mod:`circcal.jsonio`). Every refusal is one :class:`~circcal.errors.InputError`
line naming the file and the field.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from circcal.board import MAX_GRID_SIDE, MAX_LENGTH_MM, MIN_LENGTH_MM, Board, Layout
from circcal.errors import InputError
from circcal.formats.limits import JSON_LIMITS, MAX_MODEL_FILE_BYTES, check_nesting, integer, load_yaml, number, show
from circcal.jsonio import parse_json, read_text
from circcal.markers import ORIGIN_MARKER_SCALE, with_markers

__all__ = ["BOARD_KEYS", "MARKER_KEYS", "HEADER", "read_board_file", "board_from_data", "board_file_text"]

#: The first line of every board description circcal writes (how a command knows a file beside a print is its own).
HEADER = "# circcal board description (--board FILE): lengths in mm; point (row, col) is OpenCV's point row*cols+col"

#: The keys of circcal's form (:func:`board_from_data`).
BOARD_KEYS: tuple[str, ...] = ("rows", "cols", "layout", "pitch_mm", "diameter_mm", "margin_mm", "markers")
#: The keys of one marker entry.
MARKER_KEYS: tuple[str, ...] = ("row", "col", "diameter_mm")
#: Millimetres per metre (ROS-Industrial's and Kalibr's lengths are metres).
MM_PER_M = 1000.0
#: The top-level key of BoofCV's serialised calibration-target config.
BOOFCV_TARGET = "boofcv.alg.fiducial.calib.ConfigCalibrationTarget"
#: ROS-Industrial's target types: 0 chessboard, 1 circle grid, 2 modified circle grid (one big origin dot).
ROSI_CIRCLE_GRID = 1
ROSI_MODIFIED_CIRCLE_GRID = 2
#: ROS-Industrial's origin dot where twice the diameter does not fit the spacing (its older finder's 1.5x).
ROSI_SMALL_ORIGIN_SCALE = 1.5


def read_board_file(path: str | Path) -> Board:
    """The board a description file describes (module docstring: circcal's form, ROS-Industrial's, Kalibr's).

    Parameters
    ----------
    path : str or Path
        A YAML or JSON file (told apart by its content, not its name).

    Returns
    -------
    Board

    Raises
    ------
    InputError
        Naming the file (and the field): missing, unreadable, too large, malformed, of no known form, or a value
        the board refuses.

    Examples
    --------
    >>> read_board_file("board.yaml").rows  # doctest: +SKIP
    8
    """
    p = Path(path)
    text = read_text(p, "board file", max_bytes=MAX_MODEL_FILE_BYTES)
    try:
        try:
            data = parse_json(text, **JSON_LIMITS) if text.lstrip().startswith(("{", "[")) else None
        except InputError:  # not JSON: YAML's flow style ({rows: 8, ...}, as the detector's hint writes it)
            data = None
        if data is None:
            check_nesting(text)
            data = load_yaml(text)
        return board_from_data(data)
    except InputError as exc:
        raise InputError(f"board file {p}: {_unbranded(str(exc))}") from None


def _unbranded(message: str) -> str:
    """The limits' messages speak of camera files; here the file is a board file."""
    return message.replace("camera files need none", "board files need none")


def board_from_data(data: Any) -> Board:
    """The board of a parsed description (module docstring), whichever of the three forms it is.

    Parameters
    ----------
    data : object
        The parsed YAML or JSON document.

    Returns
    -------
    Board

    Raises
    ------
    InputError
        Naming the field (the caller adds the file).

    Examples
    --------
    >>> board_from_data({"rows": 4, "cols": 5, "pitch_mm": 10, "markers": [{"row": 3, "col": 0,
    ...     "diameter_mm": 8}]}).markers
    (15,)
    """
    if not isinstance(data, dict):
        raise InputError(f"expected a mapping of board fields (rows, cols, pitch_mm, ...), got {_kind(data)}")
    if "target_type" in data:
        return _kalibr(data)
    if "static_targets" in data or "moving_targets" in data:
        return _rosi_targets(data)
    if "target_finder" in data:
        return _rosi_finder(data["target_finder"])
    if BOOFCV_TARGET in data:
        return _boofcv(data[BOOFCV_TARGET])
    return _circcal(data)


def _kind(v: Any) -> str:
    """A value's kind, in words."""
    if v is None:
        return "nothing"
    if isinstance(v, (list, tuple)):
        return "a list"
    if isinstance(v, str):
        return f"the text {show(v)}"
    return show(v)


def _length_mm(v: Any, field: str, scale: float = 1.0, unit: str = "mm") -> float:
    """A positive length ``v * scale`` in mm within the board's limits; the message shows the file's own unit."""
    lo, hi = MIN_LENGTH_MM / scale, MAX_LENGTH_MM / scale
    return number(v, field, lo, hi, f" {unit}") * scale


def _side(v: Any, field: str) -> int:
    return integer(v, field, 2, MAX_GRID_SIDE)


def _diameter_default(pitch_mm: float, layout: str) -> float:
    """Half the nearest-dot spacing (what ``--diameter`` defaults to)."""
    return 0.5 * pitch_mm * (math.sqrt(2.0) if layout == "asymmetric" else 1.0)


def _circcal(data: dict[str, Any]) -> Board:
    """circcal's form."""
    unknown = [k for k in data if k not in BOARD_KEYS]
    if unknown:
        raise InputError(
            f"unknown field {show(unknown[0])}: a board description holds {', '.join(BOARD_KEYS)} "
            "(or is ROS-Industrial's target YAML, Kalibr's with target_type: circlegrid, or BoofCV's target config)"
        )
    for key in ("rows", "cols", "pitch_mm"):
        if key not in data:
            raise InputError(f"field {key!r} is missing (a board description needs rows, cols and pitch_mm)")
    rows, cols = _side(data["rows"], "rows"), _side(data["cols"], "cols")
    layout = data.get("layout", "symmetric")
    if layout not in ("symmetric", "asymmetric"):
        raise InputError(f"layout must be symmetric or asymmetric, got {show(layout)}")
    pitch = _length_mm(data["pitch_mm"], "pitch_mm")
    diameter = (
        _length_mm(data["diameter_mm"], "diameter_mm")
        if data.get("diameter_mm") is not None
        else _diameter_default(pitch, layout)
    )
    margin = _length_mm(data["margin_mm"], "margin_mm") if data.get("margin_mm") is not None else None
    markers, marker_d = _markers(data.get("markers"), rows, cols)
    board = _named(lambda: Board(rows, cols, pitch, diameter, layout, margin), "diameter_mm")
    return _named(lambda: replace(board, markers=markers, marker_diameter_mm=marker_d), "markers")


def _named(make: Callable[[], Board], field: str) -> Board:
    """``make()``, a refusal of the board's own checks prefixed with the field it concerns."""
    try:
        return make()
    except InputError as exc:
        raise InputError(f"{field}: {exc}") from None


def _markers(entries: Any, rows: int, cols: int) -> tuple[tuple[int, ...], float]:
    """(point indices, the one marker diameter mm) of a ``markers`` list (None or [] for none)."""
    if entries is None:
        return (), 0.0
    if not isinstance(entries, list):
        raise InputError(f"markers must be a list of {{row, col, diameter_mm}}, got {_kind(entries)}")
    seen: dict[int, int] = {}
    diameters: list[float] = []
    for k, m in enumerate(entries):
        field = f"markers[{k}]"
        if not isinstance(m, dict):
            raise InputError(f"{field} must be a mapping {{row, col, diameter_mm}}, got {_kind(m)}")
        unknown = [key for key in m if key not in MARKER_KEYS]
        if unknown:
            raise InputError(f"{field}: unknown field {show(unknown[0])} (a marker holds row, col, diameter_mm)")
        for key in MARKER_KEYS:
            if key not in m:
                raise InputError(f"{field}.{key} is missing (a marker holds row, col, diameter_mm)")
        r = integer(m["row"], f"{field}.row", 0, rows - 1)
        c = integer(m["col"], f"{field}.col", 0, cols - 1)
        d = _length_mm(m["diameter_mm"], f"{field}.diameter_mm")
        i = r * cols + c
        if i in seen:
            raise InputError(f"{field} repeats markers[{seen[i]}] (row {r}, col {c})")
        seen[i] = k
        if diameters and d != diameters[0]:
            raise InputError(
                f"{field}.diameter_mm is {d:g} mm, markers[0]'s {diameters[0]:g} mm: circcal's boards have one "
                "marker diameter (give every marker the same)"
            )
        diameters.append(d)
    return tuple(seen), (diameters[0] if diameters else 0.0)


def _kalibr(data: dict[str, Any]) -> Board:
    """Kalibr's target YAML (module docstring)."""
    kind = data["target_type"]
    if kind != "circlegrid":
        raise InputError(
            f"target_type {show(kind)}: Kalibr's circle grids only (target_type: circlegrid); circcal finds dots"
        )
    for key in ("targetRows", "targetCols", "spacingMeters"):
        if key not in data:
            raise InputError(f"field {key!r} is missing (Kalibr's circlegrid target)")
    rows, cols = _side(data["targetRows"], "targetRows"), _side(data["targetCols"], "targetCols")
    asym = data.get("asymmetricGrid", False)
    if not isinstance(asym, bool):
        raise InputError(f"asymmetricGrid must be true or false, got {_kind(asym)}")
    layout: Layout = "asymmetric" if asym else "symmetric"
    pitch = _length_mm(data["spacingMeters"], "spacingMeters", MM_PER_M, "m")
    return Board(rows, cols, pitch, _diameter_default(pitch, layout), layout)


def _boofcv(target: Any) -> Board:
    """BoofCV's calibration-target YAML (module docstring)."""
    at = BOOFCV_TARGET
    if not isinstance(target, dict):
        raise InputError(f"{at} must be a mapping (type, grid), got {_kind(target)}")
    kind = target.get("type")
    if kind == "CIRCLE_HEXAGONAL":
        raise InputError(
            f"{at}.type CIRCLE_HEXAGONAL: BoofCV's hexagonal grid (rows spacing * sin 60 apart) is not a layout "
            f"circcal has (a symmetric grid, or OpenCV's asymmetric one with rows spacing apart)"
        )
    if kind != "CIRCLE_GRID":
        raise InputError(f"{at}.type {show(kind)}: BoofCV's circle grids only (type: CIRCLE_GRID); circcal finds dots")
    grid = target.get("grid")
    if not isinstance(grid, dict):
        raise InputError(f"{at}.grid must be a mapping (numRows, numCols, shapeSize, shapeDistance)")
    for key in ("numRows", "numCols", "shapeDistance"):
        if key not in grid:
            raise InputError(f"{at}.grid.{key} is missing (BoofCV's circle-grid target)")
    rows, cols = _side(grid["numRows"], f"{at}.grid.numRows"), _side(grid["numCols"], f"{at}.grid.numCols")
    pitch = _length_mm(grid["shapeDistance"], f"{at}.grid.shapeDistance", 1.0, "(no unit, read as mm)")
    diameter = (
        _length_mm(grid["shapeSize"], f"{at}.grid.shapeSize", 1.0, "(no unit, read as mm)")
        if "shapeSize" in grid
        else _diameter_default(pitch, "symmetric")
    )
    warnings.warn(
        f"BoofCV's target file states no unit: its lengths are read as mm (spacing {_num(pitch)}, dots "
        f"{_num(diameter)}); poses and distances come out in the file's unit, the intrinsics do not depend on it",
        RuntimeWarning,
        stacklevel=2,
    )
    return _named(lambda: Board(rows, cols, pitch, diameter, "symmetric"), f"{at}.grid")


def _rosi_targets(data: dict[str, Any]) -> Board:
    """ROS-Industrial's ``industrial_extrinsic_cal`` targets file: its one circle-grid target."""
    found: list[tuple[str, dict[str, Any]]] = []
    for group in ("static_targets", "moving_targets"):
        targets = data.get(group)
        if targets is None:
            continue
        if not isinstance(targets, list):
            raise InputError(f"{group} must be a list of targets, got {_kind(targets)}")
        for k, t in enumerate(targets):
            if not isinstance(t, dict):
                raise InputError(f"{group}[{k}] must be a mapping of target fields, got {_kind(t)}")
            if t.get("target_type") in (ROSI_CIRCLE_GRID, ROSI_MODIFIED_CIRCLE_GRID):
                found.append((f"{group}[{k}]", t))
    if len(found) != 1:
        names = ", ".join(f"{f} ({show(t.get('target_name'))})" for f, t in found)
        raise InputError(
            "no circle-grid target (target_type 1 or 2) in static_targets / moving_targets"
            if not found
            else f"{len(found)} circle-grid targets ({names}): give a file with one"
        )
    at, t = found[0]
    for key in ("target_rows", "target_cols", "circle_dia"):
        if key not in t:
            raise InputError(f"{at}.{key} is missing (ROS-Industrial's circle-grid target)")
    rows, cols = _side(t["target_rows"], f"{at}.target_rows"), _side(t["target_cols"], f"{at}.target_cols")
    diameter = _length_mm(t["circle_dia"], f"{at}.circle_dia", MM_PER_M, "m")
    if t.get("spacing") is not None:
        pitch = _length_mm(t["spacing"], f"{at}.spacing", MM_PER_M, "m")
    elif t.get("points") is not None:
        pitch = _points_spacing(t["points"], f"{at}.points", rows, cols)
    else:
        raise InputError(f"{at}.spacing is missing (and no points to take it from)")
    board = _named(lambda: Board(rows, cols, pitch, diameter, "symmetric"), f"{at}.circle_dia")
    return _rosi_origin(board, f"{at}.circle_dia") if t["target_type"] == ROSI_MODIFIED_CIRCLE_GRID else board


def _rosi_origin(board: Board, field: str) -> Board:
    """``board`` with ROS-Industrial's origin dot (point ``(rows - 1) * cols``): twice the dots' diameter, as
    ROS-Industrial's target generator prints it, or 1.5x (what its older finder expects) where twice would leave the
    dots too little gap; the marker test tells either size from the dots with 1.5x declared."""
    for scale in (ORIGIN_MARKER_SCALE, ROSI_SMALL_ORIGIN_SCALE):
        try:
            return with_markers(board, "origin", scale * board.diameter_mm)
        except InputError as exc:
            why = exc
    raise InputError(f"{field}: {why}")


def _points_spacing(points: Any, field: str, rows: int, cols: int) -> float:
    """The spacing (mm) of ROS-Industrial's listed target points (``- pnt: [x, y, z]``, metres), which must be the
    ``rows * cols`` nodes of a square lattice of that spacing."""
    if not isinstance(points, list) or len(points) != rows * cols:
        n = len(points) if isinstance(points, list) else None
        raise InputError(
            f"{field} must list target_rows x target_cols = {rows * cols} points"
            + (f", got {n}" if n is not None else f", got {_kind(points)}")
        )
    xyz = np.empty((len(points), 3))
    for k, p in enumerate(points):
        v = p.get("pnt") if isinstance(p, dict) else None
        if not isinstance(v, list) or len(v) != 3:
            raise InputError(f"{field}[{k}] must be {{pnt: [x, y, z]}} (metres), got {_kind(p)}")
        xyz[k] = [number(x, f"{field}[{k}].pnt") for x in v]
    steps = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    steps = steps[steps > 0]
    if steps.size == 0:
        raise InputError(f"{field}: every point is the same")
    s = float(steps.min())
    lattice = (xyz - xyz.min(axis=0)) / s
    if np.any(np.abs(lattice - np.rint(lattice)) > 1e-3) or len({tuple(q) for q in np.rint(lattice).tolist()}) != len(
        xyz
    ):
        raise InputError(f"{field}: the points are not the distinct nodes of a grid of spacing {s:g} m")
    return _length_mm(s, f"{field} spacing", MM_PER_M, "m")


def _rosi_finder(block: Any) -> Board:
    """ROS-Industrial's ``industrial_calibration`` ``target_finder:`` block (a modified circle grid)."""
    if not isinstance(block, dict):
        raise InputError(f"target_finder must be a mapping (type, rows, cols, spacing), got {_kind(block)}")
    kind = block.get("type")
    if kind != "ModifiedCircleGridTargetFinder":
        raise InputError(f"target_finder.type {show(kind)}: circcal reads ModifiedCircleGridTargetFinder only")
    for key in ("rows", "cols", "spacing"):
        if key not in block:
            raise InputError(f"target_finder.{key} is missing")
    rows, cols = _side(block["rows"], "target_finder.rows"), _side(block["cols"], "target_finder.cols")
    pitch = _length_mm(block["spacing"], "target_finder.spacing", MM_PER_M, "m")
    return _rosi_origin(Board(rows, cols, pitch, _diameter_default(pitch, "symmetric")), "target_finder.spacing")


def _num(v: float) -> str:
    """A float as YAML reads it back exactly (``20``, ``0.5``; never an exponent, which YAML 1.1 reads as text)."""
    s = repr(float(v))
    if "e" in s or "E" in s:
        s = f"{float(v):.20f}".rstrip("0")
    return s[:-2] if s.endswith(".0") else s.rstrip(".")


def board_file_text(board: Board) -> str:
    """circcal's form of ``board`` (module docstring), as YAML that :func:`read_board_file` reads back exactly.

    Parameters
    ----------
    board : Board
        A circle grid (symmetric or asymmetric).

    Returns
    -------
    str
        YAML text, with a comment naming the conventions.

    Raises
    ------
    InputError
        A checkerboard (the file describes circle grids).

    Examples
    --------
    >>> print(board_file_text(Board(4, 5, 10.0, 4.0, markers=(15,), marker_diameter_mm=8.0)), end="")
    # circcal board description (--board FILE): lengths in mm; point (row, col) is OpenCV's point row*cols+col
    rows: 4
    cols: 5
    layout: symmetric
    pitch_mm: 10
    diameter_mm: 4
    markers:
      - {row: 3, col: 0, diameter_mm: 8}
    """
    if board.layout == "checkerboard":
        raise InputError("a board description file describes circle grids, not a checkerboard")
    lines = [
        HEADER,
        f"rows: {board.rows}",
        f"cols: {board.cols}",
        f"layout: {board.layout}",
        f"pitch_mm: {_num(board.pitch_mm)}",
        f"diameter_mm: {_num(board.diameter_mm)}",
    ]
    if board.margin_mm is not None:
        lines.append(f"margin_mm: {_num(board.margin_mm)}")
    if board.markers:
        lines.append("markers:")
        for i in board.markers:
            r, c = divmod(i, board.cols)
            lines.append(f"  - {{row: {r}, col: {c}, diameter_mm: {_num(board.marker_diameter_mm)}}}")
    return "\n".join(lines) + "\n"
