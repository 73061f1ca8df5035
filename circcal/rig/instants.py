"""Which images of a rig's cameras show the same instant: the same file name, or the same name between each camera's
own prefix and suffix (``left01.png`` and ``right01.png``, as OpenCV's stereo sample names them; ``0001_cam0.png``
and ``0001_cam1.png``; ``0001.png`` and ``0001.jpg``).

The plain rule comes first: where the file names already link every camera to the reference (a chain of shared
names), they name the instants. Only where they do not is each camera's affix removed -- the text before the digits
that all of its file names begin with (``left`` of ``left01.png .. left12.png``; ``cam0_`` of ``cam0_0001.png``)
and the text after the digits that they all end with (``.png``, ``_left.png``) -- and used when the remainders link
every camera. A remainder of digits alone is read as its number (``left1.png`` and ``right001.png`` are one instant).
A camera whose names have no affix keeps its names.

A name is the image's path below the folder that holds all of its camera's images: the file name where they share
one folder, ``0001/left.png`` where each instant has its own folder (``0001/left.png``, ``0001/right.png``: the
affix rule then leaves ``/left.png`` out). Where those paths link no rig, each rule is tried again on the file names
alone (one camera's images in one folder, another's spread over several).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from circcal.errors import InputError
from circcal.pathnames import display_name

__all__ = ["Affix", "PLAIN", "RigInstants", "rig_instants", "camera_affixes", "instant_of", "unlinked"]

#: A camera's (prefix, suffix) around the part of its file names that names the instant.
Affix = tuple[str, str]
#: The plain rule: the whole file name names the instant.
PLAIN: Affix = ("", "")


def instant_of(name: str, affix: Affix = PLAIN) -> str:
    """The instant an image shows: its name (:func:`camera_names`) without its camera's affix.

    Parameters
    ----------
    name : str
        An image's name among its camera's images.
    affix : (str, str)
        Its camera's prefix and suffix (:func:`camera_affixes`; :data:`PLAIN` for the plain rule).

    Returns
    -------
    str
        The whole name (plain rule); else the part between the affixes, a number without its leading zeros where it
        is digits alone.

    Examples
    --------
    >>> instant_of("left07.png", ("left", ".png"))
    '7'
    >>> instant_of("left07.png")
    'left07.png'
    """
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


def camera_names(paths: Sequence[str | Path]) -> list[str]:
    """Each image's name among its camera's images: its path below the folder that holds them all (``/``-separated).

    Parameters
    ----------
    paths : sequence of str or Path
        One camera's image files.

    Returns
    -------
    list of str
        In ``paths``' order: the file names where one folder holds them all.

    Examples
    --------
    >>> camera_names(["shots/0001/left.png", "shots/0002/left.png"])
    ['0001/left.png', '0002/left.png']
    """
    if not paths:
        return []
    full = [os.path.abspath(p) for p in paths]
    base = os.path.commonpath([os.path.dirname(p) for p in full])
    return [Path(os.path.relpath(p, base)).as_posix() for p in full]


def camera_affixes(names: Mapping[str, Sequence[str]]) -> dict[str, Affix]:
    """Each camera's prefix and suffix to remove from its images' names to name its instants (module docstring).

    Parameters
    ----------
    names : mapping of str to sequence of str
        Per camera (the reference first) its images' names (:func:`camera_names`).

    Returns
    -------
    dict of str to (str, str)
        Every camera's affix: all :data:`PLAIN` where the plain names link the cameras, or where the affixes would
        not.

    Examples
    --------
    >>> camera_affixes({"l": ["left01.png", "left02.png"], "r": ["right01.png", "right02.png"]})
    {'l': ('left', '.png'), 'r': ('right', '.png')}
    >>> camera_affixes({"l": ["01.png"], "r": ["01.png"]})
    {'l': ('', ''), 'r': ('', '')}
    """
    plain = {n: set(ns) for n, ns in names.items()}
    none = {n: PLAIN for n in names}
    if not unlinked(plain):
        return none
    affixes = {n: _affix(ns) if len(ns) > 1 else PLAIN for n, ns in names.items()}
    stripped = {n: {instant_of(m, affixes[n]) for m in ns} for n, ns in names.items()}
    return none if unlinked(stripped) or all(a == PLAIN for a in affixes.values()) else affixes


@dataclass(frozen=True)
class RigInstants:
    """Which instant each camera's images show.

    Attributes
    ----------
    of : dict of str to dict of str to str
        Per camera, per image path (as given, ``str``) its instant.
    names : dict of str to list of str
        Per camera its images' names (:func:`camera_names`), in the order given.
    affixes : dict of str to (str, str)
        Per camera the affix left out of its names; all :data:`PLAIN` under the plain rule.
    """

    of: dict[str, dict[str, str]]
    names: dict[str, list[str]]
    affixes: dict[str, Affix]

    @property
    def by_affix(self) -> bool:
        """Whether the affix rule named the instants (the plain names did not link the cameras)."""
        return any(a != PLAIN for a in self.affixes.values())


def rig_instants(
    images: Mapping[str, Sequence[str | Path]], label: Callable[[str], str] = lambda n: f"camera {n!r}"
) -> RigInstants:
    """The instant of every image of every camera (module docstring).

    Parameters
    ----------
    images : mapping of str to sequence of str or Path
        Per camera (the reference first) its image files.
    label : callable
        How a message names a camera (the command: ``--camera NAME``).

    Returns
    -------
    RigInstants

    Raises
    ------
    InputError
        Two images of one camera that show one instant (both named).

    Examples
    --------
    >>> rig_instants({"l": ["a/left1.png", "a/left2.png"], "r": ["a/right1.png", "a/right2.png"]}).of["r"]
    {'a/right1.png': '1', 'a/right2.png': '2'}
    """
    relative = {n: camera_names(ps) for n, ps in images.items()}
    files = {n: [Path(p).name for p in ps] for n, ps in images.items()}

    def named(names: dict[str, list[str]], affixes: dict[str, Affix]) -> RigInstants:
        of: dict[str, dict[str, str]] = {}
        for n, ps in images.items():
            seen: dict[str, str] = {}
            for p, m in zip(ps, names[n]):
                v = instant_of(m, affixes[n])
                if v in seen:
                    raise InputError(
                        f"{label(n)}: two images of instant {display_name(v)!r} ({display_name(seen[v])}, "
                        f"{display_name(p)}); the file name (or its folder) names the instant"
                    )
                seen[v] = str(p)
            of[n] = {p: v for v, p in seen.items()}
        return RigInstants(of, names, affixes)

    plain = {n: PLAIN for n in images}
    for names in (relative, files):  # the plain rule: the paths below the cameras' folders, else the file names
        if not unlinked({n: set(ns) for n, ns in names.items()}):
            return named(names, plain)
    for names in (relative, files):  # the affix rule, in the same order
        affixes = camera_affixes(names)
        if any(a != PLAIN for a in affixes.values()):
            return named(names, affixes)
    return named(relative, plain)  # nothing links the cameras: the caller refuses
