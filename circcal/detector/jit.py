"""``njit`` for the detector's compiled loops (:mod:`circcal.detector.edges`, :mod:`circcal.detector.levels`,
:mod:`circcal.detector.ellipse`, :mod:`circcal.detector.robust`): compiled ahead of time at install, numba's JIT
where that build is missing or stale, plain Python where numba is missing too.

Why ahead of time: numba costs a process ~0.3 s to import (it pulls in scipy) and ~0.45 s more at the first call of
a kernel it has cached on disk (its type registries load then), which alone broke the 0.6 s a one-image
``circcal detect`` may take. ``make setup`` therefore runs :func:`build` (``python -c "import circcal.detector.jit
as j; j.build()"``), which compiles every kernel module with ``numba.pycc`` into an extension under
``circcal/detector/_aot/``. Loading it needs neither numba nor scipy (~1 ms), and its code is numba's own for the
same source and the same argument types (the same results to the bit and the same speed, measured: benchmarks/
bench_startup.py). Alternatives measured against it: numba's on-disk cache (~0.75 s of fixed cost, above), Cython or
vectorised numpy (the loops written a second time, in a module the detector does not own, and slower for
quickselect and per-profile early exits).

* Signatures: :func:`build` runs the detector on synthetic boards (uint8, uint16 and float32 images) under numba and
  exports every signature numba compiled for each kernel; a call whose arguments match none of them (checked here,
  in Python: pycc's wrappers do not check types and would crash) runs under numba instead, never wrongly.
* Staleness: an extension is named after a hash of its kernel module's source, of the kernel modules it calls
  (listed in its ``KERNEL_IMPORTS``), of this file, of numpy's version and of the CPU (the build is compiled for
  the host's, :data:`TARGET_CPU`), so an edited kernel module loads no old code, nor does another machine's CPU:
  until the next build it runs under numba's JIT. A kernel reads only its own module's constants (numba freezes
  them into the code); it calls kernels of its own module or of those it lists (numba's disk cache, which checks
  only the caller's file, then also checks theirs: :mod:`circcal.detector.jitcache`).
* The GIL is released inside compiled kernels (``nogil``), as under numba, so threaded detection stays parallel.
* ``CIRCCAL_AOT=0`` ignores the ahead-of-time build (numba's JIT, as before it existed).

``numba.pycc`` is pending deprecation in numba 0.68 (its replacement is not released yet); when it goes, the build
fails loudly and the detector runs under numba's JIT as before: slower to start, the same results.
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
import json
import os
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

if TYPE_CHECKING:  # annotations only
    from circcal.board import Board

__all__ = ["njit", "COMPILED", "Kernel", "build", "aot_status", "compile_seconds", "synthetic_board"]

#: Where :func:`build` writes the compiled kernel modules (one extension + its signatures per kernel module).
AOT_DIR = Path(__file__).resolve().parent / "_aot"
#: Set to "0" to ignore the ahead-of-time build (numba's JIT only).
AOT_ENV = "CIRCCAL_AOT"
#: The CPU the ahead-of-time build generates code for: the host's (its instruction-set extensions: the levels pass
#: ~27 % and the block means ~34 % faster than pycc's portable default, measured on this project's 2-core machine),
#: as numba's JIT does; the build is named after the CPU (:func:`_host_cpu`), so it never runs on another. Where the
#: CPU's instruction sets cannot be read (no ``/proc/cpuinfo``), pycc's portable default is kept.
TARGET_CPU = "host"

_HAVE_NUMBA = importlib.util.find_spec("numba") is not None
#: True when the kernels run compiled (ahead of time or by numba); False: plain Python (~50x slower).
COMPILED = _HAVE_NUMBA or (os.environ.get(AOT_ENV) != "0" and AOT_DIR.is_dir() and any(AOT_DIR.glob("*.json")))
if not COMPILED:  # pragma: no cover - exercised by tests/test_detect.py in a subprocess
    warnings.warn("numba is not installed: circcal's detector runs its per-pixel loops in plain Python (same "
                  "results, ~50x slower); `pip install numba` restores the speed", RuntimeWarning, stacklevel=2)

_lock = threading.RLock()
#: seconds spent in calls that made numba compile (a type the ahead-of-time build lacks, or no build): the time
#: budget of an image (:class:`circcal.detector.budget.Deadline`) does not count them
_compile_s = 0.0
#: module name -> its kernels, in the order they were decorated
_registry: dict[str, list["Kernel"]] = {}
#: module name -> {kernel name: [(argument specs, compiled function)]}, loaded once per module
_aot_cache: dict[str, dict[str, list[tuple[list, Callable]]]] = {}


def _kernel_imports(module: str) -> tuple[str, ...]:
    """The kernel modules whose kernels ``module``'s kernels call (its ``KERNEL_IMPORTS``, and theirs), in
    dependency order: their sources are part of its build's name, and they are turned into numba dispatchers first."""
    out: list[str] = []
    for dep in getattr(sys.modules[module], "KERNEL_IMPORTS", ()):
        for m in (*_kernel_imports(dep), dep):
            if m not in out:
                out.append(m)
    return tuple(out)


