"""Grid recognition on candidate dots: the board found among the lattice patches of the candidates, its dots
labelled with board point numbers, and what the image shows besides (another board, a lattice larger than the
board), in words.

:func:`recognise` takes the candidates of one segmentation and

1. for an unmarked symmetric board whose candidates are exactly its dots (the common clean case) orders them
   directly (:func:`circcal.detector.locate.grid.order_lattice`: hull corners, one homography);
2. otherwise finds the lattice patches (:func:`circcal.detector.locate.lattice.find_lattices`, about linear in the number
   of candidates), reads each patch dot's marker flag from its area against the local lattice cell
   (:func:`marker_flags`), and labels the largest patches (:func:`circcal.detector.locate.labels.label_patch`);
3. keeps the patch that is the whole board (several: the largest, the others named in ``notes``), else the largest
   part of the board that is labelled unambiguously (a partial view), else says why not: the board has more dots
   than ``--grid``, the transposed grid fits, the markers disagree, or which part of the board is seen is ambiguous.
   On a marker board the board's edges in view help decide (:func:`empty_positions`); on a board given without
   markers, dots much larger than the rest are named with the ``--board`` file that would use them
   (:mod:`~circcal.detector.locate.bigdots`).

Pixels: OpenCV's convention.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from circcal.board import Board
from circcal.detector.detection import Reason
from circcal.detector.locate.bigdots import big_dot_notes, big_dot_words, big_dots
from circcal.detector.locate.budget import Deadline
from circcal.detector.locate.candidates import Candidate
from circcal.detector.locate.grid import order_lattice, orient
from circcal.detector.locate.labels import Labelling, label_patch, nearest_labelling, seed_score_needed
from circcal.detector.locate.lattice import Lattice, find_lattices
from circcal.detector.locate.smooth import local_residual
from circcal.detector.locate.undistorted import inside_image, undistorted_candidates
from circcal.model import Camera

__all__ = [
    "Recognition",
    "recognise",
    "telling",
    "order_grid",
    "marker_flags",
    "MIN_PARTIAL_POINTS",
    "cell_areas",
    "empty_positions",
]

MAX_LABELLED = 4
"""Patches labelled per segmentation, largest first: the board, a second board, a printed logo and one more; the
rest are smaller than any of them and are only counted."""
MIN_PARTIAL_POINTS = 8
"""A partial view is used with at least this many labelled dots (the solver needs 6 per view; 8 leave a little
redundancy for the pose), spanning at least :data:`MIN_PARTIAL_LINES` rows and columns."""
MIN_PARTIAL_LINES = 3
"""... (three rows and three columns: the homography of the centre correction and the pose are well posed)."""
MARKER_SPLIT = (0.35, 0.65)
"""Marker flags: ``x = log(area ratio) / log(marker area ratio)`` is ~0 for a plain dot and ~1 for a marker
(area ratio: the dot's area over the local lattice cell, over the patch's median); below the first value a dot is
plain, above the second a marker, between them unknown (not used as evidence): a misread marker then cannot make a
wrong placement fit."""
PATCH_RESIDUAL = 0.1
"""A patch counts as a lattice only when a homography from its lattice coordinates (with a quadratic term from
:data:`~circcal.detector.measure.trust.QUADRATIC_FROM` dots on, for lens distortion) explains its candidates' rough centres
to this share of a lattice step (RMS): contour centroids of real dots err by a few hundredths of a step (perspective
bias of large dots included); chance alignments of blobs, which growth accepts within a quarter of a step, by a
tenth and more. A patch that global fit does not follow (a grid bent by a fisheye or a wide lens) counts when each
dot against the quadratic of its own neighbours (:func:`~circcal.detector.locate.smooth.local_residual`, a share of
the local step) is within this share instead."""
PATCH_FILL_SPREAD = 0.35
"""... and when its dots' areas over their local lattice cells agree: relative spread (MAD over median) at most
this, markers apart (a board's dots agree within a few percent)."""
REAL_LINE_SHARE = 0.5
"""A lattice that labels as larger than the board is trimmed of an outer row or column (:func:`_trimmed`) where
fewer than this share of the positions looked at on it hold a dot of the board's size: a blob of texture, a screw
hole or a speck of the plate that the lattice took in beside the board (one in 16 positions) ..."""
REAL_FILL_FACTOR = 1.6
"""... a dot of the board's size: its area over the local lattice cell within this factor of the patch's median
either way (perspective and blur change it by tens of percent at most; the lattice admits blobs within 6.5x)."""
CLAIM_MIN_DOTS = 9
"""What a lattice that is not the board says about it (larger than the board, transposed, ambiguous) is only
claimed for a lattice of at least this many dots grown from a seed with all 8 neighbours (a 3 x 3 block at the
least): a few blobs that line up by chance (seeds of a 2 x 2 board need only 3 neighbours) claim nothing."""
NOTE_MIN_DOTS = 6
"""Other dot lattices in view are named in the notes when they have at least this many dots ..."""
NOTE_MIN_SHARE = 0.25
"""... and at least this share of the board's dots (a printed logo, a second board; not a few aligned specks)."""


@dataclass
class Recognition:
    """The board among the candidates. ``order`` (N,) candidate index of each board point, -1 where not seen
    (``None`` when not found); ``complete``: the patch covers the whole board; ``code``/``message``: why not found
    (``None``/"" when found); ``cut`` (N,) bool: board points whose candidate touches the image border;
    ``notes``: what else the image shows, in words; ``patches``: how many lattice patches were found;
    ``decisive``: a refusal no other segmentation would change (the dots continue beyond the board, or the
    transposed grid fits them)."""

    order: np.ndarray | None
    complete: bool = False
    code: Reason | None = None
    message: str = ""
    cut: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    patches: int = 0
    decisive: bool = False


def cell_areas(board: Board, lat: Lattice, points: np.ndarray) -> np.ndarray:
    """The area of one board lattice cell (pitch x pitch) at each dot of patch ``lat``, from the local lattice steps.

    Central differences where both neighbours are in the patch, one-sided otherwise.

    Parameters
    ----------
    board : Board
        The board (an asymmetric grid's patch cell is two board cells).
    lat : Lattice
        The patch (K dots).
    points : numpy.ndarray
        (M, 2) float candidate centres, px (``lat.index`` points into it).

    Returns
    -------
    numpy.ndarray
        (K,) float areas, px^2; NaN for a dot with no neighbour along an axis.
    """
    pos = {tuple(q): k for k, q in enumerate(lat.ab.tolist())}
    P = points[lat.index]
    out = np.full(len(P), np.nan)
    for k, (a, b) in enumerate(lat.ab.tolist()):
        steps = []
        for da, db in ((1, 0), (0, 1)):
            f, r = pos.get((a + da, b + db)), pos.get((a - da, b - db))
            if f is not None and r is not None:
                steps.append(0.5 * (P[f] - P[r]))
            elif f is not None:
                steps.append(P[f] - P[k])
            elif r is not None:
                steps.append(P[k] - P[r])
        if len(steps) == 2:
            out[k] = abs(steps[0][0] * steps[1][1] - steps[0][1] * steps[1][0])
    if board.layout == "asymmetric":
        out /= 2.0  # the patch's steps are the diagonals: a patch cell is two board cells
    return out


def marker_flags(board: Board, lat: Lattice, points: np.ndarray, dot_areas: np.ndarray, cut: np.ndarray) -> np.ndarray:
    """The marker flag of each dot of a patch, from its area against the local lattice cell (:data:`MARKER_SPLIT`).

    Parameters
    ----------
    board : Board
        The board; one without markers gets all -1.
    lat : Lattice
        The patch (K dots).
    points : numpy.ndarray
        (M, 2) float candidate centres, px.
    dot_areas : numpy.ndarray
        (M,) float areas of all candidates, px^2.
    cut : numpy.ndarray
        (M,) bool, candidates touching the image border.

    Returns
    -------
    numpy.ndarray
        (K,) int64 flags: 1 marker, 0 plain, -1 unknown (cut dots and dots without a local cell are unknown).
    """
    cell = cell_areas(board, lat, points)
    q = dot_areas[lat.index] / cell
    ok = np.isfinite(q) & ~cut[lat.index]
    flags = np.full(len(q), -1, np.int64)
    if not np.any(ok) or not board.has_markers:
        return flags
    x = np.log(q / np.median(q[ok])) / np.log(board.marker_scale**2)
    flags[ok & (x < MARKER_SPLIT[0])] = 0
    flags[ok & (x > MARKER_SPLIT[1])] = 1
    return flags


def _regular(board: Board, lat: Lattice, points: np.ndarray, area: np.ndarray) -> bool:
    """Whether patch ``lat`` looks like a printed lattice (:data:`PATCH_RESIDUAL`, :data:`PATCH_FILL_SPREAD`)."""
    import cv2

    from circcal.detector.measure.trust import QUADRATIC_FROM

    ab = lat.ab.astype(np.float64)
    P = points[lat.index]
    if len(P) < 5:
        return True  # 4 dots fix a homography exactly: nothing to test
    H, _ = cv2.findHomography(ab, P, 0)
    if H is None or not np.all(np.isfinite(H)):
        return False
    res = P - cv2.perspectiveTransform(ab.reshape(-1, 1, 2), H).reshape(-1, 2)
    if len(P) >= QUADRATIC_FROM:
        x, y = (ab - ab.mean(axis=0)).T / max(float(np.ptp(ab)), 1.0)
        A = np.column_stack([np.ones(len(P)), x, y, x * x, x * y, y * y])
        coef, *_ = np.linalg.lstsq(A, res, rcond=None)
        res = res - A @ coef
    cell = cell_areas(board, lat, points) * (2.0 if board.layout == "asymmetric" else 1.0)  # per patch cell
    ok = np.isfinite(cell) & (cell > 0)
    if not np.any(ok):
        return False
    step = float(np.sqrt(np.median(cell[ok])))
    if float(np.sqrt(np.mean(np.sum(res**2, axis=1)))) > PATCH_RESIDUAL * step:
        # a grid bent by a wide lens: each dot against the smooth map of its own neighbours
        local = local_residual(ab, P)
        if local is None or local > PATCH_RESIDUAL:
            return False
    fill = area[lat.index][ok] / cell[ok]
    if board.has_markers:  # markers apart: the dots nearer the smaller mode
        fill = fill[fill < np.median(fill) * board.marker_scale]
    med = float(np.median(fill))
    return bool(np.median(np.abs(fill - med)) <= PATCH_FILL_SPREAD * med)


def _trimmed(
    board: Board,
    lat: Lattice,
    pts: np.ndarray,
    area: np.ndarray,
    cut: np.ndarray,
    lab: Labelling,
    inside: Callable[[np.ndarray], np.ndarray],
) -> tuple[Lattice, Labelling]:
    """Patch ``lat`` and its labelling ``lab`` ("larger"), or the patch less its outer rows and columns that are not
    real dots of the board, where that is labelled as the board or part of it. An outer line (in patch
    coordinates) is not real when fewer than :data:`REAL_LINE_SHARE` of the positions looked at on it inside the
    image (its dots and its misses) hold a dot of the board's size: not cut by the image border, its area over the
    local lattice cell within :data:`REAL_FILL_FACTOR` of the patch's median (a marker's larger area allowed). A
    lattice that truly continues beyond the board (``--grid`` smaller than the board) has real dots there and is
    refused as before."""
    cell = cell_areas(board, lat, pts)
    q = area[lat.index] / cell
    ok = np.isfinite(q) & (q > 0) & ~cut[lat.index]
    if np.sum(ok) < 4:
        return lat, lab
    med = float(np.median(q[ok]))
    real = ok & (q > med / REAL_FILL_FACTOR) & (q < med * REAL_FILL_FACTOR * board.marker_scale**2)
    ab = lat.ab
    keep = np.ones(len(ab), bool)
    removed = True
    while removed and np.sum(keep) >= 4:
        removed = False
        for axis in (0, 1):
            for end in (np.min, np.max):
                at = int(end(ab[keep, axis]))
                line = keep & (ab[:, axis] == at)
                lo, hi = ab[keep, 1 - axis].min(), ab[keep, 1 - axis].max()
                missed = sum(1 for m in lat.misses if m[axis] == at and lo <= m[1 - axis] <= hi)
                if np.sum(real[line]) < REAL_LINE_SHARE * (np.sum(line) + missed) and np.sum(keep & ~line) >= 4:
                    keep &= ~line
                    removed = True
    if np.all(keep):
        return lat, lab
    misses = dict(lat.misses)
    misses.update({(int(a), int(b)): pts[i] for (a, b), i in zip(ab[~keep].tolist(), lat.index[~keep])})
    sub = Lattice(lat.index[keep], ab[keep], misses, lat.seed_score)
    flags = marker_flags(board, sub, pts, area, cut) if board.has_markers else None
    sub_lab = label_patch(board, sub.ab, flags, closed=_closed(sub), empty=empty_positions(sub, pts, inside))
    return (sub, sub_lab) if sub_lab.status == "labelled" else (lat, lab)


def empty_positions(lat: Lattice, points: np.ndarray, inside: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """The patch's misses (positions next to it looked at and holding no dot) that lie at least a local lattice step
    inside the image: there a dot of the board would have been whole and found, so the board ends there (or a dot
    is hidden). A miss nearer the border may be a dot cut by it.

    Parameters
    ----------
    lat : Lattice
        The patch.
    points : numpy.ndarray
        (M, 2) float candidate centres, px (``lat.index`` points into it).
    inside : callable
        (K, 2) px -> (K,) bool: which positions lie in the image.

    Returns
    -------
    numpy.ndarray
        (E, 2) int patch coordinates.
    """
    if not lat.misses:
        return np.zeros((0, 2), np.int64)
    pos = {tuple(q): points[i] for q, i in zip(lat.ab.tolist(), lat.index)}
    keys, tests = [], []
    for (a, b), xy in lat.misses.items():
        near = [pos[q] for q in ((a + 1, b), (a - 1, b), (a, b + 1), (a, b - 1)) if q in pos]
        if not near:
            continue
        step = max(float(np.linalg.norm(np.asarray(xy) - q)) for q in near)
        keys.append((a, b))
        tests.append(np.asarray(xy) + step * np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]], np.float64))
    if not keys:
        return np.zeros((0, 2), np.int64)
    ok = inside(np.concatenate(tests)).reshape(len(keys), 5).all(axis=1)
    return np.asarray(keys, np.int64)[ok].reshape(-1, 2)


