"""The board's grid found from the images alone (``--grid auto``): rows, columns and layout, with no Board given.

Per image (:func:`image_grid`), the locate stage runs without a board: the segmentations at each scale
(:func:`~circcal.detector.locate.segment.segmentations`), candidate dots within the widest area window any board of
at least :data:`PROBE` 's size allows (the only thing the candidates need of a board), the lattice patches among them
(:func:`~circcal.detector.locate.lattice.find_lattices`), the regular ones (a printed lattice), the largest. Its
shape in lattice coordinates tells the layout: a full rectangle of the patch's steps is a symmetric ``R x C`` grid; a
full staggered rectangle in the board frame of an asymmetric grid (:data:`~circcal.detector.locate.labels.ASYMMETRIC_FROM_PATCH`:
the nearest neighbours of an acircles grid are its diagonals) is an asymmetric one. The view is *complete* when that
shape is full, no dot of it touches the border and every lattice position around it lies inside the image (or was
looked at and holds no dot).

Across views (:func:`infer_grid`): the most common complete grid (ties: the one with more dots); where no view is
complete (boards that fill the frame: a row beyond it cannot be ruled out), the most common whole one; partial views
never vote, so they cannot make the grid smaller. Orientation conventions (the same board either way; the detector finds
it in any rotation): a symmetric grid is given with rows <= columns; an asymmetric one with an even row count has
two descriptions (``R x C`` and ``2C x R/2``), the one with more rows is given (OpenCV's acircles habit, 11x4).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from circcal.board import Board, placements
from circcal.detector.image import STRETCH_TAIL_PX, as_gray, normalise_u8, read_image_messages
from circcal.detector.locate.budget import Deadline
from circcal.detector.locate.candidates import area_limits, find_candidates
from circcal.detector.locate.labels import ASYMMETRIC_FROM_PATCH, shape_of
from circcal.detector.locate.lattice import Lattice, find_lattices
from circcal.detector.locate.recognise import _regular
from circcal.detector.locate.segment import (
    MAX_STRETCHED_NOISE,
    SHRUNK_MIN_RADIUS,
    noise_sigma_u8,
    segmentation_scales,
    segmentations,
    shrink,
    speckled,
)

__all__ = ["GridEvidence", "PROBE", "image_grid", "infer_grid", "grid_text"]

PROBE = Board(3, 3, 1.0, 0.8)
"""The smallest, most densely dotted board looked for: its area window (:func:`~circcal.detector.locate.candidates.area_limits`)
admits the dots of every board of at least 9 points with dots up to 0.8 pitches across, and its lattice checks
(regularity) use only the patch's own steps."""
MIN_LINES = 3
"""A grid is inferred only from a lattice of at least this many rows and columns (a seed needs all 8 neighbours)."""
INFER_SEED_SCORE = 7
"""Neighbours (of 8) the first seed of a lattice needs when no board is given: the most the dots of the thinnest
boards inferred have (:func:`~circcal.detector.locate.labels.seed_score_needed`: 8 on grids of 3 rows and columns
and more; 7 on a 4-row staggered board, 4 rows of 11 dots). A lattice with 8-neighbour seeds is found as with 8
(seeds are taken best first); only where none has 8 does a thinner one seed. Not 6 (a 3-row staggered board's):
over the 90 hostile images of :mod:`circcal.fixtures.fuzz` it found lattices in 8 more of random dots and checkers,
one a "whole" 3x2 staggered board; 7 finds two partial ones (layout unknown), no board."""
INFER_BUDGET_S = 20.0
"""Seconds per image for the board-free search (it tries every segmentation of every scale)."""


@dataclass
class GridEvidence:
    """What one image shows. ``image``: its name; ``rows``, ``cols``, ``layout``: the grid of its largest regular
    lattice (``layout`` ``None`` when that lattice is neither a full rectangle nor a full staggered one: a partial
    view; ``rows``/``cols`` are then its bounding box); ``whole``: a full grid with no dot cut by the border (the
    border may still hide more rows beyond it); ``complete``: whole, and nothing of the lattice can lie beyond the
    image; ``dots``: the lattice's dots (0: none found); ``note``: why nothing was found, in words; ``ab``: (K, 2) int the lattice's patch coordinates."""

    image: str
    rows: int = 0
    cols: int = 0
    layout: str | None = None
    complete: bool = False
    dots: int = 0
    whole: bool = False
    note: str = ""
    ab: np.ndarray | None = field(default=None, repr=False)

    def text(self) -> str:
        """One line for a person.

        Returns
        -------
        str
            The image and what its largest lattice is (its grid, its dots, whether it may go on beyond the frame).
        """
        if self.dots == 0:
            return f"{self.image}: {self.note or 'no dot lattice'}"
        what = grid_text(self.rows, self.cols, self.layout or "symmetric") if self.layout else "a partial lattice"
        how = "" if self.complete else (", may go on beyond the frame" if self.whole else ", partial view")
        return f"{self.image}: {what} ({self.dots} dots{how})"


