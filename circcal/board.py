"""Calibration targets: symmetric and asymmetric circle grids (OpenCV layouts) and checkerboards.

Conventions
-----------
* Board frame: x along a row (to the right in the board image), y down the rows, z = 0 on the board, unit mm.
* ``rows x cols`` counts *points*: ``cols`` points per row, ``rows`` rows; OpenCV's ``patternSize`` is
  ``(cols, rows)``. Object points come in OpenCV's order, row-major from the first row.
* Symmetric grid: point (i, j) at ``(j*pitch, i*pitch, 0)``.
* Asymmetric grid (OpenCV's ``acircles``, e.g. 4x11 = 11 rows of 4): point (i, j) at
  ``((2j + i % 2) * pitch, i * pitch, 0)``; ``pitch`` is OpenCV's ``squareSize``, half the spacing within a row.
* Checkerboard: ``rows x cols`` inner corners at ``(j*pitch, i*pitch, 0)``; squares of side ``pitch``; the square
  whose top-left corner is ``(a*pitch, b*pitch)`` for a, b in [-1, cols-1] x [-1, rows-1] is black when ``a + b`` is even.
* Lattice coordinates: the object points divided by the pitch, integers (``Board.lattice_coords``): ``(j, i)`` on a
  symmetric grid, ``(2j + i % 2, i)`` on an asymmetric one (only the nodes with ``x + y`` even are dots).

Marker boards
-------------
A circle grid may carry *markers*: dots of a larger diameter (``marker_diameter_mm``) at the points listed in
``markers`` (indices in OpenCV's order). They fix the board's orientation and origin, so a symmetric grid loses its
rotational ambiguity, every point keeps its ID across views, and a view that shows only part of the board can still
be labelled (:func:`placements`). The designs and circcal's marker pattern: :mod:`circcal.markers`.
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np

from circcal.errors import InputError

Layout = Literal["symmetric", "asymmetric", "checkerboard"]
LAYOUTS: tuple[str, ...] = ("symmetric", "asymmetric", "checkerboard")
#: Lengths a printed board can have (mm): finer than 1 um is no print, larger than 100 m no calibration target; a
#: value outside is a unit mix-up, and (1e-300 mm, say) would underflow the detector's area limits.
MIN_LENGTH_MM = 1e-3
MAX_LENGTH_MM = 1e5
#: Points per board side at most (a 1000 x 1000 grid is 10^6 dots; more is a typo).
MAX_GRID_SIDE = 1000
#: Printed dots must keep this share of the nearest-dot spacing free between their rims (markers included): a
#: narrower gap merges neighbouring dots under blur or a coarse segmentation.
MIN_GAP_SHARE = 0.15


@dataclass(frozen=True)
class Symmetry:
    """A rigid map of a board's point set onto itself (a rotation about the grid centre, possibly after a mirror).

    Attributes
    ----------
    label : str
        ``rot0``, ``rot90``, ``rot180``, ``rot270`` (quarter turns in the board frame), with a ``mirror+`` prefix
        (``mirror`` alone for x -> -x) for reflections.
    perm : ndarray of int, shape (N,)
        Point ``i`` goes to point ``perm[i]``; for centres ``c`` (N, 2) in some valid board order, ``c[perm]`` is
        another valid order (the same physical board, relabelled).
    det : int
        +1 for a rotation, -1 for a reflection.
    """

    label: str
    perm: np.ndarray
    det: int


@functools.lru_cache(maxsize=64)
def _object_points(rows: int, cols: int, pitch_mm: float, staggered: bool) -> np.ndarray:
    """:meth:`Board.object_points`, computed once per layout (the detector asks for them several times per image);
    read-only, so that a caller cannot change the cached copy."""
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    i = i.ravel().astype(np.float64)
    j = j.ravel().astype(np.float64)
    x = (2.0 * j + (i % 2)) * pitch_mm if staggered else j * pitch_mm
    out = np.stack([x, i * pitch_mm, np.zeros_like(x)], axis=-1)
    out.flags.writeable = False
    return out


@dataclass(frozen=True)
class Board:
    """A planar target.

    Parameters
    ----------
    rows, cols : int
        Points down and across.
    pitch_mm : float
        mm.
    diameter_mm : float
        mm; 0 for a checkerboard.
    layout : {"symmetric", "asymmetric", "checkerboard"}
    margin_mm : float or None
        White border around the outermost features, mm (None: one pitch).
    markers : tuple of int
        Indices (OpenCV's order) of the dots printed with the larger diameter ``marker_diameter_mm`` (see the module
        docstring; empty for a board without markers).
    marker_diameter_mm : float
        mm; 0 without markers.

    Raises
    ------
    InputError
        A field out of range or inconsistent (an unknown layout, a non-positive pitch, markers on a checkerboard,
        repeated or out-of-range marker indices, ...).

    Examples
    --------
    >>> Board(4, 5, 10.0, 5.0).object_points().shape
    (20, 3)
    """

    rows: int
    cols: int
    pitch_mm: float
    diameter_mm: float = 0.0
    layout: Layout = "symmetric"
    margin_mm: float | None = None
    markers: tuple[int, ...] = ()
    marker_diameter_mm: float = 0.0

    def __post_init__(self) -> None:
        if self.layout not in LAYOUTS:
            raise InputError(f"unknown layout {self.layout!r}; expected one of {', '.join(LAYOUTS)}")
        for name in ("rows", "cols"):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                raise InputError(f"board {name} must be an integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        if not (2 <= self.rows <= MAX_GRID_SIDE and 2 <= self.cols <= MAX_GRID_SIDE):
            raise InputError(
                f"a grid needs at least 2x2 points (and at most {MAX_GRID_SIDE} per side), got {self.rows}x{self.cols}"
            )
        for name in ("pitch_mm", "diameter_mm") + (("margin_mm",) if self.margin_mm is not None else ()):
            v = getattr(self, name)
            if (
                isinstance(v, (bool, np.bool_))
                or not isinstance(v, (int, float, np.floating, np.integer))
                or not np.isfinite(v)
            ):
                raise InputError(f"board {name} must be a finite number (mm), got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.pitch_mm <= 0:
            raise InputError(f"pitch must be positive, got {self.pitch_mm} mm")
        if not MIN_LENGTH_MM <= self.pitch_mm <= MAX_LENGTH_MM:
            raise InputError(
                f"pitch must lie between {MIN_LENGTH_MM:g} and {MAX_LENGTH_MM:g} mm, got "
                f"{self.pitch_mm:g} mm (a unit mix-up? lengths take mm, cm, m or in)"
            )
        if self.layout != "checkerboard":
            spacing = self.pitch_mm * (2**0.5 if self.layout == "asymmetric" else 1.0)
            if not 0 < self.diameter_mm < spacing:
                raise InputError(
                    f"dot diameter {self.diameter_mm} mm must be positive and below the nearest-neighbour "
                    f"spacing {spacing:.3g} mm (dots would touch)"
                )
        self._check_markers()

    def _check_markers(self) -> None:
        """Markers: distinct integer indices of this board's points, on a circle grid, with a diameter above the
        dots' that leaves :data:`MIN_GAP_SHARE` of the spacing free to the nearest dot (and marker)."""
        m = self.markers
        if isinstance(m, (str, bytes)) or not hasattr(m, "__iter__"):
            raise InputError(f"board markers must be a list of point indices, got {m!r}")
        idx = []
        for v in m:
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                raise InputError(f"board marker indices must be integers, got {v!r}")
            idx.append(int(v))
        object.__setattr__(self, "markers", tuple(sorted(set(idx))))
        v = self.marker_diameter_mm
        if (
            isinstance(v, (bool, np.bool_))
            or not isinstance(v, (int, float, np.floating, np.integer))
            or not np.isfinite(v)
        ):
            raise InputError(f"board marker_diameter_mm must be a finite number (mm), got {v!r}")
        object.__setattr__(self, "marker_diameter_mm", float(v))
        if not self.markers:
            if self.marker_diameter_mm != 0.0:
                raise InputError("a marker diameter without markers (give the marker points, or no diameter)")
            return
        if self.layout == "checkerboard":
            raise InputError("a checkerboard has no dots to make markers of")
        if len(idx) != len(self.markers):
            raise InputError(f"board markers repeat a point: {sorted(idx)}")
        bad = [i for i in self.markers if not 0 <= i < self.n_points]
        if bad:
            raise InputError(
                f"board markers {bad} are not points of a {self.rows}x{self.cols} grid (indices 0..{self.n_points - 1})"
            )
        spacing = self.spacing_mm
        if not self.diameter_mm < self.marker_diameter_mm:
            raise InputError(
                f"marker diameter {self.marker_diameter_mm:g} mm must exceed the dot diameter {self.diameter_mm:g} mm"
            )
        gap = spacing - 0.5 * (self.marker_diameter_mm + self.diameter_mm)
        if gap < MIN_GAP_SHARE * spacing:
            raise InputError(
                f"marker diameter {self.marker_diameter_mm:g} mm leaves {gap:.3g} mm to the nearest "
                f"dot, less than {MIN_GAP_SHARE:.0%} of the spacing {spacing:.3g} mm (dots would merge)"
            )
        if self.marker_diameter_mm > (1.0 - MIN_GAP_SHARE) * spacing and _adjacent_markers(self):
            raise InputError(
                f"two markers of {self.marker_diameter_mm:g} mm are neighbours at {spacing:.3g} mm "
                "spacing: they would touch"
            )

    @property
    def n_points(self) -> int:
        """rows * cols."""
        return self.rows * self.cols

    @property
    def pattern_size(self) -> tuple[int, int]:
        """OpenCV's ``patternSize``: (points per row, rows)."""
        return (self.cols, self.rows)

    @property
    def radius_mm(self) -> float:
        """Half the dot diameter, mm."""
        return 0.5 * self.diameter_mm

    @property
    def spacing_mm(self) -> float:
        """Distance between nearest dots (mm): the pitch, or sqrt(2) pitches on an asymmetric grid."""
        return self.pitch_mm * (2**0.5 if self.layout == "asymmetric" else 1.0)

    @property
    def has_markers(self) -> bool:
        """Whether any dot is a marker."""
        return bool(self.markers)

    def is_marker(self) -> np.ndarray:
        """Which points are markers.

        Returns
        -------
        ndarray of bool, shape (N,)
            OpenCV's order.
        """
        out = np.zeros(self.n_points, bool)
        out[list(self.markers)] = True
        return out

    def radii_mm(self) -> np.ndarray:
        """The printed radius of every dot: markers have ``marker_diameter_mm / 2``.

        Returns
        -------
        ndarray, shape (N,)
            mm.
        """
        r = np.full(self.n_points, self.radius_mm)
        r[list(self.markers)] = 0.5 * self.marker_diameter_mm
        return r

    @property
    def marker_scale(self) -> float:
        """Marker diameter over dot diameter (1 without markers)."""
        return self.marker_diameter_mm / self.diameter_mm if self.markers else 1.0

    def lattice_coords(self) -> np.ndarray:
        """Integer lattice coordinates of the points (the object points' x, y over the pitch).

        ``(j, i)`` on a symmetric grid, ``(2j + i % 2, i)`` on an asymmetric one; checkerboard corners as a symmetric
        grid.

        Returns
        -------
        ndarray of int64, shape (N, 2)
        """
        return np.rint(self.object_points()[:, :2] / self.pitch_mm).astype(np.int64)

    @property
    def margin(self) -> float:
        """The white border around the outermost features, mm (``margin_mm``, or one pitch)."""
        return self.pitch_mm if self.margin_mm is None else float(self.margin_mm)

    def object_points(self) -> np.ndarray:
        """The board coordinates of the points, OpenCV's order (a fresh array the caller may change).

        Returns
        -------
        ndarray of float64, shape (rows*cols, 3)
            mm (z = 0).
        """
        return _object_points(self.rows, self.cols, float(self.pitch_mm), self.layout == "asymmetric").copy()

    def feature_extent_mm(self) -> tuple[float, float, float, float]:
        """The bounding box of the printed features (dot rims or squares, markers included).

        Returns
        -------
        tuple of float
            (xmin, ymin, xmax, ymax), mm.
        """
        p = self.object_points()
        if self.layout == "checkerboard":
            return (-self.pitch_mm, -self.pitch_mm, self.cols * self.pitch_mm, self.rows * self.pitch_mm)
        r = self.radii_mm()
        return (
            float((p[:, 0] - r).min()),
            float((p[:, 1] - r).min()),
            float((p[:, 0] + r).max()),
            float((p[:, 1] + r).max()),
        )

    def extent_mm(self) -> tuple[float, float, float, float]:
        """The bounding box of the white board including its margin.

        Returns
        -------
        tuple of float
            (xmin, ymin, xmax, ymax), mm.
        """
        x0, y0, x1, y1 = self.feature_extent_mm()
        m = self.margin
        return (x0 - m, y0 - m, x1 + m, y1 + m)

    def centre_mm(self) -> np.ndarray:
        """The centre of the point grid in board coordinates.

        Returns
        -------
        ndarray, shape (3,)
            mm.
        """
        return self.object_points().mean(axis=0)

    def symmetries(self, *, reflections: bool = True) -> tuple[Symmetry, ...]:
        """Every rigid map of the point set onto itself, identity first; reflections only when asked.

        A symmetric grid has 2 rotations (4 when square), an asymmetric one 2 with an even number of rows and only the
        identity otherwise; each rotation has its mirrored twin. Markers must map onto markers (a marker board usually
        has the identity alone).

        Parameters
        ----------
        reflections : bool

        Returns
        -------
        tuple of Symmetry

        Examples
        --------
        >>> [s.label for s in Board(4, 5, 10.0, 5.0).symmetries(reflections=False)]
        ['rot0', 'rot180']
        """
        return tuple(s for s in _symmetries(self) if reflections or s.det > 0)

    def to_dict(self) -> dict[str, Any]:
        """The ``board`` block of truth.json, model.json and detections JSON.

        Returns
        -------
        dict
            rows, cols, pitch_mm, diameter_mm, layout, margin_mm, markers (point indices, OpenCV's order; [] for none),
            marker_diameter_mm (0 for none).
        """
        d = asdict(self)
        d["margin_mm"] = self.margin
        d["markers"] = list(self.markers)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Board:
        """The board of a ``board`` block (:meth:`to_dict`); the marker fields may be absent (no markers).

        Parameters
        ----------
        d : dict

        Returns
        -------
        Board

        Raises
        ------
        InputError
            A value the board refuses (see the class).
        KeyError, TypeError, ValueError
            ``rows``, ``cols`` or ``pitch_mm`` missing or not numbers (callers reading a file check the block first).
        """
        return cls(
            int(d["rows"]),
            int(d["cols"]),
            float(d["pitch_mm"]),
            float(d.get("diameter_mm", 0.0)),
            d.get("layout", "symmetric"),
            d.get("margin_mm"),
            tuple(d.get("markers") or ()),
            float(d.get("marker_diameter_mm") or 0.0),
        )

    def signed_distance_mm(self, xy: np.ndarray) -> np.ndarray:
        """Signed distance from board points to the nearest feature edge; negative on dark (inside a dot / on a black
        square).

        Exact for dots; the Chebyshev-style distance to the nearest square edge for a checkerboard (what the renderer
        needs to find edge pixels).

        Parameters
        ----------
        xy : ndarray, shape (..., 2)
            Board points, mm.

        Returns
        -------
        ndarray, shape (...)
            mm.
        """
        xy = np.asarray(xy, dtype=np.float64)
        x, y = xy[..., 0], xy[..., 1]
        s = self.pitch_mm
        if self.layout == "checkerboard":
            a = np.floor(x / s)
            b = np.floor(y / s)
            inside = (a >= -1) & (a <= self.cols - 1) & (b >= -1) & (b <= self.rows - 1)
            dark = inside & (((a + b) % 2) == 0)
            # distance to the nearest grid line; outside the checker area, distance to its boundary
            dx = np.abs(x - s * np.round(x / s))
            dy = np.abs(y - s * np.round(y / s))
            x0, y0, x1, y1 = self.feature_extent_mm()
            out = np.maximum.reduce([x0 - x, x - x1, y0 - y, y - y1])
            d = np.where(inside, np.minimum(dx, dy), np.maximum(out, 0.0))
            return np.where(dark, -d, d)
        r = self.radius_mm
        best = np.full(x.shape, np.inf)
        i_near = np.round(y / s)
        if self.markers:  # dots of two sizes: the nearest rim may belong to a neighbouring column's marker
            radii = self.radii_mm()
            for di in (-1.0, 0.0, 1.0):
                i = np.clip(i_near + di, 0, self.rows - 1)
                odd = i % 2 if self.layout == "asymmetric" else 0.0
                step = 2.0 if self.layout == "asymmetric" else 1.0
                j0 = np.round((x / s - odd) / step)
                for dj in (-1.0, 0.0, 1.0):
                    j = np.clip(j0 + dj, 0, self.cols - 1)
                    k = (i * self.cols + j).astype(np.int64)
                    best = np.minimum(best, np.hypot(x - (step * j + odd) * s, y - i * s) - radii[k])
            return best
        for di in (-1.0, 0.0, 1.0):
            i = np.clip(i_near + di, 0, self.rows - 1)
            if self.layout == "asymmetric":
                j = np.clip(np.round((x / s - (i % 2)) / 2.0), 0, self.cols - 1)
                cxm = (2.0 * j + (i % 2)) * s
            else:
                j = np.clip(np.round(x / s), 0, self.cols - 1)
                cxm = j * s
            best = np.minimum(best, np.hypot(x - cxm, y - i * s))
        return best - r