def _image_test(image_size: tuple[int, int]) -> Callable[[np.ndarray], np.ndarray]:
    """Which pixel positions (K, 2) lie in an image of ``image_size`` (W, H)."""
    W, H = image_size

    def test(xy: np.ndarray) -> np.ndarray:
        return (xy[:, 0] >= 0.0) & (xy[:, 0] <= W - 1) & (xy[:, 1] >= 0.0) & (xy[:, 1] <= H - 1)

    return test


def _closed(lat: Lattice) -> bool:
    """Every 4-neighbour of the patch was looked at inside the image and holds no dot."""
    occ = {tuple(q) for q in lat.ab.tolist()}
    for a, b in occ:
        for q in ((a + 1, b), (a - 1, b), (a, b + 1), (a, b - 1)):
            if q not in occ and q not in lat.misses:
                return False
    return True


def _spans(board: Board, points: np.ndarray) -> bool:
    """The labelled board points span :data:`MIN_PARTIAL_LINES` rows and columns (or all of a smaller board's)."""
    i, j = np.divmod(points, board.cols)
    return len(np.unique(i)) >= min(MIN_PARTIAL_LINES, board.rows) and len(np.unique(j)) >= min(
        MIN_PARTIAL_LINES, board.cols
    )


def recognise(
    board: Board,
    cands: list[Candidate],
    image_size: tuple[int, int],
    deadline: Deadline | None = None,
    camera: Camera | None = None,
    expected: np.ndarray | None = None,
) -> Recognition:
    """The board among the candidates ``cands`` (module docstring).

    Parameters
    ----------
    board : Board
    cands : list of Candidate
        (M,) candidate dots, full-image px.
    image_size : tuple of int
        (W, H) px.
    deadline : Deadline, optional
        Raises :class:`~circcal.detector.locate.budget.BudgetExceeded` past it.
    camera : Camera, optional
        The lens model: the lattice is recognised on the candidates undistorted
        (:func:`~circcal.detector.locate.undistorted.undistorted_candidates`), and on their pixel positions only where
        that finds no board and claims nothing decisive (a model far from the lens must not lose a board the pixels
        show). Orientation and notes use the pixel positions either way.
    expected : ndarray or None, optional
        (N, 2) px where each board point is expected in the image (NaN: not known), e.g. from a rig's other cameras:
        a part of an unmarked board that fits several places on it is labelled by the place near its expected image
        (:func:`~circcal.detector.locate.labels.nearest_labelling`), not refused as ambiguous.

    Returns
    -------
    Recognition
        ``order`` indexes ``cands``, whichever positions recognised it.
    """
    M = len(cands)
    if M == 0:
        return Recognition(None, code=Reason.TOO_FEW_CANDIDATES, message="no candidate dots")
    pix = np.array([c.centre for c in cands], np.float64)
    axes = np.array([c.axes for c in cands], np.float64)
    ang = np.array([c.angle for c in cands], np.float64)
    area = np.pi * axes[:, 0] * axes[:, 1]
    cut = np.array([c.cut for c in cands], bool)
    if camera is None:
        return _recognise(board, pix, pix, axes, ang, area, cut, image_size, deadline, M, expected=expected)
    keep, u_pts, u_axes, u_ang, u_area = undistorted_candidates(pix, axes, ang, area, camera)
    rec = _recognise(
        board,
        u_pts,
        pix[keep],
        u_axes,
        u_ang,
        u_area,
        cut[keep],
        image_size,
        deadline,
        M,
        inside_image(camera),
        expected=expected,
    )
    if rec.order is not None:
        rec.order = np.where(rec.order >= 0, keep[np.maximum(rec.order, 0)], -1)
        return rec
    if rec.decisive:
        return rec
    raw = _recognise(board, pix, pix, axes, ang, area, cut, image_size, deadline, M, expected=expected)
    return raw if raw.order is not None or telling(raw) >= telling(rec) else rec


