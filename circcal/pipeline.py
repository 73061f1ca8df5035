"""The detect -> calibrate -> re-correct pipeline: images in, a calibrated model out.

:func:`calibrate_images` detects the board in every image (:mod:`circcal.detector`), calibrates
(:func:`circcal.solver.calibrate`), re-corrects every centre under the current model (perspective and distortion,
:func:`circcal.detector.recorrect`) and recalibrates until no centre moves more than ``tol_px``;
:func:`calibrate_detections` is that loop on detections already made.
"""

from __future__ import annotations

import hashlib
import os
import stat
import warnings
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from circcal import detector as det_mod
from circcal.detector import Detection, Reason, Rejection
from circcal.errors import CalibrationError, InputError
from circcal.formats import model_json
from circcal.imagefiles import image_list
from circcal.observations import MIN_VIEWS, same_views
from circcal.pathnames import display_name, path_to_json
from circcal.solver import CalibrationOptions, CalibrationResult, calibrate, leave_one_out

__all__ = [
    "MAX_ROUNDS",
    "ImagesCalibration",
    "TooFewImagesError",
    "calibrate_images",
    "calibrate_detections",
    "holdout_detections",
    "duplicates_of",
    "detect_once",
    "choose_lens",
    "LensChoice",
    "LENS_CANDIDATES",
    "RECOVERABLE",
]


MAX_ROUNDS = 8
"""Calibrations of the re-correction loop at most. Most cameras settle below ``tol_px`` in 2-4; a wide lens fitted
with the rational model converges more slowly, each round's centre shift ~5-10x the next (rational-wide clean:
0.56, 0.029, 0.015, 0.0028, 3.0e-4, 1.9e-5 px: settled in the 7th calibration, which 6 rounds cut off)."""


#: Reasons a view refused by the first detection (no model) may be found by a second one with the first model: the
#: lattice of a strongly distorted board is recognised on undistorted candidates, its centres checked under the lens.
RECOVERABLE = frozenset(
    {
        Reason.GRID_NOT_RECOGNISED,
        Reason.IRREGULAR_GRID,
        Reason.AMBIGUOUS_VIEW,
        Reason.TOO_FEW_POINTS,
        Reason.GRID_MISMATCH,
        Reason.CENTRE_CORRECTION_FAILED,
    }
)

#: The lens models ``--lens auto`` tries, simplest first (a later one is chosen only where it predicts held-out views
#: better by more than :data:`AUTO_MARGIN`).
LENS_CANDIDATES = ("opencv5", "fisheye", "rational")
AUTO_MARGIN = 0.05
"""A richer lens model is chosen over a simpler one only where its held-out RMS is lower by more than this share:
within it the two predict alike, and the simpler model extrapolates more safely beyond the observed field."""


@dataclass(frozen=True)
class LensChoice:
    """How :func:`choose_lens` chose.

    Attributes
    ----------
    lens : str
        The model chosen.
    why : str
        In words.
    candidates : tuple of dict
        One row per model tried: ``{"lens", "rms_per_point_px", "heldout_rms_px", "fits", "error"}`` (``error``: why it
        gave no model).
    """

    lens: str
    why: str
    candidates: tuple[dict[str, Any], ...]

    def lines(self) -> list[str]:
        """The console summary: the choice, then one line per candidate.

        Returns
        -------
        list of str
        """
        out = [f"lens model chosen (--lens auto): {self.lens}: {self.why}"]
        for c in self.candidates:
            if c.get("error"):
                out.append(f"  {c['lens']:>10}: no model ({c['error']})")
            else:
                out.append(
                    f"  {c['lens']:>10}: RMS per point {c['rms_per_point_px']:.4f} px, held-out RMS per point "
                    f"{c['heldout_rms_px']:.4f} px, residuals "
                    + {True: "fit the model", False: "hold a radial pattern", None: "too few to tell"}[c["fits"]]
                )
        return out


