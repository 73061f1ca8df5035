"""File names of any bytes and characters, as JSON text and as display text.

A POSIX file name is bytes, not text: ``caf\\xe9.png`` (Latin-1 bytes) is a valid name that is not UTF-8. Python
holds such a name as a ``str`` with lone surrogates (``os.fsdecode``: byte 0xE9 -> ``'\\udce9'``), which
``json.dumps`` writes as a ``\\udce9`` escape that other JSON tools turn into U+FFFD (the name is lost), and which
crashes FreeType (matplotlib) and a UTF-8 ``write_text``. Two forms, one per use:

- :func:`path_to_json` / :func:`path_from_json`: lossless, valid JSON and UTF-8. The rule: a name whose bytes
  (``os.fsencode``) are valid UTF-8 is stored as that text, unchanged, unless it begins with :data:`BYTES_PREFIX`
  (``"bytes:"``); any other name is stored as ``"bytes:"`` followed by its bytes, where every byte that is not part
  of a valid UTF-8 sequence, and every ``%``, is written ``%XX`` (two hex digits) and the rest stays text. So
  ``caf\\xe9_00.png`` is stored ``"bytes:caf%E9_00.png"``, ``100%.png`` as is, ``bytes:x`` as ``"bytes:bytes:x"``.
  Reading: a string that begins with ``bytes:`` is decoded back to those bytes, any other is the name itself
  (a lone ``\\udcXX`` surrogate that older files hold is read as byte XX); bytes become a name by ``os.fsdecode``.
- :func:`display_name`: one printable line for messages and reports, not reversible: undecodable bytes as
  ``\\xNN``, and control characters, line separators and bidirectional-text controls escaped, so that a name can
  neither break a line, fake one, nor reorder the text around it; everything else is unchanged (emoji, ``$``,
  ``<``, ``|``: escaping for a format is the format's writer's job).

One-line summary (ARCHITECTURE): file names in JSON: ``path_to_json``/``path_from_json`` (`pathnames.py`): UTF-8
names as is, any other (or one beginning ``bytes:``) as ``"bytes:"`` + its bytes with non-UTF-8 bytes and ``%`` as
``%XX``; in messages and reports: ``display_name`` (``\\xNN`` for such bytes, control and bidi characters escaped).
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from circcal.errors import InputError

__all__ = ["BYTES_PREFIX", "path_to_json", "path_from_json", "display_name"]

#: The prefix of a name stored by its bytes (:func:`path_to_json`). On Windows ``:`` cannot appear in a name past a
#: one-letter drive, so no real path there begins with it.
BYTES_PREFIX = "bytes:"

_PERCENT = re.compile(r"%(.{0,2})", re.DOTALL)
_HEX2 = re.compile(r"[0-9A-Fa-f]{2}")

#: Characters :func:`display_name` escapes: C0 controls and DEL (``\\n``, ``\\r``, ``\\t`` by name, the rest
#: ``\\xNN``), C1 controls, the line and paragraph separators (``str.splitlines`` breaks at all of them), the
#: bidirectional controls (embeddings, overrides, isolates, the marks: the "Trojan Source" set) and lone surrogates
#: (undecodable bytes ``\\udc80``-``\\udcff`` as ``\\xNN``; any other as ``\\uNNNN``).
_UNSAFE = re.compile("[\x00-\x1f\x7f-\x9f\u061c\u200e\u200f\u2028\u2029\u202a-\u202e\u2066-\u2069\ud800-\udfff]")
_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escape_char(m: re.Match[str]) -> str:
    ch = m.group()
    o = ord(ch)
    if ch in _NAMED:
        return _NAMED[ch]
    if o < 0x80:
        return f"\\x{o:02x}"  # C0 / DEL: a byte < 0x80 is always valid UTF-8, so never ambiguous
    if 0xDC80 <= o <= 0xDCFF:
        return f"\\x{o - 0xDC00:02x}"  # an undecodable byte, as os.fsencode(...).decode(backslashreplace) shows it
    return f"\\u{o:04x}"


def display_name(path: str | bytes | os.PathLike[str] | os.PathLike[bytes]) -> str:
    """A file name (or any one-line text) as one printable line for a message or a report.

    Parameters
    ----------
    path : str, bytes or path-like
        The name (``os.fsdecode`` is applied: bytes and ``Path`` objects are taken as the file system gives them).

    Returns
    -------
    str
        The name with each undecodable byte written ``\\xNN`` (``caf\\xe9.png``), newline, carriage return and tab
        as ``\\n``, ``\\r``, ``\\t``, other C0 controls and DEL as ``\\xNN``, C1 controls, U+2028/U+2029 and the
        bidirectional controls (U+061C, U+200E, U+200F, U+202A-U+202E, U+2066-U+2069) as ``\\uNNNN``; every other
        character unchanged. Valid UTF-8 without lone surrogates; not reversible (a literal backslash stays as is).
    """
    return _UNSAFE.sub(_escape_char, os.fsdecode(path))


def path_to_json(path: str | bytes | os.PathLike[str] | os.PathLike[bytes]) -> str:
    """A file name as lossless JSON text (the rule in the module docstring); :func:`path_from_json` inverts it.

    Parameters
    ----------
    path : str, bytes or path-like
        The name as given (not normalised: ``a//b`` stays ``a//b``).

    Returns
    -------
    str
        The name itself when its bytes are valid UTF-8 and it does not begin with :data:`BYTES_PREFIX`; otherwise
        ``"bytes:"`` + the name with each byte outside a valid UTF-8 sequence, and each ``%``, as ``%XX``. Holds no
        lone surrogate (valid UTF-8, so every JSON tool reads it unchanged).

    Raises
    ------
    ValueError
        For an empty name or one holding a NUL character: no file system gives such a name (a bug in the caller).
    """
    name = os.fsdecode(path)
    if not name or "\x00" in name:
        raise ValueError(f"not a file name: {name!r}")
    raw = os.fsencode(name)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = None
    if text is not None and not text.startswith(BYTES_PREFIX):
        return text
    parts = []
    for ch in raw.decode("utf-8", "surrogateescape"):  # each undecodable byte XX becomes the surrogate U+DCXX
        o = ord(ch)
        parts.append(f"%{o - 0xDC00:02X}" if 0xDC80 <= o <= 0xDCFF else "%25" if ch == "%" else ch)
    return BYTES_PREFIX + "".join(parts)


def path_from_json(value: Any, what: str = "file name") -> Path:
    """The file name that :func:`path_to_json` stored as ``value``.

    Parameters
    ----------
    value : str
        The stored text: ``"bytes:"`` + percent-escaped bytes, or the name itself (where a lone surrogate
        ``\\udcXX``, as older files hold, stands for byte XX).
    what : str
        What the value is, for error messages (e.g. ``"detections.json: images[3].path"``).

    Returns
    -------
    pathlib.Path
        ``Path(os.fsdecode(bytes))`` of the name's bytes.

    Raises
    ------
    circcal.errors.InputError
        When ``value`` is not a string, is empty, holds a NUL, a malformed ``%`` escape after ``bytes:``, or a lone
        surrogate that stands for no byte; the message names ``what``.
    """
    if not isinstance(value, str):
        raise InputError(f"{what}: expected a file name as a string, got {type(value).__name__}")
    if not value:
        raise InputError(f"{what}: an empty string is not a file name")
    try:
        if value.startswith(BYTES_PREFIX):
            buf = bytearray()
            rest = value[len(BYTES_PREFIX) :]
            pos = 0
            for m in _PERCENT.finditer(rest):
                buf += rest[pos : m.start()].encode("utf-8")
                if not _HEX2.fullmatch(m.group(1)):
                    raise InputError(
                        f"{what}: {display_name(value)}: '%' must be followed by two hex digits "
                        f"(the byte), at character {len(BYTES_PREFIX) + m.start() + 1}"
                    )
                buf.append(int(m.group(1), 16))
                pos = m.end()
            buf += rest[pos:].encode("utf-8")
            raw = bytes(buf)
        else:
            raw = value.encode("utf-8", "surrogateescape")
    except UnicodeEncodeError:
        raise InputError(
            f"{what}: {display_name(value)}: holds a lone surrogate that stands for no byte "
            f"(expected UTF-8 text, or 'bytes:' with each other byte as %XX)"
        ) from None
    if not raw or b"\x00" in raw:
        raise InputError(f"{what}: {display_name(value)}: not a file name (empty, or holds a NUL byte)")
    return Path(os.fsdecode(raw))