def telling(rec: Recognition) -> int:
    """How much a refusal tells (the one reported when no segmentation finds the board).

    Parameters
    ----------
    rec : Recognition
        A recognition that did not find the board.

    Returns
    -------
    int
        4 a mismatch of --grid, 3 of markers, 2 an ambiguous view, 1 too few points, 0 not recognised (or anything
        else).
    """
    return {
        Reason.GRID_MISMATCH: 4,
        Reason.MARKERS_INCONSISTENT: 3,
        Reason.AMBIGUOUS_VIEW: 2,
        Reason.TOO_FEW_POINTS: 1,
    }.get(rec.code, 0)


def _recognise(
    board: Board,
    pts: np.ndarray,
    pix: np.ndarray,
    axes: np.ndarray,
    ang: np.ndarray,
    area: np.ndarray,
    cut: np.ndarray,
    image_size: tuple[int, int],
    deadline: Deadline | None,
    M: int,
    inside: Callable[[np.ndarray], np.ndarray] | None = None,
    *,
    expected: np.ndarray | None = None,
) -> Recognition:
    """:func:`recognise` on candidates given as arrays: ``pts`` (K, 2) px the positions the lattice is recognised
    on (the pixel positions, or undistorted ones with the test ``inside`` of which lie in the image), ``pix`` (K, 2)
    px their pixel positions (orientation, notes), ``axes`` (K, 2), ``ang`` (K,), ``area`` (K,) their ellipses in
    the frame of ``pts``, ``cut`` (K,) bool; ``M`` the candidates counted in the messages; ``expected`` as
    :func:`recognise` takes it. ``order`` indexes these K candidates."""
    N = board.n_points
    if len(pts) == 0:
        return Recognition(None, code=Reason.TOO_FEW_CANDIDATES, message="no candidate dots")
    if board.layout == "symmetric" and not board.has_markers and len(pts) == N and not cut.any():
        idx = order_lattice(board, pts)
        if idx is not None:
            o = orient(board, pix[idx], idx)
            if o is not None:
                return Recognition(o, True, cut=np.zeros(N, bool), notes=big_dot_notes(board, o, area, cut))
    patches = find_lattices(
        pts, axes, ang, area, image_size, min_seed_score=seed_score_needed(board), deadline=deadline, inside=inside
    )
    if not patches:
        return Recognition(
            None,
            code=Reason.GRID_NOT_RECOGNISED,
            message=f"not recognised among {M} candidate dots (no lattice of dots)",
        )
    patches = [p for p in patches if _regular(board, p, pts, area)]
    if not patches:
        return Recognition(
            None,
            code=Reason.GRID_NOT_RECOGNISED,
            message=f"not recognised among {M} candidate dots (no regular lattice of dots)",
        )
    labelled: list[tuple[Lattice, Labelling]] = []
    in_image = inside if inside is not None else _image_test(image_size)
    for lat in patches[:MAX_LABELLED]:
        if deadline is not None:
            deadline.check()
        flags = marker_flags(board, lat, pts, area, cut) if board.has_markers else None
        empty = empty_positions(lat, pts, in_image) if board.has_markers else None
        lab = label_patch(board, lat.ab, flags, closed=_closed(lat), empty=empty)
        if lab.status == "larger":  # a blob or texture beside the board is not a row of the board
            lat, lab = _trimmed(board, lat, pts, area, cut, lab, in_image)
        if lab.status == "ambiguous" and expected is not None:  # the place seen, where its image is expected
            chosen_points = nearest_labelling(board, lab.alternatives, pix[lat.index], expected)
            if chosen_points is not None:
                lab = Labelling("labelled", "", chosen_points, False, lab.size, 1)
        labelled.append((lat, lab))
    whole = [(lat, lab) for lat, lab in labelled if lab.status == "labelled" and lab.complete]
    part = [
        (lat, lab)
        for lat, lab in labelled
        if lab.status == "labelled"
        and not lab.complete
        and _spans(board, lab.points)
        and int(np.sum(~cut[lat.index])) >= MIN_PARTIAL_POINTS
    ]
    chosen = whole[0] if whole else (part[0] if part else None)
    notes = _notes(board, labelled, chosen, pix, bool(whole))
    if chosen is None:
        lat, lab = labelled[0]
        if lab.status != "labelled" and (len(lat) < CLAIM_MIN_DOTS or lat.seed_score < 8):
            return Recognition(
                None,
                code=Reason.GRID_NOT_RECOGNISED,
                notes=notes,
                patches=len(patches),
                message=f"not recognised among {M} candidate dots (the only lattice, of "
                f"{len(lat)} dots, is too small to say more)",
            )
        code = {
            "larger": Reason.GRID_MISMATCH,
            "transposed": Reason.GRID_MISMATCH,
            "layout": Reason.GRID_MISMATCH,
            "smaller": Reason.GRID_MISMATCH,
            "markers": Reason.MARKERS_INCONSISTENT,
            "ambiguous": Reason.AMBIGUOUS_VIEW,
        }.get(lab.status, Reason.TOO_FEW_POINTS)
        msg = lab.message or (
            f"only {int(np.sum(~cut[lat.index]))} dots of the board seen "
            f"(a partial view needs {MIN_PARTIAL_POINTS}, over {MIN_PARTIAL_LINES} rows and "
            "columns)"
        )
        if not board.has_markers and lab.status in ("ambiguous", "labelled"):
            big, ratio = big_dots(lat.ab, area[lat.index], cut[lat.index])
            if len(big):
                msg += "; " + big_dot_words(board, len(big), ratio)
        return Recognition(
            None,
            code=code,
            message=msg,
            notes=notes,
            patches=len(patches),
            decisive=lab.status in ("larger", "transposed", "layout"),
        )
    lat, lab = chosen
    order = np.full(N, -1, np.int64)
    order[lab.points] = lat.index
    cut_pts = np.zeros(N, bool)
    cut_pts[lab.points] = cut[lat.index]
    if not board.has_markers:
        order = orient(board, np.where((order >= 0)[:, None], pix[np.maximum(order, 0)], np.nan), order)
        if order is None:
            return Recognition(
                None,
                code=Reason.GRID_NOT_RECOGNISED,
                message="no labelling of the grid is seen from the board's front (a mirrored image?)",
                notes=notes,
                patches=len(patches),
            )
        cut_pts = np.where(order >= 0, cut[np.maximum(order, 0)], False)
        notes += big_dot_notes(board, order, area, cut)
    return Recognition(order, lab.complete, cut=cut_pts, notes=notes, patches=len(patches))


