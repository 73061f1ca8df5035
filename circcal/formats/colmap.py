"""COLMAP ``cameras.txt``: ``OPENCV`` (fx fy cx cy k1 k2 p1 p2, no k3), ``FULL_OPENCV`` (fx fy cx cy k1 k2 p1 p2 k3
k4 k5 k6: OpenCV's rational vector) and ``OPENCV_FISHEYE`` (fx fy cx cy k1 k2 k3 k4: cv2.fisheye's). COLMAP has no
thin-prism model (a ``thin-prism`` camera is refused with that reason). COLMAP puts the top-left pixel's centre at
(0.5, 0.5), OpenCV at (0, 0): ``cx_colmap = cx + 0.5`` at this file boundary and nowhere else."""

from __future__ import annotations

import numpy as np

from circcal.errors import InputError, ModelFileError
from circcal.formats.opencv import camera_from_K_dist
from circcal.model import Camera

__all__ = ["COLMAP_PIXEL_OFFSET", "COLMAP_MODELS", "camera_to_colmap", "camera_from_colmap"]

COLMAP_PIXEL_OFFSET = 0.5  # COLMAP pixel-centre convention minus OpenCV's
#: The COLMAP models this module reads, with their parameter counts.
COLMAP_MODELS = {
    "SIMPLE_PINHOLE": 3,
    "PINHOLE": 4,
    "SIMPLE_RADIAL": 4,
    "RADIAL": 5,
    "OPENCV": 8,
    "FULL_OPENCV": 12,
    "OPENCV_FISHEYE": 8,
}


def camera_to_colmap(camera: Camera, model: str = "auto", camera_id: int = 1) -> str:
    """COLMAP ``cameras.txt`` with one camera.

    The principal point is shifted by +0.5 px into COLMAP's pixel convention.

    Parameters
    ----------
    camera : Camera
    model : str
        ``"auto"`` (opencv5: OPENCV when k3 = 0, else FULL_OPENCV; rational: FULL_OPENCV; fisheye: OPENCV_FISHEYE),
        or one of those names (``OPENCV`` refuses a nonzero k3: it cannot be dropped silently).
    camera_id : int

    Returns
    -------
    str

    Raises
    ------
    InputError
        A thin-prism camera (COLMAP has no such model), or a model that cannot hold the camera.
    """
    model = model.upper()
    lens = camera.lens
    if lens == "thin-prism":
        raise InputError(
            "COLMAP has no thin-prism model (its OpenCV models are OPENCV, FULL_OPENCV and "
            "OPENCV_FISHEYE): write another format, or calibrate with --lens rational"
        )
    if model == "AUTO":
        model = {
            "fisheye": "OPENCV_FISHEYE",
            "rational": "FULL_OPENCV",
            "opencv5": "OPENCV" if camera.dist[-1] == 0.0 else "FULL_OPENCV",
        }[lens]
    d = [float(v) for v in camera.dist]
    if lens == "fisheye":
        if model != "OPENCV_FISHEYE":
            raise InputError(f"a fisheye camera is COLMAP's OPENCV_FISHEYE, not {model}")
        extra = d
    elif model == "OPENCV":
        if any(d[4:]):
            raise InputError(
                f"COLMAP's OPENCV model has no k3..k6, and this camera has k3.. = {d[4:]}: write "
                f"FULL_OPENCV instead (or calibrate with k3 fixed at 0)"
            )
        extra = d[:4]
    elif model == "FULL_OPENCV":
        extra = (d + [0.0, 0.0, 0.0])[:8]
    else:
        raise InputError(
            f"unsupported COLMAP model {model!r} for a {lens} camera; expected OPENCV, FULL_OPENCV or OPENCV_FISHEYE"
        )
    params = [camera.fx, camera.fy, camera.cx + COLMAP_PIXEL_OFFSET, camera.cy + COLMAP_PIXEL_OFFSET] + extra
    return (
        "# Camera list with one line of data per camera:\n"
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        "# Number of cameras: 1\n"
        f"{camera_id} {model} {int(camera.width)} {int(camera.height)} "
        + " ".join(repr(float(v)) for v in params)
        + "\n"
    )


def camera_from_colmap(text: str, camera_id: int | None = None) -> Camera:
    """Camera from COLMAP ``cameras.txt``.

    Models SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV (``rational`` when k4..k6 are nonzero,
    else ``opencv5``) and OPENCV_FISHEYE (``fisheye``); the principal point is shifted by -0.5 px into OpenCV's
    convention.

    Parameters
    ----------
    text : str
        The file's content.
    camera_id : int or None
        The camera to read; None: the first.

    Returns
    -------
    Camera

    Raises
    ------
    ModelFileError
        No such camera line, a malformed line, an unsupported model or a value outside the limits.
    """
    lines = [ln.split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if camera_id is not None:
        lines = [ln for ln in lines if ln[0] == str(camera_id)]
    if not lines:
        raise ModelFileError(
            "no camera line in cameras.txt" + (f" with id {camera_id}" if camera_id is not None else "")
        )
    if len(lines[0]) < 4:
        raise ModelFileError(f"a camera line needs CAMERA_ID MODEL WIDTH HEIGHT PARAMS..., got {' '.join(lines[0])!r}")
    cid, model, w_text, h_text, *vals = lines[0]
    try:
        q = [float(v) for v in vals]
        w, h = float(w_text), float(h_text)
    except ValueError:
        raise ModelFileError(
            f"COLMAP camera {cid}: the size and parameters must be numbers, got {' '.join(lines[0][2:])!r}"
        ) from None
    need = COLMAP_MODELS
    if model not in need:
        raise ModelFileError(
            f"COLMAP camera {cid}: model {model} has no exact circcal equivalent; supported: {', '.join(need)}"
        )
    if len(q) != need[model]:
        raise ModelFileError(f"COLMAP camera {cid}: {model} needs {need[model]} parameters, got {len(q)}")
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = q[0]
        cx, cy = q[1], q[2]
        dist = np.zeros(5)
        dist[: len(q) - 3] = q[3:]
    else:
        fx, fy, cx, cy = q[:4]
        dist = np.asarray(q[4:])
    K = np.array([[fx, 0.0, cx - COLMAP_PIXEL_OFFSET], [0.0, fy, cy - COLMAP_PIXEL_OFFSET], [0.0, 0.0, 1.0]])
    return camera_from_K_dist(
        w, h, K, dist, f"COLMAP camera {cid} ({model})", lens="fisheye" if model == "OPENCV_FISHEYE" else None
    )
