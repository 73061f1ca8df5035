"""The board's search in one image: the segmentations at each scale, the candidate dots of each, and the lattice
recognised among them (:func:`segment_and_recognise`), with the windows searched again at a finer scale where the
dots are small (a recognised board's window, :func:`_board_window`; the clusters of candidates too small for the
shrunk scale, :func:`_cluster_windows`).

Only the starting ellipses come from here (the candidates' contours); the edges are measured at full resolution by
:func:`~circcal.detector.measure.dots.fit_dots`. Candidates are in full-image pixels, OpenCV's convention (integer
coordinates are pixel centres), whatever the scale or window they were found at.
"""

from __future__ import annotations

import math

import numpy as np

from circcal.board import Board
from circcal.detector.detection import Reason
from circcal.detector.image import STRETCH_TAIL_PX, normalise_u8
from circcal.detector.locate.budget import Deadline
from circcal.detector.locate.candidates import Candidate, area_limits, find_candidates
from circcal.detector.locate.neighbours import NeighbourGrid, linked_clusters
from circcal.detector.locate.recognise import MIN_PARTIAL_POINTS, Recognition, recognise, telling
from circcal.detector.locate.segment import (
    MAX_STRETCHED_NOISE,
    SHRUNK_MIN_RADIUS,
    noise_sigma_u8,
    segmentation_scales,
    segmentations,
    shrink,
    speckled,
)
from circcal.model import Camera

__all__ = ["segment_and_recognise"]