def _notes(board: Board, labelled: list[tuple[Lattice, Labelling]], chosen, pts: np.ndarray, whole: bool) -> list[str]:
    """Other lattices in view, in words (module docstring)."""
    notes = []
    least = max(NOTE_MIN_DOTS, int(np.ceil(NOTE_MIN_SHARE * board.n_points)))
    others = [(lat, lab) for lat, lab in labelled if chosen is None or lat is not chosen[0]]
    for lat, lab in others:
        if len(lat) < least:
            continue
        c = pts[lat.index].mean(axis=0)
        what = {
            "labelled": "another board like this one" if lab.complete else "another part of a board",
            "larger": "a larger dot grid",
            "transposed": "a dot grid of the transposed size",
            "layout": "a dot grid of the other layout",
            "smaller": "a smaller dot grid",
            "ambiguous": "a dot grid that could be part of the board",
            "markers": "a dot grid with other markers",
        }.get(lab.status, "a dot grid")
        rows, cols = lab.size
        notes.append(f"{what} ({len(lat)} dots, {rows}x{cols}) in view around ({c[0]:.0f}, {c[1]:.0f}) px: not used")
    if chosen is not None and notes:
        c = pts[chosen[0].index].mean(axis=0)
        two = any(lab.status == "labelled" and lab.complete and len(lat) >= least for lat, lab in others)
        notes.insert(
            0,
            f"{'two boards' if two else 'more than one dot grid'} in view: used the "
            f"{len(chosen[0])} dots around ({c[0]:.0f}, {c[1]:.0f}) px"
            f"{' (the larger board)' if two else ''}",
        )
    return notes