class TooFewImagesError(CalibrationError):
    """Fewer images with the board found than a calibration needs.

    Parameters
    ----------
    message : str
    rejected : list of Rejection
        Every image left out (:class:`circcal.detector.Rejection`: path, code, reason); kept as ``rejected``.
    """

    def __init__(self, message: str, rejected: list[Rejection]):
        super().__init__(message)
        self.rejected = list(rejected)


@dataclass
class ImagesCalibration:
    """Outcome of :func:`calibrate_images`.

    Attributes
    ----------
    result : CalibrationResult
        The final model.
    paths : list of str
        All inputs.
    detections : list of Detection
        One per path (``circcal.detector.Detection``).
    used : list of int
        Indices of the paths in the model (the views of ``result``, in order).
    failed : list of Rejection
        A :class:`~circcal.detector.Rejection` (path, code, reason) for every image left out.
    rounds : list of dict
        Per calibration round ``{"round", "rms_per_point_px", "rms_per_coord_px", "mean_2d_px",
        "max_centre_shift_px"}``.
    centres : list of ndarray, each shape (N, 2)
        The final (re-corrected) centres of each used view, px in board order, NaN where a point was not detected.
    recovered : list of str
        Paths of views the first detection refused and a second pass with the first model found
        (:data:`RECOVERABLE`).
    lens_choice : LensChoice or None
        How ``--lens auto`` chose the lens model; None when the lens was given.
    """

    result: CalibrationResult
    paths: list[str]
    detections: list[Any]
    used: list[int]
    failed: list[Rejection]
    rounds: list[dict] = field(default_factory=list)
    centres: list[np.ndarray] = field(default_factory=list)
    #: paths of views the first detection refused and a second pass with the first model found (:data:`RECOVERABLE`)
    recovered: list[str] = field(default_factory=list)
    #: how ``--lens auto`` chose the lens model (:class:`LensChoice`), None when the lens was given
    lens_choice: LensChoice | None = None

    def to_model_json(self, board) -> dict[str, Any]:
        """model.json (:func:`circcal.formats.model_json`): the result's sections, the board, every image left out (path,
        reason code, reason) and the re-correction rounds.

        Each view says which board points it used (``points``: indices, OpenCV's order; a partial view uses some) and
        which dots of it the detector left out as bad (``dots_dropped``: index -> reason, e.g. cut by the image border).
        View names and image paths are stored by :func:`circcal.pathnames.path_to_json` (lossless for names of any bytes;
        read them back with ``path_from_json``), the texts beside them by :func:`~circcal.pathnames.display_name`: no
        lone surrogate (a byte of a name that is not UTF-8) reaches JSON.

        Parameters
        ----------
        board : Board
            The board calibrated with.

        Returns
        -------
        dict
        """
        sections = self.result.model_sections()
        for entry, i, c in zip(sections.get("views", []), self.used, self.centres):
            if "name" in entry:
                entry["name"] = path_to_json(entry["name"])
            entry["points"] = np.nonzero(np.all(np.isfinite(c), axis=1))[0].tolist()
            entry["dots_dropped"] = {
                str(k): display_name(r) for k, r in getattr(self.detections[i], "dropped", {}).items()
            }
            for o in entry.get("outliers", []):
                o["detail"] = display_name(o["detail"])
        return model_json(
            self.result.camera,
            **sections,
            board=board.to_dict(),
            failed_images=[
                {"path": path_to_json(r.path), "reason_code": r.code.value, "reason": display_name(r.reason)}
                for r in self.failed
            ],
            recorrection_rounds=self.rounds,
        )

    def observations(self, board) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """The observations of each used view: the final centres with their board points (finite only), exactly what the
        final model was fitted to.

        Parameters
        ----------
        board : Board

        Returns
        -------
        object_points : list of ndarray, each shape (N_v, 3)
            mm.
        image_points : list of ndarray, each shape (N_v, 2)
            px.
        """
        pairs = [_points_of(c, board.object_points()) for c in self.centres]
        return [o for o, _ in pairs], [p for _, p in pairs]


