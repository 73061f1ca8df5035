"""Blocks to text through the Jinja2 templates shipped in ``circcal/report/templates`` (package data, loaded with
:mod:`importlib.resources`, so an installed wheel renders like a checkout): Markdown (``report.md.j2``), one
self-contained HTML page (``report.html.j2``, autoescaped, figures embedded as base64 PNG) and the index of the
reports folder (``readme.md.j2``)."""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Mapping, Sequence
from functools import lru_cache
from importlib import resources

from circcal.report.blocks import Block

__all__ = ["TEMPLATES", "readme", "template_source", "to_html", "to_markdown"]

#: The package folder the templates live in.
TEMPLATES = "templates"

_CODE = re.compile(r"`([^`]+)`")


def template_source(name: str) -> str:
    """The text of a template from the package's templates folder.

    Parameters
    ----------
    name : str
        E.g. ``"report.md.j2"``.

    Returns
    -------
    str
    """
    return resources.files("circcal.report").joinpath(TEMPLATES, name).read_text(encoding="utf-8")


def _md_cell(cell: object) -> str:
    """A Markdown table cell: a literal "|" would end the cell, so it is written as "/"."""
    return str(cell).replace("|", "/")


def _inline(text: object) -> object:
    """Plain text for HTML: escaped, with `code` spans as <code>."""
    from markupsafe import Markup

    return Markup(_CODE.sub(r"<code>\1</code>", html.escape(str(text))))


@lru_cache(maxsize=2)
def _environment(autoescape: bool):
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.FunctionLoader(template_source),
        autoescape=autoescape,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        undefined=jinja2.StrictUndefined,
    )
    env.filters["md_cell"] = _md_cell
    env.filters["inline"] = _inline
    return env


def to_markdown(blocks: Sequence[Block]) -> str:
    """The document as Markdown.

    Parameters
    ----------
    blocks : sequence of Block

    Returns
    -------
    str
    """
    return _environment(False).get_template("report.md.j2").render(blocks=blocks)


def to_html(blocks: Sequence[Block], images: Mapping[str, bytes], *, title: str) -> str:
    """The document as one self-contained HTML page (autoescaped).

    Parameters
    ----------
    blocks : sequence of Block
    images : mapping of str to bytes
        PNG bytes of every figure file the blocks show (embedded as base64).
    title : str
        The page title.

    Returns
    -------
    str
    """
    data = {name: base64.b64encode(png).decode("ascii") for name, png in images.items()}
    return _environment(True).get_template("report.html.j2").render(blocks=blocks, images=data, title=title)


def readme(*, name: str, date: str, kind: str, headline: str) -> str:
    """The reports folder's index (README.md): one row for a run folder.

    Parameters
    ----------
    name : str
        The run folder.
    date : str
        When its numbers were computed.
    kind : str
        The run's kind (full or quick).
    headline : str
        One line of its results.

    Returns
    -------
    str
    """
    return _environment(False).get_template("readme.md.j2").render(name=name, date=date, kind=kind, headline=headline)
