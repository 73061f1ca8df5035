"""circcal's calibrations as mrcal ``.cameramodel`` files that carry mrcal's optimisation inputs, so that
``mrcal-show-projection-uncertainty``, ``mrcal-show-residuals`` and ``mrcal-show-projection-diff`` work on them; and
mrcal's own projection uncertainty of such a file.

The inputs are built by the out-of-process worker (:mod:`circcal.formats.mrcal_worker`, command ``export``; run by
:mod:`circcal.formats.mrcal_process`) from circcal's observations (per view, the board points on mrcal's lattice:
:func:`~circcal.formats.mrcal_process.board_lattice`, an asymmetric grid with every other lattice point missing) and
circcal's solution: intrinsics, and each view's pose as mrcal's frame (``frames_rt_toref``; mrcal's board frame
starts at the lattice origin). The switches are circcal's estimator: no board warp, no regularisation, no outlier
rejection (points circcal rejected are left out). The state is circcal's optimum, not re-solved by mrcal: the worker
reports mrcal's own residual RMS and cost gradient there as the check. ``LENSMODEL_OPENCV5`` (``OPENCV4`` when k3
is held at 0), ``OPENCV8`` / ``OPENCV12`` for the rational and thin-prism lenses
(:data:`circcal.formats.mrcal_process.LENSMODELS`); a fisheye has no mrcal model (:class:`ExportError`).

What mrcal's inputs cannot hold, and what happens then (:class:`ExportError`, the caller writes the plain model and
says why): a refined board (mrcal models a board warp of 2 parameters, not every point), points off a square
lattice. Parameters circcal held other than k3 = 0 (p1 p2, aspect ratio, principal point) are free in mrcal's
inputs: the file says so in its note, and mrcal's uncertainty then treats them as estimated.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal.errors import InputError
from circcal.formats.mrcal_process import (
    LENSMODELS,
    UNSUPPORTED_LENSES,
    UnsupportedLayout,
    board_lattice,
    mrcal_python,
    run_worker,
)
from circcal.model import Camera
from circcal.rotation import rodrigues

__all__ = [
    "ExportError",
    "ExportedModel",
    "export_cameramodel",
    "mrcal_uncertainty",
    "result_views",
    "document_views",
    "cameramodel_text",
    "WORKER_TIMEOUT_S",
]

#: Limit for one worker run (s): building and serialising the inputs takes well under a second; the first import of
#: mrcal a few.
WORKER_TIMEOUT_S = 120.0


class ExportError(RuntimeError):
    """The optimisation inputs cannot be written (no mrcal, a layout or model mrcal's inputs cannot hold); the message says
    why.

    Not an :class:`~circcal.errors.InputError`: the caller writes the plain model instead (:func:`cameramodel_text`).
    """


@dataclass
class ExportedModel:
    """A ``.cameramodel`` with optimisation inputs.

    Attributes
    ----------
    text : str
        The file.
    info : dict
        mrcal's version and API, its residual RMS per coordinate (px) and max cost gradient at circcal's state, the
        notes written into the file.
    """

    text: str
    info: dict[str, Any] = field(default_factory=dict)


def _run_worker(req: dict[str, Any], python: str | None) -> dict[str, Any]:
    """One worker run (:func:`circcal.formats.mrcal_process.run_worker`); :class:`ExportError` with mrcal's words when
    there is no mrcal or it fails."""
    if python is None:
        python, why, _ = mrcal_python()
        if python is None:
            raise ExportError(why)
    try:
        return run_worker(python, req, WORKER_TIMEOUT_S)
    except RuntimeError as exc:
        raise ExportError(str(exc)) from None


def export_cameramodel(
    camera: Camera,
    rvecs: np.ndarray,
    tvecs: np.ndarray,
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    *,
    fixed: Sequence[str] = (),
    refined_board: bool = False,
    note: str | None = None,
    uncertainty: dict[str, Any] | None = None,
    python: str | None = None,
) -> ExportedModel:
    """The ``.cameramodel`` of ``camera`` with mrcal's optimisation inputs for the observations it was fitted to.

    Parameters
    ----------
    camera : Camera
    rvecs, tvecs : ndarray, shape (V, 3)
        Board -> camera (rad / mm) of the solve.
    object_points : sequence of ndarray, each shape (N_v, 3)
        Per view, mm on the nominal board.
    image_points : sequence of ndarray, each shape (N_v, 2)
        Per view, px (OpenCV's pixel convention, which is mrcal's).
    fixed : sequence of str
        The names circcal held (:attr:`CalibrationResult.fixed`).
    refined_board : bool
        The solve estimated the board's shape (refused: mrcal's inputs cannot hold it).
    note : str or None
        A note written into the file.
    uncertainty : dict or None
        Optionally ``{"uv" (N, 2), "distance" mm | None, "observed_pixel_uncertainty" px | None}``: mrcal's
        projection uncertainty of the written model there comes back in ``info["uncertainty_stdev"]``.
    python : str or None
        The interpreter that runs the mrcal worker (None: :func:`~circcal.formats.mrcal_process.mrcal_python`).

    Returns
    -------
    ExportedModel

    Raises
    ------
    ExportError
        The inputs cannot be written (see the module).
    InputError
        Poses and views of different counts.
    """
    if refined_board:
        raise ExportError(
            "the board's shape was estimated (--refine-board): mrcal's optimisation inputs model a "
            "rigid board (with a 2-parameter warp), so they would not reproduce this calibration"
        )
    if camera.lens not in LENSMODELS:
        why = UNSUPPORTED_LENSES.get(camera.lens, "no mrcal lens model")
        raise ExportError(f"lens {camera.lens!r}: {why}")
    rvecs = np.asarray(rvecs, dtype=np.float64).reshape(-1, 3)
    tvecs = np.asarray(tvecs, dtype=np.float64).reshape(-1, 3)
    if not (len(rvecs) == len(tvecs) == len(object_points) == len(image_points)):
        raise InputError(
            f"{len(rvecs)} poses for {len(object_points)} views of object points and "
            f"{len(image_points)} of image points"
        )
    try:
        lat = board_lattice([np.asarray(o, dtype=np.float64) for o in object_points], staggered=True)
    except UnsupportedLayout as exc:
        raise ExportError(str(exc)) from None
    W, H, origin = lat["width_n"], lat["height_n"], lat["origin"]
    obs = np.zeros((len(rvecs), H, W, 3))
    obs[..., 2] = -1.0
    for v, (ij, q) in enumerate(zip(lat["ij"], image_points)):
        obs[v, ij[:, 0], ij[:, 1], :2] = np.asarray(q, dtype=np.float64)
        obs[v, ij[:, 0], ij[:, 1], 2] = 1.0
    # ours: X_cam = R (origin + X_mrcal) + t, so mrcal's frame translation is t + R origin
    frames = np.column_stack([rvecs, tvecs + np.einsum("vij,j->vi", rodrigues(rvecs), origin)])
    opencv4 = camera.lens == "opencv5" and "k3" in fixed and camera.dist[4] == 0.0
    freed = [n for n in fixed if not (n == "k3" and opencv4)]
    notes = [
        "generated by circcal: optimisation inputs at circcal's solution (no warp, no regularisation, "
        "no outlier rejection)"
    ]
    if freed:
        notes.append(
            f"circcal held {', '.join(freed)}; mrcal's inputs cannot hold them, so mrcal treats them as "
            f"estimated (its uncertainty is then larger than circcal's)"
        )
    if note:
        notes.append(note)
    req = {
        "command": "export",
        "width_n": W,
        "height_n": H,
        "spacing": float(lat["spacing"]),
        "observations": obs.tolist(),
        "imagersize": [int(camera.width), int(camera.height)],
        "intrinsics": camera.intrinsics.tolist(),
        "frames_rt_toref": frames.tolist(),
        "opencv4": bool(opencv4),
        "lensmodel": LENSMODELS[camera.lens],
        "note": "; ".join(notes),
        "uncertainty": None,
    }
    if uncertainty is not None:
        req["uncertainty"] = {
            "uv": np.asarray(uncertainty["uv"], dtype=np.float64).tolist(),
            "distance": uncertainty.get("distance"),
            "observed_pixel_uncertainty": uncertainty.get("observed_pixel_uncertainty"),
        }
    reply = _run_worker(req, python)
    info: dict[str, Any] = {
        k: reply[k] for k in ("version", "api", "rms_per_coord_px", "max_abs_gradient") if k in reply
    }
    info["lensmodel"] = "LENSMODEL_OPENCV4" if opencv4 else LENSMODELS[camera.lens]
    info["notes"] = notes
    info["lattice"] = {"width_n": W, "height_n": H, "spacing_mm": float(lat["spacing"]), "origin_mm": origin.tolist()}
    if "uncertainty_stdev" in reply:
        info["uncertainty_stdev"] = reply["uncertainty_stdev"]
    return ExportedModel(reply["cameramodel"], info)


def mrcal_uncertainty(
    cameramodel_text: str,
    uv: np.ndarray,
    *,
    distance: float | None = None,
    observed_pixel_uncertainty: float | None = None,
    python: str | None = None,
) -> np.ndarray:
    """mrcal's projection uncertainty (worst-direction standard deviation) of a ``.cameramodel`` with optimisation
    inputs.

    Parameters
    ----------
    cameramodel_text : str
        The ``.cameramodel`` text.
    uv : ndarray, shape (N, 2)
        Pixels, px.
    distance : float or None
        mm along each ray (None: infinity).
    observed_pixel_uncertainty : float or None
        px; None: mrcal's own.
    python : str or None
        The interpreter that runs the mrcal worker.

    Returns
    -------
    ndarray, shape (N,)
        px.

    Raises
    ------
    ExportError
        Without mrcal or without optimisation inputs.
    """
    reply = _run_worker(
        {
            "command": "uncertainty",
            "cameramodel": cameramodel_text,
            "uv": np.asarray(uv, dtype=np.float64).reshape(-1, 2).tolist(),
            "distance": distance,
            "observed_pixel_uncertainty": observed_pixel_uncertainty,
        },
        python,
    )
    return np.asarray(reply["stdev"], dtype=np.float64)


def result_views(result: Any) -> dict[str, Any]:
    """What :func:`export_cameramodel` needs from a :class:`circcal.solver.CalibrationResult`.

    Parameters
    ----------
    result : CalibrationResult

    Returns
    -------
    dict
        ``rvecs``, ``tvecs``, ``object_points``, ``image_points`` (the observations it was fitted to), ``fixed`` (the
        names it held), ``refined_board`` (whether it refined the board).
    """
    return {
        "rvecs": result.rvecs,
        "tvecs": result.tvecs,
        "object_points": result.object_points,
        "image_points": result.image_points,
        "fixed": tuple(result.fixed),
        "refined_board": result.board_points is not None,
    }


def document_views(document: dict[str, Any] | None) -> dict[str, Any] | None:
    """:func:`result_views` read back from a model.json document (its ``views``: ``rvec``, ``tvec_mm``, ``object_mm``,
    ``image_px``).

    Parameters
    ----------
    document : dict or None
        A model.json document.

    Returns
    -------
    dict or None
        As :func:`result_views`; None when the document holds no observations (a model.json written before they
        were, or a bare camera).

    Raises
    ------
    InputError
        Naming the view, for a malformed entry.
    """
    doc = document or {}
    views = doc.get("views")
    if not views or not all(isinstance(v, dict) and "object_mm" in v and "image_px" in v for v in views):
        return None
    try:
        rv = np.array([v["rvec"] for v in views], dtype=np.float64).reshape(-1, 3)
        tv = np.array([v["tvec_mm"] for v in views], dtype=np.float64).reshape(-1, 3)
        obj = [np.asarray(v["object_mm"], dtype=np.float64).reshape(-1, 3) for v in views]
        img = [np.asarray(v["image_px"], dtype=np.float64).reshape(-1, 2) for v in views]
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(
            f"model.json views: {type(exc).__name__}: {exc} (each view holds rvec, tvec_mm, object_mm, image_px)"
        ) from None
    if any(len(o) != len(p) for o, p in zip(obj, img)):
        raise InputError("model.json views: object_mm and image_px differ in length")
    return {
        "rvecs": rv,
        "tvecs": tv,
        "object_points": obj,
        "image_points": img,
        "fixed": tuple(doc.get("fixed") or ()),
        "refined_board": "board_refinement" in doc,
    }


def cameramodel_text(
    camera: Camera, views: dict[str, Any] | None, *, note: str | None = None
) -> tuple[str, dict[str, Any]]:
    """The ``.cameramodel`` text to write for ``camera``: with mrcal's optimisation inputs when ``views`` are given and
    mrcal can build them, else the plain model (:func:`circcal.formats.camera_to_cameramodel`).

    Parameters
    ----------
    camera : Camera
    views : dict or None
        :func:`result_views` / :func:`document_views`.
    note : str or None
        A note written into the file.

    Returns
    -------
    text : str
    info : dict
        ``info["optimization_inputs"]`` says which, ``info["why"]`` why not (no observations, no mrcal, a refined
        board, ...).

    Raises
    ------
    InputError
        A lens model mrcal lacks (:func:`~circcal.formats.camera_to_cameramodel`), or views of different counts.
    """
    from circcal.formats import camera_to_cameramodel

    if views is None:
        return camera_to_cameramodel(camera), {
            "optimization_inputs": False,
            "why": "no observations to build mrcal's optimisation inputs from",
        }
    try:
        ex = export_cameramodel(
            camera,
            views["rvecs"],
            views["tvecs"],
            views["object_points"],
            views["image_points"],
            fixed=views["fixed"],
            refined_board=views["refined_board"],
            note=note,
        )
    except ExportError as exc:
        return camera_to_cameramodel(camera), {"optimization_inputs": False, "why": str(exc)}
    return ex.text, {"optimization_inputs": True, "why": None, **ex.info}
