"""The lattice search's nearest-neighbour queries (circcal.detector.locate.neighbours) against scipy's cKDTree, which they
replace: the same distances to the bit, the same neighbours where no two are equally far, equal distances in index
order; and no scipy import on the way (the reason for the module)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial import cKDTree

from circcal.detector.kernels.jit import aot_status as _aot
from circcal.detector.locate.neighbours import NeighbourGrid


@pytest.mark.parametrize("kind", ["uniform", "integer", "collinear", "duplicates", "one"])
@pytest.mark.parametrize("k", [1, 2, 9])
def test_the_k_nearest_are_cKDTrees(kind, k):
    rng = np.random.default_rng(len(kind) * 10 + k)
    M = 1 if kind == "one" else 300
    P = {
        "uniform": lambda: rng.uniform(0, 1000, (M, 2)),
        "integer": lambda: np.round(rng.uniform(0, 30, (M, 2))),  # many exact ties
        "collinear": lambda: np.column_stack([rng.uniform(0, 500, M), np.full(M, 7.0)]),
        "duplicates": lambda: np.repeat(rng.uniform(0, 100, (M // 3, 2)), 3, axis=0),
        "one": lambda: rng.uniform(0, 10, (1, 2)),
    }[kind]()
    Q = np.concatenate([rng.uniform(-200, 1200, (200, 2)), P[:20], [[1e6, -1e6]]])  # inside, on points, far out
    d_ref, i_ref = cKDTree(P).query(Q, k=k)
    d, i = NeighbourGrid(P).query(Q, k=k)
    assert d.shape == d_ref.shape and i.shape == i_ref.shape
    assert np.array_equal(d, d_ref)  # (inf and index M where fewer than k)
    if kind == "uniform":
        assert np.array_equal(i, i_ref)
    dd = d.reshape(len(Q), -1)
    ii = i.reshape(len(Q), -1)
    same = (dd[:, 1:] == dd[:, :-1]) & np.isfinite(dd[:, 1:])
    assert np.all(ii[:, 1:][same] > ii[:, :-1][same])  # ties in index order
    ok = np.isfinite(dd)
    assert np.allclose(np.linalg.norm(P[np.where(ok, ii, 0)] - Q[:, None], axis=-1)[ok], dd[ok], rtol=0, atol=0)


def _printed(code: str) -> list[str]:
    """The words ``code`` prints, run in a fresh interpreter (what a new process imports is the question)."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout.split()


def test_an_asymmetric_board_is_detected_without_importing_scipy():
    # the lattice search (every asymmetric board, any board among clutter) used scipy's k-d tree: 0.2-0.35 s of
    # import in a one-image `circcal detect`, more than the detection
    code = (
        "import sys, numpy as np\n"
        "from circcal.board import Board\n"
        "from circcal.detector import detect\n"
        "from circcal.fixtures.render import render_view, to_uint\n"
        "from circcal.fixtures.poses import pose_looking_at\n"
        "from circcal.model import Camera\n"
        "cam = Camera(640, 480, 600.0, 600.0, 319.5, 239.5)\n"
        "b = Board(11, 4, 20.0, 10.0, 'asymmetric')\n"
        "r, t = pose_looking_at(cam, b, distance_mm=500, tilt_deg=20, tilt_axis_deg=30, roll_deg=10,"
        " target_px=(320.0, 240.0))\n"
        "img = to_uint(render_view(cam, b, r, t), 8)\n"
        "before = 'scipy.spatial' in sys.modules\n"
        "d = detect(img, b)\n"
        "print(d.found, before, 'scipy.spatial' in sys.modules)\n"
    )
    assert _printed(code) == ["True", "False", "False"]


def _scipy_clusters(P: np.ndarray, link: float) -> np.ndarray:
    """The clusters as the small dots' search computed them with scipy before linked_clusters replaced it."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    tree = cKDTree(P)
    nn = tree.query(P, k=2)[0][:, 1]
    pairs = tree.query_pairs(link * float(np.max(nn)), output_type="ndarray").reshape(-1, 2)
    dist = np.linalg.norm(P[pairs[:, 0]] - P[pairs[:, 1]], axis=1)
    pairs = pairs[dist < link * np.minimum(nn[pairs[:, 0]], nn[pairs[:, 1]])]
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(P), len(P)))
    return connected_components(g, directed=False)[1]


@pytest.mark.parametrize("kind", ["lattices-and-clutter", "integer", "duplicates", "isolated-far", "two"])
def test_linked_clusters_are_scipys_components(kind):
    from circcal.detector.locate.neighbours import linked_clusters

    rng = np.random.default_rng(len(kind))
    g = np.stack(np.meshgrid(np.arange(7), np.arange(7)), -1).reshape(-1, 2).astype(float)
    P = {
        "lattices-and-clutter": lambda: np.concatenate(
            [g * 12 + 100 + rng.normal(0, 0.3, g.shape), g * 30 + [400, 50], rng.uniform(0, 900, (400, 2))]
        ),
        "integer": lambda: np.round(rng.uniform(0, 40, (500, 2))),  # ties at the link distance
        # a point twice: nearest neighbour at 0, linked to nothing, beside a lattice that links
        "duplicates": lambda: np.concatenate([g * 10, g[:10] * 10, rng.uniform(0, 300, (60, 2))]),
        # one point far from the rest: a radius common to all would be the whole image
        "isolated-far": lambda: np.concatenate([g * 10, rng.uniform(200, 260, (300, 2)), [[5000.0, 5000.0]]]),
        "two": lambda: np.array([[0.0, 0.0], [3.0, 4.0]]),
    }[kind]()
    lab = linked_clusters(P, 2.5)
    ref = _scipy_clusters(P, 2.5)
    assert np.array_equal(lab, ref)
    assert lab.max() + 1 < len(P)  # something was linked (not a vacuous equality)


@pytest.mark.skipif(
    not (all(_aot().values()) and bool(_aot())),
    reason="no ahead-of-time build of the current kernel sources: numba (which imports scipy) runs the kernels",
)
def test_small_dots_are_searched_without_importing_scipy():
    # dots too small for the shrunk scale are searched again at full resolution in their clusters' windows; the
    # clusters came from scipy (cKDTree, csgraph) until linked_clusters: 0.18 s and 27 MiB of a one-image
    # `circcal detect` of a 12 MP frame. (2.5, not 3.0: with the 6 px^2 candidate floor the 3.0 board is found at
    # the shrunk scale itself and the search is not needed.)
    code = (
        "import sys\n"
        "from circcal.board import Board\n"
        "from circcal.detector import detect\n"
        "import circcal.detector.locate.search as S\n"
        "from circcal.fixtures.frames import embedded_board\n"
        "b = Board(7, 7, 10.0, 5.0)\n"
        "img, _ = embedded_board(b, 4000, 3000, 2.5, (1800.0, 1650.0))\n"
        "calls = []\n"
        "orig = S._cluster_windows\n"
        "S._cluster_windows = lambda *a: calls.append(1) or orig(*a)\n"
        "d = detect(img, b)\n"
        "print(d.found, len(calls) > 0, 'scipy' in sys.modules)\n"
    )
    assert _printed(code) == ["True", "True", "False"]
