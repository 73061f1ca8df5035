"""Circle-grid detection with unbiased centre projections: :func:`detect` on one image, :func:`recorrect` for
another camera model.

:func:`detect` runs, on one image:

1. grey conversion and a contrast stretch (:mod:`circcal.detector.image`), and segmentation that survives
   uneven/strong/weak illumination (:mod:`circcal.detector.locate.segment`; the guided filter where the image is noisy), on
   a copy shrunk to a short side of 360-719 px first for images of 720 px and more (full resolution when that fails,
   a finer scale when the dots are small; only the starting ellipses come from it);
2. candidate dots from contours, filtered by area (limits scaled to the image and the board's dot density),
   circularity, inertia ratio and convexity (:mod:`circcal.detector.locate.candidates`);
3. grid recognition and ordering in OpenCV's object-point order with circcal's orientation rule
   (:mod:`circcal.detector.locate.grid`); steps 1-3 over the scales and windows searched: :mod:`circcal.detector.locate.search`;
4. sub-pixel edge points on each dot's boundary (half-level crossings along ellipse normals, corrected for edge
   curvature: :mod:`circcal.detector.measure.edges`) and a direct least-squares ellipse fit
   (:mod:`circcal.detector.measure.ellipsefit`), for all dots at once (:func:`~circcal.detector.measure.dots.fit_dots`: one filtering
   call for the crops around all dots, batched interpolation, stacked 3x3 solves);
5. projective centre correction: each centre is the pole of the board's vanishing line w.r.t. its ellipse, the
   homography re-estimated from the corrected centres until stable (:mod:`circcal.detector.measure.centre`). With a camera
   model the edge points are undistorted first, the correction runs in the undistorted image and the centres are
   distorted back.

:func:`recorrect` repeats step 5 alone for another camera model, reusing the stored edge points (what a calibrator
iterating its distortion estimate needs; ~1 ms per view).

Pixel convention: OpenCV's (integer coordinates are pixel centres); centres in OpenCV's object-point order.
"""

from __future__ import annotations

import numpy as np

from circcal.board import Board
from circcal.detector.detection import Detection, Reason
from circcal.detector.image import as_gray
from circcal.detector.locate.budget import DEFAULT_TIME_BUDGET_S, BudgetExceeded, Deadline
from circcal.detector.locate.recognise import MIN_PARTIAL_POINTS, Recognition
from circcal.detector.locate.search import segment_and_recognise
from circcal.detector.measure.baddots import bad_dots
from circcal.detector.measure.centre import correct_centres, correct_centres_on_rays, fit_homography
from circcal.detector.measure.dots import EDGE_SIGMA, fit_dots
from circcal.detector.measure.ellipse import conic_from_params_batch, conic_params_batch
from circcal.detector.measure.ellipsefit import FIT_ERRORS, fit_ellipses_direct
from circcal.detector.measure.smoothing import SmoothedImage
from circcal.detector.measure.trust import ABSENT_MAX_SHARE, MAX_GAPS, absent_dots, check_grid, unseen_gaps
from circcal.errors import ImageError, InputError
from circcal.model import Camera, distort_pixels, undistort_pixels

__all__ = ["camera_size_mismatch", "detect", "recorrect"]


def camera_size_mismatch(camera: Camera | None, width: int, height: int) -> str | None:
    """Why ``camera`` cannot serve an image of ``width`` x ``height`` px (its model is for another size).

    Parameters
    ----------
    camera : Camera or None
        The camera model, or ``None`` (no model: always fits).
    width, height : int
        The image's size, px.

    Returns
    -------
    str or None
        One line saying both sizes when they differ; ``None`` when the camera fits (or there is no camera).

    Examples
    --------
    >>> camera_size_mismatch(None, 640, 480) is None
    True
    """
    if camera is not None and (camera.width, camera.height) != (width, height):
        return f"camera model is for {camera.width}x{camera.height} images, image is {width}x{height}"
    return None


def _check_camera(camera: Camera | None, width: int, height: int) -> None:
    """Raise :class:`~circcal.errors.ImageError` when ``camera`` is for another image size."""
    why = camera_size_mismatch(camera, width, height)
    if why is not None:
        raise ImageError(why)


