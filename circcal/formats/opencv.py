"""OpenCV ``cv2.FileStorage`` camera files (YAML, or XML by the name): ``camera_matrix``,
``distortion_coefficients``, ``image_width``, ``image_height``, as OpenCV's calibration sample
(samples/cpp/tutorial_code/calib3d/camera_calibration) writes them, with its ``fisheye_model: 1`` for a
cv2.fisheye camera (``distortion_coefficients`` then its 4x1 ``D`` = k1..k4); and :func:`camera_from_K_dist`, the one
conversion from an OpenCV camera matrix and distortion vector that every format holding them (OpenCV, mrcal, ROS,
COLMAP) reads through.

Nodes beyond these (OpenCV's calibration sample writes its settings, per-view extrinsics, errors, ...) are a foreign
format's extras: ignored."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any

import numpy as np

from circcal.errors import ModelFileError
from circcal.formats.limits import check_K, check_nesting, integer, number, show
from circcal.model import Camera

if TYPE_CHECKING:  # annotations only: cv2 is imported where a file is read or written
    import cv2

__all__ = [
    "opencv_yaml_text",
    "open_filestorage",
    "camera_from_opencv_yaml",
    "camera_from_K_dist",
    "OPENCV_DIST_SIZES",
    "pinhole_lens_of",
]

#: Lengths of OpenCV's distortion vector: 4 (k1 k2 p1 p2), 5 (+ k3), 8 (+ k4 k5 k6), 12 (+ s1..s4), 14 (+ tau x, y).
OPENCV_DIST_SIZES = (0, 4, 5, 8, 12, 14)
#: A skew below this fraction of fx is rounding, not skew (OpenCV's own calibration never estimates one).
SKEW_TOL = 1e-12


def opencv_yaml_text(camera: Camera, *, xml: bool = False) -> str:
    """The FileStorage text (YAML, or XML) OpenCV's calibration sample writes.

    ``image_width``, ``image_height``, ``camera_matrix`` (3x3) and ``distortion_coefficients`` (1x5, 1x8 or 1x12:
    OpenCV's vector of the lens model); for a fisheye ``fisheye_model: 1`` and the 4x1 ``D`` of cv2.fisheye.

    Parameters
    ----------
    camera : Camera
    xml : bool
        XML instead of YAML.

    Returns
    -------
    str
    """
    import cv2

    fs = cv2.FileStorage(".xml" if xml else ".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("image_width", int(camera.width))
    fs.write("image_height", int(camera.height))
    if camera.model.pinhole:
        fs.write("camera_matrix", camera.K)
        fs.write("distortion_coefficients", camera.dist.reshape(1, -1))
    else:
        fs.write("fisheye_model", 1)
        fs.write("camera_matrix", camera.K)
        fs.write("distortion_coefficients", camera.dist.reshape(-1, 1))
    return fs.releaseAndGetString()


def open_filestorage(text: str) -> Any:
    """An OpenCV FileStorage text opened for reading, after the checks every reader of one applies: nesting depth,
    XML document types and entities (:func:`~circcal.formats.limits.check_nesting`), OpenCV's own parse, and no key
    repeated at the top level.

    Parameters
    ----------
    text : str
        YAML or XML, as OpenCV writes it.

    Returns
    -------
    cv2.FileStorage
        Open for reading (the caller releases it).

    Raises
    ------
    ModelFileError
        Not a FileStorage text OpenCV can parse, too deeply nested, or a top-level key repeated.
    """
    import cv2

    check_nesting(text)
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:  # OpenCV 5's binding wraps the parser's error in a SystemError
        cause = exc if isinstance(exc, cv2.error) else exc.__cause__
        if not isinstance(cause, cv2.error):
            raise
        raise ModelFileError(f"not an OpenCV FileStorage file ({str(cause).strip().splitlines()[-1][:300]})") from None
    if not fs.isOpened():
        raise ModelFileError("not an OpenCV FileStorage file")
    try:
        _fs_unique_keys(fs.root(), "the top level")
    except ModelFileError:
        fs.release()
        raise
    return fs


def camera_from_opencv_yaml(text: str) -> Camera:
    """Camera from an OpenCV FileStorage text (YAML or XML).

    Pinhole: 4, 5, 8, 12 or 14 distortion coefficients (the lens model from them, :func:`pinhole_lens_of`; the tilt of
    14 must be zero); with a nonzero ``fisheye_model`` (OpenCV's calibration sample) a cv2.fisheye camera with its 4
    coefficients. ``image_width``/``image_height`` (or ``image_size``) are required. Each matrix must be an
    ``opencv-matrix`` mapping whose ``rows`` x ``cols`` match its ``data`` and whose ``dt`` is a one-channel type;
    every value is checked (:mod:`circcal.formats.limits`). XML document types and entities, and nesting deeper than
    :data:`~circcal.formats.limits.MAX_NESTING_DEPTH`, are refused before OpenCV's parser sees the text. Other nodes
    (OpenCV's sample writes many) are ignored.

    Parameters
    ----------
    text : str

    Returns
    -------
    Camera

    Raises
    ------
    ModelFileError
    """
    fs = open_filestorage(text)
    try:
        K = _fs_matrix(fs.getNode("camera_matrix"), "camera_matrix", max_size=9)
        if K.shape != (3, 3):
            raise ModelFileError(f"camera_matrix must be 3x3, got {K.shape[0]}x{K.shape[1]}")
        d = _fs_matrix(
            fs.getNode("distortion_coefficients"), "distortion_coefficients", max_size=max(OPENCV_DIST_SIZES)
        )
        if min(d.shape) > 1:
            raise ModelFileError(
                f"distortion_coefficients must be one row or one column, got {d.shape[0]}x{d.shape[1]}"
            )
        w_node, h_node = fs.getNode("image_width"), fs.getNode("image_height")
        if not w_node.empty() and not h_node.empty():
            w, h = _fs_scalar(w_node), _fs_scalar(h_node)
            names = ("image_width", "image_height")
        else:
            size = fs.getNode("image_size")
            if size.empty():
                raise ModelFileError("no image_width/image_height (or image_size): the image size is needed")
            if not size.isSeq() or size.size() != 2:
                raise ModelFileError("image_size must be a sequence of 2 integers [width, height]")
            w, h = _fs_scalar(size.at(0)), _fs_scalar(size.at(1))
            names = ("image_size[0] (width)", "image_size[1] (height)")
        w, h = integer(w, names[0]), integer(h, names[1])
        fisheye_node = fs.getNode("fisheye_model")
        fisheye = not fisheye_node.empty() and integer(_fs_scalar(fisheye_node), "fisheye_model", 0, 1) != 0
    finally:
        fs.release()
    return camera_from_K_dist(w, h, K, d.ravel(), lens="fisheye" if fisheye else None)


#: OpenCV FileStorage's one-channel element types (``dt``): u c w s i f d, and h (float16).
_FS_DT = re.compile(r"1?[ucwsifdh]")


def _fs_scalar(node: cv2.FileNode) -> object:
    """A FileStorage scalar as Python: a number (float), a string, or a short description of what it is instead."""
    if node.isInt() or node.isReal():
        return node.real()
    if node.isString():
        return node.string()
    return "<a sequence>" if node.isSeq() else "<a mapping>" if node.isMap() else "<nothing>"


def _fs_unique_keys(node: cv2.FileNode, where: str) -> None:
    """Refuse a key repeated in the FileStorage mapping ``node`` (OpenCV's parser keeps both and reads the first)."""
    if not node.isMap():
        raise ModelFileError(f"expected a mapping at {where}, got {show(_fs_scalar(node))}")
    seen: set[str] = set()
    for key in node.keys():
        if key in seen:
            raise ModelFileError(f"duplicate key {show(key)} at {where}")
        seen.add(key)


def _fs_matrix(node: cv2.FileNode, field: str, max_size: int) -> np.ndarray:
    """An ``opencv-matrix`` node (``rows``, ``cols``, ``dt``, ``data``) as a float64 (rows, cols) array of at most
    ``max_size`` elements, every element a finite number. Raises :class:`~circcal.errors.ModelFileError`."""
    if node.empty():
        raise ModelFileError(f"no {field} node")
    if not node.isMap():
        raise ModelFileError(
            f"{field} must be an opencv-matrix (a mapping of rows, cols, dt and data), got {show(_fs_scalar(node))}"
        )
    _fs_unique_keys(node, field)
    rows = integer(_fs_scalar(node.getNode("rows")), f"{field} rows", 0, max_size)
    cols = integer(_fs_scalar(node.getNode("cols")), f"{field} cols", 0, max_size)
    dt = _fs_scalar(node.getNode("dt"))
    if not isinstance(dt, str) or not _FS_DT.fullmatch(dt):
        raise ModelFileError(f"{field} dt must be a one-channel OpenCV type (u, c, w, s, i, f, d or h), got {show(dt)}")
    data = node.getNode("data")
    if not data.isSeq():
        raise ModelFileError(f"{field} data must be a sequence of numbers, got {show(_fs_scalar(data))}")
    if data.size() != rows * cols:
        raise ModelFileError(
            f"{field}: rows x cols = {rows} x {cols} = {rows * cols}, but its data holds {data.size()} numbers"
        )
    if rows * cols > max_size:
        raise ModelFileError(f"{field} holds {rows * cols} numbers, at most {max_size}")
    vals = [number(_fs_scalar(data.at(i)), f"{field} data[{i}]") for i in range(rows * cols)]
    return np.array(vals, dtype=np.float64).reshape(rows, cols)


#: The pinhole lens models by the distortion coefficients they hold (each one's vector a prefix of the next's).
_PINHOLE_LENSES = (("opencv5", 5), ("rational", 8), ("thin-prism", 12))


def pinhole_lens_of(d: np.ndarray) -> str:
    """The smallest pinhole lens model that holds OpenCV's distortion vector exactly.

    ``opencv5`` unless k4-k6 are nonzero (``rational``) or s1-s4 are (``thin-prism``). A file's zeros beyond k3 thus
    read as the 5-coefficient camera they are.

    Parameters
    ----------
    d : ndarray, shape (n,)
        0-12 coefficients (more when the extra ones are zero), OpenCV's order.

    Returns
    -------
    str

    Raises
    ------
    ModelFileError
        More than the thin-prism model's 12 coefficients are nonzero.

    Examples
    --------
    >>> pinhole_lens_of([0.1, 0.01, 0, 0, 0, 0, 0, 0])
    'opencv5'
    """
    d = np.asarray(d, dtype=np.float64).ravel()
    for name, n in _PINHOLE_LENSES:
        if not np.any(d[n:]):
            return name
    raise ModelFileError(f"{d.size} distortion coefficients: more than the thin-prism model's 12 are nonzero")


def camera_from_K_dist(
    w: float, h: float, K: np.ndarray, d: np.ndarray, what: str = "", lens: str | None = None
) -> Camera:
    """A :class:`~circcal.model.Camera` from OpenCV's camera matrix and distortion vector for a ``w`` x ``h`` image.

    Parameters
    ----------
    w, h : float
        The image size, px (an integer in 1..2**20).
    K : ndarray, shape (3, 3)
        The camera matrix, px.
    d : ndarray, shape (n,)
        The distortion vector: with ``lens`` None any of :data:`OPENCV_DIST_SIZES` (the tilted model's tau of 14 must
        be zero); with ``lens="fisheye"`` cv2.fisheye's ``D`` (4 coefficients).
    what : str
        Names the model in messages (e.g. the mrcal lens model).
    lens : str or None
        None: a pinhole model, the one :func:`pinhole_lens_of` ``d``; or ``"fisheye"``.

    Returns
    -------
    Camera

    Raises
    ------
    ModelFileError
        Also for a size that is not an integer in 1..2**20, a non-finite value, or a third row of ``K`` other than
        (0, 0, 1).
    """
    where = f"{what}: " if what else ""
    w, h = integer(w, f"{where}image width"), integer(h, f"{where}image height")
    K = np.asarray(K, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64).ravel()
    if K.shape != (3, 3):
        raise ModelFileError(f"{where}camera matrix must be 3x3, got {K.shape}")
    if not np.all(np.isfinite(K)):
        raise ModelFileError(f"{where}camera matrix must hold finite numbers, got {K.tolist()}")
    if not np.all(np.isfinite(d)):
        raise ModelFileError(f"{where}distortion coefficients must be finite numbers, got {show(d.tolist())}")
    check_K(K, f"{where}camera matrix")
    if abs(K[0, 1]) > SKEW_TOL * abs(K[0, 0]):
        raise ModelFileError(f"{where}skew {K[0, 1]} is not supported (circcal's model has zero skew)")
    if lens == "fisheye":
        if d.size != 4:
            raise ModelFileError(
                f"{where}a fisheye camera has 4 distortion coefficients (k1, k2, k3, k4), got {d.size}"
            )
        return Camera(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2], d, "fisheye")
    if lens is not None:
        raise ValueError(f"lens must be None (from the coefficients) or 'fisheye', got {lens!r}")
    if d.size not in OPENCV_DIST_SIZES:
        raise ModelFileError(f"{where}{d.size} distortion coefficients; expected 4, 5, 8, 12 or 14")
    if d.size == 14 and np.any(d[12:]):
        raise ModelFileError(
            f"{where}the tilted-sensor coefficients tau_x, tau_y = {d[12:].tolist()} are nonzero; "
            f"circcal's models hold at most OpenCV's 12 (thin prism)"
        )
    lens = pinhole_lens_of(d)
    n = dict(_PINHOLE_LENSES)[lens]
    dist = np.zeros(n)
    dist[: min(n, d.size)] = d[:n]
    return Camera(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist, lens)
