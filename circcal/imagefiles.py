"""Image files given as inputs: a folder stands for the images it holds (by extension, sorted by name, not
recursive), a file for itself. One rule for the commands and the Python API alike."""

from __future__ import annotations

import glob
import os
import sys
from collections.abc import Iterable
from pathlib import Path

from circcal.errors import InputError
from circcal.pathnames import display_name

__all__ = ["IMAGE_SUFFIXES", "expand_images", "image_list", "require_existing"]

#: Image files a folder given as an input expands to (by extension, case-insensitive).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm", ".pnm", ".webp", ".jp2", ".exr")


def expand_images(paths: list[Path], option: str = "images", *, announce: bool = True) -> list[Path]:
    """Image paths with every folder among them replaced by its image files, sorted by name.

    Parameters
    ----------
    paths : list of Path
        Files and folders as given on the command line.
    option : str
        How messages name the argument.
    announce : bool
        Say on stderr how many images each folder gave (False where the caller's summary says it).

    Returns
    -------
    list of Path
        The files given, in order, each folder's images (:data:`IMAGE_SUFFIXES`, not recursive) in its place, and
        each glob pattern that names no file itself (a pattern the shell did not expand: quoted, or matching
        nothing there) replaced by the image files it matches, sorted. A file that does not exist among others that
        do stays: the detector reports it as an image left out.

    Raises
    ------
    InputError
        A folder that holds no image file, or a pattern that matches no image file.
    """
    out: list[Path] = []
    for p in paths:
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise InputError(
                    f"{option}: folder {display_name(p)} holds no image file ({', '.join(IMAGE_SUFFIXES[:4])}, ...)"
                )
            if announce:
                print(f"{display_name(p)}: {len(found)} images", file=sys.stderr)
            out += found
        elif not p.exists() and not p.is_symlink() and glob.has_magic(str(p)):
            found = sorted(Path(f) for f in glob.glob(str(p)) if Path(f).suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise InputError(f"{option}: the pattern {display_name(p)} matches no image file")
            out += found
        else:
            out.append(p)
    return out


def require_existing(paths: list[Path], option: str = "images") -> None:
    """Refuse inputs none of which exists (a typo, a folder that is not there): one line, before the work. A file
    that does not exist among others that do is the detector's to report (an image left out, with its reason).

    Parameters
    ----------
    paths : list of Path
        The image files (:func:`expand_images`' result).
    option : str
        How the message names the argument.

    Raises
    ------
    InputError
        No path given exists.
    """
    if paths and not any(p.exists() or p.is_symlink() for p in paths):
        more = f" (nor {len(paths) - 1} more given)" if len(paths) > 1 else ""
        raise InputError(f"{option}: no such file or folder: {display_name(paths[0])}{more}")


def image_list(images: str | os.PathLike[str] | Iterable[str | os.PathLike[str]], option: str = "images") -> list[str]:
    """The image files of an API argument: one path (a folder or a file), or any iterable of paths (a list, a
    ``Path.glob`` generator), each folder in it standing for its images.

    Parameters
    ----------
    images : str, path-like, or iterable of them
    option : str
        How messages name the argument.

    Returns
    -------
    list of str
        The files, in order (:func:`expand_images`).

    Raises
    ------
    InputError
        A folder that holds no image file; an argument that is no path and no iterable of paths.

    Examples
    --------
    >>> image_list(["a.png", "b.png"])
    ['a.png', 'b.png']
    """
    given = [images] if isinstance(images, (str, os.PathLike)) else images
    try:
        paths = [Path(p) for p in given]
    except TypeError:
        raise InputError(f"{option}: expected a folder, an image file or a list of them, got {images!r:.80}") from None
    return [str(p) for p in expand_images(paths, option, announce=False)]
