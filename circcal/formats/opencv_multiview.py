"""OpenCV's multi-camera observation files: one ``cv::FileStorage`` JSON per camera of detected board points.

The form of OpenCV's multiview calibration test data (``opencv_extra/testdata/cv/cameracalibration/multiview/``, a
copy in ``../shared/data/multiview/``)::

    {"frame_<i>": {"type_id": "opencv-matrix", "rows": 2N, "cols": 1, "dt": "f", "data": [u0, v0, u1, v1, ...]}, ...}

One key per instant at which that camera found the whole board (the same ``<i>`` in two cameras is the same
instant); the points in ``cv::findCirclesGrid`` order of the board (OpenCV's point order = circcal's,
:mod:`circcal.board`). Pixels in OpenCV's convention (pixel centres at integers).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from circcal.errors import InputError
from circcal.jsonio import read_json

__all__ = ["read_multiview_points", "MAX_FILE_BYTES"]

#: A camera's file is at most this large (the test data's are ~0.2 MB; 1000 frames of a 1000-point board ~ 40 MB).
MAX_FILE_BYTES = 256 * 1024 * 1024


def read_multiview_points(path: str | Path, n_points: int | None = None) -> dict[str, np.ndarray]:
    """The detected points of one camera, by instant.

    Parameters
    ----------
    path : str or Path
        An OpenCV FileStorage JSON of ``frame_<i>`` matrices (module docstring).
    n_points : int or None
        The board's point count; every frame must hold it when given.

    Returns
    -------
    dict of str to ndarray
        ``{"frame_<i>": (N, 2) float64 px}`` in the file's order.

    Raises
    ------
    InputError
        Naming the file and the frame: not a mapping of matrices, a matrix of an odd number of values or not
        ``rows * cols`` of them, a non-finite value, or a frame of another point count than ``n_points``.

    Examples
    --------
    >>> pts = read_multiview_points("cam_0.json", n_points=88)  # doctest: +SKIP
    >>> pts["frame_1"].shape  # doctest: +SKIP
    (88, 2)
    """
    data = read_json(path, "multiview points file", max_bytes=MAX_FILE_BYTES)
    if not isinstance(data, dict) or not data:
        raise InputError(f"multiview points file {path}: expected a mapping of frame_<i> matrices")
    out: dict[str, np.ndarray] = {}
    for name, node in data.items():
        where = f"multiview points file {path}, {name}"
        if not isinstance(node, dict) or not isinstance(node.get("data"), list):
            raise InputError(f"{where}: expected an opencv-matrix with a 'data' list")
        rows, cols = node.get("rows"), node.get("cols")
        values = node["data"]
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
            raise InputError(f"{where}: 'data' must hold numbers only")
        if isinstance(rows, int) and isinstance(cols, int) and rows * cols * 1 not in (len(values), len(values) // 2):
            raise InputError(f"{where}: rows x cols = {rows} x {cols} but {len(values)} values")
        if len(values) % 2 or not values:
            raise InputError(f"{where}: expected u, v pairs, got {len(values)} values")
        uv = np.asarray(values, dtype=np.float64).reshape(-1, 2)
        if not np.isfinite(uv).all():
            raise InputError(f"{where}: non-finite pixel coordinates")
        if n_points is not None and len(uv) != n_points:
            raise InputError(f"{where}: {len(uv)} points, the board has {n_points}")
        out[str(name)] = uv
    return out
