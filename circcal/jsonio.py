"""JSON in and out, written once: :func:`jsonable` turns circcal's values (numpy arrays and scalars, enums, named
tuples, objects with ``to_dict()``) into plain JSON data, with non-finite floats as ``null`` (JSON has no NaN);
:func:`read_json` reads a file and names it in every error."""
from __future__ import annotations

import enum
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from circcal.errors import InputError

__all__ = ["jsonable", "dumps", "read_text", "parse_json", "read_json"]


def jsonable(x: Any) -> Any:
    """A JSON-ready copy of ``x``: dicts (keys as str), lists, tuples and arrays recursed; numpy scalars to Python;
    non-finite floats to None; an enum to its value; a named tuple to a dict of its fields; an object with a
    ``to_dict()`` method (a :class:`circcal.model.Camera`, a :class:`circcal.board.Board`) to that dict."""
    if isinstance(x, dict):
        return {str(k.value if isinstance(k, enum.Enum) else k): jsonable(v) for k, v in x.items()}
    if isinstance(x, enum.Enum):
        return jsonable(x.value)
    if isinstance(x, tuple) and hasattr(x, "_asdict"):
        return jsonable(x._asdict())
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        if x.dtype.kind in "biu" or (x.dtype.kind == "f" and bool(np.isfinite(x).all())):
            return x.tolist()   # (plain Python values already: no element-wise walk, ~3x faster for model.json)
        return jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if hasattr(x, "to_dict") and callable(x.to_dict):
        return jsonable(x.to_dict())
    return x


def dumps(x: Any, **kwargs: Any) -> str:
    """``json.dumps(jsonable(x))``, refusing anything left that JSON cannot hold (``allow_nan=False``)."""
    return json.dumps(jsonable(x), allow_nan=False, **kwargs)


def read_text(path: str | Path, what: str = "file") -> str:
    """The text in ``path``; :class:`~circcal.errors.InputError` naming the file (as ``what``) when it is missing,
    not a file, or cannot be read or decoded."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{what} {p}: {'no such file' if not p.exists() else 'not a file'}")
    try:
        return p.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{what} {p}: cannot read it ({exc})") from None


def parse_json(text: str) -> Any:
    """``json.loads(text)``; :class:`~circcal.errors.InputError` with the line and column of a syntax error."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})") from None


def read_json(path: str | Path, what: str = "JSON file") -> Any:
    """The data in ``path``; :class:`~circcal.errors.InputError` naming the file for a missing, unreadable or
    malformed one. ``what`` names the kind of file in messages."""
    text = read_text(path, what)
    try:
        return parse_json(text)
    except InputError as exc:
        raise InputError(f"{what} {path}: {exc}") from None
