"""Board markers: ROS-Industrial's origin marker and circcal's own marker pattern (:func:`with_markers`).

A circle grid may carry markers (:class:`circcal.board.Board`'s ``markers``: dots of a larger diameter). Two designs:

* ``origin``: ROS-Industrial's "modified circle grid": one dot of twice the diameter at the origin. ROS-I's finder
  numbers the points in reading order from the top-left with the big dot at the bottom-left, so the marker is point
  ``(rows - 1) * cols``: circcal's point numbers are ROS-I's. The whole board must be in view (one marker cannot
  tell which part of a board is seen unless that part holds it).
* ``pattern`` (circcal's own, :func:`marker_pattern`): about one dot in seven is 1.5x larger, placed so that every
  4 x 4 window of the grid (3 x 3 on boards with a side under 5) shows a marker pattern that differs, in at least
  two dots, from the pattern of every other window position and rotation of the board. So a partial view that
  holds one such window is labelled uniquely, and one marker misread (a dot shrunk by a shadow, a marker cut by
  the image border) cannot make a wrong labelling fit: it leaves no labelling that fits, and the view is rejected
  rather than mislabelled. Markers are never neighbours (the gaps between printed dots stay wide). 1.5x (2.25x
  the area) keeps the gap to the neighbours at half a pitch or more for dots up to 0.6 pitch and is told apart
  from a normal dot by its area alone: perspective changes the area ratio of neighbouring dots by a few percent,
  threshold blur by ~10 %.
"""

from __future__ import annotations

import functools

import numpy as np

from circcal.board import Board, placements
from circcal.errors import InputError

#: Marker designs (:func:`with_markers`).
MARKER_STYLES: tuple[str, ...] = ("origin", "pattern")
#: ROS-Industrial's modified circle grid: the origin dot has twice the diameter of the others.
ORIGIN_MARKER_SCALE = 2.0
#: circcal's pattern markers are this many times the diameter of the other dots (see the module docstring).
PATTERN_MARKER_SCALE = 1.5
#: circcal's marker pattern: every window of k x k points is unique on the board, k the smallest side for which the
#: search succeeds, from this + 1 up (boards with a side of at most this + 1 use their whole short side; 3 x 3
#: windows were never found on boards of 4 x 5 and more; measured: 4 on 5x5 to 9x6, 5 on 8x10 to 20x20).
PATTERN_SMALL_WINDOW = 3
#: ... unique by at least this many marker differences (one misread marker cannot make another placement fit).
PATTERN_MIN_DISTANCE = 2
#: ... starting from about this share of the dots as markers (the search adds and removes them).
PATTERN_DENSITY = 0.15
#: ... found by a seeded simulated annealing of at most this many single changes per window side (deterministic:
#: the same board always gets the same pattern, and the pattern is written into truth.json, model.json and the
#: printed margin), cooling by this factor per change down to this temperature (in units of the shortfall).
PATTERN_TRIES = 6000
PATTERN_COOLING = 0.9995
PATTERN_MIN_TEMPERATURE = 0.05
PATTERN_SEED = 20240601
#: Boards with a side longer than this start at windows of PATTERN_SMALL_WINDOW + 2 (4 x 4 windows were never made
#: unique on 8x10, 9x9 or 10x10 boards; the failed search costs seconds).
PATTERN_LARGE_FROM = 9
#: A window side is given up when the shortfall has not fallen for this many changes.
PATTERN_PATIENCE = 1500
#: Boards with more dots than this get no pattern (the search's memory grows with the square of the dot count).
PATTERN_MAX_POINTS = 400


def _windows(board: Board, k: int) -> list[np.ndarray]:
    """Point indices of every ``k`` x ``k`` window of rows and columns (indices, OpenCV's order) of ``board``."""
    idx = np.arange(board.n_points).reshape(board.rows, board.cols)
    return [idx[i : i + k, j : j + k].ravel() for i in range(board.rows - k + 1) for j in range(board.cols - k + 1)]