def detect(
    image: np.ndarray,
    board: Board,
    camera: Camera | None = None,
    *,
    time_budget_s: float | None = DEFAULT_TIME_BUDGET_S,
    expected: np.ndarray | None = None,
) -> Detection:
    """Find ``board``'s circle grid in ``image`` and return the images of the circle centres.

    The board may be partly out of frame or occluded: the dots seen are labelled when that is unambiguous (a marker
    board, or the board's whole extent in view), the others are NaN. Never raises for a grid that is not there
    (``found=False`` with a reason).

    Parameters
    ----------
    image : numpy.ndarray
        (H, W) grey or (H, W, 3) BGR, uint8/uint16/float; dark dots on a bright board (a board of bright dots on a
        dark ground is found on the inverted image, and the detection says so in its notes).
    board : Board
        The circle-grid board to find (not a checkerboard).
    camera : Camera or None, optional
        Camera model for images of this size; when given, the board's lattice is recognised among the candidate
        dots undistorted by it (the rows of a wide lens's view bend beyond what the pixel positions' checks follow)
        and the centre correction accounts for its lens distortion.
    time_budget_s : float or None, optional
        Seconds this image may take (:data:`~circcal.detector.locate.budget.DEFAULT_TIME_BUDGET_S`; ``None``: no
        limit); past it the image is not found with :attr:`Reason.TIME_BUDGET`.
    expected : ndarray or None, optional
        (N, 2) px where each board point is expected in the image (NaN: not known), e.g. projected through a rig
        from its other cameras' views of the same instant: a part of a board without markers that fits several
        places on it is labelled by the one near its expected image instead of being refused as ambiguous.

    Returns
    -------
    Detection
        ``found`` with (N, 2) centres (px, OpenCV's convention, board order; NaN for dots not measured), edge
        points, conics and the homography; or ``found=False`` with a reason and its :class:`Reason` code.

    Raises
    ------
    circcal.errors.ImageError
        An image it cannot take (wrong shape/dtype), or a camera model for another image size.
    circcal.errors.InputError
        ``board`` is a checkerboard.

    Examples
    --------
    >>> import cv2
    >>> d = detect(cv2.imread("view.png"), board)  # doctest: +SKIP
    >>> d.found, d.centres.shape  # doctest: +SKIP
    (True, (44, 2))
    """
    deadline = Deadline(time_budget_s)
    gray = as_gray(image)
    H, W = gray.shape
    _check_camera(camera, W, H)
    if board.layout == "checkerboard":
        raise InputError("circcal detect finds circle grids; the board is a checkerboard")
    try:
        return _detect(gray, board, camera, deadline, expected=expected)
    except BudgetExceeded:
        return Detection(
            False,
            None,
            f"not found: time budget exceeded ({deadline.budget_s:g} s; the image has dense dot-like texture?)",
            Reason.TIME_BUDGET,
            image_size=(W, H),
        )


BRIGHT_DOTS_NOTE = "bright dots on a dark board: found on the inverted image"
"""The note of a detection made on the inverted image (:func:`_not_found`)."""


def _not_found(
    board: Board,
    rec: Recognition,
    best: int,
    gray: np.ndarray,
    camera: Camera | None,
    deadline: Deadline,
    inverted: bool,
) -> Detection:
    """The Detection of an image without the board (dark dots on a bright board): the recognition's reason; where
    the inverted image shows the board's lattice (bright dots on a dark board), the detection on the inverted image
    when it is found there (noted: :data:`BRIGHT_DOTS_NOTE`), else the reason with what the inverted image gave.
    ``inverted``: ``gray`` is the inverted image already (no second inversion)."""
    H, W = gray.shape
    grid = f"grid {board.rows}x{board.cols} ({board.layout})"
    if rec.code == Reason.TOO_FEW_CANDIDATES or best < min(board.n_points, MIN_PARTIAL_POINTS):
        code = Reason.TOO_FEW_CANDIDATES
        msg = f"{grid} not found: at most {best} candidate dots, {min(board.n_points, MIN_PARTIAL_POINTS)} needed"
        if rec.code == Reason.TOO_FEW_CANDIDATES and rec.message:
            msg += f": {rec.message}"
    else:
        code = rec.code or Reason.GRID_NOT_RECOGNISED
        msg = (
            f"{grid} not found: {rec.message}" if rec.message else f"{grid} not recognised among {best} candidate dots"
        )
        if code == Reason.GRID_NOT_RECOGNISED and "candidate dots" not in msg:
            msg += f" ({best} candidate dots)"
    if not inverted and code in (Reason.TOO_FEW_CANDIDATES, Reason.GRID_NOT_RECOGNISED):
        inv = _invert(gray)
        if _shows_board(inv, board, deadline, camera):
            d = _detect(inv, board, camera, deadline, inverted=True)
            if d.found:
                d.notes = [*d.notes, BRIGHT_DOTS_NOTE]
                return d
            msg += f"; the image holds a grid of bright dots on a dark ground, but inverted: {d.reason}"
    return Detection(False, None, msg, code, image_size=(W, H), notes=list(rec.notes))


