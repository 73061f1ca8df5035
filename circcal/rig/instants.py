"""Which images of a rig's cameras show the same instant: the same file name, or the same name between each camera's
own prefix and suffix (``left01.png`` and ``right01.png``, as OpenCV's stereo sample names them; ``0001_cam0.png``
and ``0001_cam1.png``; ``0001.png`` and ``0001.jpg``).

The plain rule comes first: where the file names already link every camera to the reference (a chain of shared
names), they name the instants. Only where they do not is each camera's affix removed -- the text before the digits
that all of its file names begin with (``left`` of ``left01.png .. left12.png``; ``cam0_`` of ``cam0_0001.png``)
and the text after the digits that they all end with (``.png``, ``_left.png``) -- and used when the remainders link
every camera. A remainder of digits alone is read as its number (``left1.png`` and ``right001.png`` are one instant).
A camera whose names have no affix keeps its names.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

__all__ = ["Affix", "PLAIN", "camera_affixes", "instant_of", "unlinked"]

#: A camera's (prefix, suffix) around the part of its file names that names the instant.
Affix = tuple[str, str]
#: The plain rule: the whole file name names the instant.
PLAIN: Affix = ("", "")


def instant_of(path: str | Path, affix: Affix = PLAIN) -> str:
    """The instant an image shows: its file name without its camera's affix.

    Parameters
    ----------
    path : str or Path
        An image file.
    affix : (str, str)
        Its camera's prefix and suffix (:func:`camera_affixes`; :data:`PLAIN` for the plain rule).

    Returns
    -------
    str
        The whole file name (plain rule); else the part between the affixes, a number without its leading zeros
        where it is digits alone.

    Examples
    --------
    >>> instant_of("calib/left07.png", ("left", ".png"))
    '7'
    >>> instant_of("calib/left07.png")
    'left07.png'
    """
    name = Path(path).name
    if affix == PLAIN:
        return name
    prefix, suffix = affix
    middle = name[len(prefix) : len(name) - len(suffix)]
    return str(int(middle)) if middle.isdigit() and middle.isascii() else middle


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


def _affix(names: Sequence[str]) -> Affix:
    """The text before the digits and the text after them that all ``names`` share (each "" where there is none, or
    where the two would leave a name empty)."""
    prefix = os.path.commonprefix(list(names)).rstrip("0123456789")
    suffix = os.path.commonprefix([n[::-1] for n in names])[::-1].lstrip("0123456789")
    if any(len(n) <= len(prefix) + len(suffix) for n in names):
        return PLAIN
    return prefix, suffix


def camera_affixes(images: Mapping[str, Sequence[str | Path]]) -> dict[str, Affix]:
    """Each camera's prefix and suffix to remove from its file names to name its instants (module docstring).

    Parameters
    ----------
    images : mapping of str to sequence of path
        Per camera (the reference first) its image files.

    Returns
    -------
    dict of str to (str, str)
        Every camera's affix: all :data:`PLAIN` where the plain file names link the cameras, or where the affixes
        would not.

    Examples
    --------
    >>> camera_affixes({"l": ["left01.png", "left02.png"], "r": ["right01.png", "right02.png"]})
    {'l': ('left', '.png'), 'r': ('right', '.png')}
    >>> camera_affixes({"l": ["a/01.png"], "r": ["b/01.png"]})
    {'l': ('', ''), 'r': ('', '')}
    """
    plain = {n: {instant_of(p) for p in ps} for n, ps in images.items()}
    none = {n: PLAIN for n in images}
    if not unlinked(plain):
        return none
    affixes = {n: _affix([Path(p).name for p in ps]) if len(ps) > 1 else PLAIN for n, ps in images.items()}
    stripped = {n: {instant_of(p, affixes[n]) for p in ps} for n, ps in images.items()}
    return none if unlinked(stripped) or all(a == PLAIN for a in affixes.values()) else affixes
