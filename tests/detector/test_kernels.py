"""The detector's kernels compiled ahead of time (circcal/detector/kernels/jit.py): loaded without numba, the same results
as numba's JIT to the bit, and a call with other argument types runs under numba instead of crashing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from circcal.detector.find import detect
from circcal.detector.kernels import jit
from tests.detector.helpers import BOARD, CAM, _render

REPO = Path(__file__).resolve().parents[2]
BUILT = all(jit.aot_status().values()) and bool(jit.aot_status())
needs_build = pytest.mark.skipif(
    not BUILT,
    reason="no ahead-of-time build of the current kernel sources "
    "(make setup builds it; a failed build falls back to numba)",
)


def _run(code: str, **env: str) -> str:
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=600, env={**os.environ, **env}
    )
    assert r.returncode == 0, r.stderr
    return r.stdout


@needs_build
def test_detection_runs_the_built_kernels_without_importing_numba_or_scipy(tmp_path):
    code = (
        "import sys, numpy as np\n"
        "from circcal.detector.kernels import jit\n"
        "from circcal.detector.find import detect\n"
        "from circcal.detector.kernels.build import synthetic_board\nimg, board = synthetic_board()\n"
        "noisy = np.clip(img + np.random.default_rng(3).normal(0, 8, img.shape), 0, 255).astype(np.uint8)\n"
        "for im in (noisy, img, img.astype(np.uint16) * 257, img.astype(np.float32) / 255.0):\n"
        "    d = detect(im, board)\n"
        "    assert d.found\n"
        f"np.save({str(tmp_path / 'aot.npy')!r}, d.centres)\n"
        "print('numba' in sys.modules, 'scipy.linalg' in sys.modules, 'scipy.special' in sys.modules)\n"
    )
    assert _run(code).split() == ["False", "False", "False"]
    # the same centres as numba's JIT, to the bit
    _run(code.replace("aot.npy", "jit.npy").replace("print(", "# "), CIRCCAL_AOT="0")
    assert np.array_equal(np.load(tmp_path / "aot.npy"), np.load(tmp_path / "jit.npy"))


@needs_build
def test_the_stored_curvature_table_is_the_computed_one(tmp_path):
    from circcal.detector.measure import curvature

    assert np.array_equal(curvature._shift_table(), curvature._computed_table())
    path = curvature.store_table(tmp_path)
    assert path.parent == tmp_path and np.array_equal(np.load(path), curvature._computed_table())
    (tmp_path / "curvature-table_0000000000000000.npy").write_bytes(b"")  # an older source's table: removed
    curvature.store_table(tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


@needs_build
def test_other_argument_types_run_under_numba_not_the_built_code():
    code = (
        "import sys, numpy as np\n"
        "from circcal.detector.measure import ellipse\n"
        "q = ellipse.conic_from_params_batch(np.array([[3.0, 4.0], [9.0, 1.0]]), np.array([[5.0, 2.0], [3.0, 1.0]]),"
        " np.array([0.3, -1.0]))\n"
        "a = ellipse.conic_params_batch(q)\n"  # (the build's types)
        "before = 'numba' in sys.modules\n"
        "out = np.empty((2, 2)), np.empty((2, 2)), np.empty(2), np.empty(2, bool)\n"
        "ellipse._conic_params_kernel(q.astype(np.float32)[::-1], *out)\n"  # float32, not contiguous
        "print(before, 'numba' in sys.modules, np.allclose(a[0][::-1], out[0], rtol=1e-5))\n"
    )
    assert _run(code).split() == ["False", "True", "True"]


def test_argument_checks():
    arr = ["array", "<f8", 2, "C", True]
    x = np.zeros((3, 2))
    assert jit._matches([arr, ["int"], ["float"], ["bool"]], (x, 3, 1.5, True))
    assert jit._matches([arr, ["int"]], (x, np.int64(3)))
    assert not jit._matches([arr], (x.astype(np.float32),))
    assert not jit._matches([arr], (x.T,))  # not C-contiguous
    assert jit._matches([["array", "<f8", 2, "A", True]], (x.T,))
    assert not jit._matches([arr], (np.zeros(3),))  # ndim
    ro = x.copy()
    ro.flags.writeable = False
    assert not jit._matches([arr], (ro,))
    assert not jit._matches([arr, ["int"]], (x, True))  # a bool is not an int64
    assert not jit._matches([arr, ["int"]], (x, 2.0))
    assert not jit._matches([arr], (x, 1))


def test_numba_caches_kernels_that_call_other_modules_and_drops_them_when_a_callee_changes(tmp_path):
    # levels' kernel calls robust's selection: under numba's JIT (no ahead-of-time build) it is cached on disk like
    # the others (uncached, every process compiled it: ~8 s of start-up), and an edited robust.py, which numba's
    # own cache check would not see, makes it compile afresh. On a copy of the package, so the edit is harmless.
    import shutil

    pkg = tmp_path / "pkg"
    shutil.copytree(REPO / "circcal", pkg / "circcal", ignore=shutil.ignore_patterns("_aot", "__pycache__"))
    code = (
        "import numpy as np\n"
        "from circcal.detector.measure import levels\n"
        "from circcal.detector.kernels.build import synthetic_board\n"
        "from circcal.detector.measure.ellipse import conic_from_params_batch\n"
        "img, _ = synthetic_board()\n"
        "Q = conic_from_params_batch(np.array([[320.0, 240.0]]), np.array([[30.0, 20.0]]), np.array([0.3]))\n"
        "dark, plane, ok = levels.dot_levels_batch(img, Q, np.array([[250, 180, 390, 300]]))\n"
        "st = levels._levels_kernel.stats\n"
        f"assert levels.__file__.startswith({str(pkg)!r})\n"
        "print(sum(st.cache_hits.values()), sum(st.cache_misses.values()), repr(float(dark[0])))\n"
    )
    env = {**os.environ, "CIRCCAL_AOT": "0", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}

    def run() -> list[str]:  # (in the copy's folder: the copy comes first on sys.path)
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=pkg, timeout=600, env=env)
        assert r.returncode == 0, r.stderr
        return r.stdout.split()

    first, again = run(), run()
    robust = pkg / "circcal" / "detector" / "measure" / "robust.py"
    robust.write_text(robust.read_text() + "\n# an edited callee\n")
    edited = run()
    assert first[:2] == ["0", "1"] and again[:2] == ["1", "0"] and edited[:2] == ["0", "1"]
    assert first[2] == again[2] == edited[2]


def test_literal_signatures_are_not_exported():
    # numba specialises a helper called with a constant (Literal[int](0)): its code holds that constant, so the
    # build must not offer it for every int (a helper called from Python once got the literal-0 code and returned
    # a wrong median)
    from numba.core import types

    assert jit._spec_of(types.literal(0)) is None and jit._spec_of(types.literal(True)) is None
    assert jit._spec_of(types.int64) == ["int"]


def test_the_build_is_named_after_the_kernel_source():
    # an edited kernel module loads no old build: its name carries the hash of the module's source
    key = jit._module_key("circcal.detector.measure.edges")
    assert len(key) == 16 and jit._aot_name("circcal.detector.measure.edges") == f"edges_{key}"
    assert key != jit._module_key("circcal.detector.measure.levels")


def test_a_build_for_another_cpu_is_not_loaded(monkeypatch):
    # the build is compiled for the host CPU: on a machine whose CPU differs its name differs, so it is not found
    # there (numba's JIT runs instead of instructions that CPU may lack)
    here = jit._aot_name("circcal.detector.measure.levels")
    assert "flags=" in jit._host_cpu() or not Path("/proc/cpuinfo").is_file()
    monkeypatch.setattr(jit, "_host_cpu", lambda: "x86_64|model name=another|flags=fpu sse sse2")
    assert jit._aot_name("circcal.detector.measure.levels") != here
    monkeypatch.setattr(jit, "_aot_cache", {})
    assert jit._load_aot("circcal.detector.measure.levels") == {}


def test_synthetic_board_is_found():
    from circcal.detector.kernels.build import synthetic_board

    img, board = synthetic_board()
    d = detect(img, board)
    assert d.found and d.centres.shape == (board.n_points, 2)


def test_threads_meeting_cold_kernels_all_get_compiled_code(tmp_path):
    """Under numba's JIT on a cold cache (no ahead-of-time build), four threads detecting at once: every kernel's
    names are rebound before its dispatcher is published, so no thread meets a caller compiled against a Kernel
    object (numba's "Untyped global name '_fit_kernel'" in 1 of 6 such runs before)."""
    code = (
        "from concurrent.futures import ThreadPoolExecutor\n"
        "from circcal.detector import detect\n"
        "from circcal.detector.kernels.build import synthetic_board\n"
        "img, board = synthetic_board()\n"
        "with ThreadPoolExecutor(4) as pool:\n"
        "    found = list(pool.map(lambda _: detect(img, board, time_budget_s=None).found, range(4)))\n"
        "print(found)\n"
    )
    env = {**os.environ, "CIRCCAL_AOT": "0", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900, env=env)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.split() == ["[True,", "True,", "True,", "True]"]
    # issue 35: the first run says, once, that it compiles; a run on the warm cache says nothing
    assert r.stderr.count("compiling the detector's kernels (first run only") == 1, r.stderr[-3000:]
    again = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900, env=env)
    assert again.returncode == 0 and "compiling" not in again.stderr, again.stderr[-3000:]


def test_without_numba_the_same_detector_runs_as_plain_python(tmp_path):
    # the compiled loops are ordinary Python too: blocked numba import -> warning, identical centres
    img, truth, *_ = _render(CAM, 10, 30)
    np.save(tmp_path / "img.npy", img)
    code = (
        "import sys, warnings; sys.modules['numba'] = None\n"
        "with warnings.catch_warnings(record=True) as w:\n"
        "    warnings.simplefilter('always')\n"
        "    import circcal.detector.kernels.jit\n"
        "import numpy as np\n"
        "from circcal.board import Board\n"
        "from circcal.detector import detect\n"
        f"d = detect(np.load({str(tmp_path / 'img.npy')!r}), Board(4, 5, 10.0, 5.0))\n"
        f"np.save({str(tmp_path / 'c.npy')!r}, d.centres)\n"
        "print(circcal.detector.kernels.jit.COMPILED, any('numba is not installed' in str(x.message) for x in w))\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
        env={**os.environ, "CIRCCAL_AOT": "0"},
    )  # without the ahead-of-time kernels too
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["False", "True"]
    d = detect(img, BOARD)
    assert np.allclose(np.load(tmp_path / "c.npy"), d.centres, rtol=0, atol=1e-9)
