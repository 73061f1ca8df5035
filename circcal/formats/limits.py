"""The limits every camera-model reader applies, and the value checks they share (written once here).

A camera file is small and flat: a few numbers, a 3x3 matrix, a short vector. Everything far outside that is a
damaged or hostile file, refused with a :class:`~circcal.errors.ModelFileError` naming the field before it can
cost memory or time, or reach the camera as a value that projects to nonsense. Each bound is generous: every real
camera lies orders of magnitude inside it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from typing import Any

import numpy as np

from circcal.errors import ModelFileError
from circcal.jsonio import depth_over

__all__ = [
    "MAX_MODEL_FILE_BYTES",
    "MAX_NESTING_DEPTH",
    "MAX_INTEGER_DIGITS",
    "MAX_IMAGE_SIDE",
    "MIN_FOCAL_PX",
    "MAX_FOCAL_PX",
    "MAX_PRINCIPAL_POINT_FACTOR",
    "MAX_DIST_COEFF",
    "K_ROW3_RTOL",
    "show",
    "integer",
    "number",
    "number_list",
    "matrix",
    "check_K",
    "check_camera",
    "load_yaml",
    "check_nesting",
    "JSON_LIMITS",
]

#: Bytes a model file may hold: a model.json with every view's observations of a 100-view calibration is a few MiB,
#: and parsing costs ~10x the text in memory (a 1 GB model.json took 7.6 GB).
MAX_MODEL_FILE_BYTES = 64 * 2**20
#: Nesting depth of a JSON / YAML / literal document: model.json nests 5 deep; Python's parsers recurse per level.
MAX_NESTING_DEPTH = 64
#: Decimal digits an integer may have: 2**63 has 19; longer ones overflow a float (and Python's int parser caps
#: them at 4300 digits with an exception of its own).
MAX_INTEGER_DIGITS = 20
#: Largest image width or height, pixels (2**20: 1 Mpx on a side, beyond any sensor).
MAX_IMAGE_SIDE = 2**20
#: Focal lengths, pixels: below 1 px the whole image is a few pixels from the axis at 90 deg; above 1e6 px a 2**20 px
#: sensor sees less than 0.06 deg.
MIN_FOCAL_PX = 1.0
MAX_FOCAL_PX = 1e6
#: The principal point lies within this many image sizes of the origin (|cx|, |cy| <= factor * max(width, height)).
MAX_PRINCIPAL_POINT_FACTOR = 100
#: Largest |distortion coefficient|: fitted lenses stay below ~1e3 (rational models' k4-k6 the largest); beyond
#: 1e4 the polynomial is noise amplified, not a lens.
MAX_DIST_COEFF = 1e4
#: The camera matrix's third row must be (0, 0, 1) within this (relative to the matrix's largest entry).
K_ROW3_RTOL = 1e-9

#: :func:`circcal.jsonio.parse_json`'s keywords for a camera file.
JSON_LIMITS: dict[str, Any] = {
    "max_depth": MAX_NESTING_DEPTH,
    "max_int_digits": MAX_INTEGER_DIGITS,
    "unique_keys": True,
}

_SHOW_CHARS = 60
#: YAML block indicators nested on one line ("- - - - 1"): each opens a level
_COMPACT_NESTING = re.compile(rf"(?:[-?:][ \t]+){{{MAX_NESTING_DEPTH}}}")
_MARKUP_DECLARATION = re.compile(r"<!\s*(DOCTYPE|ENTITY|ELEMENT|ATTLIST)", re.I)


def show(v: Any) -> str:
    """``repr(v)``, cut to a readable length (a hostile file's value may be megabytes long).

    Parameters
    ----------
    v : object

    Returns
    -------
    str

    Examples
    --------
    >>> show(10**400)
    'an integer of ~400 digits'
    """
    if isinstance(v, int) and not isinstance(v, bool) and v.bit_length() > 200:
        return f"an integer of ~{int(v.bit_length() * 0.30103)} digits"
    r = repr(v)
    return r if len(r) <= _SHOW_CHARS else f"{r[: _SHOW_CHARS - 5]}...{r[-2:]} ({len(r)} characters)"


def _is_real(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _float(v: Any) -> float:
    try:
        return float(v)
    except OverflowError:  # an integer too large for a float
        return math.copysign(math.inf, v)


def integer(v: Any, field: str, lo: int = 1, hi: int = MAX_IMAGE_SIDE) -> int:
    """``v`` as an int in [``lo``, ``hi``]: an int, or a float with an integral value (never a boolean or a string).

    Parameters
    ----------
    v : object
    field : str
        Names the value in the message.
    lo, hi : int
        The bounds, inclusive.

    Returns
    -------
    int

    Raises
    ------
    ModelFileError
        Naming ``field``.

    Examples
    --------
    >>> integer(640.0, "image width")
    640
    """
    if _is_real(v):
        f = _float(v)
        if math.isfinite(f) and f == int(f) and lo <= f <= hi:
            return int(f)
    raise ModelFileError(f"{field} must be an integer in {lo}..{hi}, got {show(v)}")


def number(v: Any, field: str, lo: float = -math.inf, hi: float = math.inf, unit: str = "") -> float:
    """``v`` as a finite float in [``lo``, ``hi``] (never a boolean or a string).

    Parameters
    ----------
    v : object
    field : str
        Names the value in the message.
    lo, hi : float
        The bounds, inclusive.
    unit : str
        Appended to the range in the message (e.g. ``" px"``).

    Returns
    -------
    float

    Raises
    ------
    ModelFileError
        Naming ``field``.
    """
    if _is_real(v):
        f = _float(v)
        if math.isfinite(f) and lo <= f <= hi:
            return f
    rng = "" if (lo, hi) == (-math.inf, math.inf) else f" in [{lo:g}, {hi:g}]{unit}"
    raise ModelFileError(f"{field} must be a finite number{rng}, got {show(v)}")


def number_list(v: Any, field: str, size: int | Sequence[int] | None = None) -> np.ndarray:
    """``v`` (a list or tuple of numbers) as a float64 vector, each finite.

    Parameters
    ----------
    v : object
    field : str
        Names the value in the message.
    size : int, sequence of int, or None
        The length (or lengths) allowed; None: any.

    Returns
    -------
    ndarray, shape (n,)

    Raises
    ------
    ModelFileError
        Naming ``field`` (and the element).
    """
    if not isinstance(v, (list, tuple)):
        raise ModelFileError(f"{field} must be a list of numbers, got {show(v)}")
    sizes = (size,) if isinstance(size, int) else size
    if sizes is not None and len(v) not in sizes:
        raise ModelFileError(f"{field} must hold {' or '.join(str(s) for s in sizes)} numbers, got {len(v)}")
    return np.array([number(x, f"{field}[{i}]") for i, x in enumerate(v)], dtype=np.float64)


def matrix(values: Any, field: str, shape: tuple[int, int], rows: Any = None, cols: Any = None) -> np.ndarray:
    """A ``shape`` matrix from ``values`` (row-major numbers), with the file's own declared ``rows``/``cols`` (when it
    states them) checked against ``shape`` and against the data's length.

    Parameters
    ----------
    values : object
        A list of numbers.
    field : str
        Names the matrix in the message.
    shape : tuple of int, (rows, cols)
    rows, cols : object or None
        What the file declares.

    Returns
    -------
    ndarray, shape ``shape``

    Raises
    ------
    ModelFileError
        Naming ``field``.
    """
    if rows is not None or cols is not None:
        r = integer(rows, f"{field} rows", 1, 10**6)
        c = integer(cols, f"{field} cols", 1, 10**6)
        n = len(values) if isinstance(values, (list, tuple)) else None
        if n is not None and n != r * c:
            raise ModelFileError(f"{field}: rows x cols = {r} x {c} = {r * c}, but its data holds {n} numbers")
        if (r, c) != shape:
            raise ModelFileError(f"{field} must be {shape[0]}x{shape[1]}, got {r}x{c}")
    return number_list(values, field, shape[0] * shape[1]).reshape(shape)


def check_K(K: np.ndarray, field: str = "camera matrix") -> None:
    """A 3x3 camera matrix's third row is (0, 0, 1) within :data:`K_ROW3_RTOL` (an OpenCV matrix with another third row
    is a homography, not a camera).

    Parameters
    ----------
    K : ndarray, shape (3, 3)
    field : str
        Names the matrix in the message.

    Raises
    ------
    ModelFileError
    """
    scale = max(1.0, float(np.max(np.abs(K))))
    if np.any(np.abs(K[2] - (0.0, 0.0, 1.0)) > K_ROW3_RTOL * scale):
        raise ModelFileError(f"{field}: the third row must be [0, 0, 1], got {[float(v) for v in K[2]]}")


def check_camera(camera: Any) -> Any:
    """Refuse a :class:`~circcal.model.Camera` outside the bounds above; returns it.

    The bounds: :data:`MAX_IMAGE_SIDE`, focal lengths in [:data:`MIN_FOCAL_PX`, :data:`MAX_FOCAL_PX`], principal
    point within :data:`MAX_PRINCIPAL_POINT_FACTOR` image sizes, distortion within :data:`MAX_DIST_COEFF`.

    Parameters
    ----------
    camera : Camera

    Returns
    -------
    Camera
        ``camera`` itself.

    Raises
    ------
    ModelFileError
        Naming the field.
    """
    integer(camera.width, "camera width")
    integer(camera.height, "camera height")
    for name in ("fx", "fy"):
        number(getattr(camera, name), f"camera {name}", MIN_FOCAL_PX, MAX_FOCAL_PX, " px")
    c = MAX_PRINCIPAL_POINT_FACTOR * max(camera.width, camera.height)
    for name in ("cx", "cy"):
        number(getattr(camera, name), f"camera {name}", -c, c, f" px ({MAX_PRINCIPAL_POINT_FACTOR} image sizes)")
    for name, v in zip(camera.model.dist_names, camera.dist):
        number(float(v), f"camera distortion {name}", -MAX_DIST_COEFF, MAX_DIST_COEFF)
    return camera


def load_yaml(text: str) -> Any:
    """``yaml.safe_load(text)`` bounded for camera files.

    Nesting deeper than :data:`MAX_NESTING_DEPTH`, an anchor or alias (a 562-byte file of nested aliases expands to
    gigabytes; camera files need none), a key repeated in one mapping and an integer of more than
    :data:`MAX_INTEGER_DIGITS` digits are refused, each with its line.

    Parameters
    ----------
    text : str

    Returns
    -------
    object
        The parsed document.

    Raises
    ------
    ModelFileError
        Any of the above, and YAML that does not parse.
    """
    import yaml

    try:
        return yaml.load(text, Loader=_bounded_loader())  # noqa: S506 (a SafeLoader subclass)
    except yaml.YAMLError as exc:
        raise ModelFileError(f"not valid YAML ({' '.join(str(exc).split())[:300]})") from None
    except RecursionError:
        raise ModelFileError("YAML nested too deeply to parse") from None


_LOADER: Any = None


def _bounded_loader() -> Any:
    """The SafeLoader subclass of :func:`load_yaml` (built once, on first use: yaml is imported only then)."""
    global _LOADER
    if _LOADER is not None:
        return _LOADER
    import yaml

    def at(node_or_event: Any) -> str:
        return f"at line {node_or_event.start_mark.line + 1}"

    class BoundedLoader(yaml.SafeLoader):  # type: ignore[misc]  # PyYAML ships no stubs here: SafeLoader is Any
        _depth = 0

        def compose_node(self, parent: Any, index: Any) -> Any:
            event = self.peek_event()
            if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None) is not None:
                raise ModelFileError(
                    f"a YAML anchor or alias {at(event)}: camera files need none, and they are "
                    f"refused (nested aliases expand without bound)"
                )
            self._depth += 1
            try:
                if self._depth > MAX_NESTING_DEPTH:
                    raise ModelFileError(f"YAML nested deeper than {MAX_NESTING_DEPTH} levels ({at(event)})")
                return super().compose_node(parent, index)
            finally:
                self._depth -= 1

        def construct_mapping(self, node: Any, deep: bool = False) -> Any:
            if isinstance(node, yaml.MappingNode):
                seen: set[Any] = set()
                for key_node, _ in node.value:
                    key = key_node.value if isinstance(key_node, yaml.ScalarNode) else None
                    if key is None:
                        continue
                    if key in seen:
                        raise ModelFileError(f"duplicate key {show(key)} {at(key_node)}")
                    seen.add(key)
            return super().construct_mapping(node, deep=deep)

        def construct_yaml_int(self, node: Any) -> Any:
            digits = sum(ch.isdigit() for ch in str(node.value))
            if digits > MAX_INTEGER_DIGITS:
                raise ModelFileError(f"an integer of {digits} digits {at(node)} (at most {MAX_INTEGER_DIGITS})")
            return super().construct_yaml_int(node)

    BoundedLoader.add_constructor("tag:yaml.org,2002:int", BoundedLoader.construct_yaml_int)
    _LOADER = BoundedLoader
    return _LOADER


def check_nesting(text: str) -> None:
    """Refuse a YAML or XML text (before a parser sees it) nesting too deep, or declaring a document type.

    Nesting deeper than :data:`MAX_NESTING_DEPTH` in flow brackets, XML elements or compact YAML block indicators
    (OpenCV's parser recurses on the C stack: 100,000 brackets crash the process), and any XML document type
    declaration (``<!DOCTYPE``, ``<!ENTITY``: entities expand without bound; camera files need none).

    Parameters
    ----------
    text : str

    Raises
    ------
    ModelFileError
    """
    m = _MARKUP_DECLARATION.search(text)
    if m:
        line = text.count("\n", 0, m.start()) + 1
        raise ModelFileError(
            f"an XML <!{m.group(1).upper()} declaration at line {line}: document types and entities "
            f"are refused (camera files need none)"
        )
    deep_line = depth_over(text, MAX_NESTING_DEPTH)
    if deep_line is not None:
        raise ModelFileError(f"nested deeper than {MAX_NESTING_DEPTH} levels (at line {deep_line})")
    m = _COMPACT_NESTING.search(text)
    if m:
        raise ModelFileError(
            f"nested deeper than {MAX_NESTING_DEPTH} levels (at line {text.count(chr(10), 0, m.start()) + 1})"
        )
    if "<" in text:
        b = np.frombuffer(text.encode(), dtype=np.uint8)
        lt, nxt = b[:-1] == ord("<"), b[1:]
        letter = ((nxt | 0x20) >= ord("a")) & ((nxt | 0x20) <= ord("z")) | (nxt == ord("_"))
        opens = lt & letter
        closes = (lt & (nxt == ord("/"))) | ((b[:-1] == ord("/")) & (nxt == ord(">")))
        step = opens.astype(np.int8) - closes
        nz = np.flatnonzero(step)
        if nz.size and int(np.max(np.cumsum(step[nz], dtype=np.int32))) > MAX_NESTING_DEPTH:
            raise ModelFileError(f"XML nested deeper than {MAX_NESTING_DEPTH} elements")