def _module_key(module: str) -> str:
    """Hash (16 hex) naming a kernel module's compiled build: its source file and those of the kernel modules it
    calls (:func:`_kernel_imports`), this file, numpy's version and the CPU (:func:`_host_cpu`: the build is compiled
    for the CPU it runs on)."""
    h = hashlib.sha256()
    for path in (sys.modules[module].__file__, *(sys.modules[m].__file__ for m in _kernel_imports(module)), __file__):
        h.update(Path(path).read_bytes())
    h.update(np.__version__.encode())
    h.update(_host_cpu().encode())
    return h.hexdigest()[:16]


@functools.lru_cache(maxsize=1)
def _host_cpu() -> str:
    """What identifies this machine's CPU for code generation: on Linux the first processor's model name and
    instruction-set flags (``/proc/cpuinfo``, read in under a millisecond), beside the machine type
    (``platform.machine``; ``platform.processor`` would start a subprocess). The ahead-of-time build is compiled
    for the host CPU (:data:`TARGET_CPU`); a build copied to a machine whose CPU differs is not found there (its
    name differs) and that machine runs numba's JIT instead of code that might use instructions its CPU lacks."""
    import platform

    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        lines = []
    wanted = {}
    for line in lines:
        key, _, value = line.partition(":")
        key = key.strip()
        if key in ("model name", "flags", "Features", "CPU part") and key not in wanted:
            wanted[key] = value.strip()
    return f"{platform.machine()}|" + "|".join(f"{k}={v}" for k, v in sorted(wanted.items()))


def _aot_name(module: str) -> str:
    return f"{module.rsplit('.', 1)[-1]}_{_module_key(module)}"


def _load_aot(module: str) -> dict[str, list[tuple[list, Callable]]]:
    """The ahead-of-time kernels of ``module`` built from its current source ({} if none)."""
    with _lock:
        if module in _aot_cache:
            return _aot_cache[module]
        table: dict[str, list[tuple[list, Callable]]] = {}
        name = _aot_name(module)
        manifest = AOT_DIR / f"{name}.json"
        if os.environ.get(AOT_ENV) != "0" and manifest.is_file():
            exports = json.loads(manifest.read_text())
            ext = next(AOT_DIR.glob(f"{name}.*.so"), None) or next(AOT_DIR.glob(f"{name}.*.pyd"), None)
            if ext is not None:
                spec = importlib.util.spec_from_file_location(name, ext)
                mod = importlib.util.module_from_spec(spec)
                spec.loader.exec_module(mod)
                for kernel, entries in exports.items():
                    table[kernel] = [([_loaded_spec(a) for a in e["args"]], getattr(mod, e["symbol"]))
                                     for e in entries]
        _aot_cache[module] = table
        return table


def _loaded_spec(spec: list) -> list:
    """A manifest's argument spec with its dtype string as a ``np.dtype`` (compared in :func:`_matches` on every
    call: ~5x cheaper than building ``a.dtype.str``)."""
    return [spec[0], np.dtype(spec[1]), *spec[2:]] if spec[0] == "array" else spec