def _invert(gray: np.ndarray) -> np.ndarray:
    """``gray`` (H, W) with dark and bright swapped, in its own dtype and range (``max - gray``: non-negative, as
    the edge levels need)."""
    return gray.max() - gray


def _shows_board(gray: np.ndarray, board: Board, deadline: Deadline, camera: Camera | None) -> bool:
    """Whether the first segmentation of ``gray`` shows the board's lattice (whole or in part): the quick test
    before a whole detection on the inverted image (recognised in ``camera``'s undistorted image, where given)."""
    rec, *_ = segment_and_recognise(gray, board, deadline, first_only=True, camera=camera)  # (out of time: by detect)
    return rec.order is not None


def _detect(
    gray: np.ndarray,
    board: Board,
    camera: Camera | None,
    deadline: Deadline,
    *,
    inverted: bool = False,
    expected: np.ndarray | None = None,
) -> Detection:
    H, W = gray.shape
    rec, cands, seg_name, best = segment_and_recognise(gray, board, deadline, camera=camera, expected=expected)
    if rec.order is None:
        return _not_found(board, rec, best, gray, camera, deadline, inverted)
    N = board.n_points
    seen = rec.order >= 0
    absent = np.zeros(0, np.int64)
    if not rec.complete and not board.has_markers:
        lab = np.nonzero(seen)[0]
        absent = absent_dots(
            board,
            lab,
            np.array([cands[rec.order[k]].centre for k in lab]),
            np.array([np.sqrt(cands[rec.order[k]].axes[0] * cands[rec.order[k]].axes[1]) for k in lab]),
            gray,
            camera,
        )
        gaps = unseen_gaps(
            board,
            lab,
            np.array([cands[rec.order[k]].centre for k in lab]),
            np.array([np.sqrt(cands[rec.order[k]].axes[0] * cands[rec.order[k]].axes[1]) for k in lab]),
            gray.shape,
            camera,
            skip=absent,
        )
        if gaps > MAX_GAPS:
            return Detection(
                False,
                None,
                f"grid {board.rows}x{board.cols} not recognised: a lattice of {int(seen.sum())} dots fits part of "
                f"the board, but the board's dots it does not see lie in {gaps} separate gaps inside the image (a "
                "dot lattice of another shape? a board cut by the image border or hidden from one side leaves one)",
                Reason.GRID_NOT_RECOGNISED,
                image_size=(W, H),
                notes=list(rec.notes),
            )
        if len(absent) > ABSENT_MAX_SHARE * len(lab):
            return Detection(
                False,
                None,
                f"grid {board.rows}x{board.cols} not recognised: a lattice of "
                f"{int(seen.sum())} dots fits part of the board, but {len(absent)} of the "
                "board's other dots would lie on bare board inside the image (a dot "
                "lattice of another layout?)",
                Reason.GRID_NOT_RECOGNISED,
                image_size=(W, H),
                notes=list(rec.notes),
            )
    dropped = {
        int(k): "not seen: the image is as white as the bare board where it lies (glare, or no dot?)" for k in absent
    }
    dropped.update({int(k): "cut by the image border" for k in np.nonzero(seen & rec.cut)[0]})
    todo = np.nonzero(seen & ~rec.cut)[0]
    Q0 = conic_from_params_batch(
        np.array([cands[rec.order[k]].centre for k in todo]),
        np.array([cands[rec.order[k]].axes for k in todo]),
        np.array([cands[rec.order[k]].angle for k in todo]),
    )
    pts, mask, conics_d, errors = fit_dots(SmoothedImage(gray, EDGE_SIGMA), Q0)
    deadline.check()
    params = conic_params_batch(conics_d)  # (row by row: the same values as of any subset of the rows)
    dropped.update(bad_dots(board, todo, pts, mask, conics_d, errors, (W, H), gray, params=params))
    keep = np.array([int(k) not in dropped for k in todo], bool)
    used = todo[keep]
    cand_xy = np.array([c.centre for c in cands])
    need = min(N, MIN_PARTIAL_POINTS)
    if len(used) < need:
        return Detection(
            False,
            None,
            f"grid {board.rows}x{board.cols} recognised, but only {len(used)} of its "
            f"{int(seen.sum())} dots in view are measurable ({need} needed; "
            f"{len(dropped)} left out: " + _why(dropped) + ")" + _view_wide(dropped, int(seen.sum())),
            Reason.TOO_FEW_POINTS,
            image_size=(W, H),
            candidates=cand_xy,
            dropped=dropped,
            notes=list(rec.notes),
        )
    kept = tuple(p[keep] for p in params)
    ell_c = kept[0]
    try:  # one fit serves the lattice check and the centre correction
        H0 = fit_homography(board.object_points()[used, :2], ell_c)
    except ValueError:
        H0 = None
    why = check_grid(board, used, ell_c, conics_d[keep], params=kept, H=H0, camera=camera)
    if why is not None:
        return Detection(
            False,
            None,
            f"grid {board.rows}x{board.cols} not trusted: {why}",
            Reason.IRREGULAR_GRID,
            image_size=(W, H),
            candidates=cand_xy,
            dropped=dropped,
            notes=list(rec.notes),
        )
    flat = pts[keep][mask[keep]]  # the kept dots' points, dot after dot (one boolean index, not K)
    ends = np.cumsum(mask[keep].sum(axis=1)).tolist()
    edge_points = [np.zeros((0, 2))] * N  # (the empty entries share one (0, 2) array)
    for i, a, b in zip(used.tolist(), [0] + ends[:-1], ends):
        edge_points[i] = flat[a:b]
    try:
        centres, conics, Hb = _correct(edge_points, board, camera, conics_d[keep], used, H0=H0)
    except ValueError as exc:
        return Detection(
            False,
            None,
            f"centre correction failed: {exc}",
            Reason.CENTRE_CORRECTION_FAILED,
            edge_points=edge_points,
            image_size=(W, H),
        )
    ellipse_centres = np.full((N, 2), np.nan)
    ellipse_centres[used] = ell_c
    return Detection(
        True,
        centres,
        None,
        edge_points=edge_points,
        conics=conics,
        ellipse_centres=ellipse_centres,
        homography=Hb,
        candidates=cand_xy,
        image_size=(W, H),
        segmentation=seg_name,
        complete=rec.complete,
        dropped=dict(sorted(dropped.items())),
        notes=list(rec.notes),
    )


