"""Camera-model files: circcal's model.json and the formats other tools read, one module per format.

Every format here holds :class:`circcal.model.Camera` of its lens model (``opencv5``, ``rational``, ``thin-prism``,
``fisheye``) where the format has that model; a format that cannot hold a given camera exactly is refused with a
clear error (naming the reason) rather than written lossily.

=================  ==========================================================================================
format             module and file
=================  ==========================================================================================
``json``           :mod:`~circcal.formats.modeljson`: circcal model.json (the truth.json ``camera`` block plus
                   ``std``, errors, per-view poses, ...)
``opencv``         :mod:`~circcal.formats.opencv`: OpenCV ``cv2.FileStorage`` YAML (or .xml)
``mrcal``          :mod:`~circcal.formats.mrcal`: mrcal ``.cameramodel`` (``LENSMODEL_OPENCV5/8/12``; no fisheye);
                   with mrcal's optimisation inputs: :mod:`~circcal.formats.cameramodel_export` (mrcal
                   run out of process: :mod:`~circcal.formats.mrcal_process`, script ``mrcal_worker.py``)
``colmap``         :mod:`~circcal.formats.colmap`: COLMAP ``cameras.txt`` (``OPENCV`` / ``FULL_OPENCV`` /
                   ``OPENCV_FISHEYE``; no thin prism; +0.5 px)
``ros``            :mod:`~circcal.formats.ros`: ROS ``camera_info`` YAML (``plumb_bob``, ``rational_polynomial``,
                   ``equidistant``; no thin prism)
=================  ==========================================================================================

:func:`read_camera` (every command reads models through it) and :func:`write_camera` pick the format from the file
name and, for reading, its content. Reading checks every value and names the file and the field in its error
(:class:`~circcal.errors.ModelFileError`), within the limits of :mod:`~circcal.formats.limits` (one place for every
bound and the value checks all readers share). circcal's own model.json is read strictly (an unknown field is
refused by name); the foreign formats (OpenCV, ROS, mrcal, COLMAP) carry extra fields by custom, which are ignored.
Writing is atomic (a temporary file in the same folder, then a rename), so a failed write leaves an earlier file
as it was.

Board description files (``--board FILE``: circcal's YAML/JSON form, ROS-Industrial's target YAML, Kalibr's
circle-grid target YAML) are read by :func:`read_board_file` and written by :func:`board_file_text`
(:mod:`~circcal.formats.boardfile`).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from circcal import atomic
from circcal.errors import InputError, ModelFileError
from circcal.formats.boardfile import board_file_text, read_board_file
from circcal.formats.colmap import COLMAP_PIXEL_OFFSET, camera_from_colmap, camera_to_colmap
from circcal.formats.limits import JSON_LIMITS, MAX_MODEL_FILE_BYTES, check_camera
from circcal.formats.modeljson import MODEL_FORMAT, MODEL_SECTIONS, MODEL_VERSION, camera_from_json, model_json
from circcal.formats.mrcal import camera_from_cameramodel, camera_to_cameramodel
from circcal.formats.opencv import camera_from_K_dist, camera_from_opencv_yaml, opencv_yaml_text
from circcal.formats.ros import camera_from_ros_yaml, camera_to_ros_yaml
from circcal.jsonio import dumps, parse_json, read_text
from circcal.model import Camera

__all__ = [
    "FORMATS",
    "detect_format",
    "read_camera",
    "read_model",
    "write_camera",
    "model_json",
    "camera_from_json",
    "MODEL_FORMAT",
    "MODEL_VERSION",
    "MODEL_SECTIONS",
    "COLMAP_PIXEL_OFFSET",
    "opencv_yaml_text",
    "camera_from_opencv_yaml",
    "camera_from_K_dist",
    "camera_to_cameramodel",
    "camera_from_cameramodel",
    "camera_to_colmap",
    "camera_from_colmap",
    "camera_to_ros_yaml",
    "camera_from_ros_yaml",
    "read_board_file",
    "board_file_text",
]

FORMATS: tuple[str, ...] = ("json", "opencv", "mrcal", "colmap", "ros")


def detect_format(path: str | Path, text: str | None = None) -> str:
    """The format of a camera file from its name and (when ``text`` is given) its content.

    Parameters
    ----------
    path : str or Path
        The file's name (not opened).
    text : str or None
        Its content, when read.

    Returns
    -------
    str
        One of :data:`FORMATS`.

    Raises
    ------
    InputError
        Neither the name nor the content tells.

    Examples
    --------
    >>> detect_format("camera_info.yaml")
    'ros'
    """
    p = Path(path)
    ext = p.suffix.lower()
    name = p.name.lower()
    if text is not None:
        head = text.lstrip()
        if head.startswith("{") and ext != ".cameramodel":
            try:
                parse_json(text, **JSON_LIMITS)
                return "json"
            except InputError:  # not JSON (a mrcal literal, YAML's flow style), or JSON refused: ext decides
                pass
        if "lensmodel" in text and "intrinsics" in text:
            return "mrcal"
        if head.startswith("%YAML") or "opencv-matrix" in text or head.startswith("<?xml"):
            return "opencv"
        if re.search(r"^\s*(distortion_model|camera_matrix|K)\s*:", text, re.M):
            return "ros"
        if re.search(
            r"^\s*\d+\s+(OPENCV|FULL_OPENCV|OPENCV_FISHEYE|PINHOLE|SIMPLE_PINHOLE|SIMPLE_RADIAL|RADIAL)\s", text, re.M
        ):
            return "colmap"
    if ext == ".json":
        return "json"
    if ext == ".cameramodel":
        return "mrcal"
    if ext == ".txt":
        return "colmap"
    if ext == ".xml":
        return "opencv"
    if ext in (".yaml", ".yml"):
        return "ros" if ("camera_info" in name or "ros" in re.split(r"[._\-]", name)) else "opencv"
    raise InputError(
        f"cannot tell the camera format of {p.name!r}: use .json (circcal), .yaml/.yml/.xml (OpenCV; "
        f"ROS camera_info when the name holds 'camera_info'), .cameramodel (mrcal) or .txt (COLMAP "
        f"cameras.txt), or name the format ({', '.join(FORMATS)})"
    )


def read_model(path: str | Path, fmt: str | None = None) -> tuple[Camera, dict[str, Any] | None]:
    """The camera in ``path`` (any supported format) and, for a model.json, the whole document.

    Every reader applies :mod:`circcal.formats.limits`: the file's size (checked before it is read), nesting, integers'
    digits, repeated keys, and the camera's values (:func:`~circcal.formats.limits.check_camera`).

    Parameters
    ----------
    path : str or Path
    fmt : str or None
        One of :data:`FORMATS`; None: from the content and the name.

    Returns
    -------
    camera : Camera
    document : dict or None
        The model.json document; None for the other formats.

    Raises
    ------
    ModelFileError
        Naming the file: missing or unreadable, an unknown format, malformed, or a value outside the model.

    Examples
    --------
    >>> camera, doc = read_model("out/model.json")  # doctest: +SKIP
    """
    p = Path(path)
    try:
        text = read_text(p, "camera file", max_bytes=MAX_MODEL_FILE_BYTES)
    except InputError as exc:
        raise ModelFileError(str(exc)) from None
    if not text.strip():  # every reader would say it in its own words (OpenCV's: an assertion on its buffer)
        raise ModelFileError(f"camera file {p}: an empty file")
    try:
        fmt = fmt or detect_format(p, text)
        if fmt == "json":
            data = parse_json(text, **JSON_LIMITS)
            return check_camera(camera_from_json(data)), data
        readers = {
            "opencv": camera_from_opencv_yaml,
            "mrcal": camera_from_cameramodel,
            "colmap": camera_from_colmap,
            "ros": camera_from_ros_yaml,
        }
        if fmt not in readers:
            raise InputError(f"unknown camera format {fmt!r}; expected one of {', '.join(FORMATS)}")
        return check_camera(readers[fmt](text)), None
    except InputError as exc:  # the reader's and the camera's own checks: say which file
        raise ModelFileError(f"camera file {p} ({fmt or 'unknown format'}): {exc}") from None


def read_camera(path: str | Path, fmt: str | None = None) -> Camera:
    """The camera in ``path``: :func:`read_model` without the document.

    Parameters
    ----------
    path : str or Path
    fmt : str or None
        One of :data:`FORMATS`; None: from the content and the name.

    Returns
    -------
    Camera

    Raises
    ------
    ModelFileError
        As :func:`read_model`.
    """
    return read_model(path, fmt)[0]


def write_camera(
    path: str | Path,
    camera: Camera,
    fmt: str | None = None,
    *,
    document: dict[str, Any] | None = None,
    colmap_model: str = "auto",
    name: str = "camera",
) -> str:
    """Write ``camera`` to ``path`` in ``fmt``, atomically.

    Parameters
    ----------
    path : str or Path
    camera : Camera
    fmt : str or None
        One of :data:`FORMATS` (default: from the file name).
    document : dict or None
        For ``json``: a :func:`~circcal.formats.modeljson.model_json` document (e.g. from
        :meth:`circcal.pipeline.ImagesCalibration.to_model_json`) written with its camera block replaced by
        ``camera``'s; None: the bare camera block.
    colmap_model : str
        ``"auto"`` (the camera's lens model: OPENCV when k3 = 0, else FULL_OPENCV; OPENCV_FISHEYE), or a COLMAP model
        name.
    name : str
        The ROS ``camera_name``.

    Returns
    -------
    str
        The format written.

    Raises
    ------
    InputError
        A format that cannot tell from the name, or one without the camera's lens model (with the reason).
    """
    p = Path(path)
    fmt = fmt or detect_format(p)
    if fmt == "json":
        doc = dict(document) if document is not None else model_json(camera)
        doc["camera"] = camera.to_dict()
        text = dumps(doc, indent=2) + "\n"
    elif fmt == "opencv":
        text = opencv_yaml_text(camera, xml=p.suffix.lower() == ".xml")
    elif fmt == "mrcal":
        text = camera_to_cameramodel(camera)
    elif fmt == "colmap":
        text = camera_to_colmap(camera, model=colmap_model)
    elif fmt == "ros":
        text = camera_to_ros_yaml(camera, name=name)
    else:
        raise InputError(f"unknown camera format {fmt!r}; expected one of {', '.join(FORMATS)}")
    atomic.write_text(p, text)
    return fmt
