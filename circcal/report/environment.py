"""The environment a report ran in: library versions and the machine (no clock: run times are kept apart)."""

from __future__ import annotations

import importlib
import os
import platform
from typing import Any

__all__ = ["LIBRARIES", "VERSION_ORDER", "environment"]

#: (import name, the name the report prints), in the order the report lists them after Python; mrcal and circcal
#: follow.
LIBRARIES = (
    ("numpy", "numpy"),
    ("scipy", "scipy"),
    ("cv2", "opencv"),
    ("torch", "torch"),
    ("kornia", "kornia"),
    ("pycolmap", "pycolmap"),
    ("matplotlib", "matplotlib"),
)
#: The order in which the report lists the versions (report.json stores them sorted by name).
VERSION_ORDER = ("python", *(name for _, name in LIBRARIES), "mrcal", "circcal")


def _version(module: str) -> str:
    """``module.__version__``, or "unavailable (<why>)"."""
    try:
        return str(importlib.import_module(module).__version__)
    except Exception as exc:  # noqa: BLE001 - a library that cannot load is reported, not fatal
        return f"unavailable ({type(exc).__name__})"


def _mrcal_version() -> str:
    """The version of the mrcal the adapter drives (out of process), or why it is unavailable."""
    try:
        from circcal.validators import registry

        m = registry.get("mrcal")
        ok, why = m.available()
        return m.version if ok else f"unavailable ({why})"
    except Exception as exc:  # noqa: BLE001
        return f"unavailable ({type(exc).__name__}: {exc})"


def _circcal_version() -> str:
    try:
        from importlib.metadata import version

        return version("circcal")
    except Exception:  # noqa: BLE001 - running from a checkout that is not installed
        return "?"


def environment() -> dict[str, Any]:
    """The library versions and the machine a report ran on.

    Returns
    -------
    dict
        ``{"versions": {name: version}, "platform", "machine", "cpu_count"}``.
    """
    versions: dict[str, str] = {"python": platform.python_version()}
    versions.update({name: _version(module) for module, name in LIBRARIES})
    versions["mrcal"] = _mrcal_version()
    versions["circcal"] = _circcal_version()
    return {
        "versions": versions,
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
    }