def _window_pairs(board: Board, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Every ``k`` x ``k`` window of ``board`` against every other placement of its points on the board (markers
    ignored): ``(A, B)``, each (P, k*k) int32 point indices, window point ``A[p, j]`` lands on ``B[p, j]``."""
    L = board.lattice_coords()
    plain = Board(board.rows, board.cols, board.pitch_mm, board.diameter_mm, board.layout, board.margin_mm)
    A, B = [], []
    for w in _windows(board, k):
        for p in placements(plain, L[w]):
            if not np.array_equal(p.points, w):
                A.append(w)
                B.append(p.points)
    if not A:
        return np.zeros((0, k * k), np.int32), np.zeros((0, k * k), np.int32)
    return np.asarray(A, np.int32), np.asarray(B, np.int32)


def window_conflicts(board: Board, k: int, min_distance: int = PATTERN_MIN_DISTANCE) -> int:
    """How many (window, other placement) pairs break the marker pattern's promise.

    For every ``k`` x ``k`` window of ``board`` seen on its own, every placement of it other than the true one must
    disagree with the markers it shows in at least ``min_distance`` dots.

    Parameters
    ----------
    board : Board
    k : int
        The window side, points.
    min_distance : int
        Dots.

    Returns
    -------
    int
        0 = the promise holds.
    """
    A, B = _window_pairs(board, k)
    m = board.is_marker()
    return int(np.sum(np.sum(m[A] != m[B], axis=1) < min_distance))


def pattern_window(rows: int, cols: int) -> int:
    """The smallest window side for which :func:`marker_pattern` finds a pattern (it tries sides from
    :data:`PATTERN_SMALL_WINDOW` up).

    Parameters
    ----------
    rows, cols : int
        The symmetric grid.

    Returns
    -------
    int
        Points per side.

    Raises
    ------
    InputError
        As :func:`marker_pattern`.
    """
    return _pattern(rows, cols, "symmetric")[1]


@functools.lru_cache(maxsize=32)
def _pattern(rows: int, cols: int, layout: str) -> tuple[tuple[int, ...], int]:
    probe = Board(rows, cols, 10.0, 5.0 if layout != "asymmetric" else 7.0, layout)  # geometry only
    if probe.n_points > PATTERN_MAX_POINTS:
        raise InputError(
            f"circcal's marker pattern is made for boards of up to {PATTERN_MAX_POINTS} dots, not "
            f"{rows}x{cols}: use --markers origin"
        )
    L = probe.lattice_coords().astype(np.float64)
    near = (np.linalg.norm(L[:, None] - L[None], axis=-1) * probe.pitch_mm) < 1.01 * probe.spacing_mm
    np.fill_diagonal(near, False)
    first = min(
        rows, cols, PATTERN_SMALL_WINDOW + 1 if max(rows, cols) <= PATTERN_LARGE_FROM else PATTERN_SMALL_WINDOW + 2
    )
    for k in range(first, min(rows, cols) + 1):
        m = _search_pattern(
            probe,
            k,
            near,
            np.random.default_rng(PATTERN_SEED + 1000 * rows + cols + 97 * k + (7 if layout == "asymmetric" else 0)),
        )
        if m is not None:
            return tuple(int(i) for i in np.nonzero(m)[0]), k
    raise InputError(f"no marker pattern found for a {rows}x{cols} {layout} grid: use --markers origin")


def _search_pattern(board: Board, k: int, near: np.ndarray, rng: np.random.Generator) -> np.ndarray | None:
    """Markers (N,) bool with no window conflict (:func:`window_conflicts`) for windows of side ``k``, or None after
    :data:`PATTERN_TRIES` single changes. Simulated annealing on the total shortfall ``sum max(0, d - distance)``
    over all window pairs, kept up to date per changed dot (only the pairs that hold it)."""
    A, B = _window_pairs(board, k)
    N = board.n_points
    m = np.zeros(N, bool)
    for i in rng.permutation(N)[: max(1, round(PATTERN_DENSITY * N))]:
        if not np.any(near[i] & m):
            m[i] = True
    if len(A) == 0:
        return m
    d = PATTERN_MIN_DISTANCE
    # occurrences of each point in A or B (not both in the same slot: a point mapped onto itself never differs)
    slot_p, slot_j = np.nonzero(A != B)
    pts = np.concatenate([A[slot_p, slot_j], B[slot_p, slot_j]])
    pair = np.concatenate([slot_p, slot_p])
    col = np.concatenate([slot_j, slot_j])
    order = np.argsort(pts, kind="stable")
    pts, pair, col = pts[order], pair[order], col[order]
    bounds = np.searchsorted(pts, np.arange(N + 1))
    mis = np.sum(m[A] != m[B], axis=1)

    shortfall = np.maximum(0, d - mis)

    def flip(i: int) -> int:
        """Change dot ``i``; returns the change of the total shortfall."""
        lo, hi = bounds[i], bounds[i + 1]
        p, j = pair[lo:hi], col[lo:hi]
        step = np.where(m[A[p, j]] != m[B[p, j]], -1, 1)
        m[i] = not m[i]
        np.add.at(mis, p, step)
        u = np.unique(p)
        new = np.maximum(0, d - mis[u])
        delta = int(new.sum() - shortfall[u].sum())
        shortfall[u] = new
        return delta

    cost = int(shortfall.sum())
    best, since = cost, 0
    temperature = 1.0
    for _ in range(PATTERN_TRIES):
        if cost == 0:
            return m.copy()
        since += 1
        if cost < best:
            best, since = cost, 0
        elif since > PATTERN_PATIENCE:
            return None
        i = int(rng.integers(N))
        changed = [i] + ([int(j) for j in np.nonzero(near[i] & m)[0]] if not m[i] else [])
        delta = sum(flip(c) for c in changed)
        if delta <= 0 or rng.random() < np.exp(-delta / temperature):
            cost += delta
        else:
            for c in reversed(changed):
                flip(c)
        temperature = max(PATTERN_MIN_TEMPERATURE, temperature * PATTERN_COOLING)
    return m.copy() if cost == 0 else None


def marker_pattern(rows: int, cols: int, layout: str = "symmetric") -> tuple[int, ...]:
    """circcal's marker pattern for a ``rows`` x ``cols`` circle grid (module docstring).

    Point indices (OpenCV's order) such that every window of :func:`pattern_window` points per side differs from every
    other window position and rotation in at least :data:`PATTERN_MIN_DISTANCE` markers; markers are never nearest
    neighbours. Deterministic: a seeded search (:func:`_search_pattern`) for the smallest window side it can make
    unique, from :data:`PATTERN_SMALL_WINDOW` up.

    Parameters
    ----------
    rows, cols : int
    layout : str
        ``"symmetric"`` or ``"asymmetric"``.

    Returns
    -------
    tuple of int

    Raises
    ------
    InputError
        A board on which none was found or with more than :data:`PATTERN_MAX_POINTS` dots.
    """
    return _pattern(int(rows), int(cols), layout)[0]


def with_markers(board: Board, style: str, marker_diameter_mm: float | None = None) -> Board:
    """``board`` with the markers of ``style``.

    Parameters
    ----------
    board : Board
    style : str
        One of :data:`MARKER_STYLES`, or ``"none"`` (removes them): ``origin`` (ROS-Industrial's modified circle
        grid, the marker at point ``(rows - 1) * cols``, :data:`ORIGIN_MARKER_SCALE`) or ``pattern``
        (:func:`marker_pattern`, :data:`PATTERN_MARKER_SCALE`).
    marker_diameter_mm : float or None
        Overrides the marker diameter, mm.

    Returns
    -------
    Board

    Raises
    ------
    InputError
        An unknown style, a checkerboard, or no pattern (:func:`marker_pattern`).

    Examples
    --------
    >>> with_markers(Board(4, 5, 10.0, 5.0), "origin").markers
    (15,)
    """
    from dataclasses import replace

    if style == "none":
        return replace(board, markers=(), marker_diameter_mm=0.0)
    if style not in MARKER_STYLES:
        raise InputError(f"unknown marker style {style!r}; expected one of none, {', '.join(MARKER_STYLES)}")
    if board.layout == "checkerboard":
        raise InputError("a checkerboard has no dots to make markers of")
    if style == "origin":
        markers: tuple[int, ...] = ((board.rows - 1) * board.cols,)
        scale = ORIGIN_MARKER_SCALE
    else:
        markers = marker_pattern(board.rows, board.cols, board.layout)
        scale = PATTERN_MARKER_SCALE
    d = scale * board.diameter_mm if marker_diameter_mm is None else float(marker_diameter_mm)
    return replace(board, markers=markers, marker_diameter_mm=d)
