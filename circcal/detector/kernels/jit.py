"""``njit`` for the detector's compiled loops (:mod:`circcal.detector.measure.edges`, :mod:`circcal.detector.measure.levels`,
:mod:`circcal.detector.measure.ellipse`, :mod:`circcal.detector.measure.robust`): compiled ahead of time at install, numba's JIT
where that build is missing or stale, plain Python where numba is missing too.

Why ahead of time, and the alternatives measured: ``docs/kernels.md`` ("Why ahead of time"). In short: numba's
import and first cached call cost a process ~0.75 s, more than a one-image ``circcal detect`` may take;
``make setup`` therefore runs :func:`circcal.detector.kernels.build.build` (``python -m
circcal.detector.kernels.build``), which compiles every kernel module with ``numba.pycc`` into an extension under
``circcal/detector/_aot/``. Loading it needs neither numba nor scipy (~1 ms), and its code is numba's own for the
same source and the same argument types (the same results to the bit and the same speed).

* Signatures: :func:`~circcal.detector.kernels.build.build` runs the detector on synthetic boards (uint8, uint16 and float32 images) under numba and
  exports every signature numba compiled for each kernel; a call whose arguments match none of them (checked here,
  in Python: pycc's wrappers do not check types and would crash) runs under numba instead, never wrongly.
* Staleness: an extension is named after a hash of its kernel module's source, of the kernel modules it calls
  (listed in its ``KERNEL_IMPORTS``), of this file, of numpy's version and of the CPU (the build is compiled for
  the host's, :data:`TARGET_CPU`), so an edited kernel module loads no old code, nor does another machine's CPU:
  until the next build it runs under numba's JIT. A kernel reads only its own module's constants (numba freezes
  them into the code); it calls kernels of its own module or of those it lists (numba's disk cache, which checks
  only the caller's file, then also checks theirs: :mod:`circcal.detector.kernels.jitcache`).
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
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["njit", "COMPILED", "Kernel", "aot_status", "compile_seconds"]

#: Where :func:`build` writes the compiled kernel modules (one extension + its signatures per kernel module).
AOT_DIR = Path(__file__).resolve().parents[1] / "_aot"
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
if not COMPILED:  # pragma: no cover - exercised by tests/detector/test_kernels.py in a subprocess
    warnings.warn(
        "numba is not installed: circcal's detector runs its per-pixel loops in plain Python (same "
        "results, ~50x slower); `pip install numba` restores the speed",
        RuntimeWarning,
        stacklevel=2,
    )

_lock = threading.RLock()
#: seconds spent in calls that made numba compile (a type the ahead-of-time build lacks, or no build): the time
#: budget of an image (:class:`circcal.detector.locate.budget.Deadline`) does not count them
_compile_s = 0.0
#: module name -> its kernels, in the order they were decorated
_registry: dict[str, list[Kernel]] = {}
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
                    table[kernel] = [([_loaded_spec(a) for a in e["args"]], getattr(mod, e["symbol"])) for e in entries]
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
            flags = a.flags  # (a new flags object per access: read once)
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
    """One detector kernel, as :func:`njit` makes it: a callable that picks the fastest way to run its function.

    Called from Python it runs the ahead-of-time build for its arguments' types, else numba's JIT (imported on the
    first such call), else the plain Python function.

    Parameters
    ----------
    fn : Callable
        The kernel's Python source function.
    options : dict of str to Any
        numba's ``njit`` options for it (``cache``, ``nogil``, ``inline``, ``error_model``, ...).

    Attributes
    ----------
    py_func : Callable
        The source function (``fn``).
    options : dict of str to Any
        The ``njit`` options.
    module : str
        The name of the module that defines it (its kernel module).
    """

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
        """numba's dispatcher for this kernel, made on first use.

        The first call turns every kernel of the module into numba dispatchers at once and rebinds the module's names
        to them, since a kernel calling another is compiled by numba only if that name is numba's.

        Returns
        -------
        Callable
            numba's dispatcher; the plain Python function where numba is not installed.
        """
        if self._jit is None:
            _jit_module(self.module)
        return self._jit  # type: ignore[return-value]


#: Whether this process has said that it compiles kernels (said once, to stderr).
_told = False


def _tell_compiling(module: str) -> None:
    """Say once per process, before numba compiles, that the detector's kernels are being compiled: the first run
    without the ahead-of-time build spends up to a minute there (never charged to an image's time budget). Said
    only where numba's disk cache holds no kernel yet (no ``.nbi`` index file beside ``module``'s source, or under
    ``NUMBA_CACHE_DIR`` where that is set); later processes load the cache silently."""
    global _told
    if _told:
        return
    source = Path(sys.modules[module].__file__ or "")
    pattern = "*.nbi"  # any kernel cached: a warm cache (an edited module recompiles alone, in seconds)
    cache_dir = os.environ.get("NUMBA_CACHE_DIR")  # where set, numba caches there only
    place = Path(cache_dir) if cache_dir else source.parent / "__pycache__"
    if place.is_dir() and next(place.rglob(pattern), None) is not None:
        return
    _told = True
    print(
        "circcal: compiling the detector's kernels (first run only; `make setup` builds them ahead of time)",
        file=sys.stderr,
        flush=True,
    )


def _jit_module(module: str) -> None:
    """Turn the kernels of ``module`` into numba dispatchers and rebind its names to them, those of the kernel modules
    it calls (:func:`_kernel_imports`) first, and its imported names of their kernels too (numba compiles a call to
    another kernel only through numba's dispatcher). A module that calls other modules' kernels is cached on disk
    with its callees' sources in the cache's stamp (:mod:`circcal.detector.kernels.jitcache`: numba's own cache checks only
    the caller's file, so an edited callee would leave stale code)."""
    with _lock:
        kernels = _registry[module]
        if all(k._jit is not None for k in kernels):
            return
        deps = _kernel_imports(module)
        for dep in deps:
            _jit_module(dep)
        made: dict[Kernel, Callable] = {}
        if _HAVE_NUMBA:
            import numba

            _tell_compiling(module)

            for k in kernels:
                made[k] = numba.njit(**(dict(k.options, cache=False) if deps else k.options))(k.py_func)
                if deps and k.options.get("cache"):
                    from circcal.detector.kernels import jitcache

                    jitcache.enable(made[k], [sys.modules[m].__file__ for m in deps])
        else:
            made = {k: k.py_func for k in kernels}
        # the module's names are rebound before any kernel publishes its dispatcher (k._jit): a thread that finds a
        # dispatcher may run it at once, and numba resolves the kernels it calls through these names (published
        # first, a caller compiled in another thread met a Kernel object: "Untyped global name")
        namespace = sys.modules[module].__dict__
        for k in kernels:
            if namespace.get(k.__name__) is k:
                namespace[k.__name__] = made[k]
        for name, value in list(namespace.items()):
            if isinstance(value, Kernel) and value.module in deps:
                namespace[name] = value._jit
        for k in kernels:
            k._jit = made[k]


def njit(*args, **kwargs):
    """Mark a function as a detector kernel: numba's ``njit`` signature, returning a :class:`Kernel`.

    Usable as ``@njit`` and ``@njit(...)``. The kernel is registered under its module, for the ahead-of-time build
    (:func:`circcal.detector.kernels.build.build`).

    Parameters
    ----------
    *args : Callable
        The function, when used bare (``@njit``).
    **kwargs : Any
        numba's ``njit`` options (``cache=True``, ``nogil=True``, ``inline="always"``, ``error_model="numpy"``, ...).

    Returns
    -------
    Kernel or Callable
        The :class:`Kernel` (bare use), or a decorator that makes one.

    Examples
    --------
    >>> @njit(cache=True, nogil=True)  # doctest: +SKIP
    ... def _twice(x):
    ...     return 2.0 * x
    >>> _twice(1.5)  # doctest: +SKIP
    3.0
    """
    if len(args) == 1 and callable(args[0]) and not kwargs:
        return njit()(args[0])

    def wrap(fn: Callable) -> Kernel:
        k = Kernel(fn, kwargs)
        with _lock:
            _registry.setdefault(k.module, []).append(k)
        return k

    return wrap


def compile_seconds() -> float:
    """The time this process has spent in kernel calls that made numba compile.

    A type the ahead-of-time build lacks, or no build; the time budget of an image
    (:class:`circcal.detector.locate.budget.Deadline`) does not count it.

    Returns
    -------
    float
        s, never decreasing.
    """
    return _compile_s


def aot_status() -> dict[str, bool]:
    """Which kernel modules have an ahead-of-time build of their current source.

    Returns
    -------
    dict of str to bool
        Kernel module -> whether an ahead-of-time build of its current source is loaded or loadable. Modules whose
        kernels are all inlined into other modules' kernels (``inline="always"``) have nothing of their own to
        build and are not listed.
    """
    return {
        m: bool(_load_aot(m)) for m, ks in _registry.items() if any(k.options.get("inline") != "always" for k in ks)
    }


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
        return [
            "array",
            np.dtype(str(t.dtype) if str(t.dtype) != "bool" else np.bool_).str,
            t.ndim,
            t.layout,
            bool(t.mutable),
        ]
    if isinstance(t, types.Boolean):
        return ["bool"]
    if isinstance(t, types.Integer) and t.bitwidth == 64 and t.signed:
        return ["int"]
    if isinstance(t, types.Float) and t.bitwidth == 64:
        return ["float"]
    return None
