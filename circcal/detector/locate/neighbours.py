"""Exact nearest-neighbour queries among the candidate dots (:class:`NeighbourGrid`): what the lattice search
(:mod:`circcal.detector.locate.lattice`) needs of a k-d tree, from a uniform grid of cells, compiled; and the clusters of
candidates linked to their near neighbours (:func:`linked_clusters`), where the search for small dots looks again.

scipy's ``cKDTree`` (and ``scipy.sparse.csgraph`` for the clusters) answered these before; importing
``scipy.spatial`` costs a process 0.2-0.35 s (it pulls in scipy.sparse and scipy.linalg), more than the whole
detection of an image, and every image of an asymmetric board needed it. Pixel convention: OpenCV's; points are
``(x, y)``.
"""

from __future__ import annotations

import math

import numpy as np

from circcal.detector.kernels.jit import njit

__all__ = ["NeighbourGrid", "linked_clusters"]

POINTS_PER_CELL = 2.0
"""The grid's cells hold about this many points on average (square cells over the points' bounding box)."""


class NeighbourGrid:
    """The ``k`` nearest of fixed ``points`` (M, 2) px to any query points, exactly (Euclidean distance; equal
    distances in the order of the points' indices), as ``scipy.spatial.cKDTree(points).query(x, k)`` gives them:
    ``(dist, index)`` of shape (Q,) for ``k`` 1, (Q, k) otherwise, sorted by distance; where fewer than ``k`` points
    exist, or for a query with a NaN or infinite coordinate, the distance is ``inf`` and the index ``M``."""

    def __init__(self, points: np.ndarray):
        self.points = np.ascontiguousarray(points, np.float64).reshape(-1, 2)
        M = len(self.points)
        lo = self.points.min(axis=0) if M else np.zeros(2)
        hi = self.points.max(axis=0) if M else np.zeros(2)
        span = np.maximum(hi - lo, 1e-9)
        h = math.sqrt(float(span[0] * span[1]) * POINTS_PER_CELL / max(M, 1))
        h = max(h, float(max(span)) / max(M, 1), 1e-9)  # (points on a line: cells along it)
        self.origin = lo
        self.cell = h
        self.shape = (int(span[0] // h) + 1, int(span[1] // h) + 1)  # (nx, ny)
        self.start = np.zeros(self.shape[0] * self.shape[1] + 1, np.int64)
        self.items = np.empty(M, np.int64)
        _build(self.points, float(lo[0]), float(lo[1]), h, self.shape[0], self.shape[1], self.start, self.items)

    def query(self, x: np.ndarray, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """``(dist, index)`` of the ``k`` nearest points to each row of ``x`` (class docstring).

        Parameters
        ----------
        x : numpy.ndarray
            (Q, 2) float query points, px.
        k : int, optional
            How many nearest points.

        Returns
        -------
        dist : numpy.ndarray
            (Q,) float for ``k`` 1, (Q, k) otherwise: distances, px, sorted; ``inf`` where fewer than ``k`` points exist
            or for a query with a NaN or infinite coordinate.
        index : numpy.ndarray
            int64, same shape: the points' indices (``M`` where the distance is ``inf``).

        Examples
        --------
        >>> grid = NeighbourGrid(np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0]]))
        >>> dist, index = grid.query(np.array([[1.0, 0.0]]), k=2)
        >>> dist.tolist(), index.tolist()
        ([[1.0, 2.0]], [[0, 1]])
        """
        q = np.ascontiguousarray(x, np.float64).reshape(-1, 2)
        dist = np.empty((len(q), k))
        idx = np.empty((len(q), k), np.int64)
        _query(
            self.points,
            float(self.origin[0]),
            float(self.origin[1]),
            self.cell,
            self.shape[0],
            self.shape[1],
            self.start,
            self.items,
            q,
            int(k),
            dist,
            idx,
        )
        return (dist[:, 0], idx[:, 0]) if k == 1 else (dist, idx)


def linked_clusters(points: np.ndarray, link: float) -> np.ndarray:
    """The cluster label of each of ``points``: points linked to their near neighbours, connected.

    Two points are linked when their distance is below ``link`` times the smaller of their nearest-neighbour
    distances, and a cluster is what links connect. Each point's linked partners come from its nearest neighbours,
    ``k`` doubled until the ``k``-th lies beyond its reach (no radius common to all: one isolated point does not make
    every point search the image).

    Parameters
    ----------
    points : numpy.ndarray
        (M, 2) float points, px.
    link : float
        The link's reach, in nearest-neighbour distances.

    Returns
    -------
    numpy.ndarray
        (M,) int64 labels, counting from 0 in the order of each cluster's lowest point index
        (``scipy.sparse.csgraph.connected_components``' numbering).

    Examples
    --------
    >>> linked_clusters(np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0], [11.0, 0.0]]), 1.5).tolist()
    [0, 0, 1, 1]
    """
    P = np.ascontiguousarray(points, np.float64).reshape(-1, 2)
    M = len(P)
    if M < 2:
        return np.arange(M, dtype=np.int64)
    grid = NeighbourGrid(P)
    nn = grid.query(P, k=2)[0][:, 1]
    reach = link * nn
    firsts, seconds = [], []
    todo = np.arange(M)
    k = min(M, 16)
    while len(todo):
        d, idx = grid.query(P[todo], k=k)
        done = (d[:, -1] >= reach[todo]) | (k == M)
        i = np.repeat(todo[done], k)
        j = idx[done].ravel()
        # partners beyond the point itself, each pair once (i < j), within both points' reach; the pair's distance
        # as numpy computes it (the kernel's differs in the last bit at most)
        near = (j > i) & (d[done].ravel() <= reach[i] * (1.0 + 1e-12))
        i, j = i[near], j[near]
        ok = np.linalg.norm(P[i] - P[j], axis=1) < link * np.minimum(nn[i], nn[j])
        firsts.append(i[ok])
        seconds.append(j[ok])
        todo = todo[~done]
        k = min(M, 2 * k)
    roots = np.arange(M, dtype=np.int64)
    _union(np.concatenate(firsts), np.concatenate(seconds), roots)
    return np.unique(roots, return_inverse=True)[1].astype(np.int64)


@njit(cache=True, nogil=True)
def _union(a, b, roots):
    """Joins the sets of ``a[e]`` and ``b[e]`` (E,) int64 for each link ``e`` in the union-find forest ``roots``
    (M,) int64 (each point's parent; a root is its own), then points every entry at its set's root: the set's
    lowest index."""
    for e in range(len(a)):
        ra, rb = _root(roots, a[e]), _root(roots, b[e])
        if ra < rb:
            roots[rb] = ra
        elif rb < ra:
            roots[ra] = rb
    for i in range(len(roots)):
        roots[i] = _root(roots, i)


@njit(cache=True, nogil=True, inline="always")
def _root(roots, i):
    """The root of ``i`` in the forest ``roots``, halving the path on the way."""
    while roots[i] != i:
        roots[i] = roots[roots[i]]
        i = roots[i]
    return i


@njit(cache=True, nogil=True, inline="always")
def _cell_of(v, v0, h, n):
    """The cell index (0 .. n - 1) of coordinate ``v`` on an axis of ``n`` cells of width ``h`` from ``v0``."""
    c = math.floor((v - v0) / h)
    return min(max(c, 0), n - 1)


@njit(cache=True, nogil=True)
def _build(points, x0, y0, h, nx, ny, start, items):
    """Counting sort of ``points`` (M, 2) into the ``nx`` x ``ny`` cells: the points of cell ``c`` (``cx + nx cy``)
    are ``items[start[c]:start[c + 1]]``, in the order of their indices."""
    M = len(points)
    cell = np.empty(M, np.int64)
    for i in range(M):
        cell[i] = _cell_of(points[i, 0], x0, h, nx) + nx * _cell_of(points[i, 1], y0, h, ny)
        start[cell[i] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    for i in range(M):
        items[fill[cell[i]]] = i
        fill[cell[i]] += 1


@njit(cache=True, nogil=True, inline="always")
def _visit(points, start, items, c, qx, qy, best_d, best_i):
    """Offers the points of cell ``c`` to the sorted ``best_d``, ``best_i`` (k,) (by distance, then index)."""
    k = len(best_d)
    for s in range(start[c], start[c + 1]):
        i = items[s]
        dx, dy = points[i, 0] - qx, points[i, 1] - qy
        d = math.sqrt(dx * dx + dy * dy)
        if d < best_d[k - 1] or (d == best_d[k - 1] and i < best_i[k - 1]):
            t = k - 1
            while t > 0 and (best_d[t - 1] > d or (best_d[t - 1] == d and best_i[t - 1] > i)):
                best_d[t] = best_d[t - 1]
                best_i[t] = best_i[t - 1]
                t -= 1
            best_d[t] = d
            best_i[t] = i


@njit(cache=True, nogil=True)
def _query(points, x0, y0, h, nx, ny, start, items, q, k, dist, idx):
    """Writes the ``k`` nearest points to each query ``q`` (Q, 2) into ``dist``, ``idx`` (Q, k) (the class's
    rules). The cells are searched in square rings around the query's cell (clamped to the grid); the search stops
    once the k-th best distance is below the distance from the query to every cell not yet searched (only the
    sides of the square that have not reached the grid's edge have cells beyond them), or no cell is left."""
    M = len(points)
    best_d = np.empty(k)
    best_i = np.empty(k, np.int64)
    for j in range(len(q)):
        qx, qy = q[j, 0], q[j, 1]
        for t in range(k):
            best_d[t] = np.inf
            best_i[t] = M
        if np.isfinite(qx) and np.isfinite(qy) and M > 0:
            cx, cy = _cell_of(qx, x0, h, nx), _cell_of(qy, y0, h, ny)
            r = 0
            while True:
                for gy in range(max(cy - r, 0), min(cy + r, ny - 1) + 1):
                    if gy == cy - r or gy == cy + r:  # the ring's top and bottom rows: all their cells
                        for gx in range(max(cx - r, 0), min(cx + r, nx - 1) + 1):
                            _visit(points, start, items, gx + nx * gy, qx, qy, best_d, best_i)
                    else:  # the rows between: the ring's two end cells
                        if cx - r >= 0:
                            _visit(points, start, items, cx - r + nx * gy, qx, qy, best_d, best_i)
                        if r > 0 and cx + r <= nx - 1:
                            _visit(points, start, items, cx + r + nx * gy, qx, qy, best_d, best_i)
                left, right, low, high = cx - r > 0, cx + r < nx - 1, cy - r > 0, cy + r < ny - 1
                if not (left or right or low or high):
                    break  # every cell searched
                reach = np.inf
                if left:
                    reach = min(reach, qx - (x0 + (cx - r) * h))
                if right:
                    reach = min(reach, (x0 + (cx + r + 1) * h) - qx)
                if low:
                    reach = min(reach, qy - (y0 + (cy - r) * h))
                if high:
                    reach = min(reach, (y0 + (cy + r + 1) * h) - qy)
                if best_d[k - 1] < reach:
                    break
                r += 1
        for t in range(k):
            dist[j, t] = best_d[t]
            idx[j, t] = best_i[t]
