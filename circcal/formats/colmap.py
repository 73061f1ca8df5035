"""COLMAP ``cameras.txt``: ``OPENCV`` (fx fy cx cy k1 k2 p1 p2, no k3) or ``FULL_OPENCV`` (+ k3 k4 k5 k6).
COLMAP puts the top-left pixel's centre at (0.5, 0.5), OpenCV at (0, 0): ``cx_colmap = cx + 0.5`` at this file
boundary and nowhere else."""
from __future__ import annotations

import numpy as np

from circcal.errors import InputError, ModelFileError
from circcal.model import Camera

__all__ = ["COLMAP_PIXEL_OFFSET", "camera_to_colmap", "camera_from_colmap"]

COLMAP_PIXEL_OFFSET = 0.5  # COLMAP pixel-centre convention minus OpenCV's


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
            raise InputError(f"COLMAP's OPENCV model has no k3, and this camera has k3 = {k3:.6g}: write "
                             f"FULL_OPENCV instead (or calibrate with k3 fixed at 0)")
        extra = [k1, k2, p1, p2]
    elif model == "FULL_OPENCV":
        extra = [k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]
    else:
        raise InputError(f"unsupported COLMAP model {model!r}; expected OPENCV or FULL_OPENCV")
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
        raise ModelFileError("no camera line in cameras.txt" + (f" with id {camera_id}" if camera_id is not None
                                                                else ""))
    if len(lines[0]) < 4:
        raise ModelFileError(f"a camera line needs CAMERA_ID MODEL WIDTH HEIGHT PARAMS..., got {' '.join(lines[0])!r}")
    cid, model, w, h, *vals = lines[0]
    try:
        q = [float(v) for v in vals]
        w, h = float(w), float(h)
    except ValueError:
        raise ModelFileError(f"COLMAP camera {cid}: the size and parameters must be numbers, got "
                             f"{' '.join(lines[0][2:])!r}") from None
    need = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8, "FULL_OPENCV": 12}
    if model not in need:
        raise ModelFileError(f"COLMAP camera {cid}: model {model} has no exact OpenCV-5 equivalent; supported: "
                         f"{', '.join(need)}")
    if len(q) != need[model]:
        raise ModelFileError(f"COLMAP camera {cid}: {model} needs {need[model]} parameters, got {len(q)}")
    dist = np.zeros(5)
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = q[0]
        cx, cy = q[1], q[2]
        dist[: len(q) - 3] = q[3:]
    else:
        fx, fy, cx, cy = q[:4]
        if model == "FULL_OPENCV":
            if any(q[9:12]):
                raise ModelFileError(f"COLMAP camera {cid}: FULL_OPENCV k4..k6 = {q[9:12]} are nonzero; circcal's model "
                                 f"holds only [k1, k2, p1, p2, k3]")
            dist[:] = q[4:9]
        elif model == "OPENCV":
            dist[:4] = q[4:8]
    return Camera(w, h, fx, fy, cx - COLMAP_PIXEL_OFFSET, cy - COLMAP_PIXEL_OFFSET, dist)


