"""ROS ``camera_info`` YAML: the camera_calibration_parsers layout (``camera_matrix``, ``distortion_model``,
``distortion_coefficients``, ``rectification_matrix``, ``projection_matrix``), what camera_info_manager loads; the
message layout (``K``, ``D``, ``R``, ``P``) is read too. ROS uses OpenCV's pixel convention.

Distortion models (sensor_msgs/distortion_models.h; image_geometry projects them with OpenCV): ``plumb_bob`` D =
[k1, k2, p1, p2, k3] (``opencv5``), ``rational_polynomial`` D = [k1, k2, p1, p2, k3, k4, k5, k6] (``rational``),
``equidistant`` D = [k1, k2, k3, k4] (cv2.fisheye: ``fisheye``). ROS has no thin-prism model: such a camera is
refused with that reason."""

from __future__ import annotations

from typing import Any

import numpy as np

from circcal.errors import InputError, ModelFileError
from circcal.formats.limits import integer, load_yaml, matrix, number_list, show
from circcal.formats.opencv import camera_from_K_dist
from circcal.model import Camera

__all__ = ["ROS_DISTORTION_MODELS", "camera_to_ros_yaml", "camera_from_ros_yaml"]

#: circcal's lens model -> ROS's distortion_model.
ROS_DISTORTION_MODELS: dict[str, str] = {
    "opencv5": "plumb_bob",
    "rational": "rational_polynomial",
    "fisheye": "equidistant",
}


def camera_to_ros_yaml(camera: Camera, name: str = "camera") -> str:
    """ROS ``camera_info`` YAML as camera_calibration_parsers writes it (what camera_info_manager loads).

    The distortion model of :data:`ROS_DISTORTION_MODELS` with its D, K, R = I, P = [K | 0] (``yaml.safe_dump``).

    Parameters
    ----------
    camera : Camera
    name : str
        ``camera_name``.

    Returns
    -------
    str

    Raises
    ------
    InputError
        A thin-prism camera (ROS has no such model).
    """
    import yaml

    if camera.lens not in ROS_DISTORTION_MODELS:
        raise InputError(
            "ROS camera_info has no thin-prism distortion model (plumb_bob, rational_polynomial and "
            "equidistant only): write another format, or calibrate with --lens rational"
        )

    def matrix(a: np.ndarray) -> dict[str, Any]:
        a = np.atleast_2d(a)
        return {"rows": int(a.shape[0]), "cols": int(a.shape[1]), "data": [float(v) for v in a.ravel()]}

    doc = {
        "image_width": int(camera.width),
        "image_height": int(camera.height),
        "camera_name": str(name),
        "camera_matrix": matrix(camera.K),
        "distortion_model": ROS_DISTORTION_MODELS[camera.lens],
        "distortion_coefficients": matrix(camera.dist[None]),
        "rectification_matrix": matrix(np.eye(3)),
        "projection_matrix": matrix(np.hstack([camera.K, np.zeros((3, 1))])),
    }
    return str(yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))


def camera_from_ros_yaml(text: str) -> Camera:
    """Camera from ROS camera_info YAML.

    The camera_calibration_parsers layout (``camera_matrix.data``, ``distortion_coefficients.data``,
    ``image_width``) or the message layout (``K``, ``D``, ``width``, ``height``). The distortion model: plumb_bob,
    rational_polynomial (``rational``; ``opencv5`` when k4..k6 are 0) or equidistant (``fisheye``). Parsed with
    :func:`circcal.formats.limits.load_yaml` (no anchors or aliases, no repeated keys, bounded depth); a matrix's
    ``rows`` x ``cols`` must match its data; numbers must be numbers (a boolean is none). Other keys
    (``camera_name``, ``rectification_matrix``, ``projection_matrix``, ...) are a foreign format's extras: ignored.

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
    try:
        d = load_yaml(text)
    except ModelFileError as exc:
        raise ModelFileError(f"ROS camera_info: {exc}") from None
    if not isinstance(d, dict):
        raise ModelFileError("ROS camera_info: expected a YAML mapping at the top level")

    def entry(key_file: str, key_msg: str) -> tuple[str, object]:
        key = key_file if key_file in d else key_msg
        return f"ROS camera_info {key}", d.get(key)

    def data(key_file: str, key_msg: str) -> tuple[object, object, object]:
        """(data, rows, cols) of a matrix given as {rows, cols, data} or as a bare list."""
        field, v = entry(key_file, key_msg)
        if isinstance(v, dict):
            if "data" not in v:
                raise ModelFileError(f"{field} has no data")
            return v["data"], v.get("rows"), v.get("cols")
        return v, None, None

    field, _ = entry("camera_matrix", "K")
    k, rows, cols = data("camera_matrix", "K")
    if k is None:
        raise ModelFileError("ROS camera_info: no 3x3 camera_matrix / K")
    K = matrix(k, field, (3, 3), rows, cols)
    dfield, _ = entry("distortion_coefficients", "D")
    dv, rows, cols = data("distortion_coefficients", "D")
    D: np.ndarray | None
    if dv is not None and (rows is not None or cols is not None):
        r, c = integer(rows, f"{dfield} rows", 0, 14), integer(cols, f"{dfield} cols", 0, 14)
        D = matrix(dv, dfield, (r, c), rows, cols).ravel()
    else:
        D = None if dv is None else number_list(dv, dfield)
    model = d.get("distortion_model", "plumb_bob")
    if model not in ROS_DISTORTION_MODELS.values():
        raise ModelFileError(
            f"ROS camera_info: distortion_model {show(model)} is none of circcal's: "
            f"{', '.join(ROS_DISTORTION_MODELS.values())}"
        )
    wfield, w = entry("image_width", "width")
    hfield, h = entry("image_height", "height")
    if w is None or h is None:
        raise ModelFileError("ROS camera_info: no image_width/image_height (or width/height)")
    w, h = integer(w, wfield), integer(h, hfield)
    fisheye = model == "equidistant"
    if D is None:
        D = np.zeros(4 if fisheye else 5)
    return camera_from_K_dist(w, h, K, D, f"ROS camera_info ({model})", lens="fisheye" if fisheye else None)
