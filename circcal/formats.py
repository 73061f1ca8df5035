"""Camera-model files: circcal's model.json and the formats other tools read.

Every format here holds the same 5-coefficient OpenCV model (:class:`circcal.model.Camera`); a format that cannot
hold a given camera exactly is refused with a clear error rather than written lossily.

=================  ==========================================================================================
format             file
=================  ==========================================================================================
``json``           circcal model.json: the truth.json ``camera`` block plus ``std``, errors (convention in each
                   key), per-view poses (see :meth:`circcal.solver.CalibrationResult.to_model_json`)
``opencv``         OpenCV ``cv2.FileStorage`` YAML (or .xml): ``camera_matrix``, ``distortion_coefficients``,
                   ``image_width``, ``image_height``
``mrcal``          mrcal ``.cameramodel``: a Python dict literal, ``LENSMODEL_OPENCV5`` intrinsics
                   ``[fx, fy, cx, cy, k1, k2, p1, p2, k3]`` and ``imagersize`` (same pixel convention as OpenCV)
``colmap``         COLMAP ``cameras.txt``: ``OPENCV`` (fx fy cx cy k1 k2 p1 p2, no k3) or ``FULL_OPENCV``
                   (+ k3 k4 k5 k6). COLMAP puts the top-left pixel's centre at (0.5, 0.5): ``cx_colmap = cx + 0.5``
``ros``            ROS ``camera_info`` YAML (camera_calibration_parsers layout: ``camera_matrix``,
                   ``distortion_model: plumb_bob``, ``distortion_coefficients``, ``rectification_matrix``,
                   ``projection_matrix``; the message layout with ``K``, ``D``, ``R``, ``P`` is read too)
=================  ==========================================================================================

:func:`read_camera` and :func:`write_camera` pick the format from the file name and, for reading, its content.
"""
from __future__ import annotations

import ast
import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from circcal.jsonio import dumps
from circcal.model import Camera

__all__ = [
    "FORMATS",
    "detect_format",
    "read_camera",
    "write_camera",
    "camera_to_model_json",
    "camera_from_json",
    "write_opencv_yaml",
    "read_opencv_yaml",
    "camera_to_cameramodel",
    "camera_from_cameramodel",
    "camera_to_colmap",
    "camera_from_colmap",
    "camera_to_ros_yaml",
    "camera_from_ros_yaml",
]

FORMATS: tuple[str, ...] = ("json", "opencv", "mrcal", "colmap", "ros")
COLMAP_PIXEL_OFFSET = 0.5  # COLMAP pixel-centre convention minus OpenCV's


# --------------------------------------------------------------------------------------------------------------------
# Format detection
# --------------------------------------------------------------------------------------------------------------------

def detect_format(path: str | Path, text: str | None = None) -> str:
    """Format of a camera file from its name and (when ``text`` is given) its content. Returns one of
    :data:`FORMATS`; raises ValueError when neither tells."""
    p = Path(path)
    ext = p.suffix.lower()
    name = p.name.lower()
    if text is not None:
        head = text.lstrip()
        if head.startswith("{") and ext != ".cameramodel":
            try:
                json.loads(text)
                return "json"
            except json.JSONDecodeError:
                pass
        if "lensmodel" in text and "intrinsics" in text:
            return "mrcal"
        if head.startswith("%YAML") or "opencv-matrix" in text or head.startswith("<?xml"):
            return "opencv"
        if re.search(r"^\s*(distortion_model|camera_matrix|K)\s*:", text, re.M):
            return "ros"
        if re.search(r"^\s*\d+\s+(OPENCV|FULL_OPENCV|PINHOLE|SIMPLE_PINHOLE|SIMPLE_RADIAL|RADIAL)\s", text, re.M):
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
    raise ValueError(f"cannot tell the camera format of {p.name!r}: use .json (circcal), .yaml/.yml/.xml (OpenCV; "
                     f"ROS camera_info when the name holds 'camera_info'), .cameramodel (mrcal) or .txt (COLMAP "
                     f"cameras.txt), or name the format ({', '.join(FORMATS)})")