def grid_text(rows: int, cols: int, layout: str) -> str:
    """The command-line words for a grid: ``--grid RxC`` (and ``--asymmetric``).

    Parameters
    ----------
    rows, cols : int
    layout : str
        ``"symmetric"`` or ``"asymmetric"``.

    Returns
    -------
    str

    Examples
    --------
    >>> grid_text(5, 4, "asymmetric")
    '--grid 5x4 --asymmetric'
    """
    return f"--grid {rows}x{cols}" + (" --asymmetric" if layout == "asymmetric" else "")


def _bounded(lat: Lattice, points: np.ndarray, size: tuple[int, int]) -> bool:
    """Whether nothing of the lattice can lie beyond the image: each 4-neighbour of the patch was looked at and holds
    no dot (``lat.misses``), or lies, by the patch's homography, inside the image at least half a lattice step from
    its border (a dot there would have been a candidate)."""
    import cv2

    occ = {tuple(q) for q in lat.ab.tolist()}
    free = {q for a, b in occ for q in ((a + 1, b), (a - 1, b), (a, b + 1), (a, b - 1))} - occ - set(lat.misses)
    if not free:
        return True
    H, _ = cv2.findHomography(lat.ab.astype(np.float64), points[lat.index], 0)
    if H is None or not np.all(np.isfinite(H)):
        return False
    q = np.array(sorted(free), np.float64)
    ends = np.concatenate([q, q + [1.0, 0.0], q + [0.0, 1.0]]).reshape(-1, 1, 2)
    xy = cv2.perspectiveTransform(ends, H).reshape(3, -1, 2)
    step = np.minimum(np.linalg.norm(xy[1] - xy[0], axis=1), np.linalg.norm(xy[2] - xy[0], axis=1))
    W, H_ = size
    lo = 0.5 * step
    inside = (xy[0, :, 0] >= lo) & (xy[0, :, 1] >= lo) & (xy[0, :, 0] <= W - 1 - lo) & (xy[0, :, 1] <= H_ - 1 - lo)
    return bool(np.all(inside))


def image_grid(gray: np.ndarray, name: str = "image", deadline: Deadline | None = None) -> GridEvidence:
    """The grid of the largest regular dot lattice in one grey image (module docstring), no board given.

    Dark dots on a light board first; the inverted image when that finds no lattice (bright dots).

    Parameters
    ----------
    gray : numpy.ndarray
        (H, W) grey image (uint8/uint16/float).
    name : str
        The image's name in the evidence.
    deadline : Deadline or None
        Checked at each segmentation (:class:`~circcal.detector.locate.budget.BudgetExceeded` past it).

    Returns
    -------
    GridEvidence
    """
    best = _search(gray, name, deadline)
    if best.dots == 0:
        g = np.asarray(gray, np.float64)
        inverted = _search(float(np.nanmax(g)) - g, name, deadline)
        if inverted.dots:
            return inverted
    return best


def _search(gray: np.ndarray, name: str, deadline: Deadline | None) -> GridEvidence:
    """:func:`image_grid` on ``gray`` as it is: every segmentation of every scale (coarsest first), until a complete
    grid of dots not too small for their scale is found."""
    H, W = gray.shape
    min_area, max_area = area_limits(PROBE, W, H)
    best = GridEvidence(name, note="no regular lattice of dots")
    for scale in segmentation_scales(H, W):
        counts = np.zeros(256, np.int64)
        img = normalise_u8(gray if scale == 1 else shrink(gray, scale), STRETCH_TAIL_PX / scale**2, counts)
        noise = noise_sigma_u8(img)
        if noise > MAX_STRETCHED_NOISE:
            continue
        for _, mask in segmentations(img, noise, counts):
            if deadline is not None:
                deadline.check()
            if speckled(mask):
                continue
            cs = find_candidates(mask, min_area=min_area / scale**2, max_area=max_area / scale**2, scale=scale)
            if len(cs) < MIN_LINES * MIN_LINES:
                continue
            pts = np.array([c.centre for c in cs], np.float64)
            axes = np.array([c.axes for c in cs], np.float64)
            ang = np.array([c.angle for c in cs], np.float64)
            area = np.pi * axes[:, 0] * axes[:, 1]
            cut = np.array([c.cut for c in cs], bool)
            patches = find_lattices(pts, axes, ang, area, (W, H), min_seed_score=INFER_SEED_SCORE, deadline=deadline)
            lat = next((p for p in patches if _regular(PROBE, p, pts, area)), None)
            if lat is None:
                continue
            rows, cols, layout = shape_of(lat.ab)
            if min(rows, cols) < MIN_LINES and layout != "asymmetric":
                continue
            whole = layout is not None and not cut[lat.index].any()
            complete = whole and _bounded(lat, pts, (W, H))
            ev = GridEvidence(name, rows, cols, layout, complete, len(lat), whole=whole, ab=lat.ab.copy())
            if (ev.complete, ev.whole, ev.dots) > (best.complete, best.whole, best.dots):
                best = ev
            r_min = float(np.min(np.sqrt(axes[lat.index, 0] * axes[lat.index, 1])))
            if best is ev and whole and (scale == 1 or r_min >= SHRUNK_MIN_RADIUS * scale):
                return best
    return best