def _reason_counts(dropped: dict[int, str]) -> dict[str, int]:
    """Reason (its words before any figures in brackets) -> how many dropped dots it names."""
    counts: dict[str, int] = {}
    for r in dropped.values():
        key = r.split(" (")[0]
        counts[key] = counts.get(key, 0) + 1
    return counts


def _why(dropped: dict[int, str]) -> str:
    """The reasons of dropped dots, counted: "3 cut by the image border, 1 edge found on 60% of its rim"."""
    return ", ".join(f"{n} {r}" for r, n in _reason_counts(dropped).items()) or "none"


VIEW_WIDE_SHARE = 0.75
"""When one measured reason (not the image border, not a dot unseen) leaves out at least this share of the dots in
view, the refusal says so: what befalls nearly every dot alike is the whole view's (a shaken or defocused camera, a
board other than the one described), not an occluder's."""


def _view_wide(dropped: dict[int, str], in_view: int) -> str:
    """The hint of :data:`VIEW_WIDE_SHARE` for a view whose ``in_view`` dots lost ``dropped``, or ""."""
    counts = {
        r: n
        for r, n in _reason_counts(dropped).items()
        if r != "cut by the image border" and not r.startswith("not seen")
    }
    if not counts or max(counts.values()) < VIEW_WIDE_SHARE * in_view:
        return ""
    return (
        "; nearly every dot alike: something over the whole view (motion blur, defocus, a board other than the "
        "one described?) rather than occluders"
    )