def _matches(specs: list, args: tuple) -> bool:
    """Whether ``args`` have exactly the types one compiled signature was built for (see :func:`_spec_of`)."""
    if len(specs) != len(args):
        return False
    for s, a in zip(specs, args):
        kind = s[0]
        if kind == "array":
            if not (isinstance(a, np.ndarray) and a.dtype == s[1] and a.ndim == s[2]):
                return False
            flags = a.flags                          # (a new flags object per access: read once)
            if not flags.aligned or flags.writeable != s[4] or (s[3] == "C" and not flags.c_contiguous):
                return False
        elif kind == "int":
            if isinstance(a, (bool, np.bool_)) or not isinstance(a, (int, np.integer)):
                return False
        elif kind == "float":
            if not isinstance(a, (float, np.floating)):
                return False
        elif kind == "bool":
            if not isinstance(a, (bool, np.bool_)):
                return False
        else:
            return False
    return True


class Kernel:
    """One detector kernel: called from Python it runs the ahead-of-time build for its arguments' types, else
    numba's JIT (imported on the first such call), else the plain Python function. ``py_func`` is the source."""

    def __init__(self, fn: Callable, options: dict[str, Any]):
        self.py_func = fn
        self.options = options
        self.module = fn.__module__
        self.__name__ = fn.__name__
        self.__doc__ = fn.__doc__
        self.__wrapped__ = fn
        self._aot: list[tuple[list, Callable]] | None = None
        self._jit: Callable | None = None

    def __call__(self, *args):
        if self._jit is None:
            if self._aot is None:
                self._aot = _load_aot(self.module).get(self.__name__, [])
            for specs, fn in self._aot:
                if _matches(specs, args):
                    return fn(*args)
        fn = self.jitted()
        known = len(getattr(fn, "signatures", ()))
        t0 = time.monotonic()
        out = fn(*args)
        if len(getattr(fn, "signatures", ())) > known:  # numba compiled for these types: not the image's time
            global _compile_s
            with _lock:
                _compile_s += time.monotonic() - t0
        return out

    def jitted(self) -> Callable:
        """numba's dispatcher for this kernel (the plain function without numba). The first call turns every kernel
        of the module into numba dispatchers at once and rebinds the module's names to them, since a kernel calling
        another is compiled by numba only if that name is numba's."""
        if self._jit is None:
            _jit_module(self.module)
        return self._jit  # type: ignore[return-value]


def _jit_module(module: str) -> None:
    """Turn the kernels of ``module`` into numba dispatchers and rebind its names to them, those of the kernel modules
    it calls (:func:`_kernel_imports`) first, and its imported names of their kernels too (numba compiles a call to
    another kernel only through numba's dispatcher). A module that calls other modules' kernels is cached on disk
    with its callees' sources in the cache's stamp (:mod:`circcal.detector.jitcache`: numba's own cache checks only
    the caller's file, so an edited callee would leave stale code)."""
    with _lock:
        kernels = _registry[module]
        if all(k._jit is not None for k in kernels):
            return
        deps = _kernel_imports(module)
        for dep in deps:
            _jit_module(dep)
        if _HAVE_NUMBA:
            import numba

            for k in kernels:
                k._jit = numba.njit(**(dict(k.options, cache=False) if deps else k.options))(k.py_func)
                if deps and k.options.get("cache"):
                    from circcal.detector import jitcache

                    jitcache.enable(k._jit, [sys.modules[m].__file__ for m in deps])
        else:
            for k in kernels:
                k._jit = k.py_func
        namespace = sys.modules[module].__dict__
        for k in kernels:
            if namespace.get(k.__name__) is k:
                namespace[k.__name__] = k._jit
        for name, value in list(namespace.items()):
            if isinstance(value, Kernel) and value.module in deps:
                namespace[name] = value._jit


def njit(*args, **kwargs):
    """numba's ``njit`` signature (``@njit`` and ``@njit(...)``), returning a :class:`Kernel`."""
    if len(args) == 1 and callable(args[0]) and not kwargs:
        return njit()(args[0])

    def wrap(fn: Callable) -> Kernel:
        k = Kernel(fn, kwargs)
        with _lock:
            _registry.setdefault(k.module, []).append(k)
        return k

    return wrap