def segment_and_recognise(
    gray: np.ndarray,
    board: Board,
    deadline: Deadline,
    *,
    first_only: bool = False,
    scales: list[int] | None = None,
    box: tuple[int, int, int, int] | None = None,
    camera: Camera | None = None,
    expected: np.ndarray | None = None,
) -> tuple[Recognition, list[Candidate], str | None, int]:
    """The board among the candidate dots of ``gray``, trying the segmentations at each scale in turn.

    The scales are those of :func:`~circcal.detector.locate.segment.segmentation_scales`; candidates are in
    full-image pixels. The first segmentation in which the whole board is recognised wins; otherwise the one with the
    largest part of the board labelled at the first scale that labels a part (a partial view: finer scales see no
    more of a board whose dots they resolve already); a lattice that continues beyond the board ends the search at
    once; otherwise the most telling refusal (a lattice larger than the board, an ambiguous part, before "not
    recognised"). A grid of dots smaller than :data:`~circcal.detector.locate.segment.SHRUNK_MIN_RADIUS` at a
    shrunk scale sends the search on to the coarsest scale where they are not, in the board's window only
    (:func:`_board_window`; the whole image again when the window does not show it).

    Parameters
    ----------
    gray : numpy.ndarray
        (H, W) grey image (uint8/uint16/float).
    board : Board
        The board.
    deadline : Deadline
        The image's deadline, checked at each scale, mask and contour search.
    first_only : bool, optional
        The first segmentation at the first scale only (the inverted-board hint).
    scales : list of int or None, optional
        The scales to try (default :func:`~circcal.detector.locate.segment.segmentation_scales`).
    box : tuple of int or None, optional
        ``(x0, y0, x1, y1)`` px: search this window of ``gray`` only (candidates still in full-image pixels).
    camera : Camera or None, optional
        The lens model, whose undistorted image the lattice is recognised in
        (:func:`~circcal.detector.locate.recognise.recognise`; the candidates stay in pixels).
    expected : ndarray or None, optional
        (N, 2) px where each board point is expected (a rig's other cameras): an ambiguous part of an unmarked board
        is labelled by it (:func:`~circcal.detector.locate.recognise.recognise`).

    Returns
    -------
    recognition : Recognition
        The board found (``order`` indexes ``candidates``), or why not.
    candidates : list of Candidate
        The candidates of the segmentation chosen, full-image px.
    segmentation : str or None
        That segmentation's name (``"name@1/s"`` at a shrunk scale); ``None`` when none was chosen.
    most : int
        The most candidates (not cut by the border) any segmentation gave.

    Raises
    ------
    BudgetExceeded
        Past ``deadline`` (:class:`~circcal.detector.locate.budget.BudgetExceeded`).
    """
    H, W = gray.shape
    min_area, max_area = area_limits(board, W, H)
    best = 0
    need = min(board.n_points, MIN_PARTIAL_POINTS)
    x0, y0, x1, y1 = box if box is not None else (0, 0, W, H)
    win = gray[y0:y1, x0:x1]
    scales = list(segmentation_scales(*win.shape) if scales is None else scales)
    coarsest = max(scales, default=1)
    partial: tuple[Recognition, list[Candidate], str] | None = None
    quietest = math.inf  # the least noise of the scales left unsegmented for noise (grey levels)
    segmented = False
    refusal: tuple[Recognition, list[Candidate], str] | None = None
    unrecognised: list[Candidate] = []  # candidates of scale 2 in no recognised grid (dots too small there?)
    searched: set[tuple[int, int, int, int]] = set()  # the windows searched again at full resolution
    while scales:
        deadline.check()  # (each scale's shrink, stretch and masks cost O(pixels))
        scale = scales.pop(0)
        # shrunk (pixel-area averaging) before the contrast stretch: the stretch then touches s^2 fewer pixels
        counts = np.zeros(256, np.int64)
        img = normalise_u8(win if scale == 1 else shrink(win, scale), STRETCH_TAIL_PX / scale**2, counts)
        noise = noise_sigma_u8(img)
        if noise > MAX_STRETCHED_NOISE:  # nothing but noise at this scale: the block means of a coarser one
            quietest = min(quietest, noise)
            if box is None and scale == coarsest and min(win.shape) // (2 * scale) >= NOISY_MIN_SIDE:
                coarsest = 2 * scale
                scales.insert(0, coarsest)
            continue
        segmented = True
        for name, mask in segmentations(img, noise, counts):
            deadline.check()
            if speckled(mask):
                continue
            cs = find_candidates(mask, min_area=min_area / scale**2, max_area=max_area / scale**2, scale=scale)
            deadline.check()  # (the contours of a textured mask: O(pixels + candidates))
            n_whole = sum(not c.cut for c in cs)
            best = max(best, n_whole)
            if n_whole < need:
                if first_only:
                    return Recognition(None, code=Reason.TOO_FEW_CANDIDATES), cs, None, best
                continue
            if box is not None:
                cs = [_shifted(c, x0, y0, W, H) for c in cs]
            rec = recognise(board, cs, (W, H), deadline, camera, expected)
            if scale == 2 and rec.order is None:
                unrecognised += cs
                if box is None and not first_only and not searched:
                    # the first unrecognised mask of the finest shrunk scale: its clusters at full resolution now,
                    # before the other thresholds of this scale (they cannot make dots ~3 px across any larger)
                    got = _search_clusters(gray, board, deadline, cs, need, searched, camera, expected)
                    if got is not None and got[0].complete:
                        return got[0], got[1], got[2], max(best, got[3])
                    if got is not None and (
                        partial is None or np.sum(got[0].order >= 0) > np.sum(partial[0].order >= 0)
                    ):
                        partial = (got[0], got[1], got[2])
                        best = max(best, got[3])
            label = name if scale == 1 else f"{name}@1/{scale}"
            if box is not None:
                label += f"[{x0}:{x1},{y0}:{y1}]"
            if rec.order is not None:
                seen = rec.order[rec.order >= 0]
                radii = np.array([math.sqrt(cs[i].axes[0] * cs[i].axes[1]) for i in seen])
                r_min = float(np.min(radii))
                if scale != 1 and r_min < SHRUNK_MIN_RADIUS * scale:
                    # small dots: their contours are worth a finer scale, the coarsest one where they are not small,
                    # in the board's window first (a small board in a large frame: a few % of the pixels)
                    finer = max([s for s in range(2, scale) if r_min >= SHRUNK_MIN_RADIUS * s], default=1)
                    finer_scales = [finer, 1] if finer != 1 else [1]
                    window = _board_window(cs, rec, (W, H), (x0, y0, x1, y1))
                    if window is None and box is None and (x1 - x0) * (y1 - y0) <= WHOLE_FRAME_MAX_PX:
                        window = (x0, y0, x1, y1)  # a board filling much of a small frame: all of it
                    if window is not None:
                        got = segment_and_recognise(
                            gray,
                            board,
                            deadline,
                            scales=list(finer_scales),
                            box=window,
                            camera=camera,
                            expected=expected,
                        )
                        if got[0].order is not None:
                            return got[0], got[1], got[2], max(best, got[3])
                    # the finer scales see no board: this scale's recognition stands (the edges are measured at
                    # full resolution from its contours all the same)
                if rec.complete:
                    return rec, cs, label, best
                if partial is None or np.sum(rec.order >= 0) > np.sum(partial[0].order >= 0):
                    partial = (rec, cs, label)
            else:
                if refusal is None or telling(rec) > telling(refusal[0]):
                    refusal = (rec, cs, label)
                if rec.decisive:  # the dots continue beyond the board: no threshold changes that
                    return rec, cs, None, best
            if first_only:
                return rec, cs, label, best
        else:
            if partial is not None:  # a part of the board at this scale: the other scales see no more of it
                break
    if partial is None and box is None and not first_only and unrecognised:
        got = _search_clusters(gray, board, deadline, unrecognised, need, searched, camera, expected)
        if got is not None:
            return got[0], got[1], got[2], max(best, got[3])
    if partial is not None:
        return partial[0], partial[1], partial[2], best
    if refusal is not None:
        return refusal[0], refusal[1], None, best
    if not segmented and math.isfinite(quietest):
        return (
            Recognition(
                None,
                code=Reason.TOO_FEW_CANDIDATES,
                message=f"the image shows only noise at every scale tried (after the contrast stretch its "
                f"noise is at least {quietest:.0f} grey levels of 255; at most "
                f"{MAX_STRETCHED_NOISE:.0f} is thresholded)",
            ),
            [],
            None,
            best,
        )
    return Recognition(None, code=Reason.TOO_FEW_CANDIDATES), [], None, best