@functools.lru_cache(maxsize=64)
def _symmetries(board: Board) -> tuple[Symmetry, ...]:
    d = board.object_points()[:, :2]
    d = d - d.mean(axis=0)
    out: list[Symmetry] = []
    for mirror in (False, True):
        for quarter in range(4):
            t = d * [-1.0, 1.0] if mirror else d.copy()
            for _ in range(quarter):
                t = np.column_stack([-t[:, 1], t[:, 0]])
            dist = np.linalg.norm(t[:, None, :] - d[None, :, :], axis=-1)
            j = np.argmin(dist, axis=1)
            one_to_one = np.bincount(j, minlength=len(d)).max() == 1  # (np.unique would import numpy.ma: 9 ms)
            if (
                np.all(dist[np.arange(len(d)), j] < 1e-6 * board.pitch_mm)
                and one_to_one
                and np.array_equal(board.is_marker()[j], board.is_marker())
            ):  # markers onto markers
                label = (
                    f"rot{90 * quarter}" if not mirror else ("mirror" if quarter == 0 else f"mirror+rot{90 * quarter}")
                )
                if not any(np.array_equal(j, s.perm) for s in out):
                    j.setflags(write=False)
                    out.append(Symmetry(label, j, -1 if mirror else 1))
    return tuple(out)