def compile_seconds() -> float:
    """Seconds this process has spent in kernel calls that made numba compile (never decreases)."""
    return _compile_s


def aot_status() -> dict[str, bool]:
    """Kernel module -> whether an ahead-of-time build of its current source is loaded or loadable (modules whose
    kernels are all inlined into other modules' kernels, ``inline="always"``, have nothing of their own to build and
    are not listed)."""
    return {m: bool(_load_aot(m)) for m, ks in _registry.items()
            if any(k.options.get("inline") != "always" for k in ks)}


def _spec_of(t) -> list | None:
    """A numba argument type as a check :func:`_matches` can run without numba: ``["array", dtype.str, ndim,
    layout, writeable]``, ``["int"]``, ``["float"]``, ``["bool"]``; None for a type not exported. A literal type
    (numba specialises a kernel called inside another with a constant, e.g. ``Literal[int](0)``) is not exported:
    its code holds that constant, and a check of the Python type alone would run it for any value."""
    from numba.core import types

    if isinstance(t, types.Literal):
        return None
    if isinstance(t, types.Array):
        if t.layout not in ("C", "A"):
            return None
        return ["array", np.dtype(str(t.dtype) if str(t.dtype) != "bool" else np.bool_).str, t.ndim, t.layout,
                bool(t.mutable)]
    if isinstance(t, types.Boolean):
        return ["bool"]
    if isinstance(t, types.Integer) and t.bitwidth == 64 and t.signed:
        return ["int"]
    if isinstance(t, types.Float) and t.bitwidth == 64:
        return ["float"]
    return None


def synthetic_board() -> tuple[np.ndarray, "Board"]:
    """A 640x480 uint8 image of a 5x6 symmetric board (dots 5 mm on a 10 mm pitch) in perspective, drawn at 8x and
    area-averaged: what :func:`build` runs the detector on."""
    import cv2

    from circcal.board import Board

    board = Board(5, 6, 10.0, 5.0)
    obj = board.object_points()[:, :2]
    w, h = obj.max(axis=0) + 10.0
    H = cv2.getPerspectiveTransform(np.float32([[0, 0], [w, 0], [w, h], [0, h]]),
                                    np.float32([[180, 120], [470, 140], [450, 380], [170, 360]]))
    big = np.full((480 * 8, 640 * 8), 230, np.uint8)
    for x, y in obj:
        px, py = cv2.perspectiveTransform(np.float64([[[x + 5.0, y + 5.0]]]), H)[0, 0]
        cv2.circle(big, (int(px * 8), int(py * 8)), int(2.5 * 290.0 / w * 8), 30, -1)
    return cv2.resize(big, (640, 480), interpolation=cv2.INTER_AREA), board


def _exercise() -> None:
    """Run the detector on :func:`synthetic_board` as uint8 (clean and noisy), uint16, float32 and float64 images
    (what image files and numpy callers give it: a float64 image is what a renderer hands over), so that numba
    compiles each kernel for the argument types detection gives it."""
    from circcal.detector.find import detect, recorrect
    from circcal.detector.segment import GUIDED_EPS, GUIDED_MIN_RADIUS, guided_filter, shrink
    from circcal.model import Camera

    img, board = synthetic_board()
    noisy = np.clip(img + np.random.default_rng(0).normal(0.0, 8.0, img.shape), 0, 255).astype(np.uint8)
    # the guided filter runs on noisy images whose plain Otsu mask shows no board (not this one): called as the
    # segmentation calls it
    guided_filter(noisy, GUIDED_MIN_RADIUS, GUIDED_EPS, np.zeros(256, np.int64))
    # the lattice search's neighbour queries (an asymmetric board, clutter: not this board's direct ordering) and
    # the small dots' clusters
    from circcal.detector.neighbours import NeighbourGrid, linked_clusters

    NeighbourGrid(np.random.default_rng(0).uniform(0.0, 100.0, (20, 2))).query(np.zeros((3, 2)), k=2)
    linked_clusters(np.random.default_rng(0).uniform(0.0, 100.0, (20, 2)), 2.5)
    for im in (img, noisy, img.astype(np.uint16) * 257, img.astype(np.float32) / 255.0,
               img.astype(np.float64) / 255.0):
        d = detect(im, board, time_budget_s=None)  # numba compiles inside this call: no budget for that
        if not d.found:
            raise RuntimeError(f"kernel build: the synthetic board was not found ({d.reason})")
    # a calibration re-corrects the centres under each new distortion estimate (the ellipses refitted in Python)
    recorrect(d, board, Camera(640, 480, 600.0, 600.0, 319.5, 239.5, np.array([-0.1, 0.01, 0.0, 0.0, 0.0])))
    shrink(np.repeat(np.repeat(img, 3, axis=0), 3, axis=1), 3)   # frames of 720 px and more are segmented shrunk


