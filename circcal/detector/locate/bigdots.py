"""Dots larger than their neighbours on a board given without markers: likely markers, named with the board line
that describes them (:func:`big_dots`, :func:`big_dot_words`, :func:`big_dot_notes`; out of
:mod:`circcal.detector.locate.recognise`, which says them in its refusals and notes)."""

from __future__ import annotations

import numpy as np

from circcal.board import Board

__all__ = ["big_dots", "big_dot_words", "big_dot_notes", "BIG_DOT_AREA", "BIG_DOT_MAX_SHARE"]

BIG_DOT_AREA = 1.8
"""On a board given without markers, a dot whose area is this many times the median of its lattice neighbours' (and
of the view's dots: none of them cut by the image border) is named as a likely marker: perspective and blur
change neighbouring dots' areas by tens of percent; markers are printed 1.5-2x the diameter (2.25-4x the area)."""
BIG_DOT_MAX_SHARE = 0.25
"""... when such dots are at most this share of the view's (more is a board of mixed dots, not a few markers)."""


def big_dots(coords: np.ndarray, area: np.ndarray, cut: np.ndarray) -> tuple[np.ndarray, float]:
    """The dots much larger than the rest (:data:`BIG_DOT_AREA`), by their lattice neighbours.

    Parameters
    ----------
    coords : numpy.ndarray
        (K, 2) int lattice coordinates of the dots (patch or board (row, col)).
    area : numpy.ndarray
        (K,) float their areas, px^2.
    cut : numpy.ndarray
        (K,) bool, cut by the image border (never counted).

    Returns
    -------
    big : numpy.ndarray
        (B,) int positions into ``coords`` (none when more than :data:`BIG_DOT_MAX_SHARE` of the dots qualify).
    ratio : float
        Their median area over their neighbours' median (NaN for none).
    """
    pos = {tuple(q): k for k, q in enumerate(np.asarray(coords).tolist())}
    ok = ~np.asarray(cut, bool) & np.isfinite(area) & (area > 0)
    if np.sum(ok) < 4:
        return np.zeros(0, np.int64), float("nan")
    typical = float(np.median(area[ok]))
    ratio = np.full(len(area), np.nan)
    for k, (a, b) in enumerate(np.asarray(coords).tolist()):
        nb = [pos[q] for q in ((a + 1, b), (a - 1, b), (a, b + 1), (a, b - 1)) if q in pos and ok[pos[q]]]
        if ok[k] and nb:
            ratio[k] = area[k] / float(np.median(area[nb]))
    big = np.flatnonzero(ok & (ratio > BIG_DOT_AREA) & (area > BIG_DOT_AREA * typical))
    if len(big) == 0 or len(big) > BIG_DOT_MAX_SHARE * np.sum(ok):
        return np.zeros(0, np.int64), float("nan")
    return big, float(np.median(ratio[big]))


def big_dot_words(board: Board, n: int, ratio: float, where: list[tuple[int, int]] | None = None) -> str:
    """What a board given without markers should be told of the ``n`` dots much larger than the rest: that they
    are, and the ``--board`` description that would use them as markers.

    Parameters
    ----------
    board : Board
        The board given (no markers).
    n : int
        How many big dots.
    ratio : float
        Their area over their neighbours'.
    where : list of (int, int) or None
        Their (row, col) on the board where the view is labelled; None: not known.

    Returns
    -------
    str
        One sentence, with a one-line board file (YAML flow style) to save and give as ``--board FILE``.
    """
    d = board.diameter_mm * float(np.sqrt(ratio))
    spec = (
        f"rows: {board.rows}, cols: {board.cols}, layout: {board.layout}, pitch_mm: {board.pitch_mm:g}, "
        f"diameter_mm: {board.diameter_mm:g}, markers: ["
    )
    dots = "dot" if n == 1 else "dots"
    if where:
        spec += ", ".join(f"{{row: {r}, col: {c}, diameter_mm: {d:.3g}}}" for r, c in where) + "]"
        at = ", ".join(f"(row {r}, col {c})" for r, c in where)
        return (
            f"{n} {dots} much larger than the rest ({ratio:.1f}x the area) at {at}: markers? a board file "
            f"holding {{{spec}}} given as --board FILE labels partial views too"
        )
    spec += f"{{row: R, col: C, diameter_mm: {d:.3g}}}]"
    return (
        f"{n} {dots} much larger than the rest ({ratio:.1f}x the area) in view: markers? describe them in a board "
        f"file, {{{spec}}} with their rows and columns, and give --board FILE: partial views are then labelled"
    )


def big_dot_notes(board: Board, order: np.ndarray, area: np.ndarray, cut: np.ndarray) -> list[str]:
    """The note naming a labelled view's big dots (:func:`big_dots`) on a board given without markers.

    Parameters
    ----------
    board : Board
    order : ndarray, shape (N,)
        Per board point the candidate seen there (-1: none).
    area : ndarray, shape (M,)
        The candidates' areas, px^2.
    cut : ndarray, shape (M,)
        bool: the candidate is cut by the image border.

    Returns
    -------
    list of str
        The one sentence of :func:`big_dot_words` with the big dots' board rows and columns; empty for a marker
        board or none.
    """
    if board.has_markers:
        return []
    seen = np.flatnonzero(order >= 0)
    rc = np.column_stack(np.divmod(seen, board.cols))
    big, ratio = big_dots(rc, area[order[seen]], cut[order[seen]])
    if len(big) == 0:
        return []
    return [big_dot_words(board, len(big), ratio, [(int(r), int(c)) for r, c in rc[big]])]
