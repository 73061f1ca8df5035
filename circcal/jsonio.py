"""JSON in and out, written once: :func:`jsonable` turns circcal's values (numpy arrays and scalars, enums, named
tuples, objects with ``to_dict()``) into plain JSON data, with non-finite floats as ``null`` (JSON has no NaN);
:func:`read_json` reads a file and names it in every error."""

from __future__ import annotations

import enum
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from circcal.errors import InputError

__all__ = ["jsonable", "dumps", "read_text", "parse_json", "read_json", "depth_over"]


def jsonable(x: Any) -> Any:
    """A JSON-ready copy of ``x``.

    Dicts (keys as str), lists, tuples and arrays recursed; numpy scalars to Python; non-finite floats to None; an
    enum to its value; a named tuple to a dict of its fields; an object with a ``to_dict()`` method (a
    :class:`circcal.model.Camera`, a :class:`circcal.board.Board`) to that dict.

    Parameters
    ----------
    x : object

    Returns
    -------
    object

    Examples
    --------
    >>> jsonable({"a": np.array([1.0, np.nan])})
    {'a': [1.0, None]}
    """
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
            return x.tolist()  # (plain Python values already: no element-wise walk, ~3x faster for model.json)
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
    """``json.dumps(jsonable(x))``, refusing anything left that JSON cannot hold (``allow_nan=False``).

    Parameters
    ----------
    x : object
    **kwargs
        ``json.dumps``' keywords (``indent``, ...).

    Returns
    -------
    str

    Raises
    ------
    TypeError, ValueError
        A value JSON cannot hold (a bug: every writer's data is JSON-ready).
    """
    return json.dumps(jsonable(x), allow_nan=False, **kwargs)


def read_text(path: str | Path, what: str = "file", *, max_bytes: int | None = None) -> str:
    """The text in ``path``.

    Parameters
    ----------
    path : str or Path
    what : str
        Names the file's kind in messages.
    max_bytes : int or None
        The largest size allowed (checked before reading).

    Returns
    -------
    str

    Raises
    ------
    InputError
        Naming the file (as ``what``) when it is missing, not a file, larger than ``max_bytes``, or cannot be read or
        decoded.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{what} {p}: {'no such file' if not p.exists() else 'not a file'}")
    try:
        if max_bytes is None:
            return p.read_text()
        size = p.stat().st_size
        if size > max_bytes:
            raise InputError(f"{what} {p}: {size} bytes, more than the {max_bytes} such a file may hold")
        with p.open("rb") as f:
            data = f.read(max_bytes + 1)  # (a file that grew since the stat is still cut off here)
        if len(data) > max_bytes:
            raise InputError(f"{what} {p}: more than the {max_bytes} bytes such a file may hold")
        return data.decode()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{what} {p}: cannot read it ({exc})") from None


_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')
_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|[{}\[\]:,]|[^\s{}\[\]:,"]+')


def depth_over(text: str, max_depth: int) -> int | None:
    """The line where ``text``'s brackets (``[``/``{`` against ``]``/``}``, as JSON's and YAML's flow collections nest)
    first nest deeper than ``max_depth``.

    Double-quoted strings are left out; numpy counts the brackets, so a 64 MiB text costs well under a second.

    Parameters
    ----------
    text : str
    max_depth : int

    Returns
    -------
    int or None
        The line (from 1); None when never.

    Examples
    --------
    >>> depth_over("[\\n[[1]]]", 2)
    2
    """
    bare = _STRING.sub('""', text) if '"' in text else text
    b = np.frombuffer(bare.encode(), dtype=np.uint8)
    step = ((b == ord("[")) | (b == ord("{"))).astype(np.int8) - ((b == ord("]")) | (b == ord("}")))
    nz = np.flatnonzero(step)
    if nz.size == 0:
        return None
    depth = np.cumsum(step[nz], dtype=np.int32)
    over = np.flatnonzero(depth > max_depth)
    if over.size == 0:
        return None
    return bare.encode()[: int(nz[over[0]])].count(b"\n") + 1


def _duplicate_key(text: str) -> tuple[str, int] | None:
    """The first key repeated within one JSON object of ``text``, with its line (only called once a duplicate is
    known, to say where)."""
    stack: list[set | None] = []
    line, last, expect_key = 1, 0, False
    for m in _TOKEN.finditer(text):
        tok = m.group()
        if tok == "{":
            stack.append(set())
            expect_key = True
        elif tok == "[":
            stack.append(None)
        elif tok in "]}":
            stack.pop() if stack else None
            expect_key = False
        elif tok == ",":
            expect_key = bool(stack) and stack[-1] is not None
        elif expect_key and tok.startswith('"'):
            line += text.count("\n", last, m.start())
            last = m.start()
            key = json.loads(tok)
            if key in stack[-1]:
                return key, line
            stack[-1].add(key)
            expect_key = False
    return None


def parse_json(
    text: str, *, max_depth: int | None = None, max_int_digits: int | None = None, unique_keys: bool = False
) -> Any:
    """``json.loads(text)``, hostile texts refused in words, never with Python's own exceptions.

    Parameters
    ----------
    text : str
    max_depth : int or None
        Nesting deeper is refused (checked before parsing; without it, as deep as Python's recursion allows).
    max_int_digits : int or None
        Integers of more digits are refused (without it, Python's 4300).
    unique_keys : bool
        Refuse a key repeated in one object (``duplicate key 'fx' at line N``).

    Returns
    -------
    object

    Raises
    ------
    InputError
        With the line and column of a syntax error, or any of the above.
    """
    if max_depth is not None:
        line = depth_over(text, max_depth)
        if line is not None:
            raise InputError(f"JSON nested deeper than {max_depth} levels (at line {line})")

    def parse_int(s: str) -> int:
        if max_int_digits is not None and len(s.lstrip("-")) > max_int_digits:
            raise InputError(f"an integer of {len(s.lstrip('-'))} digits (at most {max_int_digits})")
        return int(s)

    def unique(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        d = dict(pairs)
        if len(d) != len(pairs):
            found = _duplicate_key(text)
            key, line = found if found is not None else ([k for k, _ in pairs if k in d][0], "?")
            raise InputError(f"duplicate key {key!r} at line {line}")
        return d

    try:
        return json.loads(text, parse_int=parse_int, object_pairs_hook=unique if unique_keys else None)
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})") from None
    except RecursionError:
        raise InputError("JSON nested too deeply to parse") from None
    except InputError:
        raise
    except ValueError as exc:  # Python's own integer-digit limit
        raise InputError(f"not readable JSON ({exc})") from None


def read_json(path: str | Path, what: str = "JSON file", **limits: Any) -> Any:
    """The data in ``path``.

    Parameters
    ----------
    path : str or Path
    what : str
        Names the kind of file in messages.
    **limits
        ``max_bytes`` (:func:`read_text`) and the keywords of :func:`parse_json`.

    Returns
    -------
    object

    Raises
    ------
    InputError
        Naming the file for a missing, unreadable or malformed one.
    """
    text = read_text(path, what, max_bytes=limits.pop("max_bytes", None))
    try:
        return parse_json(text, **limits)
    except InputError as exc:
        raise InputError(f"{what} {path}: {exc}") from None
