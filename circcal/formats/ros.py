"""ROS ``camera_info`` YAML: the camera_calibration_parsers layout (``camera_matrix``, ``distortion_model:
plumb_bob``, ``distortion_coefficients``, ``rectification_matrix``, ``projection_matrix``), what
camera_info_manager loads; the message layout (``K``, ``D``, ``R``, ``P``) is read too. ROS uses OpenCV's pixel
convention."""
from __future__ import annotations

import numpy as np

from circcal.errors import ModelFileError
from circcal.formats.opencv import camera_from_K_dist
from circcal.model import Camera

__all__ = ["camera_to_ros_yaml", "camera_from_ros_yaml"]


def camera_to_ros_yaml(camera: Camera, name: str = "camera") -> str:
    """ROS ``camera_info`` YAML as camera_calibration_parsers writes it (what camera_info_manager loads):
    plumb_bob D = [k1, k2, p1, p2, k3], K, R = I, P = [K | 0] (``yaml.safe_dump``)."""
    import yaml

    def matrix(a: np.ndarray) -> dict:
        a = np.atleast_2d(a)
        return {"rows": int(a.shape[0]), "cols": int(a.shape[1]), "data": [float(v) for v in a.ravel()]}

    doc = {"image_width": int(camera.width), "image_height": int(camera.height), "camera_name": str(name),
           "camera_matrix": matrix(camera.K), "distortion_model": "plumb_bob",
           "distortion_coefficients": matrix(camera.dist[None]), "rectification_matrix": matrix(np.eye(3)),
           "projection_matrix": matrix(np.hstack([camera.K, np.zeros((3, 1))]))}
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)


def camera_from_ros_yaml(text: str) -> Camera:
    """Camera from ROS camera_info YAML: the camera_calibration_parsers layout (``camera_matrix.data``,
    ``distortion_coefficients.data``, ``image_width``) or the message layout (``K``, ``D``, ``width``, ``height``).
    The distortion model must be plumb_bob (or rational_polynomial with k4..k6 = 0)."""
    import yaml

    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ModelFileError(f"ROS camera_info: not valid YAML ({exc})") from None
    if not isinstance(d, dict):
        raise ModelFileError("ROS camera_info: expected a YAML mapping at the top level")

    def data(key_file: str, key_msg: str) -> np.ndarray | None:
        v = d.get(key_file, d.get(key_msg))
        if v is None:
            return None
        try:
            return np.asarray(v["data"] if isinstance(v, dict) else v, dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            raise ModelFileError(f"ROS camera_info: {key_file} / {key_msg} must hold a list of numbers, got "
                                 f"{v!r}") from None

    K = data("camera_matrix", "K")
    D = data("distortion_coefficients", "D")
    if K is None or K.size != 9:
        raise ModelFileError("ROS camera_info: no 3x3 camera_matrix / K")
    model = str(d.get("distortion_model", "plumb_bob"))
    if model not in ("plumb_bob", "rational_polynomial"):
        raise ModelFileError(f"ROS camera_info: distortion_model {model!r} is not OpenCV's Brown model (plumb_bob)")
    w = d.get("image_width", d.get("width"))
    h = d.get("image_height", d.get("height"))
    if w is None or h is None:
        raise ModelFileError("ROS camera_info: no image_width/image_height (or width/height)")
    return camera_from_K_dist(w, h, K.reshape(3, 3), np.zeros(5) if D is None else D.ravel(), "ROS camera_info")
