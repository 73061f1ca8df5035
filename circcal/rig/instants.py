"""Which images of a rig's cameras show the same instant: the same file name, or the same name after each camera's own
prefix (``left01.png`` and ``right01.png``, as OpenCV's stereo sample names them).

The plain rule comes first: where the file names already link every camera to the reference (a chain of shared
names), they name the instants. Only where they do not is each camera's prefix removed -- the text before the digits
that all of its file names begin with (``left`` of ``left01.png .. left12.png``; ``cam0_`` of ``cam0_0001.png``) --
and used when the remainders link every camera. A camera whose names have no such prefix keeps its names.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

__all__ = ["camera_prefixes", "instant_of", "unlinked"]


def instant_of(path: str | Path, prefix: str = "") -> str:
    """The instant an image shows: its file name without its camera's prefix.

    Parameters
    ----------
    path : str or Path
        An image file.
    prefix : str
        Its camera's prefix (:func:`camera_prefixes`; "" for the plain rule).

    Returns
    -------
    str

    Examples
    --------
    >>> instant_of("calib/left07.png", "left")
    '07.png'
    """
    return Path(path).name[len(prefix) :]


def unlinked(instants: Mapping[str, set[str]]) -> list[str]:
    """The cameras no chain of shared instants links to the first (the reference).

    Parameters
    ----------
    instants : mapping of str to set of str
        Per camera (the reference first) the instants it has images of.

    Returns
    -------
    list of str
        In the mapping's order; empty when every camera is linked.
    """
    names = list(instants)
    if not names:
        return []
    linked, todo = {names[0]}, [names[0]]
    while todo:
        a = todo.pop()
        for b in names:
            if b not in linked and instants[a] & instants[b]:
                linked.add(b)
                todo.append(b)
    return [n for n in names if n not in linked]


def _prefix(names: Sequence[str]) -> str:
    """The text before the digits all ``names`` begin with ("" where there is none, or where it is a whole name)."""
    common = os.path.commonprefix(list(names)).rstrip("0123456789")
    return "" if any(len(n) <= len(common) for n in names) else common


def camera_prefixes(images: Mapping[str, Sequence[str | Path]]) -> dict[str, str]:
    """Each camera's prefix to remove from its file names to name its instants (module docstring).

    Parameters
    ----------
    images : mapping of str to sequence of path
        Per camera (the reference first) its image files.

    Returns
    -------
    dict of str to str
        Every camera's prefix: all "" where the plain file names link the cameras, or where the prefixes would not.

    Examples
    --------
    >>> camera_prefixes({"l": ["left01.png", "left02.png"], "r": ["right01.png", "right02.png"]})
    {'l': 'left', 'r': 'right'}
    >>> camera_prefixes({"l": ["a/01.png"], "r": ["b/01.png"]})
    {'l': '', 'r': ''}
    """
    plain = {n: {instant_of(p) for p in ps} for n, ps in images.items()}
    none = {n: "" for n in images}
    if not unlinked(plain):
        return none
    prefixes = {n: _prefix([Path(p).name for p in ps]) if ps else "" for n, ps in images.items()}
    stripped = {n: {instant_of(p, prefixes[n]) for p in ps} for n, ps in images.items()}
    return none if unlinked(stripped) or not any(prefixes.values()) else prefixes