def _points_of(centres: np.ndarray, board_points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keep the detected (finite) centres with their object points; a detector marks missing points with NaN."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    if len(c) != len(board_points):
        raise ValueError(f"detector returned {len(c)} centres for a board of {len(board_points)} points")
    ok = np.all(np.isfinite(c), axis=1)
    return board_points[ok], c[ok]


def duplicates_of(paths: Sequence[str]) -> dict[int, tuple[int, str]]:
    """Images given more than once.

    Only files whose byte size another file shares are read and hashed (files of different sizes cannot hold the
    same bytes). Files that cannot be read are left to the detector (it reports them).

    Parameters
    ----------
    paths : sequence of str

    Returns
    -------
    dict of int to (int, str)
        ``{i: (j, how)}`` for each path ``i`` that is the same file as an earlier path ``j`` (``how`` = "same file
        as"), or holds the same bytes ("identical content to").
    """
    out: dict[int, tuple[int, str]] = {}
    seen_file: dict[tuple[int, int], int] = {}
    by_size: dict[int, list[int]] = {}
    for i, p in enumerate(paths):
        try:
            st = os.stat(p)
        except OSError:
            continue
        if not stat.S_ISREG(st.st_mode):
            continue
        key = (st.st_dev, st.st_ino)
        if key in seen_file:
            out[i] = (seen_file[key], "same file as")
            continue
        seen_file[key] = i
        by_size.setdefault(st.st_size, []).append(i)
    for group in by_size.values():
        seen_bytes: dict[str, int] = {}
        for i in group if len(group) > 1 else ():
            try:
                digest = _sha256(paths[i])
            except OSError:
                continue
            if digest in seen_bytes:
                out[i] = (seen_bytes[digest], "identical content to")
            else:
                seen_bytes[digest] = i
    return dict(sorted(out.items()))


def _sha256(path: str) -> str:
    """The SHA-256 of a file's bytes, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def calibrate_images(
    paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    board,
    options: CalibrationOptions = CalibrationOptions(),
    *,
    progress: bool = True,
    jobs: int | None = None,
    image_size: tuple[int, int] | None = None,
    max_rounds: int = MAX_ROUNDS,
    tol_px: float = 1e-4,
    lens_candidates: Sequence[str] | None = None,
    second_pass: bool = True,
) -> ImagesCalibration:
    """Detect the board in every image, calibrate, then re-correct every centre under the current model
    (perspective and distortion aware, ``circcal.detector.recorrect``) and recalibrate, until no centre moves more than
    ``tol_px`` (typically 2-3 rounds) or ``max_rounds`` calibrations were made.

    Parameters
    ----------
    paths : str, Path, or iterable of them
        The image files; a folder stands for its images (:func:`circcal.imagefiles.image_list`).
    board : circcal.board.Board
    options : CalibrationOptions
        How every solve is made (:class:`circcal.solver.options.CalibrationOptions`). ``options.lens``: the lens
        model fitted; every re-correction goes through it (the fisheye's dot by dot, on a local perspective
        re-projection). ``options.refine_board``: estimate the board's 3-D shape as well. ``options.outlier_rule``:
        the dots the detector can tell are bad (:mod:`circcal.dotcheck`) are left out of every solve and each solve
        rejects outlying points and views (all listed in ``result.outliers``, the bad dots first; a dropped view's
        image goes to ``failed``, reason code ``outlier-view``); None fits every detected centre.
    progress : bool
        Show a progress bar.
    jobs : int or None
        Images detected at once (``circcal.detector.detect_files``; None = one per CPU; the result does not depend
        on it).
    image_size : tuple of int or None
        (width, height) px of the camera mode to calibrate (default: the size most images share). Images where the
        board is not found, or of another size, are left out and listed in ``failed`` with their reason.
    max_rounds, tol_px
        The re-correction loop's limits (:func:`calibrate_detections`).
    lens_candidates : sequence of str or None
        ``--lens auto``: the lens models to choose from (:func:`choose_lens`; e.g. :data:`LENS_CANDIDATES`);
        ``options.lens`` is then ignored. None: ``options.lens``.
    second_pass : bool
        Detect again, with the first model, the images whose board was refused for a reason a lens can cause
        (:data:`RECOVERABLE`: a strongly distorted lattice), and recalibrate with the views it finds
        (``recovered``).

    Returns
    -------
    ImagesCalibration

    Raises
    ------
    InputError
        No images given.
    TooFewImagesError
        Fewer than :data:`~circcal.observations.MIN_VIEWS` images remain.
    CalibrationError
        The solve fails (see :func:`circcal.solver.calibrate`).
    """
    paths = image_list(paths)
    if not paths:
        raise InputError("no images given")
    detections = detect_once(paths, board, None, progress=progress, jobs=jobs)
    found = [i for i, d in enumerate(detections) if d.found]
    if image_size is None and found:
        # one calibration is one camera mode: the size most images share (the first such on a tie)
        sizes = Counter(detections[i].image_size for i in found)
        image_size = max(
            sizes, key=lambda s: (sizes[s], -found.index(next(i for i in found if detections[i].image_size == s)))
        )
    failed: list[Rejection] = []
    used: list[int] = []
    for i, d in enumerate(detections):
        if not d.found:
            failed.append(Rejection(paths[i], d.code, d.reason))
        elif tuple(d.image_size) != tuple(image_size):
            failed.append(
                Rejection(
                    paths[i],
                    Reason.WRONG_IMAGE_SIZE,
                    f"image is {d.image_size[0]}x{d.image_size[1]}, the calibration's images are "
                    f"{image_size[0]}x{image_size[1]}",
                )
            )
        else:
            used.append(i)
    repeats = same_views([detections[i].centres for i in used])
    for k, (kj, rms) in repeats.items():  # a photograph given twice, re-saved: one view
        why = (
            f"the same view as {display_name(Path(paths[used[kj]]).name)} (its dots within {rms:.2g} px RMS: a copy "
            f"re-saved, or neither board nor camera moved): counted once"
        )
        failed.append(Rejection(paths[used[k]], Reason.DUPLICATE, why))
    used = [i for k, i in enumerate(used) if k not in repeats]
    failed.sort(key=lambda r: paths.index(r.path))
    if len(used) < MIN_VIEWS:
        raise TooFewImagesError(
            f"the board was found in {len(used)} of {len(paths)} images; calibration needs at least {MIN_VIEWS}"
            + "".join(f"\n  {display_name(r.path)}: {display_name(r.reason)}" for r in failed),
            failed,
        )
    choice = None
    if lens_candidates is not None:
        choice = choose_lens([detections[i] for i in used], board, image_size, options, lens_candidates)
        options = options.replace(lens=choice.lens)
    cal = _solve(paths, detections, used, failed, board, image_size, options, max_rounds, tol_px)
    if second_pass:
        again = [
            k
            for k, r in enumerate(failed)
            if r.code in RECOVERABLE and detections[paths.index(r.path)].image_size in (None, tuple(image_size))
        ]
        if again:
            redo = det_mod.detect_files(
                [failed[k].path for k in again], board, camera=cal.result.camera, progress=False, jobs=jobs
            )
            found_again = {failed[k].path: d for k, d in zip(again, redo) if d.found}
            if found_again:
                for path, d in found_again.items():
                    detections[paths.index(path)] = d
                used = sorted(used + [paths.index(p) for p in found_again])
                failed = [r for r in failed if r.path not in found_again]
                cal = _solve(paths, detections, used, failed, board, image_size, options, max_rounds, tol_px)
                cal.recovered = [p for p in paths if p in found_again]
    cal.lens_choice = choice
    return cal


def detect_once(
    paths: Sequence[str], board, camera, *, progress: bool = True, jobs: int | None = None
) -> list[Detection]:
    """One detection per path, each file's contents detected once: a file whose bytes (or pixels) an earlier one
    holds (:func:`duplicates_of`) is not found, reason ``DUPLICATE``, naming the earlier one.

    Parameters
    ----------
    paths : sequence of str
        The image files.
    board : circcal.board.Board
    camera : Camera or None
        The camera model the detector may use (:func:`circcal.detector.detect_files`).
    progress : bool
        Show a progress bar.
    jobs : int or None
        Images detected at once.

    Returns
    -------
    list of Detection
        In the order of ``paths``.
    """
    first = duplicates_of(paths)
    unique = [i for i in range(len(paths)) if i not in first]
    found = det_mod.detect_files([paths[i] for i in unique], board, camera=camera, progress=progress, jobs=jobs)
    detections: list[Detection] = [None] * len(paths)  # type: ignore[list-item]
    for i, d in zip(unique, found):
        detections[i] = d
    for i, (j, how) in first.items():
        detections[i] = Detection(
            False, None, f"{how} {display_name(paths[j])} (given earlier): counted once", Reason.DUPLICATE
        )
    return detections


def _same_size(size: Any, image_size: tuple[int, int]) -> bool:
    """Whether a refused view may be of the calibration's size (unknown where the image was not measured)."""
    return size is None or tuple(size) == tuple(image_size)


def _solve(paths, detections, used, failed, board, image_size, options, max_rounds, tol_px) -> ImagesCalibration:
    """The used views' calibration loop, with the bad dots and the solve's outliers (a dropped view to ``failed``)."""
    failed = list(failed)
    exclude = bad = None
    if options.outlier_rule is not None:
        from circcal.dotcheck import bad_dot_rejections

        exclude, bad = bad_dot_rejections([detections[i] for i in used], board)
    result, centres, rounds = calibrate_detections(
        [detections[i] for i in used], board, image_size, options, max_rounds=max_rounds, tol_px=tol_px, exclude=exclude
    )
    rej = result.outliers
    if rej is not None:  # the bad dots first, then what the solve rejected; names of the views as given
        rej = replace(rej, items=[*bad, *rej.items], view_names=[Path(paths[i]).name for i in used])
        failed += [Rejection(paths[used[r.view]], r.reason, r.detail) for r in rej.dropped_views]
        used, centres = [used[i] for i in rej.kept_views], rej.kept_centres(centres, board.object_points())
    result = replace(result, outliers=rej, view_names=[Path(paths[i]).name for i in used])
    return ImagesCalibration(result, paths, detections, used, failed, rounds, centres)


def choose_lens(
    detections: Sequence[Any],
    board,
    image_size: tuple[int, int],
    options: CalibrationOptions,
    candidates: Sequence[str] = LENS_CANDIDATES,
) -> LensChoice:
    """Choose the lens model of ``--lens auto``: each candidate fitted through the re-correction loop (no outlier
    rule), its residuals tested for a radial pattern (:func:`circcal.solver.modelfit.model_fit`) and each view
    predicted by the model of the others (:func:`circcal.solver.holdout_errors`, centres re-corrected under the
    candidate's model).

    Parameters
    ----------
    detections : sequence of Detection
        The found views.
    board : circcal.board.Board
    image_size : tuple of int
        (width, height) px.
    options : CalibrationOptions
        Held parameters and the rest; a hold a candidate lacks (``--fix-tangential`` for the fisheye) leaves that
        candidate out, with the reason.
    candidates : sequence of str
        Lens models, simplest first.

    Returns
    -------
    LensChoice
        The first candidate whose residuals fit and whose held-out RMS is within :data:`AUTO_MARGIN` of the best
        such; where none fits, the lowest held-out RMS.

    Raises
    ------
    CalibrationError
        No candidate gave a model (every reason named).
    """
    from circcal.solver import holdout_errors
    from circcal.solver.modelfit import model_fit

    rows: list[dict[str, Any]] = []
    for lens in candidates:
        row: dict[str, Any] = {"lens": lens}
        rows.append(row)
        try:
            opts = options.replace(lens=lens, outlier_rule=None, refine_board=False)
            with warnings.catch_warnings():  # a candidate's own troubles (a fold, no convergence) are its row's
                warnings.simplefilter("ignore")
                res, centres, _ = calibrate_detections(detections, board, image_size, opts)
                obj, img = zip(*[_points_of(c, board.object_points()) for c in centres])
                held = holdout_errors(list(obj), list(img), image_size, opts)
        except InputError as exc:
            row["error"] = str(exc).splitlines()[0]
            continue
        fit = model_fit(res)
        errs = np.concatenate([[h["rms_per_point_px"]] for h in held if "rms_per_point_px" in h] or [[np.inf]])
        row.update(
            rms_per_point_px=float(res.errors["rms_per_point_px"]),
            heldout_rms_px=float(np.sqrt(np.mean(errs**2))),
            fits=None if fit is None else bool(fit.fits),
        )
    ok = [r for r in rows if "error" not in r and np.isfinite(r["heldout_rms_px"])]
    if not ok:
        raise CalibrationError(
            "no lens model gave a model: "
            + "; ".join(f"{r['lens']}: {r.get('error', 'no held-out view')}" for r in rows)
        )
    fitting = [r for r in ok if r["fits"] is not False] or ok
    best = min(r["heldout_rms_px"] for r in fitting)
    chosen = next(r for r in fitting if r["heldout_rms_px"] <= best * (1 + AUTO_MARGIN))
    others = ", ".join(f"{r['lens']} {r['heldout_rms_px']:.4f}" for r in ok if r is not chosen)
    why = (
        f"held-out RMS per point {chosen['heldout_rms_px']:.4f} px (others: {others or 'none'})"
        + ("" if chosen["fits"] is not False else "; no candidate's residuals are free of a radial pattern")
        + ("" if chosen is fitting[0] else f"; the simpler models predict worse by more than {AUTO_MARGIN:.0%}")
    )
    return LensChoice(chosen["lens"], why, tuple(rows))


def calibrate_detections(
    detections: Sequence[Any],
    board,
    image_size: tuple[int, int],
    options: CalibrationOptions = CalibrationOptions(),
    *,
    max_rounds: int = MAX_ROUNDS,
    tol_px: float = 1e-4,
    exclude: Sequence[Sequence[int]] | None = None,
) -> tuple[CalibrationResult, list[np.ndarray], list[dict]]:
    """The loop of :func:`calibrate_images` on detections already made: calibrate, re-correct every centre under the
    current model (``circcal.detector.recorrect``), recalibrate, until no centre moves more than ``tol_px`` or
    ``max_rounds`` calibrations were made (then a RuntimeWarning). Reused for held-out checks: the detector runs
    without a model, so detections do not depend on other views.

    Parameters
    ----------
    detections : sequence of circcal.detector.Detection
        One per view, all found.
    board : circcal.board.Board
    image_size : tuple of int
        (width, height) px.
    options : CalibrationOptions
        How every solve is made (:func:`circcal.solver.calibrate`).
    max_rounds : int
        Calibrations at most (:data:`MAX_ROUNDS`).
    tol_px : float
        The largest centre shift (px) at which the loop has settled.
    exclude : sequence of sequence of int, or None
        Per detection, indices of dots (board order) left out of every solve (the detector's bad dots).

    Returns
    -------
    tuple
        ``(result, centres, rounds)`` as :class:`ImagesCalibration` holds them (with outlier rejection,
        ``result``'s views are ``result.outliers.kept_views`` of the detections; the centres stay one per
        detection).
    """
    board_pts = board.object_points()

    def left_out(cs: list[np.ndarray]) -> list[np.ndarray]:
        if exclude is None:
            return cs
        out = [c.copy() for c in cs]
        for c, ex in zip(out, exclude):
            c[list(ex)] = np.nan
        return out

    centres = [np.asarray(d.centres, dtype=np.float64) for d in detections]
    pairs = [_points_of(c, board_pts) for c in left_out(centres)]
    result = calibrate([o for o, _ in pairs], [p for _, p in pairs], image_size, options)
    stats = ("rms_per_point_px", "rms_per_coord_px", "mean_2d_px")
    rounds = [{"round": 0, **{k: result.errors[k] for k in stats}, "max_centre_shift_px": float("nan")}]
    for r in range(1, max_rounds):
        new = [np.asarray(det_mod.recorrect(d, board, result.camera), dtype=np.float64) for d in detections]
        stuck = [np.isnan(a[:, 0]) & np.isfinite(b[:, 0]) for a, b in zip(new, centres)]
        if any(s.any() for s in stuck):
            for a, b, s in zip(new, centres, stuck):
                a[s] = b[s]
            warnings.warn(
                f"centre re-correction: the {result.camera.lens} model has no inverse over the rims of "
                f"{sum(int(s.sum()) for s in stuck)} dot(s) in {sum(bool(s.any()) for s in stuck)} view(s) "
                f"(beyond the fold of its distortion polynomial: a lens model too simple for this lens?); "
                f"those centres keep the previous round's",
                RuntimeWarning,
                stacklevel=3,
            )
        shift = max(float(np.nanmax(np.linalg.norm(a - b, axis=1))) for a, b in zip(new, centres))
        pairs = [_points_of(c, board_pts) for c in left_out(new)]
        try:
            result = calibrate([o for o, _ in pairs], [p for _, p in pairs], image_size, options, initial=result.camera)
        except CalibrationError as exc:  # the last round's model cannot start the next one: keep it, and say so
            warnings.warn(
                f"centre re-correction stopped after round {r - 1}, whose model is kept: {exc}",
                RuntimeWarning,
                stacklevel=3,
            )
            break
        centres = new
        rounds.append({"round": r, **{k: result.errors[k] for k in stats}, "max_centre_shift_px": shift})
        if shift < tol_px:
            break
    else:
        if max_rounds > 1:
            warnings.warn(
                f"centre re-correction did not settle below {tol_px:g} px in {max_rounds} rounds "
                f"(last shift {rounds[-1]['max_centre_shift_px']:.3g} px)",
                RuntimeWarning,
                stacklevel=3,
            )
    return result, centres, rounds


def holdout_detections(
    detections: Sequence[Any], board, image_size: tuple[int, int], options: CalibrationOptions = CalibrationOptions()
) -> list[dict[str, Any]]:
    """Leave-one-view-out prediction through the whole loop.

    Each view k is predicted by the model that :func:`calibrate_detections` makes from the other views with
    ``options`` (e.g. ``refine_board``), with view k's centres re-corrected under that model (the detector ran without
    a model, so a detection does not depend on the other views) and its board points that model's (refined) ones.

    Parameters
    ----------
    detections : sequence of Detection
        Found ones, one per view.
    board : Board
    image_size : tuple of int
        (width, height), px.
    options : CalibrationOptions

    Returns
    -------
    list of dict
        One per view: see :func:`circcal.solver.leave_one_out`.
    """
    board_pts = board.object_points()

    def fit(rest: list[int]):
        return calibrate_detections([detections[i] for i in rest], board, image_size, options)[0]

    def held_out(k: int, res: CalibrationResult):
        obj, img = _points_of(det_mod.recorrect(detections[k], board, res.camera), board_pts)
        return res.board_lookup(obj), img, res.camera

    return leave_one_out(len(detections), fit, held_out)