def _search_clusters(
    gray: np.ndarray,
    board: Board,
    deadline: Deadline,
    cands: list[Candidate],
    need: int,
    searched: set[tuple[int, int, int, int]],
    camera: Camera | None = None,
    expected: np.ndarray | None = None,
) -> tuple[Recognition, list[Candidate], str | None, int] | None:
    """The board in a window around one of the clusters of ``cands`` (:func:`_cluster_windows`), segmented again at
    full resolution: dots ~3 px across at scale 2 are candidates but too rough for the lattice search. Each window is
    searched once (``searched``: the windows searched so far, updated), never the whole frame; ``camera``: the lens
    model, and ``expected``, as :func:`segment_and_recognise` takes them. Returns what
    :func:`_segment_and_recognise` returns for the first window whose recognition labels dots, else ``None``."""
    H, W = gray.shape
    for window in _cluster_windows(cands, need, (W, H)):
        deadline.check()
        if window in searched:
            continue
        searched.add(window)
        got = segment_and_recognise(gray, board, deadline, scales=[1], box=window, camera=camera, expected=expected)
        if got[0].order is not None:
            return got
    return None


NOISY_MIN_SIDE = 120
"""A scale too noisy to segment (its stretched noise above :data:`~circcal.detector.locate.segment.MAX_STRETCHED_NOISE`),
the coarsest one tried, sends the search on to twice that scale (its block means: half the noise against the same
contrast), as long as the shrunk image's shorter side is at least this (px): a board whose dots stand only a few
noise sigmas from the white (a dim photograph at high gain) is found where its pixels are averaged, and its edges
are measured at full resolution all the same. A frame of noise alone stays noise at every scale (the stretch scales
its noise with its range: ~50 grey levels), so it costs a few shrunk passes more."""
CLUSTER_LINK = 2.5
"""Candidates closer than this many times the smaller of their nearest-neighbour distances belong to one cluster
(:func:`_cluster_windows`: the dots of a board are about equally spaced, clutter is not)."""
MAX_CLUSTER_WINDOWS = 3
"""At most this many clusters (the largest) are searched again at full resolution."""


