"""Detection on image files (:func:`detect_files`: in threads, in the order given), with the per-image error rule:
what an image file can legitimately cause becomes ``found=False`` with its :class:`~circcal.detector.Reason`;
anything else is a bug and propagates with its traceback."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from circcal.board import Board
from circcal.detector.detection import Detection, Reason
from circcal.detector.find import camera_size_mismatch, detect
from circcal.detector.image import ImageTooLargeError, exif_orientation_note, read_image_messages
from circcal.errors import ImageError, InputError
from circcal.model import Camera
from circcal.progress import progress_bar

__all__ = ["MAX_DEFAULT_JOBS", "detect_files"]

MAX_DEFAULT_JOBS = 8
"""Images detected at once by default: one per CPU, at most this many (the default ``--jobs`` documents)."""


def detect_files(
    paths: list[Path],
    board: Board,
    camera: Camera | None = None,
    progress: bool = True,
    jobs: int | None = None,
    on_result: Callable[[int, Detection], None] | None = None,
) -> list[Detection]:
    """:func:`~circcal.detector.find.detect` on each image file, in threads, the results in the order given.

    A missing, unreadable or corrupt file, an image the detector cannot take, or one of another size than
    ``camera``'s, gives ``found=False`` with its reason and code (:func:`_detect_file`); nothing else is caught.
    Decoding, OpenCV and the compiled loops release the GIL, so threads run in parallel. The results do not depend on
    ``jobs``: each image is detected on its own.

    Parameters
    ----------
    paths : list of pathlib.Path
        The image files (str accepted).
    board : circcal.board.Board
        The board to find.
    camera : circcal.model.Camera or None
        A lens model: the centres are corrected under it, and an image of another size is refused
        (``WRONG_IMAGE_SIZE``).
    progress : bool
        Show a tqdm progress bar.
    jobs : int or None
        Images processed at once, in threads; ``None`` = one per CPU (at most :data:`MAX_DEFAULT_JOBS`).
    on_result : Callable[[int, Detection], None] or None
        Called as ``on_result(i, detection)`` (in the calling thread) as soon as image ``i`` is done, in the order
        they finish: a caller can save each result as it comes, so an interruption loses nothing already done.

    Returns
    -------
    list of Detection
        One per path, in the order given.

    Raises
    ------
    InputError
        ``paths`` one path rather than a list of them (a folder: :func:`circcal.imagefiles.image_list` first).
    ValueError
        ``jobs < 1``.

    Examples
    --------
    >>> from circcal.board import Board
    >>> ds = detect_files([Path("view1.png"), Path("view2.png")], Board(7, 7, 20.0, 10.0))  # doctest: +SKIP
    >>> [d.found for d in ds]  # doctest: +SKIP
    [True, False]
    """
    from concurrent.futures import ThreadPoolExecutor, as_completed

    if isinstance(paths, (str, os.PathLike)):  # a string would be read as one file name per character
        raise InputError(
            f"paths: a list of image files, one detection each, got the single path {str(paths)!r:.80} (a folder: "
            f"circcal.imagefiles.image_list(folder))"
        )

    paths = [Path(p) for p in paths]
    jobs = min(MAX_DEFAULT_JOBS, os.cpu_count() or 1) if jobs is None else int(jobs)
    if jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    bar = progress_bar(len(paths), "detect", "img", progress)
    try:
        out: list[Detection | None] = [None] * len(paths)

        def done(i: int, d: Detection) -> None:
            out[i] = d
            bar.update()
            if on_result is not None:
                on_result(i, d)

        if jobs == 1 or len(paths) < 2:
            for i, p in enumerate(paths):
                done(i, _detect_file(p, board, camera))
            return out  # type: ignore[return-value]
        with ThreadPoolExecutor(max_workers=min(jobs, len(paths))) as pool:
            futures = {pool.submit(_detect_file, p, board, camera): i for i, p in enumerate(paths)}
            try:
                for f in as_completed(futures):
                    done(futures[f], f.result())
            except BaseException:
                for f in futures:  # an interruption or a bug: do not start the images still queued
                    f.cancel()
                raise
        return out  # type: ignore[return-value]
    finally:
        bar.close()


def _detect_file(path: Path, board: Board, camera: Camera | None) -> Detection:
    """:func:`~circcal.detector.find.detect` on one image file. What a file can legitimately cause gives
    ``found=False`` with its :class:`~circcal.detector.Reason`: missing, or not a regular file (a folder, a fifo, a
    link to nothing or a loop of links: ``FILE_NOT_FOUND``), unreadable, empty or undecodable (``UNREADABLE``), a
    header claiming more pixels than :func:`~circcal.detector.image.max_image_pixels` (``IMAGE_TOO_LARGE``, not
    decoded), of another size than the camera model (``WRONG_IMAGE_SIZE``), an image the detector cannot take
    (:class:`~circcal.errors.ImageError`: ``BAD_IMAGE``). Any other exception is a bug and propagates. What the
    decoder prints about a corrupt file goes into the reason (or the notes), not onto the console."""
    if not path.is_file():
        return Detection(False, None, _not_a_file(path), Reason.FILE_NOT_FOUND)
    try:
        img, said = read_image_messages(path)
    except OSError as exc:  # permission denied, I/O error
        return Detection(False, None, f"cannot read the file: {exc.strerror or exc}", Reason.UNREADABLE)
    except ImageTooLargeError as exc:
        return Detection(False, None, str(exc), Reason.IMAGE_TOO_LARGE)
    if img is None:
        if not said and _is_empty(path):
            return Detection(False, None, "unreadable file (empty: 0 bytes)", Reason.UNREADABLE)
        said_ = f": {'; '.join(said[:3])}" if said else ""
        return Detection(False, None, f"unreadable file (not an image, or corrupt{said_})", Reason.UNREADABLE)
    d = _detect_image(img, board, camera)
    if said:  # decoded, but the decoder found the file damaged: say so with the result
        d.notes = [*d.notes, "the file is damaged (the decoder said: " + "; ".join(said[:3]) + ")"]
    turned = exif_orientation_note(path)
    if turned:
        d.notes = [*d.notes, turned]
    return d


def _not_a_file(path: Path) -> str:
    """Why ``path``, which is no regular file, cannot be read, in words."""
    try:
        os.stat(path)
    except OSError as exc:  # missing, a link to nothing, a loop of links, a folder on the way that is a file
        if path.is_symlink():
            return f"file not found: a symbolic link that leads nowhere ({exc.strerror or exc})"
        return "file not found" + ("" if isinstance(exc, FileNotFoundError) else f" ({exc.strerror or exc})")
    return "not a file (a folder)" if path.is_dir() else "not a file (a device, fifo or socket)"


def _is_empty(path: Path) -> bool:
    """Whether the file ``path`` holds no bytes (False where it cannot be told)."""
    try:
        return path.stat().st_size == 0
    except OSError:
        return False


def _detect_image(img, board: Board, camera: Camera | None) -> Detection:
    """The decoded image ``img``: its size checked against ``camera``, then detected."""
    h, w = img.shape[:2]
    why = camera_size_mismatch(camera, w, h)
    if why is not None:
        return Detection(False, None, why, Reason.WRONG_IMAGE_SIZE, image_size=(w, h))
    try:
        return detect(img, board, camera)
    except ImageError as exc:
        return Detection(False, None, str(exc), Reason.BAD_IMAGE, image_size=(w, h))
