"""OpenCV ``cv2.FileStorage`` camera files (YAML, or XML by the name): ``camera_matrix``,
``distortion_coefficients``, ``image_width``, ``image_height``, as OpenCV's calibration sample writes them; and
:func:`camera_from_K_dist`, the one conversion from an OpenCV camera matrix and distortion vector that every format
holding them (OpenCV, mrcal, ROS) reads through."""
from __future__ import annotations

import numpy as np

from circcal.errors import ModelFileError
from circcal.model import DIST_NAMES, Camera

__all__ = ["opencv_yaml_text", "camera_from_opencv_yaml", "camera_from_K_dist", "OPENCV_DIST_SIZES"]

#: Lengths of OpenCV's distortion vector: 4 (k1 k2 p1 p2), 5 (+ k3), 8 (+ k4 k5 k6), 12 (+ s1..s4), 14 (+ tau x, y).
OPENCV_DIST_SIZES = (0, 4, 5, 8, 12, 14)
#: A skew below this fraction of fx is rounding, not skew (OpenCV's own calibration never estimates one).
SKEW_TOL = 1e-12


def opencv_yaml_text(camera: Camera, *, xml: bool = False) -> str:
    """The FileStorage text (YAML, or XML) OpenCV's calibration sample writes: ``image_width``, ``image_height``,
    ``camera_matrix`` (3x3) and ``distortion_coefficients`` (1x5)."""
    import cv2

    fs = cv2.FileStorage(".xml" if xml else ".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("image_width", int(camera.width))
    fs.write("image_height", int(camera.height))
    fs.write("camera_matrix", camera.K)
    fs.write("distortion_coefficients", camera.dist.reshape(1, len(DIST_NAMES)))
    return fs.releaseAndGetString()


def camera_from_opencv_yaml(text: str) -> Camera:
    """Camera from an OpenCV FileStorage text (YAML or XML). Accepts 4, 5, 8, 12 or 14 distortion coefficients as
    long as those beyond k3 are zero; ``image_width``/``image_height`` (or ``image_size``) are required."""
    import cv2

    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except cv2.error as exc:
        raise ModelFileError(f"not an OpenCV FileStorage file ({str(exc).strip().splitlines()[-1]})") from None
    if not fs.isOpened():
        raise ModelFileError("not an OpenCV FileStorage file")
    try:
        K = fs.getNode("camera_matrix").mat()
        if K is None:
            raise ModelFileError("no camera_matrix node")
        d = fs.getNode("distortion_coefficients").mat()
        if d is None:
            raise ModelFileError("no distortion_coefficients node")
        w_node, h_node = fs.getNode("image_width"), fs.getNode("image_height")
        if not w_node.empty() and not h_node.empty():
            w, h = w_node.real(), h_node.real()
        else:
            size = fs.getNode("image_size")
            if size.empty():
                raise ModelFileError("no image_width/image_height (or image_size): the image size is needed")
            w, h = size.at(0).real(), size.at(1).real()
    finally:
        fs.release()
    return camera_from_K_dist(w, h, np.asarray(K, dtype=np.float64), np.asarray(d, dtype=np.float64).ravel())


def camera_from_K_dist(w: float, h: float, K: np.ndarray, d: np.ndarray, what: str = "") -> Camera:
    """A :class:`~circcal.model.Camera` from OpenCV's 3x3 camera matrix ``K`` and distortion vector ``d`` (any of
    :data:`OPENCV_DIST_SIZES`; coefficients beyond k3 must be zero) for a ``w`` x ``h`` image. ``what`` names the
    model in messages (e.g. the mrcal lens model). Raises :class:`~circcal.errors.ModelFileError`."""
    where = f"{what}: " if what else ""
    K = np.asarray(K, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64).ravel()
    if K.shape != (3, 3):
        raise ModelFileError(f"{where}camera matrix must be 3x3, got {K.shape}")
    if abs(K[0, 1]) > SKEW_TOL * abs(K[0, 0]):
        raise ModelFileError(f"{where}skew {K[0, 1]} is not supported (circcal's model has zero skew)")
    if d.size not in OPENCV_DIST_SIZES:
        raise ModelFileError(f"{where}{d.size} distortion coefficients; expected 4, 5, 8, 12 or 14")
    n = len(DIST_NAMES)
    if d.size > n and np.any(d[n:] != 0):
        raise ModelFileError(f"{where}distortion coefficients beyond k3 are nonzero ({d[n:].tolist()}); circcal's "
                             f"model holds only [k1, k2, p1, p2, k3]")
    dist = np.zeros(n)
    dist[: min(n, d.size)] = d[:n]
    return Camera(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist)
