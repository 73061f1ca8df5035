"""The report as a list of blocks, one type per kind of content; the templates (:mod:`circcal.report.render`) turn
them into Markdown and HTML. Text may mark code with backticks; everything else is plain text (HTML escapes it)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

__all__ = ["Block", "Bullets", "Heading", "Image", "Paragraph", "Table"]


@dataclass(frozen=True)
class Heading:
    """A section heading.

    Attributes
    ----------
    text : str
    level : int
        1 is the title.
    """

    level: int
    text: str
    kind: ClassVar[str] = "heading"


@dataclass(frozen=True)
class Paragraph:
    """A paragraph of text (backticks mark code).

    Attributes
    ----------
    text : str
    """

    text: str
    kind: ClassVar[str] = "paragraph"


@dataclass(frozen=True)
class Bullets:
    """A bullet list.

    Attributes
    ----------
    items : tuple of str
    """

    items: tuple[str, ...]
    kind: ClassVar[str] = "bullets"


@dataclass(frozen=True)
class Table:
    """A table of text cells.

    Attributes
    ----------
    head : tuple of str
        Column titles.
    rows : tuple of tuple of str
        Cells as text, as many per row as ``head`` has.
    """

    head: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    kind: ClassVar[str] = "table"


@dataclass(frozen=True)
class Image:
    """A figure.

    Attributes
    ----------
    file : str
        The PNG's file name (beside the document).
    caption : str
    """

    file: str
    caption: str
    kind: ClassVar[str] = "image"


Block = Heading | Paragraph | Bullets | Table | Image
