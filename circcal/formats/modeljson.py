"""circcal's model.json: one schema, written here and nowhere else.

::

    {"format": "circcal-model", "version": 1,
     "camera": {"width", "height", "fx", "fy", "cx", "cy", "dist": [...], "lens"},   # = truth.json's block
         # dist in circcal.model.LENS_MODELS[lens].dist_names order; "lens" absent = "opencv5" ([k1, k2, p1, p2, k3])
     ... sections (MODEL_SECTIONS, each optional): "std", "fixed", "parameter_order", "correlation", "errors",
         "sigma_px", "n_params", "n_iterations", "converged", "views", "board_refinement", "board",
         "failed_images", "recorrection_rounds", "board_warp"}

Errors keys name their convention (``rms_per_point_px`` = OpenCV's RMS, ``rms_per_coord_px`` = mrcal's,
``mean_2d_px`` = the paper's). Non-finite numbers are written as ``null`` (JSON has no NaN).

Reading (:func:`camera_from_json`) is strict, as this is circcal's own format: a field its writers never write is
refused by name (a foreign format's extras, by contrast, are ignored by that format's reader).
"""

from __future__ import annotations

from typing import Any

from circcal.errors import ModelFileError
from circcal.formats.limits import integer, number, number_list, show
from circcal.model import DEFAULT_LENS, LENS_MODELS, Camera

__all__ = [
    "MODEL_FORMAT",
    "MODEL_VERSION",
    "MODEL_SECTIONS",
    "TRUTH_SECTIONS",
    "CAMERA_FIELDS",
    "FIXED_NAMES",
    "model_json",
    "camera_from_json",
]

MODEL_FORMAT = "circcal-model"
MODEL_VERSION = 1
#: The sections a model.json may hold beside the camera block, in the order they are written.
MODEL_SECTIONS: tuple[str, ...] = (
    "std",
    "fixed",
    "parameter_order",
    "correlation",
    "errors",
    "sigma_px",
    "n_params",
    "n_iterations",
    "converged",
    "views",
    "board_refinement",
    "board",
    "failed_images",
    "recorrection_rounds",
    "board_warp",
)


def model_json(camera: Camera, **sections: Any) -> dict[str, Any]:
    """A model.json document: the header, ``camera``'s block and the given ``sections``.

    Parameters
    ----------
    camera : Camera
    **sections
        Names from :data:`MODEL_SECTIONS`, written in that order.

    Returns
    -------
    dict
        ``format``, ``version``, ``camera`` and the sections.

    Raises
    ------
    TypeError
        A section name outside :data:`MODEL_SECTIONS` (a bug, not an input error).
    """
    unknown = set(sections) - set(MODEL_SECTIONS)
    if unknown:
        raise TypeError(f"model.json has no section(s) {sorted(unknown)}; known: {', '.join(MODEL_SECTIONS)}")
    return {
        "format": MODEL_FORMAT,
        "version": MODEL_VERSION,
        "camera": camera.to_dict(),
        **{k: sections[k] for k in MODEL_SECTIONS if k in sections},
    }


#: truth.json's sections beside model.json's (read_model reads a fixture's truth.json too).
TRUTH_SECTIONS: tuple[str, ...] = ("scenario", "renderer")
#: The fields of a camera block (Camera.to_dict; ``lens`` absent = opencv5).
CAMERA_FIELDS: tuple[str, ...] = ("width", "height", "fx", "fy", "cx", "cy", "dist", "lens")
#: What "fixed" may name: the solver's held parameters (circcal.solver.calibrate: "aspect_ratio", "cx", "cy", "k2",
#: "p1", "p2", "k3") and, for files from elsewhere, any lens model's parameter names.
FIXED_NAMES: frozenset[str] = frozenset({"aspect_ratio"}.union(*(m.param_names for m in LENS_MODELS.values())))