def read_camera(path: str | Path, fmt: str | None = None) -> Camera:
    """Read a camera from any supported file (format from ``fmt``, else content and name)."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"no such camera file: {p}")
    text = p.read_text()
    fmt = fmt or detect_format(p, text)
    if fmt == "json":
        return camera_from_json(json.loads(text))
    if fmt == "opencv":
        return read_opencv_yaml(p)
    if fmt == "mrcal":
        return camera_from_cameramodel(text)
    if fmt == "colmap":
        return camera_from_colmap(text)
    if fmt == "ros":
        return camera_from_ros_yaml(text)
    raise ValueError(f"unknown camera format {fmt!r}; expected one of {', '.join(FORMATS)}")


def write_camera(path: str | Path, camera: Camera, fmt: str | None = None, *, model_json: dict | None = None,
                 colmap_model: str = "auto", name: str = "camera") -> str:
    """Write ``camera`` to ``path`` in ``fmt`` (default: from the file name). For ``json``, ``model_json`` (e.g.
    :meth:`CalibrationResult.to_model_json`) is written when given, else the bare camera block.
    ``colmap_model``: ``"auto"`` (OPENCV when k3 = 0, else FULL_OPENCV), ``"OPENCV"`` or ``"FULL_OPENCV"``.
    Returns the format written."""
    p = Path(path)
    fmt = fmt or detect_format(p)
    if fmt == "json":
        data = model_json if model_json is not None else camera_to_model_json(camera)
        p.write_text(dumps(data, indent=2) + "\n")
    elif fmt == "opencv":
        write_opencv_yaml(p, camera)
    elif fmt == "mrcal":
        p.write_text(camera_to_cameramodel(camera))
    elif fmt == "colmap":
        p.write_text(camera_to_colmap(camera, model=colmap_model))
    elif fmt == "ros":
        p.write_text(camera_to_ros_yaml(camera, name=name))
    else:
        raise ValueError(f"unknown camera format {fmt!r}; expected one of {', '.join(FORMATS)}")
    return fmt


# --------------------------------------------------------------------------------------------------------------------
# circcal model.json
# --------------------------------------------------------------------------------------------------------------------

def camera_to_model_json(camera: Camera) -> dict[str, Any]:
    """A minimal model.json: just the ``camera`` block (no uncertainty known)."""
    return {"format": "circcal-model", "version": 1, "camera": camera.to_dict()}


def camera_from_json(data: dict[str, Any]) -> Camera:
    """Camera from model.json / truth.json (its ``camera`` block) or a bare camera block."""
    if "camera" in data and isinstance(data["camera"], dict):
        return Camera.from_dict(data["camera"])
    return Camera.from_dict(data)


# --------------------------------------------------------------------------------------------------------------------
# OpenCV FileStorage
# --------------------------------------------------------------------------------------------------------------------

def write_opencv_yaml(path: str | Path, camera: Camera) -> None:
    """OpenCV FileStorage file (YAML, or XML for a .xml name), as OpenCV's calibration sample writes it."""
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise ValueError(f"cannot open {path} for writing")
    fs.write("image_width", int(camera.width))
    fs.write("image_height", int(camera.height))
    fs.write("camera_matrix", camera.K)
    fs.write("distortion_coefficients", camera.dist.reshape(1, 5))
    fs.release()


def read_opencv_yaml(path: str | Path) -> Camera:
    """Camera from an OpenCV FileStorage file. Accepts 4, 5, 8, 12 or 14 distortion coefficients as long as those
    beyond k3 are zero; ``image_width``/``image_height`` (or ``image_size``) are required."""
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise ValueError(f"{path}: not an OpenCV FileStorage file")
    try:
        K = fs.getNode("camera_matrix").mat()
        if K is None:
            raise ValueError(f"{path}: no camera_matrix node")
        d = fs.getNode("distortion_coefficients").mat()
        if d is None:
            raise ValueError(f"{path}: no distortion_coefficients node")
        w_node, h_node = fs.getNode("image_width"), fs.getNode("image_height")
        if not w_node.empty() and not h_node.empty():
            w, h = int(w_node.real()), int(h_node.real())
        else:
            size = fs.getNode("image_size")
            if size.empty():
                raise ValueError(f"{path}: no image_width/image_height (or image_size): the image size is needed")
            w, h = int(size.at(0).real()), int(size.at(1).real())
    finally:
        fs.release()
    return _camera_from_K_dist(w, h, np.asarray(K, dtype=np.float64), np.asarray(d, dtype=np.float64).ravel(),
                               str(path))


def _camera_from_K_dist(w: int, h: int, K: np.ndarray, d: np.ndarray, where: str) -> Camera:
    if K.shape != (3, 3):
        raise ValueError(f"{where}: camera matrix must be 3x3, got {K.shape}")
    if abs(K[0, 1]) > 1e-12 * abs(K[0, 0]):
        raise ValueError(f"{where}: skew {K[0, 1]} is not supported (circcal's model has zero skew)")
    if d.size not in (0, 4, 5, 8, 12, 14):
        raise ValueError(f"{where}: {d.size} distortion coefficients; expected 4, 5, 8, 12 or 14")
    if d.size > 5 and np.any(d[5:] != 0):
        raise ValueError(f"{where}: distortion coefficients beyond k3 are nonzero ({d[5:].tolist()}); circcal's "
                         f"model holds only [k1, k2, p1, p2, k3]")
    dist = np.zeros(5)
    dist[: min(5, d.size)] = d[:5]
    return Camera(int(w), int(h), float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), dist)


