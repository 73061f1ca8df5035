"""Rig cameras whose intrinsics are given (``initial=``, ``calibrate-rig --intrinsics``): read and checked against
the rig (:func:`given_cameras`); held, a camera's images are searched and its centres corrected under them, and it
is not calibrated alone.

``cv2.stereoCalibrate`` with ``CALIB_FIX_INTRINSIC`` needs no view count of a camera beyond what its pose in the rig
needs, and the usual workflow calibrates each camera alone on many views, then the rig on a few shared ones. A camera
calibrated alone needs 3 views (:data:`circcal.observations.MIN_VIEWS`) and enough of them to determine its lens
model; a held camera needs 1 view that another camera saw at the same instant.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal import detector as det_mod
from circcal.board import Board
from circcal.detector import Reason, Rejection
from circcal.errors import InputError
from circcal.formats import read_camera
from circcal.model import Camera
from circcal.pathnames import display_name
from circcal.pipeline import TooFewImagesError, detect_once
from circcal.rig.problem import free_intrinsics
from circcal.solver import CalibrationOptions
from circcal.solver.options import ASPECT_RATIO

__all__ = [
    "LocatedImages",
    "check_given_names",
    "given_camera",
    "given_cameras",
    "locate_images",
    "locate_held_camera",
    "is_held",
    "held_cameras",
]


@dataclass
class LocatedImages:
    """A held camera's images: where its board was found and its centres under the given intrinsics.

    Attributes
    ----------
    camera : Camera
        The given intrinsics.
    paths : list of str
        All inputs.
    detections : list of Detection
        One per path.
    used : list of int
        Indices of the paths whose board was found (at the camera's image size).
    failed : list of Rejection
        Every image left out, with its reason.
    centres : list of ndarray, each shape (N, 2)
        Each used view's centres corrected under ``camera`` (px, board order, NaN where a dot was not found).
    """

    camera: Camera
    paths: list[str]
    detections: list[Any]
    used: list[int] = field(default_factory=list)
    failed: list[Rejection] = field(default_factory=list)
    centres: list[np.ndarray] = field(default_factory=list)


def is_held(camera: Camera, options: CalibrationOptions) -> bool:
    """Whether ``options`` hold every intrinsic of ``camera`` (``cv2.stereoCalibrate``'s ``CALIB_FIX_INTRINSIC``).

    Parameters
    ----------
    camera : Camera
    options : CalibrationOptions

    Returns
    -------
    bool
    """
    aspect = camera.fx / camera.fy if ASPECT_RATIO in options.fixed else None
    return not free_intrinsics(camera.model.param_names, options.fixed, aspect)[0]


def locate_images(
    paths: Sequence[str],
    board: Board,
    camera: Camera,
    *,
    progress: bool = False,
    jobs: int | None = None,
) -> LocatedImages:
    """Find the board in a held camera's images with its intrinsics and correct every centre under them.

    Parameters
    ----------
    paths : sequence of str
        The camera's image files.
    board : Board
    camera : Camera
        The given intrinsics (its lens model corrects the centres, as :func:`circcal.detector.recorrect` does).
    progress : bool
        Show the detector's progress bar.
    jobs : int or None
        Images detected at once (:func:`circcal.detector.detect_files`).

    Returns
    -------
    LocatedImages
        No view may be found (``used`` empty): the caller says what that means for it.

    Examples
    --------
    >>> found = locate_images(["right/001.png", "right/003.png"], board, camera)  # doctest: +SKIP
    >>> [found.paths[i] for i in found.used]  # doctest: +SKIP
    ['right/001.png', 'right/003.png']
    """
    paths = [str(p) for p in paths]
    detections = detect_once(paths, board, camera, progress=progress, jobs=jobs)
    out = LocatedImages(camera, paths, detections)
    size = (camera.width, camera.height)
    for i, d in enumerate(detections):
        if not d.found:
            out.failed.append(Rejection(paths[i], d.code, d.reason))
        elif tuple(d.image_size) != size:
            why = f"image is {d.image_size[0]}x{d.image_size[1]}, the given intrinsics' {size[0]}x{size[1]}"
            out.failed.append(Rejection(paths[i], Reason.WRONG_IMAGE_SIZE, why))
        else:
            raw = np.asarray(d.centres, dtype=np.float64)
            new = np.asarray(det_mod.recorrect(d, board, camera), dtype=np.float64)
            out.used.append(i)
            out.centres.append(np.where(np.isfinite(new), new, raw))  # a rim the lens cannot invert: as detected
    return out


def held_cameras(names: Sequence[str], options: Sequence[CalibrationOptions], start: Mapping[str, Any]) -> set[str]:
    """The cameras whose every intrinsic is held at their start (:func:`is_held`): they need one view (their pose in
    the rig), not a calibration's three.

    Parameters
    ----------
    names : sequence of str
        The rig's cameras.
    options : sequence of CalibrationOptions
        One per camera.
    start : mapping of str to Camera
        Where some cameras start (given intrinsics, or an earlier rig's cameras); other values are ignored.

    Returns
    -------
    set of str
    """
    return {
        n
        for n, o in zip(names, options)
        if isinstance(start.get(n), Camera) and start[n].lens == o.lens and is_held(start[n], o)
    }


def locate_held_camera(
    name: str,
    paths: Sequence[str],
    board: Board,
    camera: Any,
    options: CalibrationOptions,
    *,
    progress: bool = False,
    jobs: int | None = None,
) -> LocatedImages:
    """:func:`locate_images` for rig camera ``name``, its given camera checked against its options first.

    Parameters
    ----------
    name : str
        The camera's name in the rig (for the errors).
    paths, board, progress, jobs
        As :func:`locate_images`.
    camera : Camera
        Its given intrinsics.
    options : CalibrationOptions
        Its options (their lens model must be the camera's).

    Returns
    -------
    LocatedImages
        With at least one view found.

    Raises
    ------
    InputError
        ``camera`` is no Camera, or of another lens model than ``options``'.
    TooFewImagesError
        The board is found in none of the images (each named with its reason).
    """
    camera = given_camera(name, camera, options)
    found = locate_images(paths, board, camera, progress=progress, jobs=jobs)
    if not found.used:
        raise TooFewImagesError(
            f"camera {name!r}: the board was found in none of its {len(paths)} images"
            + "".join(f"\n  {display_name(r.path)}: {display_name(r.reason)}" for r in found.failed),
            found.failed,
        )
    return found


def check_given_names(initial: Any, names: Sequence[str], every: bool) -> None:
    """Refuse an ``initial`` that is no mapping, or that names other cameras.

    Parameters
    ----------
    initial : object
        What was given: a mapping of camera name to Camera or model file.
    names : sequence of str
        The rig's cameras.
    every : bool
        Every camera must be named (else some of them).

    Raises
    ------
    InputError
        One line naming what differs.
    """
    if not isinstance(initial, Mapping):
        raise InputError(
            f"initial must be a RigCalibration or a mapping of camera name to Camera or model file, got {initial!r}"
        )
    given = sorted(map(str, initial))
    if (every and given != sorted(names)) or not set(given) <= set(names):
        raise InputError(f"initial: cameras {given}, the observations' are {sorted(names)}")


def given_camera(name: str, camera: Any, options: CalibrationOptions, size: tuple[int, int] | None = None) -> Camera:
    """Camera ``name``'s given intrinsics, a Camera or a model file, checked against its options and images.

    Parameters
    ----------
    name : str
        The camera's name in the rig (for the errors).
    camera : Camera, str or path-like
        As given (a model file in any format :func:`circcal.formats.read_camera` reads; its errors name it).
    options : CalibrationOptions
        Its options: their lens model must be the camera's.
    size : (int, int) or None
        Its images' (width, height) px, where known.

    Returns
    -------
    Camera

    Raises
    ------
    InputError
        No Camera, another lens model or another image size (one line naming the camera).
    """
    if isinstance(camera, (str, os.PathLike)):
        camera = read_camera(os.fspath(camera))
    if not isinstance(camera, Camera):
        raise InputError(f"initial: camera {name!r} must be a Camera or a model file, got {type(camera).__name__}")
    if size is not None and (camera.width, camera.height) != tuple(size):
        raise InputError(f"initial: camera {name!r} is {camera.width}x{camera.height}, its images {size[0]}x{size[1]}")
    if camera.lens != options.lens:
        raise InputError(f"initial: camera {name!r} has lens {camera.lens!r}, its options lens={options.lens!r}")
    return camera


def given_cameras(
    initial: Any,
    names: Sequence[str],
    sizes: Sequence[tuple[int, int]],
    options: Sequence[CalibrationOptions],
    every: bool = True,
) -> dict[str, Camera]:
    """The cameras of an ``initial`` mapping camera name -> Camera or model file, checked against the rig.

    Parameters
    ----------
    initial : mapping of str to Camera or path
    names : sequence of str
        The rig's cameras.
    sizes : sequence of (int, int)
        Each camera's image size, px.
    options : sequence of CalibrationOptions
        Each camera's options.
    every : bool
        One per camera (else some of them).

    Returns
    -------
    dict of str to Camera
        The cameras given, by name.

    Raises
    ------
    InputError
        As :func:`check_given_names` and :func:`given_camera`.
    """
    check_given_names(initial, names, every)
    return {n: given_camera(n, initial[n], o, size) for n, size, o in zip(names, sizes, options) if n in initial}
