"""Which reference calibrators exist: the built-ins plus plug-ins from the entry-point group ``circcal.validators``.

A third party registers its calibrator in its own ``pyproject.toml``::

    [project.entry-points."circcal.validators"]
    mycal = "mypackage.mymodule:MyCalibrator"

The target is a class (or any callable) returning an object that follows
:class:`circcal.validators.reference_protocol.ReferenceCalibrator`; keyword arguments given to :func:`get` are passed to it. A
built-in name wins over a plug-in of the same name (the clash is reported by :func:`problems`).
"""

from __future__ import annotations

import importlib
import importlib.metadata
from collections.abc import Callable
from typing import Any

from circcal.validators.lens_support import lens_support
from circcal.validators.reference_protocol import ReferenceCalibrator, missing_members

__all__ = ["ENTRY_POINT_GROUP", "BUILTINS", "names", "get", "get_for_lens", "all_available", "problems"]

ENTRY_POINT_GROUP = "circcal.validators"

#: name -> "module:attribute"; imported lazily so a missing optional dependency only affects its own reference.
BUILTINS: dict[str, str] = {
    "opencv": "circcal.validators.opencv:OpenCVCalibrator",
    "mrcal": "circcal.validators.mrcal:MrcalCalibrator",
    "kornia": "circcal.validators.kornia:KorniaCalibrator",
    "pycolmap": "circcal.validators.pycolmap:PycolmapCalibrator",
    "lensboy": "circcal.validators.lensboy:LensboyCalibrator",
}

_problems: dict[str, str] = {}


def _plugins() -> dict[str, Any]:
    try:
        eps = importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)
    except TypeError:  # Python < 3.10 API
        eps = importlib.metadata.entry_points().get(ENTRY_POINT_GROUP, [])  # type: ignore[attr-defined]
    found: dict[str, Any] = {}
    for ep in eps:
        if ep.name in BUILTINS:
            _problems[ep.name] = f"plug-in {ep.value!r} ignored: {ep.name!r} is a built-in reference"
            continue
        found[ep.name] = ep
    return found


def names() -> list[str]:
    """Every known reference name.

    Returns
    -------
    list of str
        Built-in names first (fixed order), then plug-ins sorted.
    """
    return list(BUILTINS) + sorted(_plugins())


def _load(name: str) -> Callable[..., ReferenceCalibrator]:
    if name in BUILTINS:
        module, attr = BUILTINS[name].split(":")
        return getattr(importlib.import_module(module), attr)
    plugins = _plugins()
    if name in plugins:
        return plugins[name].load()
    raise KeyError(f"unknown reference calibrator {name!r}; known: {', '.join(names())}")


def get(name: str, **kwargs: Any) -> ReferenceCalibrator:
    """An instance of a reference calibrator.

    Parameters
    ----------
    name : str
        A name from :func:`names`.
    **kwargs
        Passed to its constructor (e.g. ``lens="rational"``).

    Returns
    -------
    ReferenceCalibrator

    Raises
    ------
    KeyError
        An unknown name.
    ImportError
        A reference (plug-in) that cannot be imported; the message names it.
    TypeError
        The object lacks a member of :data:`~circcal.validators.reference_protocol.REQUIRED_MEMBERS`.

    Examples
    --------
    >>> from circcal.validators import registry
    >>> registry.get("opencv").name  # doctest: +SKIP
    'opencv'
    """
    try:
        factory = _load(name)
    except KeyError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise ImportError(f"reference calibrator {name!r} could not be loaded: {type(exc).__name__}: {exc}") from exc
    obj = factory(**kwargs)
    missing = missing_members(obj)
    if missing:
        raise TypeError(
            f"reference calibrator {name!r} lacks {missing[0]!r}; see circcal.validators.reference_protocol.ReferenceCalibrator"
        )
    return obj


def get_for_lens(name: str, lens: str, **kwargs: Any) -> ReferenceCalibrator:
    """A reference set up for a lens model.

    Constructed with ``lens=`` when it is a built-in (every one takes it, and answers "unsupported" with its reason
    for a model it does not fit) or a plug-in that declares the model in its ``lenses``; else as it comes (a plug-in
    without that model: the caller reports :func:`~circcal.validators.lens_support.lens_support`'s reason instead of calling
    it).

    Parameters
    ----------
    name : str
        A name from :func:`names`.
    lens : str
        A :data:`circcal.model.LENS_MODELS` name.
    **kwargs
        Passed to its constructor.

    Returns
    -------
    ReferenceCalibrator

    Raises
    ------
    KeyError, ImportError, TypeError
        As :func:`get`.
    """
    plain = get(name, **kwargs)
    if lens == getattr(plain, "lens", "opencv5"):
        return plain
    if name in BUILTINS or lens_support(plain, lens)[0]:
        return get(name, lens=lens, **kwargs)
    return plain


def all_available() -> dict[str, tuple[bool, str]]:
    """Which references can run here; never raises.

    Returns
    -------
    dict of str to tuple of (bool, str)
        ``{name: (available, reason)}`` for every known reference; a reference that cannot be loaded is unavailable
        with the exception as its reason.
    """
    out: dict[str, tuple[bool, str]] = {}
    for n in names():
        try:
            out[n] = get(n).available()
        except Exception as exc:  # noqa: BLE001
            out[n] = (False, f"{type(exc).__name__}: {exc}")
    return out


def problems() -> dict[str, str]:
    """Plug-ins ignored while listing.

    Returns
    -------
    dict of str to str
        Name -> why (a plug-in whose name is a built-in's).
    """
    _plugins()
    return dict(_problems)
