"""circcal's model.json: one schema, written here and nowhere else.

::

    {"format": "circcal-model", "version": 1,
     "camera": {"width", "height", "fx", "fy", "cx", "cy", "dist": [...], "lens"},   # = truth.json's block
         # dist in circcal.model.LENS_MODELS[lens].dist_names order; "lens" absent = "opencv5" ([k1, k2, p1, p2, k3])
     ... sections (MODEL_SECTIONS, each optional): "std", "fixed", "parameter_order", "correlation", "errors",
         "sigma_px", "n_params", "n_iterations", "converged", "views", "board_refinement", "board",
         "failed_images", "recorrection_rounds"}

Errors keys name their convention (``rms_per_point_px`` = OpenCV's RMS, ``rms_per_coord_px`` = mrcal's,
``mean_2d_px`` = the paper's). Non-finite numbers are written as ``null`` (JSON has no NaN).
"""
from __future__ import annotations

from typing import Any

from circcal.errors import ModelFileError
from circcal.model import Camera

__all__ = ["MODEL_FORMAT", "MODEL_VERSION", "MODEL_SECTIONS", "model_json", "camera_from_json"]

MODEL_FORMAT = "circcal-model"
MODEL_VERSION = 1
#: The sections a model.json may hold beside the camera block, in the order they are written.
MODEL_SECTIONS: tuple[str, ...] = ("std", "fixed", "parameter_order", "correlation", "errors", "sigma_px",
                                   "n_params", "n_iterations", "converged", "views", "board_refinement", "board",
                                   "failed_images", "recorrection_rounds")


def model_json(camera: Camera, **sections: Any) -> dict[str, Any]:
    """A model.json document: the header, ``camera``'s block and the given ``sections`` (names from
    :data:`MODEL_SECTIONS`, in that order; a name outside it is a bug and raises ``TypeError``)."""
    unknown = set(sections) - set(MODEL_SECTIONS)
    if unknown:
        raise TypeError(f"model.json has no section(s) {sorted(unknown)}; known: {', '.join(MODEL_SECTIONS)}")
    return {"format": MODEL_FORMAT, "version": MODEL_VERSION, "camera": camera.to_dict(),
            **{k: sections[k] for k in MODEL_SECTIONS if k in sections}}


def camera_from_json(data: Any) -> Camera:
    """Camera from model.json / truth.json (their ``camera`` block) or a bare camera block; every value checked
    (:class:`~circcal.errors.ModelFileError` naming the field)."""
    if not isinstance(data, dict):
        raise ModelFileError(f"expected a JSON object with a 'camera' block (or a bare camera block), got "
                             f"{type(data).__name__}")
    block = data["camera"] if "camera" in data else data
    try:
        return Camera.from_dict(block)
    except ModelFileError:
        raise
    except ValueError as exc:  # InputError from the camera's own checks
        raise ModelFileError(str(exc)) from None