# --------------------------------------------------------------------------------------------------------------------
# mrcal .cameramodel
# --------------------------------------------------------------------------------------------------------------------

def camera_to_cameramodel(camera: Camera) -> str:
    """mrcal ``.cameramodel`` text (LENSMODEL_OPENCV5; identity extrinsics). mrcal's pixel convention is OpenCV's."""
    vals = ", ".join(repr(float(v)) for v in camera.intrinsics)
    return ("# generated by circcal\n"
            "# intrinsics are fx,fy,cx,cy,distortion0,distortion1,....\n"
            "{\n"
            "    'lensmodel':  'LENSMODEL_OPENCV5',\n"
            f"    'intrinsics': [ {vals},],\n"
            "    # extrinsics are rt_fromref\n"
            "    'extrinsics': [ 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,],\n"
            f"    'imagersize': [ {int(camera.width)}, {int(camera.height)} ],\n"
            "}\n")


def camera_from_cameramodel(text: str) -> Camera:
    """Camera from mrcal ``.cameramodel`` text (read with ``ast.literal_eval``; no mrcal needed). Accepts
    LENSMODEL_PINHOLE and LENSMODEL_OPENCV4/5/8/12 (coefficients beyond k3 must be zero)."""
    try:
        d = ast.literal_eval(text)
    except (ValueError, SyntaxError) as exc:
        raise ValueError(f"not a mrcal .cameramodel (not a Python dict literal): {exc}") from exc
    if not isinstance(d, dict) or "lensmodel" not in d or "intrinsics" not in d or "imagersize" not in d:
        raise ValueError("not a mrcal .cameramodel: needs 'lensmodel', 'intrinsics' and 'imagersize'")
    model = str(d["lensmodel"])
    p = np.asarray(d["intrinsics"], dtype=np.float64)
    n = {"LENSMODEL_PINHOLE": 4, "LENSMODEL_OPENCV4": 8, "LENSMODEL_OPENCV5": 9, "LENSMODEL_OPENCV8": 12,
         "LENSMODEL_OPENCV12": 16}.get(model)
    if n is None:
        raise ValueError(f"mrcal lens model {model} has no exact OpenCV-5 equivalent; supported: "
                         f"LENSMODEL_PINHOLE, LENSMODEL_OPENCV4/5/8/12")
    if p.size != n:
        raise ValueError(f"{model} needs {n} intrinsics, got {p.size}")
    w, h = (int(v) for v in d["imagersize"])
    K = np.array([[p[0], 0.0, p[2]], [0.0, p[1], p[3]], [0.0, 0.0, 1.0]])
    return _camera_from_K_dist(w, h, K, p[4:], model)


# --------------------------------------------------------------------------------------------------------------------
# COLMAP cameras.txt
# --------------------------------------------------------------------------------------------------------------------

def camera_to_colmap(camera: Camera, model: str = "auto", camera_id: int = 1) -> str:
    """COLMAP ``cameras.txt`` with one camera. ``model``: ``"auto"`` (OPENCV when k3 = 0, else FULL_OPENCV),
    ``"OPENCV"`` (refuses a nonzero k3: it cannot be dropped silently) or ``"FULL_OPENCV"``. The principal point
    is shifted by +0.5 px into COLMAP's pixel convention."""
    k1, k2, p1, p2, k3 = (float(v) for v in camera.dist)
    model = model.upper()
    if model == "AUTO":
        model = "OPENCV" if k3 == 0.0 else "FULL_OPENCV"
    if model == "OPENCV":
        if k3 != 0.0:
            raise ValueError(f"COLMAP's OPENCV model has no k3, and this camera has k3 = {k3:.6g}: write "
                             f"FULL_OPENCV instead (or calibrate with k3 fixed at 0)")
        extra = [k1, k2, p1, p2]
    elif model == "FULL_OPENCV":
        extra = [k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]
    else:
        raise ValueError(f"unsupported COLMAP model {model!r}; expected OPENCV or FULL_OPENCV")
    params = [camera.fx, camera.fy, camera.cx + COLMAP_PIXEL_OFFSET, camera.cy + COLMAP_PIXEL_OFFSET] + extra
    return ("# Camera list with one line of data per camera:\n"
            "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
            "# Number of cameras: 1\n"
            f"{camera_id} {model} {int(camera.width)} {int(camera.height)} "
            + " ".join(repr(float(v)) for v in params) + "\n")