def build(out_dir: Path = AOT_DIR, force: bool = False) -> dict[str, list[str]]:
    """Compile every kernel module ahead of time into ``out_dir`` (see the module docstring), skipping those whose
    current source is built already (unless ``force``); builds of older sources are removed. Returns module -> the
    kernels exported (or ``["(current)"]``). Needs numba and a C compiler (pycc compiles the module's C glue)."""
    import tempfile

    import numba.pycc.compiler as pycc_compiler
    from numba.pycc import CC

    import circcal.detector.find  # noqa: F401 - registers every kernel module the detector uses

    for module in list(_registry):
        _jit_module(module)
    _exercise()

    class _NoGilFlags(pycc_compiler.Flags):  # pycc's wrappers would hold the GIL; numba's nogil kernels do not
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            self.release_gil = True

    pycc_compiler.Flags = _NoGilFlags
    # a kernel's own compile options that change its code (numba's njit takes them per function; pycc compiles all
    # exports of a module with one set of flags): ``error_model="numpy"`` (a float division without Python's zero
    # check, which keeps a loop from vectorising) is applied to that kernel's exports alone
    models = {k.py_func: k.options["error_model"] for ks in _registry.values() for k in ks
              if "error_model" in k.options}
    compile_extra = pycc_compiler.compile_extra

    def _compile_extra(typingctx, targetctx, func, args, return_type, flags, locals, **kw):
        if func in models:
            flags = flags.copy()
            flags.error_model = models[func]
        return compile_extra(typingctx, targetctx, func, args, return_type, flags, locals, **kw)

    pycc_compiler.compile_extra = _compile_extra
    out_dir.mkdir(parents=True, exist_ok=True)
    done: dict[str, list[str]] = {}
    from circcal.detector.curvature import store_table  # the curvature model's table: no scipy import at start-up

    store_table(out_dir)
    for module, kernels in _registry.items():
        name = _aot_name(module)
        if not force and out_dir == AOT_DIR and (out_dir / f"{name}.json").is_file():
            done[module] = ["(current)"]
            continue
        cc = CC(name)
        cc.verbose = False
        if "flags=" in _host_cpu() or "Features=" in _host_cpu():   # the CPU is known to the build's name
            cc.target_cpu = TARGET_CPU
        manifest: dict[str, list] = {}
        for k in kernels:
            for i, sig in enumerate(k._jit.signatures):
                specs = [_spec_of(t) for t in sig]
                if any(s is None for s in specs):
                    continue
                symbol = f"{k.__name__}__{i}"
                ret = k._jit.overloads[sig].signature.return_type
                cc.export(symbol, ret(*sig))(k.py_func)
                manifest.setdefault(k.__name__, []).append({"symbol": symbol, "args": specs})
        if not manifest:
            continue
        with tempfile.TemporaryDirectory(dir=out_dir) as tmp:  # moved in whole: a reader never sees half a build
            cc.output_dir = tmp
            with warnings.catch_warnings():  # pycc's own pending-deprecation notice: stated in the module docstring
                warnings.simplefilter("ignore")
                cc.compile()
            for old in out_dir.glob(f"{module.rsplit('.', 1)[-1]}_*"):
                old.unlink()
            for f in Path(tmp).iterdir():
                os.replace(f, out_dir / f.name)
            manifest_tmp = Path(tmp) / "manifest"
            manifest_tmp.write_text(json.dumps(manifest, indent=1) + "\n")
            os.replace(manifest_tmp, out_dir / f"{name}.json")
        done[module] = sorted(manifest)
    return done