def _cluster_windows(cands: list[Candidate], need: int, size: tuple[int, int]) -> list[tuple[int, int, int, int]]:
    """Windows ``(x0, y0, x1, y1)`` px around the largest clusters of ``cands`` (full-image pixels) with at least
    ``need`` members (:data:`CLUSTER_LINK`, :data:`MAX_CLUSTER_WINDOWS`), each grown as :func:`_board_window` grows
    a recognised board's; windows larger than :data:`WINDOW_MAX_SHARE` of the image are left out."""
    W, H = size
    P = np.array([c.centre for c in cands], np.float64)
    if len(P) < max(need, 2):
        return []
    lab = linked_clusters(P, CLUSTER_LINK)
    n = int(lab.max()) + 1
    if n == len(P):  # no point linked to another
        return []
    counts = np.bincount(lab, minlength=n)
    out = []
    for k in np.argsort(-counts)[:MAX_CLUSTER_WINDOWS]:
        if counts[k] < need:
            break
        idx = np.nonzero(lab == k)[0]
        rec = Recognition(order=idx)
        window = _board_window(cands, rec, (W, H), (0, 0, W, H))
        if window is not None:
            out.append(window)
    return out


WINDOW_MARGIN_STEPS = 2.0
"""The board's window (:func:`_board_window`) reaches this many lattice steps beyond the dots recognised at a coarse
scale (room for the dots that scale missed and for the lattice's continuation, which the search checks)."""
WINDOW_MAX_SHARE = 0.25
"""... and is used only when it is at most this share of the image searched (else the whole image is, up to
:data:`WHOLE_FRAME_MAX_PX`)."""
WHOLE_FRAME_MAX_PX = 4_000_000
"""A board of small dots filling more than that share of the frame is segmented again at the finer scale on the whole
frame only up to this many pixels (a 4 MP frame takes ~0.1 s at full resolution; a 48 MP one seconds)."""


def _board_window(
    cands: list[Candidate], rec: Recognition, size: tuple[int, int], within: tuple[int, int, int, int]
) -> tuple[int, int, int, int] | None:
    """``(x0, y0, x1, y1)`` px: the bounding box of the recognised dots of ``rec`` (candidates ``cands``, full-image
    pixels) grown by :data:`WINDOW_MARGIN_STEPS` lattice steps (the median nearest-neighbour distance of those
    dots), clipped to the image ``size`` (W, H); ``None`` when it is not much smaller than the window ``within``
    searched (:data:`WINDOW_MAX_SHARE`)."""
    W, H = size
    used = [cands[i] for i in rec.order[rec.order >= 0]]
    P = np.array([c.centre for c in used])
    if len(P) < 2:
        return None
    # each dot's nearest other dot from the neighbour grid (O(n) memory: a cluster of clutter may hold thousands of
    # candidates, and an n x n distance matrix of 8,000 took 3 GB); the distance as numpy computes it
    nearest = NeighbourGrid(P).query(P, k=2)[1]
    other = np.where(nearest[:, 0] != np.arange(len(P)), nearest[:, 0], nearest[:, 1])
    step = np.linalg.norm(P - P[other], axis=1)
    pad = WINDOW_MARGIN_STEPS * float(np.median(step)) + 2.0 * max(max(c.axes) for c in used)
    lo, hi = P.min(axis=0) - pad, P.max(axis=0) + pad
    x0, y0 = max(0, int(np.floor(lo[0]))), max(0, int(np.floor(lo[1])))
    x1, y1 = min(W, int(np.ceil(hi[0])) + 1), min(H, int(np.ceil(hi[1])) + 1)
    area = (within[2] - within[0]) * (within[3] - within[1])
    if (x1 - x0) * (y1 - y0) > WINDOW_MAX_SHARE * area or x1 - x0 < 16 or y1 - y0 < 16:
        return None
    return x0, y0, x1, y1


def _shifted(c: Candidate, x0: int, y0: int, W: int, H: int) -> Candidate:
    """Candidate ``c`` of a window at ``(x0, y0)`` in full-image pixels; cut only where it touches the image's own
    border (its contour touching the window's edge inside the image is clutter reaching in, not a dot cut off)."""
    centre = c.centre + [x0, y0]
    cut = c.cut and bool(
        centre[0] - c.axes[0] <= 1.0
        or centre[1] - c.axes[0] <= 1.0
        or centre[0] + c.axes[0] >= W - 2.0
        or centre[1] + c.axes[0] >= H - 2.0
    )
    return Candidate(centre, c.axes, c.angle, c.area, cut)
