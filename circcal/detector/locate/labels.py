"""Which board points a lattice patch shows: the placements of the patch on the board (rotation and shift, markers
agreeing), and what the detector may claim from them.

A patch (:class:`~circcal.detector.locate.lattice.Lattice`) has integer coordinates of its own; the board's points have
lattice coordinates too (:meth:`circcal.board.Board.lattice_coords`: ``(j, i)`` symmetric, ``(2j + i % 2, i)``
asymmetric). A symmetric grid's lattice steps are the board's rows and columns (patch coordinates are board
coordinates up to a rotation and shift); an asymmetric grid's nearest neighbours are its diagonals, so patch
``(a, b)`` is board ``(a + b, b - a)`` (a right-handed map). :func:`circcal.board.placements` lists every rotation
and shift that lays the patch on board points; :func:`label_patch` decides:

* exactly one placement, up to a symmetry of the board: the patch is labelled (the whole board, or part of it);
* none, because the patch does not fit: the lattice continues beyond the board (``--grid`` smaller than the board,
  "the board has more dots than 6x6: 7x7?"), or the transposed board would fit (an asymmetric ``RxC`` given for a
  ``CxR`` board);
* none, because markers disagree: a different marker layout, or markers misread;
* several that no board symmetry relates: the patch could be several parts of the board (a partial view of a board
  without markers, or one whose visible markers do not tell): rejected, never guessed -- unless the board's edge
  is seen (below).

The board's edge: lattice positions next to the patch that lie well inside the image and hold no dot (``empty``)
are off the board, unless a dot there is hidden. A placement that puts such positions on board points contradicts
them; on a marker board, where several placements fit the markers, the one with at most :data:`EDGE_TOLERANCE`
contradictions is taken when every other has at least :data:`EDGE_MARGIN` more (a whole side of the patch lands
on board points). So a view holding no marker, or a single marker that several placements share, is labelled from
the board edges in view (a board with one marker dot in a corner, seen with that corner out of frame: the two
sides in view fix the shift, the marker's absence the rotation). Boards without markers do not use it: there a
straight occluder along a row would be taken for the board's edge with nothing to contradict it.

The orientation rule of :mod:`circcal.detector.locate.grid` picks among placements related by a board symmetry (an
unmarked board seen whole); with markers there is one placement and every point keeps its ID across views.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from circcal.board import LATTICE_ROTATIONS, Board, Placement, placements

__all__ = [
    "Labelling",
    "ASYMMETRIC_FROM_PATCH",
    "EDGE_TOLERANCE",
    "EDGE_MARGIN",
    "board_frame",
    "label_patch",
    "seed_score_needed",
    "patch_grid_text",
    "nearest_labelling",
    "shape_of",
    "EXPECTED_SHARE",
    "EXPECTED_MARGIN",
]

EDGE_TOLERANCE = 1
"""A placement chosen from the board's edges may put at most this many empty positions on board points (a dot
hidden by a speck of glare or a shadow next to the patch)."""
EDGE_MARGIN = 3
"""... and every other placement must put at least this many more there (a side of the patch, three dots long at
the least: a partial view spans three rows and columns)."""

ASYMMETRIC_FROM_PATCH = np.array([[1, 1], [-1, 1]], np.int64)
"""Patch coordinates -> board lattice coordinates of an asymmetric grid: ``u`` (the patch's first step, a
diagonal) -> (1, -1), ``v`` -> (1, 1); determinant +2 > 0 keeps the handedness."""


@dataclass
class Labelling:
    """What a patch is. ``status``: ``"labelled"`` (``points`` (K,) the board point of each patch dot, in the
    patch's order; ``complete`` when every board point is in it), ``"larger"`` (the lattice continues beyond the
    board), ``"transposed"`` (the transposed grid fits), ``"markers"`` (markers disagree with every placement),
    ``"smaller"`` (a complete grid smaller than the board, nothing around it) or ``"ambiguous"`` (several
    placements). ``message``: the words for a person; ``size``: (rows, cols) of the
    patch's bounding box in board terms (for the messages); ``placements``: how many distinct labellings fit;
    ``alternatives``: for ``"ambiguous"``, each labelling that fits (the board point of each patch dot), one per
    class of placements equal up to a rotation of the board onto itself (:func:`nearest_labelling` chooses among
    them where the board's image is expected)."""

    status: str
    message: str
    points: np.ndarray | None = None
    complete: bool = False
    size: tuple[int, int] = (0, 0)
    placements: int = 0
    alternatives: tuple[np.ndarray, ...] = ()


def board_frame(board: Board, ab: np.ndarray) -> np.ndarray:
    """Board lattice coordinates (up to a rotation and shift) of patch coordinates ``ab``.

    Parameters
    ----------
    board : Board
        The board (its layout: an asymmetric grid maps by :data:`ASYMMETRIC_FROM_PATCH`).
    ab : numpy.ndarray
        (K, 2) int patch coordinates.

    Returns
    -------
    numpy.ndarray
        (K, 2) int board lattice coordinates (a new array).

    Examples
    --------
    >>> board_frame(Board(3, 4, 10.0, 5.0, "asymmetric"), [[1, 0], [0, 1]]).tolist()
    [[1, -1], [1, 1]]
    """
    ab = np.asarray(ab, np.int64).reshape(-1, 2)
    return ab @ ASYMMETRIC_FROM_PATCH.T if board.layout == "asymmetric" else ab.copy()


def seed_score_needed(board: Board) -> int:
    """How many of its 8 patch neighbours (``+-u, +-v, +-u+-v``) the best-placed dot of ``board`` has: what a seed must
    show.

    Parameters
    ----------
    board : Board
        The board.

    Returns
    -------
    int
        8 on any grid with 3 rows and columns and more; fewer on 2 x C grids and thin asymmetric ones.

    Examples
    --------
    >>> seed_score_needed(Board(3, 4, 10.0, 5.0)), seed_score_needed(Board(2, 5, 10.0, 5.0))
    (8, 5)
    """
    L = board.lattice_coords()
    occ = {tuple(p) for p in L.tolist()}
    offs = np.array([[1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [-1, -1], [1, -1], [-1, 1]], np.int64)
    offs = board_frame(board, offs)
    return int(max(sum((x + dx, y + dy) in occ for dx, dy in offs.tolist()) for x, y in L.tolist()))


def patch_grid_text(board: Board, xy: np.ndarray) -> tuple[int, int]:
    """(rows, cols) in ``--grid`` terms of the bounding box of board-frame lattice points ``xy``.

    Parameters
    ----------
    board : Board
        The board; of the two rotations of the box, the one that best matches its orientation (rows along y) is
        given.
    xy : numpy.ndarray
        (K, 2) int board-frame lattice coordinates (:func:`board_frame`).

    Returns
    -------
    tuple of int
        ``(rows, cols)``.

    Examples
    --------
    >>> patch_grid_text(Board(3, 4, 10.0, 5.0), np.array([[0, 0], [3, 2]]))
    (3, 4)
    """
    span = xy.max(axis=0) - xy.min(axis=0)
    if board.layout == "asymmetric":
        rows, cols = int(span[1]) + 1, int(span[0]) // 2 + 1
        alt = (int(span[0]) + 1, int(span[1]) // 2 + 1)
    else:
        rows, cols = int(span[1]) + 1, int(span[0]) + 1
        alt = (cols, rows)
    a = abs(rows - board.rows) + abs(cols - board.cols)
    b = abs(alt[0] - board.rows) + abs(alt[1] - board.cols)
    return (rows, cols) if a <= b else alt


def _classes(board: Board, fits: list[Placement]) -> list[list[Placement]]:
    """Placements grouped by the labelling they give up to a rotation of the board onto itself."""
    syms = [s.perm for s in board.symmetries(reflections=False)]
    groups: list[list[Placement]] = []
    for p in fits:
        for g in groups:
            if any(np.array_equal(perm[g[0].points], p.points) for perm in syms):
                g.append(p)
                break
        else:
            groups.append([p])
    return groups


def label_patch(
    board: Board,
    ab: np.ndarray,
    flags: np.ndarray | None = None,
    *,
    closed: bool = False,
    empty: np.ndarray | None = None,
) -> Labelling:
    """Label a patch with coordinates ``ab`` on ``board`` (module docstring).

    The ``points`` of a labelled patch follow one labelling; for an unmarked board seen whole that is one of the
    board's symmetric labellings (the caller applies the orientation rule).

    Parameters
    ----------
    board : Board
        The board.
    ab : numpy.ndarray
        (K, 2) int patch coordinates.
    flags : numpy.ndarray or None, optional
        (K,) int: 1 a dot seen as a marker, 0 a plain dot, -1 unknown; ``None`` = all unknown (a board without
        markers ignores them).
    closed : bool, optional
        Every lattice position around the patch lies in the image and holds no dot (so a complete patch smaller than
        the board is a whole, smaller board rather than a partial view).
    empty : numpy.ndarray or None, optional
        (E, 2) int patch coordinates of positions next to the patch that lie well inside the image and hold no dot:
        the board's edge where it is in view (module docstring; used on marker boards only).

    Returns
    -------
    Labelling
        ``"labelled"`` with the board point of each patch dot, or why not (``"larger"``, ``"transposed"``,
        ``"layout"`` (a whole grid of the other layout), ``"markers"``, ``"smaller"``, ``"ambiguous"``) with a
        message for a person.

    Examples
    --------
    >>> board = Board(3, 4, 10.0, 5.0)
    >>> lab = label_patch(board, np.array([[i, j] for j in range(3) for i in range(4)]))
    >>> lab.status, lab.complete
    ('labelled', True)
    """
    xy = board_frame(board, ab)
    K = len(xy)
    rows, cols = patch_grid_text(board, xy)
    grid = f"{board.rows}x{board.cols}"
    geometric = placements(board, xy)
    if not geometric:
        if _fits(board, xy, transposed=True):
            return Labelling(
                "transposed",
                f"--grid {grid} does not match the dots, but {board.cols}x{board.rows} "
                f"does: the board is {board.cols}x{board.rows}?",
                size=(rows, cols),
            )
        r, c, layout = shape_of(ab)
        if layout is not None and layout != board.layout and r * c == board.n_points:  # the flag forgotten
            flag = "--asymmetric" if layout == "asymmetric" else "without --asymmetric"
            flag = flag if (r, c) == (board.rows, board.cols) else f"--grid {r}x{c} {flag}"
            return Labelling(
                "layout",
                f"the dots form a whole {r}x{c} {layout} grid, not {'an' if board.layout == 'asymmetric' else 'a'} "
                f"{board.layout} {grid} one: {flag}?",
                size=(r, c),
            )
        bigger = rows >= board.rows and cols >= board.cols or rows >= board.cols and cols >= board.rows
        if bigger or rows * cols > board.n_points or K > board.n_points:
            return Labelling("larger", f"the board has more dots than {grid}: {rows}x{cols}?", size=(rows, cols))
        return Labelling(
            "larger", f"the dots form a {rows}x{cols} lattice that does not fit a {grid} grid", size=(rows, cols)
        )
    if not board.has_markers:
        flags = None
    fits = placements(board, xy, flags) if flags is not None else geometric
    if not fits:
        n_mk = int(np.sum(np.asarray(flags) == 1))
        return Labelling(
            "markers",
            f"the {n_mk} marker dots seen match no part of the board's marker layout "
            f"(another marker layout, or a marker misread)",
            size=(rows, cols),
        )
    classes = _classes(board, fits)
    complete = K == board.n_points
    if len(classes) > 1 and board.has_markers and empty is not None and len(empty):
        classes = _edge_decided(board, classes, board_frame(board, empty))
    if len(classes) > 1:
        if closed and K == _nodes_in_box(board, xy):
            return Labelling(
                "smaller",
                f"the dots form a complete {rows}x{cols} grid with none around it: the board "
                f"is {rows}x{cols}, not {grid}?",
                size=(rows, cols),
                placements=len(classes),
            )
        why = (
            "a board without markers: a marker board (circcal board --markers pattern) labels partial views"
            if not board.has_markers
            else "its markers in view do not tell which part of the board this is"
        )
        return Labelling(
            "ambiguous",
            f"{K} of {board.n_points} dots seen ({rows}x{cols}): {len(classes)} "
            f"parts of the board fit them ({why}); view rejected rather than guessed",
            size=(rows, cols),
            placements=len(classes),
            alternatives=tuple(g[0].points.copy() for g in classes),
        )
    p = classes[0][0]
    return Labelling("labelled", "", p.points.copy(), complete, (rows, cols), 1)


#: :func:`nearest_labelling` decides when the nearest labelling's RMS distance to the expected image is below this
#: share of the patch's dot spacing (another placement is a shift of at least one pitch) ...
EXPECTED_SHARE = 0.25
#: ... and the next nearest is at least this many times farther (the rule of the rig's symmetry choice).
EXPECTED_MARGIN = 3.0


def nearest_labelling(
    board: Board, alternatives: Sequence[np.ndarray], pix: np.ndarray, expected: np.ndarray
) -> np.ndarray | None:
    """The labelling of an ambiguous patch whose board points lie where the board's image is expected.

    A part of an unmarked board fits several places on it (:func:`label_patch`: ``"ambiguous"``); where the board's
    image is known from elsewhere (another camera of a rig at the same instant) the one near it is the part seen.

    Parameters
    ----------
    board : Board
    alternatives : sequence of ndarray
        Each (K,) the board point of each patch dot (:attr:`Labelling.alternatives`).
    pix : ndarray, shape (K, 2)
        The patch dots' pixel positions, px.
    expected : ndarray, shape (N, 2)
        Where each board point is expected in the image, px (NaN: not known).

    Returns
    -------
    ndarray or None
        (K,) the chosen labelling (or one of its rotations onto itself: the orientation rule decides among those);
        None unless one is within :data:`EXPECTED_SHARE` of the dot spacing and the others :data:`EXPECTED_MARGIN`
        times farther.
    """
    if len(pix) < 2 or not alternatives:
        return None
    d = np.linalg.norm(pix[:, None, :] - pix[None, :, :], axis=2)
    np.fill_diagonal(d, np.inf)
    spacing = float(np.median(np.min(d, axis=1)))
    syms = [s.perm for s in board.symmetries(reflections=False)]
    rms = []
    for pts in alternatives:
        best = np.inf
        for perm in syms:
            e = pix - expected[perm[pts]]
            ok = np.all(np.isfinite(e), axis=1)
            if ok.sum() >= max(3, len(pix) // 2):
                best = min(best, float(np.sqrt(np.mean(np.sum(e[ok] ** 2, axis=1)))))
        rms.append(best)
    order = np.argsort(rms)
    first = float(rms[order[0]])
    second = float(rms[order[1]]) if len(rms) > 1 else np.inf
    if first < EXPECTED_SHARE * spacing and second > EXPECTED_MARGIN * first:
        return np.asarray(alternatives[int(order[0])]).copy()
    return None


def _edge_decided(board: Board, classes: list[list[Placement]], empty_xy: np.ndarray) -> list[list[Placement]]:
    """The one class of placements the board's edges in view single out (module docstring), or ``classes``."""
    nodes = {tuple(q) for q in board.lattice_coords().tolist()}
    counts = []
    for group in classes:
        best = None
        for p in group:
            on = empty_xy @ LATTICE_ROTATIONS[p.quarter].T + np.asarray(p.shift)
            n = sum(tuple(q) in nodes for q in on.tolist())
            best = n if best is None else min(best, n)
        counts.append(best)
    order = np.argsort(counts, kind="stable")
    first, second = counts[order[0]], counts[order[1]]
    if first <= EDGE_TOLERANCE and second >= first + EDGE_MARGIN:
        return [classes[int(order[0])]]
    return classes


def _nodes_in_box(board: Board, xy: np.ndarray) -> int:
    """Lattice nodes of ``board``'s kind (asymmetric: same parity as the patch's) in the bounding box of ``xy``."""
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
    if board.layout != "asymmetric":
        return int(gx.size)
    return int(np.sum((gx + gy) % 2 == (xy[0, 0] + xy[0, 1]) % 2))


def _fits(board: Board, xy: np.ndarray, *, transposed: bool) -> bool:
    """Whether the patch fits the transposed board (rows and columns swapped; only differs for asymmetric grids,
    where ``RxC`` and ``CxR`` are different boards)."""
    if not transposed or board.layout != "asymmetric" or board.rows == board.cols:
        return False
    t = Board(board.cols, board.rows, board.pitch_mm, board.diameter_mm, board.layout, board.margin_mm)
    return bool(placements(t, xy))


def shape_of(ab: np.ndarray) -> tuple[int, int, str | None]:
    """The grid a lattice patch's coordinates form.

    Parameters
    ----------
    ab : numpy.ndarray
        (K, 2) int patch coordinates (:class:`~circcal.detector.locate.lattice.Lattice`).

    Returns
    -------
    rows, cols : int
        The grid in ``--grid`` terms (conventions: module docstring); for a patch of neither shape, its bounding box.
    layout : str or None
        ``"symmetric"`` (a full rectangle), ``"asymmetric"`` (a full staggered rectangle), ``None`` (neither).

    Examples
    --------
    >>> shape_of(np.array([[i, j] for j in range(3) for i in range(5)]))
    (3, 5, 'symmetric')
    """
    ab = np.asarray(ab, np.int64).reshape(-1, 2)
    K = len(ab)
    span = np.ptp(ab, axis=0) + 1
    if K == int(span[0] * span[1]) and len({tuple(q) for q in ab.tolist()}) == K:
        r, c = sorted(int(s) for s in span)
        return r, c, "symmetric"
    xy = ab @ ASYMMETRIC_FROM_PATCH.T
    sx, sy = (int(s) for s in np.ptp(xy, axis=0) + 1)
    options = []  # (rows, cols): rows along one board axis, each of cols dots at every other node
    for across, along in ((sx, sy), (sy, sx)):
        if across >= 4 and across % 2 == 0 and along >= 2 and K == along * across // 2:  # 2 dots a row at least
            options.append((along, across // 2))
    # both readings of a staggered rectangle are one board only where a rotation (no mirror) puts every dot on it:
    # OpenCV's rows start on the even nodes, and a quarter turn of a 6x9 board is no 18x3 board
    fit = [o for o in options if placements(Board(o[0], o[1], 1.0, 0.5, "asymmetric"), xy)]
    if fit or options:
        r, c = max(fit or options)
        return r, c, "asymmetric"
    r, c = sorted(int(s) for s in span)
    return r, c, None
