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


@dataclass(frozen=True)
class Symmetry:
    """A rigid map of a board's point set onto itself (a rotation about the grid centre, possibly after a mirror).

    ``perm`` (N,): point ``i`` goes to point ``perm[i]``; for centres ``c`` (N, 2) in some valid board order,
    ``c[perm]`` is another valid order (the same physical board, relabelled). ``det``: +1 for a rotation, -1 for a
    reflection. ``label``: ``rot0``, ``rot90``, ``rot180``, ``rot270`` (quarter turns in the board frame), with a
    ``mirror+`` prefix (``mirror`` alone for x -> -x) for reflections."""

    label: str
    perm: np.ndarray
    det: int


@dataclass(frozen=True)
class Board:
    """A planar target. ``pitch_mm`` and ``diameter_mm`` in mm (``diameter_mm`` is 0 for a checkerboard);
    ``margin_mm``: white border around the outermost features (defaults to one pitch)."""

    rows: int
    cols: int
    pitch_mm: float
    diameter_mm: float = 0.0
    layout: Layout = "symmetric"
    margin_mm: float | None = None

    def __post_init__(self) -> None:
        if self.layout not in LAYOUTS:
            raise InputError(f"unknown layout {self.layout!r}; expected one of {', '.join(LAYOUTS)}")
        for name in ("rows", "cols"):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                raise InputError(f"board {name} must be an integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        if not (2 <= self.rows <= MAX_GRID_SIDE and 2 <= self.cols <= MAX_GRID_SIDE):
            raise InputError(f"a grid needs at least 2x2 points (and at most {MAX_GRID_SIDE} per side), got "
                             f"{self.rows}x{self.cols}")
        for name in ("pitch_mm", "diameter_mm") + (("margin_mm",) if self.margin_mm is not None else ()):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.floating, np.integer)) \
                    or not np.isfinite(v):
                raise InputError(f"board {name} must be a finite number (mm), got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.pitch_mm <= 0:
            raise InputError(f"pitch must be positive, got {self.pitch_mm} mm")
        if not MIN_LENGTH_MM <= self.pitch_mm <= MAX_LENGTH_MM:
            raise InputError(f"pitch must lie between {MIN_LENGTH_MM:g} and {MAX_LENGTH_MM:g} mm, got "
                             f"{self.pitch_mm:g} mm (a unit mix-up? lengths take mm, cm, m or in)")
        if self.layout != "checkerboard":
            spacing = self.pitch_mm * (2 ** 0.5 if self.layout == "asymmetric" else 1.0)
            if not 0 < self.diameter_mm < spacing:
                raise InputError(
                    f"dot diameter {self.diameter_mm} mm must be positive and below the nearest-neighbour "
                    f"spacing {spacing:.3g} mm (dots would touch)")

    @property
    def n_points(self) -> int:
        return self.rows * self.cols

    @property
    def pattern_size(self) -> tuple[int, int]:
        """OpenCV's ``patternSize``: (points per row, rows)."""
        return (self.cols, self.rows)

    @property
    def radius_mm(self) -> float:
        return 0.5 * self.diameter_mm

    @property
    def margin(self) -> float:
        return self.pitch_mm if self.margin_mm is None else float(self.margin_mm)

    def object_points(self) -> np.ndarray:
        """(rows*cols, 3) float64 board coordinates in mm, OpenCV's order."""
        i, j = np.meshgrid(np.arange(self.rows), np.arange(self.cols), indexing="ij")
        i = i.ravel().astype(np.float64)
        j = j.ravel().astype(np.float64)
        if self.layout == "asymmetric":
            x = (2.0 * j + (i % 2)) * self.pitch_mm
        else:
            x = j * self.pitch_mm
        return np.stack([x, i * self.pitch_mm, np.zeros_like(x)], axis=-1)

    def feature_extent_mm(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the printed features (dot rims or squares), mm."""
        p = self.object_points()
        if self.layout == "checkerboard":
            return (-self.pitch_mm, -self.pitch_mm, self.cols * self.pitch_mm, self.rows * self.pitch_mm)
        r = self.radius_mm
        return (p[:, 0].min() - r, p[:, 1].min() - r, p[:, 0].max() + r, p[:, 1].max() + r)

    def extent_mm(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the white board including its margin, mm."""
        x0, y0, x1, y1 = self.feature_extent_mm()
        m = self.margin
        return (x0 - m, y0 - m, x1 + m, y1 + m)

    def centre_mm(self) -> np.ndarray:
        """(3,) centre of the point grid in board coordinates."""
        return self.object_points().mean(axis=0)

    def symmetries(self, *, reflections: bool = True) -> tuple[Symmetry, ...]:
        """Every rigid map of the point set onto itself (:class:`Symmetry`), identity first; reflections only when
        asked. A symmetric grid has 2 rotations (4 when square), an asymmetric one 2 with an even number of rows
        and only the identity otherwise; each rotation has its mirrored twin."""
        return tuple(s for s in _symmetries(self) if reflections or s.det > 0)

    def to_dict(self) -> dict[str, Any]:
        """The ``board`` block of truth.json / detections JSON."""
        d = asdict(self)
        d["margin_mm"] = self.margin
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Board":
        return cls(int(d["rows"]), int(d["cols"]), float(d["pitch_mm"]), float(d.get("diameter_mm", 0.0)),
                   d.get("layout", "symmetric"), d.get("margin_mm"))

    def signed_distance_mm(self, xy: np.ndarray) -> np.ndarray:
        """Signed distance (mm) from board points ``xy`` (..., 2) to the nearest feature edge; negative on dark
        (inside a dot / on a black square). Exact for dots; the Chebyshev-style distance to the nearest square
        edge for a checkerboard (what the renderer needs to find edge pixels)."""
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
            if np.all(dist[np.arange(len(d)), j] < 1e-6 * board.pitch_mm) and len(np.unique(j)) == len(d):
                label = f"rot{90 * quarter}" if not mirror else ("mirror" if quarter == 0 else
                                                                 f"mirror+rot{90 * quarter}")
                if not any(np.array_equal(j, s.perm) for s in out):
                    j.setflags(write=False)
                    out.append(Symmetry(label, j, -1 if mirror else 1))
    return tuple(out)
