"""A camera model read from any file circcal reads (:func:`circcal.formats.read_model`), with its projection
uncertainty where the file carries what it takes:

* a circcal model.json with the observations of its views (what ``circcal calibrate`` writes): the solve is made
  again from them, with the parameters the file says were held, from the file's camera (it lands on the same
  optimum: the file's camera to 1e-6 px, checked), and circcal's uncertainty is that solve's
  (:mod:`circcal.solver.uncertainty`);
* an mrcal ``.cameramodel`` with optimisation inputs: mrcal's own ``projection_uncertainty`` through the worker
  (:func:`circcal.formats.cameramodel_export.mrcal_uncertainty`), when mrcal is installed;
* anything else: no uncertainty (``LoadedModel.uncertainty`` is None, ``note`` says why).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from circcal.errors import ModelFileError
from circcal.formats import read_model
from circcal.formats.limits import MAX_MODEL_FILE_BYTES
from circcal.formats.mrcal import cameramodel_has_optimization_inputs, check_optimization_inputs
from circcal.jsonio import read_text
from circcal.model import Camera

if TYPE_CHECKING:  # annotations only: the solver is imported where a document is re-solved
    from circcal.solver import CalibrationResult

__all__ = ["LoadedModel", "load_model", "resolve_document", "RESOLVE_TOL_PX"]

#: The re-solve from a model.json's observations must reproduce its camera to this (px, projection difference over
#: the image): the file's numbers are the optimum's to ~1e-9 relative.
RESOLVE_TOL_PX = 1e-6


@dataclass
class LoadedModel:
    """A camera file with its projection uncertainty.

    Attributes
    ----------
    path : Path
    camera : Camera
    uncertainty : callable or None
        ``uncertainty(uv, distance)``: pixels (N, 2) -> worst-direction projection standard deviation (N,) px at
        ``distance`` mm (None: infinity); None when none is known.
    note : str
        Where the uncertainty comes from, or why there is none.
    """

    path: Path
    camera: Camera
    uncertainty: Callable[[np.ndarray, float | None], np.ndarray] | None
    note: str


def resolve_document(camera: Camera, document: dict[str, Any]) -> CalibrationResult | None:
    """The :class:`~circcal.solver.CalibrationResult` of a model.json's own observations (see the module).

    Parameters
    ----------
    camera : Camera
        The file's camera.
    document : dict
        The model.json document.

    Returns
    -------
    CalibrationResult or None
        None when it holds none, the solve refuses them, or the solve does not land on its camera.

    Raises
    ------
    InputError
        A malformed ``views`` entry (:func:`~circcal.formats.cameramodel_export.document_views`).
    """
    from circcal.analysis.compare import projection_diff
    from circcal.errors import InputError
    from circcal.formats.cameramodel_export import document_views
    from circcal.solver import CalibrationOptions, calibrate

    views = document_views(document)
    if views is None:
        return None
    try:  # the file's holds by name (any the lens model has), refused like any option when it has not
        options = CalibrationOptions(
            lens=camera.lens, fixed=tuple(views["fixed"]), refine_board=bool(views["refined_board"])
        )
        res = calibrate(
            views["object_points"], views["image_points"], (camera.width, camera.height), options, initial=camera
        )
    except InputError:
        return None
    if projection_diff(camera, res.camera)["max_px"] > RESOLVE_TOL_PX or res.covariance is None:
        return None
    return res


def load_model(path: str | Path) -> LoadedModel:
    """Read a camera file (any format) and find its uncertainty (see the module).

    An mrcal file's optimisation inputs are checked before mrcal gets them
    (:func:`circcal.formats.mrcal.check_optimization_inputs`), and mrcal's refusal of them later, when the
    uncertainty is asked for, is a :class:`~circcal.errors.ModelFileError` naming the file too.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    LoadedModel

    Raises
    ------
    ModelFileError
        Naming the file, when it cannot be read.
    InputError
        A model.json whose ``views`` entries are malformed (:func:`resolve_document`).

    Examples
    --------
    >>> m = load_model("out/model.json")  # doctest: +SKIP
    >>> m.uncertainty(uv, None)  # doctest: +SKIP
    """
    from circcal.solver.uncertainty import result_projection_stdev

    p = Path(path)
    camera, document = read_model(p)
    if document is not None:
        res = resolve_document(camera, document)
        if res is not None:
            return LoadedModel(
                p,
                camera,
                lambda uv, d: result_projection_stdev(res, uv, distance=d),
                f"circcal's, from the {len(res.rvecs)} views' observations in the file",
            )
        return LoadedModel(p, camera, None, "the model.json holds no observations of its views")
    text = read_text(p, "camera file", max_bytes=MAX_MODEL_FILE_BYTES)
    if cameramodel_has_optimization_inputs(text):
        from circcal.formats.cameramodel_export import ExportError, mrcal_uncertainty
        from circcal.formats.mrcal_process import mrcal_python

        try:
            check_optimization_inputs(text)
        except ModelFileError as exc:
            raise ModelFileError(f"camera file {p} (mrcal): {exc}") from None
        py, why, info = mrcal_python()
        if py is None:
            return LoadedModel(p, camera, None, f"it has mrcal optimisation inputs, but {why}")

        def uncertainty(uv: np.ndarray, d: float | None) -> np.ndarray:
            try:
                return mrcal_uncertainty(text, uv, distance=d, python=py)
            except ExportError as exc:  # mrcal refused the file's optimisation inputs (checked only in outline)
                raise ModelFileError(
                    f"camera file {p} (mrcal): mrcal cannot compute the projection uncertainty "
                    f"from its optimization_inputs: {' '.join(str(exc).split())[-300:]}"
                ) from None

        return LoadedModel(
            p, camera, uncertainty, f"mrcal {info.get('version', '')}'s, from the file's optimisation inputs"
        )
    return LoadedModel(p, camera, None, "the file holds no optimisation inputs or observations")