def recorrect(detection: Detection, board: Board, camera: Camera | None) -> np.ndarray:
    """The centres of a found ``detection`` corrected again with another camera model, from its stored edge points.

    Undistort the edge points, refit the ellipses, iterate homography/poles in the undistorted image, distort back
    (a fisheye: each dot on its own local perspective re-projection,
    :func:`~circcal.detector.measure.centre.correct_centres_on_rays`). What a calibrator iterating its distortion
    estimate needs (~1 ms per view).

    Parameters
    ----------
    detection : Detection
        A found detection (from :func:`detect`) with its edge points.
    board : Board
        The board it was found for.
    camera : Camera or None
        The camera model whose distortion the correction removes; ``None``: no distortion.

    Returns
    -------
    numpy.ndarray
        (N, 2) float centres, px, board order. Points not seen (no edge points) stay NaN, and so do the dots whose
        rim a pinhole ``camera``'s distortion cannot invert (beyond the fold of its polynomial,
        :func:`~circcal.model.undistort`: a lens model too simple for the lens); the caller says what it does with
        those.

    Raises
    ------
    ValueError
        ``detection`` was not found (or has no edge points), an ellipse cannot be fitted, or no board homography
        fits the centres.
    circcal.errors.ImageError
        ``camera`` is for another image size than the detection's.
    """
    if not detection.found or detection.edge_points is None:
        raise ValueError(f"cannot re-correct a detection that was not found ({detection.reason})")
    if detection.image_size is not None:
        _check_camera(camera, *detection.image_size)
    used = np.array([k for k, p in enumerate(detection.edge_points) if len(p)], np.int64)
    return _correct(detection.edge_points, board, camera, None, used, drop_uninvertible=True)[0]


def _correct(
    edge_points: list[np.ndarray],
    board: Board,
    camera: Camera | None,
    conics: np.ndarray | None,
    used: np.ndarray,
    *,
    drop_uninvertible: bool = False,
    H0: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (N, 2) in the observed image (NaN for points not in ``used``), conics (N, 3, 3) in the undistorted
    image (NaN likewise), H board -> undistorted image, from the ``edge_points`` (N lists of (M_k, 2) px, board
    order, observed image) of the board points ``used`` (K,). ``conics``: (K, 3, 3) the ellipses already fitted
    to those edge points (observed image), reused when there is no distortion to remove, with ``H0``, the homography
    board -> their centres, where the caller has it. ``drop_uninvertible``: a
    dot whose rim a pinhole ``camera``'s distortion cannot invert everywhere is left out (NaN) instead of fitted.
    Raises ``ValueError`` when an ellipse cannot be fitted or no board homography fits the centres. A fisheye ``camera``: the centres from
    :func:`~circcal.detector.measure.centre.correct_centres_on_rays`, the conics those given (observed image; else NaN) and
    H board -> rays."""
    N = board.n_points
    obj = board.object_points()[used, :2]
    fisheye = camera is not None and not camera.model.pinhole
    distorted = camera is not None and np.any(camera.dist) and not fisheye
    reuse = conics is not None and not (distorted or fisheye)
    if not reuse:
        sub = [edge_points[k] for k in used]
        counts = [len(p) for p in sub]
        width = max(counts) if counts else 0
        P = np.zeros((len(sub), width, 2))
        M = np.zeros((len(sub), width), bool)
        for i, p in enumerate(sub):
            P[i, : len(p)] = p
            M[i, : len(p)] = True
        if fisheye:
            c, H = correct_centres_on_rays(P, M, obj, camera)
            centres = np.full((N, 2), np.nan)
            centres[used] = c
            all_conics = np.full((N, 3, 3), np.nan)
            if conics is not None:
                all_conics[used] = conics
            return centres, all_conics, H
        if distorted:
            P[M] = undistort_pixels(P[M], camera)
            finite = np.isfinite(P[..., 0]) & np.isfinite(P[..., 1])
            if drop_uninvertible:
                keep = ~np.any(M & ~finite, axis=1)
                P, M, finite, used, obj = P[keep], M[keep], finite[keep], used[keep], obj[keep]
            M &= finite
        conics, err = fit_ellipses_direct(P, M)
        if np.any(err):
            i = int(np.argmax(err != 0))
            msg = FIT_ERRORS[int(err[i])]
            raise ValueError(f"{msg}, got {int(M[i].sum())}" if err[i] == 1 else msg)
    c, H = correct_centres(conics, obj, H0=H0 if reuse else None)
    if distorted:
        c = distort_pixels(c, camera)
    centres = np.full((N, 2), np.nan)
    centres[used] = c
    all_conics = np.full((N, 3, 3), np.nan)
    all_conics[used] = conics
    return centres, all_conics, H