def camera_from_json(data: Any) -> Camera:
    """Camera from model.json / truth.json (their ``camera`` block) or a bare camera block; every value checked.

    circcal's own files hold only what its writers write: an unknown top-level section or camera field is refused by
    name (:data:`MODEL_SECTIONS`, :data:`TRUTH_SECTIONS`, :data:`CAMERA_FIELDS`), as is a ``format`` other than
    :data:`MODEL_FORMAT`, a ``version`` above :data:`MODEL_VERSION`, a ``fixed`` that is not a list of parameter
    names, ``views`` that are not a list of objects.

    Parameters
    ----------
    data : object
        The parsed JSON.

    Returns
    -------
    Camera

    Raises
    ------
    ModelFileError
        Naming the field.
    """
    if not isinstance(data, dict):
        raise ModelFileError(
            f"expected a JSON object with a 'camera' block (or a bare camera block), got {type(data).__name__}"
        )
    known = ("format", "version", "camera", *MODEL_SECTIONS, *TRUTH_SECTIONS)
    if "camera" in data:
        _check_sections(data, known)
        block, where = data["camera"], "camera block"
    elif set(data) & (set(known) - set(CAMERA_FIELDS)):
        raise ModelFileError("no 'camera' block (a model.json holds its camera under \"camera\")")
    else:
        block, where = data, "camera block"
    if not isinstance(block, dict):
        raise ModelFileError(f"the {where} must be a JSON object, got {show(block)}")
    unknown = [k for k in block if k not in CAMERA_FIELDS]
    if unknown:
        raise ModelFileError(
            f"{where}: unknown field {show(unknown[0])} (a camera block holds {', '.join(CAMERA_FIELDS)})"
        )
    missing = [k for k in CAMERA_FIELDS[:7] if k not in block]
    if missing:
        raise ModelFileError(f"{where} lacks {', '.join(missing)}")
    lens = block.get("lens", DEFAULT_LENS)
    if not isinstance(lens, str) or lens not in LENS_MODELS:
        raise ModelFileError(f"camera lens must be one of {', '.join(LENS_MODELS)}, got {show(lens)}")
    integer(block["width"], "camera width")
    integer(block["height"], "camera height")
    for name in ("fx", "fy", "cx", "cy"):
        number(block[name], f"camera {name}")
    number_list(block["dist"], "camera dist", LENS_MODELS[lens].n_dist)
    try:
        return Camera.from_dict(block)
    except ModelFileError:
        raise
    except ValueError as exc:  # InputError from the camera's own checks
        raise ModelFileError(str(exc)) from None


def _check_sections(doc: dict[str, Any], known: tuple[str, ...]) -> None:
    """The document-level checks of :func:`camera_from_json`."""
    unknown = [k for k in doc if k not in known]
    if unknown:
        raise ModelFileError(
            f"unknown top-level field {show(unknown[0])} (a model.json holds format, version, camera "
            f"and {', '.join(MODEL_SECTIONS)})"
        )
    if "format" in doc and doc["format"] != MODEL_FORMAT:
        raise ModelFileError(f"format must be {MODEL_FORMAT!r}, got {show(doc['format'])}")
    if "version" in doc:
        integer(doc["version"], "version", 1, MODEL_VERSION)
    fixed = doc.get("fixed")
    if fixed is not None and (
        not isinstance(fixed, list) or not all(isinstance(n, str) and n in FIXED_NAMES for n in fixed)
    ):
        raise ModelFileError(
            f"fixed must be a list of parameter names ({', '.join(sorted(FIXED_NAMES))}), got {show(fixed)}"
        )
    views = doc.get("views")
    if views is not None and (not isinstance(views, list) or not all(isinstance(v, dict) for v in views)):
        raise ModelFileError(f"views must be a list of objects, got {show(views)}")
    for name in ("board_refinement", "board", "std", "errors", "scenario", "renderer"):
        if name in doc and not isinstance(doc[name], dict):
            raise ModelFileError(f"{name} must be an object, got {show(doc[name])}")