#: The four rotations of the integer lattice (quarter turns, x right and y down as in the board frame): rotation
#: ``q`` maps lattice coordinates ``xy`` to ``xy @ LATTICE_ROTATIONS[q].T``.
LATTICE_ROTATIONS: tuple[np.ndarray, ...] = tuple(
    np.linalg.matrix_power(np.array([[0, -1], [1, 0]], np.int64), q) for q in range(4)
)


@dataclass(frozen=True)
class Placement:
    """One way to lay observed lattice points onto a board.

    Attributes
    ----------
    quarter : int
        The rotation: an index into :data:`LATTICE_ROTATIONS`.
    shift : tuple of int, (2,)
        The translation, lattice units.
    points : ndarray of int, shape (K,)
        The board point of each observed point.
    mismatches : int
        Observed marker flags that disagree with the board's.
    """

    quarter: int
    shift: tuple[int, int]
    points: np.ndarray
    mismatches: int


def placements(
    board: Board, xy: np.ndarray, flags: np.ndarray | None = None, *, max_mismatches: int = 0
) -> list[Placement]:
    """Every placement of observed lattice points onto ``board``'s points by a rotation and an integer translation.

    No reflection: ``xy`` must have the board frame's handedness. Kept: those that put every observed point on a
    board point and have at most ``max_mismatches`` marker disagreements. Cost: O(translations x K) per rotation,
    vectorised (translations: the ways the observed bounding box fits in the board's).

    Parameters
    ----------
    board : Board
    xy : ndarray of int, shape (K, 2)
        The observed lattice points.
    flags : ndarray of int, shape (K,), or None
        1 for a dot seen as a marker, 0 for a dot seen as a plain dot, -1 for unknown (not compared); ``None``: all
        unknown.
    max_mismatches : int

    Returns
    -------
    list of Placement
    """
    xy = np.asarray(xy, np.int64).reshape(-1, 2)
    K = len(xy)
    flags = np.full(K, -1, np.int64) if flags is None else np.asarray(flags, np.int64).reshape(K)
    occ, mk, origin = _lattice_grid(board)
    Hh, Ww = occ.shape
    known = flags >= 0
    out: list[Placement] = []
    for q, R in enumerate(LATTICE_ROTATIONS):
        G = xy @ R.T - origin
        lo = -G.min(axis=0)
        hi = np.array([Ww - 1, Hh - 1]) - G.max(axis=0)
        if np.any(hi < lo):
            continue
        tx, ty = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
        T = np.stack([tx.ravel(), ty.ravel()], -1)
        for c in range(0, len(T), max(1, (1 << 20) // max(K, 1))):  # bounded memory
            Tc = T[c : c + (1 << 20) // max(K, 1)]
            P = G[None] + Tc[:, None]
            idx = occ[P[..., 1], P[..., 0]]
            ok = np.all(idx >= 0, axis=1)
            if not np.any(ok):
                continue
            miss = np.sum(known[None] & (mk[P[..., 1], P[..., 0]].astype(np.int64) != flags[None]), axis=1)
            for t in np.nonzero(ok & (miss <= max_mismatches))[0]:
                sh = Tc[t] + origin
                out.append(Placement(q, (int(sh[0]), int(sh[1])), idx[t].copy(), int(miss[t])))
    return out


@functools.lru_cache(maxsize=64)
def _lattice_grid(board: Board) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(occupancy (H, W) int: board point index or -1, markers (H, W) bool, origin (2,) int) over the bounding box
    of the board's lattice coordinates."""
    L = board.lattice_coords()
    origin = L.min(axis=0)
    W, H = L.max(axis=0) - origin + 1
    occ = np.full((H, W), -1, np.int64)
    occ[L[:, 1] - origin[1], L[:, 0] - origin[0]] = np.arange(len(L))
    mk = np.zeros((H, W), bool)
    mk[L[:, 1] - origin[1], L[:, 0] - origin[0]] = board.is_marker()
    occ.setflags(write=False)
    mk.setflags(write=False)
    return occ, mk, origin


def _adjacent_markers(board: Board) -> bool:
    """Whether two markers are nearest neighbours on the board."""
    L = board.lattice_coords()[list(board.markers)].astype(np.float64)
    if len(L) < 2:
        return False
    d = np.linalg.norm(L[:, None] - L[None], axis=-1) * board.pitch_mm
    np.fill_diagonal(d, np.inf)
    return bool(np.any(d < 1.01 * board.spacing_mm))