def order_grid(board: Board, points: np.ndarray, radii: np.ndarray, image_shape: tuple[int, int]) -> np.ndarray | None:
    """Recognise the whole board among candidate dots and order it (:func:`recognise` on round candidates).

    Parameters
    ----------
    board : Board
        The board.
    points : numpy.ndarray
        (M, 2) float candidate centres, px.
    radii : numpy.ndarray
        (M,) float their rough radii, px.
    image_shape : tuple of int
        (H, W) px.

    Returns
    -------
    numpy.ndarray or None
        (N,) int indices into ``points`` in board order (orientation rule of :mod:`circcal.detector.locate.grid`),
        or ``None`` when the whole board is not among them.

    Examples
    --------
    >>> board = Board(4, 5, 10.0, 5.0)
    >>> points = board.object_points()[:, :2] * 3 + 40
    >>> order_grid(board, points[::-1], np.full(20, 7.5), (200, 240)).tolist()[:3]
    [19, 18, 17]
    """
    points = np.asarray(points, np.float64).reshape(-1, 2)
    radii = np.asarray(radii, np.float64).reshape(-1)
    cands = [Candidate(p, (float(r), float(r)), 0.0, float(np.pi * r * r)) for p, r in zip(points, radii)]
    rec = recognise(board, cands, (int(image_shape[1]), int(image_shape[0])))
    if rec.order is None or not rec.complete or np.any(rec.order < 0):
        return None
    return rec.order
