"""numba's on-disk cache for the kernels of a module that calls other kernel modules' kernels (the module's
``KERNEL_IMPORTS``, :mod:`circcal.detector.kernels.jit`), kept safe against an edited callee.

numba's cache checks only the caller's source file (its index stores that file's hash as the "source stamp"), so
code compiled against an older callee would load as current. Here the stamp is the caller's together with the
hash of every callee's source: an edited callee makes the cache a miss, and numba compiles afresh. numba's own
locators (``numba.core.caching``, in numba's order) still decide where the files go (``NUMBA_CACHE_DIR``, the
package's ``__pycache__``, the user's cache directory). Without this the JIT path (``CIRCCAL_AOT=0``, or a stale or
missing ahead-of-time build) compiled the levels kernels in every process: ~8 s of start-up.

Imported only where numba runs (it imports numba).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path

from numba.core import caching, config

__all__ = ["enable", "sources_digest"]


def sources_digest(paths: Sequence[str | Path]) -> str:
    """The SHA-256 of the contents of some files, in order.

    Parameters
    ----------
    paths : sequence of (str or pathlib.Path)
        The files.

    Returns
    -------
    str
        64 hex digits.

    Raises
    ------
    OSError
        A file cannot be read.
    """
    h = hashlib.sha256()
    for p in paths:
        h.update(Path(p).read_bytes())
    return h.hexdigest()


class _DependentLocator(caching._CacheLocator):
    """numba's first suitable locator for the function, its source stamp extended by :attr:`digest` (set on the
    subclass :func:`enable` makes)."""

    digest = ""

    def __init__(self, inner: caching._CacheLocator):
        self._inner = inner

    def ensure_cache_path(self) -> None:
        self._inner.ensure_cache_path()

    def get_cache_path(self) -> str:
        return self._inner.get_cache_path()

    def get_source_stamp(self):
        return self._inner.get_source_stamp(), self.digest

    def get_disambiguator(self) -> str:
        return self._inner.get_disambiguator()

    @classmethod
    def from_function(cls, py_func, py_file):
        for base in caching.CompileResultCacheImpl._locator_classes:
            inner = base.from_function(py_func, py_file)
            if inner is not None:
                return cls(inner)
        return None


def enable(dispatcher, dependency_files: Sequence[str | Path]) -> bool:
    """Cache a numba dispatcher on disk with the sources of the kernels it calls in its stamp.

    Parameters
    ----------
    dispatcher : numba.core.registry.CPUDispatcher
        numba's dispatcher, made with ``cache=False``.
    dependency_files : sequence of (str or pathlib.Path)
        The source files of the kernel modules it calls.

    Returns
    -------
    bool
        True when cached; False, leaving it uncached, where numba's locators are overridden
        (``NUMBA_CACHE_LOCATOR_CLASSES``: the stamp would not be this one) or none can cache the function (no
        writable directory).
    """
    if config.CACHE_LOCATOR_CLASSES:
        return False
    locator = type("Locator", (_DependentLocator,), {"digest": sources_digest(dependency_files)})
    impl = type("Impl", (caching.CompileResultCacheImpl,), {"_locator_classes": [locator]})
    cache_class = type("Cache", (caching.FunctionCache,), {"_impl_class": impl})
    try:
        cache = cache_class(dispatcher.py_func)
    except RuntimeError:  # numba: "cannot cache function ...: no locator available"
        return False
    dispatcher._cache = cache  # what numba's Dispatcher.enable_caching sets, with its own FunctionCache
    return True
