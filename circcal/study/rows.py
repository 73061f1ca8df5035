"""One row per run: the columns of a study's Parquet table, and how a calibration becomes a row.

Conventions: parameters in :data:`circcal.model.PARAM_NAMES` order and units (fx, fy, cx, cy px; k1, k2, p1, p2, k3
unitless); ``err_<p>`` = estimate - truth; ``std_<p>`` = the calibrator's stated standard deviation (NaN where it
states none; 0 for a parameter it held fixed). ``truth_rms_px`` / ``truth_max_px``: projection difference to the
true camera over the whole imager with the implied rotation fitted
(:func:`circcal.analysis.compare.projection_diff`, the conformance suite's truth check). Reprojection errors in
the three conventions (:mod:`circcal.metrics`): ``rms_per_point_px`` (OpenCV), ``rms_per_coord_px`` (mrcal),
``mean_2d_px`` (the paper). ``time_s``: the run's own calibration time (a batched solve: the batch's time / its
size); ``fixture_s``: the time to render the fixture the run used (shared by the runs of one render; a
``vary: noise`` seed's render starts from the views' noise-free render kept by the worker,
:func:`circcal.study.seeded.geometry`, so it is the noise and the files; 0 for observations runs). Missing numbers
are NaN, missing counts -1, so every column keeps one type.
"""

from __future__ import annotations

import json
import platform
from functools import lru_cache
from typing import Any

import numpy as np

from circcal.model import PARAM_NAMES, Camera

__all__ = ["COLUMNS", "ROW_VERSION", "TIME_COLUMNS", "make_row", "schema", "versions"]

#: Bumped when a column's meaning changes: it is part of every run key, so old rows are not mixed with new ones.
ROW_VERSION = 1

_NAN = float("nan")

#: (name, type) of every column; types: "str", "int", "float".
COLUMNS: tuple[tuple[str, str], ...] = (
    ("key", "str"),
    ("study", "str"),
    ("cell", "int"),
    ("kind", "str"),
    ("scenario", "str"),
    ("variant", "str"),
    ("vary", "str"),
    ("noise_px", "float"),
    ("seed", "int"),
    ("calibrator", "str"),
    ("calibrator_name", "str"),
    ("mode", "str"),
    ("observations", "str"),
    ("lens_model", "str"),
    ("status", "str"),
    ("message", "str"),
    ("n_views", "int"),
    ("n_points", "int"),
    ("images_total", "int"),
    ("images_used", "int"),
    *((f"true_{p}", "float") for p in PARAM_NAMES),
    *((f"est_{p}", "float") for p in PARAM_NAMES),
    *((f"err_{p}", "float") for p in PARAM_NAMES),
    *((f"std_{p}", "float") for p in PARAM_NAMES),
    ("truth_rms_px", "float"),
    ("truth_max_px", "float"),
    ("rms_per_point_px", "float"),
    ("rms_per_coord_px", "float"),
    ("mean_2d_px", "float"),
    ("time_s", "float"),
    ("fixture_s", "float"),
    ("device", "str"),
    ("batch_size", "int"),
    ("circcal_version", "str"),
    ("calibrator_version", "str"),
    ("versions", "str"),
)
#: Columns that measure time: they differ between two executions of the same run, every other column does not.
TIME_COLUMNS = ("time_s", "fixture_s")


def schema():
    """The pyarrow schema of a study table.

    Returns
    -------
    pyarrow.Schema
    """
    import pyarrow as pa

    types = {"str": pa.string(), "int": pa.int64(), "float": pa.float64()}
    return pa.schema([(n, types[t]) for n, t in COLUMNS])


@lru_cache(maxsize=1)
def versions() -> str:
    """The versions that decide a run's numbers on this worker: circcal, Python, numpy, OpenCV.

    Returns
    -------
    str
        JSON.
    """
    import cv2

    import circcal

    return json.dumps(
        {
            "circcal": circcal.__version__,
            "python": platform.python_version(),
            "numpy": np.__version__,
            "opencv": cv2.__version__,
        },
        sort_keys=True,
    )


def make_row(
    run: Any,
    study: str,
    *,
    status: str,
    message: str = "",
    truth: Camera,
    camera: Camera | None = None,
    std: dict[str, float] | None = None,
    errors: dict[str, float] | None = None,
    n_views: int = -1,
    n_points: int = -1,
    images_total: int = -1,
    images_used: int = -1,
    time_s: float = _NAN,
    fixture_s: float = 0.0,
    device: str = "",
    batch_size: int = 1,
    calibrator_version: str = "",
) -> dict[str, Any]:
    """The row of a run: its axes, then what the calibration gave.

    NaN where it gave nothing: a failed or unsupported run keeps its status and message.

    Parameters
    ----------
    run : circcal.study.plan.Run
    study : str
        The study's name.
    status, message : str
        The calibrator's status and why.
    truth : circcal.model.Camera
    camera : circcal.model.Camera, optional
    std : dict of str to float, optional
        Stated standard deviations.
    errors : dict of str to float, optional
        Reprojection errors, px.
    n_views, n_points, images_total, images_used : int
        -1 when unknown.
    time_s : float
        The run's calibration time, s.
    fixture_s : float
        Render time of its fixture, s.
    device : str
    batch_size : int
    calibrator_version : str

    Returns
    -------
    dict
        Column -> value (:func:`schema`).
    """
    import circcal
    from circcal.analysis.compare import projection_diff

    row: dict[str, Any] = {
        "key": run.key,
        "study": study,
        "cell": run.cell,
        "kind": run.kind,
        "scenario": run.scenario,
        "variant": run.variant,
        "vary": run.vary,
        "noise_px": run.noise_px,
        "seed": run.seed,
        "calibrator": run.calibrator.label,
        "calibrator_name": run.calibrator.name,
        "mode": run.calibrator.mode,
        "observations": run.calibrator.observations,
        "lens_model": run.lens_model,
        "status": status,
        "message": message,
        "n_views": n_views,
        "n_points": n_points,
        "images_total": images_total,
        "images_used": images_used,
        "time_s": float(time_s),
        "fixture_s": float(fixture_s),
        "device": device,
        "batch_size": batch_size,
        "circcal_version": circcal.__version__,
        "calibrator_version": calibrator_version,
        "versions": versions(),
    }
    true_p = truth.intrinsics
    est = camera.intrinsics if camera is not None else np.full(len(PARAM_NAMES), np.nan)
    for i, p in enumerate(PARAM_NAMES):
        row[f"true_{p}"] = float(true_p[i])
        row[f"est_{p}"] = float(est[i])
        row[f"err_{p}"] = float(est[i] - true_p[i])
        s = (std or {}).get(p)
        row[f"std_{p}"] = float(s) if s is not None else _NAN
    if camera is not None:
        d = projection_diff(truth, camera, fit=True)
        row["truth_rms_px"], row["truth_max_px"] = float(d["rms_px"]), float(d["max_px"])
    else:
        row["truth_rms_px"] = row["truth_max_px"] = _NAN
    for k in ("rms_per_point_px", "rms_per_coord_px", "mean_2d_px"):
        row[k] = float((errors or {}).get(k, _NAN))
    return row
