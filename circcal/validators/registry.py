"""Which reference calibrators exist: the built-ins plus plug-ins from the entry-point group ``circcal.validators``.

A third party registers its calibrator in its own ``pyproject.toml``::

    [project.entry-points."circcal.validators"]
    mycal = "mypackage.mymodule:MyCalibrator"

The target is a class (or any callable) returning an object that follows
:class:`circcal.validators.base.ReferenceCalibrator`; keyword arguments given to :func:`get` are passed to it. A
built-in name wins over a plug-in of the same name (the clash is reported by :func:`problems`).
"""

from __future__ import annotations

import importlib
import importlib.metadata
from collections.abc import Callable
from typing import Any

from circcal.validators.base import ReferenceCalibrator, lens_support, missing_members

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
    """Built-in names first (fixed order), then plug-ins sorted."""
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
    """An instance of reference ``name`` (``kwargs`` go to its constructor). ``KeyError`` for an unknown name;
    a plug-in that cannot be imported raises ``ImportError`` naming it."""
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
            f"reference calibrator {name!r} lacks {missing[0]!r}; see circcal.validators.base.ReferenceCalibrator"
        )
    return obj


def get_for_lens(name: str, lens: str, **kwargs: Any) -> ReferenceCalibrator:
    """Reference ``name`` set up for lens model ``lens``: constructed with ``lens=`` when it is a built-in (every one
    takes it, and answers "unsupported" with its reason for a model it does not fit) or a plug-in that declares the
    model in its ``lenses``; else as it comes (a plug-in without that model: the caller reports
    :func:`~circcal.validators.base.lens_support`'s reason instead of calling it)."""
    plain = get(name, **kwargs)
    if lens == getattr(plain, "lens", "opencv5"):
        return plain
    if name in BUILTINS or lens_support(plain, lens)[0]:
        return get(name, lens=lens, **kwargs)
    return plain


def all_available() -> dict[str, tuple[bool, str]]:
    """``{name: (available, reason)}`` for every known reference; never raises."""
    out: dict[str, tuple[bool, str]] = {}
    for n in names():
        try:
            out[n] = get(n).available()
        except Exception as exc:  # noqa: BLE001
            out[n] = (False, f"{type(exc).__name__}: {exc}")
    return out


def problems() -> dict[str, str]:
    """Plug-ins ignored while listing (name -> why)."""
    _plugins()
    return dict(_problems)