def _gray_of(item, index: int) -> tuple[np.ndarray | None, str, str]:
    """(grey image or None, name, why not) of an image file or array."""
    if isinstance(item, np.ndarray):
        return as_gray(item), f"image {index}", ""
    path = Path(item)
    img, messages = read_image_messages(path)
    if img is None:
        return None, path.name, "; ".join(messages) or "not a readable image file"
    return as_gray(img), path.name, ""


def infer_grid(
    images, budget_s: float | None = INFER_BUDGET_S
) -> tuple[int | None, int | None, str | None, list[GridEvidence]]:
    """The board's grid from the images alone: the largest lattice of each (:func:`image_grid`), the grid consistent
    with the views (:func:`choose_grid`).

    Parameters
    ----------
    images : sequence of (path-like or numpy.ndarray)
        Image files, or images ((H, W) grey or (H, W, 3) BGR arrays).
    budget_s : float or None
        Seconds per image for the search (``None``: no limit); an image past it gives no evidence.

    Returns
    -------
    rows, cols : int or None
        The grid's rows and columns (``--grid RxC``; :func:`choose_grid`); ``None`` when no image shows a lattice.
    layout : str or None
        ``"symmetric"`` or ``"asymmetric"``; ``None`` as above.
    evidence : list of GridEvidence
        What each image showed, in the order given.

    Raises
    ------
    ImageError
        A file whose header claims more pixels than allowed (as the detector refuses it).
    OSError
        A file that exists but cannot be read.
    """
    from circcal.detector.locate.budget import BudgetExceeded

    evidence = []
    for i, item in enumerate(images):
        gray, name, why = _gray_of(item, i)
        if gray is None:
            evidence.append(GridEvidence(name, note=why))
            continue
        try:
            evidence.append(image_grid(gray, name, Deadline(budget_s)))
        except BudgetExceeded:
            evidence.append(GridEvidence(name, note=f"no lattice within {budget_s:g} s"))
    rows, cols, layout = choose_grid(evidence)
    return rows, cols, layout, evidence


FIT_SHARE = 0.8
"""A grid is consistent with the views when the lattices of at least this share of them fit in it (a lattice of
clutter beside the board in one view, or a second board, does not veto the board)."""


def _candidates(e: GridEvidence) -> set[tuple[int, int, str]]:
    """The grids one view suggests: its own where whole, else the boxes around its lattice, either layout."""
    if e.whole and e.layout is not None:
        return {(e.rows, e.cols, e.layout)}
    span = np.ptp(e.ab, axis=0) + 1
    out = {(*sorted(int(x) for x in span), "symmetric")}
    sx, sy = (int(x) for x in np.ptp(e.ab @ ASYMMETRIC_FROM_PATCH.T, axis=0) + 1)
    for along, across in ((sy, sx), (sx, sy)):
        if along >= 2:
            out.add(probe_grid_of(Board(along, (across + 1) // 2, 1.0, 0.5, "asymmetric")))
    return out


def choose_grid(evidence: list[GridEvidence]) -> tuple[int | None, int | None, str | None]:
    """The grid of the views (module docstring): among the grids they suggest (:func:`_candidates`) that the lattices
    of :data:`FIT_SHARE` of the views fit in, the one most views show complete, then whole; then the one most views
    fit; then the smallest (the least the views need).

    Parameters
    ----------
    evidence : list of GridEvidence

    Returns
    -------
    tuple
        ``(rows, cols, layout)``, or ``(None, None, None)`` when no view shows a lattice.
    """
    seen = [e for e in evidence if e.dots and e.ab is not None]
    cands = set().union(*(_candidates(e) for e in seen)) if seen else set()
    best, best_key = (None, None, None), None
    for r, c, layout in cands:
        board = Board(r, c, 1.0, 0.5, layout)
        conv = "asymmetric" == layout
        fits = sum(bool(placements(board, e.ab @ ASYMMETRIC_FROM_PATCH.T if conv else e.ab)) for e in seen)
        same = [e for e in seen if e.whole and (e.rows, e.cols, e.layout) == (r, c, layout)]
        key = (fits >= FIT_SHARE * len(seen), sum(e.complete for e in same), len(same), fits, -r * c, r, c)
        if best_key is None or key > best_key:
            best, best_key = (r, c, layout), key
    return best


def probe_grid_of(board: Board) -> tuple[int, int, str]:
    """A board's grid in :func:`infer_grid`'s conventions (to compare a given ``--grid`` with the one inferred).

    Parameters
    ----------
    board : Board

    Returns
    -------
    tuple
        ``(rows, cols, layout)``.
    """
    if board.layout == "asymmetric":
        if board.rows % 2 == 0 and 2 * board.cols > board.rows:
            return 2 * board.cols, board.rows // 2, "asymmetric"
        return board.rows, board.cols, "asymmetric"
    return min(board.rows, board.cols), max(board.rows, board.cols), "symmetric"