def camera_from_colmap(text: str, camera_id: int | None = None) -> Camera:
    """Camera from COLMAP ``cameras.txt`` (the first camera, or ``camera_id``). Models SIMPLE_PINHOLE, PINHOLE,
    SIMPLE_RADIAL, RADIAL, OPENCV and FULL_OPENCV (k4..k6 must be zero); the principal point is shifted by -0.5 px
    into OpenCV's convention."""
    lines = [ln.split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if camera_id is not None:
        lines = [ln for ln in lines if ln[0] == str(camera_id)]
    if not lines:
        raise ValueError("no camera line in cameras.txt" + (f" with id {camera_id}" if camera_id is not None else ""))
    cid, model, w, h, *vals = lines[0]
    q = [float(v) for v in vals]
    need = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8, "FULL_OPENCV": 12}
    if model not in need:
        raise ValueError(f"COLMAP camera {cid}: model {model} has no exact OpenCV-5 equivalent; supported: "
                         f"{', '.join(need)}")
    if len(q) != need[model]:
        raise ValueError(f"COLMAP camera {cid}: {model} needs {need[model]} parameters, got {len(q)}")
    dist = np.zeros(5)
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = q[0]
        cx, cy = q[1], q[2]
        dist[: len(q) - 3] = q[3:]
    else:
        fx, fy, cx, cy = q[:4]
        if model == "FULL_OPENCV":
            if any(q[9:12]):
                raise ValueError(f"COLMAP camera {cid}: FULL_OPENCV k4..k6 = {q[9:12]} are nonzero; circcal's model "
                                 f"holds only [k1, k2, p1, p2, k3]")
            dist[:] = q[4:9]
        elif model == "OPENCV":
            dist[:4] = q[4:8]
    return Camera(int(w), int(h), fx, fy, cx - COLMAP_PIXEL_OFFSET, cy - COLMAP_PIXEL_OFFSET, dist)


# --------------------------------------------------------------------------------------------------------------------
# ROS camera_info YAML
# --------------------------------------------------------------------------------------------------------------------

def camera_to_ros_yaml(camera: Camera, name: str = "camera") -> str:
    """ROS ``camera_info`` YAML as camera_calibration_parsers writes it (what camera_info_manager loads):
    plumb_bob D = [k1, k2, p1, p2, k3], K, R = I, P = [K | 0]. ROS uses OpenCV's pixel convention."""
    K = camera.K.ravel()
    P = np.hstack([camera.K, np.zeros((3, 1))]).ravel()

    def fmt(a):
        return "[" + ", ".join(repr(float(v)) for v in a) + "]"

    return (f"image_width: {int(camera.width)}\n"
            f"image_height: {int(camera.height)}\n"
            f"camera_name: {name}\n"
            "camera_matrix:\n  rows: 3\n  cols: 3\n"
            f"  data: {fmt(K)}\n"
            "distortion_model: plumb_bob\n"
            "distortion_coefficients:\n  rows: 1\n  cols: 5\n"
            f"  data: {fmt(camera.dist)}\n"
            "rectification_matrix:\n  rows: 3\n  cols: 3\n"
            f"  data: {fmt(np.eye(3).ravel())}\n"
            "projection_matrix:\n  rows: 3\n  cols: 4\n"
            f"  data: {fmt(P)}\n")


def camera_from_ros_yaml(text: str) -> Camera:
    """Camera from ROS camera_info YAML: the camera_calibration_parsers layout (``camera_matrix.data``,
    ``distortion_coefficients.data``, ``image_width``) or the message layout (``K``, ``D``, ``width``, ``height``).
    The distortion model must be plumb_bob (or rational_polynomial with k4..k6 = 0)."""
    import yaml

    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"ROS camera_info: not valid YAML ({exc})") from None
    if not isinstance(d, dict):
        raise ValueError("ROS camera_info: expected a YAML mapping at the top level")

    def data(key_file: str, key_msg: str) -> np.ndarray | None:
        if key_file in d and d[key_file] is not None:
            v = d[key_file]
            return np.asarray(v["data"] if isinstance(v, dict) else v, dtype=np.float64)
        if key_msg in d and d[key_msg] is not None:
            return np.asarray(d[key_msg], dtype=np.float64)
        return None

    K = data("camera_matrix", "K")
    D = data("distortion_coefficients", "D")
    if K is None or K.size != 9:
        raise ValueError("ROS camera_info: no 3x3 camera_matrix / K")
    model = str(d.get("distortion_model", "plumb_bob"))
    if model not in ("plumb_bob", "rational_polynomial"):
        raise ValueError(f"ROS camera_info: distortion_model {model!r} is not OpenCV's Brown model (plumb_bob)")
    w = d.get("image_width", d.get("width"))
    h = d.get("image_height", d.get("height"))
    if w is None or h is None:
        raise ValueError("ROS camera_info: no image_width/image_height (or width/height)")
    return _camera_from_K_dist(int(w), int(h), K.reshape(3, 3), np.zeros(5) if D is None else D.ravel(),
                               "ROS camera_info")
